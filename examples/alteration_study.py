"""Run-to-run spread ("alteration") of the identification over 10 seeds.

The paper ran its GA several times on the same log and reported how much the
identified parameters varied from run to run, its "alteration": from ±3 %
(f9) to ±80 % (f3).  This script repeats the experiment for the paper's
procedure (``method="paper"``: the GA alone) and for the library's default
(``"ga+pem"``: the same GA, then prediction-error refinement), and prints,
per parameter,

* the **mean** over the seeds,
* the **alteration** ± % = half the range (max - min) over the seeds,
  relative to |mean|, x 100 (our reading of the paper's "±" figures),
* the **error** of the mean against the true f (%), and the worst error of a
  single run (%), if the truth file is found.

The figures, every run's f and the per-method statistics are saved as JSON
(``out/alteration/alteration.json``); ``docs/alteration.rst`` shows them
beside the paper's numbers.

Run from the repository root (about 10 s on 2 cores, kernels compiled)::

    python examples/alteration_study.py
    python examples/alteration_study.py --truth tests/data/puma560_paper_rigid.truth.json \
        --validate tests/data/puma560_validation_rigid.csv
    python examples/alteration_study.py --quick      # a smoke run (seconds)

Without a truth the study reports the spread alone.  The truth
(``STEM.truth.json``, only present for the emulated development logs, which a
clone of the repository has in ``tests/data``) is taken from ``--truth PATH``,
else looked for next to the log and in ``$PUMA_DATA_DIR``.  The library itself
never reads truth files: only this study compares with them.  A bad log,
truth file or option ends with one line ``error: ...`` and exit status 1.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

import identification
import plant
from identification.result import write_json_atomic

def parse_args(argv=None):
    """Command-line options of the study."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--log", type=Path, default=plant.example_log_path(),
                   help="log to identify (default: the bundled paper log)")
    p.add_argument("--seeds", type=int, default=10, help="number of seeds (default 10)")
    p.add_argument("--first-seed", type=int, default=0, help="seeds first..first+n-1")
    p.add_argument("--methods", nargs="+", default=["paper", "ga+pem"],
                   choices=identification.METHODS)
    p.add_argument("--truth", type=Path, help="STEM.truth.json with the true f (f_vector)")
    p.add_argument("--validate", type=Path, metavar="LOG2.csv",
                   help="also give each run's output error on this second log")
    p.add_argument("--workers", type=int, help="simulation threads (default: all cores)")
    p.add_argument("--generations", type=int, metavar="N",
                   help="GA generations per run (default: the paper's 40)")
    p.add_argument("--quick", action="store_true",
                   help="smoke run: 2 seeds, 2 GA generations, one refinement start")
    p.add_argument("--out", type=Path, default=Path("out") / "alteration",
                   help="directory of alteration.json")
    args = p.parse_args(argv)
    if args.quick:
        args.seeds = min(args.seeds, 2)
        args.generations = args.generations or 2
    if args.seeds < 1:
        p.error(f"--seeds must be >= 1, got {args.seeds}")
    if args.generations is not None and args.generations < 1:
        p.error(f"--generations must be >= 1, got {args.generations}")
    return args


def find_truth(log_path, explicit=None):
    """Path of the log's ``STEM.truth.json``, or None if there is none."""
    if explicit is not None:
        return Path(explicit)
    stem = Path(log_path).name.rsplit(".", 1)[0]
    dirs = [Path(log_path).parent]
    if os.environ.get("PUMA_DATA_DIR"):
        dirs.append(Path(os.environ["PUMA_DATA_DIR"]))
    for d in dirs:
        p = d / f"{stem}.truth.json"
        if p.is_file():
            return p
    return None


def spread_statistics(F, f_true=None):
    """Per-parameter statistics of identified vectors ``F`` (n_runs, 9).

    Returns
    -------
    dict of lists (9 values each)
        ``mean``, ``std``, ``min``, ``max``, ``alteration_pct`` (half the
        range relative to |mean|, %), and with ``f_true``: ``truth``,
        ``error_of_mean_pct`` ((mean - truth) / |truth|, %) and
        ``max_abs_error_pct`` (worst single run, %).
    """
    F = np.asarray(F, dtype=float)
    mean = F.mean(axis=0)
    half_range = 0.5 * (F.max(axis=0) - F.min(axis=0))
    s = {
        "mean": mean, "std": F.std(axis=0, ddof=1) if len(F) > 1 else np.zeros(9),
        "min": F.min(axis=0), "max": F.max(axis=0),
        "alteration_pct": 100.0 * half_range / np.abs(mean),
    }
    if f_true is not None:
        t = np.asarray(f_true, dtype=float)
        s["truth"] = t
        s["error_of_mean_pct"] = 100.0 * (mean - t) / np.abs(t)
        s["max_abs_error_pct"] = 100.0 * np.max(np.abs(F - t), axis=0) / np.abs(t)
    return {k: [float(x) for x in v] for k, v in s.items()}


def format_table(method, stats, runs):
    """The per-parameter table of one method as text."""
    has_truth = "truth" in stats
    head = f"{'':5}{'mean':>12}{'alteration':>13}"
    if has_truth:
        head += f"{'truth':>12}{'err(mean)':>13}{'max|err|':>13}"
    lines = [f"method {method!r}: {len(runs)} runs", head]
    for i, name in enumerate(plant.F_NAMES):
        ln = f"{name:5}{stats['mean'][i]:>12.5g}{'±%.3g %%' % stats['alteration_pct'][i]:>13}"
        if has_truth:
            ln += (f"{stats['truth'][i]:>12.5g}{'%+.3g %%' % stats['error_of_mean_pct'][i]:>13}"
                   f"{'%.3g %%' % stats['max_abs_error_pct'][i]:>13}")
        lines.append(ln)
    y = np.array([r["objective_pulses2"] for r in runs])
    t = np.array([r["wall_time_s"] for r in runs])
    ev = np.array([r["evaluations"] for r in runs])
    y0 = np.array([r["initial_best_pulses2"] for r in runs])
    yga = np.array([r["ga_final_best_pulses2"] for r in runs])
    lines.append(f"objective (eq. 4), best of the initial population: {y0.min():.0f} .. "
                 f"{y0.max():.0f} pulses^2; end of the GA: {yga.min():.0f} .. {yga.max():.0f}")
    lines.append(f"objective (eq. 4) of the result: {y.min():.0f} .. {y.max():.0f} pulses^2 "
                 f"(median {np.median(y):.0f}); simulations {ev.min()}..{ev.max()}; "
                 f"wall time {t.mean():.1f} s per run")
    if runs[0].get("validation_pulses2") is not None:
        v = np.array([r["validation_pulses2"] for r in runs])
        lines.append(f"validation output error: {v.min():.0f} .. {v.max():.0f} pulses^2 "
                     f"(median {np.median(v):.0f})")
    return "\n".join(lines)


def main(argv=None):
    """Run the study; returns the dict written to ``alteration.json``."""
    args = parse_args(argv)
    log = plant.load_log(args.log)
    truth_path = find_truth(args.log, args.truth)
    f_true = None
    if truth_path is not None:
        try:
            f_true = np.asarray(json.loads(truth_path.read_text())["f_vector"], dtype=float)
        except FileNotFoundError:
            raise ValueError(f"{truth_path}: truth file not found") from None
        except (json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"{truth_path}: not a truth file with an 'f_vector' "
                             f"({type(exc).__name__}: {exc})") from None
        if f_true.shape != (9,):
            raise ValueError(f"{truth_path}: 'f_vector' must have 9 values")
        print(f"truth: {truth_path}")
    else:
        print("no truth file found: errors against the truth are left out")
    val = plant.load_log(args.validate) if args.validate else None
    seeds = list(range(args.first_seed, args.first_seed + args.seeds))

    report = {
        "log": log.name, "seeds": seeds, "truth_file": str(truth_path) if truth_path else None,
        "alteration_definition": "half the range (max - min) over the seeds, relative to "
                                 "|mean|, in percent",
        "methods": {},
    }
    if val is not None:
        report["validation_log"] = val.name
        if f_true is not None:
            report["validation_pulses2_at_truth"] = float(plant.output_error(val, f_true))
    if f_true is not None:
        report["objective_pulses2_at_truth"] = float(
            identification.OutputError(log)(f_true)[0])

    ga_options = None if args.generations is None else {"n_gen": args.generations}
    report["generations"] = args.generations or 40
    for method in args.methods:
        runs = []
        refine_options = {"n_starts": 1} if args.quick and method != "paper" else None
        t0 = time.perf_counter()
        for seed in seeds:
            res = identification.identify(log, method=method, rng=seed, progress=False,
                                          workers=args.workers, ga_options=ga_options,
                                          refine_options=refine_options)
            run = {"seed": seed, "f": [float(v) for v in res.f],
                   "objective_pulses2": float(res.fun),
                   "initial_best_pulses2": float(res.history["best"][0]),
                   "ga_final_best_pulses2": float(res.history["best"][-1]),
                   "evaluations": int(res.nfev),
                   "wall_time_s": float(res.wall_time_s)}
            if val is not None:
                run["validation_pulses2"] = float(plant.output_error(val, res.f))
            runs.append(run)
            print(f"  {method} seed {seed}: objective {res.fun:.0f} pulses^2, "
                  f"{res.nfev} simulations, {res.wall_time_s:.1f} s", flush=True)
        stats = spread_statistics([r["f"] for r in runs], f_true)
        report["methods"][method] = {"runs": runs, "statistics": stats,
                                     "total_time_s": time.perf_counter() - t0}
        print(format_table(method, stats, runs), flush=True)

    args.out.mkdir(parents=True, exist_ok=True)
    write_json_atomic(args.out / "alteration.json", report)
    print(f"wrote {args.out / 'alteration.json'}")
    return report


def cli(argv=None):
    """Run :func:`main`; a bad log, file or option ends with one line on stderr, exit 1."""
    try:
        main(argv)
    except (plant.LogError, ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(cli())
