"""Identify f1..f9 from the bundled paper log; plot convergence and tracking errors.

The tutorial script of ``docs/tutorial_identification.rst``.  It

1. loads the bundled example log (the paper's experiment, rigid joints,
   ``plant.load_example()``), or the log given with ``--log``;
2. identifies the base parameters f1..f9 with the default method (the paper's
   multi-population GA, then prediction-error refinement) and prints them;
3. saves the convergence plot (``convergence.png``) and the logged vs
   simulated tracking errors of the identified model
   (``tracking_errors.png``, cf. the paper's figures 12-15);
4. with ``--validate LOG2.csv``, cross-validates the identified f on a second
   log of the same robot that was not used for identifying
   (``tracking_errors_validation.png``).  A clone of the repository has one:
   ``tests/data/puma560_validation_rigid.csv`` (another trajectory of the
   robot of the bundled log).

It needs nothing but the installed library.  Run from the repository root::

    python examples/identify_paper_log.py
    python examples/identify_paper_log.py --validate tests/data/puma560_validation_rigid.csv
    python examples/identify_paper_log.py --method paper        # the paper's GA alone
    python examples/identify_paper_log.py --quick               # a smoke run (seconds)

Figures and ``result.json`` go to ``out/identify_paper_log/`` (``--out``).  A
bad log or option ends with one line ``error: ...`` and exit status 1.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

import identification
import plant
from identification.cli import format_result_table


def parse_args(argv=None):
    """Command-line options of the example."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--log", type=Path, default=plant.example_log_path(),
                   help="log to identify (default: the bundled paper log)")
    p.add_argument("--validate", type=Path, metavar="LOG2.csv",
                   help="a second log of the same robot to cross-validate f on")
    p.add_argument("--method", choices=identification.METHODS,
                   default=identification.DEFAULT_METHOD)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--generations", type=int, metavar="N",
                   help="GA generations (default: the paper's 40)")
    p.add_argument("--quick", action="store_true",
                   help="smoke run: 2 GA generations and one refinement start")
    p.add_argument("--out", type=Path, default=Path("out") / "identify_paper_log",
                   help="directory of the figures and result.json")
    args = p.parse_args(argv)
    if args.generations is not None and args.generations < 1:
        p.error(f"--generations must be >= 1, got {args.generations}")
    return args


def main(argv=None):
    """Run the tutorial; returns the :class:`identification.IdentificationResult`."""
    args = parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)

    # 1. the log: CSV + JSON sidecar (rig constants, trajectory, search ranges)
    log = plant.load_log(args.log)
    print(f"{log.name}: {log.n_samples} samples, Ts = {log.rig.sample_time_s * 1e3:g} ms, "
          f"T = {log.t[-1]:.2f} s")

    # 2. identify (a tqdm bar shows the GA's generations)
    n_gen = 2 if args.quick and args.generations is None else args.generations
    ga_options = None if n_gen is None else {"n_gen": n_gen}
    refine_options = {"n_starts": 1} if args.quick and args.method != "paper" else None
    res = identification.identify(log, method=args.method, rng=args.seed,
                                  ga_options=ga_options, refine_options=refine_options)
    print(format_result_table(res, log))
    if res.refinement is not None:
        y_ga = identification.OutputError(log)(res.refinement["ga_f"])[0]
        print(f"the GA alone ended at {res.history['best'][-1]:.0f} pulses^2 "
              f"(its best f re-evaluated: {y_ga:.0f}); after refinement {res.fun:.0f}")
    res.save_json(args.out / "result.json")

    # 3. figures: convergence, and logged vs simulated tracking errors
    res.plot().savefig(args.out / "convergence.png", dpi=120)
    res.plot_tracking_errors().savefig(args.out / "tracking_errors.png", dpi=120)

    # 4. cross-validation on a trajectory not used for identifying
    if args.validate is not None:
        val = plant.load_log(args.validate)
        e_model = plant.simulate_experiment(val, res.f)
        y = float(np.sum((val.e_pulses - e_model) ** 2))
        print(f"cross-validation on {val.name} ({val.n_samples} samples): output error "
              f"{y:.0f} pulses^2, max |e_logged - e_model| = "
              f"{np.abs(val.e_pulses - e_model).max()} pulses")
        res.plot_tracking_errors(val).savefig(args.out / "tracking_errors_validation.png",
                                              dpi=120)
    print(f"figures and result.json in {args.out}/")
    return res


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
