"""Compiling the simulation kernels before a timed run (numba's on-disk cache).

The kernels of the logged run (:mod:`plant.simulation.simulate`) and of the
any-controller loop (:mod:`plant.simulation.closed_loop`) are compiled on their first
call and cached on disk by numba; :func:`warm_up` makes that call on a
three-sample problem, so that a timed run afterwards excludes compilation.
"""
from __future__ import annotations

import time

from plant.simulation import closed_loop as loop_module
from plant.simulation import simulate
from plant.simulation.simulate import log_chunk, warm_arguments

__all__ = ["warm_up", "kernels_cached"]


def kernels_cached() -> bool:
    """Whether numba's on-disk cache already holds the simulation kernels.

    Returns
    -------
    bool
        True when the P-experiment kernel of the rigid plant loads from the
        cache without compiling (then :func:`warm_up` takes about a second).
    """
    from numba import typeof

    try:
        sig = tuple(typeof(a) for a in warm_arguments())
        return log_chunk._cache.load_overload(sig, log_chunk.targetctx) is not None
    except Exception:  # noqa: BLE001 - any trouble with the cache means "not cached"
        return False


def warm_up(*, announce=None, closed_loop=True) -> float:
    """Compile (or load from numba's cache) the simulation kernels.

    Runs each kernel once on a three-sample problem so that a timed run
    afterwards excludes JIT compilation.

    Parameters
    ----------
    announce : callable, optional
        ``announce(message)`` is called once, before compiling, when the
        kernels are not in numba's cache yet (a first run compiles them once,
        which takes several seconds); not called when they load from the
        cache.
    closed_loop : bool
        Also warm the sample step of the any-controller loop.

    Returns
    -------
    float
        Seconds it took.
    """
    t0 = time.perf_counter()
    if announce is not None and not kernels_cached():
        announce("compiling the numerical kernels once (about 5 s on 2 cores); "
                 "later runs load them from numba's cache")
    simulate.warm_kernels()  # the P experiment and the replay: one kernel
    if closed_loop:
        loop_module.warm_kernels()
    return time.perf_counter() - t0
