"""A payload on any arm's last link, identified from 0.2 s windows on an independent robot (issue 23).

The paper's on-line proposal (identify a carried load from a 100-200 ms
window and feed it to the computed-torque controller) for the arm path: for
each family (``planar2``: random two-link arms in a vertical plane;
``puma123``: PUMA 560 joints 1-3; ``random``: chains of 2-4 joints from
random DH tables; ``urdf``: random URDF chains, pinocchio's dynamics) and
each draw of
``benchmarks/independent_arm.py`` (seeds ``seed + i``, chosen before
looking; rigid; friction known or ``null`` at random), this benchmark

1. logs the unloaded arm under the rig's P card (independent simulator:
   Robotics Toolbox ``rne``, the drive and friction written there, DOP853)
   and identifies it with the library (:func:`identification.arm.identify_arm`):
   the prior, as a user would have it;
2. draws a payload -- a point mass of 0.5-5 kg, its centre of mass within
   +-0.15 m of the last link's frame origin on each axis -- fixes it to the
   independent robot's last link (parallel axes, written in
   ``independent_arm.py``) and logs the loaded arm on the same reference;
3. identifies the payload (:func:`identification.arm_payload.identify_arm_payload`)
   on ``--windows`` 0.2 s windows at random times after 0.5 s, and on the
   whole log; the criterion is the mass within 5 %;
4. runs the computed-torque controller (:class:`ctc.arm.ArmComputedTorque`)
   on the loaded independent robot, with the prior alone and with the first
   window's payload, and checks ``abs(e) <= 1`` pulse on every joint after
   0.1 s (``--ctc-s`` seconds of the reference);
5. on-line, the paper's way: identifies the payload on a 0.2 s window (at a
   random time after 0.3 s) of the prior CTC's own run on the loaded robot,
   replaying the currents it commanded (``currents="logged"``), and runs the
   CTC with that payload.

Usage::

    python benchmarks/bench_arm_payload.py --n 8 6 --seed 20261125 --jobs 2 [--json out.json]
    python benchmarks/bench_arm_payload.py --n 0 0 6 6 --seed 20262751   # random DH and URDF chains

Prints one line per draw, a summary and the worst cases with their
settings.  Needs the ``bench`` extra (Robotics Toolbox).
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import independent_arm as ia  # noqa: E402

MASS_TOLERANCE = 0.05
WINDOW_S = 0.2
FAMILIES = ("planar2", "puma123", "random", "urdf")


def draw_payload(seed: int) -> dict:
    """The payload of a draw: its own random stream (the robot's draw is unchanged)."""
    rng = np.random.default_rng([seed, 23])
    return dict(mass_kg=float(rng.uniform(0.5, 5.0)),
                com_m=[float(v) for v in rng.uniform(-0.15, 0.15, 3)])


def run_case(family: str, seed: int, n_windows: int, ctc_s: float) -> dict:
    from ctc.arm import ArmComputedTorque, log_envelope
    from identification.arm import identify_arm
    from identification.arm_payload import identify_arm_payload

    s = ia.draw(family, seed)
    tool = draw_payload(seed)
    loaded = dataclasses.replace(s, payload=tool)
    log0 = ia.make_log(s)
    prior = identify_arm(log0, model="rigid")
    log = ia.make_log(loaded)
    rng = np.random.default_rng([seed, 7])
    starts = rng.uniform(0.5, s.duration_s - WINDOW_S - 0.01, n_windows)
    windows = []
    for t0 in starts:
        r = identify_arm_payload(log, prior, window_s=(t0, t0 + WINDOW_S))
        windows.append(dict(t0=float(t0), mass_kg=r.mass_kg, mass_std=float(r.x_std[0]),
                            com_m=r.com_m.tolist(), success=bool(r.success), s=r.elapsed_s,
                            beta=r.beta))
    whole = identify_arm_payload(log, prior)
    m_true = tool["mass_kg"]
    err = [abs(w["mass_kg"] / m_true - 1) for w in windows]
    n_ctc = int(round(ctc_s / s.sample_time_s))
    k0 = int(round(0.1 / s.sample_time_s))

    def run_ctc(beta):
        """The CTC with ``beta`` on the loaded independent robot: its run and a summary."""
        ctrl = ArmComputedTorque(prior.plant, beta, prior.rig, log.trajectory,
                                 envelope=log_envelope(log))
        out = ia.IndependentArm(loaded).run(ctrl, log.trajectory, n_ctc)
        e = np.abs(out["e"][k0:]).max(axis=0) if out["ok"] else None
        return out, dict(max=None if e is None else e.tolist(),
                         ok=bool(e is not None and np.all(e <= 1)),
                         fallback=ctrl.fallback_t_s is not None)

    ctc, online = {}, None
    run_prior, ctc["prior"] = run_ctc(prior.beta)
    _, ctc["payload"] = run_ctc(windows[0]["beta"])
    if run_prior["ok"]:
        # the paper's on-line proposal: a 0.2 s window of the prior CTC's own run on the
        # loaded robot (its logged commands replayed), then the CTC with that payload
        n_run = run_prior["e"].shape[0]
        run_log = dataclasses.replace(log, t=log.t[:n_run], q_ref=log.q_ref[:n_run],
                                      e_pulses=run_prior["e"], i_A=run_prior["i"])
        t0 = float(rng.uniform(0.3, n_run * s.sample_time_s - WINDOW_S - 0.01))
        r = identify_arm_payload(run_log, prior, window_s=(t0, t0 + WINDOW_S), currents="logged")
        online = dict(t0=t0, mass_kg=r.mass_kg, err_pct=100 * abs(r.mass_kg / tool["mass_kg"] - 1),
                      s=r.elapsed_s)
        _, ctc["online"] = run_ctc(r.beta)
    for w in windows:
        w.pop("beta")
    return dict(family=family, seed=seed, n_joints=len(s.active), tool=tool,
                friction_known=s.friction_known, prior_s=prior.elapsed_s,
                windows=windows, window_err_pct=[100 * v for v in err],
                windows_ok=int(sum(v <= MASS_TOLERANCE for v in err)),
                whole_mass_kg=whole.mass_kg, whole_err_pct=100 * abs(whole.mass_kg / m_true - 1),
                whole_s=whole.elapsed_s, ctc=ctc, online=online,
                p_max=np.abs(log.e_pulses[k0:n_ctc]).max(axis=0).tolist(),
                settings=dict(encoder_ppr=list(s.encoder_ppr),
                              gear_ratio=[round(g, 1) for g in s.gear_ratio],
                              sample_time_s=s.sample_time_s))


#: The committed test log (``--make-test-log``): a loaded planar2 draw, friction known, 3 s.
TEST_LOG_SEED = 20261199
TEST_LOG_STEM = "indep_arm_planar2_payload"
TEST_LOG_DIR = Path(__file__).resolve().parent.parent / "tests" / "data" / "independent_arm"


def make_test_log(directory: Path = TEST_LOG_DIR) -> None:
    """Write the loaded planar2 log of :data:`TEST_LOG_SEED` (3 s) for ``tests/test_arm_payload.py``:
    ``STEM.csv``, ``STEM.json`` and ``STEM.truth.json`` (the unloaded arm's base parameters
    ``beta``, the payload in ``settings``, the loaded arm's ``beta_loaded``)."""
    s = dataclasses.replace(ia.draw("planar2", TEST_LOG_SEED), duration_s=3.0)
    if not s.friction_known:
        raise RuntimeError("the test log's draw must have known friction")
    loaded = dataclasses.replace(s, payload=draw_payload(TEST_LOG_SEED))
    log = ia.write_log(loaded, directory, TEST_LOG_STEM)
    path = directory / f"{TEST_LOG_STEM}.truth.json"
    truth = json.loads(path.read_text())
    tool = loaded.payload
    delta = log.model.payload_delta(tool["mass_kg"], tool["com_m"])
    truth["beta_loaded"] = [float(v) for v in np.asarray(truth["beta"]) + delta]
    truth["note"] = ("beta: the unloaded arm's base parameters; settings.payload: the point mass "
                     "fixed to the independent robot's last link")
    path.write_text(json.dumps(truth, indent=1) + "\n")
    print(f"wrote {directory / TEST_LOG_STEM}.csv/.json/.truth.json")


def _job(args):
    family, seed, n_windows, ctc_s = args
    try:
        return run_case(family, seed, n_windows, ctc_s)
    except Exception as exc:  # a draw that fails is reported, not hidden
        return dict(family=family, seed=seed, error=f"{type(exc).__name__}: {exc}")


def _line(r) -> str:
    if "error" in r:
        return f"{r['family']:8s} {r['seed']}  ERROR {r['error']}"
    w = " ".join(f"{v:5.2f}" for v in r["window_err_pct"])
    return (f"{r['family']:8s} {r['seed']}  m {r['tool']['mass_kg']:4.2f} kg  "
            f"windows err % [{w}] ({np.mean([x['s'] for x in r['windows']]):.2f} s each)  "
            f"whole {r['whole_err_pct']:5.2f} %  CTC prior {r['ctc']['prior']['max']} -> "
            f"payload {r['ctc']['payload']['max']}  on-line {_online(r)}  P {r['p_max']}")


def _online(r) -> str:
    o = r.get("online")
    if o is None:
        return "-"
    return f"{o['err_pct']:.2f} % -> {r['ctc']['online']['max']}"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[8, 6],
                    help="draws per family, in the order " + " ".join(FAMILIES)
                         + " (families left out: none)")
    ap.add_argument("--seed", type=int, default=20261125)
    ap.add_argument("--windows", type=int, default=3, help="0.2 s windows per draw")
    ap.add_argument("--ctc-s", type=float, default=3.0, help="seconds of the CTC runs")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--make-test-log", action="store_true",
                    help=f"write tests/data/independent_arm/{TEST_LOG_STEM}.* and stop")
    a = ap.parse_args(argv)
    ia.check_counts(ap, a.n, FAMILIES)
    if a.make_test_log:
        make_test_log()
        return
    jobs = [(fam, a.seed + i, a.windows, a.ctc_s) for fam, n in zip(FAMILIES, a.n) for i in range(n)]
    t0 = time.perf_counter()
    rows = ia.run_jobs(_job, jobs, a.jobs, _line)
    ok = [r for r in rows if "error" not in r]
    print()
    print(f"summary over {len(rows)} draws ({len(rows) - len(ok)} errors), seed {a.seed}, "
          f"{time.perf_counter() - t0:.0f} s:")
    for fam in FAMILIES:
        fr = [r for r in ok if r["family"] == fam]
        if not fr:
            continue
        nw = sum(len(r["windows"]) for r in fr)
        print(f"  {fam}: mass within 5 % from a 0.2 s window  "
              f"{sum(r['windows_ok'] for r in fr)}/{nw}; from the whole log "
              f"{sum(r['whole_err_pct'] <= 100 * MASS_TOLERANCE for r in fr)}/{len(fr)}; "
              f"CTC <= 1 pulse after 0.1 s: prior {sum(r['ctc']['prior']['ok'] for r in fr)}/{len(fr)}, "
              f"with the window's payload {sum(r['ctc']['payload']['ok'] for r in fr)}/{len(fr)}; "
              f"on-line (a window of the prior CTC's own run): mass within 5 % "
              f"{sum(bool(r['online'] and r['online']['err_pct'] <= 100 * MASS_TOLERANCE) for r in fr)}"
              f"/{len(fr)}, CTC <= 1 pulse {sum(r['ctc'].get('online', {}).get('ok', False) for r in fr)}"
              f"/{len(fr)}; "
              f"median window {np.median([w['s'] for r in fr for w in r['windows']]):.2f} s")
    worst = sorted(ok, key=lambda r: -max(r["window_err_pct"]))[:5]
    print("worst five draws (largest window mass error):")
    for r in worst:
        print(f"  {r['family']} seed {r['seed']}: tool {r['tool']}, friction "
              f"{'known' if r['friction_known'] else 'identified'}, window errors "
              f"{[round(v, 2) for v in r['window_err_pct']]} % at t0 "
              f"{[round(w['t0'], 2) for w in r['windows']]} s, settings {r['settings']}, "
              f"CTC with payload {r['ctc']['payload']['max']}")
    if a.json:
        a.json.write_text(json.dumps(rows, indent=1, default=float) + "\n")


if __name__ == "__main__":
    main()
