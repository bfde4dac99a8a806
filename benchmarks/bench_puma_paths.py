"""The PUMA 560 links 2-3 on both paths: ``identification.identify`` and ``identify_arm``.

What it measures
----------------
For each development log, the PUMA path (``identification.identify(log)``,
the default method ``ga+pem`` and model choice, seed ``--seed``) and the arm
path (``identification.arm.identify_arm(load_arm_log(path))``, its defaults:
IDIM-LS start, output-error refinement, model choice, on the robot model
``RobotModel.puma560_links23()`` that ``load_arm_log`` gives a sidecar
without a ``robot`` object) side by side:

* the relative error of each f1..f9 against the truth (the rigid-equivalent
  f for a flexible result), its maximum over the nine and over the paper's
  well-excited f1 f2 f4 f6 f7 f9;
* ``fun`` as each path reports it -- the PUMA path: the output error of
  eq. 4 at the identification's substeps (1 RK4 step per sample for a rigid
  result, the flexible fit's for a flexible one); the arm path: the
  prediction-error cost of its refinement -- and ``Y``, the output error of
  eq. 4 of both results computed the same way: the instance's arm plant
  (rigid, or two-mass with the result's K, D, ``Jm k^2``, backlash) at
  ``max(DEFAULT_SUBSTEPS, the flexible fits' substeps)`` RK4 steps per
  sample (the truth's ``Y`` on the first row of each log);
* the model chosen and, for a flexible result, the joints against the
  emulator's;
* the wall time of the identification call (each path's rigid kernels
  compiled before the clock; the drill log's flexible kernels compile
  inside it);
* the paper's GA on both paths (``method="paper"``, the paper's budget,
  seed ``--seed``, the rigid model, one worker): the relative difference of
  the best f (issue 23's acceptance: within 1e-9), the difference of its
  output error of eq. 4 (each path's GA objective: one RK4 step per
  sample), whether the best output error after every generation is the
  same, and each GA's wall time;
* unless ``--no-kernels``: each path's compiled kernels in ns per lane
  and RK4 step (64 lanes, one thread, the drill log): the P experiment
  (the GA's objective), the rigid replay and the two-mass replay;
* unless ``--no-ctc``: the largest tracking error after 0.1 s (pulses,
  joint 2 / 3) of each result's computed torque (``from_result``:
  ``ctc.ComputedTorqueController`` and ``ctc.arm.ArmComputedTorque``) on the
  true robot (rigid, or the drill log's two-mass robot with the emulator's
  joints), whole log.

The truth files (``tests/data/*.truth.json``) are read here for the errors;
the library never reads them.  Not part of the test suite.

Usage (from the repository root)::

    python benchmarks/bench_puma_paths.py [--logs STEM ...] [--seed 0] [--no-ctc] [--no-ga]
                                          [--no-kernels] [--out F.json]
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
DATA = Path(os.environ.get("PUMA_DATA_DIR", ROOT / "tests" / "data"))
STEMS = ("puma560_paper_rigid", "puma560_validation_rigid", "puma560_paper_drill_flex")
WELL_EXCITED = [0, 1, 3, 5, 6, 8]  # f1 f2 f4 f6 f7 f9

import plant  # noqa: E402
from identification import identify  # noqa: E402
from identification.arm import identify_arm  # noqa: E402
from plant.logs.arm_log import load_arm_log  # noqa: E402
from plant.simulation.arm import arm_plant, replay_arm, simulate_arm  # noqa: E402
from plant.simulation.simulate import DEFAULT_SUBSTEPS  # noqa: E402


def truth_of(stem):
    """The truth file's f, and for a flexible log the emulator's joints (K, D, Jm k^2)."""
    t = json.loads((DATA / f"{stem}.truth.json").read_text())
    f = np.array(t["f_vector"], dtype=float)
    v = (t.get("emulator") or {}).get("variant") or {}
    if not v.get("flexible"):
        return f, None
    log = load_arm_log(DATA / f"{stem}.csv")
    m = log.model  # Corke's motor inertias (the emulator's Jm = 200e-6 kg m^2)
    ia = [m.links[i].motor_inertia * m.links[i].gear_ratio ** 2 for i in m.active]
    return f, dict(K=list(v["flex_stiffness"]), D=list(v["flex_damping"]), Ia=ia, b=[0.0, 0.0])


def joints_of(res):
    """A result's joints (K, D, Jm k^2, backlash), or None for a rigid result."""
    if res.get("model") != "flexible" or res.get("joint_stiffness_Nm_per_rad") is None:
        return None
    b = res.get("joint_backlash_rad")
    return dict(K=list(res["joint_stiffness_Nm_per_rad"]), D=list(res["joint_damping_Nms_per_rad"]),
                Ia=list(res["motor_inertia_reflected_kgm2"]), b=list(b) if b else [0.0, 0.0])


def output_error(log, f, joints, substeps):
    """Eq. 4 of f (and joints) against the log on the instance's arm plant (pulses^2)."""
    if joints is None:
        robot, row = arm_plant(log.model), np.asarray(f, dtype=float)
    else:
        robot = arm_plant(log.model, flexible=True)
        row = np.concatenate([f, joints["K"], joints["D"], joints["Ia"], joints["b"]])
    sim = simulate_arm(robot, row[None], log.rig, log.trajectory, log.n_samples,
                       e_log=log.e_pulses, errors=False, substeps=substeps, workers=1)
    return float(sim.objective[0])


def ctc_errors(path_name, res, log, plog, f, joints, substeps):
    """Largest |e| after 0.1 s (pulses, per joint) of the result's CTC on the true robot."""
    from ctc import ComputedTorqueController
    from ctc.arm import ArmComputedTorque

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if path_name == "puma":
            ctl = ComputedTorqueController.from_result(res, plog)
            fj = None if joints is None else plant.FlexibleJoints(
                joints["K"], joints["D"], np.asarray(joints["Ia"]) / np.asarray(plog.rig.gear_ratio) ** 2)
            run = plant.simulate_closed_loop(plog, f, ctl, flexible=fj, substeps=substeps)
        else:
            ctl = ArmComputedTorque.from_result(res, log)
            if joints is None:
                robot, row = arm_plant(log.model), f
            else:
                robot = arm_plant(log.model, flexible=True)
                row = np.concatenate([f, joints["K"], joints["D"], joints["Ia"], joints["b"]])
            run = plant.simulate_closed_loop(log.rig, row, ctl, trajectory=log.trajectory,
                                             n_samples=log.n_samples, plant=robot, substeps=substeps)
    name = type(ctl).__name__
    sel = getattr(ctl, "selection", None)
    if sel and sel.get("designs"):  # the arm path's flexible designs over the model-error set
        print(f"arm path's design check (ctrl.selection; worst max|e| pulses over "
              f"{', '.join(sel['scenarios'])}; kept: {name}): "
              + "; ".join(f"{d['name']} {d['worst']:g}" for d in sel["designs"])
              + f"; rigid-equivalent {sel['worst_rigid_equivalent']:g}")
    if not run.success:
        return name, None
    return name, [int(v) for v in run.max_abs_error(0.1)]


def warm_up(stems):
    """Compile (or load from numba's cache) each path's rigid kernels before the clock."""
    t = time.perf_counter()
    plant.warm_up()
    log = load_arm_log(DATA / f"{stems[0]}.csv")
    robot = arm_plant(log.model)
    f = robot.beta()[None]
    simulate_arm(robot, f, log.rig, log.trajectory, 10, workers=1)
    replay_arm(robot, f, log.rig, log.reference_counts()[:10], log.e_pulses[:10].astype(float),
               log.i_A[:10], gain=0.02, workers=1)
    return time.perf_counter() - t


def ga_agreement(stem, seed):
    """The paper's GA on both paths (seed, rigid, one worker): f, output error, history."""
    path = DATA / f"{stem}.csv"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        t = time.perf_counter()
        puma = identify(plant.load_log(path), method="paper", rng=seed, workers=1,
                        progress=False, model="rigid")
        t_puma = time.perf_counter() - t
        t = time.perf_counter()
        arm = identify_arm(load_arm_log(path), method="paper", rng=seed, workers=1, model="rigid")
        t_arm = time.perf_counter() - t
    f_puma, f_arm = np.asarray(puma.f, dtype=float), np.asarray(arm.ga["x"], dtype=float)
    return dict(log=stem, seed=seed, f_rel=float(np.max(np.abs(f_arm / f_puma - 1.0))),
                Y_puma=float(puma.fun), Y_arm=float(arm.ga["output_error"]),
                history_equal=bool(np.array_equal(arm.ga["best"], puma.history["best"])),
                generations=int(arm.ga["generations"]), substeps=int(arm.ga["substeps"]),
                wall_puma_s=t_puma, wall_arm_s=t_arm)


def print_ga(ga_rows):
    print()
    print("the paper's GA on both paths (method='paper', seed, rigid, 1 worker): best f and "
          "its output error Y (eq. 4, pulses^2, each path's GA objective)")
    head = (f"{'log':<25}{'seed':>5}{'max|f_arm/f_puma-1|':>21}{'Y puma':>10}{'Y arm':>10}"
            f"{'dY/Y':>9}  {'best per gen.':<14}{'substeps':>9}{'puma s':>8}{'arm s':>7}")
    print(head)
    print("-" * len(head))
    for g in ga_rows:
        dy = abs(g["Y_arm"] - g["Y_puma"]) / g["Y_puma"] if g["Y_puma"] else 0.0
        print(f"{g['log']:<25}{g['seed']:>5}{g['f_rel']:>21.3g}{g['Y_puma']:>10.0f}"
              f"{g['Y_arm']:>10.0f}{dy:>9.2g}  "
              f"{('same' if g['history_equal'] else 'differ') + ' (' + str(g['generations']) + ')':<14}"
              f"{g['substeps']:>9}{g['wall_puma_s']:>8.1f}{g['wall_arm_s']:>7.1f}")


def run_log(stem, seed, ctc):
    """Both paths on one log: a list of row dicts (truth first)."""
    path = DATA / f"{stem}.csv"
    f_true, j_true = truth_of(stem)
    plog, log = plant.load_log(path), load_arm_log(path)
    rows = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        t = time.perf_counter()
        puma = identify(plog, rng=seed, progress=False)
        t_puma = time.perf_counter() - t
        t = time.perf_counter()
        arm = identify_arm(log)
        t_arm = time.perf_counter() - t
    subs = [DEFAULT_SUBSTEPS]
    if puma.get("model") == "flexible":
        subs.append(int((puma.get("settings") or {}).get("substeps") or 0))
    if arm.get("model") == "flexible":
        subs.append(int(arm.get("flexible_substeps") or 0))
    S = max(subs)
    rows.append(dict(log=stem, path="truth", model="flexible" if j_true else "rigid",
                     f=f_true.tolist(), joints=j_true, Y=output_error(log, f_true, j_true, S),
                     substeps=S))
    for name, res, f, fun, wall in (("puma", puma, np.asarray(puma.f, dtype=float), float(puma.fun), t_puma),
                                    ("arm", arm, np.asarray(arm.beta, dtype=float), float(arm.fun), t_arm)):
        rel = np.abs(f / f_true - 1.0)
        joints = joints_of(res)
        row = dict(log=stem, path=name, model=res.get("model", "rigid"), f=f.tolist(),
                   rel=rel.tolist(), max_rel=float(rel.max()),
                   max_rel_well=float(rel[WELL_EXCITED].max()), fun=fun,
                   Y=output_error(log, f, joints, S), substeps=S, wall_s=wall, joints=joints,
                   choice=(res.get("model_choice") or {}).get("reason"))
        if ctc:
            t = time.perf_counter()
            row["ctc"], row["ctc_max_e"] = ctc_errors(name, res, log, plog, f_true, j_true, S)
            row["ctc_s"] = time.perf_counter() - t
        rows.append(row)
    return rows


def print_table(rows, ctc):
    head = (f"{'log':<25}{'path':<7}{'model':<9}" + "".join(f"{f'f{i}':>7}" for i in range(1, 10))
            + f"{'max':>7}{'maxWE':>7}{'fun':>11}{'Y':>9}{'wall s':>8}")
    if ctc:
        head += f"  {'CTC |e| 2/3':<12}controller"
    print("relative f error (%) against the truth; maxWE over f1 f2 f4 f6 f7 f9")
    print(head)
    print("-" * len(head))
    for r in rows:
        line = f"{r['log']:<25}{r['path']:<7}{r['model']:<9}"
        if r["path"] == "truth":
            line += " " * 63 + " " * 14 + f"{'-':>11}{r['Y']:>9.0f}{'-':>8}"
        else:
            line += "".join(f"{100 * v:>7.3f}" for v in r["rel"])
            line += f"{100 * r['max_rel']:>7.3f}{100 * r['max_rel_well']:>7.3f}"
            line += f"{r['fun']:>11.5g}{r['Y']:>9.0f}{r['wall_s']:>8.1f}"
            if ctc:
                e = r.get("ctc_max_e")
                line += f"  {('failed' if e is None else f'{e[0]} / {e[1]}'):<12}{r['ctc']}"
        print(line)
    print()
    print("fun: PUMA path = eq. 4 at the identification's substeps (1 per sample rigid, the "
          "flexible fit's for a flexible result); arm path = its refinement's prediction-error cost")
    print("Y: eq. 4 (pulses^2) on the instance's arm plant at "
          + ", ".join(sorted({f"{r['log']}: {r['substeps']}" for r in rows if r['path'] == 'truth'}))
          + " RK4 steps per sample")
    flex = [r for r in rows if r.get("joints")]
    if flex:
        print()
        print(f"{'log':<25}{'path':<7}{'K2':>10}{'K3':>10}{'D2':>8}{'D3':>8}{'Jm2k2^2':>9}"
              f"{'Jm3k3^2':>9}{'b2 mrad':>9}{'b3 mrad':>9}")
        for r in flex:
            j = r["joints"]
            print(f"{r['log']:<25}{r['path']:<7}{j['K'][0]:>10.1f}{j['K'][1]:>10.1f}"
                  f"{j['D'][0]:>8.3f}{j['D'][1]:>8.3f}{j['Ia'][0]:>9.4f}{j['Ia'][1]:>9.4f}"
                  f"{1e3 * j['b'][0]:>9.3f}{1e3 * j['b'][1]:>9.3f}")
    for r in rows:
        if r["path"] != "truth" and r.get("choice"):
            print(f"{r['log']} {r['path']}: {r['choice']}")


def kernel_times(stem="puma560_paper_drill_flex", lanes=64, repeat=7):
    """ns per lane and RK4 step of each path's kernels, one thread, the same candidates.

    ``lanes`` candidates (the truth's f perturbed by 3 %, seed 0) on the log:
    the P experiment at 1 step a sample (the paper's GA objective), the
    logged-input replay at 1 step (the rigid refinement) and, with the
    drill emulator's joints, the two-mass replay at 9 steps (the flexible
    fit's); the best of ``repeat`` runs after one that compiles.
    """
    from plant.simulation.arm import reference_counts
    from plant.simulation.plants import FlexibleJoints
    from plant.simulation.replay import prediction_errors

    f, joints = truth_of(stem)  # the emulator's K, D, Jm k^2 (a flexible log's)
    log, plog = load_arm_log(DATA / f"{stem}.csv"), plant.load_log(DATA / f"{stem}.csv")
    F = f * (1 + 0.03 * np.random.default_rng(0).standard_normal((lanes, 9)))
    J = np.tile(joints["K"] + joints["D"] + joints["Ia"], (lanes, 1))
    B = np.hstack([F, J, np.zeros((lanes, 2))])
    rigid, flexible = arm_plant(log.model), arm_plant(log.model, flexible=True)
    ref = reference_counts(log.trajectory, log.rig, log.n_samples)
    two_mass = FlexibleJoints(1.0, 0.0, 1.0)  # every lane carries its joints
    cases = [
        ("P experiment, 1 step (GA)", 1,
         lambda: plant.simulate_batch(plog, F, substeps=1, workers=1, errors=False),
         lambda: simulate_arm(rigid, F, log.rig, log.trajectory, log.n_samples,
                              e_log=log.e_pulses, substeps=1, errors=False, workers=1)),
        ("replay, 1 step (rigid refinement)", 1,
         lambda: prediction_errors(plog, F, gain=0.05, substeps=1, workers=1),
         lambda: replay_arm(rigid, F, log.rig, ref, log.e_pulses, log.i_A, gain=0.05,
                            substeps=1, workers=1)),
        ("two-mass replay, 9 steps (flexible fit)", 9,
         lambda: prediction_errors(plog, F, gain=0.05, substeps=9, workers=1, plant=two_mass,
                                   plant_parameters=dict(joints=J)),
         lambda: replay_arm(flexible, B, log.rig, ref, log.e_pulses, log.i_A, gain=0.05,
                            substeps=9, workers=1)),
    ]
    out = []
    for name, steps, puma_fn, arm_fn in cases:
        row = dict(kernel=name)
        for path_name, fn in (("puma", puma_fn), ("arm", arm_fn)):
            fn()
            best = min(_timed(fn) for _ in range(repeat))
            row[path_name] = 1e9 * best / (lanes * steps * log.n_samples)
        out.append(row)
    return out


def _timed(fn):
    t = time.perf_counter()
    fn()
    return time.perf_counter() - t


def print_kernels(rows, lanes=64, repeat=7):
    print(f"\nkernels: ns per lane and RK4 step, {lanes} lanes, 1 thread, best of {repeat} "
          f"(puma560_paper_drill_flex)")
    print(f"{'kernel':42s} {'PUMA path':>10s} {'arm path':>10s} {'arm/PUMA':>9s}")
    for r in rows:
        print(f"{r['kernel']:42s} {r['puma']:10.1f} {r['arm']:10.1f} {r['arm'] / r['puma']:9.2f}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--logs", nargs="+", default=list(STEMS), choices=STEMS,
                    help="development logs (default: all three)")
    ap.add_argument("--seed", type=int, default=0, help="the PUMA path's rng (default 0)")
    ap.add_argument("--no-ctc", action="store_true", help="skip the computed-torque runs")
    ap.add_argument("--no-ga", action="store_true", help="skip the paper's GA on both paths")
    ap.add_argument("--no-kernels", action="store_true",
                    help="skip the kernels' ns per lane and RK4 step")
    ap.add_argument("--out", type=Path, help="write the rows as JSON")
    args = ap.parse_args(argv)
    compile_s = warm_up(args.logs)
    print(f"compiled the rigid kernels of both paths in {compile_s:.1f} s (not timed below)")
    t0 = time.perf_counter()
    rows, ga_rows = [], []
    for stem in args.logs:
        rows += run_log(stem, args.seed, not args.no_ctc)
        if not args.no_ga:
            ga_rows.append(ga_agreement(stem, args.seed))
    print_table(rows, not args.no_ctc)
    if ga_rows:
        print_ga(ga_rows)
    kernels = [] if args.no_kernels else kernel_times()
    if kernels:
        print_kernels(kernels)
    print(f"\ntotal {time.perf_counter() - t0:.0f} s")
    if args.out:
        args.out.write_text(json.dumps(rows + ga_rows + kernels, indent=1) + "\n")


if __name__ == "__main__":
    main()
