"""On-line payload identification under CTC: the robot picks up a tool mid-run.

The tutorial script of ``docs/tutorial_online_payload.rst``.  Along the
paper trajectory of the bundled example log (``plant.load_example()``) a
simulated rigid robot picks up a tool (default 2 kg, COM (0.1, 0.02) m in
link 3's frame, 0.01 kg m^2) at t = 1.0 s and runs under

* the paper's P controller (i = P e);
* the static CTC built from the unloaded robot's identified f (the prior);
* the adaptive CTC (:class:`ctc.AdaptiveComputedTorqueController`), which
  identifies the payload every 100 ms window with itself in the loop, lets
  its supervisor accept or refuse each estimate, and switches its model
  after the fixed latency (0.1 s, so that runs repeat).

The prior is ``identification.identify(log, rng=SEED).f`` (``--truth``
passes a truth file's ``f_vector`` instead).  Prints max |e| per joint
before the pick-up and from 0.5 s after it, the identified masses over time
the per-identification wall times and the supervisor's decisions; saves
``errors.png`` (P control on its own scale, the two CTCs on the CTC's scale,
the pick-up and the model switches labelled, the identified mass over time)
and ``results.json``.

Usage (from the repository root)::

    python examples/online_payload.py
    python examples/online_payload.py --mass 4 --t-pick 1.5
    python examples/online_payload.py --quick          # a smoke run

A bad option ends with one line ``error: ...`` and exit status 1.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import ctc  # noqa: E402
import identification  # noqa: E402
import plant  # noqa: E402


def run(args):
    """Simulate the three controllers; return the results dict."""
    log = plant.load_example()
    if args.truth:
        prior = np.asarray(json.loads(Path(args.truth).read_text())["f_vector"], dtype=float)
    else:
        opts = dict(ga_options={"n_gen": 8}) if args.quick else {}
        prior = identification.identify(log, rng=args.seed, progress=False, **opts).f
    payload = plant.Payload(args.mass, (args.xp, args.yp), args.izz)
    f_loaded = plant.add_payload(prior, payload, log.rig.a3_m)
    schedule = [(args.t_pick, f_loaded)]
    ts = log.rig.sample_time_s
    n = log.n_total if not args.quick else int(round((args.t_pick + 0.8) / ts))
    adaptive = ctc.AdaptiveComputedTorqueController.from_log(prior, log)
    controllers = {
        "P": ctc.PController.from_log(log),
        "static CTC": ctc.ComputedTorqueController.from_log(prior, log),
        "adaptive CTC": adaptive,
    }
    responses = {name: plant.simulate_closed_loop(log, prior, c, f_schedule=schedule,
                                                  n_samples=n, substeps=args.substeps)
                 for name, c in controllers.items()}
    k_pick = int(np.ceil(args.t_pick / ts))
    k_settled = min(int(np.ceil((args.t_pick + 0.5) / ts)), n - 1)
    table = {}
    for name, r in responses.items():
        table[name] = dict(max_before=np.abs(r.e_pulses[50:k_pick]).max(0).tolist(),
                           max_after_settle=np.abs(r.e_pulses[k_settled:]).max(0).tolist())
    return log, responses, adaptive, table, payload


def plot_comparison(responses, adaptive, payload, t_pick):
    """P, static CTC and adaptive CTC around a pick-up: the figure the tutorial shows.

    The CTC errors are a few pulses and P control's tens: each joint gets
    two panels, P control on its own scale above, the two CTCs on the CTC's
    scale below (integer ticks, the +-1 pulse band shaded); the pick-up and
    every model switch of the adaptive CTC are labelled; the last panel is
    the identified mass against the true one.
    """
    from matplotlib.ticker import MaxNLocator

    fig, axes = plt.subplots(5, 1, figsize=(9, 10.5), sharex=True,
                             gridspec_kw=dict(height_ratios=[1.2, 2, 1.2, 2, 1.4]))
    colours = {"P": "0.45", "static CTC": "tab:orange", "adaptive CTC": "tab:blue"}
    for j in range(2):
        ax_p, ax_c = axes[2 * j], axes[2 * j + 1]
        r = responses["P"]
        ax_p.step(r.t, r.e_pulses[:, j], where="post", lw=0.8, color=colours["P"], label="P")
        ax_p.set_ylabel(f"e{j + 2}, P\n(pulses)")
        for name in ("static CTC", "adaptive CTC"):
            r = responses[name]
            ax_c.step(r.t, r.e_pulses[:, j], where="post", lw=0.9, color=colours[name], label=name)
        ax_c.axhspan(-1, 1, color="tab:green", alpha=0.12, lw=0, label="+-1 pulse")
        ax_c.set_ylabel(f"e{j + 2}, CTC\n(pulses)")
        for a in (ax_p, ax_c):
            a.yaxis.set_major_locator(MaxNLocator(integer=True))
            a.grid(True, alpha=0.3)
    hist = [(0.0, 0.0)] + list(adaptive.payload_history)
    for a in axes:
        a.axvline(t_pick, color="k", ls=":", lw=1.0)
        for t_sw, _ in adaptive.payload_history:
            a.axvline(t_sw, color="tab:blue", ls="--", lw=0.6, alpha=0.6)
    axes[0].text(t_pick, axes[0].get_ylim()[1], f" pick-up {payload.mass_kg:g} kg", va="top",
                 fontsize="small")
    axes[1].legend(loc="upper left", fontsize="small", ncol=3)
    t_end = responses["P"].t[-1]
    axes[4].step([h[0] for h in hist] + [t_end], [h[1] for h in hist] + [hist[-1][1]],
                 where="post", color="tab:blue", label="identified (model switch: dashed)")
    axes[4].axhline(payload.mass_kg, color="k", ls=":", label=f"true {payload.mass_kg:g} kg")
    axes[4].set_ylabel("payload\nmass (kg)")
    axes[4].set_xlabel("t (s)")
    axes[4].legend(fontsize="small", loc="lower right")
    axes[4].grid(True, alpha=0.3)
    fig.suptitle(f"A {payload.mass_kg:g} kg payload picked up at {t_pick:g} s: "
                 "P control, static and adaptive computed-torque control")
    fig.tight_layout()
    return fig


def main(argv=None):
    """Command line entry point."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--truth", default=None, help="truth JSON with f_vector (skips identify)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the prior's identification")
    ap.add_argument("--mass", type=float, default=2.0, help="payload mass (kg)")
    ap.add_argument("--xp", type=float, default=0.1, help="payload COM x in link 3 (m)")
    ap.add_argument("--yp", type=float, default=0.02, help="payload COM y in link 3 (m)")
    ap.add_argument("--izz", type=float, default=0.01, help="payload inertia about its COM")
    ap.add_argument("--t-pick", type=float, default=1.0, help="pick-up time (s)")
    ap.add_argument("--substeps", type=int, default=8, help="RK4 substeps per sample")
    ap.add_argument("--quick", action="store_true", help="short run, quick prior (smoke test)")
    ap.add_argument("--out", default="out/online_payload", help="output directory")
    args = ap.parse_args(argv)
    try:
        if not (0.0 < args.mass <= 5.0):
            raise ValueError(f"--mass must be in (0, 5] kg, got {args.mass}")
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        log, responses, adaptive, table, payload = run(args)
    except (ValueError, OSError, KeyError, plant.LogError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(f"payload {payload.mass_kg} kg picked up at t = {args.t_pick} s")
    print(f"{'controller':<14s} {'max|e| before':>16s} {'max|e| from +0.5 s':>20s}")
    for name, row in table.items():
        print(f"{name:<14s} {str(row['max_before']):>16s} {str(row['max_after_settle']):>20s}")
    print("identifications (window, wall s, mass kg, supervisor's decision):")
    for rec in adaptive.identifications:
        w = rec["window_s"]
        print(f"  [{w[0]:.3f}, {w[1]:.3f}) s  {rec['wall_time_s']:.3f}  {rec['mass_kg']:.3f}"
              f"  {rec['decision']}")
    for ev in adaptive.events:
        print(f"  event at {ev['t_s']:.3f} s: {ev['kind']}: {ev['message']}")
    fig = plot_comparison(responses, adaptive, payload, args.t_pick)
    fig.savefig(out / "errors.png", dpi=110)
    (out / "results.json").write_text(json.dumps(dict(
        payload_mass_kg=payload.mass_kg, t_pick_s=args.t_pick, table=table,
        payload_history=adaptive.payload_history,
        identifications=[{**r, "window_s": list(r["window_s"])}
                         for r in adaptive.identifications]), indent=2))
    print(f"wrote {out / 'errors.png'} and {out / 'results.json'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
