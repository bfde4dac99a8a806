"""Ctrl-C that Python could not raise: remember it (issue 22, interrupts).

A SIGINT arriving while the interpreter runs a finaliser (``__del__``, e.g.
numba's ``ObjectRef.__del__`` while it loads its cache) or a ctypes callback
raises ``KeyboardInterrupt`` *there*, where Python can only print
``Exception ignored in ...`` and go on; one raised inside Python code that
compiled code called (a hash or attribute look-up made from C) can be
cleared by that C code without a trace.  Either way the run would continue
and write its outputs as if no Ctrl-C had come.  So the command line
(:func:`install`):

* puts a ``sys.unraisablehook`` in front of the default one that swallows
  such a ``KeyboardInterrupt`` silently and records it;
* replaces Python's default SIGINT handler by one that records the signal
  before raising ``KeyboardInterrupt`` as the default does, so that an
  interrupt cleared on its way up is still known;
* in a process of its own (``python -m identification``, ``puma-identify``),
  starts a watchdog: a command that has not ended :data:`GRACE_S` seconds
  after a Ctrl-C (stuck where no check is made) leaves with the one line
  ``error: interrupted (...)`` and exit status 130.  Outputs are written
  atomically (:mod:`plant.logs.fileio`), so what is on disk is complete or
  absent.

The command asks :func:`seen` at its checkpoints (before the search, in
every progress callback, before writing) and ends with its one ``error:
interrupted`` line and exit status 130.  Every other unraisable exception
goes to the previous hook unchanged -- until the command is leaving on a
Ctrl-C (:func:`leaving`): from then on a finaliser's failure (llvmlite's
``ObjectRef.__del__`` on an object the interrupt left half made) is an echo
of the interrupt and is not printed.
"""
from __future__ import annotations

import os
import signal
import sys
import threading
import time

__all__ = ["install", "uninstall", "seen", "note", "clear", "leaving", "GRACE_S",
           "EXIT_INTERRUPTED"]

#: Seconds a command in a process of its own has, after a Ctrl-C, to stop by
#: itself (finish the current GA generation or refinement start and write the
#: best result so far) before the watchdog ends the process with exit status 130.
GRACE_S = 60.0

#: Exit status of a run stopped by Ctrl-C (128 + SIGINT).
EXIT_INTERRUPTED = 130

_STATE = {"seen": False, "seen_at": None, "previous": None, "previous_handler": None,
          "leaving": False, "watchdog": None}


def _hook(args):
    if isinstance(args.exc_value, KeyboardInterrupt) or args.exc_type is KeyboardInterrupt:
        note()
        return
    if _STATE["leaving"]:
        return  # an echo of the Ctrl-C the command is ending on
    previous = _STATE["previous"] or sys.__unraisablehook__
    previous(args)


def _on_sigint(signum, frame):
    """Python's default SIGINT handler, recording the signal first."""
    note()
    raise KeyboardInterrupt


def _watch():
    # polls a float set by the signal handler: no lock is shared with the code the
    # Ctrl-C interrupted (a handler that took one could deadlock on it)
    while True:
        time.sleep(0.25)
        t = _STATE["seen_at"]
        if t is not None and time.monotonic() - t > GRACE_S:
            _STATE["leaving"] = True
            try:
                os.write(2, (f"error: interrupted (the run did not stop within {GRACE_S:g} s "
                             "of the Ctrl-C; nothing more written)\n").encode())
            except OSError:
                pass
            os._exit(EXIT_INTERRUPTED)


def install(*, watchdog: bool = False) -> bool:
    """Put the hook and the SIGINT handler in place (idempotent).

    Parameters
    ----------
    watchdog : bool
        Also start the watchdog thread (only for a process of its own: it
        ends the process).

    Returns
    -------
    bool
        True when this call installed them (then :func:`uninstall` undoes it).
    """
    installed = False
    if sys.unraisablehook is not _hook:
        _STATE["previous"] = sys.unraisablehook
        sys.unraisablehook = _hook
        installed = True
    if (threading.current_thread() is threading.main_thread()
            and signal.getsignal(signal.SIGINT) is signal.default_int_handler):
        _STATE["previous_handler"] = signal.signal(signal.SIGINT, _on_sigint)
        installed = True
    if watchdog and _STATE["watchdog"] is None:
        _STATE["watchdog"] = threading.Thread(target=_watch, name="ctrl-c-watchdog", daemon=True)
        _STATE["watchdog"].start()
    return installed


def uninstall() -> None:
    """Restore the previous hook and SIGINT handler and forget a Ctrl-C (a call in-process)."""
    if sys.unraisablehook is _hook:
        sys.unraisablehook = _STATE["previous"] or sys.__unraisablehook__
    if (_STATE["previous_handler"] is not None
            and threading.current_thread() is threading.main_thread()
            and signal.getsignal(signal.SIGINT) is _on_sigint):
        signal.signal(signal.SIGINT, _STATE["previous_handler"])
    _STATE["previous_handler"] = None
    _STATE["leaving"] = False
    clear()


def note() -> None:
    """Record a Ctrl-C (the handlers call it; the watchdog's grace starts with the first)."""
    _STATE["seen"] = True
    if _STATE["seen_at"] is None:
        _STATE["seen_at"] = time.monotonic()


def seen() -> bool:
    """Whether a Ctrl-C came since :func:`clear` (raised, swallowed or cleared on its way)."""
    return bool(_STATE["seen"])


def clear() -> None:
    """Forget a Ctrl-C (a new run in the same process)."""
    _STATE["seen"] = False
    _STATE["seen_at"] = None


def leaving() -> None:
    """The command is ending on a Ctrl-C: finalisers' errors from now on are not printed."""
    _STATE["leaving"] = True
