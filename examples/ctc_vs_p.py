"""P control vs computed-torque control (CTC) on the paper trajectory.

The tutorial script of ``docs/tutorial_ctc.rst``.  Along the paper trajectory
of the bundled example log (``plant.load_example()``,
``plant/data/puma560_paper_rigid.csv``) it runs, on a simulated rigid robot,

* the paper's P controller (i = P e);
* CTC built from the f identified on the log (``identification.identify(log,
  rng=SEED)``; ``--f-identified`` passes a ready f instead);
* CTC built from the true f, if a truth file is given (``--truth``);
* CTC built from the centre of the sidecar's search ranges (no identification);

prints a table of max |e| (whole run and after 50 ms) and RMS |e| per joint,
saves the tracking errors (pulses) and the currents as PNG, and sweeps the
robustness: CTC on robots whose f differs from the controller's model by
±0.5, 5, 10, 20 % (all parameters scaled together, and each parameter by
±delta with random signs).

**Which robot.**  A user's log comes without the true f, so by default the
simulated robot *is* the identified model (its f from ``identify``).  With
``--truth STEM.truth.json`` (a file with ``f_vector``, such as the emulated
development log's ``tests/data/puma560_paper_rigid.truth.json`` in a clone of
the repository) the robot is the true one instead, and the table gains the
row "CTC, true f"; the robustness sweep is centred on the robot's f.

**Flexible robot.**  It also runs P and CTC on a two-mass flexible robot
(:class:`plant.simulation.closed_loop.FlexibleJoints`) along the bundled drill/flex
example (``plant.load_example("drill_flex")``: 1.5 kg drill, compliant
gearboxes).  The spring constants are not in a log's sidecar: the defaults
of ``--flex-ks``, ``--flex-ds``, ``--flex-jm`` are the constants the
emulated log was made with (its truth file's ``emulator`` section).  The
robot's rigid-equivalent f is identified on the drill log (suggested
low-pass, ``consistent=True``), or read from ``--drill-truth`` (which also
supplies the spring constants).  ``--no-flex`` skips this part.

Usage (from the repository root)::

    python examples/ctc_vs_p.py                       # identifies f (about 8 s)
    python examples/ctc_vs_p.py --truth tests/data/puma560_paper_rigid.truth.json \
        --drill-truth tests/data/puma560_paper_drill_flex.truth.json
    python examples/ctc_vs_p.py --f-identified 0.9385,0.3618,0.01087,-0.3860,0.02538,-0.8942,4.4358,-0.1040,3.7952
    python examples/ctc_vs_p.py --quick               # a smoke run (seconds)

Outputs go to ``--out`` (default ``out/ctc_vs_p``): ``errors.png``,
``currents.png``, ``robustness.png``, ``flex.png`` and ``results.json``.  A
bad log, truth file or option ends with one line ``error: ...`` and exit
status 1.
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

from plant import LogError  # noqa: E402
from plant.simulation.closed_loop import FlexibleJoints, simulate_closed_loop  # noqa: E402
from plant.logs.log import example_log_path, load_log  # noqa: E402
from plant.robot.model import is_positive_definite  # noqa: E402
from ctc import ComputedTorqueController, PController  # noqa: E402

DELTAS = (-0.20, -0.10, -0.05, -0.005, 0.005, 0.05, 0.10, 0.20)
AFTER_S = 0.05


#: Spring stiffness (N m/rad), damping (N m s/rad) and motor inertia (kg m^2)
#: of the emulated drill/flex log (its truth file's ``emulator`` section).
FLEX_KS = (30000.0, 6000.0)
FLEX_DS = (4.0, 0.4)
FLEX_JM = 200e-6


def _floats(text: str, n: int, what: str) -> np.ndarray:
    """``n`` comma-separated finite numbers, or a one-line ValueError."""
    try:
        v = np.array([float(x) for x in text.replace(" ", "").split(",") if x])
    except ValueError:
        raise ValueError(f"{what} needs {n} comma-separated numbers, got {text!r}") from None
    if v.shape != (n,) or not np.all(np.isfinite(v)):
        raise ValueError(f"{what} needs {n} comma-separated finite numbers, got {text!r}")
    return v


def _parse_f(text: str) -> np.ndarray:
    return _floats(text, 9, "--f-identified")


def read_truth(path) -> dict:
    """A truth file (``STEM.truth.json``): its dict, with ``f_vector`` checked."""
    path = Path(path)
    try:
        d = json.loads(path.read_text())
        f = np.asarray(d["f_vector"], dtype=float)
    except FileNotFoundError:
        raise ValueError(f"{path}: truth file not found") from None
    except (json.JSONDecodeError, KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{path}: not a truth file with an 'f_vector' of 9 numbers "
                         f"({type(exc).__name__}: {exc})") from None
    if f.shape != (9,) or not np.all(np.isfinite(f)):
        raise ValueError(f"{path}: 'f_vector' must be 9 finite numbers")
    d["f_vector"] = f
    return d


def _quick_options(args):
    """identify() keyword arguments of the smoke-run settings (``--quick``)."""
    if not args.quick:
        return {}
    return dict(ga_options={"n_gen": 2}, refine_options={"n_starts": 1})


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
    res = identify(log, rng=args.seed, progress=False, **_quick_options(args))
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


def plot_errors(responses, path, robot="simulated rigid robot"):
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
    fig.suptitle(f"Tracking errors on the paper trajectory ({robot})")
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


def robustness(log, f_model, substeps, seed, n_draws, deltas=DELTAS):
    """Max |e| after 50 ms of CTC(f_model) on robots f_model*(1+delta) (uniform and random-sign)."""
    ctl = ComputedTorqueController.from_log(f_model, log)
    rng = np.random.default_rng(seed)
    signs = rng.choice([-1.0, 1.0], size=(n_draws, 9))
    out = []
    for d in deltas:
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
    """P and CTC on the two-mass flexible robot along the drill/flex log."""
    drill = load_log(args.drill_log)
    if args.drill_truth:
        tr = read_truth(args.drill_truth)
        f = tr["f_vector"]
        try:
            v = tr["emulator"]["variant"]
            flex = FlexibleJoints(tuple(v["flex_stiffness"]), tuple(v["flex_damping"]), FLEX_JM)
        except (KeyError, TypeError):
            raise ValueError(f"{args.drill_truth}: no emulator.variant.flex_stiffness / "
                             "flex_damping") from None
        source = f"true rigid-equivalent f and spring constants from {args.drill_truth}"
    else:
        from identification import identify
        from identification.diagnostics import suggest_lowpass

        cutoff = suggest_lowpass(drill)
        res = identify(drill, rng=args.seed, progress=False, lowpass_hz=cutoff, consistent=True,
                       **_quick_options(args))
        f = np.asarray(res.f, dtype=float)
        flex = FlexibleJoints(tuple(_floats(args.flex_ks, 2, "--flex-ks")),
                              tuple(_floats(args.flex_ds, 2, "--flex-ds")), float(args.flex_jm))
        lp = "unfiltered" if cutoff is None else f"low-pass {cutoff:.1f} Hz"
        source = (f"f identified on {drill.name} ({lp}, consistent=True), "
                  f"Ks = {args.flex_ks}, Ds = {args.flex_ds}, Jm = {args.flex_jm}")
    print(f"\nflexible robot: {source}")
    runs = [("P (paper)", PController.from_log(drill))]
    for bw in (None, 15.0):
        kw = {} if bw is None else dict(bandwidth_hz=bw)
        ctl = ComputedTorqueController.from_log(f, drill, **kw)
        runs.append((f"CTC, {ctl.gains.bandwidth_hz[0]:.1f} Hz", ctl))
    rows, resp = [], []
    for name, ctl in runs:
        r = simulate_closed_loop(drill, f, ctl, flexible=flex, substeps=substeps, label=name)
        rows.append(row(name, r))
        resp.append((name, r))
    print_table(rows, f"Flexible joints + drill ({drill.name}; robot = two-mass model, "
                      "controller = rigid model with the rigid-equivalent f)")
    return dict(robot=source, f=f.tolist(), rows=rows), resp


def main(argv=None):
    """Run the comparison; returns 0 (the results are in ``OUT/results.json``)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--log", default=str(example_log_path()), help="log CSV (default: bundled example)")
    ap.add_argument("--truth", default=None,
                    help="truth JSON with f_vector: simulate the true robot (default: the identified f)")
    ap.add_argument("--f-identified", default=None, help="identified f1..f9, comma-separated (skips identify)")
    ap.add_argument("--seed", type=int, default=0, help="seed of identify and of the random-sign sweep")
    ap.add_argument("--substeps", type=int, default=32, help="RK4 substeps per sample")
    ap.add_argument("--draws", type=int, default=5, help="random-sign draws per delta in the sweep")
    ap.add_argument("--drill-log", default=str(example_log_path("drill_flex")),
                    help="drill/flex log CSV of the flexible-robot section (default: bundled example)")
    ap.add_argument("--drill-truth", default=None,
                    help="truth JSON of the drill log: its f_vector and emulator spring constants")
    ap.add_argument("--flex-ks", default=",".join(f"{v:g}" for v in FLEX_KS),
                    help="spring stiffness Ks of joints 2,3 (N m/rad; default: the emulator's)")
    ap.add_argument("--flex-ds", default=",".join(f"{v:g}" for v in FLEX_DS),
                    help="spring damping Ds of joints 2,3 (N m s/rad; default: the emulator's)")
    ap.add_argument("--flex-jm", type=float, default=FLEX_JM, help="motor inertia Jm (kg m^2)")
    ap.add_argument("--no-flex", action="store_true", help="skip the flexible-robot section")
    ap.add_argument("--quick", action="store_true",
                    help="smoke run: 2 GA generations, 8 substeps, 1 draw, deltas +-5 %%")
    ap.add_argument("--out", default="out/ctc_vs_p", help="output directory")
    args = ap.parse_args(argv)
    if args.substeps < 1 or args.draws < 0:
        ap.error("--substeps must be >= 1 and --draws >= 0")
    substeps = min(args.substeps, 8) if args.quick else args.substeps
    draws = min(args.draws, 1) if args.quick else args.draws
    deltas = (-0.05, 0.05) if args.quick else DELTAS

    log_path = Path(args.log)
    log = load_log(log_path)
    truth = read_truth(args.truth) if args.truth else None
    f_id, source = identified_f(log, args)
    if truth is not None:
        f_robot, robot = truth["f_vector"], f"true f from {args.truth}"
    else:
        f_robot, robot = f_id, "the identified f"
    f_centre = log.rig.bounds.mean(axis=1)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    print(f"log {log.name}: {log.n_samples} samples, Ts = {log.rig.sample_time_s * 1e3:.1f} ms")
    print(f"identified f ({source}):")
    print("  " + ", ".join(f"{v:.6g}" for v in f_id))
    if truth is not None:
        print("  relative error vs truth: "
              + ", ".join(f"{v:+.2e}" for v in (f_id - f_robot) / np.abs(f_robot)))
    print(f"simulated robot: {robot}")

    controllers = [
        ("P (paper)", PController.from_log(log)),
        ("CTC, identified f", ComputedTorqueController.from_log(f_id, log)),
    ]
    if truth is not None:
        controllers.append(("CTC, true f", ComputedTorqueController.from_log(f_robot, log)))
    controllers.append(("CTC, centre of search ranges", ComputedTorqueController.from_log(f_centre, log)))
    print("\n" + controllers[1][1].gains.report())
    rows, responses = [], []
    for name, ctl in controllers:
        r = simulate_closed_loop(log, f_robot, ctl, substeps=substeps, label=name)
        rows.append(row(name, r))
        responses.append((name, r))
    print_table(rows, f"Rigid robot ({robot}), paper trajectory; pulses (joint 2 / joint 3)")
    for scale in (0.995, 1.005):
        r = simulate_closed_loop(log, f_robot * scale, controllers[1][1], substeps=substeps)
        print(f"CTC (identified f) on a robot with f x {scale}: max |e| after 50 ms = "
              f"{r.max_abs_error(AFTER_S).tolist()}, whole run {r.max_abs_error().tolist()}")
    plot_errors(responses, out / "errors.png", robot=f"simulated rigid robot, {robot}")
    plot_currents(responses, out / "currents.png")

    rob = robustness(log, f_robot, substeps, args.seed, draws, deltas)
    print("\nRobustness: CTC (model = robot's f) on robots whose f differs by delta "
          "(max |e| after 50 ms, j2/j3)")
    print(f"{'delta':>7} {'all f scaled':>13} {'RMS':>13} {'random signs (worst)':>21}")
    for x in rob:
        u, w = x["uniform_max_abs_after_50ms"], x["random_worst_max_abs_after_50ms"]
        print(f"{x['delta'] * 100:>+6.1f}% {u[0]:>6}/{u[1]:<6} {x['uniform_rms'][0]:>6.2f}/{x['uniform_rms'][1]:<6.2f} "
              f"{w[0]:>10}/{w[1]:<10} ({x['random_draws']} draws)")
    plot_robustness(rob, out / "robustness.png")

    flex = None
    if not args.no_flex:
        flex, flex_resp = flexible_section(args, substeps)
        plot_errors(flex_resp, out / "flex.png", robot="two-mass flexible robot with the drill")

    gains = controllers[1][1].gains
    results = dict(log=log.name, f_identified=f_id.tolist(), f_source=source,
                   robot=robot, f_robot=np.asarray(f_robot).tolist(),
                   f_true=None if truth is None else truth["f_vector"].tolist(),
                   f_centre=f_centre.tolist(), substeps=substeps, rigid=rows, robustness=rob,
                   flexible=flex, gains=dict(Kp=gains.Kp.tolist(), Kv=gains.Kv.tolist()))
    (out / "results.json").write_text(json.dumps(results, indent=2))
    print(f"\nfigures and results.json written to {out}/")
    return 0


def cli(argv=None):
    """Run :func:`main`; a bad log, file or option ends with one line on stderr, exit 1."""
    try:
        return main(argv)
    except (LogError, ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(cli())
