"""Real rigs: a flexible, noisy log, its error spectrum, and an on-line payload.

The tutorial script of ``docs/tutorial_real_rigs.rst``.  It

1. reads the error spectrum of the flexible drill log, the package's second
   bundled example (``plant.load_example("drill_flex")``,
   ``puma560_paper_drill_flex``: 1.5 kg drill, compliant gearboxes, noisy
   currents), which shows the ~30 Hz mode and the lowered loop resonance, and
   takes the suggested low-pass cut-off (``spectrum.png``);
2. identifies that log with the default ``identify`` (``model="auto"``: the
   two-mass flexible model is chosen on held-back samples), prints the model
   choice, the rigid-equivalent f and the joints (K, D, Jm k^2), and builds
   the computed-torque controller from the result
   (``ComputedTorqueController.from_result``), run on the two-mass robot
   (the truth's emulator constants with ``--truth``, else the identified
   ones) against the rigid CTC with the same f;
3. identifies the *unloaded* robot on the bundled paper log (the prior);
4. cuts the window [1.0, 1.2) s out of the loaded run, saves it as a log
   whose sidecar does not know the payload (``"payload": {"mass_kg": null}``),
   loads it back and identifies the payload on-line against the prior; then
   the same for 0.4 and 0.8 s windows and the whole run, to show how the
   window length conditions the estimate.

The identified mass is compared with the mass in the loaded run's sidecar
(``payload.mass_kg``: 1.5 kg), which the window's sidecar hides.  The
identified f of the drill log are compared with a truth only if one is given
with ``--truth`` (a ``STEM.truth.json`` with ``f_vector``, e.g. the emulated
log's ``tests/data/puma560_paper_drill_flex.truth.json`` in a clone of the
repository); the example needs nothing but the installed library.  Run from
the repository root::

    python examples/real_rigs.py                 # about 6 s on 2 cores
    python examples/real_rigs.py --skip-full     # spectrum and payload part only
    python examples/real_rigs.py --truth tests/data/puma560_paper_drill_flex.truth.json
    python examples/real_rigs.py --quick         # a smoke run (seconds)

Figures, the prior, the window log and ``results.json`` go to
``out/real_rigs/``.  A bad log, truth file or option ends with one line
``error: ...`` and exit status 1.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import warnings
from pathlib import Path

import numpy as np

import identification
import plant
from identification.diagnostics import error_spectrum



def parse_args(argv=None):
    """Command-line options of the example."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--log", type=Path, default=plant.example_log_path("drill_flex"),
                   help="the loaded, flexible run (default: the bundled drill/flex example)")
    p.add_argument("--truth", type=Path,
                   help="truth JSON (f_vector) of that run, to print the errors of f (optional)")
    p.add_argument("--prior-log", type=Path, default=plant.example_log_path(),
                   help="log of the unloaded robot (default: the bundled paper log)")
    p.add_argument("--window", type=float, nargs=2, default=(1.0, 1.2), metavar=("T0", "T1"))
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--skip-full", action="store_true",
                   help="skip the identification of the drill log and its CTC (step 2)")
    p.add_argument("--quick", action="store_true",
                   help="smoke run: skip step 2, 2 GA generations for the prior, one window")
    p.add_argument("--out", type=Path, default=Path("out") / "real_rigs")
    args = p.parse_args(argv)
    if not args.window[0] < args.window[1]:
        p.error(f"--window needs T0 < T1, got {args.window[0]} {args.window[1]}")
    return args


def truth_f(path):
    """``f_vector`` of a truth file (``STEM.truth.json``), or a one-line ValueError."""
    path = Path(path)
    try:
        f = np.asarray(json.loads(path.read_text())["f_vector"], dtype=float)
    except FileNotFoundError:
        raise ValueError(f"{path}: truth file not found") from None
    except (json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{path}: not a truth file with an 'f_vector' "
                         f"({type(exc).__name__}: {exc})") from None
    if f.shape != (9,):
        raise ValueError(f"{path}: 'f_vector' must have 9 values, got {f.size}")
    return f


def print_f(label, f, f_true=None):
    """One line of f1..f9 (and their relative errors in % if the truth is known)."""
    print(f"  {label:<22s}" + " ".join(f"{v:9.4f}" for v in f))
    if f_true is not None:
        err = 100 * (np.asarray(f) - f_true) / np.abs(f_true)
        print(f"  {'  error (%)':<22s}" + " ".join(f"{e:+9.2f}" for e in err))


def main(argv=None):
    """Run the tutorial; returns a dict of the results."""
    args = parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    drill = plant.load_log(args.log)
    f_drill_true = truth_f(args.truth) if args.truth is not None else None
    mass_sidecar = drill.rig.payload_mass_kg
    quick = dict(ga_options={"n_gen": 2}, refine_options={"n_starts": 1}) if args.quick else {}
    out = {"log": drill.name, "truth": None if args.truth is None else str(args.truth)}

    # 1. the error spectrum: where is the unmodelled mode, where to cut
    spec = error_spectrum(drill)
    print(spec.summary())
    spec.plot().savefig(args.out / "spectrum.png", dpi=120)
    cutoff = spec.cutoff_hz
    out["cutoff_hz"] = cutoff

    # 2. identify the flexible log (model="auto": the flexible model is chosen on held-back
    # samples) and build the computed-torque controller from the result
    if not (args.skip_full or args.quick):
        print(f"\nidentify {drill.name} (default: model auto, seed {args.seed}):")
        res = identification.identify(drill, rng=args.seed, progress=False)
        res.save_json(args.out / "drill_result.json")
        print(f"  model {res.model}: {(res.model_choice or {}).get('reason', '')}")
        print(f"  {'':<22s}" + " ".join(f"{'f' + str(i + 1):>9s}" for i in range(9)))
        if f_drill_true is not None:
            print_f("truth (rigid-equiv.)", f_drill_true)
        print_f("identified", res.f, f_drill_true)
        if res.model == "flexible":
            print(f"  K {np.round(res.joint_stiffness_Nm_per_rad, 1).tolist()} N m/rad, "
                  f"D {np.round(res.joint_damping_Nms_per_rad, 3).tolist()} N m s/rad, "
                  f"Jm k^2 {np.round(res.motor_inertia_reflected_kgm2, 4).tolist()} kg m^2")
        out.update(drill_model=res.model, drill_f=[float(v) for v in res.f],
                   drill_K=res.joint_stiffness_Nm_per_rad, drill_D=res.joint_damping_Nms_per_rad,
                   drill_Jk2=res.motor_inertia_reflected_kgm2)
        from ctc import ComputedTorqueController
        from ctc.protocol import current_per_pulse

        ctl = ComputedTorqueController.from_result(args.out / "drill_result.json", drill)
        print(f"  controller: {ctl}")
        if res.model == "flexible":
            # the robust design's scenario check (ctc.flexible.robustness_check): the
            # first design's report (robust="check") and the chosen one's
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # the first design may not hold the set
                first = ComputedTorqueController.from_result(args.out / "drill_result.json",
                                                             drill, robust="check")
            for name, c in (("first design", first), ("chosen design", ctl)):
                rep = c.robustness
                rows = ", ".join(f"{sc['name']} {sc['max_abs_e'][0]} / {sc['max_abs_e'][1]}"
                                 for sc in rep["scenarios"])
                bw = " / ".join(f"{v:.0f}" for v in c.gains.bandwidth_hz) + (
                    " Hz, integral action" if np.any(c.gains.Ki) else " Hz")
                # the current the law commands for one pulse of quantisation
                step = current_per_pulse(c, drill)
                print(f"  {name} ({bw}): {rows} pulses; "
                      f"{step[0]:.2f} / {step[1]:.2f} A per pulse")
                out[f"robustness_{name.split()[0]}"] = dict(rep, current_per_pulse_A=step.tolist())
            # the robot: the truth's emulator constants if given, else the identified ones
            robot_f, robot = res.f, None
            if args.truth is not None:
                tr = json.loads(Path(args.truth).read_text())
                v = (tr.get("emulator") or {}).get("variant") or {}
                if "flex_stiffness" in v:
                    robot_f = f_drill_true
                    robot = plant.FlexibleJoints(tuple(v["flex_stiffness"]),
                                                 tuple(v["flex_damping"]), 200e-6)
            if robot is None:
                jk = np.asarray(res.motor_inertia_reflected_kgm2)
                robot = plant.FlexibleJoints(res.joint_stiffness_Nm_per_rad,
                                             res.joint_damping_Nms_per_rad,
                                             jk / np.asarray(drill.rig.gear_ratio) ** 2)
            for name, c in (("rigid CTC, same f", ComputedTorqueController.from_log(res.f, drill)),
                            ("CTC from_result", ctl)):
                run = plant.simulate_closed_loop(drill, robot_f, c, flexible=robot)
                e = np.abs(run.e_pulses[run.t >= 0.1]).max(axis=0)
                print(f"  {name:<20s} on the two-mass robot: max |e| after 0.1 s "
                      f"{int(e[0])} / {int(e[1])} pulses")
                out[f"ctc_max_e_{name}"] = [int(v) for v in e]

    # 3. the prior: the unloaded robot, identified on its own log
    prior_log = plant.load_log(args.prior_log)
    prior = identification.identify(prior_log, rng=args.seed, progress=False, **quick)
    prior.save_json(args.out / "prior.json")
    print(f"\nprior: identified on {prior_log.name} in {prior.wall_time_s:.1f} s "
          f"-> {args.out / 'prior.json'}")

    # 4. on-line payload identification from a window cut from the loaded run;
    # the window's sidecar does not know the payload (mass_kg: null)
    t0, t1 = args.window
    window = drill.window(t0, t1)
    window = window.replace(rig=dataclasses.replace(window.rig, payload_mass_kg=None))
    csv_path = window.save(args.out / f"drill_window_{t0 * 1e3:.0f}_{t1 * 1e3:.0f}ms")
    window = plant.load_log(csv_path)
    print(f"\nwindow {window.window_s} s of {drill.name}: {window.n_samples} samples, "
          f"sidecar payload mass {window.rig.payload_mass_kg}")
    res = identification.identify(window, payload=True, prior=prior, rng=args.seed,
                                  progress=False)
    res.save_json(args.out / "payload_result.json")
    d = res.to_dict()
    print(f"  identified payload mass {d['payload_mass_kg']:.3f} kg (the run's sidecar: "
          f"{mass_sidecar} kg) "
          f"in {res.wall_time_s:.2f} s (window length {t1 - t0:.1f} s)")
    out["window_s"] = [t0, t1]
    out["sidecar_mass_kg"] = mass_sidecar
    out["window_mass_kg"], out["window_wall_s"] = d["payload_mass_kg"], res.wall_time_s

    # conditioning: the same start with longer windows, and the whole run
    if not args.quick:
        print("  window length -> identified mass (kg) [wall s]:")
        out["mass_by_window_length_kg"] = {}
        for length in (0.2, 0.4, 0.8):
            w = drill.window(t0, t0 + length)
            r = identification.identify(w, payload=True, prior=prior, rng=args.seed,
                                        progress=False)
            print(f"    {length:.1f} s: {r.payload['mass_kg']:.3f} [{r.wall_time_s:.2f}]")
            out["mass_by_window_length_kg"][f"{length:.1f}"] = r.payload["mass_kg"]
        r = identification.identify(drill, payload=True, prior=prior, rng=args.seed,
                                    progress=False)
        print(f"    whole run ({drill.t[-1]:.2f} s): {r.payload['mass_kg']:.3f} "
              f"[{r.wall_time_s:.2f}]")
        out["whole_run_mass_kg"] = r.payload["mass_kg"]
    res.plot_tracking_errors(window).savefig(args.out / "payload_window_errors.png", dpi=120)
    (args.out / "results.json").write_text(json.dumps(out, indent=2))
    print(f"figures and results in {args.out}/")
    return out


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
