"""The adaptive computed torque of any arm under changes, on an independent robot (issues 21 and 23).

For each family (``planar2``: random two-link arms in a vertical plane;
``puma123``: PUMA 560 joints 1-3; ``random``: chains of 2-4 joints from
random DH tables; ``urdf``: random URDF chains, pinocchio's dynamics) and
each draw of
``benchmarks/independent_arm.py`` (seeds ``seed + i``, chosen before
looking; rigid; friction known or ``null`` at random), this benchmark

1. logs the unloaded arm under the rig's P card (independent simulator:
   Robotics Toolbox ``rne``, the drive and friction written there, DOP853)
   and identifies it with the library (:func:`identification.arm.identify_arm`,
   rigid): the prior;
2. draws a change (its own random stream): a pick-up (a point mass of
   0.5-5 kg, centre of mass within +-0.15 m of the last link's frame origin
   per axis, at 0.6-2 s), a put-down (the same tool carried from the start and
   put down at 0.6-2 s), a friction change (motor-side viscous and Coulomb
   friction x0.5-2 at 0.6-2 s: not a payload) or none; with ``--compliant``,
   ``--kinds`` may also name ``stiffness`` (every joint's spring x0.7) and
   ``damping`` (every spring's damping x2), issue 21's changes of a flexible
   robot that are no payload;
3. runs the static CTC (:meth:`ctc.arm.ArmComputedTorque.from_result`) and
   the adaptive CTC (:class:`ctc.arm_adaptive.ArmAdaptiveComputedTorque`,
   its defaults) on the independent robot through the change
   (``--run-s`` seconds), the first draw's adaptive run twice.

With ``--compliant`` the draws have two-mass flexible joints (half of them
with gearbox backlash; ``independent_arm.draw(..., compliant=True)``), the
prior is the library's default identification (``model="auto"``: flexible
when the springs show), and the adaptive CTC runs on a flexible prior the
robust flexible-joint design, identifying each window's payload through the
two-mass arm (:mod:`ctc.arm_adaptive`).

Scores, from 0.5 s after the change to the end (max abs(e) per joint, pulses):
payload changes -- adaptive within 1 pulse, last mass within 5 % of the
carried one (of the tool's mass for a put-down); friction changes -- the
adaptive CTC no worse than the static one + 1 pulse, no payload installed
(> 0.05 kg) at the end, the change reported (``'unexplained'``); stiffness and
damping changes -- the same, with no payload installed at any time; no change
-- no update and no report; every run -- no update > 0.05 kg before the change (a
put-down: none farther than 0.05 kg + 5 % from the carried tool's mass), no
current beyond the drive's full scale; the first draw's two adaptive runs
identical bit for bit.

Usage::

    python benchmarks/bench_arm_adaptive.py --n 12 8 --seed 20261501 --jobs 2 [--json out.json]
    python benchmarks/bench_arm_adaptive.py --compliant --n 6 2 --seed 20261901 --jobs 2
    python benchmarks/bench_arm_adaptive.py --compliant --kinds pick-up,put-down --n 6 0 --seed 20262101

Prints one line per draw, the summary and the worst cases with their
settings.  Needs the ``bench`` extra (Robotics Toolbox).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import math
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import independent_arm as ia  # noqa: E402
from bench_arm_payload import draw_payload  # noqa: E402

FAMILIES = ("planar2", "puma123", "random", "urdf")
KINDS = ("pick-up", "put-down", "friction", "none")
#: Changes of the joints' springs, drawn only with ``--kinds`` on compliant draws (issue 21's
#: non-payload changes of a flexible robot): the factor on every joint's stiffness (x0.7) or
#: damping (x2), each kind the name of the settings' field it scales.
DRIVE_KINDS = {"stiffness": 0.7, "damping": 2.0}
MASS_TOLERANCE = 0.05
#: Shortest run: the latest change (2 s) plus the 0.5 s before scoring plus 0.1 s scored.
MIN_RUN_S = 2.6


def draw_change(seed: int, kinds=KINDS) -> dict:
    """The change of a draw: its own random stream (robot and payload draws unchanged); its
    kind drawn from ``kinds`` (default all of :data:`KINDS`)."""
    rng = np.random.default_rng([seed, 31])
    kind = str(rng.choice(list(kinds)))
    ch = dict(kind=kind, t_s=float(rng.uniform(0.6, 2.0)))
    if kind == "friction":
        ch["factor"] = float(np.exp(rng.uniform(math.log(0.5), math.log(2.0))))
    elif kind in DRIVE_KINDS:
        ch["factor"] = DRIVE_KINDS[kind]
    return ch


def run_case(family: str, seed: int, run_s: float, repeat: bool, compliant: bool = False,
             kinds=KINDS) -> dict:
    from ctc.arm import ArmComputedTorque
    from ctc.arm_adaptive import ArmAdaptiveComputedTorque
    from identification.arm import identify_arm

    s = ia.draw(family, seed, compliant=compliant)
    tool = draw_payload(seed)
    ch = draw_change(seed, kinds)
    log = ia.make_log(s)
    prior = identify_arm(log, model="auto" if compliant else "rigid")
    ts = s.sample_time_s
    n = int(round(run_s / ts))
    k_change = int(math.ceil(ch["t_s"] / ts))
    k_after = int(math.ceil((ch["t_s"] + 0.5) / ts))
    loaded = dataclasses.replace(s, payload=tool)
    if ch["kind"] == "pick-up":
        start, after, m_end = s, loaded, tool["mass_kg"]
    elif ch["kind"] == "put-down":
        start, after, m_end = loaded, s, 0.0
    elif ch["kind"] == "friction":
        f = ch["factor"]
        start, m_end = s, 0.0
        after = dataclasses.replace(s, viscous=tuple(v * f for v in s.viscous),
                                    coulomb=tuple((a * f, b * f) for a, b in s.coulomb))
    elif ch["kind"] in DRIVE_KINDS:
        field = ch["kind"]
        start, m_end = s, 0.0
        after = dataclasses.replace(s, **{field: tuple(v * ch["factor"] for v in getattr(s, field))})
    else:
        start, after, m_end = s, None, 0.0
    changes = [] if after is None else [(k_change, ia.IndependentArm(after))]
    i_fs = math.inf if s.current_full_scale is None else float(s.current_full_scale)
    row = dict(family=family, seed=seed, n_joints=len(s.active), change=ch, tool=tool,
               m_end=m_end, friction_known=s.friction_known, prior_s=prior.elapsed_s,
               compliant=compliant, prior_model=prior.model,
               backlash=bool(compliant and s.backlash is not None and max(s.backlash) > 0),
               settings=dict(encoder_ppr=list(s.encoder_ppr),
                             gear_ratio=[round(g, 1) for g in s.gear_ratio],
                             sample_time_s=ts))

    def run(ctrl):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            t0 = time.perf_counter()
            out = ia.IndependentArm(start).run(ctrl, log.trajectory, n, changes=changes)
            wall = time.perf_counter() - t0
        e = np.abs(out["e"])
        return out, dict(ok=bool(out["ok"]), wall_s=wall,
                         max_after=e[k_after:].max(axis=0).tolist() if out["ok"] else None,
                         max_before=e[int(0.1 / ts):k_change].max(axis=0).tolist(),
                         i_max_over_fs=float(np.max(np.abs(out["i"])) / i_fs),
                         warnings=sorted({type(w.message).__name__ for w in caught}))

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the design's warnings: the adaptive CTC keeps them
        static = ArmComputedTorque.from_result(prior, log)
        t0 = time.perf_counter()
        adaptive = ArmAdaptiveComputedTorque(prior, log)
        build_s = time.perf_counter() - t0
    _, row["static"] = run(static)
    row["static"]["controller"] = type(static).__name__
    out, row["adaptive"] = run(adaptive)
    row["adaptive"].update(
        inner=type(adaptive._ctc).__name__, design_warnings=adaptive.design_warnings,
        build_s=build_s, history=[list(map(float, h)) for h in adaptive.payload_history],
        events=[dict(t_s=float(ev["t_s"]), kind=ev["kind"], message=ev["message"])
                for ev in adaptive.events],
        window_s_median=float(np.median([r["elapsed_s"] for r in adaptive.identifications])),
        decisions=[(round(r["window_s"][0], 2), r["decision"], round(r["mass_kg"], 3),
                    round(r["mass_std"], 4), round(r["lr"], 1), round(r["y_now"], 1),
                    round(r["y_new"], 1), round(r["tracking_mse"], 2), r.get("quiet_wald"))
                   for r in adaptive.identifications],
        fallback=adaptive.fallback_t_s,
        handovers=[dict(h) for h in adaptive.handovers],
        # a model identified but not yet in effect when the run ended: (t_effective_s, kg)
        pending=adaptive.pending)
    if repeat:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            again = ArmAdaptiveComputedTorque(prior, log)
        out2, _ = run(again)
        row["repeat_identical"] = bool(np.array_equal(out["e"], out2["e"])
                                       and np.array_equal(out["i"], out2["i"]))
    return row


def score(r: dict) -> dict:
    """Per-draw verdicts (None where a target does not apply)."""
    a, st, kind = r["adaptive"], r["static"], r["change"]["kind"]
    hist = a["history"]
    t_c = r["change"]["t_s"]
    m_last = hist[-1][1]
    v = dict(payload_ok=None, mass_ok=None, friction_not_worse=None, friction_no_payload=None,
             friction_reported=None, drive_not_worse=None, drive_no_payload=None,
             drive_reported=None, none_quiet=None)
    after_ok = a["max_after"] is not None and max(a["max_after"]) <= 1
    # a change that is no payload: the adaptive CTC no worse than the static one + 1 pulse
    not_worse = bool(a["max_after"] is not None and st["max_after"] is not None
                     and all(x <= y + 1 for x, y in zip(a["max_after"], st["max_after"])))
    if kind in ("pick-up", "put-down"):
        v["payload_ok"] = after_ok
        v["mass_ok"] = abs(m_last - r["m_end"]) <= MASS_TOLERANCE * r["tool"]["mass_kg"]
    elif kind == "friction":
        v["friction_not_worse"] = not_worse
        v["friction_no_payload"] = m_last <= 0.05
        v["friction_reported"] = any(ev["kind"] == "unexplained" for ev in a["events"])
    elif kind in DRIVE_KINDS:
        v["drive_not_worse"] = not_worse
        # no payload at any time: the springs' change is no payload, before or after
        v["drive_no_payload"] = all(abs(m) <= 0.05 for _, m in hist)
        v["drive_reported"] = any(ev["kind"] == "unexplained" for ev in a["events"])
    else:
        v["none_quiet"] = len(hist) == 1 and not a["events"]
    if kind == "put-down":
        # carried from the start: every model before the change is the tool's (its first
        # update is expected; none may move away from the tool by more than 0.05 kg + 5 %)
        m_tool = r["tool"]["mass_kg"]
        v["no_false_update"] = all(abs(m - m_tool) <= 0.05 + MASS_TOLERANCE * m_tool
                                   for t, m in hist[1:] if t < t_c)
    else:
        v["no_false_update"] = all(abs(m) <= 0.05 for t, m in hist if t < t_c)
    v["current_ok"] = a["i_max_over_fs"] <= 1.0 + 1e-12
    return v


TARGETS = (("payload_ok", "payload change: adaptive <= 1 pulse from 0.5 s after"),
           ("mass_ok", "payload change: last mass within 5 %"),
           ("friction_not_worse", "friction change: adaptive <= static + 1 pulse"),
           ("friction_no_payload", "friction change: no payload installed at the end"),
           ("friction_reported", "friction change: reported as not a payload"),
           ("drive_not_worse", "stiffness/damping change: adaptive <= static + 1 pulse"),
           ("drive_no_payload", "stiffness/damping change: no payload installed at any time"),
           ("drive_reported", "stiffness/damping change: reported as not a payload"),
           ("none_quiet", "no change: no update and no report"),
           ("no_false_update", "no update > 0.05 kg before the change"),
           ("current_ok", "no current beyond full scale"))


def _job(args):
    family, seed, run_s, repeat, compliant, kinds = args
    try:
        return run_case(family, seed, run_s, repeat, compliant, kinds)
    except Exception as exc:  # a draw that fails is reported, not hidden
        return dict(family=family, seed=seed, error=f"{type(exc).__name__}: {exc}")


def _line(r) -> str:
    if "error" in r:
        return f"{r['family']:8s} {r['seed']}  ERROR {r['error']}"
    ch = r["change"]
    what = (f"{ch['kind']} {r['tool']['mass_kg']:.2f} kg" if ch["kind"] in ("pick-up", "put-down")
            else f"{ch['kind']} x{ch['factor']:.2f}" if "factor" in ch else "none")
    a = r["adaptive"]
    ev = ",".join(sorted({e["kind"] for e in a["events"]})) or "-"
    prior = (f"  prior {r['prior_model']}{'+backlash' if r.get('backlash') else ''}"
             f" inner {a.get('inner', '?')}" if r.get("compliant") else "")
    return (f"{r['family']:8s} {r['seed']}  {what:22s} @ {ch['t_s']:.2f} s{prior}  static {r['static']['max_after']}"
            f"  adaptive {a['max_after']}  last {a['history'][-1][1]:.3f} kg  events {ev}  "
            f"window {a['window_s_median']:.2f} s")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[12, 8],
                    help="draws per family, in the order " + " ".join(FAMILIES)
                         + " (families left out: none)")
    ap.add_argument("--seed", type=int, default=20261501)
    ap.add_argument("--run-s", type=float, default=3.5, help="seconds of each closed-loop run")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--compliant", action="store_true",
                    help="two-mass flexible joints (half with backlash), the default identification")
    ap.add_argument("--kinds", default=",".join(KINDS),
                    help=f"comma-separated kinds of change to draw from (default {','.join(KINDS)}; "
                         f"with --compliant also {','.join(DRIVE_KINDS)})")
    ap.add_argument("--only", default=None,
                    help="rerun just these draws of the call, e.g. planar2:20262001,puma123:20262002")
    a = ap.parse_args(argv)
    kinds = tuple(k.strip() for k in a.kinds.split(",") if k.strip())
    allowed = KINDS + (tuple(DRIVE_KINDS) if a.compliant else ())
    if not kinds or any(k not in allowed for k in kinds):
        ap.error(f"--kinds must name some of {', '.join(allowed)}, got {a.kinds!r}"
                 + ("" if a.compliant else f" ({', '.join(DRIVE_KINDS)} need --compliant)"))
    if a.run_s < MIN_RUN_S:
        ap.error(f"--run-s must be at least {MIN_RUN_S} s (a change at 2 s, scored from 0.5 s after)")
    ia.check_counts(ap, a.n, FAMILIES)
    # the call's first draw is run twice (bit for bit)
    draws = [(fam, a.seed + i) for fam, n in zip(FAMILIES, a.n) for i in range(n)]
    jobs = [(fam, seed, a.run_s, k == 0, a.compliant, kinds) for k, (fam, seed) in enumerate(draws)]
    if a.only:
        wanted = {w.strip() for w in a.only.split(",") if w.strip()}
        jobs = [j for j in jobs if f"{j[0]}:{j[1]}" in wanted]
        if len(jobs) != len(wanted):
            ap.error(f"--only names draws this call does not make: {a.only!r}")
    t0 = time.perf_counter()
    rows = ia.run_jobs(_job, jobs, a.jobs, _line)
    ok = [r for r in rows if "error" not in r]
    for r in ok:
        r["score"] = score(r)
    print()
    print(f"summary over {len(rows)} {'compliant ' if a.compliant else ''}draws "
          f"({len(rows) - len(ok)} errors), seed {a.seed}"
          f"{'' if kinds == KINDS else ', changes ' + '/'.join(kinds)}, "
          f"{time.perf_counter() - t0:.0f} s:")
    for key, text in TARGETS:
        vals = [r["score"][key] for r in ok if r["score"][key] is not None]
        if vals:
            print(f"  {text:55s} {sum(vals):3d}/{len(vals):<3d}")
    rep = [r["repeat_identical"] for r in ok if "repeat_identical" in r]
    if rep:
        print(f"  {'fixed latency: two runs identical bit for bit':55s} {'yes' if all(rep) else 'NO'}")
    med = [r["adaptive"]["window_s_median"] for r in ok]
    if med:
        print("  median identification time per window (two fits): "
              + ", ".join(f"{fam} {np.median([r['adaptive']['window_s_median'] for r in ok if r['family'] == fam]):.2f} s"
                          for fam in FAMILIES if any(r['family'] == fam for r in ok)))
    if a.compliant:
        models = [f"{r['prior_model']}{'+backlash' if r.get('backlash') else ''} -> {r['adaptive']['inner']}"
                  for r in ok]
        print("  priors and inner controllers: "
              + ", ".join(f"{m} {models.count(m)}" for m in sorted(set(models))))
    bad = [r for r in ok if not all(v for v in r["score"].values() if v is not None)]
    print(f"draws missing a target: {len(bad)}")
    for r in bad[:5]:
        print(f"  {r['family']} seed {r['seed']}: change {r['change']}, tool {r['tool']}, friction "
              f"{'known' if r['friction_known'] else 'identified'}, static {r['static']['max_after']}, "
              f"adaptive {r['adaptive']['max_after']}, history "
              f"{[(round(t, 2), round(m, 3)) for t, m in r['adaptive']['history']]}"
              + (f" (pending at the run's end: {r['adaptive']['pending'][1]:.3f} kg from "
                 f"{r['adaptive']['pending'][0]:.2f} s)" if r["adaptive"].get("pending") else "")
              + f", missed {[k for k, v in r['score'].items() if v is False]}, settings {r['settings']}")
    if a.json:
        a.json.write_text(json.dumps(rows, indent=1, default=float) + "\n")


if __name__ == "__main__":
    main()
