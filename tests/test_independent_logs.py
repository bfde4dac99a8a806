"""Identification on logs from an INDEPENDENT simulator (no library plant code made them).

The logs in ``tests/data/independent`` were made by
``python benchmarks/bench_robustness.py --make-test-logs`` with
``benchmarks/independent_robot.py``: Robotics Toolbox for Python's Puma560
rigid-body dynamics (C rne), a drive written afresh (encoders, truncation,
zero-order-hold current, saturation, motor-side friction with a Coulomb
ramp, Spong two-mass joints, backlash dead zone) and scipy's DOP853.  Each
``STEM.truth.json`` holds the rigid-equivalent f1..f9 (least squares of RTB's
rne plus Jm k^2 qdd on the paper regressor) and every simulation setting.

=====================================  =============================================
log                                    set-up
=====================================  =============================================
``indep_a_rigid_friction_unknown``     rigid joints, friction null in the sidecar
``indep_b_flex_friction_known_2kg``    K 3e4 / 6e3, friction known, 2 kg payload
``indep_c_flex_friction_unknown_noise``  K 2e4 / 1.2e4, friction unknown, 0.08 A noise
``indep_d_flex_backlash_2mrad``        K 3e4 / 1e4, 2 mrad backlash on joint 2
``indep_e_stiff_4kg_250ppr``           K 6e4 / 2.5e4, 4 kg, 250 ppr encoders
``indep_20261205_0013``                a draw of the robustness suite (seed 20261205,
                                       index 13): rigid, heavy unknown Coulomb
                                       friction, 1 kg; the GA's starts all end in a
                                       wrong basin, the IDIM-LS start does not
``indep_20261327_0046``                a draw of the robustness suite (seed 20261327,
                                       index 46, the changes benchmark's): K 1.1e4 /
                                       4.8e4, backlash 0.69 / 0.93 mrad, 250 ppr,
                                       friction unknown; the springs alone leave the
                                       held-back samples at 2.1 floors, the backlash
                                       at 1.13 (kept by the excess test of
                                       ``identification.model_choice.ModelImprovement``)
``indep_20261327_0054``                a draw of the robustness suite (seed 20261327,
                                       index 54): rigid, 3.4 kg payload, friction
                                       unknown; the true viscous friction of joint 2
                                       lies 3 % above the log's friction box (its
                                       weight drives the joint), widened by
                                       ``identify`` where the fit ends on it
=====================================  =============================================

These tests need no roboticstoolbox (the logs are committed).  The
identification property: the default call gives a finite output error and
f1 f2 f4 f6 f7 f9 within 2 % of the truth, *or* its result flags the
problem (``success`` False or a warning).
"""
from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import numpy as np
import pytest

import plant

DATA = Path(__file__).parent / "data" / "independent"
STEMS = (
    "indep_a_rigid_friction_unknown",
    "indep_b_flex_friction_known_2kg",
    "indep_c_flex_friction_unknown_noise",
    "indep_d_flex_backlash_2mrad",
    "indep_e_stiff_4kg_250ppr",
    "indep_20261205_0013",
    "indep_20261327_0046",
    "indep_20261327_0054",
)
F_MAIN = (0, 1, 3, 5, 6, 8)  # f1 f2 f4 f6 f7 f9


def _truth(stem):
    return json.loads((DATA / f"{stem}.truth.json").read_text())


@pytest.mark.parametrize("stem", STEMS)
def test_loads(stem):
    log = plant.load_log(DATA / f"{stem}.csv")
    truth = _truth(stem)
    st = truth["settings"]
    assert log.n_samples == int(round(st["duration_s"] / st["sample_time_s"])) + 1
    assert log.rig.encoder_ppr == tuple(st["encoder_ppr"])
    assert (log.rig.unknown_friction == ()) == st["friction_known"]
    # the reference column is the sidecar's formula (what the robot followed)
    assert np.array_equal(log.q_ref, log.trajectory.position(log.t))
    # every f inside the sidecar's search ranges (widened where the paper's were too narrow)
    b = log.rig.bounds
    f = np.asarray(truth["f_vector"])
    assert np.all((f > b[:, 0]) & (f < b[:, 1]))


@pytest.mark.parametrize("stem", STEMS)
def test_truth_residual_tiny(stem):
    truth = _truth(stem)
    assert truth["regression_rel_residual"] < 1e-12
    pc = truth["physical_consistency"]
    assert all(abs(v) < 1e-10 for v in pc.values()), pc
    assert truth["draw"]["stability_radius"] <= truth["draw"]["rho_max"] < 1.0


@pytest.mark.parametrize("stem", STEMS)
def test_truth_matches_library_model(stem):
    """The rigid-equivalent truth with the library's model, at the sidecar's rig, is PD and consistent."""
    truth = _truth(stem)
    f = np.asarray(truth["f_vector"])
    assert plant.is_positive_definite(f)
    jk2 = np.asarray(truth["joints"]["motor_inertia_reflected_kgm2"])
    k = np.asarray(truth["settings"]["gear_ratio"])
    assert np.allclose(jk2, np.asarray(truth["settings"]["jm_kgm2"]) * k * k)


_RESULTS: dict = {}


def _identify(stem):
    if stem not in _RESULTS:
        import identification

        log = plant.load_log(DATA / f"{stem}.csv")
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            res = identification.identify(log, rng=0, progress=False)
        _RESULTS[stem] = (res, [f"{w.category.__name__}: {w.message}" for w in caught])
    return _RESULTS[stem]


# the flexible logs with unknown friction or backlash take 15-30 s each on 2 busy cores
_SLOW = ("indep_c_flex_friction_unknown_noise", "indep_d_flex_backlash_2mrad",
         "indep_20261327_0046")


@pytest.mark.parametrize("stem", [pytest.param(s, marks=pytest.mark.slow) if s in _SLOW else s
                                  for s in STEMS])
def test_identify_accurate_or_flagged(stem):
    res, caught = _identify(stem)
    truth = _truth(stem)
    f_true = np.asarray(truth["f_vector"])
    assert math.isfinite(float(res.fun)), f"{stem}: fun = {res.fun}"
    err = np.abs(np.asarray(res.f) - f_true) / np.abs(f_true)
    worst = float(np.max(err[list(F_MAIN)]))
    flagged = (not bool(res["success"])) or bool(caught)
    detail = ", ".join(f"f{i + 1} {100 * err[i]:.2f}%" for i in F_MAIN)
    assert worst <= 0.02 or flagged, (
        f"{stem}: f1 f2 f4 f6 f7 f9 off by up to {100 * worst:.2f}% ({detail}), model "
        f"{res.get('model')}, success {res['success']}, and no warning")


@pytest.mark.parametrize("stem", [pytest.param(s, marks=pytest.mark.slow) if s in _SLOW else s
                                  for s in STEMS])
def test_identify_meets_the_issue_targets(stem):
    """Issue 20's per-log targets on the committed independent logs: f1 f2 f4 f6 f7 f9
    within 2 %, the compliant model chosen on a compliant robot with K within 10 %,
    unknown friction within 15 %, backlash >= 1 mrad within 30 %, none reported where
    there is none, the truth within 3 f_std, and no inadequacy warning."""
    res, caught = _identify(stem)
    truth = _truth(stem)
    f_true = np.asarray(truth["f_vector"])
    err = np.abs(np.asarray(res.f) - f_true) / np.abs(f_true)
    assert np.all(err[list(F_MAIN)] <= 0.02), err
    assert res["success"]
    assert not any("ModelInadequacyWarning" in c for c in caught), caught
    assert np.sum(np.abs(np.asarray(res.f) - f_true) <= 3 * np.asarray(res.f_std)) >= 8
    joints = truth["joints"]
    if joints["model"] == "flexible":
        assert res["model"] == "flexible"
        K = np.asarray(res["joint_stiffness_Nm_per_rad"])
        assert np.all(np.abs(K / np.asarray(joints["stiffness_Nm_per_rad"]) - 1) <= 0.10), K
    else:
        assert res["model"] == "rigid"
    b_true = np.asarray(joints.get("backlash_rad") or [0.0, 0.0])
    b = res.get("joint_backlash_rad")
    if np.any(b_true >= 1e-3):
        assert b is not None
        big = b_true >= 1e-3
        assert np.all(np.abs(np.asarray(b)[big] / b_true[big] - 1) <= 0.30), b
    elif np.any(b_true > 0):  # a smaller backlash: a width reported is within 30 % of it
        if b is not None:
            some = (b_true > 0) & (np.asarray(b) > 0)
            assert np.all(np.abs(np.asarray(b)[some] / b_true[some] - 1) <= 0.30), b
    elif b is not None:  # a width reported where the robot has none: at most a pulse's
        assert np.all(np.asarray(b) <= 2 * np.pi / (abs(np.asarray(truth["settings"]["gear_ratio"]))
                                                    * np.asarray(truth["settings"]["encoder_ppr"])))
    fr = truth["friction"]
    if not fr["known_in_sidecar"]:
        assert res["friction_identified"]
        v = np.asarray(res["viscous_friction_Nms_per_rad"])
        c = np.asarray(res["coulomb_friction_Nm"])
        assert np.all(np.abs(v / np.asarray(fr["viscous_friction_Nms_per_rad"]) - 1) <= 0.15), v
        assert np.all(np.abs(c / np.asarray(fr["coulomb_friction_Nm"]) - 1) <= 0.15), c


@pytest.mark.slow
def test_a_backlash_the_springs_leave_above_the_floor_is_kept():
    """The PUMA path's model choice tries the backlash whenever the springs leave the held-back
    samples above the quantisation floor, and keeps it by the tests every robot's model choice
    uses (identification.model_choice.ModelImprovement): on the 0.7-0.9 mrad draw the springs sit at
    2.1 floors, which the former rule (backlash only above INADEQUATE_FACTOR = 4 floors, kept
    at half the cost) left without backlash."""
    res, _ = _identify("indep_20261327_0046")
    mc = res["model_choice"]
    assert mc["model"] == "flexible+backlash" and mc["backlash_against"] == "springs"
    assert mc["backlash_test"] in ("ratio", "paired_t", "floor", "excess")
    assert mc["held_back_cost_backlash_pulses2"] < mc["held_back_cost_springs_pulses2"]
    assert mc["floor_ratio"] < 1.5 and mc["adequate"]


def test_a_friction_box_the_fit_ends_on_is_widened():
    """The unknown friction's box is the log's guess (B <= T / w): on the rigid arm whose
    weight drives joint 2, the true B2 lies above it, and the refined fit ended on that bound
    far above the quantisation floor.  ``identify`` widens the guessed box where the fit ends
    on it (as identify_arm its guessed box): the fit then reaches the floor, the result's
    bounds are the widened box, the refinement record and the message say so; a caller's
    friction box is kept as given (and the fit stays on it)."""
    import identification
    from identification.model_choice import ARM_FLOOR_FACTOR
    from identification.flexible import FLOOR_FACTOR, quantisation_floor
    from identification.friction import FrictionParameters, default_friction_bounds

    res, caught = _identify("indep_20261327_0054")
    log = plant.load_log(DATA / "indep_20261327_0054.csv")
    wide = res["refinement"]["friction_box_widened"]
    guess = default_friction_bounds(log)
    assert "B2_Nms_per_rad" in wide["names"] and wide["friction_bounds"][0][1] > guess[0, 1]
    assert "friction box" in res["message"]
    i = res["x_names"].index("B2_Nms_per_rad")
    assert res["bounds"][i][1] > guess[0, 1] and res["x"][i] > guess[0, 1]
    assert res["model_choice"]["floor_ratio"] <= ARM_FLOOR_FACTOR
    assert not any("SearchBoundWarning" in c for c in caught), caught
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        kept = identification.identify(log, rng=0, progress=False, model="rigid",
                                       parameters=FrictionParameters(friction_bounds=guess))
    assert "friction_box_widened" not in kept["refinement"]
    assert kept["x"][i] >= guess[0, 1] * (1 - 1e-6)
    assert kept["refinement"]["fun"] > FLOOR_FACTOR * quantisation_floor(2 * log.n_samples)


@pytest.mark.slow
def test_the_backlash_search_keeps_its_best_schedule_and_only_improving_hops():
    """On the backlash log the model choice records the backlash fit's search
    (:func:`identification.flexible.fit_backlash`): one cost per gain schedule,
    the kept one the lowest, every accepted hop lower than the one before, and
    the random hops never above where the deterministic ones ended."""
    res, _ = _identify("indep_d_flex_backlash_2mrad")
    search = res["model_choice"]["backlash_search"]
    costs = [np.inf if c is None else c for c in search["schedule_costs"]]
    assert len(costs) == len(search["schedules"]) >= 2
    assert search["schedule"] == int(np.argmin(costs))
    chain = [costs[search["schedule"]]] + list(search["hops"])
    assert all(b < a for a, b in zip(chain, chain[1:])), chain
    # the random hops continue from there and never raise the cost
    random_chain = chain[-1:] + list(search["random_hops"])
    assert all(b <= a for a, b in zip(random_chain, random_chain[1:])), random_chain
    assert search["floor_pulses2"] > 0


def test_the_idim_ls_start_refines_a_search_the_ga_started_wrong(paper_log):
    """identification.api._idim_restart: on the drawn log whose GA's starts all end far
    above the quantisation floor, the IDIM-LS estimate is refined too and kept (it
    starts below where they ended and ends lower); on the paper log the GA's starts
    reach the floor and it is not tried (the result is the GA's)."""
    import identification

    res, _ = _identify("indep_20261205_0013")
    rec = res["refinement"]["idim_start"]
    assert rec["used"] and rec["fun"] < rec["start_cost"]
    assert "IDIM-LS" in res["message"]
    paper = identification.identify(paper_log, rng=0, progress=False)
    assert "idim_start" not in paper["refinement"]
