"""Benchmark of the closed-loop simulator and of a full identification (issues 3 and 6).

Prints (asserts nothing):

1. JIT compile time (first call in a fresh process; a second process loads
   numba's cache).
2. Exactness against the log's own integration: fraction of samples identical
   and within +-1 pulse for the true f, against the RK4 substeps (tests only
   check the default; this shows the convergence).
3. One simulation of the paper log (5215 samples): ms per run, reference and
   lockstep kernels, for the identification's substeps and the exact default;
   then the cost per candidate of lockstep batches of 1 to 160 candidates.
4. Candidates per second of the batch form on 1 and 2 threads.
5. Scaling: cost against log length (windows of the validation log),
   population size and threads; the per-sample cost in ns and the arithmetic
   the model needs per sample.
6. The paper's full GA budget (4 x 20 individuals, 40 generations) through
   ``identify(method='paper')`` and the default GA + refinement: wall time
   excluding compilation.

Usage::

    NUMBA_NUM_THREADS=2 python benchmarks/bench_simulate.py [--plot scaling.png] [--quick]

The true parameters are read from the development data (benchmarks may).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
DATA = Path(os.environ.get("PUMA_DATA_DIR", ROOT.parent / "shared" / "data"))


def best_of(fn, repeat=5):
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t)
    return best


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--plot", help="write the scaling figure to this PNG")
    ap.add_argument("--quick", action="store_true", help="fewer repetitions, no identification")
    args = ap.parse_args(argv)
    rep = 2 if args.quick else 5

    t0 = time.perf_counter()
    import plant
    from plant.simulate import DEFAULT_SUBSTEPS, simulate_batch, warm_up

    import_s = time.perf_counter() - t0
    compile_s = warm_up()
    print(f"import {import_s:.2f} s, kernel compile/cache load {compile_s:.2f} s")

    log = plant.load_log(DATA / "puma560_paper_rigid.csv")
    val = plant.load_log(DATA / "puma560_validation_rigid.csv")
    truth = {s: np.array(json.loads((DATA / f"{s}.truth.json").read_text())["f_vector"])
             for s in ("puma560_paper_rigid", "puma560_validation_rigid")}
    f = truth["puma560_paper_rigid"]

    print("\n== exactness against the logs (true f) ==")
    print(f"{'substeps':>8} {'log':>26} {'identical':>10} {'within 1':>9} {'Y (pulses^2)':>13}")
    for S in (1, 2, 4, 8, 16, 24, 32, 48, 64):
        for lg in (log, val):
            e = plant.simulate_experiment(lg, truth[lg.name], substeps=S)
            d = e - lg.e_pulses
            print(f"{S:>8} {lg.name:>26} {np.mean(np.all(d == 0, 1)):>10.4f} "
                  f"{np.mean(np.all(np.abs(d) <= 1, 1)):>9.4f} {int(np.sum(d * d)):>13}")

    print("\n== one simulation of the paper log (5215 samples), 1 thread ==")
    print("(a single candidate runs the plain loop on both paths: lockstep needs >= 8 lanes)")
    n = log.n_samples
    for S in (1, 2, DEFAULT_SUBSTEPS):
        for fast in (False, True):
            fn = lambda: simulate_batch(log, f[None], substeps=S, errors=False,  # noqa: E731
                                        workers=1, fast=fast)
            fn()
            t = best_of(fn, rep)
            print(f"substeps {S:>2} {'fast' if fast else 'reference':>9}: {t * 1e3:8.3f} ms "
                  f"({t / n * 1e9:6.0f} ns/sample, {t / n / (4 * S) * 1e9:5.1f} ns per "
                  f"derivative evaluation)")

    print("\n== lockstep batches: cost per candidate against lanes, 1 thread, substeps 1 ==")
    rng = np.random.default_rng(0)
    for m in (1, 8, 16, 40, 80, 160):
        Fm = f * (1 + 0.05 * rng.standard_normal((m, 9)))
        for fast in (False, True):
            fn = lambda: simulate_batch(log, Fm, substeps=1, errors=False,  # noqa: E731
                                        workers=1, fast=fast)
            fn()
            t = best_of(fn, rep) / m
            print(f"{m:4d} candidates {'lockstep' if fast else 'reference':>9}: {t * 1e3:7.3f} ms "
                  f"per candidate, {t / n * 1e9:5.0f} ns per candidate-sample, "
                  f"{t / n / 4 * 1e9:5.1f} ns per derivative evaluation")

    print("\n== batch form: candidates per second (paper log, 76 candidates = one GA generation) ==")
    F = f * (1 + 0.05 * rng.standard_normal((76, 9)))
    for S in (1, 2):
        for w in (1, 2):
            simulate_batch(log, F[:2], substeps=S, errors=False, workers=w)
            t = best_of(lambda: simulate_batch(log, F, substeps=S, errors=False, workers=w),
                        rep)
            print(f"substeps {S}, {w} thread(s): {76 / t:8.0f} candidates/s "
                  f"({t / 76 * 1e3:.3f} ms each)")

    print("\n== scaling ==")
    lengths, costs_len = [], []
    for frac in (0.125, 0.25, 0.5, 1.0):
        lg = val.window(0.0, val.t[-1] * frac + 1e-9) if frac < 1 else val
        t = best_of(lambda: simulate_batch(lg, F[:20], substeps=2, errors=False, workers=1),
                    rep)
        lengths.append(lg.n_samples)
        costs_len.append(t / 20)
        print(f"log length {lg.n_samples:5d} samples: {t / 20 * 1e3:7.3f} ms per candidate, "
              f"{t / 20 / lg.n_samples * 1e9:5.0f} ns/sample")
    pops, costs_pop = [], []
    for m in (4, 16, 64, 256):
        Fm = f * (1 + 0.05 * rng.standard_normal((m, 9)))
        for w in (1, 2):
            simulate_batch(log, Fm[:2], substeps=2, errors=False, workers=w)
            t = best_of(lambda: simulate_batch(log, Fm, substeps=2, errors=False, workers=w),
                        max(1, rep // 2))
            pops.append((m, w))
            costs_pop.append(t)
            print(f"population {m:4d}, {w} thread(s): {t * 1e3:8.1f} ms "
                  f"({m / t:7.0f} candidates/s)")
    # Arithmetic per derivative evaluation: ~60 flops of the model (D, h, g,
    # 2x2 solve with one division, friction with one division per joint) and
    # ~30 for the two angle additions; RK4 adds ~20 per stage.  At substeps 2
    # a sample needs 8 evaluations, ~900 flops: 0.09 us at 4 doubles per
    # instruction and 2.5 GHz, if every instruction were an arithmetic one.
    print("model arithmetic: ~8 x 110 = 900 flops per sample at substeps 2 "
          "(~0.09 us at 4-wide SIMD, 2.5 GHz)")

    if args.plot:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(1, 2, figsize=(9, 3.6), layout="constrained")
        ax[0].plot(lengths, np.array(costs_len) * 1e3, "o-")
        ax[0].set_xlabel("log length (samples)")
        ax[0].set_ylabel("ms per candidate (1 thread)")
        for w in (1, 2):
            ms = [m for (m, ww) in pops if ww == w]
            cs = [c for (m, ww), c in zip(pops, costs_pop) if ww == w]
            ax[1].loglog(ms, cs, "o-", label=f"{w} thread(s)")
        ax[1].set_xlabel("population size")
        ax[1].set_ylabel("s per batch")
        ax[1].legend()
        fig.savefig(args.plot, dpi=120)
        print(f"wrote {args.plot}")

    if args.quick:
        return 0
    print("\n== identification on the paper log (wall time excludes compilation) ==")
    import identification

    print("(best and median of 3 runs: this machine's speed varies from minute to minute)")
    for method in ("paper", "ga+pem"):
        for w in (1, 2):
            runs = [identification.identify(log, method=method, rng=0, progress=False,
                                            workers=w) for _ in range(3)]
            walls = sorted(r.wall_time_s for r in runs)
            r = runs[0]
            err = np.abs(r.f - f) / np.abs(f) * 100
            print(f"{method:>7}, {w} thread(s): wall {walls[0]:6.2f} s (median {walls[1]:.2f}), "
                  f"{r.evaluations} simulations, objective {r.objective:.0f} pulses^2, "
                  f"max error of f1 f2 f4 f6 f7 f9 {err[[0, 1, 3, 5, 6, 8]].max():.3f} %, "
                  f"compile {r.compile_time_s:.2f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
