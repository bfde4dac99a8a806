"""P control vs computed-torque control (CTC) on the paper trajectory.

Runs, on the simulated rigid robot with the true f (the truth file of the
development log; examples may read it), along the paper trajectory of the
bundled example log ``plant/data/puma560_paper_rigid.csv``:

* the paper's P controller (i = P e);
* CTC built from the f identified on the log (``identification.identify(log,
  rng=SEED)``; ``--f-identified`` passes a ready f instead, e.g. when the
  identification package is not installed);
* CTC built from the true f;
* CTC built from the centre of the sidecar's search ranges (no identification);

prints a table of max |e| (whole run and after 50 ms) and RMS |e| per joint,
saves the tracking errors (pulses) and the currents as PNG, and sweeps the
robustness: CTC (true-f model) when the robot's f differs from the
controller's by ±0.5, 5, 10, 20 % (all parameters scaled together, and each
parameter by ±delta with random signs).  With the drill/flex development log
and its truth file it also reports P and CTC on the two-mass flexible robot
(:class:`plant.closed_loop.FlexibleJoints`, constants of the truth file's
``emulator`` section).

Usage (from the repository root)::

    python examples/ctc_vs_p.py                       # identifies f (about 30 s)
    python examples/ctc_vs_p.py --f-identified 0.9385,0.3618,0.01087,-0.3860,0.02538,-0.8942,4.4358,-0.1040,3.7952
    python examples/ctc_vs_p.py --out out/ctc --truth ../shared/data/puma560_paper_rigid.truth.json

Outputs go to ``--out`` (default ``out/ctc_vs_p``): ``errors.png``,
``currents.png``, ``robustness.png``, ``flex.png`` and ``results.json``.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

import matplotlib

matplotlib.use("Agg")
from matplotlib.figure import Figure  # noqa: E402

from plant.closed_loop import FlexibleJoints, simulate_closed_loop  # noqa: E402
from plant.log import example_log_path, load_log  # noqa: E402
from plant.model import is_positive_definite  # noqa: E402
from ctc import ComputedTorqueController, PController  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared" / "data"
DELTAS = (-0.20, -0.10, -0.05, -0.005, 0.005, 0.05, 0.10, 0.20)
AFTER_S = 0.05


def _truth_path(log_path: Path, given: str | None) -> Path | None:
    if given:
        return Path(given)
    stem = log_path.name[: -len(".csv")] if log_path.name.endswith(".csv") else log_path.stem
    for d in (log_path.parent, SHARED):
        p = d / f"{stem}.truth.json"
        if p.is_file():
            return p
    return None


def _parse_f(text: str) -> np.ndarray:
    f = np.array([float(v) for v in text.replace(" ", "").split(",") if v])
    if f.shape != (9,):
        raise SystemExit(f"--f-identified needs 9 comma-separated numbers, got {f.size}")
    return f


def identified_f(log, args):
    """f from the command line, else from identification.identify(log, rng=seed)."""
    if args.f_identified:
        return _parse_f(args.f_identified), "command line"
    try:
        from identification import identify
    except ImportError as exc:  # the identification package is not available
        raise SystemExit(
            f"identification is not importable ({exc}); pass --f-identified f1,...,f9"
        ) from None
    t0 = time.perf_counter()
    res = identify(log, rng=args.seed, progress=False)
    return np.asarray(res.f, dtype=float), f"identify(log, rng={args.seed}) in {time.perf_counter() - t0:.1f} s"


def row(name, r):
    m, m50, rms = r.max_abs_error(), r.max_abs_error(AFTER_S), r.rms_error()
    imax = np.max(np.abs(r.i_A), axis=0)
    return dict(name=name, max_abs=m.tolist(), max_abs_after_50ms=m50.tolist(),
                rms=rms.round(4).tolist(), max_abs_current_A=imax.round(3).tolist(),
                within_1_after_50ms=r.within(1, AFTER_S), success=r.success)


def print_table(rows, title):
    print(f"\n{title}")
    print(f"{'controller':<34} {'max|e| run':>11} {'max|e| >50ms':>13} {'RMS |e|':>15} {'max|i| (A)':>13}")
    for d in rows:
        print(f"{d['name']:<34} {d['max_abs'][0]:>5}/{d['max_abs'][1]:<5} "
              f"{d['max_abs_after_50ms'][0]:>6}/{d['max_abs_after_50ms'][1]:<6} "
              f"{d['rms'][0]:>7.3f}/{d['rms'][1]:<7.3f} "
              f"{d['max_abs_current_A'][0]:>6.2f}/{d['max_abs_current_A'][1]:<6.2f}")


def plot_errors(responses, path):
    fig = Figure(figsize=(11, 2.3 * len(responses)), layout="constrained")
    axes = fig.subplots(len(responses), 2, sharex=True, squeeze=False)
    for i, (name, r) in enumerate(responses):
        for j in range(2):
            ax = axes[i, j]
            ax.step(r.t, r.e_pulses[:, j], where="post", lw=0.7)
            ax.set_title(f"{name}, joint {j + 2}: max |e| = {r.max_abs_error()[j]} pulses", fontsize=9)
            ax.set_ylabel("e (pulses)")
            ax.grid(True, alpha=0.3)
    for j in range(2):
        axes[-1, j].set_xlabel("t (s)")
    fig.suptitle("Tracking errors on the paper trajectory (simulated rigid robot, true f)")
    fig.savefig(path, dpi=110)


def plot_currents(responses, path):
    fig = Figure(figsize=(11, 4), layout="constrained")
    axes = fig.subplots(1, 2, sharex=True)
    for name, r in responses:
        for j in range(2):
            axes[j].plot(r.t, r.i_A[:, j], lw=0.8, label=name)
    for j in range(2):
        axes[j].set_title(f"joint {j + 2}")
        axes[j].set_xlabel("t (s)")
        axes[j].set_ylabel("motor current (A)")
        axes[j].grid(True, alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.savefig(path, dpi=110)


def robustness(log, f_model, substeps, seed, n_draws):
    """Max |e| after 50 ms of CTC(f_model) on robots f_model*(1+delta) (uniform and random-sign)."""
    ctl = ComputedTorqueController.from_log(f_model, log)
    rng = np.random.default_rng(seed)
    signs = rng.choice([-1.0, 1.0], size=(n_draws, 9))
    out = []
    for d in DELTAS:
        r = simulate_closed_loop(log, f_model * (1 + d), ctl, substeps=substeps)
        worst = np.zeros(2, dtype=int)
        worst_rms = np.zeros(2)
        n_ok = 0
        for s in signs:
            fr = f_model * (1 + d * s)
            if not is_positive_definite(fr):
                continue
            rr = simulate_closed_loop(log, fr, ctl, substeps=substeps)
            worst = np.maximum(worst, rr.max_abs_error(AFTER_S))
            worst_rms = np.maximum(worst_rms, rr.rms_error())
            n_ok += 1
        out.append(dict(delta=d, uniform_max_abs_after_50ms=r.max_abs_error(AFTER_S).tolist(),
                        uniform_rms=r.rms_error().round(3).tolist(),
                        random_worst_max_abs_after_50ms=worst.tolist(),
                        random_worst_rms=worst_rms.round(3).tolist(), random_draws=n_ok))
    return out


def plot_robustness(rob, path):
    fig = Figure(figsize=(8, 4), layout="constrained")
    ax = fig.subplots()
    d = np.array([x["delta"] for x in rob]) * 100
    u = np.array([x["uniform_max_abs_after_50ms"] for x in rob])
    w = np.array([x["random_worst_max_abs_after_50ms"] for x in rob])
    for j, c in enumerate(("C0", "C1")):
        off = 0.04 * (2 * j - 1)  # small vertical offset so equal values stay visible
        ax.plot(d, u[:, j] + off, "o-", color=c, label=f"joint {j + 2}, all f scaled")
        ax.plot(d, w[:, j] + off, "s--", color=c, mfc="none", label=f"joint {j + 2}, random signs (worst)")
    ax.axhline(1, color="k", lw=0.8, ls=":")
    ax.set_xlabel("robot f relative to the controller's model (%)")
    ax.set_ylabel("max |e| after 50 ms (pulses)")
    ax.set_title("CTC robustness to model error")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.savefig(path, dpi=110)


def flexible_section(args, substeps):
    drill = Path(args.drill_log) if args.drill_log else SHARED / "puma560_paper_drill_flex.csv"
    tpath = drill.with_name(drill.name.replace(".csv", ".truth.json"))
    if not (drill.is_file() and tpath.is_file()):
        print(f"\n(flexible robot skipped: {drill} or its truth file not found)")
        return None, []
    log = load_log(drill)
    tr = json.loads(tpath.read_text())
    f = np.array(tr["f_vector"])
    v = tr["emulator"]["variant"]
    flex = FlexibleJoints(v["flex_stiffness"], v["flex_damping"], 200e-6)
    runs = [("P (paper)", PController.from_log(log))]
    for bw in (None, 15.0):
        kw = {} if bw is None else dict(bandwidth_hz=bw)
        ctl = ComputedTorqueController.from_log(f, log, **kw)
        runs.append((f"CTC true f, {ctl.gains.bandwidth_hz[0]:.1f} Hz", ctl))
    rows, resp = [], []
    for name, ctl in runs:
        r = simulate_closed_loop(log, f, ctl, flexible=flex, substeps=substeps, label=name)
        rows.append(row(name, r))
        resp.append((name, r))
    print_table(rows, f"Flexible joints + 1.5 kg drill ({drill.name}; robot = two-mass model, "
                      "controller = rigid model with the rigid-equivalent f)")
    return rows, resp


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--log", default=str(example_log_path()), help="log CSV (default: bundled example)")
    ap.add_argument("--truth", default=None, help="truth JSON with f_vector (default: next to the log or ../shared/data)")
    ap.add_argument("--f-identified", default=None, help="identified f1..f9, comma-separated (skips identify)")
    ap.add_argument("--seed", type=int, default=0, help="seed of identify and of the random-sign sweep")
    ap.add_argument("--substeps", type=int, default=32, help="RK4 substeps per sample")
    ap.add_argument("--draws", type=int, default=5, help="random-sign draws per delta in the sweep")
    ap.add_argument("--drill-log", default=None, help="drill/flex log CSV for the flexible-robot section")
    ap.add_argument("--no-flex", action="store_true", help="skip the flexible-robot section")
    ap.add_argument("--out", default="out/ctc_vs_p", help="output directory")
    args = ap.parse_args(argv)

    log_path = Path(args.log)
    log = load_log(log_path)
    tpath = _truth_path(log_path, args.truth)
    if tpath is None:
        raise SystemExit("no truth file found for the simulated robot; pass --truth PATH")
    f_true = np.array(json.loads(tpath.read_text())["f_vector"])
    f_id, source = identified_f(log, args)
    f_centre = log.rig.bounds.mean(axis=1)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    print(f"log {log.name}: {log.n_samples} samples, Ts = {log.rig.sample_time_s * 1e3:.1f} ms")
    print(f"identified f ({source}):")
    print("  " + ", ".join(f"{v:.6g}" for v in f_id))
    print("  relative error vs truth: " + ", ".join(f"{v:+.2e}" for v in (f_id - f_true) / np.abs(f_true)))

    controllers = [
        ("P (paper)", PController.from_log(log)),
        ("CTC, identified f", ComputedTorqueController.from_log(f_id, log)),
        ("CTC, true f", ComputedTorqueController.from_log(f_true, log)),
        ("CTC, centre of search ranges", ComputedTorqueController.from_log(f_centre, log)),
    ]
    print("\n" + controllers[2][1].gains.report())
    rows, responses = [], []
    for name, ctl in controllers:
        r = simulate_closed_loop(log, f_true, ctl, substeps=args.substeps, label=name)
        rows.append(row(name, r))
        responses.append((name, r))
    print_table(rows, "Rigid robot (true f), paper trajectory; pulses (joint 2 / joint 3)")
    for scale in (0.995, 1.005):
        r = simulate_closed_loop(log, f_true * scale, controllers[1][1], substeps=args.substeps)
        print(f"CTC (identified f) on a robot with f x {scale}: max |e| after 50 ms = "
              f"{r.max_abs_error(AFTER_S).tolist()}, whole run {r.max_abs_error().tolist()}")
    plot_errors(responses, out / "errors.png")
    plot_currents(responses, out / "currents.png")

    rob = robustness(log, f_true, args.substeps, args.seed, args.draws)
    print("\nRobustness: CTC (true-f model) on robots whose f differs by delta (max |e| after 50 ms, j2/j3)")
    print(f"{'delta':>7} {'all f scaled':>13} {'RMS':>13} {'random signs (worst)':>21}")
    for x in rob:
        u, w = x["uniform_max_abs_after_50ms"], x["random_worst_max_abs_after_50ms"]
        print(f"{x['delta'] * 100:>+6.1f}% {u[0]:>6}/{u[1]:<6} {x['uniform_rms'][0]:>6.2f}/{x['uniform_rms'][1]:<6.2f} "
              f"{w[0]:>10}/{w[1]:<10} ({x['random_draws']} draws)")
    plot_robustness(rob, out / "robustness.png")

    flex_rows = None
    if not args.no_flex:
        flex_rows, flex_resp = flexible_section(args, args.substeps)
        if flex_resp:
            plot_errors(flex_resp, out / "flex.png")

    results = dict(log=log.name, f_identified=f_id.tolist(), f_source=source, f_true=f_true.tolist(),
                   f_centre=f_centre.tolist(), rigid=rows, robustness=rob, flexible=flex_rows,
                   gains=dict(Kp=controllers[2][1].gains.Kp.tolist(), Kv=controllers[2][1].gains.Kv.tolist()))
    (out / "results.json").write_text(json.dumps(results, indent=2))
    print(f"\nfigures and results.json written to {out}/")
    return 0


if __name__ == "__main__":
    sys.exit(main())
