"""Real rigs: a flexible, noisy log, its error spectrum, and an on-line payload.

The tutorial script of ``docs/tutorial_real_rigs.rst``.  It

1. reads the error spectrum of the flexible drill log
   (``puma560_paper_drill_flex``: 1.5 kg drill, compliant gearboxes, noisy
   currents), which shows the ~30 Hz mode and the lowered loop resonance, and
   takes the suggested low-pass cut-off (``spectrum.png``);
2. identifies f1..f9 of that log unfiltered and with the suggested cut-off;
3. identifies the *unloaded* robot on the bundled paper log (the prior);
4. cuts the window [1.0, 1.2) s out of the loaded run, saves it as a log
   whose sidecar does not know the payload (``"payload": {"mass_kg": null}``),
   loads it back and identifies the payload on-line against the prior; then
   the same for 0.4 and 0.8 s windows and the whole run, to show how the
   window length conditions the estimate.

If the truth files are next to the logs (development data), the identified
values are compared with them.  Run from the repository root::

    python examples/real_rigs.py
    python examples/real_rigs.py --data ../shared/data --skip-full   # payload part only

Figures, the prior, the window log and the results go to ``out/real_rigs/``.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np

import identification
import plant
from identification.diagnostics import error_spectrum

DRILL = "puma560_paper_drill_flex"


def parse_args(argv=None):
    """Command-line options of the example."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", type=Path,
                   default=Path(__file__).resolve().parents[2] / "shared" / "data",
                   help="directory of puma560_paper_drill_flex.csv (default ../shared/data)")
    p.add_argument("--prior-log", type=Path, default=plant.example_log_path(),
                   help="log of the unloaded robot (default: the bundled paper log)")
    p.add_argument("--window", type=float, nargs=2, default=(1.0, 1.2), metavar=("T0", "T1"))
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--skip-full", action="store_true",
                   help="skip the two full identifications of the drill log (step 2)")
    p.add_argument("--out", type=Path, default=Path("out") / "real_rigs")
    return p.parse_args(argv)


def truth_f(log_path):
    """True f from ``STEM.truth.json`` next to a log, or None (development data only)."""
    p = Path(log_path).with_suffix("").with_suffix(".truth.json")
    return np.asarray(json.loads(p.read_text())["f_vector"]) if p.is_file() else None


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
    drill_path = args.data / f"{DRILL}.csv"
    drill = plant.load_log(drill_path)
    f_drill_true = truth_f(drill_path)
    out = {}

    # 1. the error spectrum: where is the unmodelled mode, where to cut
    spec = error_spectrum(drill)
    print(spec.summary())
    spec.plot().savefig(args.out / "spectrum.png", dpi=120)
    cutoff = spec.cutoff_hz
    out["cutoff_hz"] = cutoff

    # 2. identify the flexible log with and without the filter
    if not args.skip_full:
        print(f"\nidentify {drill.name} (default method, seed {args.seed}):")
        print(f"  {'':<22s}" + " ".join(f"{'f' + str(i + 1):>9s}" for i in range(9)))
        if f_drill_true is not None:
            print_f("truth (rigid-equiv.)", f_drill_true)
        for label, lp, cons in (("unfiltered", None, False),
                                (f"low-pass {cutoff:.1f} Hz", cutoff, False),
                                ("+ eq. 3 structure", cutoff, True)):
            res = identification.identify(drill, rng=args.seed, lowpass_hz=lp, progress=False,
                                          consistent=cons)
            print_f(label, res.f, f_drill_true)
            out[f"drill_f_{label}"] = res.f

    # 3. the prior: the unloaded robot, identified on its own log
    prior_log = plant.load_log(args.prior_log)
    prior = identification.identify(prior_log, rng=args.seed, progress=False)
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
    print(f"\nwindow {window.window_s} s of {DRILL}: {window.n_samples} samples, "
          f"sidecar payload mass {window.rig.payload_mass_kg}")
    res = identification.identify(window, payload=True, prior=prior, rng=args.seed,
                                  progress=False)
    res.save_json(args.out / "payload_result.json")
    d = res.to_dict()
    print(f"  identified payload mass {d['payload_mass_kg']:.3f} kg (true 1.5 kg) "
          f"in {res.wall_time_s:.2f} s (window length {t1 - t0:.1f} s)")
    out["window_mass_kg"], out["window_wall_s"] = d["payload_mass_kg"], res.wall_time_s

    # conditioning: the same start with longer windows, and the whole run
    print("  window length -> identified mass (kg) [wall s]:")
    for length in (0.2, 0.4, 0.8):
        w = drill.window(t0, t0 + length)
        r = identification.identify(w, payload=True, prior=prior, rng=args.seed,
                                    progress=False)
        print(f"    {length:.1f} s: {r.payload['mass_kg']:.3f} [{r.wall_time_s:.2f}]")
    r = identification.identify(drill, payload=True, prior=prior, rng=args.seed, progress=False)
    print(f"    whole run ({drill.t[-1]:.2f} s): {r.payload['mass_kg']:.3f} [{r.wall_time_s:.2f}]")
    out["whole_run_mass_kg"] = r.payload["mass_kg"]
    res.plot_tracking_errors(window).savefig(args.out / "payload_window_errors.png", dpi=120)
    print(f"figures and results in {args.out}/")
    return out


if __name__ == "__main__":
    main()
