"""Optimisers compared on the same cost and the same evaluation budget.

What it measures
----------------
On ``puma560_paper_rigid``, the output error of paper eq. 4
(:class:`identification.OutputError`, 2 RK4 substeps per sample -- the
identification's setting) is minimised over the sidecar's search box with
the paper's evaluation budget, 80 + 40 x 76 = 3120 simulations, by

``paper``
    the paper's GA alone, ``identify(method='paper')`` (4 x 20, 40 gen.);
``ga+pem``
    the library default, ``identify()``: Gray-coded GA, then Gauss-Newton
    refinement on prediction errors.  Its GA runs 36 generations
    (80 + 36 x 76 = 2816 simulations) so that GA + refinement (~300
    simulations of the replay, which cost the same) stays on the budget;
``de``
    :func:`scipy.optimize.differential_evolution`, ``vectorized=True``
    feeding the batch simulator, a Latin-hypercube initial population of 80
    and ``maxiter=38`` (39 x 80 = 3120), ``updating='deferred'``,
    ``polish=False``, ``tol=atol=0`` (never stops early), other settings
    scipy's defaults (``best1bin``);
``cmaes``
    CMA-ES (the ``cma`` package), ask/tell on the box scaled to [0, 1]^9
    (``bounds`` option), popsize 16, sigma0 0.3, a uniform random start,
    195 iterations (16 x 195 = 3120), the flat-fitness / tolerance
    stopping rules disabled,

and, as a control experiment (is it the GA or the refinement?),

``de+pem``, ``cmaes+pem``
    DE / CMA-ES on the GA stage's 2816 simulations, then exactly the
    default's refinement (4 starts: the best distinct points evaluated),
``pem``
    the refinement alone from 4 uniform random starts in the box (no global
    search; ~500 simulations),

each over the same seeds (default 0..4).  All four use the same batch
objective with the same number of numba threads (``--workers``, default all
cores).

Reported per method (median over seeds, and the range): evaluations, wall
time (JIT compilation excluded: the kernels are warmed up first), the best
objective on the identification log, the output error of the identified f
on ``puma560_validation_rigid`` at the same 2 substeps **relative to the
true f's** output error at 2 substeps (1.0 = as good as the truth), and the
parameter errors in % of the truth (mean |error| over the well-excited
f1 f2 f4 f6 f7 f9, and per parameter).  The truth files are read here, by
the benchmark only.

Why parameter errors first: the integer output error is chaotic at the pulse
level -- any f more than ~1e-7 (relative) from the truth sits on a floor of
~1000 pulses^2 on the paper log at 2 substeps (the true f itself gives
~1066 there) -- so a lower objective below the floor says little about the
parameters.

Usage (from the repository root)::

    PYTHONPATH=. python benchmarks/bench_optimisers.py --out out/bench_optimisers.json \
        --plot out/optimisers_convergence.png

Prints the table; writes the JSON (all per-seed figures and the convergence
curves) and a PNG of the convergence curves (best objective vs simulations,
median over seeds, min-max band).
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

import plant
from identification import OutputError, identify
from identification.result import write_json_atomic
from plant import warm_up

LOG = "puma560_paper_rigid"
VALIDATION = "puma560_validation_rigid"
SUBSTEPS = 2
#: The paper's budget: 4 x 20 initial individuals, then 40 generations of
#: 4 x 19 offspring (generation gap 0.94).
BUDGET = 80 + 40 * 76
#: Well-excited parameters (0-based indices of f1 f2 f4 f6 f7 f9).
WELL_EXCITED = (0, 1, 3, 5, 6, 8)
#: Simulations of the default method's GA stage (36 generations), leaving
#: ~300 of the budget to the refinement.
GA_PEM_BUDGET = 80 + 36 * 76
METHODS = ("paper", "ga+pem", "de", "cmaes", "de+pem", "cmaes+pem", "pem")
LABELS = {
    "paper": "paper GA",
    "ga+pem": "GA + refinement (default)",
    "de": "differential evolution (scipy)",
    "cmaes": "CMA-ES (cma)",
    "de+pem": "DE + refinement (control)",
    "cmaes+pem": "CMA-ES + refinement (control)",
    "pem": "refinement alone (control)",
}


def _data_dir() -> Path:
    env = os.environ.get("PUMA_DATA_DIR")
    return Path(env) if env else Path(__file__).resolve().parents[1] / "tests" / "data"


class Recorder:
    """Batch objective wrapper recording the best-so-far after every call.

    Parameters
    ----------
    objective : callable
        ``objective(F) -> y``, ``F`` of shape (m, 9).
    """

    def __init__(self, objective):
        self.objective = objective
        self.evaluations = 0
        self.best = np.inf
        self.best_x = None
        self.curve = []  # (evaluations, best so far)
        self._X, self._y = [], []

    def __call__(self, F):
        F = np.atleast_2d(np.asarray(F, dtype=float))
        y = np.asarray(self.objective(F), dtype=float)
        self.evaluations += F.shape[0]
        self._X.append(F.copy())
        self._y.append(y.copy())
        j = int(np.nanargmin(np.where(np.isfinite(y), y, np.inf)))
        if y[j] < self.best:
            self.best, self.best_x = float(y[j]), F[j].copy()
        self.curve.append((self.evaluations, self.best))
        return y

    def best_points(self, k):
        """The ``k`` best distinct points evaluated, best first, shape (<= k, 9)."""
        X, y = np.vstack(self._X), np.concatenate(self._y)
        out = []
        for i in np.argsort(np.where(np.isfinite(y), y, np.inf), kind="stable"):
            if len(out) >= k:
                break
            if not any(np.array_equal(X[i], x) for x in out):
                out.append(X[i])
        return np.array(out)


# --------------------------------------------------------------------- methods
def run_paper(log, bounds, seed, workers):
    """The paper's GA, ``identify(method='paper')``."""
    r = identify(log, method="paper", rng=seed, workers=workers, progress=False)
    h = r.history
    curve = list(zip(np.asarray(h["nfev"]).tolist(),
                     np.asarray(h["best_so_far"]).tolist()))
    return dict(f=np.asarray(r.f), objective=float(r.fun), evaluations=int(r.nfev),
                wall_time_s=float(r.wall_time_s), curve=curve)


def run_ga_pem(log, bounds, seed, workers):
    """The default method with 36 GA generations (GA + refinement on the budget)."""
    r = identify(log, rng=seed, workers=workers, progress=False, ga_options={"n_gen": 36})
    h = r.history
    curve = list(zip(np.asarray(h["nfev"]).tolist(),
                     np.asarray(h["best_so_far"]).tolist()))
    # after the refinement: the eq.-4 objective of the refined f
    curve.append((int(r.nfev), float(r.fun)))
    return dict(f=np.asarray(r.f), objective=float(r.fun), evaluations=int(r.nfev),
                wall_time_s=float(r.wall_time_s), curve=curve,
                ga_objective=float(np.min(h["best_so_far"])),
                refine_evaluations=int(r.refinement["nfev"]))


def run_de(log, bounds, seed, workers, budget=BUDGET, objective=None):
    """scipy's differential evolution, vectorised on the batch objective."""
    from scipy.optimize import differential_evolution
    from scipy.stats import qmc

    n_pop = 80
    maxiter = budget // n_pop - 1  # initial population + maxiter generations
    t0 = time.perf_counter()
    rec = Recorder(objective or OutputError(log, substeps=SUBSTEPS, workers=workers))
    lo, hi = bounds[:, 0], bounds[:, 1]
    init = lo + qmc.LatinHypercube(d=9, seed=np.random.default_rng(seed)).random(n_pop) * (hi - lo)

    def fun(x):  # vectorized=True: x has shape (9, S)
        return rec(np.asarray(x).T)

    res = differential_evolution(
        fun, list(map(tuple, bounds)), maxiter=maxiter, init=init, vectorized=True,
        updating="deferred", polish=False, tol=0.0, atol=0.0, rng=seed,
    )
    wall = time.perf_counter() - t0
    return dict(f=np.asarray(res.x), objective=float(res.fun), evaluations=rec.evaluations,
                wall_time_s=wall, curve=rec.curve, message=str(res.message), recorder=rec)


def run_cmaes(log, bounds, seed, workers, budget=BUDGET, objective=None):
    """CMA-ES (``cma``), ask/tell on the unit box."""
    import cma

    popsize = 16
    t0 = time.perf_counter()
    rec = Recorder(objective or OutputError(log, substeps=SUBSTEPS, workers=workers))
    lo, hi = bounds[:, 0], bounds[:, 1]
    rng = np.random.default_rng(seed)
    x0 = rng.uniform(0.0, 1.0, 9)
    opts = {
        "bounds": [0.0, 1.0], "popsize": popsize, "seed": int(seed) + 1, "verbose": -9,
        "maxfevals": budget, "tolfun": 0.0, "tolfunhist": 0.0, "tolx": 0.0,
        "tolflatfitness": 10**9, "tolstagnation": 10**9, "tolfunrel": 0.0,
    }
    es = cma.CMAEvolutionStrategy(x0, 0.3, opts)
    while rec.evaluations + popsize <= budget and not es.stop():
        U = np.clip(np.array(es.ask()), 0.0, 1.0)
        y = rec(lo + U * (hi - lo))
        es.tell(list(U), y.tolist())
    wall = time.perf_counter() - t0
    return dict(f=rec.best_x, objective=rec.best, evaluations=rec.evaluations,
                wall_time_s=wall, curve=rec.curve, stop=str(dict(es.stop())), recorder=rec)


def _with_refinement(runner):
    """``runner`` on the GA stage's budget (2816), then the default's refinement.

    The control experiment: is the default method's accuracy due to its GA
    or to the refinement?  Same refinement as ``identify()``: 4 starts (the
    best distinct points evaluated), refined together, at most 40 batches.
    """
    from identification.refinement import DEFAULT_GAIN, PredictionErrorProblem, refine

    def run(log, bounds, seed, workers):
        t0 = time.perf_counter()
        r = runner(log, bounds, seed, workers, budget=GA_PEM_BUDGET)
        rec = r.pop("recorder")
        problem = PredictionErrorProblem(log, gain=DEFAULT_GAIN, substeps=SUBSTEPS,
                                         workers=workers)
        ref = refine(problem, rec.best_points(4), bounds, max_iter=40)
        y = float(OutputError(log, substeps=SUBSTEPS, workers=workers)(ref.x[None])[0])
        evals = rec.evaluations + ref.nfev + 1
        curve = list(r["curve"]) + [(evals, y)]
        return dict(f=np.asarray(ref.x), objective=y, evaluations=evals,
                    wall_time_s=time.perf_counter() - t0, curve=curve,
                    search_objective=r["objective"], refine_evaluations=int(ref.nfev))

    run.__doc__ = f"{runner.__name__} on {GA_PEM_BUDGET} simulations, then the refinement."
    return run


def run_pem(log, bounds, seed, workers):
    """The default's refinement alone from 4 uniform random starts in the box.

    Control experiment: does the refinement need a global search at all?
    Uses only the refinement's own simulations (far below the budget).
    """
    from identification.refinement import DEFAULT_GAIN, PredictionErrorProblem, refine

    t0 = time.perf_counter()
    rng = np.random.default_rng(seed)
    lo, hi = bounds[:, 0], bounds[:, 1]
    starts = lo + rng.uniform(size=(4, 9)) * (hi - lo)
    problem = PredictionErrorProblem(log, gain=DEFAULT_GAIN, substeps=SUBSTEPS, workers=workers)
    ref = refine(problem, starts, bounds, max_iter=40)
    y = float(OutputError(log, substeps=SUBSTEPS, workers=workers)(ref.x[None])[0])
    evals = ref.nfev + 1
    return dict(f=np.asarray(ref.x), objective=y, evaluations=evals,
                wall_time_s=time.perf_counter() - t0, curve=[(evals, y)],
                refine_costs=np.asarray(ref.costs).tolist())


def _plain(runner):
    def run(*args):
        r = runner(*args)
        r.pop("recorder", None)
        return r
    return run


RUNNERS = {"paper": run_paper, "ga+pem": run_ga_pem, "de": _plain(run_de),
           "cmaes": _plain(run_cmaes), "de+pem": _with_refinement(run_de),
           "cmaes+pem": _with_refinement(run_cmaes), "pem": run_pem}


def optimiser_overhead(bounds, repeats=3):
    """Seconds each search spends outside the simulator on the full budget.

    The GA (paper settings), DE and CMA-ES are run on a zero-cost quadratic
    (same box, same budget, same population sizes); best of ``repeats``.
    The refinement's overhead is not included (its cost is simulations).
    """
    from identification.ga import PAPER_GA
    from identification.ga import run_ga

    c, w = bounds.mean(1), bounds[:, 1] - bounds[:, 0]

    def trivial(F):
        return np.sum(((np.atleast_2d(F) - c) / w) ** 2, 1)

    def ga():
        run_ga(trivial, bounds, rng=0, **PAPER_GA)

    def de():
        run_de(None, bounds, 0, None, objective=trivial)

    def cmaes():
        run_cmaes(None, bounds, 0, None, objective=trivial)

    out = {}
    for name, fn in (("ga", ga), ("de", de), ("cmaes", cmaes)):
        best = np.inf
        for _ in range(repeats):
            t0 = time.perf_counter()
            fn()
            best = min(best, time.perf_counter() - t0)
        out[name] = best
    return out


# -------------------------------------------------------------------- analysis
def _stats(values):
    v = np.asarray(values, dtype=float)
    return dict(median=float(np.median(v)), min=float(v.min()), max=float(v.max()))


def _median_curve(curves, grid):
    """Step functions of the curves on ``grid``; median, min, max over seeds.

    Each curve is a list of (evaluations, best objective so far); for
    ``ga+pem`` the last point is the eq.-4 objective of the refined f (the
    method's answer), which may lie above the GA's best.
    """
    import warnings

    Y = np.full((len(curves), grid.size), np.nan)
    for k, c in enumerate(curves):
        e = np.array([p[0] for p in c], dtype=float)
        b = np.array([p[1] for p in c], dtype=float)
        idx = np.searchsorted(e, grid, side="right") - 1
        ok = idx >= 0
        Y[k, ok] = b[idx[ok]]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN columns before the start
        return np.nanmedian(Y, 0), np.nanmin(Y, 0), np.nanmax(Y, 0)


def plot(summary, path, truth_objective):
    """Convergence curves (median over seeds, min-max band) to a PNG.

    Left: the searches alone; right: search + refinement (the last step of
    each curve is the eq.-4 objective of the refined f).
    """
    from matplotlib.figure import Figure

    fig = Figure(figsize=(11, 4.4), layout="constrained")
    axes = fig.subplots(1, 2, sharey=True)
    grid = np.arange(0, BUDGET + 41, 10, dtype=float)
    colours = {"paper": "C0", "ga+pem": "C0", "de": "C2", "de+pem": "C2",
               "cmaes": "C3", "cmaes+pem": "C3", "pem": "C4"}
    n_seeds = len(next(iter(summary.values()))["runs"])
    for ax, refined, title in ((axes[0], False, "searches alone"),
                               (axes[1], True, "search + refinement")):
        for m, s in summary.items():
            if m.endswith("pem") != refined:
                continue
            med, lo, hi = _median_curve(s["curves"], grid)
            ax.semilogy(grid, med, "-", color=colours.get(m), label=LABELS[m])
            ax.fill_between(grid, lo, hi, color=colours.get(m), alpha=0.15, lw=0)
        ax.axhline(truth_objective, color="k", ls="--", lw=1,
                   label=f"true f: {truth_objective:.0f} pulses$^2$ ({SUBSTEPS} substeps)")
        ax.axvline(BUDGET, color="0.5", ls=":", lw=1)
        ax.set_xlabel("simulations")
        ax.set_title(f"{title} (median of {n_seeds} seeds, band min-max)", fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    axes[0].set_ylabel("best output error Y (pulses$^2$, eq. 4)")
    fig.suptitle(f"{LOG}: the same objective, the paper's budget of {BUDGET} simulations",
                 fontsize=11)
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--seeds", type=int, nargs="+", default=list(range(5)))
    p.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    p.add_argument("--workers", type=int, default=None,
                   help="numba threads of the batch objective (default: all cores)")
    p.add_argument("--out", default="out/bench_optimisers.json", help="JSON result file")
    p.add_argument("--plot", default="out/optimisers_convergence.png", help="PNG of the curves")
    p.add_argument("--replot", metavar="JSON",
                   help="only redraw the PNG from a JSON written by an earlier run")
    args = p.parse_args(argv)
    if args.replot:
        old = json.loads(Path(args.replot).read_text())
        plot(old["methods"], args.plot, old["truth_objective"])
        print(f"wrote {args.plot}")
        return

    data = _data_dir()
    log = plant.load_log(data / f"{LOG}.csv")
    val = plant.load_log(data / f"{VALIDATION}.csv")
    f_true = np.asarray(json.loads((data / f"{LOG}.truth.json").read_text())["f_vector"])
    f_true_val = np.asarray(json.loads((data / f"{VALIDATION}.truth.json").read_text())["f_vector"])
    if not np.allclose(f_true, f_true_val):
        print("warning: the two logs' true f differ", file=sys.stderr)
    bounds = log.rig.bounds

    compile_s = warm_up()
    truth_obj = float(plant.output_error(log, f_true, substeps=SUBSTEPS))
    truth_val = float(plant.output_error(val, f_true_val, substeps=SUBSTEPS))
    print(f"budget {BUDGET} simulations, {SUBSTEPS} substeps; JIT warm-up {compile_s:.2f} s; "
          f"workers {args.workers or 'all'}")
    overhead = optimiser_overhead(bounds)
    print("optimiser overhead on the full budget, zero-cost objective: "
          + ", ".join(f"{k} {v:.2f} s" for k, v in overhead.items()))
    print(f"true f: objective {truth_obj:.0f} pulses^2 on {LOG}, "
          f"validation {truth_val:.0f} pulses^2 on {VALIDATION} (both at {SUBSTEPS} substeps)")

    summary = {}
    for m in args.methods:
        runs = []
        for seed in args.seeds:
            r = RUNNERS[m](log, bounds, seed, args.workers)
            f = np.asarray(r["f"], dtype=float)
            v = float(plant.output_error(val, f, substeps=SUBSTEPS))
            err = 100.0 * (f - f_true) / np.abs(f_true)
            r.update(seed=seed, f=f.tolist(), validation=v, validation_rel=v / truth_val,
                     param_err_pct=err.tolist(),
                     mean_abs_err_well_pct=float(np.mean(np.abs(err[list(WELL_EXCITED)]))))
            runs.append(r)
            print(f"  {m:7s} seed {seed}: {r['evaluations']:5d} sims {r['wall_time_s']:7.2f} s  "
                  f"Y {r['objective']:9.0f}  val/true {r['validation_rel']:8.2f}  "
                  f"mean|err| {r['mean_abs_err_well_pct']:8.3f} %", flush=True)
        summary[m] = dict(
            runs=runs,
            curves=[r["curve"] for r in runs],
            evaluations=_stats([r["evaluations"] for r in runs]),
            wall_time_s=_stats([r["wall_time_s"] for r in runs]),
            objective=_stats([r["objective"] for r in runs]),
            validation_rel=_stats([r["validation_rel"] for r in runs]),
            mean_abs_err_well_pct=_stats([r["mean_abs_err_well_pct"] for r in runs]),
            median_abs_err_pct=np.median(np.abs([r["param_err_pct"] for r in runs]), 0).tolist(),
        )

    print()
    hdr = (f"{'method':32s} {'sims':>5s} {'wall s':>7s} {'best Y':>17s} {'val / true':>17s} "
           f"{'mean|err| %':>19s}")
    print(hdr)
    print("-" * len(hdr))
    for m, s in summary.items():
        def rng_(k, fmt):
            st = s[k]
            return f"{st['median']:{fmt}} [{st['min']:{fmt}}-{st['max']:{fmt}}]"
        print(f"{LABELS[m]:32s} {s['evaluations']['median']:5.0f} "
              f"{s['wall_time_s']['median']:7.2f} {rng_('objective', '.0f'):>17s} "
              f"{rng_('validation_rel', '.2f'):>17s} {rng_('mean_abs_err_well_pct', '.2f'):>19s}")
    print("(median over seeds [min-max]; val / true: validation output error relative to "
          f"the true f's {truth_val:.0f} pulses^2)")
    print()
    print("median |parameter error| (% of truth):")
    print(f"{'method':32s} " + " ".join(f"{'f' + str(i + 1):>8s}" for i in range(9)))
    for m, s in summary.items():
        print(f"{LABELS[m]:32s} " + " ".join(f"{e:8.3f}" for e in s["median_abs_err_pct"]))

    out = dict(log=LOG, validation_log=VALIDATION, substeps=SUBSTEPS, budget=BUDGET,
               seeds=args.seeds, workers=args.workers, compile_time_s=compile_s,
               truth_objective=truth_obj, truth_validation=truth_val,
               optimiser_overhead_s=overhead, load_average=list(os.getloadavg()),
               well_excited=[f"f{i + 1}" for i in WELL_EXCITED],
               methods={m: {k: v for k, v in s.items()} for m, s in summary.items()})
    write_json_atomic(args.out, _clean(out))
    plot(summary, args.plot, truth_obj)
    print(f"\nwrote {args.out} and {args.plot}")


def _clean(x):
    if isinstance(x, dict):
        return {str(k): _clean(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_clean(v) for v in x]
    if isinstance(x, np.ndarray):
        return _clean(x.tolist())
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        return float(x) if np.isfinite(x) else None
    return x


if __name__ == "__main__":
    main()
