"""A study over many six-joint logs on a Dask cluster (issue 23: "a Dask study over many logs").

What it measures
----------------
``--n`` six-joint PUMA 560 draws of ``benchmarks/independent_arm.py``
(``puma6``: robot, gears, encoders, torque constants, motor inertias,
friction known or ``null``, P gains, multisine reference; 5 s logs at 0.5 or
1 ms; seeds ``seed + i``, chosen before looking) are written as log files
(``STEM.csv`` + ``STEM.json`` with a ``robot`` section, and the truth in
``STEM.truth.json``), then identified by path with
:func:`identification.distributed.identify_many` -- the default
identification of a robot-model log (:func:`identification.arm.identify_arm`)
-- twice, side by side in one run:

* ``serial``: one job after another in one worker process (a
  ``ProcessPoolExecutor`` of one process, BLAS on one thread as in a Dask
  worker: the study as one core runs it);
* ``dask``: all jobs on a ``dask.distributed`` ``LocalCluster`` of
  ``--workers`` processes with one thread each, through
  ``Client.get_executor()`` (the same jobs, submitted by path).

Printed: per log the identification's own wall time on each side, whether
the two results are the same (``x`` to 1e-9 relative: a job is the same
computation wherever it runs), the well-excited base parameters (relative
standard error below 1/3 %) within 1 % of the truth, and the unknown
friction; then each side's wall time for the whole study (the Dask side
includes starting the cluster, the serial side its one process; each
process pays the import and the loading of the compiled kernels; the
robot's generated kernels are compiled by the first process that needs
them -- the serial side, which runs first, unless numba's cache has them
already -- and loaded from the cache by the others) and the speed-up.  The truth files are read here for the errors only.

Usage::

    pip install -e ".[bench]"
    python benchmarks/bench_arm_study.py --n 6 --seed 20261140 --workers 2

Needs the ``bench`` extra (Robotics Toolbox, for the independent simulator)
and ``dask[distributed]`` (the ``distributed`` or ``test`` extra).
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import independent_arm as ia  # noqa: E402
from bench_arms import well_excited_check  # noqa: E402


def write_logs(n: int, seed: int, directory: Path) -> list[Path]:
    """The study's logs: ``n`` puma6 draws, seeds ``seed .. seed + n - 1``."""
    paths = []
    for i in range(n):
        stem = f"puma6_{seed + i}"
        ia.write_log(ia.draw("puma6", seed + i), directory, stem)
        paths.append(directory / f"{stem}.csv")
    return paths


def accuracy(result, path: Path) -> dict:
    """Well-excited base parameters against the truth file, and the unknown friction's flag."""
    truth = json.loads(path.with_suffix(".truth.json").read_text())
    err, well, worst, ok = well_excited_check(result, truth["beta"])
    return dict(n_base=len(err), n_well=int(well.sum()), params_ok=ok,
                worst_pct=100.0 * float(err[worst]) if worst >= 0 else float("nan"),
                friction=("known" if truth["settings"].get("friction_known") else "identified"))


#: The BLAS thread variables a Dask worker sets to 1 (distributed's default
#: ``distributed.nanny.pre-spawn-environ``); the serial side's process gets them too,
#: so that both sides run the same arithmetic (a multi-threaded BLAS sums the
#: IDIM-LS start in another order, and a poorly excited base parameter carries
#: that to ~1e-3 relative).
BLAS_ENV = ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS")


def run_serial(paths):
    """The jobs one after another in one worker process (spawned inside the clock)."""
    import multiprocessing
    import os
    from concurrent.futures import ProcessPoolExecutor

    from identification.distributed import identify_many

    saved = {k: os.environ.get(k) for k in BLAS_ENV}
    os.environ.update({k: "1" for k in BLAS_ENV})  # inherited by the spawned process
    try:
        t0 = time.perf_counter()
        with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
            out = identify_many([dict(log=str(p)) for p in paths], executor=pool)
        return out, time.perf_counter() - t0
    finally:
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def run_dask(paths, workers: int):
    from dask.distributed import Client, LocalCluster

    from identification.distributed import identify_many

    t0 = time.perf_counter()
    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True,
                      dashboard_address=None) as cluster, Client(cluster) as client:
        out = identify_many([dict(log=str(p)) for p in paths], executor=client.get_executor())
    return out, time.perf_counter() - t0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=6, help="six-joint logs in the study")
    ap.add_argument("--seed", type=int, default=20261140, help="first seed (log i uses seed + i)")
    ap.add_argument("--workers", type=int, default=2, help="Dask worker processes")
    ap.add_argument("--dir", type=Path, default=None,
                    help="where the logs are written (default: a temporary directory)")
    a = ap.parse_args(argv)
    if a.n < 1 or a.workers < 1:
        ap.error("--n and --workers must be >= 1")
    try:
        import dask.distributed  # noqa: F401
    except ImportError:
        ap.error("needs dask.distributed: pip install -e \".[distributed]\"")
    with tempfile.TemporaryDirectory() as tmp:
        directory = a.dir or Path(tmp)
        t0 = time.perf_counter()
        paths = write_logs(a.n, a.seed, directory)
        print(f"{a.n} six-joint logs (puma6, seeds {a.seed}..{a.seed + a.n - 1}) written by the "
              f"independent simulator in {time.perf_counter() - t0:.1f} s")
        serial, t_serial = run_serial(paths)
        dask_out, t_dask = run_dask(paths, a.workers)
        print(f"\n{'log':<16} {'serial s':>9} {'dask s':>7}  {'same x':<6}  {'well-excited within 1 %':<24}"
              f" {'worst':>8}  friction")
        n_ok = n_same = 0
        for p, rs, rd in zip(paths, serial, dask_out):
            if not (rs.ok and rd.ok):
                print(f"{p.stem:<16} failed: {rs.error or rd.error}")
                continue
            acc = accuracy(rs.result, p)
            xs, xd = np.asarray(rs.result.x, dtype=float), np.asarray(rd.result.x, dtype=float)
            same = bool(np.allclose(xs, xd, rtol=1e-9, atol=0.0))
            diff = float(np.max(np.abs(xs - xd) / np.maximum(np.abs(xd), 1e-300)))
            n_ok += acc["params_ok"]
            n_same += same
            print(f"{p.stem:<16} {rs.result.elapsed_s:9.1f} {rd.result.elapsed_s:7.1f}  "
                  f"{'yes' if same else f'{diff:.0e}':<6}  "
                  f"{acc['n_well']:>2}/{acc['n_base']} {'ok' if acc['params_ok'] else 'MISS':<18} "
                  f"{acc['worst_pct']:7.3f} %  {acc['friction']}")
        print(f"\nstudy of {a.n} logs: serial (one process, one job after another) {t_serial:.1f} s; "
              f"Dask LocalCluster ({a.workers} workers x 1 thread, started inside the clock) "
              f"{t_dask:.1f} s; speed-up {t_serial / t_dask:.2f}")
        print(f"well-excited base parameters within 1 %: {n_ok} / {a.n}; the same x on both sides "
              f"(1e-9): {n_same} / {a.n}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
