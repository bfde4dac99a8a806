"""Timing of the flexible-joint CTC's model-error check in ``ArmComputedTorque.from_result`` (printed).

``from_result`` on a flexible identification result runs the rigid-equivalent
CTC and the flexible designs over the model-error set of the robust design
(stiffness +-30 %, damping x0.5 .. x2; :data:`ctc.arm.FLEXIBLE_CHECK_SCENARIOS`)
on the identified two-mass arm, and keeps the minimax controller.  This script
identifies three committed flexible logs (:func:`identification.arm.identify_arm`,
defaults) and times ``from_result`` twice in one process: the first call
includes compiling (or loading from numba's cache) the robot's compiled laws
(:meth:`ctc.arm.ArmComputedTorque.logged_controller`), the second does not.
It prints the choice and every scenario's error, so that two versions of the
library can be compared on the same figures (run it with ``PYTHONPATH`` at
another checkout).

Run from the repository root: ``python benchmarks/bench_flexible_check.py``.
"""
from __future__ import annotations

import time
import warnings
from pathlib import Path

from ctc.arm import ArmComputedTorque
from identification.arm import identify_arm
from plant.logs.arm_log import load_arm_log

DATA = Path(__file__).resolve().parents[1] / "tests" / "data"
LOGS = {"drill (PUMA 560 links 2-3)": DATA / "puma560_paper_drill_flex.csv",
        "compliant planar, backlash": DATA / "independent_arm" / "indep_arm_planar2_compliant_backlash.csv",
        "compliant planar, light motor": DATA / "independent_arm" / "indep_arm_planar2_compliant_light_motor.csv"}


def main():
    warnings.simplefilter("ignore")
    print(f"{'log':<32} {'model':<9} {'first (s)':>10} {'second (s)':>11}  chosen")
    details = []
    for name, path in LOGS.items():
        log = load_arm_log(path)
        res = identify_arm(log)
        if res.model != "flexible":
            print(f"{name:<32} {res.model:<9} (no check: a rigid result)")
            continue
        times = []
        for _ in range(2):
            t0 = time.perf_counter()
            ctrl = ArmComputedTorque.from_result(res, log)
            times.append(time.perf_counter() - t0)
        sel = ctrl.selection
        print(f"{name:<32} {res.model:<9} {times[0]:>10.2f} {times[1]:>11.2f}  "
              f"{type(ctrl).__name__} (design {sel['design']}, worst flexible "
              f"{sel['worst_flexible']}, rigid-equivalent {sel['worst_rigid_equivalent']})")
        details.append((name, sel))
    print("\nerrors after 0.1 s per scenario (pulses; None: not run, the design had lost):")
    for name, sel in details:
        print(f"  {name}: scenarios {sel['scenarios']}")
        print(f"    rigid-equivalent {sel['rigid_equivalent']}")
        for d in sel["designs"]:
            print(f"    {d['name']:<24} {d['errors']}")


if __name__ == "__main__":
    main()
