"""Many identifications at once: :func:`identify_many` over any executor.

A study (the alteration study's seeds, many logs, many robots) is a list of
independent :func:`identification.identify` calls.  :func:`identify_many`
submits them to any :class:`concurrent.futures.Executor` -- by default a
local process pool, or e.g. a ``dask.distributed`` cluster through
``Client.get_executor()`` -- and returns one :class:`JobResult` per job, in
job order, each with its seed; a job that fails carries its error and the
others still return.

Example
-------
Five seeds of the paper log on the local cores::

    from identification.distributed import identify_many, seed_jobs

    out = identify_many(seed_jobs("puma560_paper_rigid.csv", range(5), method="paper"))
    for r in out:
        print(r.seed, r.result.fun if r.ok else r.error)

The same on a Dask cluster (``pip install ".[distributed]"``)::

    from dask.distributed import Client, LocalCluster

    with LocalCluster(n_workers=4, threads_per_worker=1) as cluster, Client(cluster) as client:
        out = identify_many(jobs, executor=client.get_executor())

Parallelism and threads
-----------------------
The parallelism is across jobs: unless a job sets ``workers`` itself, each
job runs its simulations on **one** numba thread (``workers=1``), and the
default pool has one process per core (``os.cpu_count()``, capped at the
number of jobs).  Give a Dask cluster ``threads_per_worker=1`` for the same
reason.  The default pool starts its processes with the ``'spawn'`` method:
forking a process whose numba thread pool is already running can deadlock.
Each process pays the import of the library and the loading of the cached
numba kernels once (a few seconds); pass your own executor to reuse
processes across calls.

What travels between processes
------------------------------
Send logs as **paths** (strings or :class:`pathlib.Path`): each worker loads
its own copy, and the job pickles to a few hundred bytes.  An
:class:`plant.ExperimentLog` works too (it is picklable) but is pickled once
per job.  The result comes back as the :class:`IdentificationResult` itself,
**without its** ``log`` entry (the log is data the caller already has; this
keeps every result a small pickle): ``result.log_name`` names it, and
``result.plot_tracking_errors(log)`` takes it explicitly.  Use
:meth:`JobResult.to_dict` for a JSON-ready record.
"""
from __future__ import annotations

import inspect
import multiprocessing
import os
import time
import traceback
from concurrent.futures import Executor, ProcessPoolExecutor, as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable, Mapping, Optional, Sequence

from .api import identify
from .arm import identify_arm

__all__ = ["Job", "JobResult", "identify_many", "seed_jobs", "default_executor"]

#: Keyword arguments of :func:`identification.identify` a job may set
#: (``rng`` is set from the job's ``seed``).
_IDENTIFY_KWARGS = frozenset(inspect.signature(identify).parameters) - {"log", "rng"}
#: identify_arm's keywords (a robot model's log, :mod:`identification.arm`).
_IDENTIFY_ARM_KWARGS = frozenset(inspect.signature(identify_arm).parameters) - {"log", "rng"}


@dataclass
class Job:
    """One identification of a study.

    Parameters
    ----------
    log : str, os.PathLike or plant.ExperimentLog
        The log (prefer a path: cheap to send to another process).
    seed : int or None
        Seed of the identification's random source (``identify(rng=seed)``);
        None draws fresh entropy (not reproducible).
    options : dict
        Further keyword arguments of :func:`identification.identify`
        (``method``, ``bounds``, ``ga_options``, ...).  ``workers`` defaults
        to 1 and ``progress`` to False inside :func:`identify_many`.
    """

    log: Any
    seed: Optional[int] = None
    options: dict = field(default_factory=dict)

    @classmethod
    def from_mapping(cls, spec: Mapping) -> "Job":
        """Build a job from ``{'log': ..., 'seed': ..., **identify_kwargs}``.

        Parameters
        ----------
        spec : mapping
            ``log`` (path or ExperimentLog), optional ``seed`` (int), and
            keyword arguments of :func:`identification.identify`.

        Returns
        -------
        Job

        Raises
        ------
        ValueError
            If ``log`` is missing, ``rng`` is given (use ``seed``), or a key
            is not an argument of :func:`identification.identify`.
        """
        spec = dict(spec)
        if "log" not in spec:
            raise ValueError("a job needs a 'log' (path or ExperimentLog)")
        if "rng" in spec:
            raise ValueError("give a job's random seed as 'seed' (an int), not 'rng'")
        log = spec.pop("log")
        seed = spec.pop("seed", None)
        return cls(log=log, seed=seed, options=spec)

    def check(self) -> "Job":
        """Validate the job's structure (not the log file: that fails in the job)."""
        unknown = set(self.options) - (_IDENTIFY_KWARGS | _IDENTIFY_ARM_KWARGS)
        if unknown:
            raise ValueError(f"unknown identify() option(s) in job: {', '.join(sorted(unknown))}")
        if self.seed is not None:
            try:
                ok = int(self.seed) == self.seed
            except (TypeError, ValueError):
                ok = False
            if not ok or isinstance(self.seed, bool):
                raise ValueError(f"a job's seed must be an int or None, got {self.seed!r}")
            self.seed = int(self.seed)
        return self


@dataclass
class JobResult:
    """Outcome of one job of :func:`identify_many`.

    Attributes
    ----------
    index : int
        Position of the job in the ``jobs`` given.
    seed : int or None
        The job's seed.
    log : str
        The log's path (as given) or, for an in-memory log, its name.
    result : IdentificationResult or None
        The identification, without its ``log`` entry; None if the job failed.
    error : str or None
        ``"ExceptionType: one-line message"`` if the job failed, else None.
    error_type : str or None
        The exception's class name.
    traceback : str or None
        The formatted traceback (from the worker when the job itself raised).
    wall_time_s : float
        Wall time of the job in its worker (s), including the log loading and
        the worker's JIT warm-up; NaN when the job never ran.
    """

    index: int
    seed: Optional[int]
    log: str
    result: Any = None
    error: Optional[str] = None
    error_type: Optional[str] = None
    traceback: Optional[str] = None
    wall_time_s: float = float("nan")

    @property
    def ok(self) -> bool:
        """True when the job returned a result."""
        return self.error is None

    def to_dict(self) -> dict:
        """JSON-ready record: ``index``, ``seed``, ``log``, ``ok``, ``error``,
        ``error_type``, ``wall_time_s`` and ``result``
        (:meth:`IdentificationResult.to_dict`, or None; a robot model's
        result: its base parameters, names, standard errors and costs)."""
        import math

        return {
            "index": self.index,
            "seed": self.seed,
            "log": self.log,
            "ok": self.ok,
            "error": self.error,
            "error_type": self.error_type,
            "wall_time_s": self.wall_time_s if math.isfinite(self.wall_time_s) else None,
            "result": None if self.result is None else self.result.to_dict(),
        }


def _one_line(exc: BaseException) -> str:
    msg = " ".join(str(exc).split())
    if len(msg) > 300:
        msg = msg[:297] + "..."
    return f"{type(exc).__name__}: {msg}" if msg else type(exc).__name__


def _log_label(log) -> str:
    if isinstance(log, (str, os.PathLike)):
        return os.fspath(log)
    return str(getattr(log, "name", type(log).__name__))


def _as_job(j) -> Job:
    if isinstance(j, Job):
        return Job(log=j.log, seed=j.seed, options=dict(j.options)).check()
    if isinstance(j, Mapping):
        return Job.from_mapping(j).check()
    raise TypeError(f"a job must be a dict or an identification.distributed.Job, "
                    f"got {type(j).__name__}")


def _is_arm_log(log) -> bool:
    """A robot model's log (an ArmLog, or a path whose sidecar names a robot)."""
    from plant.logs.arm_log import ArmLog, is_arm_sidecar
    from plant.logs.sidecar import read_sidecar

    if isinstance(log, ArmLog):
        return True
    if isinstance(log, str):
        side = Path(log).with_suffix(".json")
        return side.is_file() and is_arm_sidecar(read_sidecar(side))
    return False


def _run_job(index: int, log, seed, options: dict) -> JobResult:
    """Worker side: one ``identify`` (or ``identify_arm``) call; never raises (errors are returned)."""
    t0 = time.perf_counter()
    label = _log_label(log)
    try:
        if isinstance(log, os.PathLike):
            log = os.fspath(log)
        if _is_arm_log(log):  # a robot model's log: identification.arm
            from plant.logs.arm_log import load_arm_log

            options = {k: v for k, v in options.items() if k != "progress"}  # identify_many's default
            extra = set(options) - _IDENTIFY_ARM_KWARGS
            if extra:
                raise ValueError(f"option(s) {', '.join(sorted(extra))} are for PUMA 560 links 2-3 "
                                 "logs, not a robot model's")
            arm_log = load_arm_log(log) if isinstance(log, str) else log
            result = identify_arm(arm_log, rng=seed, **options)
            # its generated plant is rebuilt from the log's robot (plant.simulation.arm.arm_plant), not sent
            result.pop("plant", None)
        else:
            result = identify(log, rng=seed, **options)
        result.pop("log", None)  # the caller has the log; keep the pickle small
        return JobResult(index, seed, label, result=result,
                         wall_time_s=time.perf_counter() - t0)
    except Exception as exc:  # reported, not raised: the other jobs go on
        return JobResult(index, seed, label, error=_one_line(exc),
                         error_type=type(exc).__name__, traceback=traceback.format_exc(),
                         wall_time_s=time.perf_counter() - t0)


def default_executor(n_jobs: int, max_workers: Optional[int] = None) -> ProcessPoolExecutor:
    """Create the default pool of :func:`identify_many`.

    Parameters
    ----------
    n_jobs : int
        Jobs to run (the pool has no more processes than jobs).
    max_workers : int, optional
        Processes (default ``os.cpu_count()``).

    Returns
    -------
    concurrent.futures.ProcessPoolExecutor
        ``min(max_workers, n_jobs)`` processes started with the ``'spawn'``
        method (fork is unsafe with numba's thread pool); the caller shuts
        it down.
    """
    n = int(max_workers) if max_workers is not None else (os.cpu_count() or 1)
    if n < 1:
        raise ValueError(f"max_workers must be >= 1, got {max_workers}")
    return ProcessPoolExecutor(max_workers=max(1, min(n, n_jobs)),
                               mp_context=multiprocessing.get_context("spawn"))


def identify_many(
    jobs: Iterable,
    executor: Optional[Executor] = None,
    *,
    progress: bool = False,
    max_workers: Optional[int] = None,
) -> list:
    """Run many identifications through a ``concurrent.futures`` executor.

    Parameters
    ----------
    jobs : iterable of dict or Job
        Each a :class:`Job` or a dict ``{'log': path_or_log, 'seed': int,
        **identify_kwargs}`` (any keyword argument of
        :func:`identification.identify` except ``rng``, which ``seed``
        replaces).  Unless a job says otherwise, it runs with ``workers=1``
        (one numba thread: the parallelism is across jobs) and
        ``progress=False``.  A ``callback`` must be picklable (a module-level
        function) to reach another process.
    executor : concurrent.futures.Executor, optional
        Anything with ``submit(fn, *args) -> Future``: a
        :class:`~concurrent.futures.ProcessPoolExecutor`, a Dask
        ``Client(...).get_executor()``, ...  It is used, not shut down.
        Default: a local process pool (:func:`default_executor`), created
        for this call and shut down at its end.
    progress : bool
        Show a tqdm bar counting finished jobs.
    max_workers : int, optional
        Processes of the default pool (default ``os.cpu_count()``); ignored
        when ``executor`` is given.

    Returns
    -------
    list of JobResult
        One per job, in job order, each with its ``index`` and ``seed``.  A
        job that raised (bad path, malformed log, bad options ...) or that
        the executor could not run (worker lost, unpicklable argument) has
        ``ok == False`` and its ``error`` (``"Type: message"``); the other
        jobs are unaffected.

    Raises
    ------
    TypeError, ValueError
        Before anything is submitted, if a job is not a dict/Job, has no
        ``log``, gives ``rng``, a non-integer seed, or an option that
        :func:`identification.identify` does not take.

    Notes
    -----
    The same job (log, seed, options) gives the same ``f`` wherever it runs:
    the identification is deterministic for a seed.  Results come back
    without their ``log`` entry (see the module docstring).
    """
    specs = [_as_job(j) for j in jobs]
    if not specs:
        return []
    own = executor is None
    if own:
        executor = default_executor(len(specs), max_workers)
    out: list = [None] * len(specs)
    try:
        futures = {}
        for i, job in enumerate(specs):
            opts = dict(workers=1, progress=False)
            opts.update(job.options)
            log = job.log
            if isinstance(log, Path):
                log = str(log)
            try:
                fut = executor.submit(_run_job, i, log, job.seed, opts)
            except Exception as exc:  # e.g. an unpicklable argument, a closed executor
                out[i] = JobResult(i, job.seed, _log_label(job.log), error=_one_line(exc),
                                   error_type=type(exc).__name__,
                                   traceback=traceback.format_exc())
                continue
            futures[fut] = i
        from tqdm.auto import tqdm

        with tqdm(total=len(specs), desc="identify_many", unit="job",
                  disable=not progress) as bar:
            bar.update(len(specs) - len(futures))
            for fut in as_completed(futures):
                i = futures[fut]
                job = specs[i]
                try:
                    r = fut.result()
                    if not isinstance(r, JobResult):
                        raise TypeError(f"executor returned {type(r).__name__}, not JobResult")
                except Exception as exc:  # the executor lost the job (worker died ...)
                    r = JobResult(i, job.seed, _log_label(job.log), error=_one_line(exc),
                                  error_type=type(exc).__name__,
                                  traceback=traceback.format_exc())
                out[i] = r
                bar.update(1)
    finally:
        if own:
            executor.shutdown(wait=True, cancel_futures=True)
    return out


def seed_jobs(log, seeds: Sequence[int], **options) -> list:
    """Build jobs identifying ``log`` once per seed with the same options.

    Parameters
    ----------
    log : str, os.PathLike or plant.ExperimentLog
        The log of every job (prefer a path).
    seeds : sequence of int
        One job per seed, in this order.
    **options
        Keyword arguments of :func:`identification.identify` (not ``rng``).

    Returns
    -------
    list of Job
    """
    if "rng" in options:
        raise ValueError("seed_jobs sets rng from the seeds; do not pass rng")
    return [Job(log=log, seed=s, options=dict(options)).check() for s in seeds]

