"""Randomised robustness benchmark on logs from an INDEPENDENT simulator.

Independence
------------
Every log here is made by :mod:`benchmarks.independent_robot`, which shares
no code with the library's plant (``plant/``): the rigid-body dynamics are
Robotics Toolbox for Python's Puma560 (C recursive Newton-Euler), the drive
(encoders, truncation, zero-order-hold current, saturation, motor-side
friction with its Coulomb ramp, Spong two-mass joints, backlash dead zone) is
written afresh there, and the equations are integrated by scipy's DOP853.
The library is used only to *evaluate the reference formula*
(``plant.logs.trajectory.Trajectory``, so the sidecar's formula is exactly the
reference the robot followed), to define the f1..f9 parameterisation when
projecting the RTB dynamics onto the paper regressor (the truth), and to
write the files (``ExperimentLog.save``).  A bug in the library's plant
therefore cannot cancel out between the log and its fit.  The simulator
reproduces the two development logs ``puma560_paper_rigid`` and
``puma560_paper_drill_flex`` pulse for pulse (an independent check of those
logs, too).

Each log is drawn at random from ``--seed`` (one child generator per log, so
log i is the same whatever ``--n``): rigid or compliant joints, payload,
encoders, P gains (stable loops only), sample time, Kt, Jm, gear ratios,
trajectory (paper or multisine), friction known or unknown, current noise,
backlash (see :func:`draw_settings`).  Each log is then identified with the
library's default call exactly as a user would make it,
``identification.identify(log, rng=0, progress=False)`` (timed whole; the
numba kernels are warmed first in each worker by one identification of the
bundled drill log, so compile time is excluded), compared with the truth, and
the computed-torque controller built from the result
(``ctc.ComputedTorqueController.from_result``) is run on the same independent
robot along the log's trajectory.

Run
---
::

    pip install -e ".[bench]"          # roboticstoolbox-python (and cma)
    python benchmarks/bench_robustness.py --n 20 --seed 20261122 --jobs 1
    python benchmarks/bench_robustness.py --n 100 --seed 20261122 --jobs 2 --rst docs/figures/robustness.rst

Logs and per-log results are cached in ``--out`` (default
``benchmarks/out/robustness``): an interrupted run resumes; delete a
``results/STEM.json`` to re-evaluate a log (``--evaluate-only`` never
generates, ``--generate-only`` never evaluates).
"""
from __future__ import annotations

import argparse
import json
import math
import multiprocessing as mp
import os
import sys
import time
import traceback
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE.parent))

import independent_robot as ir  # noqa: E402

DEFAULT_OUT = HERE / "out" / "robustness"
PPR_CHOICES = (250, 500, 1000, 2000, 4096)
#: largest spectral radius of the linearised sampled P loop accepted (4 poses, Coulomb ignored)
RHO_MAX = 0.9998
#: the base parameters that the paper's trajectory identifies well (targets)
F_MAIN = (0, 1, 3, 5, 6, 8)
#: a CTC run is stopped (and reported diverged) once an error exceeds this many pulses
CTC_DIVERGED_PULSES = 5000
F_MAIN_NAMES = tuple(f"f{i + 1}" for i in F_MAIN)

TARGETS = {
    "f_within_2pct": 0.95, "flagged_beyond_5pct": 1.0, "K_within_10pct": 0.95,
    "friction_within_15pct": 1.0, "backlash_within_30pct": 1.0, "coverage_3std": 0.95,
    "ctc_within_1pulse": 0.90,
}


#: A reference is feasible when a perfect tracker needs at most this fraction of
#: the drive's full-scale current (the rest is the feedback's headroom).
FEASIBLE_FRACTION = 0.7


# ----------------------------------------------------------------------------- draws
def _multisine(rng):
    """A random multisine reference (sidecar parameters) and its duration."""
    from plant.logs.trajectory import Trajectory

    duration = float(rng.uniform(2.0, 5.0))
    t_ramp = float(rng.uniform(0.3, 0.5))
    c, terms = [], []
    for _ in range(2):
        m = int(rng.integers(2, 5))
        f_hz = rng.uniform(0.2, 2.0, m)
        om = 2 * math.pi * f_hz
        amp = rng.uniform(0.2, 1.0, m) * rng.choice([-1.0, 1.0], m)
        ph = rng.uniform(0, 2 * math.pi, m)
        budget = float(rng.uniform(0.6, 1.0))  # |c| + sum |A| <= budget (rad)
        cj = float(rng.uniform(-0.3, 0.3))
        amp *= (budget - abs(cj)) / np.sum(np.abs(amp))
        acc = float(np.sum(np.abs(amp) * om ** 2))
        if acc > 40.0:  # cap the peak reference acceleration (rad/s^2)
            amp *= 40.0 / acc
        c.append(cj)
        terms.append([[float(a), float(w), float(p)] for a, w, p in zip(amp, om, ph)])
    traj = Trajectory.from_terms(c, terms, t_ramp)
    return traj.to_parameters(), duration, dict(kind="multisine", n_terms=[len(t) for t in terms])


def _paper(rng):
    from plant.logs.trajectory import Trajectory

    T = float(rng.uniform(1.5, 5.0))
    return Trajectory.paper(T).to_parameters(), T, dict(kind="paper", T_s=T)


def random_payload(rng, mass_kg=(0.0, 5.0)) -> dict:
    """A payload (RTB link-6 frame): mass uniform in ``mass_kg``, centre of mass up to
    0.15 m from the flange in a random direction, diagonal inertia about it."""
    mass = float(rng.uniform(*mass_kg))
    d = rng.normal(size=3)
    d *= rng.uniform(0.0, 0.15) / np.linalg.norm(d)
    return {"mass_kg": mass, "com_m_rtb_frame6": [float(x) for x in d],
            "inertia_about_com_kgm2": [float(x) for x in mass * rng.uniform(2e-4, 2e-3, 3)]}


def draw_settings(seed: int, index: int) -> tuple[ir.RobotSettings, dict]:
    """Settings of log ``index`` of the suite ``seed`` (independent of the suite size).

    Feasibility: a reference that a perfect tracker could only follow with more
    than :data:`FEASIBLE_FRACTION` of the full-scale current (inverse dynamics
    of the independent robot along it) is redrawn from a separate stream (and
    after every ten such redraws the payload too), so a feasible first draw is
    unchanged; the redraws are recorded.

    Stability: the P gains are redrawn until the linearised sampled P loop is
    stable with margin (spectral radius <= RHO_MAX at four poses, Coulomb
    friction ignored, :meth:`IndependentRobot.linear_loop_radius`); after 20
    rejected gain draws the drive and joint block (Kt, Jm, B, Tc, and K, D of
    flexible joints) is redrawn too.  The number of rejected draws is
    recorded.  The suite is thus drawn from the stated ranges *conditioned on
    a stable loop* (low Jm with a soft spring and a long sample time, for
    one, has no stable P gain in 0.1-0.6 A/pulse).
    """
    rng = np.random.default_rng([int(seed), int(index)])
    flexible = bool(rng.random() < 0.5)
    s = ir.RobotSettings()
    s.flexible = flexible
    if flexible:
        if rng.random() < 0.5:
            s.backlash_rad = (0.0, 0.0)
        else:
            s.backlash_rad = tuple(float(x) for x in rng.uniform(0.5e-3, 3e-3, 2))
    s.payload = random_payload(rng)
    s.encoder_ppr = tuple(int(x) for x in rng.choice(PPR_CHOICES, 2))
    s.sample_time_s = float(rng.uniform(0.5e-3, 1e-3))
    s.gear_ratio = (float(107.8 * rng.uniform(0.8, 1.2)), float(-53.7 * rng.uniform(0.8, 1.2)))
    if rng.random() < 0.5:
        s.trajectory, s.duration_s, traj_info = _paper(rng)
    else:
        s.trajectory, s.duration_s, traj_info = _multisine(rng)
    s.friction_known = bool(rng.random() < 0.5)
    s.v_reg = float(rng.uniform(0.25, 1.0))
    s.current_noise_std_A = float(rng.uniform(0.0, 0.1))
    redraws = 0
    rho = math.inf
    for attempt in range(400):
        if attempt % 20 == 0:  # the drive and joint block, redrawn after 20 rejected gain draws
            s.kt = tuple(float(x) for x in rng.uniform(0.15, 0.3, 2))
            s.jm_kgm2 = tuple(float(x) for x in rng.uniform(100e-6, 300e-6, 2))
            s.viscous_B = tuple(float(x) for x in rng.uniform(0.5e-3, 1e-2, 2))
            s.coulomb_Tc = tuple(tuple(float(v) for v in rng.uniform(0.03, 0.2, 2)) for _ in range(2))
            if flexible:
                s.K = tuple(float(x) for x in np.exp(rng.uniform(math.log(5e3), math.log(1e5), 2)))
                s.D = tuple(float(x) for x in np.exp(rng.uniform(math.log(0.1), math.log(10.0), 2)))
        s.p_gain = tuple(float(x) for x in rng.uniform(0.1, 0.6, 2))
        rho = ir.stability_radius(s)
        if rho <= RHO_MAX:
            break
        redraws += 1
    else:
        raise RuntimeError(f"no stable drive found for log {index}")
    # Feasibility: the reference must be within the drive's torque (a test engineer
    # never runs an experiment whose reference needs more than the full-scale current:
    # the loop then saturates and the robot cannot follow).  An infeasible reference is
    # redrawn from a separate stream, so that a feasible first draw is unchanged.
    traj_redraws = 0
    rng_t = np.random.default_rng([int(seed), int(index), 2])
    i_fs = float(s.current_full_scale_A or math.inf)
    while True:
        from plant.logs.trajectory import Trajectory

        traj = Trajectory.from_sidecar(s.trajectory)
        need = ir.IndependentRobot(s).required_current(
            traj, int(round(s.duration_s / s.sample_time_s)) + 1)
        if np.all(need <= FEASIBLE_FRACTION * i_fs):
            break
        traj_redraws += 1
        if traj_redraws > 100:
            raise RuntimeError(f"no feasible reference found for log {index}")
        if traj_redraws % 10 == 0:  # the drive cannot carry this payload on any reference
            s.payload = random_payload(rng_t)
        if rng_t.random() < 0.5:
            s.trajectory, s.duration_s, traj_info = _paper(rng_t)
        else:
            s.trajectory, s.duration_s, traj_info = _multisine(rng_t)
    info = dict(seed=int(seed), index=int(index), trajectory=traj_info, stability_radius=rho,
                drive_redraws=redraws, rho_max=RHO_MAX, trajectory_redraws=traj_redraws,
                required_current_A=[float(x) for x in need],
                feasible_fraction=FEASIBLE_FRACTION)
    return s, info


def stem_of(seed: int, index: int) -> str:
    return f"indep_{seed}_{index:04d}"


def generate(seed: int, index: int, out: Path) -> Path:
    """Make (or find cached) log ``index``; return its CSV path."""
    stem = stem_of(seed, index)
    logs = out / "logs"
    logs.mkdir(parents=True, exist_ok=True)
    csv = logs / f"{stem}.csv"
    if csv.exists() and (logs / f"{stem}.truth.json").exists() and (logs / f"{stem}.json").exists():
        return csv
    s, info = draw_settings(seed, index)
    ir.make_log(s, logs / stem, rng=np.random.default_rng([int(seed), int(index), 1]),
                extra_truth={"draw": info})
    return csv


# ----------------------------------------------------------------------------- evaluation
_WARM = {"done": False}


def warm():
    """Compile / load the numba kernels once per process (excluded from the timings)."""
    if _WARM["done"]:
        return
    import identification
    import plant

    plant.warm_up()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        identification.identify(plant.load_example("drill_flex"), rng=0, progress=False)
    _WARM["done"] = True


def _rel(a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    return np.abs(a - b) / np.maximum(np.abs(b), 1e-12)


def _get(res, key):
    try:
        return res[key]
    except (KeyError, TypeError):
        return getattr(res, key, None)


def evaluate(csv: Path, out: Path) -> dict:
    """Identify one log with the default call, compare with the truth, run the CTC; cache the row."""
    stem = csv.stem
    res_dir = out / "results"
    res_dir.mkdir(parents=True, exist_ok=True)
    cache = res_dir / f"{stem}.json"
    if cache.exists():
        return json.loads(cache.read_text())
    truth = json.loads((csv.parent / f"{stem}.truth.json").read_text())
    s = ir.RobotSettings.from_dict(truth["settings"])
    f_true = np.asarray(truth["f_vector"], float)
    row = dict(stem=stem, settings=settings_summary(truth), error=None)
    try:
        import identification
        import plant

        warm()
        log = plant.load_log(csv)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            t0 = time.perf_counter()
            res = identification.identify(log, rng=0, progress=False)
            wall = time.perf_counter() - t0
        row["warnings"] = sorted({f"{w.category.__name__}: {w.message}" for w in caught})
        row["wall_time_s"] = wall
        res.save_json(res_dir / f"{stem}.result.json")  # for --ctc-only
        f = np.asarray(res.f, float)
        row["f"] = f.tolist()
        row["f_true"] = f_true.tolist()
        err = _rel(f, f_true)
        row["f_rel_err"] = err.tolist()
        row["f_main_err_max"] = float(np.max(err[list(F_MAIN)]))
        fun = _get(res, "fun")
        row["fun"] = float(fun) if fun is not None and np.isfinite(fun) else None
        row["fun_per_sample"] = None if row["fun"] is None else row["fun"] / (2 * log.n_samples)
        row["success"] = bool(_get(res, "success"))
        row["message"] = str(_get(res, "message"))
        row["model"] = _get(res, "model")
        # stiffness
        K_true = truth["joints"]["stiffness_Nm_per_rad"]
        K_id = _get(res, "joint_stiffness_Nm_per_rad")
        row["K_id"] = None if K_id is None else [float(x) for x in K_id]
        row["K_rel_err_max"] = (float(np.max(_rel(K_id, K_true))) if (K_true is not None and K_id is not None)
                                else None)
        # friction (only where the sidecar left it unknown)
        fr = truth["friction"]
        row["friction_identified"] = bool(_get(res, "friction_identified"))
        if not fr["known_in_sidecar"]:
            v_id, c_id = _get(res, "viscous_friction_Nms_per_rad"), _get(res, "coulomb_friction_Nm")
            errs = {}
            if v_id is not None:
                errs["viscous"] = float(np.max(_rel(v_id, fr["viscous_friction_Nms_per_rad"])))
            if c_id is not None:
                errs["coulomb"] = float(np.max(_rel(np.asarray(c_id, float).reshape(2, 2),
                                                    np.asarray(fr["coulomb_friction_Nm"]))))
            row["friction_rel_err"] = errs
            row["friction_rel_err_max"] = (max(errs.values()) if errs and row["friction_identified"]
                                           else None)
        # backlash
        b_true = np.asarray(truth["joints"]["backlash_rad"], float)
        b_id = _get(res, "joint_backlash_rad")
        row["backlash_id"] = None if b_id is None else [float(x) for x in np.ravel(b_id)]
        big = b_true >= 1e-3
        row["backlash_rel_err_max"] = (float(np.max(_rel(np.ravel(b_id), b_true)[big]))
                                       if (b_id is not None and np.any(big)) else None)
        # coverage
        f_std = _get(res, "f_std")
        if f_std is not None:
            f_std = np.asarray(f_std, float)
            inside = np.abs(f - f_true) <= 3.0 * f_std
            row["f_std"] = f_std.tolist()
            row["coverage_3std"] = inside.tolist()
        else:
            row["coverage_3std"] = None
        row["flagged"] = (not row["success"]) or bool(row["warnings"]) or row["fun"] is None
        row["fun_huge"] = row["fun_per_sample"] is None or row["fun_per_sample"] > 4.0
        # the CTC built from the result, on the same independent robot
        row.update(ctc_row(res, log, s, truth))
    except Exception as exc:  # noqa: BLE001 - a library failure is a row, not a crash
        row["error"] = f"{type(exc).__name__}: {exc}"
        row["traceback"] = traceback.format_exc()[-2000:]
    cache.write_text(json.dumps(row, indent=1, default=_json_default) + "\n")
    return row


def ctc_row(res, log, s, truth) -> dict:
    """Run the CTC of a result on the independent robot along the log's reference."""
    import ctc

    row = {}
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            ctrl = ctc.ComputedTorqueController.from_result(res, log)
        row["ctc_type"] = type(ctrl).__name__
        row["ctc_warnings"] = [str(w.message) for w in caught]
        rob = ir.IndependentRobot(s)
        t0 = time.perf_counter()
        run = rob.run(ctrl, log.trajectory, log.n_total, max_step_fraction=ir.max_step_fraction(s),
                      max_abs_e=CTC_DIVERGED_PULSES)
        row["ctc_sim_time_s"] = time.perf_counter() - t0
        k0 = int(math.ceil(0.1 / s.sample_time_s))
        row["ctc_success"] = bool(run["success"])
        row["ctc_max_abs_e"] = np.max(np.abs(run["e"][k0:]), axis=0).astype(int).tolist()
        row["ctc_saturated"] = int(run["n_saturated"])
        # the following-error limit (ctc.guard) handed the arm to the rig's P law at this time
        row["ctc_fallback_t_s"] = getattr(ctrl, "fallback_t_s", None)
        row["p_max_abs_e"] = truth["run"]["max_abs_e_pulses"]
    except Exception as exc:  # noqa: BLE001
        row["ctc_error"] = f"{type(exc).__name__}: {exc}"
        row["ctc_max_abs_e"] = None
    return row


def recheck_ctc(csv: Path, out: Path) -> dict:
    """Re-run only the CTC part of a cached row from its saved result (``--ctc-only``)."""
    import identification
    import plant

    stem = csv.stem
    cache = out / "results" / f"{stem}.json"
    saved = out / "results" / f"{stem}.result.json"
    if not (cache.exists() and saved.exists()):
        return evaluate(csv, out)
    row = json.loads(cache.read_text())
    truth = json.loads((csv.parent / f"{stem}.truth.json").read_text())
    s = ir.RobotSettings.from_dict(truth["settings"])
    res = identification.IdentificationResult.load_json(saved)
    for key in ("ctc_error", "ctc_type", "ctc_warnings", "ctc_fallback_t_s"):
        row.pop(key, None)
    row.update(ctc_row(res, plant.load_log(csv), s, truth))
    cache.write_text(json.dumps(row, indent=1, default=_json_default) + "\n")
    return row


def _json_default(o):
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    return str(o)


def settings_summary(truth: dict) -> dict:
    st = truth["settings"]
    draw = truth.get("draw", {})
    j = truth["joints"]
    return dict(
        joints=j["model"],
        K=None if j["stiffness_Nm_per_rad"] is None else [round(x) for x in j["stiffness_Nm_per_rad"]],
        D=None if j["damping_Nms_per_rad"] is None else [round(x, 2) for x in j["damping_Nms_per_rad"]],
        backlash_mrad=[round(1e3 * x, 2) for x in j["backlash_rad"]],
        payload_kg=round(0.0 if not st["payload"] else st["payload"]["mass_kg"], 2),
        ppr=st["encoder_ppr"], P=[round(x, 3) for x in st["p_gain"]],
        Ts_ms=round(1e3 * st["sample_time_s"], 3), kt=[round(x, 3) for x in st["kt"]],
        gear=[round(x, 1) for x in st["gear_ratio"]],
        traj=draw.get("trajectory", {}).get("kind", "?"), duration_s=round(st["duration_s"], 2),
        friction="known" if st["friction_known"] else "unknown",
        noise_A=round(st["current_noise_std_A"], 3),
        n_samples=int(round(st["duration_s"] / st["sample_time_s"])) + 1,
        p_sat=truth["run"]["n_saturated"], p_max_e=truth["run"]["max_abs_e_pulses"],
    )


# ----------------------------------------------------------------------------- reporting
def _frac(xs):
    xs = [x for x in xs if x is not None]
    return (sum(bool(x) for x in xs), len(xs))


def summarise(rows: list[dict]) -> dict:
    ok = [r for r in rows if r.get("error") is None]
    no_loop = [r for r in rows if r.get("generation_failed")]
    comp = [r for r in ok if r["settings"]["joints"] == "flexible"]
    unk = [r for r in ok if r["settings"]["friction"] == "unknown"]
    blog = [r for r in ok if max(r["settings"]["backlash_mrad"]) >= 1.0]
    cov = [c for r in ok if r.get("coverage_3std") for c in r["coverage_3std"]]
    beyond5 = [r for r in ok if r["f_main_err_max"] > 0.05]
    walls = [r["wall_time_s"] for r in ok]
    s = {
        "n_logs": len(rows) - len(no_loop), "n_errors": len(rows) - len(ok) - len(no_loop),
        "n_draws_without_stable_loop": len(no_loop),
        "f_within_2pct": _frac([r["f_main_err_max"] <= 0.02 for r in ok]),
        "flagged_beyond_5pct": _frac([r["flagged"] for r in beyond5]),
        "K_within_10pct": _frac([(r["K_rel_err_max"] is not None and r["K_rel_err_max"] <= 0.10) for r in comp]),
        "friction_within_15pct": _frac([(r.get("friction_rel_err_max") is not None
                                         and r["friction_rel_err_max"] <= 0.15) for r in unk]),
        "backlash_within_30pct": _frac([(r.get("backlash_rel_err_max") is not None
                                         and r["backlash_rel_err_max"] <= 0.30) for r in blog]),
        "coverage_3std": _frac(cov),
        "ctc_within_1pulse": _frac([(r.get("ctc_max_abs_e") is not None and max(r["ctc_max_abs_e"]) <= 1)
                                    for r in ok]),
        "median_wall_time_s": float(np.median(walls)) if walls else None,
        "max_wall_time_s": float(np.max(walls)) if walls else None,
        "flagged": _frac([r["flagged"] for r in ok]),
    }
    s["pass"] = {k: (s[k][1] == 0 or s[k][0] / s[k][1] >= TARGETS[k]) for k in TARGETS}
    return s


def _fmt(x, pct=False, nd=2):
    if x is None:
        return "-"
    return f"{100 * x:.{nd}f}%" if pct else f"{x:.{nd}g}"


COLS = ("stem", "joints", "K", "bl_mrad", "kg", "ppr", "P", "Ts", "traj", "fric", "noise",
        "f_err", "K_err", "fr_err", "bl_err", "cov", "flag", "model", "ctc|e|", "wall_s")


def table_rows(rows):
    out = []
    for r in rows:
        st = r["settings"]
        if r.get("generation_failed"):
            out.append([r["stem"][-4:], "no log: " + r["error"][:60]] + [""] * (len(COLS) - 2))
            continue
        if r.get("error"):
            out.append([r["stem"][-4:], st["joints"], str(st["K"]), str(st["backlash_mrad"]),
                        str(st["payload_kg"]), str(st["ppr"]), str(st["P"]), str(st["Ts_ms"]),
                        st["traj"], st["friction"], str(st["noise_A"]), "ERROR", r["error"][:40],
                        "", "", "", "", "", "", ""])
            continue
        cov = r.get("coverage_3std")
        out.append([
            r["stem"][-4:], st["joints"][:4], str(st["K"]), str(st["backlash_mrad"]),
            str(st["payload_kg"]), str(st["ppr"]), str(st["P"]), str(st["Ts_ms"]),
            f"{st['traj'][:5]} {st['duration_s']}", st["friction"][:3], str(st["noise_A"]),
            _fmt(r["f_main_err_max"], True), _fmt(r.get("K_rel_err_max"), True, 1),
            _fmt(r.get("friction_rel_err_max"), True, 1), _fmt(r.get("backlash_rel_err_max"), True, 0),
            "-" if cov is None else f"{sum(cov)}/{len(cov)}",
            ("F" if not r["success"] else "") + (f"W{len(r['warnings'])}" if r["warnings"] else "") or ".",
            str(r.get("model")), str(r.get("ctc_max_abs_e")), f"{r['wall_time_s']:.2f}",
        ])
    return out


def print_table(rows, file=sys.stdout):
    data = table_rows(rows)
    w = [max(len(c), *(len(d[i]) for d in data)) if data else len(c) for i, c in enumerate(COLS)]
    print("  ".join(c.ljust(w[i]) for i, c in enumerate(COLS)), file=file)
    for d in data:
        print("  ".join(x.ljust(w[i]) for i, x in enumerate(d)), file=file)


def print_summary(s, rows, file=sys.stdout):
    def line(key, label):
        k, n = s[key]
        pct = f"{100 * k / n:.0f}%" if n else "n/a"
        print(f"  {label:<48} {k}/{n} = {pct:>5}  target >= {100 * TARGETS[key]:.0f}%  "
              f"{'PASS' if s['pass'][key] else 'FAIL'}", file=file)

    print(f"\nsummary over {s['n_logs']} logs ({s['n_errors']} library errors; "
          f"{s['n_draws_without_stable_loop']} draws had no stable P loop and no log):", file=file)
    line("f_within_2pct", "f1 f2 f4 f6 f7 f9 within 2 %")
    line("flagged_beyond_5pct", "logs beyond 5 % flagged by their result")
    line("K_within_10pct", "K within 10 % (compliant logs)")
    line("friction_within_15pct", "friction within 15 % (unknown friction)")
    line("backlash_within_30pct", "backlash within 30 % (>= 1 mrad)")
    line("coverage_3std", "truth within 3 f_std (all f)")
    line("ctc_within_1pulse", "CTC max|e| <= 1 pulse after 0.1 s")
    print(f"  median wall time of identify(): {s['median_wall_time_s']:.2f} s "
          f"(max {s['max_wall_time_s']:.2f} s; numba warmed first)", file=file)
    ok = [r for r in rows if r.get("error") is None]
    handed = [r for r in ok if r.get("ctc_fallback_t_s") is not None]
    print(f"  CTC handed to the rig's P law by its following-error limit: {len(handed)} "
          + "".join(f"\n    {r['stem']} at {r['ctc_fallback_t_s']:.3f} s: max|e| after 0.1 s "
                    f"{r['ctc_max_abs_e']} (P loop's log {r.get('p_max_abs_e')})" for r in handed),
          file=file)

    def badness(r):
        if r.get("error"):
            return math.inf
        return r["f_main_err_max"]

    worst = sorted([r for r in rows if not r.get("generation_failed")], key=badness,
                   reverse=True)[:5]
    print("\nworst five logs (by f1 f2 f4 f6 f7 f9 error):", file=file)
    for r in worst:
        st = r["settings"]
        what = r["error"] if r.get("error") else (
            f"f_err {_fmt(r['f_main_err_max'], True)} (per f: "
            + ", ".join(f"{n} {100 * r['f_rel_err'][i]:.2f}%" for n, i in zip(F_MAIN_NAMES, F_MAIN))
            + f"), model {r.get('model')}, success {r['success']}, warnings {r['warnings']}, "
            f"K_err {_fmt(r.get('K_rel_err_max'), True, 1)}, fric_err {_fmt(r.get('friction_rel_err_max'), True, 1)}, "
            f"CTC {r.get('ctc_max_abs_e')}")
        print(f"  {r['stem']}: {json.dumps(st)}\n      -> {what}", file=file)
    del ok


TARGET_LABELS = {
    "f_within_2pct": "f1 f2 f4 f6 f7 f9 within 2 %",
    "flagged_beyond_5pct": "logs beyond 5 % flagged by their result",
    "K_within_10pct": "K within 10 % (compliant logs)",
    "friction_within_15pct": "friction within 15 % (unknown friction)",
    "backlash_within_30pct": "backlash within 30 % (>= 1 mrad)",
    "coverage_3std": "truth within 3 f_std (all f)",
    "ctc_within_1pulse": "CTC max abs(e) <= 1 pulse after 0.1 s",
}


def write_rst(rows, s, path: Path):
    """The docs' tables: the success rates, the worst five logs; the per-log table beside."""
    lines = [f"{s['n_logs']} logs (seed {rows[0]['stem'].split('_')[1]}; "
             f"{s['n_draws_without_stable_loop']} further draws had no stable P loop in the "
             f"gain range and made no log; {s['n_errors']} library errors).", ""]
    w0 = max(len(v) for v in TARGET_LABELS.values())
    bar = "=" * w0 + "  ==========  =======  ========"
    lines += [bar, f"{'target'.ljust(w0)}  result      rate     goal", bar]
    for key, label in TARGET_LABELS.items():
        k, n = s[key]
        rate = f"{100 * k / n:.1f} %" if n else "n/a"
        lines.append(f"{label.ljust(w0)}  {f'{k} / {n}'.ljust(10)}  {rate.ljust(7)}  "
                     f">= {100 * TARGETS[key]:.0f} %")
    lines += [bar, "", f"Median wall time of the default ``identify(log)``: "
              f"{s['median_wall_time_s']:.2f} s (max {s['max_wall_time_s']:.1f} s; kernels "
              "compiled beforehand).", ""]
    ok = [r for r in rows if r.get("error") is None]
    worst = sorted(ok, key=lambda r: r["f_main_err_max"], reverse=True)[:5]
    data = [d for d in table_rows(worst)]
    wc = [max(len(c), *(len(d[i]) for d in data)) if data else len(c) for i, c in enumerate(COLS)]
    bar = "  ".join("=" * x for x in wc)
    lines += ["The five logs with the largest f error:", "", bar,
              "  ".join(c.ljust(wc[i]) for i, c in enumerate(COLS)), bar]
    lines += ["  ".join((x if x else "..").ljust(wc[i]) for i, x in enumerate(d)) for d in data]
    lines += [bar, ""]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines) + "\n")
    with open(path.with_suffix(".txt"), "w") as fh:  # every log, as the benchmark prints it
        print_table(rows, file=fh)
        print_summary(s, rows, file=fh)


# ----------------------------------------------------------------------------- committed test logs
TEST_LOG_DIR = HERE.parent / "tests" / "data" / "independent"


def test_log_settings() -> dict:
    """The five short logs committed in ``tests/data/independent`` (made once with :func:`make_test_logs`)."""
    from plant.logs.trajectory import Trajectory

    base = dict(sample_time_s=0.0007, gear_ratio=(107.8, -53.7), encoder_ppr=(1000, 1000),
                p_gain=(0.15, 0.15), kt=(0.22, 0.22), jm_kgm2=(200e-6, 200e-6),
                viscous_B=(0.0068, 0.0074), coulomb_Tc=((0.071, 0.126), (0.105, 0.132)), v_reg=0.5)
    drill = lambda m: {"mass_kg": m, "com_m_rtb_frame6": [0.01, -0.02, 0.1],  # noqa: E731
                       "inertia_about_com_kgm2": [2e-3 * m, 2e-3 * m, 7e-4 * m]}
    ms = Trajectory.from_terms(
        [-0.2, 0.3],
        [[(0.35, 2 * math.pi * 0.7, 0.3), (0.2, 2 * math.pi * 1.6, 1.1)],
         [(-0.3, 2 * math.pi * 0.9, 0.0), (0.15, 2 * math.pi * 1.9, 2.0), (0.1, 2 * math.pi * 0.4, 0.5)]],
        0.4).to_parameters()
    paper = lambda T: Trajectory.paper(T).to_parameters()  # noqa: E731
    mk = lambda **kw: ir.RobotSettings(**{**base, **kw})  # noqa: E731
    return {
        "indep_a_rigid_friction_unknown": mk(
            trajectory=paper(2.0), duration_s=2.0, friction_known=False, encoder_ppr=(1000, 2000)),
        "indep_b_flex_friction_known_2kg": mk(
            trajectory=paper(1.8), duration_s=1.8, flexible=True, K=(3e4, 6e3), D=(4.0, 0.4),
            payload=drill(2.0), encoder_ppr=(800, 1000)),
        "indep_c_flex_friction_unknown_noise": mk(
            trajectory=ms, duration_s=2.0, flexible=True, K=(2e4, 1.2e4), D=(2.0, 1.0),
            friction_known=False, current_noise_std_A=0.08, encoder_ppr=(2000, 1000),
            payload=drill(1.0)),
        "indep_d_flex_backlash_2mrad": mk(
            trajectory=paper(2.0), duration_s=2.0, flexible=True, K=(3e4, 1e4), D=(3.0, 0.8),
            backlash_rad=(2e-3, 0.0), encoder_ppr=(1000, 1000)),
        "indep_e_stiff_4kg_250ppr": mk(
            trajectory=ms, duration_s=2.0, flexible=True, K=(6e4, 2.5e4), D=(5.0, 2.0),
            payload=drill(4.0), encoder_ppr=(250, 250), p_gain=(0.5, 0.5)),
    }


#: Drawn logs of this suite committed beside the five (seed, index): a draw whose
#: default identification once failed, kept as a regression test --
#: 20261205/13, rigid joints with heavy unknown Coulomb friction, where the GA's
#: starts all ended in a wrong basin (f7 8 % off, a flexible model chosen) until
#: the refinement also started from the IDIM-LS estimate.
DRAWN_TEST_LOGS = ((20261205, 13),)


def make_test_logs(out: Path = TEST_LOG_DIR) -> None:
    """Write the five fixed logs of :func:`test_log_settings` and the drawn ones of
    :data:`DRAWN_TEST_LOGS` (their draws' stems) to ``out``."""
    import shutil
    import tempfile

    out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        for seed, index in DRAWN_TEST_LOGS:
            csv = generate(seed, index, Path(tmp))
            for suffix in (".csv", ".json", ".truth.json"):
                shutil.copyfile(csv.parent / f"{csv.stem}{suffix}", out / f"{csv.stem}{suffix}")
            print(f"{csv.stem}: drawn (seed {seed}, index {index})", flush=True)
    for i, (stem, s) in enumerate(test_log_settings().items()):
        rho = ir.stability_radius(s)
        if rho > RHO_MAX:
            raise RuntimeError(f"{stem}: linearised P loop radius {rho} > {RHO_MAX}")
        t0 = time.perf_counter()
        info = ir.make_log(s, out / stem, rng=np.random.default_rng([7, i]),
                           extra_truth={"draw": {"trajectory": {"kind": "fixed"}, "stability_radius": rho,
                                                 "rho_max": RHO_MAX, "made_by": "bench_robustness.make_test_logs"}})
        print(f"{stem}: {s.n_samples} samples in {time.perf_counter() - t0:.1f} s, "
              f"P max|e| {info['truth']['run']['max_abs_e_pulses']}, residual "
              f"{info['truth']['regression_rel_residual']:.1e}, rho {rho:.6f}", flush=True)


# ----------------------------------------------------------------------------- main
def _job(args):
    task, seed, index, out = args
    out = Path(out)
    try:
        csv = generate(seed, index, out)
    except Exception as exc:  # noqa: BLE001
        return dict(stem=stem_of(seed, index), settings={}, error=f"generation: {type(exc).__name__}: {exc}",
                    generation_failed=True)
    if task == "generate":
        return dict(stem=csv.stem)
    if task == "ctc":
        return recheck_ctc(csv, out)
    return evaluate(csv, out)


def run_jobs(fn, jobs, n_jobs) -> list:
    """``fn`` over ``jobs`` in order, on up to two spawned processes; a line per finished job.

    With two processes each runs numba single-threaded (``NUMBA_NUM_THREADS=1``
    unless set): two processes of two threads each on the 2 cores took 3.5x
    the wall time of one process alone on a backlash log (61 s -> 215 s),
    and the per-log wall times would mostly measure that contention.
    """
    t0 = time.perf_counter()
    rows = []
    if n_jobs > 1:
        os.environ.setdefault("NUMBA_NUM_THREADS", "1")  # read by the spawned workers' numba
        with mp.get_context("spawn").Pool(min(n_jobs, 2)) as pool:
            for row in pool.imap(fn, jobs):
                rows.append(row)
                print(f"[{time.perf_counter() - t0:7.1f} s] {row['stem']} done", flush=True)
    else:
        for j in jobs:
            rows.append(fn(j))
            print(f"[{time.perf_counter() - t0:7.1f} s] {rows[-1]['stem']} done", flush=True)
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, default=20)
    ap.add_argument("--seed", type=int, default=20261122)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT)
    ap.add_argument("--generate-only", action="store_true")
    ap.add_argument("--evaluate-only", action="store_true")
    ap.add_argument("--ctc-only", action="store_true",
                    help="re-run only the CTC of each cached result on its robot (after a "
                         "controller change); logs without a cached result are evaluated")
    ap.add_argument("--rst", type=Path, default=None)
    ap.add_argument("--make-test-logs", action="store_true",
                    help="(re)write the committed logs in tests/data/independent and exit")
    a = ap.parse_args(argv)
    if a.make_test_logs:
        make_test_logs()
        return 0
    a.out.mkdir(parents=True, exist_ok=True)
    task = "generate" if a.generate_only else "ctc" if a.ctc_only else "evaluate"
    indices = list(range(a.n))
    # (--evaluate-only / --ctc-only: a log not generated yet is generated; a draw
    # without a stable loop is reported as such, as in a full run)
    jobs = [(task, a.seed, i, str(a.out)) for i in indices]
    rows = run_jobs(_job, jobs, a.jobs)
    if task == "generate":
        print(f"generated {len(rows)} logs in {a.out / 'logs'}")
        return 0
    rows = [r for r in rows if not r.get("generation_failed")] + \
           [r for r in rows if r.get("generation_failed")]
    print()
    print_table(rows)
    s = summarise(rows)
    print_summary(s, rows)
    (a.out / f"summary_{a.seed}_{a.n}.json").write_text(
        json.dumps(dict(summary=s, rows=rows), indent=1, default=_json_default) + "\n")
    print(f"\nrows written to {a.out / f'summary_{a.seed}_{a.n}.json'}")
    if a.rst:
        write_rst(rows, s, a.rst)
        print(f"RST table written to {a.rst}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
