"""Excitation design (issue 15, item 3): limits, start at rest, the CLI's JSON, and a design
that the prediction-error criterion rates better than the paper trajectory of the same length."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

import plant
from identification import design_excitation
from identification import excitation as ex

DURATION = 1.5


@pytest.fixture(scope="module")
def drill_rig(data_dir):
    return plant.load_log(data_dir / "puma560_paper_drill_flex.csv").rig


@pytest.fixture(scope="module")
def design(drill_rig):
    return design_excitation(drill_rig, DURATION, rng=0, generations=6, rerank=2,
                             full_output=True)


def test_design_within_limits_and_starts_at_rest(design, drill_rig):
    traj, info = design
    assert isinstance(traj, plant.Trajectory)
    q, qd, _ = traj.evaluate(np.array([0.0]))
    np.testing.assert_allclose(q[0], drill_rig.q0_rad, atol=1e-12)
    np.testing.assert_allclose(qd[0], 0.0, atol=1e-12)
    # the paper trajectory's range and the drive's full scale, on a grid finer than the design's
    lim = ex.trajectory_limits(traj, DURATION, drill_rig, info["f_prior"], grid_s=2.5e-4)
    assert np.all(lim["q_min"] >= np.array([-math.pi / 2, 0.0]) - 1e-6)
    assert np.all(lim["q_max"] <= np.array([0.0, math.pi / 2]) + 1e-6)
    assert np.all(lim["i_max"] <= drill_rig.current_full_scale_A)
    # the sidecar form round-trips
    assert plant.Trajectory.from_sidecar(traj.to_parameters()) == traj


def test_design_beats_paper_trajectory_rse(design, drill_rig):
    """The design beats the paper trajectory over the same 1.5 s, at T = 1.5 s and at
    its fastest period within the same drive limits, on the regressor's relative
    standard errors (the criterion the design optimises), and its closed-loop
    prediction is finite.

    (The closed-loop prediction of the paper trajectory at T = 1.5 s, whose
    feed-forward current of 18 A exceeds the 15 A full scale, was poor only while
    the simulation ignored the drive's current limit; with the limit simulated the
    replay reproduces a saturated run and that trajectory is informative again.)
    """
    traj, info = design
    f = info["f_prior"]
    scale = np.maximum(np.abs(f), ex.SCALE_FLOOR * np.ptp(drill_rig.bounds, axis=1))
    period = next(T for T in np.arange(DURATION, 5.0, 0.25)
                  if ex.trajectory_limits(plant.Trajectory.paper(T), DURATION, drill_rig,
                                          f)["violation"] == 0.0)
    mine = np.max(ex.regressor_rse(traj, DURATION, scale))
    for T in (DURATION, period):
        assert mine < np.max(ex.regressor_rse(plant.Trajectory.paper(T), DURATION, scale))
    assert np.all(np.isfinite(info["predicted_f_std"]))


def test_rest_start_away_from_zero(drill_rig):
    import dataclasses

    rig = dataclasses.replace(drill_rig, q0_rad=(-0.5, 0.7))
    traj = design_excitation(rig, 1.0, rng=1, generations=2, rerank=0)
    q, qd, _ = traj.evaluate(np.array([0.0]))
    np.testing.assert_allclose(q[0], [-0.5, 0.7], atol=1e-12)
    np.testing.assert_allclose(qd[0], 0.0, atol=1e-12)


def test_bad_input_one_line(drill_rig):
    with pytest.raises(ValueError, match="duration_s"):
        design_excitation(drill_rig, -1.0)
    with pytest.raises(ValueError, match="outside joint_limits_rad"):
        design_excitation(drill_rig, 1.0, joint_limits_rad=[[0.1, 0.5], [0.0, 1.0]])


def test_cli_contract_json(tmp_path, data_dir, capsys):
    out = tmp_path / "traj.json"
    rc = ex.main([str(data_dir / "puma560_paper_drill_flex.json"), "--duration-s", "0.8",
                  "--seed", "0", "--output", str(out), "--generations", "2"])
    assert rc == 0
    d = json.loads(out.read_text())
    assert set(d["trajectory"]) >= {"parameters", "duration_s"}
    assert d["trajectory"]["duration_s"] == 0.8
    assert len(d["predicted_f_std"]) == 9 and all(v > 0 for v in d["predicted_f_std"])
    # ready to paste into a sidecar
    traj = plant.Trajectory.from_sidecar({"trajectory": d["trajectory"]})
    assert traj.t_ramp_s > 0
    rc = ex.main([str(tmp_path / "missing.json"), "--duration-s", "1", "--output",
                  str(tmp_path / "x.json")])
    err = capsys.readouterr().err
    assert rc == 1 and err.startswith("error:") and err.count("\n") == 1


# ------------------------------------------------------------------ any robot model (issue 23)
ARM_SIDECAR = "independent_arm/indep_arm_planar2_payload.json"


@pytest.fixture(scope="module")
def planar(data_dir):
    """The committed planar arm's robot model and rig (its sidecar's ``robot`` object)."""
    from plant.logs.arm_log import arm_rig
    from plant.logs.sidecar import read_sidecar

    side = data_dir / ARM_SIDECAR
    return arm_rig(read_sidecar(side), side)


@pytest.fixture(scope="module")
def planar_design(planar):
    model, rig = planar
    return design_excitation(rig, 2.0, model=model, rng=0, generations=6, rerank=2,
                             full_output=True)


def test_the_puma_instance_through_its_robot_model_gives_the_same_design(design, drill_rig):
    """The PUMA 560 links 2-3 as a robot model (RobotModel.puma560_links23, f1..f9): the same
    family, limits (the paper trajectory's range), box (the sidecar's) and search give the
    default path's trajectory at the same seed, and its prediction-error criterion (the arm
    refinement on the instance's arm plant) is the PUMA path's at the same replay substeps
    (to 1e-3: the arm plant's generated kernels round differently; by default the arm
    refinement replays at 2 RK4 steps a sample, the PUMA path's at 1)."""
    from identification.objective import IDENTIFICATION_SUBSTEPS
    from plant.robot.robot_model import RobotModel

    model = RobotModel.puma560_links23(gear_ratios=drill_rig.gear_ratio,
                                       gravity_m_s2=drill_rig.gravity_m_s2)
    traj, info = design
    mine, minfo = design_excitation(drill_rig, DURATION, rng=0, generations=6, rerank=2,
                                    full_output=True, model=model, grid_s=ex.GRID_S)
    assert mine.to_parameters() == traj.to_parameters()
    assert minfo["names"] == info["names"] == tuple(f"f{i}" for i in range(1, 10))
    np.testing.assert_allclose(minfo["regressor_rse"], info["regressor_rse"], rtol=1e-9)
    f = info["f_prior"]
    np.testing.assert_allclose(
        ex.predicted_f_std(drill_rig, traj, DURATION, f, model=model,
                           substeps=IDENTIFICATION_SUBSTEPS),
        ex.predicted_f_std(drill_rig, traj, DURATION, f, substeps=IDENTIFICATION_SUBSTEPS),
        rtol=1e-3)


def test_arm_design_within_limits_starts_at_rest_and_beats_a_multisine(planar, planar_design):
    """A planar arm from its sidecar's DH table: the design starts at rest at the start state,
    stays within the default range (start state +- pi/4) and the drive's limits, and its
    regressor criterion (max relative standard error of the 7 base parameters) beats a
    multisine brought within the same limits; its closed-loop prediction is finite."""
    model, rig = planar
    traj, info = planar_design
    assert len(info["names"]) == 7 and info["f_prior"].shape == (7,)
    q, qd, _ = traj.evaluate(np.array([0.0]))
    np.testing.assert_allclose(q[0], 0.0, atol=1e-12)
    np.testing.assert_allclose(qd[0], 0.0, atol=1e-12)
    lim = ex.trajectory_limits(traj, 2.0, rig, info["f_prior"], model=model, grid_s=5e-4)
    assert np.all(lim["q_min"] >= -math.pi / 4 - 1e-6) and np.all(lim["q_max"] <= math.pi / 4 + 1e-6)
    if rig.current_full_scale_A is not None:
        assert np.all(lim["i_max"] <= rig.current_full_scale_A)
    assert np.all(np.isfinite(info["predicted_f_std"])) and "prediction-error" in info["message"]
    scale = info["f_scale"]
    mine = np.max(ex.regressor_rse(traj, 2.0, scale, model=model, rig=rig))
    np.testing.assert_allclose(mine, np.max(info["regressor_rse"]), rtol=1e-12)
    # a two-tone multisine per joint, scaled down until it fits the same limits
    for amp in (0.6, 0.4, 0.3, 0.2, 0.1, 0.05):
        other = plant.Trajectory.from_terms(
            [-amp, -amp], [[(amp * 0.7, 2 * math.pi, 0.0), (amp * 0.3, 3 * math.pi, 0.0)],
                           [(amp * 0.6, 3 * math.pi, 0.0), (amp * 0.4, 5 * math.pi, 0.0)]], 0.3)
        if ex.trajectory_limits(other, 2.0, rig, info["f_prior"], model=model)["violation"] == 0:
            break
    else:
        pytest.fail("no multisine within the limits")
    assert mine < np.max(ex.regressor_rse(other, 2.0, scale, model=model, rig=rig))


def test_unknown_friction_is_a_nuisance_of_the_criteria(planar, planar_design):
    """A sidecar that leaves friction null: its components enter the regressor criterion as
    nuisance parameters -- no base parameter is determined better than with the friction
    known, and some worse; the friction prior sets the current check's friction."""
    import dataclasses

    model, rig = planar
    traj, info = planar_design
    scale = info["f_scale"]
    unknown = dataclasses.replace(rig, viscous_friction_Nms_per_rad=None, coulomb_friction_Nm=None)
    known_rse = ex.regressor_rse(traj, 2.0, scale, model=model, rig=rig)
    null_rse = ex.regressor_rse(traj, 2.0, scale, model=model, rig=unknown)
    assert np.all(null_rse >= known_rse * (1 - 1e-9)) and np.any(null_rse > 1.05 * known_rse)
    k = np.abs(np.asarray(rig.gear_ratio))
    true = np.column_stack([k ** 2 * np.asarray(rig.viscous_friction_Nms_per_rad),
                            k[:, None] * np.asarray(rig.coulomb_friction_Nm)])
    a = ex.trajectory_limits(traj, 2.0, rig, info["f_prior"], model=model)
    b = ex.trajectory_limits(traj, 2.0, unknown, info["f_prior"], model=model, friction_prior=true)
    np.testing.assert_allclose(b["i_max"], a["i_max"], rtol=1e-12)
    with pytest.raises(ValueError, match="friction_prior"):
        ex.trajectory_limits(traj, 2.0, unknown, info["f_prior"], model=model,
                             friction_prior=np.ones(3))


def test_arm_design_bad_input_one_line(planar, drill_rig):
    from plant.robot.robot_model import RobotModel

    model, rig = planar
    with pytest.raises(ValueError, match="the rig has 2 joints, the robot model 3"):
        design_excitation(rig, 1.0, model=RobotModel.puma560(active=(0, 1, 2)))
    with pytest.raises(ValueError, match="joint_limits_rad must be 2 rows"):
        design_excitation(rig, 1.0, model=model, joint_limits_rad=[[-1.0, 1.0]])
    with pytest.raises(ValueError, match="f_prior must be 7 finite numbers"):
        design_excitation(rig, 1.0, model=model, f_prior=np.ones(9))
    with pytest.raises(ValueError, match="model must be a plant.RobotModel"):
        design_excitation(drill_rig, 1.0, model="puma")


def test_cli_designs_for_the_robot_model_of_an_arm_sidecar(tmp_path, data_dir, capsys):
    """A sidecar with a ``robot`` object: the CLI designs for that model (its base
    parameters' names in the JSON), takes a min and a max per joint, and refuses a wrong
    count with one line (nothing written)."""
    out = tmp_path / "arm.json"
    side = str(data_dir / ARM_SIDECAR)
    rc = ex.main([side, "--duration-s", "1", "--seed", "0", "--output", str(out),
                  "--generations", "2", "--joint-limits", "-0.5", "0.5", "-0.6", "0.6"])
    assert rc == 0
    d = json.loads(out.read_text())
    assert len(d["parameter_names"]) == len(d["predicted_f_std"]) == 7
    assert np.all(np.array(d["q_range_rad"])[:, 0] >= [-0.5 - 1e-9, -0.6 - 1e-9])
    assert "predicted max relative standard error" in capsys.readouterr().out
    bad = tmp_path / "bad.json"
    rc = ex.main([side, "--duration-s", "1", "--output", str(bad), "--joint-limits", "-1", "1"])
    err = capsys.readouterr().err
    assert rc == 1 and "--joint-limits takes a min and a max per joint: 4 numbers" in err
    assert err.count("\n") == 1 and not bad.exists()
    rc = ex.main([side, "--duration-s", "1", "--output", str(bad), "--friction-prior", "1", "2"])
    err = capsys.readouterr().err
    assert rc == 1 and "--friction-prior takes 3 numbers per joint" in err and not bad.exists()


def test_a_prediction_that_fails_on_every_candidate_is_said(planar, monkeypatch):
    """When no candidate's emulated P experiment runs (e.g. a loop that needs its unknown
    friction for damping, no friction_prior given), the design is the regressor criterion's
    best, its predicted errors inf, and a RuntimeWarning and the message say so."""
    model, rig = planar
    ref = design_excitation(rig, 1.0, model=model, rng=4, generations=2, rerank=0)

    def failing(*args, **kwargs):
        raise ValueError("the emulated run failed")

    monkeypatch.setattr(ex, "predicted_f_std", failing)
    with pytest.warns(RuntimeWarning, match="failed on every candidate"):
        traj, info = design_excitation(rig, 1.0, model=model, rng=4, generations=2, rerank=3,
                                       full_output=True)
    assert traj.to_parameters() == ref.to_parameters()
    assert np.all(np.isinf(info["predicted_f_std"])) and "regressor criterion" in info["message"]


def test_the_repair_pulls_offsets_the_start_ramp_cannot_reach_towards_the_start():
    """From rest at q = 0 a candidate whose 0.3 s start ramp to its offsets alone breaks a rate
    limit is not lost to the search: the repair scales its offsets towards the start state
    before its amplitudes, the repaired reference keeps the limit, and ``_Family.scaled`` gives
    the point whose unscaled reference is the repaired one (the polish starts there)."""
    fam = ex._Family(np.zeros(2), 2.0, 2, np.array([[-1.5, 1.5], [-1.5, 1.5]]), 0.3)
    t = np.linspace(0.0, 2.0, 401)

    def feasible(x, s):
        _, qd, _ = fam.trajectory(x, s).evaluate(t)
        return bool(np.all(np.abs(qd) <= 1.0))

    x = fam.bounds[:, 1].copy()  # offsets at the top of the range, the largest amplitudes
    assert not feasible(x, (1.0, 0.0))  # the ramp alone: 1.5 rad in 0.3 s
    so, sa = ex._repair(fam, feasible, x)
    assert 0.0 < so < 1.0 and sa > 0.0 and feasible(x, (so, sa))
    assert not feasible(x, (so, min(1.0, 1.1 * sa)))  # the largest such factor (bisection)
    z = fam.scaled(x, (so, sa))
    for a, b in zip(fam.trajectory(z, 1.0).evaluate(t), fam.trajectory(x, (so, sa)).evaluate(t)):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-12)


def test_the_polish_keeps_the_limits_and_never_worsens_the_search_criterion(planar):
    """The SLSQP polish of the GA's best (the regressor criterion, the limits as constraints):
    the design with it is within the same limits and its regressor criterion is no worse
    than the GA's best at the same seed (it is kept only when it improves)."""
    model, rig = planar
    plain, pinfo = design_excitation(rig, 2.0, model=model, rng=1, generations=6, rerank=0,
                                     polish=False, full_output=True)
    pol, info = design_excitation(rig, 2.0, model=model, rng=1, generations=6, rerank=0,
                                  full_output=True)
    assert pinfo["polished"] is False and isinstance(info["polished"], bool)
    assert np.max(info["regressor_rse"]) <= np.max(pinfo["regressor_rse"]) * (1 + 1e-12)
    if info["polished"]:
        assert np.max(info["regressor_rse"]) < np.max(pinfo["regressor_rse"])
    assert info["limits"]["violation"] == 0.0


def test_the_puma_prediction_counts_unknown_friction_as_nuisance(design, drill_rig):
    """A PUMA 560 links 2-3 sidecar that leaves friction null: the prediction-error criterion
    (no robot model given) runs through the instance's robot model with the friction estimated
    as nuisance parameters -- no f predicted better than with the friction known, some worse."""
    import dataclasses

    from plant.robot.robot_model import RobotModel

    traj, info = design
    f = info["f_prior"]
    unknown = dataclasses.replace(drill_rig, viscous_friction_Nms_per_rad=None,
                                  coulomb_friction_Nm=None)
    k = np.abs(np.asarray(drill_rig.gear_ratio))
    true = np.column_stack([k ** 2 * np.asarray(drill_rig.viscous_friction_Nms_per_rad),
                            k[:, None] * np.asarray(drill_rig.coulomb_friction_Nm)])
    inst = RobotModel.puma560_links23(gear_ratios=drill_rig.gear_ratio,
                                      gravity_m_s2=drill_rig.gravity_m_s2)
    known = ex.predicted_f_std(drill_rig, traj, DURATION, f, model=inst)
    null = ex.predicted_f_std(unknown, traj, DURATION, f, friction_prior=true)
    assert null.shape == (9,) and np.all(np.isfinite(null))
    assert np.all(null >= known * (1 - 1e-6)) and np.any(null > 1.01 * known)
