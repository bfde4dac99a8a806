"""Threads over candidate chunks, Ctrl-C inside kernels, and kernel warm-up.

The batch drivers split their candidates into one chunk per thread; each
chunk runs in a compiled kernel that releases the GIL (``nogil``), so Python
threads run the chunks in parallel: the first chunk in the calling thread,
the others in worker threads that are kept between calls (idle between
them; a forked child starts with none).  The number of threads is an
argument of each call: nothing global is set (numba's own thread count is
left alone), so nothing needs restoring afterwards.
"""
from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np

__all__ = ["default_workers", "chunk_ranges", "run_chunks", "call_kernel"]


def default_workers() -> int:
    """Threads used when ``workers`` is not given: the CPUs this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not on Linux
        return max(1, os.cpu_count() or 1)


def check_workers(workers) -> int:
    """``workers`` as an int >= 1 (None: :func:`default_workers`).

    Raises
    ------
    ValueError
        If ``workers`` is not a whole number >= 1.
    """
    if workers is None:
        return default_workers()
    try:
        w = int(workers)
    except (TypeError, ValueError):
        raise ValueError(f"workers must be a whole number >= 1, got {workers!r}") from None
    if w < 1 or w != workers:
        raise ValueError(f"workers must be a whole number >= 1, got {workers!r}")
    return w


#: Fewest candidates per chunk (thread).  A chunk pays a fixed cost per
#: sample (the set-up of every loop over its lanes) that its lanes share, so
#: splitting a batch over threads pays only from about this many lanes per
#: chunk on (``benchmarks/bench_simulate.py`` prints the cost per candidate
#: against lanes and threads).
MIN_LANES_PER_CHUNK = 16


def chunk_ranges(m: int, workers: int, block=None) -> list:
    """Split ``m`` candidates into at most ``workers`` contiguous chunks ``(lo, hi)``.

    At least :data:`plant.simulation.parallel.MIN_LANES_PER_CHUNK` candidates go to a
    chunk (one chunk for a smaller batch) -- or, with ``block``, a batch of more
    than one block of lanes is split: for kernels whose lanes cost per lane
    (a robot model's generated arm), a chunk's fixed cost is small beside its
    lanes'.  ``benchmarks/bench_arm_threads.py`` (two threads, this rule
    against the one-chunk rule before it): 12, 16 and 24 candidates of the
    PUMA 560 joints 1-3 of ``examples/any_arm.py`` (48 RK4 steps a sample,
    2000 samples) 454, 453 and 913 ms against 852, 852 and 1282 ms; the
    PUMA 560 links 2-3 instance at one step a sample 1.9-2.6 against
    2.3-3.2 ms; the same pulses.

    Parameters
    ----------
    m : int
        Number of candidates.
    workers : int
        Threads.
    block : int, optional
        Lanes of one SIMD block (:data:`plant.simulation.core.LANE_PAD`):
        at most ``ceil(m / block)`` chunks.

    Returns
    -------
    list of (int, int)
        Non-empty half-open ranges covering ``0..m-1`` in order.
    """
    most = m // MIN_LANES_PER_CHUNK if block is None else -(-m // int(block))
    n = max(1, min(most, workers))
    size = -(-m // n)
    return [(lo, min(m, lo + size)) for lo in range(0, m, size)]


def call_kernel(fn, *args):
    """Call a compiled kernel; a Ctrl-C inside it surfaces as KeyboardInterrupt.

    numba may report a signal that arrives while compiled code runs as
    ``SystemError: ... returned a result with an exception set`` chained to
    the KeyboardInterrupt; callers (the GA, the CLI) expect the interrupt.

    Parameters
    ----------
    fn : callable
        The kernel.
    *args
        Its arguments.

    Returns
    -------
    object
        What the kernel returns.
    """
    try:
        return fn(*args)
    except SystemError as exc:
        cause = exc
        while cause is not None:
            if isinstance(cause, KeyboardInterrupt):
                raise KeyboardInterrupt() from None
            cause = cause.__cause__ or cause.__context__
        raise


def run_chunks(chunk_fn, m: int, workers, block=None) -> None:
    """Run ``chunk_fn(lo, hi)`` over the chunks of ``m`` candidates in threads.

    Parameters
    ----------
    chunk_fn : callable
        Called once per chunk with its range; runs a ``nogil`` kernel.
    m : int
        Number of candidates.
    workers : int or None
        Threads (None: :func:`default_workers`).
    block : int, optional
        As :func:`chunk_ranges`.
    """
    chunks = chunk_ranges(m, check_workers(workers), block)
    if len(chunks) == 1:
        call_kernel(chunk_fn, *chunks[0])
        return
    # the first chunk runs in this thread, the others in the pool's threads
    pool = _pool(len(chunks) - 1)
    futures = [pool.submit(call_kernel, chunk_fn, lo, hi) for lo, hi in chunks[1:]]
    try:
        call_kernel(chunk_fn, *chunks[0])
    finally:
        for fut in futures:
            fut.result()


# Worker threads kept between calls (a GA calls the batch drivers once per
# generation; starting threads each time cost about 1 % of the paper's GA).
# They hold no state of a call, and a forked child starts with none.
_POOLS: dict = {}
_POOLS_LOCK = threading.Lock()


def _pool(n: int) -> ThreadPoolExecutor:
    with _POOLS_LOCK:
        pool = _POOLS.get(n)
        if pool is None:
            pool = _POOLS[n] = ThreadPoolExecutor(max_workers=n, thread_name_prefix="plant-chunk")
        return pool


def _forget_pools() -> None:
    global _POOLS_LOCK
    _POOLS.clear()
    _POOLS_LOCK = threading.Lock()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_forget_pools)


def as_float_array(a, name: str, shape=None) -> np.ndarray:
    """``a`` as a C-contiguous float64 array, checked finite (and of ``shape``).

    Raises
    ------
    ValueError
        On a wrong shape or NaN/inf.
    """
    a = np.ascontiguousarray(a, dtype=np.float64)
    if shape is not None and a.shape != shape:
        raise ValueError(f"{name} must have shape {shape}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} contains NaN or inf")
    return a
