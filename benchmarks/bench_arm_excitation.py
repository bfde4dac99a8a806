"""Excitation design for any arm, checked on an independent simulator (issue 23).

What it measures
----------------
For each draw of ``benchmarks/independent_arm.py`` (``--n A B C``: planar
two-link arms, PUMA 560 joints 1-3, the six-joint PUMA 560; seeds ``--seed
+ i``, chosen before looking; rigid; friction known or ``null`` as drawn):

1. the *baseline* reference is the draw's own random multisine (the one
   ``bench_arms.py`` identifies from, 5 s);
2. :func:`identification.design_excitation` designs a reference of the same
   length for the draw's robot model (``model=``: the DH table the user
   knows) within the *baseline's envelope*: per joint its range of angles
   (widened to hold the start state), its peak rate, and its peak
   feed-forward current divided by ``CURRENT_MARGIN`` (so that the design's
   feed-forward current peaks no higher than the baseline's), and its band
   (harmonics of ``1 / duration`` up to the baseline's highest frequency).  The prior
   the design linearises at is the truth's base parameters each scaled by a
   random factor in [0.7, 1.3] (the user's nominal model, 30 % off), and
   so is the friction prior of a draw whose sidecar leaves friction ``null``;
3. both references are run on the independent robot (Robotics Toolbox
   ``rne``, its own drive and friction, DOP853) under the rig's P law and
   identified with the default :func:`identification.arm.identify_arm`;
4. per reference: the number of *well-excited* base parameters (relative
   standard error < 1/3 %, ``bench_arms.py``'s criterion), whether every
   well-excited one is within 1 % of the truth, and the largest error of any
   base parameter relative to its scale ``max(|beta|, 5 % of the rms of
   |beta|)`` (the design's own scale: a parameter near zero does not divide
   by zero); and the design's predicted largest relative standard error
   (at the prior) and its wall time.

The truth (the draw's settings) is read here only; the library never sees it.

Usage (from the repository root; needs the ``bench`` extra)::

    python benchmarks/bench_arm_excitation.py --n 3 3 0 --seed 20262601 [--generations G]
                                               [--jobs 2] [--json out.json]
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import independent_arm as ia  # noqa: E402
from bench_arms import TOLERANCE, WELL_EXCITED_RSE, well_excited_check  # noqa: E402

#: Relative spread of the prior the design linearises at (each base parameter x U(1 - p, 1 + p)).
PRIOR_SPREAD = 0.3


def _identify(s, trajectory_parameters, beta):
    """Run a reference on the independent robot, identify it; the figures of step 4."""
    from identification.arm import identify_arm

    d = dataclasses.replace(s, trajectory=trajectory_parameters)
    log = ia.make_log(d)
    res = identify_arm(log)
    err, well, _, ok = well_excited_check(res, beta)
    scale = np.maximum(np.abs(beta), 0.05 * math.sqrt(float(np.mean(beta ** 2))))
    scaled = np.abs(np.asarray(res.beta, float) - beta) / scale
    return dict(success=bool(res.success), n_well=int(np.sum(well)), well_ok=ok,
                max_scaled_error_pct=100.0 * float(np.max(scaled)),
                worst=str(res.names[int(np.argmax(scaled))]),
                max_rse_pct=100.0 * float(np.max(np.asarray(res.x_rse)[:len(beta)])))


def run_case(job) -> dict:
    family, seed, generations = job
    from identification import design_excitation
    from identification.excitation import CURRENT_MARGIN, predicted_f_std, trajectory_limits
    from plant.logs.trajectory import Trajectory

    s = ia.draw(family, seed)
    model = ia.library_model(s)
    rig = ia.rig_of(s)
    names, beta = ia.truth_beta(s, model)
    beta = np.asarray(beta, float)
    rng = np.random.default_rng([seed, 1])
    prior = beta * rng.uniform(1 - PRIOR_SPREAD, 1 + PRIOR_SPREAD, beta.shape)
    n = len(s.active)
    friction_prior = None
    if not s.friction_known:  # the sidecar says null: the user's guess, 30 % off like beta's
        k = np.abs(np.asarray(s.gear_ratio))
        true = np.column_stack([k ** 2 * np.asarray(s.viscous), k[:, None] * np.asarray(s.coulomb)])
        friction_prior = true * rng.uniform(1 - PRIOR_SPREAD, 1 + PRIOR_SPREAD, true.shape)
    base_traj = Trajectory.from_sidecar(s.trajectory, "draw", n_joints=n)
    env = trajectory_limits(base_traj, s.duration_s, rig, prior, model=model,
                            joint_limits_rad=np.tile([-10.0, 10.0], (n, 1)),
                            friction_prior=friction_prior)
    lim = np.column_stack([np.minimum(env["q_min"], 0.0), np.maximum(env["q_max"], 0.0)])
    # the same band: harmonics of 1 / duration up to the baseline's highest frequency
    w_max = max(abs(term[1]) for terms in s.trajectory["terms_A_omega_phi"] for term in terms)
    n_harmonics = max(1, math.ceil(w_max / (2 * math.pi) * s.duration_s))
    t0 = time.perf_counter()
    traj, info = design_excitation(rig, s.duration_s, model=model, joint_limits_rad=lim,
                                   max_velocity_rad_s=env["qd_max"],
                                   max_current_A=env["i_max"] / CURRENT_MARGIN, rng=seed,
                                   f_prior=prior, friction_prior=friction_prior,
                                   n_harmonics=n_harmonics, generations=generations,
                                   full_output=True)
    t_design = time.perf_counter() - t0
    scale = info["f_scale"]
    base_rse = predicted_f_std(rig, base_traj, s.duration_s, prior, model=model,
                               friction_prior=friction_prior) / scale
    row = dict(family=family, seed=seed, n_base=len(beta), friction_known=s.friction_known,
               n_harmonics=n_harmonics, generations=info["generations"],
               design_s=round(t_design, 1),
               predicted_max_rse_pct=100.0 * float(np.max(info["predicted_f_rse"])),
               baseline_predicted_max_rse_pct=100.0 * float(np.max(base_rse)),
               baseline=_identify(s, s.trajectory, beta),
               design=_identify(s, traj.to_parameters(), beta))
    return row


def line(r) -> str:
    b, d = r["baseline"], r["design"]
    return (f"{r['family']:8s} {r['seed']:>9d}  r={r['n_base']:2d}  well-excited "
            f"{b['n_well']:2d} -> {d['n_well']:2d}  all within 1 %: {str(b['well_ok']):5s} -> "
            f"{str(d['well_ok']):5s}  max scaled error {b['max_scaled_error_pct']:8.3f} % "
            f"({b['worst']}) -> {d['max_scaled_error_pct']:8.3f} % ({d['worst']})  "
            f"design ({r['n_harmonics']} harmonics, {r['generations']} generations) "
            f"{r['design_s']:6.1f} s, predicted max rse "
            f"{r['baseline_predicted_max_rse_pct']:.3f} -> {r['predicted_max_rse_pct']:.3f} %")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, nargs=3, default=(3, 3, 0), metavar=("PLANAR2", "PUMA123", "PUMA6"),
                    help="draws per family (default 3 3 0)")
    ap.add_argument("--seed", type=int, default=20262601, help="first seed (default 20262601)")
    ap.add_argument("--generations", type=int, default=None,
                    help="GA generations of the design (default design_excitation's rule)")
    ap.add_argument("--jobs", type=int, default=1, help="processes (default 1)")
    ap.add_argument("--json", type=Path, default=None, help="write the rows as JSON")
    a = ap.parse_args(argv)
    jobs = [(fam, a.seed + i, a.generations) for fam, k in zip(ia.FAMILIES, a.n)
            for i in range(k)]
    print(f"excitation design vs the draw's multisine, seed {a.seed}, {len(jobs)} draws, "
          f"generations {a.generations or 'by the default rule'}; tolerance {100 * TOLERANCE:g} %, well excited: "
          f"rse < {100 * WELL_EXCITED_RSE:.3g} %", flush=True)
    rows = ia.run_jobs(run_case, jobs, a.jobs, line)
    for fam in ia.FAMILIES:
        rs = [r for r in rows if r["family"] == fam]
        if not rs:
            continue
        more = sum(r["design"]["n_well"] > r["baseline"]["n_well"] for r in rs)
        same = sum(r["design"]["n_well"] == r["baseline"]["n_well"] for r in rs)
        better = sum(r["design"]["max_scaled_error_pct"] < r["baseline"]["max_scaled_error_pct"]
                     for r in rs)
        ok = (sum(r["baseline"]["well_ok"] for r in rs), sum(r["design"]["well_ok"] for r in rs))
        med = (np.median([r["baseline"]["max_scaled_error_pct"] for r in rs]),
               np.median([r["design"]["max_scaled_error_pct"] for r in rs]))
        print(f"{fam}: more well-excited parameters {more}/{len(rs)} (as many {same}); smaller "
              f"largest error {better}/{len(rs)}; median largest scaled error {med[0]:.3f} -> "
              f"{med[1]:.3f} %; every well-excited within 1 %: {ok[0]} -> {ok[1]} of {len(rs)}; "
              f"median design time {np.median([r['design_s'] for r in rs]):.1f} s")
    if a.json is not None:
        a.json.parent.mkdir(parents=True, exist_ok=True)
        a.json.write_text(json.dumps(rows, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
