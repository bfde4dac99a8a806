"""Exceptions raised by the :mod:`plant` package."""


class LogError(ValueError):
    """A rig log (CSV + JSON sidecar) is missing, malformed or inconsistent.

    The message is one line and names the file and, where it applies, the
    row, column or sidecar key at fault.
    """


class SimulationError(RuntimeError):
    """A closed-loop simulation failed (diverged or left the valid model region).

    Raised at the Python level by the single-candidate wrappers; the compiled
    batch kernels never raise, they return a status code and a penalty instead.
    """
