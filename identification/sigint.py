"""Ctrl-C that Python could not raise: remember it (issue 22, interrupts).

A SIGINT arriving while the interpreter runs a finaliser (``__del__``, e.g.
numba's ``ObjectRef.__del__`` while it loads its cache) or a ctypes callback
raises ``KeyboardInterrupt`` *there*, where Python can only print
``Exception ignored in ...`` and go on: the run would continue and write
its outputs as if no Ctrl-C had come.  :func:`install` puts a
``sys.unraisablehook`` in front of the default one that swallows such a
``KeyboardInterrupt`` silently and records it; the command line asks
:func:`seen` at its checkpoints (before the search, in every progress
callback, before writing) and ends with its one ``error: interrupted``
line and exit status 130.  Every other unraisable exception goes to the
previous hook unchanged -- until the command is leaving on a Ctrl-C
(:func:`leaving`): from then on a finaliser's failure (llvmlite's
``ObjectRef.__del__`` on an object the interrupt left half made) is an
echo of the interrupt and is not printed.
"""
from __future__ import annotations

import sys

__all__ = ["install", "seen", "clear", "leaving"]

_STATE = {"seen": False, "previous": None, "leaving": False}


def _hook(args):
    if isinstance(args.exc_value, KeyboardInterrupt) or args.exc_type is KeyboardInterrupt:
        _STATE["seen"] = True
        return
    if _STATE["leaving"]:
        return  # an echo of the Ctrl-C the command is ending on
    previous = _STATE["previous"] or sys.__unraisablehook__
    previous(args)


def install() -> None:
    """Put the hook in place (idempotent)."""
    if sys.unraisablehook is not _hook:
        _STATE["previous"] = sys.unraisablehook
        sys.unraisablehook = _hook


def seen() -> bool:
    """Whether a Ctrl-C was swallowed by a finaliser or callback since :func:`clear`."""
    return bool(_STATE["seen"])


def clear() -> None:
    """Forget a swallowed Ctrl-C (a new run in the same process)."""
    _STATE["seen"] = False


def leaving() -> None:
    """The command is ending on a Ctrl-C: finalisers' errors from now on are not printed."""
    _STATE["leaving"] = True
