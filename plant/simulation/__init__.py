"""The closed-loop simulator: one sample-step core advancing a plant's right-hand side, and the drivers (P experiment, logged-input replay, any controller).

Part of :mod:`plant`; the public names are re-exported there.
"""
