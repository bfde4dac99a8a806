"""Coverage of the standard errors: do f +- 1.96 f_std contain the truth?

What it measures
----------------
Held-out logs emulated with :func:`plant.emulate_log` (known f): rigid and
two-mass flexible plants (:class:`plant.FlexibleJoints`), encoders of 250,
1000 and 4096 pulses per revolution (the P gain scaled to keep the loop gain
in A/rad), the paper trajectory at several periods and a ramped two-harmonic
trajectory, the true f perturbed per seed (+-5 % per parameter, keeping eq. 3's
f3 = a3 f5 and f4 = a3 f6 of a rigid body).  Each log is
identified with the default method (``identify(log, rng=seed)``) and the
benchmark prints, per log and in total, the fraction of the nine f whose
interval ``f +- 1.96 f_std`` contains the truth (target >= 90 %), the
median |f - truth| / f_std, the Newey-West lag and the HAC factor (HAC
standard error / textbook sigma^2 (J^T J)^-1 one), and the coverage the
textbook (white-residual) standard errors would have had.

Usage (from the repository root)::

    PYTHONPATH=. python benchmarks/bench_coverage.py [--quick] [--out out/coverage.json]
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import time
import warnings
from pathlib import Path

import numpy as np

import identification
import plant

HERE = Path(__file__).resolve().parent
DATA = HERE.parent / "tests" / "data"

#: Flexible plants of the held-out logs: (stiffness N m/rad, damping N m s/rad).
FLEX = {"stiff": ((60000.0, 15000.0), (6.0, 1.0)), "soft": ((30000.0, 6000.0), (4.0, 0.4))}


def trajectories():
    """Name -> (Trajectory, duration s)."""
    two = plant.Trajectory.from_terms(
        [-0.4, 0.6], [[(0.35, 2 * math.pi / 3.0, 0.0), (0.15, 2 * math.pi / 1.0, 0.7)],
                      [(0.45, 2 * math.pi / 1.5, 1.2), (0.12, 2 * math.pi / 0.6, 0.3)]], 0.6)
    return {"paper_T3.65": (plant.Trajectory.paper(3.65), 3.65),
            "paper_T3.0": (plant.Trajectory.paper(3.0), 3.0),
            "paper_T5.0": (plant.Trajectory.paper(5.0), 5.0),
            "two_harmonic": (two, 3.0),
            }


def make_log(base, f_true, *, ppr, traj, duration, flex=None, name="held_out"):
    """An emulated log at encoder ``ppr`` (both joints), loop gain kept in A/rad."""
    rig = base.rig
    scale = np.array(rig.encoder_ppr, float) / ppr
    rig = dataclasses.replace(rig, encoder_ppr=(ppr, ppr),
                              p_gain_A_per_pulse=tuple(float(v) for v in
                                                       np.array(rig.p_gain_A_per_pulse) * scale))
    flexible = None
    if flex is not None:
        k, d = FLEX[flex]
        flexible = plant.FlexibleJoints(k, d, 200e-6)
    return plant.emulate_log(base, f_true, rig=rig, trajectory=traj, duration_s=duration,
                             flexible=flexible, name=name)


def cases(quick=False):
    """The held-out set: (name, ppr, trajectory name, flex, seed)."""
    if quick:
        return [("r1000_paper", 1000, "paper_T3.65", None, 0),
                ("r250_two", 250, "two_harmonic", None, 1),
                ("r4096_T3", 4096, "paper_T3.0", None, 2),
                ("fstiff1000_paper", 1000, "paper_T3.65", "stiff", 3)]
    out = []
    seed = 0
    for flex in (None, "stiff", "soft"):
        for ppr in (250, 1000, 4096):
            for tname in ("paper_T3.65", "two_harmonic", "paper_T5.0" if ppr != 1000
                          else "paper_T3.0"):
                if flex == "soft" and tname != "paper_T3.65":
                    continue
                out.append((f"{'rigid' if flex is None else flex}_{ppr}_{tname}", ppr, tname,
                            flex, seed))
                seed += 1
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="4 logs instead of the full set")
    ap.add_argument("--out", help="write the per-log figures as JSON")
    args = ap.parse_args(argv)
    base = plant.load_log(DATA / "puma560_paper_rigid.csv")
    f0 = np.array(json.loads((DATA / "puma560_paper_rigid.truth.json").read_text())["f_vector"])
    trajs = trajectories()
    plant.warm_up(closed_loop=True)
    rows, inside, inside_iid, n_par = [], 0, 0, 0
    print(f"{'log':<28}{'cover':>7}{'iid':>6}{'med|z|':>8}{'max|z|':>8}{'lag':>6}"
          f"{'hac':>6}{'scale':>7}{'max rel err %':>15}{'time s':>8}")
    t_all = time.perf_counter()
    for name, ppr, tname, flex, seed in cases(args.quick):
        rng = np.random.default_rng(1000 + seed)
        f_true = f0 * (1 + 0.05 * rng.uniform(-1, 1, 9))
        f_true[2:4] = base.rig.a3_m * f_true[4:6]  # a rigid body: eq. 3's f3 = a3 f5, f4 = a3 f6
        traj, dur = trajs[tname]
        t0 = time.perf_counter()
        log = make_log(base, f_true, ppr=ppr, traj=traj, duration=dur, flex=flex, name=name)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            r = identification.identify(log, rng=seed, progress=False)
        dt = time.perf_counter() - t0
        z = (r.f - f_true) / r.f_std
        ok = np.abs(z) <= 1.96
        # the textbook standard errors, for comparison (HAC factor per parameter ~ median)
        z_iid = z * r.uncertainty["hac_factor"] * r.uncertainty["scale"]
        ok_iid = np.abs(z_iid) <= 1.96
        inside += int(ok.sum())
        inside_iid += int(ok_iid.sum())
        n_par += 9
        rel = np.max(np.abs(r.f - f_true) / np.abs(f_true)) * 100
        print(f"{name:<28}{ok.mean():>7.0%}{ok_iid.mean():>6.0%}{np.median(np.abs(z)):>8.2f}"
              f"{np.max(np.abs(z)):>8.2f}{r.uncertainty['lag']:>6d}"
              f"{r.uncertainty['hac_factor']:>6.2f}{r.uncertainty['scale']:>7.2f}{rel:>15.2f}{dt:>8.1f}", flush=True)
        rows.append(dict(log=name, ppr=ppr, trajectory=tname, flexible=flex, seed=seed,
                         z=z.tolist(), covered=ok.tolist(), lag=r.uncertainty["lag"],
                         hac_factor=r.uncertainty["hac_factor"], f_true=f_true.tolist(),
                         f=r.f.tolist(), f_std=r.f_std.tolist()))
    print(f"coverage of f +- 1.96 f_std: {inside}/{n_par} = {inside / n_par:.1%} "
          f"(textbook white-residual errors: {inside_iid / n_par:.1%}); "
          f"{time.perf_counter() - t_all:.0f} s")
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(dict(coverage=inside / n_par, rows=rows), indent=1))


if __name__ == "__main__":
    main()
