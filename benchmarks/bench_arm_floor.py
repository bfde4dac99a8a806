"""What a model of the robot leaves: the rigid fit's cost in quantisation floors on rigid arms.

``identify_arm(model="auto")`` keeps the rigid model without fitting two-mass
joints when its prediction-error cost is at most
:data:`identification.model_choice.ARM_FLOOR_FACTOR` quantisation floors (``n / 12``
pulse^2, a count known to a unit cell).  The threshold must lie above what
the rigid model leaves on a *rigid* robot -- the quantisation noise and the
numerics -- and below what a compliant arm's rigid fit leaves.  This
benchmark measures the first: for each family and draw of
``benchmarks/independent_arm.py`` (rigid joints; robot, gears, encoders,
motor inertias, friction known or ``null``, P gains, multisine reference,
seeds ``seed + i`` chosen before looking) it makes the 5 s P-control log with
the independent simulator (Robotics Toolbox ``rne`` or pinocchio, its own
drive, DOP853), identifies it with the default ``identify_arm(log)`` and
prints the rigid fit's cost in floors (``res.fun`` over ``n_samples *
n_joints / 12``), the model chosen, and whether every well-excited base
parameter is within 1 % (:func:`bench_arms.well_excited_check`).

Usage::

    python benchmarks/bench_arm_floor.py --n 6 6 0 6 6 --seed 20262901 --jobs 2

Needs the ``bench`` extra.  The truth is read here; the library never reads it.
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import independent_arm as ia  # noqa: E402


def run_case(job) -> dict:
    """One rigid draw: its log, the default identification and the rigid fit's level."""
    from bench_arms import well_excited_check
    from identification.arm import identify_arm
    from identification.flexible import quantisation_floor

    family, seed = job
    s = ia.draw(family, seed, compliant=False)
    log = ia.make_log(s)
    _, beta = ia.truth_beta(s, log.model)
    t0 = time.perf_counter()
    res = identify_arm(log)
    wall = time.perf_counter() - t0
    _, _, _, ok = well_excited_check(res, beta)
    level = float(res.fun) / quantisation_floor(log.n_samples * log.n_joints)
    return dict(family=family, seed=seed, n_joints=len(s.active), level=level,
                model=(res.model_choice or {}).get("model", res.model), params_ok=ok,
                friction_known=s.friction_known, encoder_ppr=list(s.encoder_ppr),
                sample_time_s=s.sample_time_s, identify_s=wall)


def _line(c) -> str:
    return (f"{c['family']:8s} seed {c['seed']}  joints {c['n_joints']}  rigid fit "
            f"{c['level']:.4f} floors  model {c['model']:18s} well-excited "
            f"{'ok' if c['params_ok'] else 'MISS'}  friction "
            f"{'known' if c['friction_known'] else 'identified'}  ppr {c['encoder_ppr']}  "
            f"Ts {1e3 * c['sample_time_s']:.1f} ms  identify {c['identify_s']:.1f} s")


def main(argv=None):
    from identification.model_choice import ARM_FLOOR_FACTOR

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, nargs="+", default=(6, 6, 0, 6, 6), metavar="N",
                    help="rigid draws per family, in the order " + " ".join(ia.FAMILIES))
    ap.add_argument("--seed", type=int, default=20262901, help="first seed (draw i uses seed + i)")
    ap.add_argument("--jobs", type=int, default=1, help="draws run in parallel processes")
    a = ap.parse_args(argv)
    ia.check_counts(ap, a.n, ia.FAMILIES)
    jobs = [(family, a.seed + i) for family, n in zip(ia.FAMILIES, a.n) for i in range(n)]
    cases = ia.run_jobs(run_case, jobs, a.jobs, _line)
    if not cases:
        print("bench_arm_floor: no draws (--n all zero)")
        return 0
    lv = np.array([c["level"] for c in cases])
    above = [c for c in cases if c["level"] > ARM_FLOOR_FACTOR]
    named = ", ".join(f"{c['family']} {c['seed']}" for c in above) or "none"
    print(f"\n{len(cases)} rigid draws (seed {a.seed}): the rigid fit at {lv.min():.4f} - "
          f"{lv.max():.4f} quantisation floors (median {np.median(lv):.4f}); above "
          f"ARM_FLOOR_FACTOR = {ARM_FLOOR_FACTOR:g}: {len(above)} "
          f"({named}); rigid model "
          f"chosen on {sum(c['model'] == 'rigid' for c in cases)} / {len(cases)}; well-excited "
          f"base parameters within 1 % on {sum(c['params_ok'] for c in cases)} / {len(cases)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
