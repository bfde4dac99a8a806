"""The robot model: the DH/URDF robot description, its symbolic derivation (casadi), generated numeric code, the PUMA 560 links 2-3 instance, payloads.

Part of :mod:`plant`; the public names are re-exported there.
"""
