"""Timing of the computed-torque controller and its closed-loop tools (printed, not asserted).

Measures, on the bundled paper log:

* one call of ``ComputedTorqueController.__call__`` (the per-sample work a
  real control PC would do at Ts = 0.7 ms; target <= 20 us), of its compiled
  step alone, and of ``PController.__call__``;
* one closed-loop run of the paper log (5215 samples) with
  :func:`plant.simulation.closed_loop.simulate_closed_loop` for P and CTC;
* the casadi evaluation (:func:`ctc.evaluate.evaluate_ctc`): graph build and
  run over the whole log;
* :func:`ctc.design.design_gains`;
* one call of ``ctc.arm.ArmComputedTorque`` (any serial arm's CTC, in
  Python around one evaluation of the robot model's casadi function) for the
  planar two-link arm, the PUMA 560 joints 1-3 and the six-joint PUMA 560 of
  ``examples/any_arm.py``, and its closed loop on the arm's plant; the
  build and one call of the flexible-joint CTC of the same arms
  (``ctc.arm.ArmFlexibleComputedTorque``, the example's two-mass joints:
  its link model over a sample is compiled when it is built); the arm CTC's
  law compiled in the arm's logged-run driver
  (``ArmComputedTorque.logged_controller``, ``simulate_arm(controller=)``)
  for one robot and for 16 side by side.

The model f is the centre of the sidecar's search ranges (no truth file
needed; timing does not depend on f).  JIT compilation is timed separately
(the first call) and excluded from the steady-state figures.

Run from the repository root: ``python benchmarks/bench_ctc.py``.
"""
from __future__ import annotations

import sys
import time
import warnings
from pathlib import Path

import numpy as np

from ctc import ComputedTorqueController, PController, design_gains
from ctc.computed_torque import _ctc_step
from plant.simulation.closed_loop import simulate_closed_loop
from plant.logs.log import load_example


def per_call(fn, n):
    t0 = time.perf_counter()
    for k in range(n):
        fn(k)
    return (time.perf_counter() - t0) / n


def best_of(fn, repeat=5):
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def arm_rows(n_calls=3000, n_samples=2000):
    """Rows of the arm CTC's per-sample call and closed loop (robots of examples/any_arm.py)."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "examples"))
    from any_arm import flexible_joints, reference, rig_for, robot

    from ctc.arm import ArmComputedTorque, ArmFlexibleComputedTorque
    from plant.simulation.arm import arm_plant, simulate_arm

    rows = []
    for name in ("planar2", "puma123", "puma6"):
        model = robot(name)
        arm, rig, traj = arm_plant(model), rig_for(model), reference(model.n_joints)
        c = ArmComputedTorque(arm, arm.beta(), rig, traj)
        q0 = np.asarray(traj.position(np.zeros(1)), dtype=float)[0]
        e = np.zeros(model.n_joints, dtype=np.int64)
        c(0, 0.0, q0, e)  # first call outside the timing
        dt = min(per_call(lambda k: c(k, k * c.ts, q0, e), n_calls) for _ in range(3))
        rows.append((f"arm CTC __call__, {name} ({model.n_joints} joints)", dt * 1e6, "us"))
        # the arm's kernels compile on the first run, outside the timing
        simulate_closed_loop(rig, arm.beta(), c, trajectory=traj, n_samples=10, plant=arm)
        rows.append((f"arm closed loop CTC, {name}, {n_samples} samples",
                     best_of(lambda: simulate_closed_loop(rig, arm.beta(), c, trajectory=traj,
                                                          n_samples=n_samples, plant=arm), 3) * 1e3,
                     "ms"))
        # the same law compiled in the arm's logged-run driver (ArmComputedTorque.logged_controller):
        # one robot, and 16 robots side by side in lanes (2 threads); the first run compiles
        # (or loads from numba's cache) the robot's law module
        t0 = time.perf_counter()
        simulate_arm(arm, arm.beta(), rig, traj, 10, controller=c.logged_controller(10))
        rows.append((f"arm CTC compiled in the driver, {name}: first run (compile or load)",
                     (time.perf_counter() - t0) * 1e3, "ms"))
        law = c.logged_controller(n_samples)
        for m in (1, 16):
            B = np.tile(arm.beta(), (m, 1))
            rows.append((f"arm CTC compiled in the driver, {name}, {m} robot(s) x {n_samples}",
                         best_of(lambda: simulate_arm(arm, B, rig, traj, n_samples, controller=law),
                                 3) * 1e3, "ms"))
            rows.append((f"arm P loop in the driver, {name}, {m} robot(s) x {n_samples}",
                         best_of(lambda: simulate_arm(arm, B, rig, traj, n_samples), 3) * 1e3,
                         "ms"))
        stiff, damp, ia, backlash = flexible_joints(model)
        t0 = time.perf_counter()
        c = ArmFlexibleComputedTorque(arm, arm.beta(), rig, traj, stiffness=stiff, damping=damp,
                                      motor_inertia=ia, backlash=backlash)
        rows.append((f"arm flexible CTC build, {name}", (time.perf_counter() - t0) * 1e3, "ms"))
        c(0, 0.0, q0, e)
        dt = min(per_call(lambda k: c(k, k * c.ts, q0, e), n_calls // 3) for _ in range(3))
        rows.append((f"arm flexible CTC __call__, {name} ({c.link_substeps} link steps)",
                     dt * 1e6, "us"))
    return rows


def main():
    warnings.simplefilter("ignore")
    log = load_example()
    f = log.rig.bounds.mean(axis=1)
    n_ref = log.n_total

    t0 = time.perf_counter()
    ctc = ComputedTorqueController.from_log(f, log)
    q = np.array([0.001, -0.002])
    e = np.array([1, 2], dtype=np.int64)
    ctc.reset()
    ctc(0, 0.0, q, e)
    t_first = time.perf_counter() - t0
    p = PController.from_log(log)

    n = 200_000
    rows = []
    ctc.reset()
    dt = min(per_call(lambda k: ctc(k % n_ref, 0.0, q, e), n) for _ in range(3))
    rows.append(("CTC __call__ (public, per sample)", dt * 1e6, "us"))
    state = ctc.estimator_state().copy() if hasattr(ctc, "estimator_state") else None
    state = np.zeros((9, 1)) if state is None else np.asarray(state, dtype=float).reshape(-1, 1)
    args = (ctc.f, ctc.parameters, ctc.reference_table, state)
    dt = min(per_call(lambda k: _ctc_step(k % n_ref, q, *args), n) for _ in range(3))
    rows.append(("CTC compiled step alone", dt * 1e6, "us"))
    dt = min(per_call(lambda k: p(k, 0.0, q, e), n) for _ in range(3))
    rows.append(("PController __call__", dt * 1e6, "us"))

    for sub in (24, 32):
        rows.append((f"closed loop P, 5215 samples, {sub} substeps",
                     best_of(lambda: simulate_closed_loop(log, f, p, substeps=sub)) * 1e3, "ms"))
        rows.append((f"closed loop CTC, 5215 samples, {sub} substeps",
                     best_of(lambda: simulate_closed_loop(log, f, ctc, substeps=sub)) * 1e3, "ms"))

    from ctc.evaluate import build_step_function, evaluate_ctc

    rows.append(("casadi step Function build (32 substeps)",
                 best_of(lambda: build_step_function(ctc, f, substeps=32), 3) * 1e3, "ms"))
    rows.append(("casadi evaluation, 5215 samples (build + run)",
                 best_of(lambda: evaluate_ctc(ctc, f, substeps=32), 3) * 1e3, "ms"))
    rows.append(("design_gains (observer)", best_of(lambda: design_gains(log.rig), 5) * 1e3, "ms"))
    rows += arm_rows()

    print(f"first CTC build + call (includes JIT load/compile): {t_first * 1e3:.1f} ms")
    print(f"{'measure':<52} {'value':>10}")
    for name, v, unit in rows:
        print(f"{name:<52} {v:>8.2f} {unit}")
    budget = rows[0][1]
    print(f"\nCTC per-sample call: {budget:.2f} us = {budget / 700 * 100:.2f} % of the 0.7 ms sample (target <= 20 us)")


if __name__ == "__main__":
    main()
