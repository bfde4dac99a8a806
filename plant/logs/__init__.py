"""Rig logs and their I/O: the CSV + JSON sidecar, the rig constants, the reference trajectory, plots of logged errors.

Part of :mod:`plant`; the public names are re-exported there.
"""
