"""Excitation design on the drill/flex rig: predicted and achieved accuracy of all nine f.

What it measures
----------------
1. :func:`identification.design_excitation` designs a 1.5 s trajectory for
   the rig of ``tests/data/puma560_paper_drill_flex.json`` (seed 0, defaults:
   the paper trajectory's joint range, the drive's 15 A full scale, prior f =
   the search box's centre).
2. Predicted relative standard errors (:func:`identification.excitation.predicted_f_std`,
   Gauss-Newton on the refinement's prediction errors at the *true* f) of
   the design, of the paper trajectory with T = 1.5 s (the acceptance's
   reference; it saturates the drives at 15 A) and of the paper trajectory
   with T = 3.65 s cut at 1.5 s, on the rigid plant and on the drill's
   flexible plant (the truth's ``emulator.variant``: stiffness 30000 / 6000
   N m/rad, damping 4 / 0.4 N m s/rad, Jm 200e-6 kg m^2).
3. Each trajectory is run on both plants (:func:`plant.emulate_log`) and
   identified with the default ``identify()``: error per f in % of the truth.
4. ``--agreement N``: Spearman rank correlation between the search's cheap
   regressor criterion and the prediction-error criterion over N random
   trajectories of the design's family, brought within the limits (the
   measurement behind the two-stage search).

The truth file is read here, by the benchmark only.

Usage (from the repository root)::

    PYTHONPATH=. python benchmarks/bench_excitation.py [--agreement 20] [--seed 0]
"""
from __future__ import annotations

import argparse
import json
import time
import warnings
from pathlib import Path

import numpy as np

import identification
import plant
from identification import excitation as ex

HERE = Path(__file__).resolve().parent
DATA = HERE.parent / "tests" / "data"
DURATION = 1.5


def _fmt(v):
    return " ".join(f"{x:8.2f}" for x in v)


def agreement(rig, f, n, rng):
    """Spearman correlation of the regressor and prediction-error max RSEs over n trajectories."""
    from scipy.stats import spearmanr

    lim = ex._paper_range()
    fam = ex._Family(np.asarray(rig.q0_rad), DURATION, ex.DEFAULT_HARMONICS, lim, None)
    scale = np.abs(f)
    a, b = [], []
    while len(a) < n:
        x = rng.uniform(fam.bounds[:, 0], fam.bounds[:, 1])
        s = 1.0
        for _ in range(12):
            tr = fam.trajectory(x, s)
            if ex.trajectory_limits(tr, DURATION, rig, f)["violation"] == 0:
                break
            s *= 0.8
        else:
            continue
        a.append(np.max(ex.regressor_rse(tr, DURATION, scale)))
        b.append(np.max(ex.predicted_f_std(rig, tr, DURATION, f) / scale))
    return spearmanr(a, b).statistic, np.array(a), np.array(b)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--agreement", type=int, default=0,
                    help="random trajectories of the criteria-agreement check (0: skip)")
    ap.add_argument("--out", help="write the figures as JSON")
    args = ap.parse_args(argv)
    base = plant.load_log(DATA / "puma560_paper_drill_flex.csv")
    truth = json.loads((DATA / "puma560_paper_drill_flex.truth.json").read_text())
    f = np.array(truth["f_vector"])
    v = truth["emulator"]["variant"]
    flex = plant.FlexibleJoints(v["flex_stiffness"], v["flex_damping"], 200e-6)
    rig = base.rig
    plant.warm_up(closed_loop=True)
    t0 = time.perf_counter()
    traj, info = identification.design_excitation(rig, DURATION, rng=args.seed, full_output=True)
    print(f"design: {time.perf_counter() - t0:.1f} s, {info['nfev']} candidates; "
          f"peak feed-forward current {_fmt(info['limits']['i_max'])} A")
    print(json.dumps({"trajectory": {"parameters": traj.to_parameters(), "duration_s": DURATION}}))
    trajs = {"designed": traj, "paper T=1.5": plant.Trajectory.paper(1.5),
             "paper T=3.65 cut": plant.Trajectory.paper(3.65)}
    out = {}
    names = "".join(f"{'f' + str(i + 1):>9}" for i in range(9))
    print(f"\npredicted relative standard error (%) at the true f{'':<6}{names}      max")
    for pname, fl in (("rigid", None), ("flexible", flex)):
        for tname, tr in trajs.items():
            sd = ex.predicted_f_std(rig, tr, DURATION, f, flexible=fl, base=base)
            rse = 100 * sd / np.abs(f)
            out.setdefault(tname, {})[f"predicted_rse_{pname}"] = rse.tolist()
            print(f"{pname + ' ' + tname:<41}{_fmt(rse)} {rse.max():8.2f}")
    print(f"\nidentify() (defaults), error (%) of the truth{'':<3}{names}   max|e|  model  s")
    for pname, fl in (("rigid", None), ("flexible", flex)):
        for tname, tr in trajs.items():
            log = plant.emulate_log(base, f, trajectory=tr, duration_s=DURATION, flexible=fl,
                                    name="excitation_check")
            t1 = time.perf_counter()
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                r = identification.identify(log, rng=args.seed, progress=False)
            err = 100 * (r.f - f) / np.abs(f)
            out[tname][f"error_{pname}"] = err.tolist()
            print(f"{pname + ' ' + tname:<41}{_fmt(err)} {np.abs(err).max():8.2f}"
                  f"  {getattr(r, 'model', '?'):<8}{time.perf_counter() - t1:5.1f}", flush=True)
    if args.agreement:
        rho, a, b = agreement(rig, f, args.agreement, np.random.default_rng(args.seed))
        print(f"\ncriteria agreement over {args.agreement} random trajectories: Spearman "
              f"rho = {rho:.2f} (regressor vs prediction-error max RSE)")
        out["agreement"] = dict(spearman=float(rho), regressor=a.tolist(), pem=b.tolist())
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
