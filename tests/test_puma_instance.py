"""The PUMA 560 links 2-3 instance through the arm path, against the PUMA path (issue 23).

``load_arm_log`` reads a development log as the log of
``RobotModel.puma560_links23()`` (parameters f1..f9); the generic arm plant
(:mod:`plant.simulation.arm`), :func:`identification.arm.identify_arm` and
:mod:`ctc.arm` then run it like any robot model.  Checked here: the arm
driver gives the PUMA path's pulses (:func:`plant.simulate_experiment`)
sample for sample, rigid and flexible, at the same substeps and by default;
its output errors (failure penalty and early termination included) are the
PUMA path's, and the paper's GA gives the PUMA path's f for the same seed;
the identification takes the sidecar's search box and recovers the truth;
the computed torque of the result tracks the true robot.  Side-by-side
figures of both paths: ``benchmarks/bench_puma_paths.py``.
"""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import plant
from plant.logs.arm_log import load_arm_log
from plant.simulation.arm import ARM_SUBSTEPS, arm_plant, simulate_arm
from plant.simulation.simulate import DEFAULT_SUBSTEPS

#: The paper's well-excited parameters (0-based: f1 f2 f4 f6 f7 f9; tests/test_identify.py).
PAPER_WELL_EXCITED = (0, 1, 3, 5, 6, 8)


def _true_joints(log, truth_file):
    """The drill robot's true two-mass joints as the arm plant's lane blocks K, D, Jm k^2."""
    v = truth_file["emulator"]["variant"]
    model = log.model
    ia = np.array([model.links[i].motor_inertia * model.links[i].gear_ratio ** 2
                   for i in model.active])
    return np.asarray(v["flex_stiffness"], float), np.asarray(v["flex_damping"], float), ia


@pytest.mark.parametrize("stem", ["puma560_paper_rigid", "puma560_validation_rigid",
                                  "puma560_paper_drill_flex"])
def test_the_arm_driver_gives_the_puma_paths_pulses(stem, dev_log_paths, truth):
    """Rigid arm plant of the instance at the true (rigid-equivalent) f: the arm driver's pulses
    are plant.simulate_experiment's, sample for sample, at the same substeps -- the default
    of both (one rule: DEFAULT_SUBSTEPS) and a coarse one -- on every development log."""
    path = dev_log_paths[stem]
    log, ref = load_arm_log(path), plant.load_log(path)
    robot = arm_plant(log.model)
    f = np.array(truth(stem)["f_vector"])
    assert ARM_SUBSTEPS == DEFAULT_SUBSTEPS
    e_arm = simulate_arm(robot, f[None], log.rig, log.trajectory, log.n_samples, workers=1)
    e_puma = plant.simulate_experiment(ref, f)
    assert e_arm.status[0] == 0  # the arm driver's integer pulses come as float64
    np.testing.assert_array_equal(e_arm.errors[0], e_puma)
    coarse = simulate_arm(robot, f[None], log.rig, log.trajectory, log.n_samples, substeps=2,
                          workers=1).errors[0]
    np.testing.assert_array_equal(coarse, plant.simulate_experiment(ref, f, substeps=2))
    if stem == "puma560_paper_rigid":  # the default reproduces this log exactly, on both paths
        np.testing.assert_array_equal(e_arm.errors[0], log.e_pulses)


def test_the_flexible_arm_plant_gives_the_drill_logs_pulses(dev_log_paths, truth):
    """Two-mass arm plant of the instance at the drill robot's true joints: its link model
    takes the reflected motor inertias out of f7 (joint 2) and f1 (joint 3), from the
    instance's definition (eq. 3 in the chain's parameters), as plant.FlexibleJoints does; its
    pulses are the PUMA path's and the log's, sample for sample, by default."""
    stem = "puma560_paper_drill_flex"
    path = dev_log_paths[stem]
    log, ref = load_arm_log(path), plant.load_log(path)
    t = truth(stem)
    f = np.array(t["f_vector"])
    k, d, ia = _true_joints(log, t)
    robot = arm_plant(log.model, flexible=True)
    cols = np.zeros((2, 9))
    cols[0, 6] = cols[1, 0] = 1.0  # Jm2 k2^2 in f7, Jm3 k3^2 in f1 (eq. 3)
    np.testing.assert_allclose(robot.motor_inertia_columns, cols, rtol=0, atol=1e-12)
    row = np.concatenate([f, k, d, ia, np.zeros(2)])
    jm = ia / np.asarray(log.rig.gear_ratio) ** 2
    fj = plant.FlexibleJoints(k, d, jm)
    np.testing.assert_allclose(robot.lane_parameters(row[None])[:9, 0],
                               fj.link_parameters(f, ref.rig), rtol=1e-12, atol=1e-12)
    sim = simulate_arm(robot, row[None], log.rig, log.trajectory, log.n_samples, workers=1)
    assert sim.status[0] == 0
    np.testing.assert_array_equal(sim.errors[0], plant.simulate_experiment(ref, f, plant=fj))
    np.testing.assert_array_equal(sim.errors[0], log.e_pulses)


def test_the_arm_driver_gives_the_puma_paths_output_errors_of_failed_and_stopped_candidates(
        paper_rigid_path):
    """The GA's objective on both paths (one RK4 step per sample, IDENTIFICATION_SUBSTEPS): a
    population drawn in the sidecar's box -- some candidates fail (D not positive definite) --
    gets the same output errors and status codes from simulate_arm against the log as from
    plant.simulate_batch: the same pulses, the same finite penalty of a failed candidate
    (default_bound), and with a cap the same early-terminated candidates and extrapolated
    values."""
    from identification.objective import IDENTIFICATION_SUBSTEPS
    from plant.simulation.core import STATUS_NOT_PD, STATUS_STOPPED

    log, ref = load_arm_log(paper_rigid_path), plant.load_log(paper_rigid_path)
    robot = arm_plant(log.model)
    b = ref.rig.bounds
    X = b[:, 0] + np.random.default_rng(2).random((40, 9)) * (b[:, 1] - b[:, 0])
    for cap in (None, 3e5):
        puma = plant.simulate_batch(ref, X, substeps=IDENTIFICATION_SUBSTEPS, errors=False,
                                    workers=1, cap=cap)
        arm = simulate_arm(robot, X, log.rig, log.trajectory, log.n_samples, e_log=log.e_pulses,
                           substeps=IDENTIFICATION_SUBSTEPS, errors=False, cap=cap, workers=1)
        np.testing.assert_array_equal(arm.status, puma.status)
        np.testing.assert_array_equal(arm.objective, puma.objective)
        assert np.any(arm.status == STATUS_NOT_PD) and np.all(np.isfinite(arm.objective))
        assert np.any(arm.status == STATUS_STOPPED) == (cap is not None)


@pytest.mark.parametrize("stem, method, budget", [
    ("puma560_paper_rigid", "paper", None),  # the paper's whole GA budget
    ("puma560_validation_rigid", "paper", "small"),
    ("puma560_paper_drill_flex", "paper", "small"),
    ("puma560_paper_rigid", "ga+pem", "small"),
])
def test_the_arm_paths_ga_is_the_puma_paths(stem, method, budget, dev_log_paths):
    """Issue 23's acceptance, the GA: identify_arm and identification.identify, seed 0, the
    same method and budget, the rigid model, give the same GA -- the same best f (to 1e-9
    relative; in fact bit for bit), the same output error of eq. 4 and the same best
    output error after every generation: the same settings, encoding (binary for "paper",
    Gray with early termination for "ga+pem"), random stream, search box (the sidecar's),
    parameter order (f1..f9), substeps (one RK4 step per sample: output_error_substeps of the
    instance) and failure penalty."""
    import warnings

    from identification import identify
    from identification.arm import ARM_REPORT_SUBSTEPS, identify_arm
    from identification.objective import IDENTIFICATION_SUBSTEPS

    path = dev_log_paths[stem]
    opts = None if budget is None else dict(n_subpops=2, n_ind=8, n_gen=3)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # e.g. a parameter at its search bound after 3 generations
        puma = identify(plant.load_log(path), method=method, rng=0, workers=1, progress=False,
                        ga_options=opts, model="rigid")
    arm = identify_arm(load_arm_log(path), method=method, rng=0, workers=1, ga_options=opts,
                       model="rigid")
    assert arm.ga["substeps"] == IDENTIFICATION_SUBSTEPS == puma.settings["substeps"]
    # the result's own output error (the model choice's) at converged steps
    assert arm.output_error_substeps == ARM_REPORT_SUBSTEPS
    f_puma = np.asarray(puma.f if method == "paper" else puma.refinement["ga_f"])
    assert np.max(np.abs(arm.ga["x"] / f_puma - 1)) <= 1e-9
    np.testing.assert_array_equal(arm.ga["best"], puma.history["best"])
    assert arm.ga["output_error"] == float(np.min(puma.history["best"]))
    assert arm.ga["nfev"] == int(puma.history["nfev"][-1])
    if method == "paper":  # the result is the GA's best, with its output error
        np.testing.assert_array_equal(arm.x, puma.f)
        assert arm.ga["output_error"] == puma.fun


def test_the_rig_search_box_is_the_sidecars_for_f1_to_f9(paper_rigid_path):
    """identify_arm's default box: the sidecar's f_search_ranges when the model's base parameters
    are f1..f9 (the instance), none for other names (a DH model's QR base parameters)."""
    from identification.arm import rig_search_box
    from plant.robot.robot_model import RobotModel

    log = load_arm_log(paper_rigid_path)
    box = rig_search_box(log.rig, log.model.base_parameters())
    np.testing.assert_array_equal(box, log.rig.bounds)
    assert rig_search_box(log.rig, RobotModel.puma560().base_parameters()) is None
    assert rig_search_box(dataclasses.replace(log.rig, f_bounds=()),
                          log.model.base_parameters()) is None


def test_identify_arm_on_the_rigid_log_and_its_ctc(paper_rigid_path, truth):
    """identify_arm (defaults) on the rigid development log: the rigid model kept (prediction
    errors at the quantisation floor), the sidecar's box, the well-excited f (relative standard
    error < 1 %, the arm tests' rule; it includes the paper's f1 f2 f4 f6 f7 f9) within 1 % of
    the truth; the computed torque of the result tracks the true robot within +-1 pulse after
    0.1 s, where the log's P loop does not."""
    from ctc import PController
    from ctc.arm import ArmComputedTorque
    from identification.arm import identify_arm

    log = load_arm_log(paper_rigid_path)
    f = np.array(truth("puma560_paper_rigid")["f_vector"])
    res = identify_arm(log)
    assert res.success and res.model == "rigid" and res.model_choice["adequate"]
    assert res.names == tuple(f"f{i}" for i in range(1, 10))
    np.testing.assert_array_equal(res.bounds, log.rig.bounds)
    well = res.x_rse < 0.01
    assert set(PAPER_WELL_EXCITED) <= set(np.flatnonzero(well))
    rel = np.abs(res.beta / f - 1)
    assert np.all(rel[well] < 0.01), rel
    ctl = ArmComputedTorque.from_result(res, log)
    robot = arm_plant(log.model)
    run = plant.simulate_closed_loop(log.rig, f, ctl, trajectory=log.trajectory,
                                     n_samples=log.n_samples, plant=robot)
    assert run.success and run.within(1, after_s=0.1) and ctl.tripped_at is None
    p = plant.simulate_closed_loop(log.rig, f, PController.from_log(log.rig),
                                   trajectory=log.trajectory, n_samples=log.n_samples, plant=robot)
    assert np.all(p.max_abs_error(0.1) > 10)
    # the same computed torque compiled (watchdog armed) in the loop of robots side by side:
    # the arm driver and the PUMA path's driver give the Python loop's pulses for the true f,
    # and each other's for every robot
    F = np.vstack([f, 1.05 * f, 0.9 * f])
    arm_run = simulate_arm(robot, F, log.rig, log.trajectory, log.n_samples, controller=ctl,
                           workers=1)
    puma_run = plant.simulate_batch(plant.load_log(paper_rigid_path), F, controller=ctl, workers=1)
    assert np.all(arm_run.status == 0) and np.all(puma_run.status == 0)
    np.testing.assert_array_equal(arm_run.errors[0], run.e_pulses)
    np.testing.assert_array_equal(puma_run.e_pulses, arm_run.errors)
    # its state is the controller's at t = 0: a window run from a given start state is refused
    window = plant.load_log(paper_rigid_path).window(1.0, 2.0)
    with pytest.raises(ValueError, match="starts from its state at sample 0"):
        plant.simulate_batch(window, F, controller=ctl, initial_state=np.zeros(4))


@pytest.fixture(scope="module")
def drill_result(drill_flex_path):
    from identification.arm import identify_arm

    log = load_arm_log(drill_flex_path)
    return log, identify_arm(log)  # model="auto"


def test_identify_arm_auto_chooses_the_flexible_model_on_the_drill_log(drill_result, truth):
    """model="auto" on the drill log (compliant gearboxes, noisy currents): the flexible model,
    at the quantisation floor on the held-back blocks; the rigid-equivalent well-excited f, the
    stiffnesses and the reflected motor inertias within 1 % of the emulator's."""
    log, res = drill_result
    t = truth("puma560_paper_drill_flex")
    f = np.array(t["f_vector"])
    k, _, ia = _true_joints(log, t)
    assert res.success and res.model == "flexible", res.model_choice
    assert res.model_choice["adequate"] and res.model_choice["ratio"] < 0.1
    # the springs reach the quantisation floor: no backlash left to explain, none fitted
    from identification.model_choice import ARM_FLOOR_FACTOR

    assert res.model_choice["floor_ratio"] <= ARM_FLOOR_FACTOR
    assert "held_back_cost_backlash_pulses2" not in res.model_choice
    assert "backlash not tried" in res.model_choice["reason"]
    rel = np.abs(res.beta / f - 1)
    assert np.all(rel[list(PAPER_WELL_EXCITED)] < 0.01), rel
    np.testing.assert_allclose(res.joint_stiffness_Nm_per_rad, k, rtol=0.01)
    np.testing.assert_allclose(res.motor_inertia_reflected_kgm2, ia, rtol=0.01)


def test_the_arm_ctc_of_the_drill_result_tracks_the_two_mass_robot(drill_result, truth):
    """ctc.arm's controller of the flexible result (from_result's minimax check between the
    flexible-joint and the rigid-equivalent CTC) on the true two-mass drill robot: within 2
    pulses after 0.1 s (the P loop of the log: tens)."""
    import warnings

    from ctc import PController
    from ctc.arm import ArmComputedTorque

    log, res = drill_result
    t = truth("puma560_paper_drill_flex")
    f = np.array(t["f_vector"])
    k, d, ia = _true_joints(log, t)
    row = np.concatenate([f, k, d, ia, np.zeros(2)])
    robot = arm_plant(log.model, flexible=True)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # which CTC: in ctl.selection
        ctl = ArmComputedTorque.from_result(res, log)
    assert ctl.selection["counted"][0]
    sub = max(DEFAULT_SUBSTEPS, int(res.flexible_substeps))
    run = plant.simulate_closed_loop(log.rig, row, ctl, trajectory=log.trajectory,
                                     n_samples=log.n_samples, plant=robot, substeps=sub)
    assert run.success and np.all(run.max_abs_error(0.1) <= 2), run.max_abs_error(0.1)
    p = plant.simulate_closed_loop(log.rig, row, PController.from_log(log.rig),
                                   trajectory=log.trajectory, n_samples=log.n_samples,
                                   plant=robot, substeps=sub)
    assert np.all(p.max_abs_error(0.1) > 20)
