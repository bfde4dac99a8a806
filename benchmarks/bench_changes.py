"""Randomised benchmark of mid-run changes on the INDEPENDENT simulator (issue 21, item 7).

A robot in service picks up and puts down tools, and changes in ways a
payload does not describe (friction as it warms, drive damping, gearbox
stiffness).  Each case here draws one robot of the robustness suite
(:func:`bench_robustness.draw_settings`: rigid or two-mass flexible joints,
backlash, payload, encoders, P gains, sample time, drive, paper or multisine
reference), identifies it from its P-control log with the library's default
call (the prior; cached with the robustness suite's results), draws one
change at random from a separate stream of the same seed, and runs three
controllers through that change on :mod:`independent_robot` (RTB dynamics,
own drive, DOP853; no code shared with the library's plant):

* ``P`` -- the rig's own P law;
* ``static`` -- ``ctc.ComputedTorqueController.from_result(prior, log)``
  (the flexible-joint CTC on a flexible result);
* ``adaptive`` -- ``ctc.AdaptiveComputedTorqueController.from_log`` of the
  same result, with the default window and fixed latency (0.1 s) and its
  supervisor; on a flexible result its inner controller is the
  flexible-joint CTC and the payload is identified through the two-mass
  plant.

On payload cases a fourth run, ``oracle``, is the static CTC of the same
result whose model is switched, at the sample of each change, to the prior
plus the true change of the rigid-equivalent parameters (RTB with and
without the tool, :func:`independent_robot.rigid_equivalent_truth`): what
the same controller achieves when its adaptation is exact and immediate.
It reads the truth and is a reference, not a controller; it separates what
the controller cannot do from what the adaptation does late or wrong.

Changes (``kind``):

* ``pick-up`` -- 0.5-5 kg, centre of mass up to 0.15 m from the flange, at a
  random time;
* ``put-down`` -- a pick-up, then the same tool put down again;
* ``friction`` -- motor-side viscous and Coulomb friction x0.5-2;
* ``damping`` -- drive damping x2 (the spring damping D of flexible joints,
  the motor-side viscous friction of rigid ones);
* ``stiffness`` -- joint stiffness x0.7 (flexible robots).

A loaded robot whose reference would need more than the drive's full-scale
current is given a lighter tool (halved until feasible; recorded).

Scores (from 0.5 s after the last change to the end of the run, max abs(e)
in pulses per joint): payload cases -- adaptive within 1 pulse, last mass
within 5 % of the mass carried at the end (``put-down``: within 5 % of the
tool's mass of zero); non-payload cases -- no divergence, adaptive no worse
than static + 1 pulse, the change reported (an ``'unexplained'`` event), and
not turned into a payload (no model of more than 0.05 kg in use at any time
after it); every case -- no update before the (first) change that moves the mass by
more than 0.05 kg, no commanded current beyond full scale.  With
``--repeat`` the first case's adaptive run is repeated and compared bit for
bit.

Run
---
::

    pip install -e ".[bench]"
    python benchmarks/bench_changes.py --n 60 --seed 20261122 --jobs 2 --rst docs/figures/changes.rst
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
import traceback
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))

import bench_robustness as br  # noqa: E402
import independent_robot as ir  # noqa: E402

DEFAULT_OUT = HERE / "out" / "changes"
PAYLOAD_KINDS = ("pick-up", "put-down")
TARGETS = {"payload_rigid": 0.90, "payload_flexible": 0.80, "mass_within_5pct": 1.0,
           "nonpayload_no_divergence": 1.0, "nonpayload_not_worse": 1.0,
           "nonpayload_reported": 1.0, "nonpayload_visible_reported": 1.0,
           "nonpayload_no_payload": 1.0, "no_false_update": 1.0, "within_full_scale": 1.0,
           "no_update_before": None,
           "oracle_payload_rigid": None, "oracle_payload_flexible": None}
#: a run is stopped (and reported diverged) once an error exceeds this many pulses
DIVERGED_PULSES = 5000


# ----------------------------------------------------------------------------- draws
def combine_payloads(p1: dict | None, p2: dict) -> dict:
    """One rigid payload (RTB link-6 frame, diagonal inertia about its COM) from two."""
    if not p1 or p1["mass_kg"] <= 0.0:
        return dict(p2)
    m1, m2 = p1["mass_kg"], p2["mass_kg"]
    c1, c2 = np.asarray(p1["com_m_rtb_frame6"]), np.asarray(p2["com_m_rtb_frame6"])
    m = m1 + m2
    c = (m1 * c1 + m2 * c2) / m

    def about(ci, mi, di):
        d = ci - c
        return np.diag(di) + mi * (d @ d * np.eye(3) - np.outer(d, d))

    inertia = about(c1, m1, p1["inertia_about_com_kgm2"]) + about(c2, m2, p2["inertia_about_com_kgm2"])
    return {"mass_kg": float(m), "com_m_rtb_frame6": [float(x) for x in c],
            "inertia_about_com_kgm2": [float(x) for x in np.diag(inertia)]}


def _feasible(s: ir.RobotSettings) -> bool:
    from plant.logs.trajectory import Trajectory

    need = ir.IndependentRobot(s).required_current(Trajectory.from_sidecar(s.trajectory), s.n_samples)
    return bool(np.all(need <= 0.9 * float(s.current_full_scale_A or math.inf)))


def draw_change(seed: int, index: int, s: ir.RobotSettings) -> dict:
    """The change of case ``index``: kind, times (s), the changed settings' deltas."""
    rng = np.random.default_rng([int(seed), int(index), 21])
    kinds = ["pick-up", "put-down", "friction", "damping"] + (["stiffness"] if s.flexible else [])
    # half payload changes, half the others
    if rng.random() < 0.5:
        kind = str(rng.choice(PAYLOAD_KINDS))
    else:
        kind = str(rng.choice(kinds[2:]))
    dur = float(s.duration_s)
    if kind == "put-down" and dur < 2.6:
        kind = "pick-up"
    ch = dict(kind=kind)
    if kind in PAYLOAD_KINDS:
        tool = br.random_payload(rng, (0.5, 5.0))
        halvings = 0
        while True:
            loaded = ir.RobotSettings.from_dict(s.to_dict())
            loaded.payload = combine_payloads(s.payload, tool)
            if _feasible(loaded) or halvings >= 6:
                break
            tool = dict(tool, mass_kg=tool["mass_kg"] / 2.0,
                        inertia_about_com_kgm2=[x / 2.0 for x in tool["inertia_about_com_kgm2"]])
            halvings += 1
        ch.update(tool=tool, tool_halvings=halvings)
        if kind == "pick-up":
            ch["times_s"] = [float(rng.uniform(0.6, max(0.61, dur - 1.0)))]
        else:
            t1 = float(rng.uniform(0.4, dur / 2.0 - 0.3))
            ch["times_s"] = [t1, float(rng.uniform(t1 + 0.8, max(t1 + 0.81, dur - 1.0)))]
    else:
        ch["times_s"] = [float(rng.uniform(0.6, max(0.61, dur - 1.0)))]
        if kind == "friction":
            ch["factor"] = float(np.exp(rng.uniform(math.log(0.5), math.log(2.0))))
        elif kind == "damping":
            ch["factor"] = 2.0
        else:
            ch["factor"] = 0.7
    return ch


def changed_settings(s: ir.RobotSettings, ch: dict) -> list[ir.RobotSettings]:
    """The robot after each of the change's times."""
    def copy():
        return ir.RobotSettings.from_dict(s.to_dict())

    kind = ch["kind"]
    if kind in PAYLOAD_KINDS:
        loaded = copy()
        loaded.payload = combine_payloads(s.payload, ch["tool"])
        return [loaded] if kind == "pick-up" else [loaded, copy()]
    c = copy()
    f = ch["factor"]
    if kind == "friction":
        c.viscous_B = tuple(b * f for b in s.viscous_B)
        c.coulomb_Tc = tuple(tuple(t * f for t in tc) for tc in s.coulomb_Tc)
    elif kind == "damping":
        if s.flexible:
            c.D = tuple(d * f for d in s.D)
        else:
            c.viscous_B = tuple(b * f for b in s.viscous_B)
    else:
        c.K = tuple(k * f for k in s.K)
    return [c]


# ----------------------------------------------------------------------------- evaluation
def _prior(csv, robust_out: Path, out: Path, log):
    """The default identification of the log (the robustness suite's cache, else computed)."""
    import identification

    stem = csv.stem
    cached = robust_out / "results" / f"{stem}.result.json"
    res_dir = out / "priors"
    res_dir.mkdir(parents=True, exist_ok=True)
    path = cached if cached.exists() else res_dir / f"{stem}.result.json"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if path.exists():
            return identification.IdentificationResult.load_json(path)
        res = identification.identify(log, rng=0, progress=False)
        res.save_json(path)
    return res


class _Oracle:
    """The static CTC whose model is switched to the true one at each change (reference)."""

    def __init__(self, inner, switches):
        self.inner, self.switches = inner, dict(switches)
        self.prior_f = np.array(inner.f, dtype=float)

    def reset(self):
        self.inner.reset()
        self.inner.set_model_f(self.prior_f)

    def __call__(self, k, t, q_meas, e_pulses):
        if k in self.switches:
            self.inner.set_model_f(self.switches[k])
        return self.inner(k, t, q_meas, e_pulses)


def oracle_of(inner, s: ir.RobotSettings, ch: dict, changes) -> _Oracle:
    """``inner`` (a CTC of the prior) switched to the true model at each of the change's
    times: its f plus the true rigid-equivalent f's change (no switch for a non-payload
    change)."""
    switches = []
    if ch["kind"] in PAYLOAD_KINDS:
        f_unloaded = ir.rigid_equivalent_truth(s)["f"]
        switches = [(k, inner.f + ir.rigid_equivalent_truth(c)["f"] - f_unloaded)
                    for (k, _), c in zip(changes, changed_settings(s, ch))]
    return _Oracle(inner, switches)


def run_case(seed: int, index: int, out: Path, robust_out: Path, repeat: bool = False,
             adaptive_options: dict | None = None, design_options: dict | None = None) -> dict:
    import ctc
    import plant

    csv = br.generate(seed, index, robust_out)
    truth = json.loads(csv.with_suffix(".truth.json").read_text())
    s = ir.RobotSettings.from_dict(truth["settings"])
    log = plant.load_log(csv)
    ch = draw_change(seed, index, s)
    row = dict(stem=csv.stem, index=index, joints="flexible" if s.flexible else "rigid",
               traj=truth["draw"]["trajectory"].get("kind", "?"), ppr=list(s.encoder_ppr),
               change=ch)
    prior = _prior(csv, robust_out, out, log)
    row["prior_model"] = prior.get("model", "rigid")
    # options of the flexible-joint CTC's robust design (max_current_per_pulse): a flexible
    # prior's controllers only (a rigid CTC takes none)
    design = dict(design_options or {}) if row["prior_model"] != "rigid" else {}
    adaptive_options = {**(adaptive_options or {}), **design}
    ts = s.sample_time_s
    n = log.n_total
    robots = [ir.IndependentRobot(c) for c in changed_settings(s, ch)]
    changes = [(int(math.ceil(t / ts)), r) for t, r in zip(ch["times_s"], robots)]
    k_first = changes[0][0]
    k_after = int(math.ceil((ch["times_s"][-1] + 0.5) / ts))
    i_fs = float(s.current_full_scale_A)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        controllers = {
            "P": ir.PCard(s.p_gain),
            "static": ctc.ComputedTorqueController.from_result(prior, log, **design),
            "adaptive": ctc.AdaptiveComputedTorqueController.from_log(prior, log,
                                                                      **adaptive_options),
        }
        if ch["kind"] in PAYLOAD_KINDS:
            controllers["oracle"] = oracle_of(
                ctc.ComputedTorqueController.from_result(prior, log, **design), s, ch, changes)
    row["build_warnings"] = [str(w.message)[:400] for w in caught]
    for name, c in controllers.items():
        rob = ir.IndependentRobot(s)
        t0 = time.perf_counter()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            run = rob.run(c, log.trajectory, n, max_step_fraction=ir.max_step_fraction(s),
                          max_abs_e=DIVERGED_PULSES, changes=changes)
        e = np.abs(run["e"])
        row[name] = dict(success=bool(run["success"]), message=run["message"],
                         max_e_before=e[int(math.ceil(0.1 / ts)):k_first].max(axis=0).astype(int).tolist()
                         if k_first > int(math.ceil(0.1 / ts)) else [0, 0],
                         max_e_after=e[k_after:].max(axis=0).astype(int).tolist() if k_after < n else None,
                         max_i_cmd=float(np.max(np.abs(run["i_cmd"]))),
                         wall_s=time.perf_counter() - t0,
                         warnings=sorted({type(w.message).__name__ for w in caught}))
        if name == "adaptive":
            row[name].update(
                payload_history=[list(map(float, h)) for h in c.payload_history],
                events=[{k: (float(v) if isinstance(v, (np.floating, float)) else v)
                         for k, v in ev.items() if k in ("t_s", "kind", "message", "mass_kg", "cause")}
                        for ev in c.events],
                # window start, decision, estimated mass and, where the rival hypotheses were
                # fitted, Vuong's z of each (friction, then drive) against the payload over
                # the run's windows
                decisions=[(round(r["window_s"][0], 3), r["decision"], round(r["mass_kg"], 3))
                           + tuple(round(float(h["z_run"]), 2) for h in r.get("rivals") or ())
                           for r in c.identifications])
            if repeat:
                c2 = ctc.AdaptiveComputedTorqueController.from_log(prior, log,
                                                                   **adaptive_options)
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    run2 = ir.IndependentRobot(s).run(
                        c2, log.trajectory, n, max_step_fraction=ir.max_step_fraction(s),
                        max_abs_e=DIVERGED_PULSES, changes=changes)
                row["repeat_identical"] = bool(np.array_equal(run2["e"], run["e"])
                                               and np.array_equal(run2["i"], run["i"]))
    row["i_full_scale"] = i_fs
    return row


def score(row: dict) -> dict:
    """Per-case verdicts (None where a target does not apply)."""
    ch = row["change"]
    kind = ch["kind"]
    ad, st = row["adaptive"], row["static"]
    hist = ad["payload_history"]
    t_first = ch["times_s"][0]
    m_before = [m for t, m in hist if t < t_first]
    v = dict(payload=None, mass=None, nonpayload_no_divergence=None, nonpayload_not_worse=None,
             nonpayload_reported=None, nonpayload_visible_reported=None,
             nonpayload_no_payload=None, oracle_payload=None)
    v["no_false_update"] = all(abs(m) <= 0.05 for m in m_before)
    v["no_update_before"] = not m_before
    v["within_full_scale"] = all(row[c]["max_i_cmd"] <= row["i_full_scale"] + 1e-9
                                 for c in ("static", "adaptive"))
    last = hist[-1][1] if hist else 0.0
    if kind in PAYLOAD_KINDS:
        m_true = ch["tool"]["mass_kg"] if kind == "pick-up" else 0.0
        v["payload"] = bool(ad["success"] and ad["max_e_after"] is not None
                            and max(ad["max_e_after"]) <= 1)
        v["mass"] = bool(abs(last - m_true) <= 0.05 * ch["tool"]["mass_kg"])
        if "oracle" in row:
            o = row["oracle"]
            v["oracle_payload"] = bool(o["success"] and o["max_e_after"] is not None
                                       and max(o["max_e_after"]) <= 1)
    else:
        v["nonpayload_no_divergence"] = bool(ad["success"])
        v["nonpayload_not_worse"] = bool(
            ad["success"] and ad["max_e_after"] is not None and st["max_e_after"] is not None
            and all(a <= b + 1 for a, b in zip(ad["max_e_after"], st["max_e_after"])))
        v["nonpayload_reported"] = any(ev["kind"] == "unexplained" and ev["t_s"] >= t_first
                                       for ev in ad["events"])
        # not turned into a payload: no model with more than 0.05 kg in use at any time from
        # the change on (a payload installed, even if a later rule dropped it)
        in_use = [m for t, m in hist if t < t_first][-1:]  # the model in use at the change
        v["nonpayload_no_payload"] = all(abs(m) <= 0.05 for m in in_use
                                         + [m for t, m in hist if t >= t_first])
        # visible: the static CTC tracks worse after the change than before it (a change
        # that leaves the errors where they were leaves no evidence to report)
        if st["max_e_after"] is not None and any(
                a > b + 1 for a, b in zip(st["max_e_after"], st["max_e_before"])):
            v["nonpayload_visible_reported"] = v["nonpayload_reported"]
    return v


def summarise(rows):
    ok = [r for r in rows if "error" not in r]

    def frac(key, sel=lambda r: True):
        xs = [r["verdict"].get(key) for r in ok if sel(r) and r["verdict"].get(key) is not None]
        return [sum(xs), len(xs)]

    return {
        "payload_rigid": frac("payload", lambda r: r["joints"] == "rigid"),
        "payload_flexible": frac("payload", lambda r: r["joints"] == "flexible"),
        "mass_within_5pct": frac("mass"),
        "nonpayload_no_divergence": frac("nonpayload_no_divergence"),
        "nonpayload_not_worse": frac("nonpayload_not_worse"),
        "nonpayload_reported": frac("nonpayload_reported"),
        "nonpayload_visible_reported": frac("nonpayload_visible_reported"),
        "nonpayload_no_payload": frac("nonpayload_no_payload"),
        "no_false_update": frac("no_false_update"),
        "within_full_scale": frac("within_full_scale"),
        "no_update_before": frac("no_update_before"),
        "oracle_payload_rigid": frac("oracle_payload", lambda r: r["joints"] == "rigid"),
        "oracle_payload_flexible": frac("oracle_payload", lambda r: r["joints"] == "flexible"),
        "errors": len(rows) - len(ok),
    }


LABELS = {
    "payload_rigid": "pick-up/put-down, rigid: adaptive <= 1 pulse from 0.5 s after",
    "payload_flexible": "pick-up/put-down, flexible: adaptive <= 1 pulse from 0.5 s after",
    "mass_within_5pct": "last mass within 5 % (payload cases)",
    "nonpayload_no_divergence": "non-payload change: adaptive does not diverge",
    "nonpayload_not_worse": "non-payload change: adaptive <= static + 1 pulse",
    "nonpayload_reported": "non-payload change reported as not a payload",
    "nonpayload_visible_reported": "... of those the static CTC's errors show (> before + 1)",
    "nonpayload_no_payload": "non-payload change: no payload (> 0.05 kg) installed after it",
    "no_false_update": "no update > 0.05 kg before the change",
    "within_full_scale": "no commanded current beyond full scale",
    "no_update_before": "reference: no update at all (0 kg included) before the change",
    "oracle_payload_rigid": "reference, rigid: true model switched in at the change <= 1 pulse",
    "oracle_payload_flexible": "reference, flexible: true model switched in at the change <= 1 pulse",
}


def _change_text(ch):
    if ch["kind"] in PAYLOAD_KINDS:
        return f"{ch['kind']} {ch['tool']['mass_kg']:.2f} kg @ " + "/".join(f"{t:.2f}" for t in ch["times_s"])
    return f"{ch['kind']} x{ch['factor']:.2f} @ {ch['times_s'][0]:.2f}"


def table_lines(rows):
    head = ("case", "joints", "ppr", "change", "P after", "static after", "adaptive after",
            "oracle after", "last kg", "events", "ok")
    lines = [head]
    for r in rows:
        if "error" in r:
            lines.append((r["stem"][-4:], "-", "-", "error: " + r["error"][:60], "", "", "", "", "", "", ""))
            continue
        ad = r["adaptive"]
        last = ad["payload_history"][-1][1] if ad["payload_history"] else 0.0
        ev = ",".join(sorted({e["kind"] + (":" + e["cause"] if e.get("cause") else "")
                              for e in ad["events"]})) or "-"
        good = _passes(r["verdict"])
        lines.append((r["stem"][-4:], r["joints"][:4], str(r["ppr"]), _change_text(r["change"]),
                      str(r["P"]["max_e_after"]), str(r["static"]["max_e_after"]),
                      str(ad["max_e_after"]) + ("" if ad["success"] else " DIV"),
                      str(r["oracle"]["max_e_after"]) if "oracle" in r else "-",
                      f"{last:.2f}", ev, "yes" if good else "NO"))
    return lines


def _passes(verdict) -> bool:
    """Every target of a case met (the oracle is a reference, not a target)."""
    return all(x for k, x in verdict.items()
               if x is not None and not k.startswith("oracle") and TARGETS.get(k, 1.0) is not None)


def _badness(r):
    if "error" in r:
        return 1e9
    ad = r["adaptive"]
    return (0 if _passes(r["verdict"]) else 1e6) + \
        (max(ad["max_e_after"]) if ad["max_e_after"] else 1e5)


def print_report(rows, s, file=sys.stdout):
    lines = table_lines(rows)
    w = [max(len(str(l[i])) for l in lines) for i in range(len(lines[0]))]
    for l in lines:
        print("  ".join(str(x).ljust(w[i]) for i, x in enumerate(l)), file=file)
    print(f"\nsummary over {len(rows)} cases ({s['errors']} errors):", file=file)
    for key, label in LABELS.items():
        k, n = s[key]
        rate = k / n if n else float("nan")
        goal = TARGETS[key]
        if goal is None:
            print(f"  {label:<66} {k:3d}/{n:<3d} = {100 * rate:5.1f} %  (reference)", file=file)
            continue
        verdict = "PASS" if n and rate >= goal else ("-" if not n else "FAIL")
        print(f"  {label:<66} {k:3d}/{n:<3d} = {100 * rate:5.1f} %  target >= {100 * goal:.0f} %  {verdict}",
              file=file)
    worst = sorted(rows, key=_badness, reverse=True)[:5]
    print("\nworst five cases:", file=file)
    for r in worst:
        if "error" in r:
            print(f"  {r['stem']}: {r['error']}", file=file)
            continue
        print(f"  {r['stem']} {r['joints']} ppr {r['ppr']} P {r.get('p_gain')} {_change_text(r['change'])}: "
              f"P {r['P']['max_e_after']}, static {r['static']['max_e_after']}, adaptive "
              f"{r['adaptive']['max_e_after']}; updates {r['adaptive']['payload_history']}; events "
              f"{[_event_text(e) for e in r['adaptive']['events']]}", file=file)
        for w in dict.fromkeys(r.get("build_warnings") or ()):  # once each (static, adaptive)
            print(f"    built with the warning: {w}", file=file)


def _event_text(ev) -> str:
    """``kind``, its ``cause`` when it names one (a named payload with its mass), and its
    time: ``'unexplained:friction@1.101'``, ``'diagnosis:payload 2.87 kg@2.929'``."""
    cause = ev.get("cause")
    mass = f" {ev['mass_kg']:.3g} kg" if cause == "payload" and "mass_kg" in ev else ""
    return f"{ev['kind']}{':' + cause if cause else ''}{mass}@{ev['t_s']:.3f}"


def write_rst(rows, s, path: Path, seed: int):
    out = [f"{len(rows)} cases (seed {seed}; {s['errors']} errors), each one robot of the robustness "
           "suite with one random change, P / static CTC / adaptive CTC side by side on the "
           "independent simulator (``benchmarks/bench_changes.py``).", ""]
    tab = [("target", "result", "rate", "goal")]
    for key, label in LABELS.items():
        k, n = s[key]
        goal = "reference" if TARGETS[key] is None else f">= {100 * TARGETS[key]:.0f} %"
        tab.append((label, f"{k} / {n}", f"{100 * k / n:.1f} %" if n else "-", goal))
    out += _rst_table(tab)
    out += ["", "The five worst cases (max abs(e) in pulses from 0.5 s after the last change, "
            "joint 2 / joint 3):", ""]
    lines = table_lines(sorted(rows, key=_badness, reverse=True)[:5])
    out += _rst_table([lines[0]] + lines[1:]) if len(lines) > 1 else []
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text("\n".join(out) + "\n")
    tmp.replace(path)
    txt = path.with_suffix(".txt")
    with open(txt.with_suffix(".txt.tmp"), "w") as fh:
        print_report(rows, s, file=fh)
    txt.with_suffix(".txt.tmp").replace(txt)


def _rst_table(rows):
    w = [max(len(str(r[i])) for r in rows) for i in range(len(rows[0]))]
    sep = "  ".join("=" * x for x in w)
    fmt = lambda r: "  ".join(str(x).ljust(w[i]) for i, x in enumerate(r)).rstrip()  # noqa: E731
    return [sep, fmt(rows[0]), sep] + [fmt(r) for r in rows[1:]] + [sep]


def _job(args):
    seed, index, out, robust_out, repeat, adaptive_options, design_options = args
    out, robust_out = Path(out), Path(robust_out)
    stem = br.stem_of(seed, index)
    cache = out / "cases" / f"{stem}.json"
    if cache.exists():
        row = json.loads(cache.read_text())
        if "verdict" in row:  # scored anew: a target added since the case ran is scored too
            row["verdict"] = score(row)
        return row
    try:
        row = run_case(seed, index, out, robust_out, repeat=repeat,
                       adaptive_options=adaptive_options, design_options=design_options)
        row["verdict"] = score(row)
    except Exception as exc:  # noqa: BLE001
        if isinstance(exc, RuntimeError) and "no stable drive" in str(exc) or "no feasible" in str(exc):
            return dict(stem=stem, skipped=str(exc))
        row = dict(stem=stem, error=f"{type(exc).__name__}: {exc}", trace=traceback.format_exc()[-2000:])
    cache.parent.mkdir(parents=True, exist_ok=True)
    tmp = cache.with_suffix(".tmp")
    tmp.write_text(json.dumps(row, indent=1, default=float) + "\n")
    tmp.replace(cache)
    return row


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=60, help="robots drawn (draws without a stable loop are skipped)")
    ap.add_argument("--seed", type=int, default=20261122)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    ap.add_argument("--robust-out", type=Path, default=br.DEFAULT_OUT,
                    help="the robustness suite's cache (logs and default identifications)")
    ap.add_argument("--rst", type=Path, default=None)
    ap.add_argument("--cases", type=str, default=None,
                    help="comma-separated case indices to run (default: 0 .. n-1)")
    ap.add_argument("--window", type=float, default=None,
                    help="the adaptive CTC's window_s (default: its default)")
    ap.add_argument("--latency", type=float, default=None,
                    help="the adaptive CTC's fixed latency_s (default: its default)")
    ap.add_argument("--max-current-per-pulse", type=float, default=None,
                    help="a flexible prior's robust design admits a faster candidate only when "
                         "its one-pulse current step is within this fraction of full scale "
                         "(ctc.flexible.select_robust_design; default: no cap; use a fresh --out: "
                         "cached cases are reused)")
    a = ap.parse_args(argv)
    if a.n < 1 or a.jobs < 1:
        ap.error("--n and --jobs must be >= 1")
    design = {}
    if a.max_current_per_pulse is not None:
        if not a.max_current_per_pulse > 0:
            ap.error("--max-current-per-pulse must be > 0")
        design["max_current_per_pulse"] = a.max_current_per_pulse
    opts = {}
    if a.window is not None:
        opts["window_s"] = a.window
    if a.latency is not None:
        opts["latency_s"] = a.latency
    indices = range(a.n) if a.cases is None else [int(c) for c in a.cases.split(",")]
    jobs = [(a.seed, i, str(a.out), str(a.robust_out), i == 0, opts, design) for i in indices]
    rows = br.run_jobs(_job, jobs, a.jobs)
    skipped = [r for r in rows if "skipped" in r]
    rows = [r for r in rows if "skipped" not in r]
    for r in rows:  # a cached case is scored anew (the scores may have grown since it ran)
        if "error" not in r:
            r["verdict"] = score(r)
    print()
    s = summarise(rows)
    print_report(rows, s)
    rep = [r.get("repeat_identical") for r in rows if "repeat_identical" in r]
    if rep:
        print(f"\nadaptive run repeated with the fixed latency: identical bit for bit: {rep[0]}")
    print(f"{len(skipped)} draws had no stable P loop or feasible reference and were skipped")
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / f"summary_{a.seed}_{a.n}.json").write_text(json.dumps(dict(summary=s, rows=rows), indent=1,
                                                                   default=float) + "\n")
    if a.rst:
        write_rst(rows, s, a.rst, a.seed)
        print(f"RST written to {a.rst}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
