"""ctc.ComputedTorqueController.from_result and the flexible-joint CTC (issue 13, item 5)."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import plant
from ctc import ComputedTorqueController, FlexibleJointComputedTorqueController
from ctc.guard import MIN_LIMIT_PULSES, FollowingErrorLimit
from ctc.flexible import DESIGN_TIE_PULSES
from identification.result import IdentificationResult
from plant.simulation.plants import FlexibleJoints

JM = 200e-6
AFTER_S = 0.1


def max_error_after(resp, t0=AFTER_S):
    k = resp.t >= t0
    return np.abs(resp.e_pulses[k]).max(axis=0)


def result_of(f, *, model="rigid", joints=None, friction=None):
    """An IdentificationResult built from known values (no identification run)."""
    f = np.asarray(f, dtype=float)
    d = dict(x=f.copy(), f=f, fun=0.0, nfev=1, nit=1, success=True, message="known values",
             method="ga+pem", model=model, joint_stiffness_Nm_per_rad=None,
             joint_damping_Nms_per_rad=None, motor_inertia_reflected_kgm2=None,
             friction_identified=False, model_choice=None)
    if joints is not None:
        K, D, jk = joints
        d.update(joint_stiffness_Nm_per_rad=list(K), joint_damping_Nms_per_rad=list(D),
                 motor_inertia_reflected_kgm2=list(jk))
    if friction is not None:
        d.update(viscous_friction_Nms_per_rad=list(friction[0]),
                 coulomb_friction_Nm=[list(r) for r in friction[1]], friction_identified=True)
    return IdentificationResult(d)


@pytest.fixture(scope="module")
def held_out(paper_log):
    """A flexible robot unlike the drill log's: other joints, payload, encoders."""
    f_unloaded = np.array([1.15, 0.58, 0.0, -0.52, 0.0, -1.2, 4.75, -0.1, 3.8])
    rig = dataclasses.replace(paper_log.rig, encoder_ppr=(2000, 500))
    f = plant.add_payload(f_unloaded, plant.Payload(2.5, (0.05, 0.0), 0.005), rig.a3_m)
    flex = FlexibleJoints((1.2e4, 2.5e4), (2.0, 1.0), JM)
    log = paper_log.replace(rig=rig)
    return log, f, flex


def test_rigid_result_gives_the_from_log_controller(paper_log, truth, tmp_path):
    """A rigid result (object, dict, JSON path) builds exactly from_log(result.f, log)."""
    f = np.asarray(truth("puma560_paper_rigid")["f_vector"])
    res = result_of(f)
    path = tmp_path / "rigid.json"
    res.save_json(path)
    ref = ComputedTorqueController.from_log(f, paper_log)
    q = paper_log.trajectory.position(np.arange(40) * paper_log.rig.sample_time_s)
    expected = np.array([ref(k, 0.0, q[k], np.zeros(2)) for k in range(40)])
    for src in (res, res.to_dict(), path, str(path)):
        c = ComputedTorqueController.from_result(src, paper_log)
        assert type(c) is ComputedTorqueController
        assert c.parameters == ref.parameters
        np.testing.assert_array_equal(c.f, ref.f)
        c.reset()
        got = np.array([c(k, 0.0, q[k], np.zeros(2)) for k in range(40)])
        np.testing.assert_array_equal(got, expected)


def test_identified_friction_replaces_the_sidecar_friction(paper_log, truth):
    f = np.asarray(truth("puma560_paper_rigid")["f_vector"])
    visc, coul = (0.01, 0.02), ((0.1, 0.2), (0.3, 0.4))
    c = ComputedTorqueController.from_result(result_of(f, friction=(visc, coul)), paper_log)
    k = np.asarray(paper_log.rig.gear_ratio)
    np.testing.assert_allclose(c.parameters.rig.viscous, k * k * np.array(visc))
    np.testing.assert_allclose(c.parameters.rig.coulomb_pos, np.abs(k) * np.array([0.1, 0.3]))
    np.testing.assert_allclose(c.parameters.rig.coulomb_neg, np.abs(k) * np.array([0.2, 0.4]))
    # not identified: the log's friction, even if the result echoes other numbers
    d = result_of(f, friction=(visc, coul))
    d["friction_identified"] = False
    c = ComputedTorqueController.from_result(d, paper_log)
    assert c.parameters == ComputedTorqueController.from_log(f, paper_log).parameters


def test_flexible_result_builds_the_flexible_ctc(held_out):
    log, f, flex = held_out
    jk = flex.reflected_inertia(log.rig)
    res = result_of(f, model="flexible",
                    joints=(flex.stiffness_Nm_per_rad, flex.damping_Nms_per_rad, jk))
    c = ComputedTorqueController.from_result(res.to_dict(), log, robust=None)  # the default design
    assert isinstance(c, FlexibleJointComputedTorqueController)
    np.testing.assert_allclose(c.link_f, flex.link_parameters(f, log.rig))
    assert c.flexible_parameters.stiffness == flex.stiffness_Nm_per_rad
    # the motor loop is the rigid CTC's (same gains, rig layout, options); only the
    # observer gains differ: the motor-and-link observer's
    rigid = ComputedTorqueController.from_log(f, log).parameters
    assert c.flexible_parameters.ctc._replace(observer_q=rigid.observer_q,
                                              observer_w=rigid.observer_w) == rigid


def test_flexible_ctc_tracks_a_held_out_flexible_robot_to_a_pulse(held_out):
    """On a flexible robot with other joints, payload and encoders: <= 1 pulse after 0.1 s;
    the rigid CTC with the true rigid-equivalent f does not get there."""
    log, f, flex = held_out
    jk = flex.reflected_inertia(log.rig)
    res = result_of(f, model="flexible",
                    joints=(flex.stiffness_Nm_per_rad, flex.damping_Nms_per_rad, jk))
    n = 2000
    robust = ComputedTorqueController.from_result(res, log)  # the default, robust design
    r = plant.simulate_closed_loop(log, f, robust, flexible=flex, n_samples=n)
    assert r.success and robust.robustness["robust"]
    assert np.all(max_error_after(r) <= 1), max_error_after(r)
    c = ComputedTorqueController.from_result(res, log, robust=None)  # the default design
    r = plant.simulate_closed_loop(log, f, c, flexible=flex, n_samples=n)
    assert r.success
    assert np.all(max_error_after(r) <= 1), max_error_after(r)
    rigid = plant.simulate_closed_loop(log, f, ComputedTorqueController.from_log(f, log),
                                       flexible=flex, n_samples=n)
    assert np.max(max_error_after(rigid)) > 1
    # the controller's link model (at the next sample) follows the robot's link to well
    # within a pulse (joint 3: 2.3e-4 rad)
    ts = log.rig.sample_time_s
    q_next = r.q[-1] + ts * r.qd[-1]
    assert np.all(np.abs(c.link_estimate()[:2] - q_next) < 1e-4)


def test_link_observer_places_the_error_poles(held_out):
    """eig(Phi - L C Phi) of the per-joint two-mass model = the requested poles."""
    from scipy.linalg import expm

    from ctc.flexible import link_observer_gains
    from plant.robot.model import inertia_matrix

    log, f, flex = held_out
    c = ComputedTorqueController.from_result(
        result_of(f, model="flexible", joints=(flex.stiffness_Nm_per_rad,
                                               flex.damping_Nms_per_rad,
                                               flex.reflected_inertia(log.rig))), log)
    L = link_observer_gains(c.link_f, c.flexible_parameters.stiffness,
                            c.flexible_parameters.damping, c.flexible_parameters.motor_inertia,
                            c.gains, c.link_damping)  # the robust design's choice
    ts = log.rig.sample_time_s
    jl = np.diag(inertia_matrix(c.link_f, np.zeros(2)))
    for j in range(2):
        K, D, jm = flex.stiffness_Nm_per_rad[j], flex.damping_Nms_per_rad[j], c.motor_inertia_reflected[j]
        a = np.array([[0, 1, 0, 0], [-K / jm, -D / jm, K / jm, D / jm], [0, 0, 0, 1],
                      [K / jl[j], D / jl[j], -K / jl[j], -D / jl[j]]])
        phi = expm(a * ts)
        C = np.array([[1.0, 0, 0, 0]])
        z = np.linalg.eigvals(phi - L[j][:, None] @ C @ phi)
        s = np.log(z) / ts
        wl = np.sqrt(K / jl[j])
        link = s[np.argsort(np.abs(np.abs(s) - wl))[:2]]
        np.testing.assert_allclose(np.abs(link), wl, rtol=1e-3)
        np.testing.assert_allclose(-link.real / np.abs(link), c.link_damping, rtol=1e-3)
    assert c.flexible_parameters.link_gain_q == (L[0, 2], L[1, 2])


def test_link_substeps_converged(held_out):
    """Two RK4 steps of the link model per sample give the currents of eight (to 1e-4 A)."""
    log, f, flex = held_out
    jk = flex.reflected_inertia(log.rig)
    kw = dict(stiffness_Nm_per_rad=flex.stiffness_Nm_per_rad,
              damping_Nms_per_rad=flex.damping_Nms_per_rad, motor_inertia_reflected_kgm2=jk)
    n = 1500
    q = log.trajectory.position(np.arange(n) * log.rig.sample_time_s)
    s = np.asarray(log.rig.gear_ratio) * np.asarray(log.rig.encoder_ppr) / (2 * np.pi)
    qm = np.trunc(q * s) / s
    out = []
    for ns in (2, 8):
        c = FlexibleJointComputedTorqueController.from_log(f, log, link_substeps=ns, **kw)
        out.append(np.array([c(k, 0.0, qm[k], np.zeros(2)) for k in range(n)]))
    assert np.max(np.abs(out[0] - out[1])) < 1e-4


def test_flexible_ctc_law_in_the_logged_driver_equals_the_python_loop(held_out):
    """The compiled law in the logged-run driver reproduces simulate_closed_loop."""
    log, f, flex = held_out
    jk = flex.reflected_inertia(log.rig)
    c = FlexibleJointComputedTorqueController.from_log(
        f, log, stiffness_Nm_per_rad=flex.stiffness_Nm_per_rad,
        damping_Nms_per_rad=flex.damping_Nms_per_rad, motor_inertia_reflected_kgm2=jk)
    n = 500
    resp = plant.simulate_closed_loop(log, f, c, n_samples=n, substeps=8, flexible=flex)
    run = plant.emulate_log(log, f, duration_s=(n - 1) * log.rig.sample_time_s)
    run = run.replace(e_pulses=resp.e_pulses, i_A=resp.i_A)
    sim = plant.simulate_batch(run, f[None], substeps=8, controller=c, plant=flex)
    np.testing.assert_array_equal(sim.e_pulses[0], resp.e_pulses)


def test_from_result_refuses_bad_input(paper_log, tmp_path, truth):
    f = np.asarray(truth("puma560_paper_rigid")["f_vector"])
    with pytest.raises(ValueError, match="unknown model"):
        ComputedTorqueController.from_result(dict(f=f, model="elastic"), paper_log)
    with pytest.raises(ValueError, match="joint_stiffness_Nm_per_rad"):
        ComputedTorqueController.from_result(dict(f=f, model="flexible"), paper_log)
    with pytest.raises(ValueError, match="result must be"):
        ComputedTorqueController.from_result(42, paper_log)
    with pytest.raises(ValueError, match="not found"):
        ComputedTorqueController.from_result(tmp_path / "missing.json", paper_log)
    with pytest.raises(ValueError, match="no 'f'"):
        ComputedTorqueController.from_result({}, paper_log)
    bad = dict(f=f, model="flexible", joint_stiffness_Nm_per_rad=[3e4, 6e3],
               joint_damping_Nms_per_rad=[1.0, 1.0], motor_inertia_reflected_kgm2=[50.0, 0.5])
    with pytest.raises(ValueError, match="positive definite"):
        ComputedTorqueController.from_result(bad, paper_log)
    bad["motor_inertia_reflected_kgm2"] = [0.0, 0.5]
    with pytest.raises(ValueError, match="motor_inertia_reflected_kgm2"):
        ComputedTorqueController.from_result(bad, paper_log)


@pytest.fixture(scope="module")
def drill_result(drill_log, tmp_path_factory):
    """The drill/flex log identified once with no options (about 30-45 s), saved as JSON."""
    from identification import identify

    res = identify(drill_log, rng=0, progress=False)
    path = tmp_path_factory.mktemp("drill") / "drill_result.json"
    res.save_json(path)
    return res, path


@pytest.mark.slow
def test_ctc_from_identified_drill_result_tracks_to_a_pulse(drill_log, truth, drill_result):
    """Acceptance: the CTC from the identified flexible result on the two-mass drill robot,
    paper trajectory: max abs(e) <= 1 pulse on both joints after 0.1 s."""
    res, path = drill_result
    assert res.model == "flexible"
    tr = truth("puma560_paper_drill_flex")
    v = tr["emulator"]["variant"]
    f = np.asarray(tr["f_vector"])
    flex = FlexibleJoints(tuple(v["flex_stiffness"]), tuple(v["flex_damping"]), JM)
    c = ComputedTorqueController.from_result(path, drill_log)
    assert isinstance(c, FlexibleJointComputedTorqueController)
    r = plant.simulate_closed_loop(drill_log, f, c, flexible=flex)
    assert r.success
    assert np.all(max_error_after(r) <= 1), max_error_after(r)
    # the rigid CTC of the true rigid-equivalent f: more than a pulse
    rigid = plant.simulate_closed_loop(drill_log, f, ComputedTorqueController.from_log(f, drill_log),
                                       flexible=flex)
    assert np.max(max_error_after(rigid)) > 1


@pytest.mark.parametrize("k_factor, d_factor", [(1.005, 2.6), (0.995, 0.4)])
def test_flexible_ctc_tolerates_joint_errors(held_out, k_factor, d_factor):
    """K off by 0.5 % and D by a factor 2.5 (D is the least identifiable): still <= 1 pulse
    (the measurement-corrected link estimate cannot drift out of phase)."""
    log, f, flex = held_out
    c = FlexibleJointComputedTorqueController.from_log(
        f, log, stiffness_Nm_per_rad=np.array(flex.stiffness_Nm_per_rad) * k_factor,
        damping_Nms_per_rad=np.array(flex.damping_Nms_per_rad) * d_factor,
        motor_inertia_reflected_kgm2=flex.reflected_inertia(log.rig))
    r = plant.simulate_closed_loop(log, f, c, flexible=flex)
    assert np.all(max_error_after(r) <= 1), max_error_after(r)


def test_robustness_check_reports_and_the_fallback_is_minimax(drill_log, drill_result):
    """Issue 21 item 3 (in progress): the scenario check over the stated model errors,
    its report on the controller, and robust='fallback' picking the smaller worst case."""
    import warnings as _w

    from ctc.flexible import ROBUSTNESS_SCENARIOS, _nominal, _worst

    log, res = drill_log, drill_result[0]
    c = ComputedTorqueController.from_result(res, log, robust=None)
    assert isinstance(c, FlexibleJointComputedTorqueController) and not hasattr(c, "robustness")
    # the default is the robust design: never a worse worst case than the default design
    d = ComputedTorqueController.from_result(res, log)
    assert hasattr(d, "robustness")
    with _w.catch_warnings(record=True):
        _w.simplefilter("always")
        checked = ComputedTorqueController.from_result(res, log, robust="check")
        fb = ComputedTorqueController.from_result(res, log, robust="fallback")
    rep = checked.robustness
    assert _worst(d.robustness) <= _worst(rep) + DESIGN_TIE_PULSES or \
        not isinstance(d, FlexibleJointComputedTorqueController)
    assert [s["name"] for s in rep["scenarios"]] == [s["name"] for s in ROBUSTNESS_SCENARIOS]
    assert rep["scenarios"][0]["success"]  # the nominal model holds the bound
    # the bound is the following-error limit joint by joint: a design the guard would hand
    # to the P law on one joint is not robust, however far the other joint's limit is
    limit = FollowingErrorLimit(log).limit_pulses
    assert rep["bound_pulses"] == limit.astype(int).tolist()
    for sc in rep["scenarios"]:
        assert sc["success"] == (sc["completed"] and all(
            e <= b for e, b in zip(sc["max_abs_e"], rep["bound_pulses"]))), sc
    assert rep["robust"] == all(sc["success"] for sc in rep["scenarios"])
    p_half = np.maximum(3, 0.5 * np.abs(log.e_pulses).max(axis=0))
    if not rep["robust"]:
        assert _worst(fb.robustness["rigid"]) >= _worst(fb.robustness["flexible"]) or \
            not isinstance(fb, FlexibleJointComputedTorqueController) or \
            np.any(_nominal(fb.robustness["rigid"]) > p_half)
    if not isinstance(d, FlexibleJointComputedTorqueController):
        # a rigid fallback tracks the identified robot itself (no worse than half P control)
        assert np.all(_nominal(d.robustness) <= p_half)
    with pytest.raises(ValueError, match="robust must be"):
        ComputedTorqueController.from_result(res, log, robust="yes")


def test_robustness_bound_is_each_joints_following_error_limit(drill_log, drill_result):
    """A scenario beyond one joint's following-error limit fails the check even when the
    other joint's limit is far larger (the check and the guard agree joint by joint)."""
    from ctc.flexible import robustness_check

    res = drill_result[0]
    c = ComputedTorqueController.from_result(res, drill_log, robust=None)
    scenarios = ({"name": "nominal"}, {"name": "payload +6 kg", "payload_kg": 6.0})
    first = robustness_check(c, res, drill_log, scenarios=scenarios, duration_s=0.5)
    e = np.array([sc["max_abs_e"] for sc in first["scenarios"]])
    assert e[1, 1] > MIN_LIMIT_PULSES + 5  # the heavy payload swings joint 3
    # a log whose P errors put joint 2's limit above every run and joint 3's below the heavy one
    pulses = np.zeros_like(np.asarray(drill_log.e_pulses))
    pulses[0] = [e[:, 0].max() + 5, (e[1, 1] - 1) // 2]
    log = drill_log.replace(e_pulses=pulses)
    bound = FollowingErrorLimit(log).limit_pulses
    assert bound[0] > e[:, 0].max() and e[0, 1] <= bound[1] < e[1, 1]
    rep = robustness_check(c, res, log, scenarios=scenarios, duration_s=0.5)
    assert rep["bound_pulses"] == bound.astype(int).tolist()
    assert [sc["max_abs_e"] for sc in rep["scenarios"]] == e.tolist()
    assert rep["scenarios"][0]["success"] and not rep["scenarios"][1]["success"]
    assert not rep["robust"] and "payload +6 kg" in rep["reason"]
    assert max(rep["bound_pulses"]) > e.max()  # a bound over both joints would have passed it


def test_a_result_that_says_its_model_is_off_makes_a_controller_that_says_so(paper_log, truth):
    """Issue 21: a controller says when its model no longer fits (here: from the start)."""
    f = np.asarray(truth("puma560_paper_rigid")["f_vector"])
    d = result_of(f).to_dict()
    d["model_choice"] = {"model": "rigid", "adequate": False, "reason": "held-back cost 30 floors"}
    with pytest.warns(RuntimeWarning, match="does not describe its log"):
        ComputedTorqueController.from_result(d, paper_log)
    d["model_choice"]["adequate"] = True
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        ComputedTorqueController.from_result(d, paper_log)


@pytest.mark.parametrize("ppr, ts", [((4096, 4096), 5e-4), ((250, 2000), 1e-3)])
def test_robust_design_candidates_stay_within_the_sample_rate(paper_log, ppr, ts):
    """Every candidate of the robust design is a valid design on any rig: the fast
    candidates (for gearboxes with backlash) are capped below fs/6 and fs/3, and a
    larger factor never gives a slower loop."""
    from ctc.design import default_bandwidth_hz
    from ctc.flexible import (INTEGRAL_FRACTION, MAX_BANDWIDTH_FRACTION, MAX_ESTIMATOR_FRACTION,
                              ROBUST_DESIGNS, robust_design_gains, robust_design_options)

    rig = dataclasses.replace(paper_log.rig, encoder_ppr=ppr, sample_time_s=ts)
    fs = 1.0 / ts
    last = np.zeros(2)
    for factor in sorted({f for f, _ in ROBUST_DESIGNS}):
        g = robust_design_gains(rig, factor)
        assert np.all(g.bandwidth_hz <= MAX_BANDWIDTH_FRACTION * fs + 1e-9)
        assert np.all(g.estimator_bandwidth_hz <= MAX_ESTIMATOR_FRACTION * fs + 1e-9)
        assert np.all(g.bandwidth_hz >= last) and g.stable
        np.testing.assert_allclose(g.bandwidth_hz, np.minimum(factor * default_bandwidth_hz(rig),
                                                              MAX_BANDWIDTH_FRACTION * fs))
        last = g.bandwidth_hz
        # its integral-action twin: the same loop and observer bandwidths, the sum's pole at
        # INTEGRAL_FRACTION of the loop's, stable
        gi = robust_design_gains(rig, factor, integral=True)
        np.testing.assert_array_equal(gi.bandwidth_hz, g.bandwidth_hz)
        np.testing.assert_array_equal(gi.estimator_bandwidth_hz, g.estimator_bandwidth_hz)
        np.testing.assert_allclose(gi.integral_bandwidth_hz, INTEGRAL_FRACTION * g.bandwidth_hz)
        assert gi.stable and np.all(gi.Ki > 0) and np.all(g.Ki == 0)
    # the candidates: the default's integral twin, then each design without and with it
    names = [n for n, _ in robust_design_options(rig)]
    assert len(names) == 1 + 2 * len(ROBUST_DESIGNS)
    assert names[0].endswith("integral action") and not names[1].endswith("integral action")
    assert sum(n.endswith("integral action") for n in names) == 1 + len(ROBUST_DESIGNS)


def test_a_model_switch_places_the_link_observer_for_the_new_link(held_out):
    """A payload lowers the link mode: set_model_f re-places the motor-and-link observer
    for the new link inertia (as a controller built for that f would have it), the motor
    loop keeps its gains, and a window's law under a model carries that model's observer."""
    from ctc.flexible import link_observer_gains

    log, f, flex = held_out
    joints = dict(stiffness_Nm_per_rad=flex.stiffness_Nm_per_rad,
                  damping_Nms_per_rad=flex.damping_Nms_per_rad,
                  motor_inertia_reflected_kgm2=flex.reflected_inertia(log.rig))
    c = FlexibleJointComputedTorqueController.from_log(f, log, **joints)
    before = c.flexible_parameters
    loaded = plant.add_payload(f, plant.Payload(2.0, (0.0, -0.4318), 0.0), log.rig.a3_m)
    c.set_model_f(loaded)
    fresh = FlexibleJointComputedTorqueController.from_log(loaded, log, **joints, gains=c.gains)
    assert c.flexible_parameters == fresh.flexible_parameters
    assert c.flexible_parameters.link_gain_q != before.link_gain_q
    assert c.flexible_parameters.ctc.kp == before.ctc.kp
    lg = link_observer_gains(c.link_f, c.stiffness, c.damping, c.motor_inertia_reflected,
                             c.gains, c.link_damping)
    np.testing.assert_array_equal(c.flexible_parameters.link_gain_w, lg[:, 3])
    law = c.logged_law_with(log, None, f)  # a window run under the unloaded model
    assert law.parameters.parameters == before


def test_current_per_pulse_measures_the_laws_step(paper_log, truth):
    """ctc.protocol.current_per_pulse: the P law's step is its gain; a faster CTC design
    steps more (Kp ~ w^2, the observer's velocity correction ~ w^3); the controller measured
    keeps its state (a run after the measurement equals one before it)."""
    from ctc.design import design_gains
    from ctc.protocol import PController, current_per_pulse

    rig = paper_log.rig
    p = PController(rig.p_gain_A_per_pulse, rig.current_full_scale_A)
    np.testing.assert_allclose(current_per_pulse(p, paper_log), rig.p_gain_A_per_pulse, rtol=1e-12)
    f = np.asarray(truth("puma560_paper_rigid")["f_vector"])
    slow = ComputedTorqueController.from_log(f, paper_log)
    fast = ComputedTorqueController.from_log(f, paper_log, gains=design_gains(
        rig, bandwidth_hz=2 * slow.gains.bandwidth_hz))
    s_slow, s_fast = current_per_pulse(slow, paper_log), current_per_pulse(fast, paper_log)
    assert np.all(s_slow > 0) and np.all(s_fast > 4 * s_slow), (s_slow, s_fast)
    before = plant.simulate_closed_loop(paper_log, f, slow, n_samples=300).e_pulses
    current_per_pulse(slow, paper_log, sample=50)
    np.testing.assert_array_equal(plant.simulate_closed_loop(paper_log, f, slow, n_samples=300).e_pulses,
                                  before)
    for bad in (0, 1.5, True):
        with pytest.raises(ValueError, match="sample must be"):
            current_per_pulse(slow, paper_log, sample=bad)


def test_the_robust_selection_is_minimax_at_the_encoders_resolution():
    """Worst cases within DESIGN_TIE_PULSES of the smallest are one: of the designs among
    them that hold the set, the one with the smallest one-pulse current step is kept (joint
    by joint from the largest step, inf the largest); a best design that loses the set is
    kept."""
    from ctc.flexible import select_robust_design, tied_choice

    assert DESIGN_TIE_PULSES == 1
    inf, nan = np.inf, np.nan
    # the fastest loop's 5 pulses against 6 at half its current step: the slower one
    assert tied_choice([9, 6, 5], [[3.3, 4.3], [5.0, 6.8], [7.0, 9.5]]) == 1
    # every tied design saturates a joint on one pulse: the other joint's step decides
    assert tied_choice([2, 3, 3, 4], [[4.3, inf], [3.4, inf], [3.9, inf], [0.7, 6.2]]) == 1
    # a strict minimum beyond the tie is kept whatever its step
    assert tied_choice([5, 7], [[9.0, 9.0], [1.0, 1.0]]) == 0
    # equal steps: the smaller worst case, then the first
    assert tied_choice([4, 3, 3], [[1.0, 2.0], [2.0, 1.0], [1.0, 2.0]]) == 1
    # a design that loses the set is no tie for one that holds it, and one that holds it is
    # preferred whatever the worst cases (the bound is per joint; stability first)
    assert tied_choice([3, 4], [[5.0, 5.0], [1.0, 1.0]], [True, False]) == 0
    assert tied_choice([3, 4], [[5.0, 5.0], [1.0, 1.0]], [False, True]) == 1
    assert tied_choice([3, 9, 9], [[5.0, 5.0], [1.0, 1.0], [2.0, 2.0]], [False, True, True]) == 1
    # none holds the set: the smallest worst case, whatever its step
    assert tied_choice([4, 3], [[1.0, 1.0], [5.0, 5.0]], [False, False]) == 1
    # lost runs (10**9, inf, nan) are never best unless every run was lost
    assert tied_choice([10 ** 9, 7], [[0.5, 0.5], [9.0, 9.0]]) == 1
    assert tied_choice([nan, 7], [[0.5, 0.5], [9.0, 9.0]]) == 1
    assert tied_choice([10 ** 9, inf, nan], [[1.0, 1.0], [0.5, 0.5], [0.1, 0.1]]) == 0
    # the strict minimax: the step decides equal worst cases only
    assert tied_choice([5, 6], [[9.0, 9.0], [1.0, 1.0]], tie_pulses=0) == 0
    assert tied_choice([5, 5], [[9.0, 9.0], [1.0, 1.0]], tie_pulses=0) == 1
    assert tied_choice([5, 6], [[9.0, 9.0], [1.0, 1.0]], tie_pulses=np.int64(1)) == 1
    with pytest.raises(ValueError, match="one worst case"):
        tied_choice([1, 2], [[1.0, 1.0]])
    with pytest.raises(ValueError, match="one worst case"):
        tied_choice([], [])
    for bad in (-1, "1", None, np.nan, True):
        with pytest.raises(ValueError, match="tie_pulses must be"):
            tied_choice([1], [[1.0]], tie_pulses=bad)
        # refused by the selection before any check runs
        with pytest.raises(ValueError, match="tie_pulses must be"):
            select_robust_design(None, None, None, tie_pulses=bad)


def test_robust_design_reports_and_caps_the_current_per_pulse(drill_log, drill_result):
    """Issue 21: every checked design reports its one-pulse current step; with
    max_current_per_pulse the robust design picks among the candidates whose step stays
    within that fraction of full scale (the first design always counts), a faster one only
    when none of those holds the model-error set; a bad cap is refused with one line."""
    from ctc.flexible import _worst
    from ctc.protocol import current_per_pulse

    res = drill_result[0]
    free = ComputedTorqueController.from_result(res, drill_log)
    assert free.robustness["current_per_pulse_limit_A"] == np.inf
    np.testing.assert_allclose(free.robustness["current_per_pulse_A"],
                               current_per_pulse(free, drill_log), atol=1e-4)
    c = ComputedTorqueController.from_result(res, drill_log, max_current_per_pulse=0.1)
    assert isinstance(c, FlexibleJointComputedTorqueController)
    rep = c.robustness
    limit = 0.1 * drill_log.rig.current_full_scale_A
    assert rep["current_per_pulse_limit_A"] == pytest.approx(limit)
    np.testing.assert_allclose(rep["current_per_pulse_A"], current_per_pulse(c, drill_log), atol=1e-4)
    first = ComputedTorqueController.from_result(res, drill_log, robust=None)
    assert np.max(rep["current_per_pulse_A"]) <= limit or rep["robust"] or \
        np.array_equal(c.gains.bandwidth_hz, first.gains.bandwidth_hz)
    # on the drill robot a design within the cap holds the set: the drive stays linear
    assert rep["robust"] and np.max(rep["current_per_pulse_A"]) <= limit
    assert np.max(free.robustness["current_per_pulse_A"]) >= np.max(rep["current_per_pulse_A"])
    # the cap costs robustness, never buys it (at the selection's resolution, DESIGN_TIE_PULSES)
    assert _worst(free.robustness) <= _worst(rep) + DESIGN_TIE_PULSES
    for bad in (0, -0.1, "a", True, np.inf):
        with pytest.raises(ValueError, match="max_current_per_pulse must be"):
            ComputedTorqueController.from_result(res, drill_log, max_current_per_pulse=bad)
