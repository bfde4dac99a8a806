"""Any serial arm end to end: emulate a log, identify the base parameters, CTC vs P.

The paper's pipeline for a robot given by a DH table or a URDF file
(:class:`plant.RobotModel`), one robot per run (``--robot``):

* ``planar2`` -- a two-link arm in a vertical plane, its DH table written here;
* ``puma123`` -- the PUMA 560 joints 1-3 (Corke's parameters, wrist locked);
* ``puma6``   -- the six-joint PUMA 560;
* ``urdf``    -- the three-joint arm of ``tests/data/urdf/arm_3r_tool.urdf``
  (needs the ``urdf`` extra, Robotics Toolbox's reader).

Steps: the rig's P-control experiment is emulated with the library's own
plant (:func:`plant.simulation.synthetic.emulate_arm_log`; a tutorial's log -- the
acceptance figures come from an independent simulator,
``benchmarks/bench_arms.py``), written as ``STEM.csv`` + ``STEM.json``
(columns per named joint, the robot in the sidecar) and read back;
:func:`identification.arm.identify_arm` identifies the base parameters
(IDIM-LS start, output-error refinement); the computed-torque controller
built from them (:class:`ctc.arm.ArmComputedTorque`) and the rig's P loop
track the same reference on the robot.

With ``--flexible`` the robot has two-mass joints (link modes of 12-20 Hz,
light damping, 2 mrad of gearbox backlash on the last joint): the
identification chooses the model itself (``model_choice``), and the
controller built from the result is the motor-side flexible-joint CTC
(:class:`ctc.arm.ArmFlexibleComputedTorque`).

With ``--excite`` the log's reference is designed for the robot model
first (:func:`identification.design_excitation`: the worst base
parameter's predicted error minimised within a quarter turn of the start
and the drive's current) instead of the hand-written multisine.

With ``--pick-up KG`` a tool of KG kg is picked up at half the log, and the
static CTC of the unloaded identification runs against the adaptive one
(:class:`ctc.arm_adaptive.ArmAdaptiveComputedTorque`: the payload
identified on-line from windows of its own run).

Run from the repository root::

    python examples/any_arm.py --robot planar2        # seconds
    python examples/any_arm.py --flexible             # the planar arm with compliant joints
    python examples/any_arm.py --robot puma6          # about half a minute (compiling included)
    python examples/any_arm.py --quick                # a 2 s log of the planar arm
    python examples/any_arm.py --pick-up 2            # and a 2 kg tool picked up mid-run
    python examples/any_arm.py --excite               # the log's reference designed first

Writes ``out/any_arm/<robot>.{csv,json}``, ``<robot>_result.json`` and
``<robot>_tracking.png``.  A bad option ends with one line ``error: ...``
and exit status 1.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

ROBOTS = ("planar2", "puma123", "puma6", "urdf")
URDF = Path(__file__).resolve().parents[1] / "tests" / "data" / "urdf" / "arm_3r_tool.urdf"


def parse(argv):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--robot", choices=ROBOTS, default="planar2", help="the arm (default planar2)")
    p.add_argument("--duration", type=float, default=5.0, help="log length in s (default 5)")
    p.add_argument("--quick", action="store_true", help="a 2 s log (smoke run)")
    p.add_argument("--flexible", action="store_true",
                   help="two-mass joints with backlash on the last joint (model choice, flexible CTC)")
    p.add_argument("--pick-up", type=float, default=None, metavar="KG",
                   help="also pick up a tool of KG kg at half the log and compare the static "
                        "and the adaptive CTC (rigid arms)")
    p.add_argument("--excite", action="store_true",
                   help="design the log's reference (identification.design_excitation for the "
                        "robot model, within a quarter turn of the start) instead of the multisine")
    p.add_argument("--out", type=Path, default=Path("out") / "any_arm",
                   help="output directory (default out/any_arm)")
    a = p.parse_args(argv)
    if a.quick:
        a.duration = 2.0
    if not (math.isfinite(a.duration) and 1.0 <= a.duration <= 60.0):
        raise ValueError(f"--duration must lie in [1, 60] s, got {a.duration}")
    if a.pick_up is not None:
        if not (math.isfinite(a.pick_up) and 0.0 < a.pick_up <= 9.0):
            raise ValueError(f"--pick-up must lie in (0, 9] kg, got {a.pick_up}")
        if a.flexible:
            raise ValueError("--pick-up needs a rigid arm (the adaptive CTC identifies a rigid "
                             "payload): drop --flexible")
    return a


def robot(name):
    """The robot model and the rig's gear ratios."""
    from plant import RobotModel

    if name == "planar2":
        return RobotModel.from_dh([
            dict(a=0.6, mass=4.0, com=(-0.3, 0.01, 0), inertia=(0.01, 0.12, 0.13, 0, 0, 0),
                 gear_ratio=80.0, motor_inertia=1e-4),
            dict(a=0.45, mass=2.5, com=(-0.2, 0, 0), inertia=(0.005, 0.05, 0.05, 0, 0, 0),
                 gear_ratio=-50.0, motor_inertia=1e-4),
        ], gravity=(0.0, -9.81, 0.0), name="planar 2R arm")
    if name == "puma123":
        return RobotModel.puma560(active=(0, 1, 2))
    if name == "puma6":
        return RobotModel.puma560(active=range(6))
    names = ("waist", "shoulder", "elbow")
    return RobotModel.from_urdf(URDF, gear_ratios={n: g for n, g in zip(names, (60.0, 80.0, 50.0))},
                                motor_inertias={n: 1e-4 for n in names})


def rig_for(model, ts=1e-3, ppr=2000, kt=0.25):
    """A rig for the model: P gains for a loop at 1 % of the sample rate, damped by viscous friction."""
    from plant import Rig

    n = model.n_joints
    k = model.gear_ratios
    rng = np.random.default_rng(0)
    Dm = np.mean([np.diag(model.inertia_matrix(q)) for q in rng.uniform(-0.5, 0.5, (8, n))], axis=0)
    w = 2 * math.pi * 0.01 / ts
    spr = np.abs(k) * ppr / (2 * math.pi)
    return Rig(sample_time_s=ts, gear_ratio=tuple(k), encoder_ppr=(ppr,) * n,
               p_gain_A_per_pulse=tuple(w * w * Dm / (np.abs(k) * kt * spr)),
               torque_constant_Nm_per_A=(kt,) * n,
               viscous_friction_Nms_per_rad=tuple(2 * 0.5 * w * Dm / k ** 2),
               coulomb_friction_Nm=((0.01, 0.012),) * n, coulomb_ramp_speed_rad_per_s=0.5,
               gravity_m_s2=9.81, a3_m=0.0, q0_rad=(0.0,) * n, qd0_rad_per_s=(0.0,) * n,
               current_full_scale_A=60.0)


def flexible_joints(model):
    """Two-mass joints for the model: stiffness K (link modes 12-20 Hz at q = 0), damping D
    (ratio 0.05), reflected motor inertia Ia (the model's) and backlash (2 mrad on the last
    joint), each (n,) joint side."""
    nj = model.n_joints
    ia = model.standard_parameters()[-nj:]
    link = np.diag(model.inertia_matrix(np.zeros(nj))) - ia
    stiff = link * (2 * math.pi * np.linspace(12.0, 20.0, nj)) ** 2
    damp = 2 * 0.05 * np.sqrt(stiff * link * ia / (link + ia))
    backlash = np.zeros(nj)
    backlash[-1] = 2e-3
    return stiff, damp, ia, backlash


def reference(n, seed=1):
    """A multisine per joint (two terms, 0.2-0.8 Hz) from rest at q = 0, quintic ramp 0.5 s."""
    from plant import Trajectory

    rng = np.random.default_rng(seed)
    terms, c = [], []
    for _ in range(n):
        amp = rng.uniform(0.15, 0.35, 2)
        ph = rng.uniform(0, 2 * math.pi, 2)
        terms.append([(a, 2 * math.pi * f, p) for a, f, p in zip(amp, rng.uniform(0.2, 0.8, 2), ph)])
        c.append(-float(np.sum(amp * np.cos(ph))))
    return Trajectory.from_terms(c, terms, t_ramp_s=0.5)


def main(argv=None):
    args = parse(argv)
    import plant
    from ctc import PController
    from ctc.arm import ArmComputedTorque
    from identification.arm import identify_arm
    from plant.simulation.arm import arm_plant
    from plant.logs.arm_log import load_arm_log
    from plant.simulation.synthetic import emulate_arm_log

    if args.robot == "urdf":
        try:
            import roboticstoolbox  # noqa: F401  (the urdf extra)
        except ImportError:
            print("error: --robot urdf needs Robotics Toolbox (pip install 'puma-ga-ctc[urdf]')",
                  file=sys.stderr)
            return 1
    model = robot(args.robot)
    arm = arm_plant(model)
    rig = rig_for(model)
    traj = reference(model.n_joints)
    n = int(round(args.duration / rig.sample_time_s))
    truth = arm.beta()
    print(f"{model!r}: {len(truth)} base parameters")
    if args.excite:  # the reference designed for this robot model (its own inertials the prior)
        from identification import design_excitation
        from identification.excitation import predicted_f_std

        t0 = time.perf_counter()
        traj, info = design_excitation(rig, args.duration, model=model, rng=0, full_output=True)
        scale = info["f_scale"]  # the design's own scales
        before = predicted_f_std(rig, reference(model.n_joints), args.duration,
                                 info["f_prior"], model=model) / scale
        print(f"designed reference in {time.perf_counter() - t0:.0f} s: predicted largest "
              f"relative standard error {100 * np.max(info['predicted_f_rse']):.3f} % "
              f"(the multisine's {100 * np.max(before):.3f} %)")
    robot_row = truth
    if args.flexible:  # two-mass joints: link modes 12-20 Hz, backlash 2 mrad on the last joint
        arm = arm_plant(model, flexible=True)
        stiff, damp, ia, backlash = flexible_joints(model)
        robot_row = np.concatenate([truth, stiff, damp, ia, backlash])
        print("flexible joints: K " + ", ".join(f"{v:.0f}" for v in stiff) + " N m/rad, backlash "
              + ", ".join(f"{1e3 * v:g}" for v in backlash) + " mrad")
    sidecar_robot = (dict(urdf=str(URDF), joints=list(model.joint_names),
                          motor_inertias={j: 1e-4 for j in model.joint_names})
                     if args.robot == "urdf" else None)
    name = args.robot + ("_flexible" if args.flexible else "")
    log = emulate_arm_log(arm, robot_row, rig, traj, n, name=name, robot=sidecar_robot)
    try:
        args.out.mkdir(parents=True, exist_ok=True)
        path = log.save(args.out / f"{name}.csv")
    except OSError as exc:
        print(f"error: cannot write {args.out}: {exc.strerror or exc}", file=sys.stderr)
        return 1
    log = load_arm_log(path)
    print(f"log {path}: {log.n_samples} samples, P loop max |e| {np.abs(log.e_pulses).max(0).tolist()} pulses")

    res = identify_arm(log)
    print(f"identified in {res.elapsed_s:.1f} s ({res.nit} iterations, {res.nfev} simulations): "
          f"{res.message}")
    if res.model_choice:
        print(f"model: {res.model_choice['model']} ({res.model_choice['reason']})")
    print(f"  {'name':8s} {'truth':>11s} {'identified':>11s} {'error %':>9s} {'rse %':>8s}")
    for pname, t, x, r in zip(res.names, truth, res.beta, res.x_rse):
        err = 100 * (x / t - 1) if abs(t) > 1e-12 else float("nan")
        print(f"  {pname:8s} {t:11.5f} {x:11.5f} {err:9.3f} {100 * r:8.3f}")
    if args.flexible and res.joint_stiffness_Nm_per_rad is not None:
        for what, t, x in (("K (N m/rad)", stiff, res.joint_stiffness_Nm_per_rad),
                           ("Jm k^2 (kg m^2)", ia, res.motor_inertia_reflected_kgm2),
                           ("backlash (mrad)", 1e3 * backlash,
                            1e3 * np.asarray(res.joint_backlash_rad or np.zeros(len(ia))))):
            print(f"  {what:16s} truth " + ", ".join(f"{v:.4g}" for v in t) + "   identified "
                  + ", ".join(f"{v:.4g}" for v in x))

    out = {}
    fig_rows = []
    for label, ctrl in (("P", PController.from_log(log)),
                        ("CTC", ArmComputedTorque.from_result(res, log))):
        t0 = time.perf_counter()
        r = plant.simulate_closed_loop(log.rig, robot_row, ctrl, trajectory=log.trajectory,
                                       n_samples=log.n_samples, plant=arm, label=label,
                                       substeps=16 if args.flexible else 8)
        out[label] = dict(max_abs_error_after_0p1s=r.max_abs_error(0.1).tolist(),
                          rms_error_after_0p1s=r.rms_error(0.1).tolist(),
                          within_1_pulse=r.within(1, after_s=0.1), wall_s=time.perf_counter() - t0)
        fig_rows.append(r)
        print(f"{label:4s} max |e| after 0.1 s {r.max_abs_error(0.1).tolist()} pulses, "
              f"within +-1: {r.within(1, after_s=0.1)}" + (f" ({type(ctrl).__name__})"
                                                           if label == "CTC" else ""))
    report = dict(robot=args.robot, model=repr(model), names=list(res.names), truth=truth.tolist(),
                  identified=res.x.tolist(), rse=res.x_rse.tolist(), identify_s=res.elapsed_s,
                  tracking=out, flexible=bool(args.flexible), model_choice=res.to_dict()["model_choice"])
    if args.pick_up is not None:
        report["pick_up"], pick_rows = pick_up(args.pick_up, model, arm, truth, log, res)
        fig_rows += pick_rows
    try:
        (args.out / f"{name}_result.json").write_text(json.dumps(report, indent=1) + "\n")
        from matplotlib.figure import Figure

        fig = Figure(figsize=(3.5 * model.n_joints, 2.5 * len(fig_rows)), layout="constrained")
        axes = fig.subplots(len(fig_rows), model.n_joints, squeeze=False)
        title = f"{name}: P (top), CTC" + (
            f", then static and adaptive CTC with {args.pick_up:g} kg picked up at "
            f"{report['pick_up']['t_s']:.2f} s (bottom)" if args.pick_up is not None else " (bottom)")
        for row, r in zip(axes, fig_rows):
            r.plot(currents=False, ax=row[None, :], title=title)
        fig.savefig(args.out / f"{name}_tracking.png", dpi=90)
    except OSError as exc:
        print(f"error: cannot write {args.out}: {exc.strerror or exc}", file=sys.stderr)
        return 1
    print(f"wrote {args.out}/{name}_result.json and {name}_tracking.png")
    return 0


def pick_up(mass, model, arm, truth, log, res):
    """A tool of ``mass`` kg picked up at half the log: the static CTC of the unloaded
    identification against :class:`ctc.arm_adaptive.ArmAdaptiveComputedTorque` (report, runs)."""
    import plant
    from ctc.arm import ArmComputedTorque
    from ctc.arm_adaptive import ArmAdaptiveComputedTorque

    t_pick = 0.5 * log.n_samples * log.rig.sample_time_s
    com = (0.05, 0.02, 0.0)
    loaded = truth + model.payload_delta(mass, com, base=arm.base)
    k_after = int(round((t_pick + 0.5) / log.rig.sample_time_s))
    report, rows = dict(mass_kg=mass, com_m=list(com), t_s=t_pick), []
    for label, ctrl in (("static", ArmComputedTorque.from_result(res, log)),
                        ("adaptive", ArmAdaptiveComputedTorque(res, log))):
        r = plant.simulate_closed_loop(log.rig, truth, ctrl, trajectory=log.trajectory,
                                       n_samples=log.n_samples, plant=arm, label=label,
                                       f_schedule=[(t_pick, loaded)])
        after = np.abs(r.e_pulses[k_after:]).max(axis=0).tolist() if k_after < r.e_pulses.shape[0] \
            else None
        report[label] = dict(max_abs_error_after_change_0p5s=after)
        if label == "adaptive":
            report[label].update(payload_history=[list(h) for h in ctrl.payload_history],
                                 events=[dict(t_s=e["t_s"], kind=e["kind"]) for e in ctrl.events])
        rows.append(r)
        print(f"{mass:g} kg picked up at {t_pick:.2f} s, {label:8s} CTC: max |e| from 0.5 s after "
              f"{after} pulses" + (f"; payload {ctrl.payload_mass_kg:.3f} kg, events "
                                   f"{[e['kind'] for e in ctrl.events]}"
                                   if label == "adaptive" else ""))
    return report, rows


if __name__ == "__main__":
    try:
        sys.exit(main())
    except KeyboardInterrupt:
        sys.exit(130)
    except (ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        sys.exit(1)
