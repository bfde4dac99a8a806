"""Threads over an arm's candidates: one chunk against two (printed, not asserted).

A robot model's arm (:mod:`plant.simulation.arm`) splits a batch over the
threads as soon as it holds more than one SIMD block of lanes
(:func:`plant.simulation.parallel.chunk_ranges` with ``block``): its generated
right-hand side costs per lane, so a chunk's fixed cost is small beside its
lanes'.  This script times :func:`plant.simulation.arm.simulate_arm` on one
thread (one chunk) and on two (two chunks from 9 candidates on), and
:func:`identification.arm.identify_arm` on two committed logs of the tests
with ``workers=1`` and ``workers=2``; it checks that the results are the same.

Run from the repository root: ``python benchmarks/bench_arm_threads.py``.
"""
from __future__ import annotations

import json
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "examples"))

from any_arm import reference, rig_for, robot  # noqa: E402
from identification.arm import identify_arm  # noqa: E402
from plant.logs.arm_log import load_arm_log  # noqa: E402
from plant.simulation.arm import arm_plant, simulate_arm  # noqa: E402

DATA = ROOT / "tests" / "data"


def best_of(fn, repeat=3):
    best, out = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t0)
    return best, out


def main():
    warnings.simplefilter("ignore")
    log = load_arm_log(DATA / "puma560_paper_rigid.csv")
    f = np.array(json.loads((DATA / "puma560_paper_rigid.truth.json").read_text())["f_vector"])
    model = robot("puma123")
    cases = [("PUMA 560 links 2-3 instance, paper log, 1 RK4 step", arm_plant(log.model), f,
              log.rig, log.trajectory, log.n_samples, 1),
             ("PUMA 560 joints 1-3 (any_arm), 2000 samples, 48 steps", arm_plant(model),
              arm_plant(model).beta(), rig_for(model), reference(3), 2000, 48)]
    rng = np.random.default_rng(0)
    print(f"{'simulate_arm':<58} {'robots':>6} {'1 thread (ms)':>14} {'2 threads (ms)':>15}  same")
    for label, p, beta, rig, traj, n, sub in cases:
        for m in (8, 12, 16, 24):
            B = beta * (1 + 0.01 * rng.standard_normal((m, beta.size)))
            runs = {}
            for w in (1, 2):
                simulate_arm(p, B, rig, traj, n, substeps=sub, workers=w)  # compiled, warm
                runs[w] = best_of(lambda: simulate_arm(p, B, rig, traj, n, substeps=sub, workers=w))
            same = np.array_equal(runs[1][1].errors, runs[2][1].errors)
            print(f"{label:<58} {m:>6} {runs[1][0] * 1e3:>14.1f} {runs[2][0] * 1e3:>15.1f}  {same}")
    print(f"\n{'identify_arm (defaults)':<58} {'':>6} {'1 thread (s)':>14} {'2 threads (s)':>15}  same")
    for name in ("indep_arm_urdf_locked_tool", "indep_arm_planar2_compliant_backlash"):
        alog = load_arm_log(DATA / "independent_arm" / f"{name}.csv")
        identify_arm(alog, model="rigid")  # the robot's kernels compiled
        runs = {w: best_of(lambda: identify_arm(alog, workers=w), 2) for w in (1, 2)}
        same = np.array_equal(runs[1][1].x, runs[2][1].x)
        print(f"{name + ' (' + runs[2][1].model + ')':<58} {'':>6} {runs[1][0]:>14.2f} "
              f"{runs[2][0]:>15.2f}  {same}")


if __name__ == "__main__":
    main()
