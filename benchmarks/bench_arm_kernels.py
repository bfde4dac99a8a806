"""An arm's compiled kernels: compile time and cost per lane and RK4 step (printed, not asserted).

For each robot of ``examples/any_arm.py`` (the planar arm, PUMA 560 joints
1-3, the three-joint URDF arm when Robotics Toolbox is installed, the
six-joint PUMA 560) and the PUMA 560 links 2-3 instance
(``RobotModel.puma560_links23()``), rigid and with two-mass flexible joints
(``arm_plant(model, flexible=True)``, the example's joints), one process per
case with an empty kernel directory (``PUMA_GA_CTC_KERNELS``) measures:

* ``compile s``: ``arm_plant`` (derivation and code generation) and the first
  :func:`plant.simulation.arm.simulate_arm` call of one candidate, which
  compiles the robot's generated module;
* ``ns per lane and RK4 step`` at 1, 8 and 64 candidates (one thread, 200
  samples of the P experiment at 48 RK4 steps, best of 3): the logged P
  loop of :mod:`plant.simulation.simulate` around the generated right-hand
  side; SIMD shows as 8 and 64 candidates costing far less per lane than one;
* ``dynamics instr.``: casadi instructions of the generated dynamics
  (:func:`plant.simulation.arm._dynamics_function`) and whether numba inlines
  the right-hand side (:data:`plant.simulation.arm.INLINE_MAX_INSTRUCTIONS`);
* ``pulses``: a hash of the 64 candidates' pulses, and whether one candidate
  alone gives the pulses it gives among 64 (a lane does not depend on its
  neighbours).

``--inline-limit N`` sets that limit in the measuring processes (e.g. to see
the six-joint arm inlined); ``--rigid`` skips the flexible arms.
``--out F.json`` writes the rows; ``--before F.json`` (the same script run on
another version of the library, e.g. from a git worktree with
``PYTHONPATH``) prints the two side by side and whether the pulses are the
same.

Run from the repository root::

    python benchmarks/bench_arm_kernels.py [--robots planar2 puma123 ...] [--out F.json]
                                           [--before F.json]
"""
from __future__ import annotations

import argparse
import hashlib
import inspect
import json
import os
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

CASES = [("planar2", False), ("planar2", True), ("puma123", False), ("puma123", True),
         ("urdf", False), ("puma6", False), ("puma6", True), ("links23", False)]
LANES = (1, 8, 64)
N_SAMPLES = 200


def measure(name: str, flexible: bool, inline_limit: int | None = None) -> dict:
    """One case, in this process (its kernel directory should be empty)."""
    import plant

    # the examples of the library version imported (any_arm puts its own root first)
    sys.path.insert(0, str(Path(plant.__file__).resolve().parents[1] / "examples"))
    import any_arm
    import plant.simulation.arm as arm
    from plant import RobotModel

    warnings.simplefilter("ignore")
    if inline_limit is not None:
        arm.INLINE_MAX_INSTRUCTIONS = inline_limit
    model = RobotModel.puma560_links23() if name == "links23" else any_arm.robot(name)
    rig, traj = any_arm.rig_for(model), any_arm.reference(model.n_joints)
    beta = model.base_parameters()(model.standard_parameters())  # the robot's base parameters
    if flexible:
        beta = np.concatenate([beta, *any_arm.flexible_joints(model)])
    t0 = time.perf_counter()
    p = arm.arm_plant(model, flexible=flexible)
    arm.simulate_arm(p, beta[None, :], rig, traj, 20, workers=1)
    compile_s = time.perf_counter() - t0
    dyn = arm._dynamics_function(model, model.base_parameters())
    module = sys.modules[type(p.kind).__module__]  # inlined: the generated module's decorator
    row = dict(robot=name, flexible=flexible, joints=model.n_joints, compile_s=compile_s,
               instructions=int(dyn.n_instructions()),
               inlined="@_inline_always\ndef rhs(" in inspect.getsource(module), ns={})
    rng = np.random.default_rng(0)
    B = beta * (1 + 0.01 * rng.standard_normal((max(LANES), beta.size)))
    pulses = {}
    for m in LANES:
        best = float("inf")
        for _ in range(3):
            t = time.perf_counter()
            run = arm.simulate_arm(p, B[:m], rig, traj, N_SAMPLES, workers=1)
            best = min(best, time.perf_counter() - t)
        row["ns"][str(m)] = best / (m * N_SAMPLES * arm.ARM_SUBSTEPS) * 1e9
        pulses[m] = np.asarray(run.errors)  # (m, n_samples, n_joints)
    row["status_ok"] = int(np.sum(run.status == 0))
    row["pulses_hash"] = hashlib.sha1(np.ascontiguousarray(pulses[max(LANES)]).tobytes()).hexdigest()[:12]
    row["lane_alone_same"] = bool(np.array_equal(pulses[1][0], pulses[max(LANES)][0]))
    return row


def run_case(name: str, flexible: bool, inline_limit: int | None = None) -> dict:
    with tempfile.TemporaryDirectory() as kernels:
        env = dict(os.environ, PUMA_GA_CTC_KERNELS=kernels)
        extra = [] if inline_limit is None else ["--inline-limit", str(inline_limit)]
        out = subprocess.run([sys.executable, __file__, "--case", name, str(int(flexible)), *extra],
                             env=env, capture_output=True, text=True, check=False)
    lines = [ln for ln in out.stdout.splitlines() if ln.startswith("{")]
    if out.returncode or not lines:
        return dict(robot=name, flexible=flexible, error=(out.stderr.strip().splitlines() or ["?"])[-1])
    return json.loads(lines[-1])


def fmt(row: dict | None) -> str:
    if row is None:
        return f"{'-':>8} {'-':>24} {'-':>6}"
    if "error" in row:
        return f"error: {row['error'][:60]}"
    ns = " ".join(f"{row['ns'][str(m)]:7.1f}" for m in LANES)
    return f"{row['compile_s']:8.1f} {ns} {row['instructions']:6d}{'*' if row['inlined'] else ' '}"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", nargs=2, help=argparse.SUPPRESS)
    ap.add_argument("--robots", nargs="+", default=None, help="robots (default all)")
    ap.add_argument("--rigid", action="store_true", help="rigid arms only")
    ap.add_argument("--inline-limit", type=int, default=None,
                    help="set plant.simulation.arm.INLINE_MAX_INSTRUCTIONS (what if a robot were inlined)")
    ap.add_argument("--out", type=Path, help="write the rows as JSON")
    ap.add_argument("--before", type=Path, help="rows of another version, printed beside")
    args = ap.parse_args(argv)
    if args.case:
        print(json.dumps(measure(args.case[0], bool(int(args.case[1])), args.inline_limit)))
        return 0
    cases = [c for c in CASES if (args.robots is None or c[0] in args.robots) and not (args.rigid and c[1])]
    before = {}
    if args.before:
        before = {(r["robot"], r["flexible"]): r for r in json.loads(args.before.read_text())}
    head = f"{'compile s':>9} {'ns/lane/step at 1, 8, 64':>24} {'instr.':>7}"
    print(f"{'robot':<9} {'joints':<9}" + (f" {'before: ' + head:<50} |" if before else "") + f" {head}"
          + ("  same pulses" if before else "  lane alone = in 64"))
    rows = []
    for name, flexible in cases:
        row = run_case(name, flexible, args.inline_limit)
        rows.append(row)
        old = before.get((name, flexible))
        same = ""
        if before and old is not None and "error" not in row and "error" not in old:
            same = "yes" if old["pulses_hash"] == row["pulses_hash"] else "no"
        elif "error" not in row:
            same = "yes" if row["lane_alone_same"] else "NO"
        print(f"{name:<9} {'flexible' if flexible else 'rigid':<9}"
              + (f" {fmt(old):<50} |" if before else "") + f" {fmt(row)}  {same}", flush=True)
    print("* right-hand side inlined by numba (plant.simulation.arm.INLINE_MAX_INSTRUCTIONS); "
          f"{N_SAMPLES} samples, 48 RK4 steps each, one thread, best of 3")
    if args.out:
        args.out.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
