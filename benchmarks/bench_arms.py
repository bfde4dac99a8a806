"""Any serial arm on logs from an independent simulator: identify, then CTC vs P (issue 23).

For each family (``planar2``: random two-link arms in a vertical plane;
``puma123``: PUMA 560 joints 1-3; ``puma6``: the six-joint PUMA 560;
``random``: chains of 2-4 joints from random DH tables, standard or
modified, on a randomly tilted base; ``urdf``: random URDF chains, their
dynamics pinocchio's) and each
draw of ``benchmarks/independent_arm.py`` (robot, gears, encoders, torque
constants, motor inertias, friction, P gains, multisine reference; seeds
``seed + i``, chosen before looking), this benchmark

1. makes a 5 s P-control log with the independent simulator (Robotics
   Toolbox ``rne``, DOP853; rigid, friction known);
2. identifies the base parameters with the library
   (:func:`identification.arm.identify_arm`: IDIM-LS start, output-error
   refinement), timing it;
3. compares with the truth: a base parameter is *well excited* when the
   log determines it to a third of the 1 % tolerance (relative standard
   error < 1/3 %, so that a correct estimate lies within 1 % at 3 sigma);
   the criterion is that every well-excited parameter is within 1 %;
   the friction the sidecar leaves ``null`` (half of the draws) is
   identified with them and compared with the drawn one;
4. runs the computed-torque controller built from the identified
   parameters (:class:`ctc.arm.ArmComputedTorque`) on the same independent
   robot and checks ``abs(e) <= 1`` pulse on every joint after 0.1 s, with
   the rig's P card as the baseline.

Usage::

    python benchmarks/bench_arms.py --n 10 8 6 --seed 20261122 [--json out.json] [--jobs 2]
    python benchmarks/bench_arms.py --n 0 0 0 12 --seed 20262711   # random DH chains only
    python benchmarks/bench_arms.py --n 0 0 0 0 12 --seed 20262741 # random URDF chains only
    python benchmarks/bench_arms.py --compliant --cases a.json b.json [--rst out.rst]

``--jobs`` runs the draws in parallel processes (the identification times
then share the cores); ``--cases`` summarises the ``--json`` files of
earlier runs (e.g. one family per process) without running anything.

Prints one line per draw and a summary per family (success rates, worst
cases with their settings).  Needs the ``bench`` extra (Robotics Toolbox).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import independent_arm as ia  # noqa: E402

TOLERANCE = 0.01
WELL_EXCITED_RSE = TOLERANCE / 3.0


def well_excited_check(res, beta):
    """The criterion of step 3: every well-excited base parameter within TOLERANCE.

    Parameters
    ----------
    res : identification.arm.ArmIdentificationResult
    beta : ndarray, shape (r,)
        The true base parameters.

    Returns
    -------
    err : ndarray, shape (r,)
        Relative errors of the identified beta.
    well : ndarray of bool, shape (r,)
        Relative standard error below :data:`WELL_EXCITED_RSE`.
    worst : int
        Index of the largest well-excited error (-1 when none is well excited).
    ok : bool
        The identification succeeded, at least one base parameter is well
        excited, and every well-excited error is within :data:`TOLERANCE`.
    """
    beta = np.asarray(beta, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        err = np.abs(np.asarray(res.beta, dtype=float) / beta - 1.0)
    well = np.asarray(res.x_rse, dtype=float)[:len(beta)] < WELL_EXCITED_RSE
    worst = int(np.argmax(np.where(well, err, -1.0))) if np.any(well) else -1
    # a log that determines no base parameter to the tolerance is no success either
    return err, well, worst, (bool(np.any(well)) and bool(np.all(err[well] <= TOLERANCE))
                              and bool(res.success))


def run_case(family: str, seed: int, compliant: bool = False) -> dict:
    from ctc.arm import ArmComputedTorque
    from identification.arm import identify_arm

    s = ia.draw(family, seed, compliant=compliant)
    t0 = time.perf_counter()
    log = ia.make_log(s)
    t_log = time.perf_counter() - t0
    names, beta = ia.truth_beta(s, log.model)
    res = identify_arm(log)
    err, well, worst, ok_params = well_excited_check(res, beta)
    fr_err = fr_ok = None
    if not s.friction_known:  # the identified friction (joint side) against the drawn one
        from identification.friction import FRICTION_COMPONENTS, friction_layout

        k = np.abs(np.asarray(s.gear_ratio))
        true = np.column_stack([k ** 2 * np.asarray(s.viscous), k[:, None] * np.asarray(s.coulomb)])
        errs, oks = [], []
        for j, w in friction_layout(log.rig)[1]:
            # by name: a flexible result's x holds the joints between beta and the friction
            i = list(res.names).index(f"{FRICTION_COMPONENTS[w]}_{log.joint_names[j]}")
            est, sd, t = res.x[i], res.x_std[i], true[j, w]
            errs.append(abs(est - t) / abs(t) if t else float("inf"))
            # within 15 %, or within 3 of its own standard errors (a component the log
            # hardly excites, e.g. a Coulomb level far below the viscous torque, says so)
            oks.append(bool(abs(est - t) <= max(0.15 * abs(t), 3.0 * sd)))
        fr_err, fr_ok = 100.0 * float(max(errs)), bool(all(oks))
    joints = None
    if compliant:  # the joints against the drawn ones (K, Ia within 10 %, backlash >= 1 mrad within 30 %)
        k = np.asarray(s.gear_ratio)
        true = dict(K=np.asarray(s.stiffness), Ia=np.asarray(s.motor_inertia) * k ** 2,
                    b=np.asarray(s.backlash))
        joints = dict(model=res.model_choice.get("model") if res.model_choice else res.model,
                      # the chosen model's held-back cost in quantisation floors, and whether
                      # the backlash was fitted (not when the springs reach the floor)
                      floors=round(float((res.model_choice or {}).get("floor_ratio", float("nan"))), 3),
                      backlash_tried="held_back_cost_backlash_pulses2" in (res.model_choice or {}),
                      K_true=true["K"].round(1).tolist(), b_true_mrad=(1e3 * true["b"]).round(3).tolist())
        mc = res.model_choice or {}
        if mc.get("floor_pulses2"):  # the model choice ran: what each model left, its tests
            joints["held_back_floors"] = {
                k: round(float(mc[f"held_back_cost_{k}_pulses2"]) / float(mc["floor_pulses2"]), 3)
                for k in ("rigid", "springs", "backlash") if f"held_back_cost_{k}_pulses2" in mc}
            joints["paired_t"] = {k: round(float(mc[f"{k}_paired_t"]), 2)
                                  for k in ("flexible", "backlash") if f"{k}_paired_t" in mc}
        if res.joint_stiffness_Nm_per_rad is not None:
            K = np.asarray(res.joint_stiffness_Nm_per_rad)
            Ia = np.asarray(res.motor_inertia_reflected_kgm2)
            joints.update(K_err_pct=(100 * np.abs(K / true["K"] - 1)).round(2).tolist(),
                          Ia_err_pct=(100 * np.abs(Ia / true["Ia"] - 1)).round(2).tolist())
            big = true["b"] >= 1e-3
            if np.any(big):
                b = np.zeros_like(true["b"]) if res.joint_backlash_rad is None else \
                    np.asarray(res.joint_backlash_rad)
                joints["b_err_pct"] = (100 * np.abs(b[big] / true["b"][big] - 1)).round(2).tolist()
        joints["K_ok"] = bool(joints.get("K_err_pct") is not None and max(joints["K_err_pct"]) <= 10)
        joints["b_ok"] = bool(max(joints.get("b_err_pct", [0.0]) or [0.0]) <= 30) if joints.get("K_err_pct") else \
            not bool(np.any(true["b"] >= 1e-3))
    k0 = int(round(0.1 / s.sample_time_s))
    ctrl = ArmComputedTorque.from_result(res, log)
    controller = type(ctrl).__name__
    if getattr(ctrl, "selection", None) is not None and controller != "ArmComputedTorque":
        controller += f" ({ctrl.selection['design']})"  # the robust design the check chose
    out = ia.IndependentArm(s).run(ctrl, log.trajectory, s.n_samples)
    e_ctc = np.abs(out["e"][k0:]).max(axis=0) if out["ok"] else None
    e_p = np.abs(log.e_pulses[k0:]).max(axis=0)
    return dict(family=family, seed=seed, n_joints=len(s.active), n_base=len(names),
                identify_s=res.elapsed_s, log_s=t_log, success=bool(res.success),
                n_well=int(well.sum()), params_ok=ok_params,
                worst_param=(names[worst] if worst >= 0 else None),
                worst_err_pct=(100 * float(err[worst]) if worst >= 0 else None),
                ctc_max=(e_ctc.tolist() if e_ctc is not None else None),
                ctc_ok=bool(e_ctc is not None and np.all(e_ctc <= 1)), controller=controller,
                p_max=e_p.tolist(), nfev=int(res.nfev), nit=int(res.nit),
                friction_known=s.friction_known, friction_err_pct=fr_err, friction_ok=fr_ok,
                compliant=compliant, joints=joints, warnings=list(res.warnings),
                settings=dict(encoder_ppr=list(s.encoder_ppr),
                              gear_ratio=[round(g, 1) for g in s.gear_ratio],
                              sample_time_s=s.sample_time_s))


def _table(rows):
    """An RST simple table of string rows (first row: header)."""
    w = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    rule = "  ".join("=" * x for x in w)
    out = [rule, "  ".join(c.ljust(x) for c, x in zip(rows[0], w)), rule]
    out += ["  ".join(c.ljust(x) for c, x in zip(r, w)) for r in rows[1:]]
    return "\n".join(out + [rule])


def _worst(c, none="-") -> str:
    """A draw's largest well-excited error and its parameter (``none`` when none is well excited)."""
    return none if c["worst_err_pct"] is None else f"{c['worst_param']} {c['worst_err_pct']:.3f} %"


def _line(c) -> str:
    """One printed line per draw."""
    return (f"{c['family']:8s} seed {c['seed']}  identify {c['identify_s']:6.1f} s  "
            f"well-excited {c['n_well']:2d}/{c['n_base']:2d}  worst {_worst(c)}  "
            f"params {'ok' if c['params_ok'] else 'MISS'}  "
            f"friction {'known' if c['friction_known'] else 'unknown, %.1f %% %s' % (c['friction_err_pct'], 'ok' if c['friction_ok'] else 'MISS')}  "
            f"CTC max|e| {c['ctc_max']} {'ok' if c['ctc_ok'] else 'MISS'} "
            f"[{c['controller']}]  P max|e| {c['p_max']}"
            + (f"  joints {c['joints']}" if c["joints"] else ""))


def _write_cases(path, seed, cases):
    """Write ``{"seed", "cases"}`` to path (whole, or not at all)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(dict(seed=seed, cases=cases), indent=1,
                              default=lambda o: o.item() if hasattr(o, "item") else str(o)))
    tmp.replace(path)


def _job(args):
    family, seed, compliant = args
    return run_case(family, seed, compliant=compliant)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, nargs="+", default=(6, 4, 3), metavar="N",
                    help="draws per family, in the order " + " ".join(ia.FAMILIES)
                         + " (families left out: none)")
    ap.add_argument("--seed", type=int, default=20261122, help="first seed (draw i uses seed + i)")
    ap.add_argument("--json", type=Path, help="write the cases to this JSON file (after every draw)")
    ap.add_argument("--compliant", action="store_true",
                    help="compliant joints (two-mass, half with backlash; independent_arm.draw)")
    ap.add_argument("--rst", type=Path, help="write the summary as reStructuredText (docs/figures)")
    ap.add_argument("--jobs", type=int, default=1,
                    help="draws run in parallel processes (identification times then share the cores)")
    ap.add_argument("--cases", type=Path, nargs="+", metavar="JSON",
                    help="summarise the cases of earlier runs' --json files (same seed and "
                         "--compliant) instead of running draws")
    a = ap.parse_args(argv)
    ia.check_counts(ap, a.n, ia.FAMILIES)
    if a.cases:
        cases = []
        for path in a.cases:
            try:
                d = json.loads(path.read_text())
                cases += d["cases"]
                a.seed = int(d["seed"])
            except (OSError, ValueError, KeyError, TypeError) as exc:
                print(f"bench_arms: cannot read cases from {path}: {exc}", file=sys.stderr)
                return 2
        if any(bool(c.get("compliant")) != a.compliant for c in cases):
            print("bench_arms: the cases' --compliant differs from this call's", file=sys.stderr)
            return 2
        order = {f: i for i, f in enumerate(ia.FAMILIES)}
        cases.sort(key=lambda c: (order[c["family"]], c["seed"]))
        for c in cases:
            print(_line(c))
    else:
        jobs = [(family, a.seed + i, a.compliant) for family, n in zip(ia.FAMILIES, a.n)
                for i in range(n)]
        done = []

        def report(c):  # the cases so far on disk after every draw: a stopped run keeps them
            done.append(c)
            if a.json:
                _write_cases(a.json, a.seed, done)
            return _line(c)

        cases = ia.run_jobs(_job, jobs, a.jobs, report)
    rows = [("family", "draws", "well-excited within 1 %", "unknown friction within 15 %",
             "... or within 3 std",
             "CTC +-1 pulse after 0.1 s", "identify median / max (s)", "worst well-excited error")]
    if a.compliant:
        rows[0] = rows[0][:5] + ("flexible chosen", "K and Ia within 10 %",
                                 "backlash >= 1 mrad within 30 %") + rows[0][5:]
    for family in ia.FAMILIES:
        cs = [c for c in cases if c["family"] == family]
        if not cs:
            continue
        t = np.array([c["identify_s"] for c in cs])
        w = max(cs, key=lambda c: c["worst_err_pct"] or 0.0)
        fu = [c for c in cs if not c["friction_known"]]
        extra = ()
        if a.compliant:
            kia = [c for c in cs if c["joints"].get("K_err_pct") is not None]
            nb_ = [c for c in cs if any(v >= 1.0 for v in c["joints"]["b_true_mrad"])]
            extra = (f"{sum(c['joints']['model'] != 'rigid' for c in cs)} / {len(cs)}",
                     f"{sum(max(c['joints']['K_err_pct'] + c['joints']['Ia_err_pct']) <= 10 for c in kia)}"
                     f" / {len(cs)}",
                     f"{sum(c['joints']['b_ok'] for c in nb_)} / {len(nb_)}")
        rows.append((family, str(len(cs)), f"{sum(c['params_ok'] for c in cs)} / {len(cs)}",
                     f"{sum(c['friction_err_pct'] <= 15.0 for c in fu)} / {len(fu)}",
                     f"{sum(c['friction_ok'] for c in fu)} / {len(fu)}", *extra,
                     f"{sum(c['ctc_ok'] for c in cs)} / {len(cs)}",
                     f"{np.median(t):.1f} / {t.max():.1f}",
                     "-" if w["worst_err_pct"] is None else
                     f"{w['worst_err_pct']:.3f} % ({w['worst_param']}, seed {w['seed']})"))
    misses = [c for c in cases if not (c["params_ok"] and c["ctc_ok"] and c["friction_ok"] is not False
                                       and (not c["joints"] or c["joints"]["K_ok"] and c["joints"]["b_ok"]))]
    text = [_table(rows), ""]
    text.append(f"Seeds {a.seed} + i; a base parameter is well excited when its relative standard "
                f"error is below {100 * WELL_EXCITED_RSE:.2f} %.  Friction is null in the sidecar "
                "on about half of the draws (identified with the base parameters, joint side; a "
                "component passes within 15 % of the truth or within 3 of its own standard "
                "errors; the largest relative error is printed per draw).  "
                "Identification times include compiling the robot's kernels in the first draw of "
                "each family and of each friction setting, unless numba's disk cache has them "
                "from an earlier run.")
    for c in misses:
        text.append("")
        fr = ("" if c["friction_known"] else
              f", unknown friction {c['friction_err_pct']:.1f} % ({'ok' if c['friction_ok'] else 'miss'})")
        text.append(f"Miss: {c['family']} seed {c['seed']}: worst well-excited parameter "
                    f"{_worst(c, 'none well excited')}{fr}, CTC max abs(e) {c['ctc_max']} "
                    f"pulses (P {c['p_max']}), settings {c['settings']}"
                    + (f", joints {c['joints']}" if c["joints"] else "") + ".")
    print()
    print("\n".join(text))
    if a.rst:
        a.rst.parent.mkdir(parents=True, exist_ok=True)
        tmp = a.rst.with_name(a.rst.name + ".tmp")
        tmp.write_text("\n".join(text) + "\n")
        tmp.replace(a.rst)
    return 0


if __name__ == "__main__":
    sys.exit(main())
