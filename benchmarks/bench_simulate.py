"""Benchmark of the one closed-loop core and of a full identification.

Prints (asserts nothing):

1. Compile time: the first compile of the kernels in a fresh process with an
   empty numba cache, and the load from the cache in a second fresh process
   (both in subprocesses, so this process's state does not matter); then the
   README's main job (``python -m identification --example``) timed whole,
   Python start-up included: first run with an empty numba cache, second
   run from the cache (three pairs, medians).
2. Exactness against the log's own integration: fraction of samples identical
   and within +-1 pulse for the true f, against the RK4 substeps.
3. One simulation of the paper log (5215 samples, one lane): ms per run at the
   identification's substeps and the exact default.
4. Cost per candidate against the number of SIMD lanes (1 to 160), 1 thread.
5. Candidates per second of one GA generation (76 candidates) on 1 and 2
   threads; scaling with log length and population.
6. The refinement's replay: one batch of 40 candidates (4 starts x (1 + 9)
   Jacobian columns), the cost per candidate.
7. Side by side in one run: the paper's GA budget (4 x 20 individuals, 40
   generations, ``identify(method='paper')``) and the default GA + batched
   Levenberg-Marquardt refinement, wall time excluding compilation, and
   their ratio (target <= 1.5).

Usage::

    python benchmarks/bench_simulate.py [--plot scaling.png] [--quick]

The true parameters are read from the development data (benchmarks may):
``PUMA_DATA_DIR`` or ``tests/data``.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
DATA = Path(os.environ.get("PUMA_DATA_DIR", ROOT / "tests" / "data"))
WELL_EXCITED = [0, 1, 3, 5, 6, 8]  # f1 f2 f4 f6 f7 f9


def best_of(fn, repeat=5):
    """Best wall time (s) of ``repeat`` calls."""
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


_COMPILE_SNIPPET = """
import sys, time
t0 = time.perf_counter()
sys.path.insert(0, {root!r})
import plant
t1 = time.perf_counter()
cached = plant.kernels_cached()
t2 = time.perf_counter()
plant.warm_up(closed_loop=False)
t3 = time.perf_counter()
plant.warm_up()
t4 = time.perf_counter()
print(f"{{t1 - t0:.2f}} {{cached}} {{t3 - t2:.2f}} {{t4 - t3:.2f}}")
"""


def compile_times():
    """(import s, was cached, logged-run kernel s, closed-loop step s) for cold and warm runs."""
    out = []
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        for _ in range(2):
            r = subprocess.run([sys.executable, "-c", _COMPILE_SNIPPET.format(root=str(ROOT))],
                               env=env, capture_output=True, text=True, check=True)
            imp, cached, run_s, cl_s = r.stdout.split()
            out.append((float(imp), cached == "True", float(run_s), float(cl_s)))
    return out


def main_job_times(pairs=3):
    """Wall times (s) of the README main job: lists of first (empty cache) and second runs."""
    first, second = [], []
    for _ in range(pairs):
        with tempfile.TemporaryDirectory() as tmp:
            env = dict(os.environ, NUMBA_CACHE_DIR=str(Path(tmp) / "cache"))
            for runs in (first, second):
                t = time.perf_counter()
                subprocess.run([sys.executable, "-m", "identification", "--example"],
                               cwd=ROOT, env=env, capture_output=True, check=True)
                runs.append(time.perf_counter() - t)
    return first, second


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plot", help="write the scaling figure to this PNG")
    ap.add_argument("--quick", action="store_true", help="fewer repetitions and cases")
    args = ap.parse_args(argv)
    rep = 2 if args.quick else 5

    print("== compile time (fresh processes, empty numba cache, then the cache) ==")
    for label, (imp, cached, run_s, cl_s) in zip(("first run", "second run"), compile_times()):
        print(f"{label:>10}: import plant {imp:.2f} s, kernels cached: {cached}, "
              f"logged-run kernel (P experiment + replay) {run_s:.2f} s, "
              f"any-controller step {cl_s:.2f} s")
    first, second = main_job_times(1 if args.quick else 3)
    print(f"README main job (python -m identification --example, wall incl. start-up): "
          f"first run (empty cache) median {np.median(first):.1f} s "
          f"[{', '.join(f'{v:.1f}' for v in first)}], "
          f"second run median {np.median(second):.1f} s "
          f"[{', '.join(f'{v:.1f}' for v in second)}]")

    import plant
    from plant import DEFAULT_SUBSTEPS, simulate_batch

    plant.warm_up()
    log = plant.load_log(DATA / "puma560_paper_rigid.csv")
    val = plant.load_log(DATA / "puma560_validation_rigid.csv")
    truth = {s: np.array(json.loads((DATA / f"{s}.truth.json").read_text())["f_vector"])
             for s in ("puma560_paper_rigid", "puma560_validation_rigid")}
    f = truth["puma560_paper_rigid"]
    n = log.n_samples

    print("\n== exactness against the logs (true f) ==")
    print(f"{'substeps':>8} {'log':>26} {'identical':>10} {'within 1':>9} {'Y (pulses^2)':>13}")
    for S in ((1, 8, 48) if args.quick else (1, 2, 4, 8, 16, 24, 32, 48, 64)):
        for lg in (log, val):
            e = plant.simulate_experiment(lg, truth[lg.name], substeps=S)
            d = e - lg.e_pulses
            print(f"{S:>8} {lg.name:>26} {np.mean(np.all(d == 0, 1)):>10.4f} "
                  f"{np.mean(np.all(np.abs(d) <= 1, 1)):>9.4f} {int(np.sum(d * d)):>13}")

    print("\n== one simulation of the paper log (5215 samples, one lane, 1 thread) ==")
    for S in (1, 2, DEFAULT_SUBSTEPS):
        t = best_of(lambda: simulate_batch(log, f[None], substeps=S, errors=False, workers=1),
                    rep)
        print(f"substeps {S:>2}: {t * 1e3:8.3f} ms ({t / n * 1e9:6.0f} ns/sample, "
              f"{t / n / (4 * S) * 1e9:5.1f} ns per right-hand-side evaluation)")

    print("\n== SIMD lanes: cost per candidate against lanes, 1 thread, substeps 1 ==")
    rng = np.random.default_rng(0)
    lane_counts = (1, 8, 40, 160) if args.quick else (1, 4, 8, 16, 40, 80, 160)
    for m in lane_counts:
        Fm = f * (1 + 0.05 * rng.standard_normal((m, 9)))
        t = best_of(lambda: simulate_batch(log, Fm, substeps=1, errors=False, workers=1),
                    rep) / m
        print(f"{m:4d} lanes: {t * 1e3:7.3f} ms per candidate, {t / n * 1e9:5.0f} ns per "
              f"candidate-sample, {t / n / 4 * 1e9:5.1f} ns per right-hand-side evaluation")

    print("\n== one GA generation (76 candidates, paper log) ==")
    F = f * (1 + 0.05 * rng.standard_normal((76, 9)))
    for S in (1, 2):
        for w in (1, 2):
            t = best_of(lambda: simulate_batch(log, F, substeps=S, errors=False, workers=w),
                        rep)
            print(f"substeps {S}, {w} thread(s): {76 / t:8.0f} candidates/s "
                  f"({t / 76 * 1e3:.3f} ms each)")

    print("\n== scaling (substeps 2) ==")
    lengths, costs_len = [], []
    for frac in (0.125, 0.25, 0.5, 1.0):
        lg = val.window(0.0, val.t[-1] * frac + 1e-9) if frac < 1 else val
        t = best_of(lambda: simulate_batch(lg, F[:40], substeps=2, errors=False, workers=1),
                    rep)
        lengths.append(lg.n_samples)
        costs_len.append(t / 40)
        print(f"log length {lg.n_samples:5d} samples: {t / 40 * 1e3:7.3f} ms per candidate, "
              f"{t / 40 / lg.n_samples * 1e9:5.0f} ns/sample")
    pops, costs_pop = [], []
    for m in (4, 16, 64, 256):
        Fm = f * (1 + 0.05 * rng.standard_normal((m, 9)))
        for w in (1, 2):
            t = best_of(lambda: simulate_batch(log, Fm, substeps=2, errors=False, workers=w),
                        max(1, rep // 2))
            pops.append((m, w))
            costs_pop.append(t)
            print(f"population {m:4d}, {w} thread(s): {t * 1e3:8.1f} ms "
                  f"({m / t:7.0f} candidates/s)")

    print("\n== refinement replay: one batch of 40 candidates (4 starts x 10), substeps 1 ==")
    F40 = f * (1 + 1e-3 * rng.standard_normal((40, 9)))
    for w in (1, 2):
        t = best_of(lambda: plant.prediction_errors(log, F40, substeps=1, workers=w), rep)
        print(f"{w} thread(s): {t * 1e3:7.1f} ms per batch ({t / 40 * 1e3:.3f} ms per candidate)")

    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(1, 2, figsize=(9, 3.6), layout="constrained")
        ax[0].plot(lengths, np.array(costs_len) * 1e3, "o-")
        ax[0].set_xlabel("log length (samples)")
        ax[0].set_ylabel("ms per candidate (1 thread, 40 lanes)")
        for w in (1, 2):
            ms = [m for (m, ww) in pops if ww == w]
            cs = [c for (m, ww), c in zip(pops, costs_pop) if ww == w]
            ax[1].loglog(ms, cs, "o-", label=f"{w} thread(s)")
        ax[1].set_xlabel("population size")
        ax[1].set_ylabel("s per batch")
        ax[1].legend()
        fig.savefig(args.plot, dpi=120)
        print(f"wrote {args.plot}")

    print("\n== identification on the paper log, side by side (wall time excludes compilation) ==")
    import identification

    repeats = 2 if args.quick else 5
    walls = {}
    for method in ("paper", "ga+pem"):
        runs = [identification.identify(log, method=method, rng=0, progress=False)
                for _ in range(repeats)]
        w = sorted(r.wall_time_s for r in runs)
        walls[method] = w
        r = runs[0]
        err = np.abs(r.f - f) / np.abs(f) * 100
        print(f"{method:>7}: wall best {w[0]:6.3f} s, median {w[len(w) // 2]:.3f} s, "
              f"{r.nfev} simulations, output error {r.fun:.0f} pulses^2 "
              f"(1 RK4 step/sample), max error of f1 f2 f4 f6 f7 f9 "
              f"{err[WELL_EXCITED].max():.3f} %")
    ratio = walls["ga+pem"][len(walls["ga+pem"]) // 2] / walls["paper"][len(walls["paper"]) // 2]
    print(f"default method / paper GA (medians): {ratio:.2f} (target <= 1.5)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
