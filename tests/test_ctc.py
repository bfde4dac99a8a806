"""Tests of the ctc package: controllers, gain design, casadi evaluation, tracking."""
from __future__ import annotations

import numpy as np
import pytest

from conftest import PAPER_RIGID
from plant.simulation.closed_loop import simulate_closed_loop
from plant.robot.model import coriolis_centrifugal, friction_torque, gravity_vector, inertia_matrix, inverse_dynamics
from ctc import ComputedTorqueController, GainDesign, PController, SampledController, design_gains
from ctc import computed_torque as ctm

SUBSTEPS = 32


@pytest.fixture(scope="module")
def f_true(truth):
    return np.array(truth(PAPER_RIGID)["f_vector"])


@pytest.fixture(scope="module")
def ctc_true(paper_log, f_true):
    return ComputedTorqueController.from_log(f_true, paper_log)


@pytest.fixture(scope="module")
def ctc_response(paper_log, f_true, ctc_true):
    return simulate_closed_loop(paper_log, f_true, ctc_true, substeps=SUBSTEPS)


# --------------------------------------------------------------------------- model terms
def _raw_step(ctl, q, qd, qdd, *, kp=0.0, kv=0.0, friction=False):
    """Run the compiled step once on one custom reference row, estimator state = (q, qd)."""
    p = ctl.parameters._replace(kp=(float(kp), float(kp)), kv=(float(kv), float(kv)),
                                friction=friction, cell_centre=False)
    ref = np.array([[q[0], q[1], qd[0], qd[1], qdd[0], qdd[1]]])
    s = np.zeros(ctm.S_LEN)  # first sample: q_hat = q_meas, qd_hat = qd_d
    i = ctm._ctc_step(0, np.asarray(q, float), ctl.f, p, ref, s)
    return i * np.array(p.rig.torque_per_amp)  # joint torque


def test_D_h_g_from_f_match_plant_model(ctc_true, f_true):
    rng = np.random.default_rng(1)
    f = f_true * (1 + 0.3 * rng.standard_normal(9))  # any f, not only the truth
    f[0], f[6] = abs(f[0]) + 0.5, abs(f[6]) + 3.0
    ctl = ComputedTorqueController(f, ctc_true.rig, ctc_true.trajectory, ctc_true.gains, n_samples=1)
    g = ctc_true.rig.gravity_m_s2
    for _ in range(20):
        q = rng.uniform(-np.pi, np.pi, 2)
        qd = rng.uniform(-3, 3, 2)
        hg = _raw_step(ctl, q, qd, [0.0, 0.0])
        np.testing.assert_allclose(hg, coriolis_centrifugal(f, q, qd) + gravity_vector(f, q, g), rtol=1e-13, atol=1e-13)
        D = np.column_stack([_raw_step(ctl, q, qd, e) - hg for e in np.eye(2)])
        np.testing.assert_allclose(D, inertia_matrix(f, q), rtol=1e-12, atol=1e-12)
        qdd = rng.uniform(-10, 10, 2)
        np.testing.assert_allclose(_raw_step(ctl, q, qd, qdd), inverse_dynamics(f, q, qd, qdd, g), rtol=1e-12, atol=1e-12)


def test_friction_feedforward_and_current(ctc_true, f_true):
    r = ctc_true.rig
    q, qd, qdd = np.array([0.2, -0.4]), np.array([0.7, -0.003]), np.array([1.0, 2.0])
    tau = _raw_step(ctc_true, q, qd, qdd, friction=True)
    c = ctc_true.parameters.rig
    fr = [friction_torque(qd[j], c.viscous[j], c.coulomb_pos[j], c.coulomb_neg[j],
                          c.ramp_speed[j]) for j in range(2)]
    np.testing.assert_allclose(tau, inverse_dynamics(f_true, q, qd, qdd, r.gravity_m_s2) - fr, rtol=1e-12)
    # joint-side constants of plant.logs.rig.rig_constants
    k = np.array(r.gear_ratio)
    assert c.viscous[0] == pytest.approx(k[0] ** 2 * r.viscous_friction_Nms_per_rad[0])
    assert c.coulomb_neg[1] == pytest.approx(abs(k[1]) * r.coulomb_friction_Nm[1][1])


def test_first_call_is_the_control_law(paper_log, ctc_true, f_true):
    """Public call: i = (D_hat(q) a + h_hat(q, qd_d) + g_hat(q) - tau_f(qd_d)) / (k Kt)."""
    rig = paper_log.rig
    k = 700
    t = k * rig.sample_time_s
    qd_, qdd_, qdd2 = paper_log.trajectory.evaluate(t)
    q_d, w_d, a_d = qd_[0], qdd_[0], qdd2[0]
    counts = np.trunc((q_d + [3e-4, -2e-4]) * rig.pulses_per_rad)
    q_meas = counts / rig.pulses_per_rad
    y = (counts + 0.5 * np.sign(counts)) / rig.pulses_per_rad  # centre of the pulse cell
    ctc_true.reset()
    i = ctc_true(k, t, q_meas, np.zeros(2, dtype=np.int64))
    a = a_d + ctc_true.gains.Kp * (q_d - y)
    c = ctc_true.parameters.rig
    fr = [friction_torque(w_d[j], c.viscous[j], c.coulomb_pos[j], c.coulomb_neg[j],
                          c.ramp_speed[j]) for j in range(2)]
    tau = inverse_dynamics(f_true, y, w_d, a, rig.gravity_m_s2) - fr
    np.testing.assert_allclose(i * np.array(c.torque_per_amp), tau, rtol=1e-11)
    ctc_true.reset()


# --------------------------------------------------------------------------- protocol
def test_protocol(paper_log, ctc_true):
    for c in (PController.from_log(paper_log), ctc_true):
        assert isinstance(c, SampledController)
        c.reset()
        i = c(0, 0.0, np.zeros(2), np.array([2, -1]))
        assert isinstance(i, np.ndarray) and i.shape == (2,) and np.all(np.isfinite(i))
    np.testing.assert_allclose(PController([0.1, 0.2])(0, 0.0, np.zeros(2), np.array([3, -4])), [0.3, -0.8])


def test_ctc_beyond_the_table_evaluates_trajectory(paper_log, f_true):
    short = ComputedTorqueController.from_log(f_true, paper_log, n_samples=10)
    full = ComputedTorqueController.from_log(f_true, paper_log)
    ts = paper_log.rig.sample_time_s
    for c in (short, full):
        c.reset()
    for k in range(20):
        q = paper_log.trajectory.position(k * ts)[0]
        np.testing.assert_allclose(short(k, k * ts, q, np.zeros(2)), full(k, k * ts, q, np.zeros(2)), rtol=1e-12)


# --------------------------------------------------------------------------- tracking
def test_ctc_true_f_tracks_within_one_pulse(ctc_response):
    r = ctc_response
    assert r.success
    np.testing.assert_array_less(r.max_abs_error(after_s=0.05), 2)  # <= 1 pulse after 50 ms
    assert r.within(pulses=1, after_s=0.05)
    assert r.within(pulses=1)  # also over the whole run
    assert np.all(r.rms_error() < 0.4)
    assert r.n_clipped == 0


@pytest.mark.parametrize("scale", [0.995, 1.005])
def test_ctc_with_half_percent_model_error(paper_log, f_true, ctc_true, scale):
    r = simulate_closed_loop(paper_log, f_true * scale, ctc_true, substeps=SUBSTEPS)
    assert r.within(pulses=1, after_s=0.05)


def test_ctc_with_half_percent_error_per_parameter(paper_log, f_true, ctc_true):
    signs = np.random.default_rng(0).choice([-1.0, 1.0], size=9)
    r = simulate_closed_loop(paper_log, f_true * (1 + 0.005 * signs), ctc_true, substeps=SUBSTEPS)
    assert r.within(pulses=1, after_s=0.05)


def test_ctc_much_better_than_p(paper_log, f_true, ctc_response):
    p = simulate_closed_loop(paper_log, f_true, PController.from_log(paper_log), substeps=SUBSTEPS)
    assert np.all(p.max_abs_error() >= 40)
    assert np.all(ctc_response.rms_error() < p.rms_error() / 20)


# --------------------------------------------------------------------------- design
@pytest.mark.parametrize("estimator", ["observer", "difference"])
@pytest.mark.parametrize("delay", [0, 1])
def test_gains_give_stable_loop(paper_log, estimator, delay):
    g = design_gains(paper_log.rig, estimator=estimator, delay_samples=delay)
    assert isinstance(g, GainDesign)
    assert g.stable
    for j in range(2):
        assert np.all(np.abs(g.poles[j]) < 1.0)
        assert g.gain_margin[j] > 1.5
        assert g.phase_margin_deg[j] > 20.0
        assert g.stability_margin[j] > 0.3
    assert g.Kp.shape == g.Kv.shape == (2,) and np.all(g.Kp > 0) and np.all(g.Kv > 0)
    rep = g.report()
    assert "pole" in rep and "phase margin" in rep and "stable: yes" in rep


def test_design_places_the_poles(paper_log):
    import control

    bw, zeta = 20.0, 0.8
    g = design_gains(paper_log.rig, bandwidth_hz=bw, damping=zeta)
    ts = paper_log.rig.sample_time_s
    w = 2 * np.pi * bw
    target = np.exp(np.roots([1, 2 * zeta * w, w * w]) * ts)
    a = np.array([[1, ts], [0, 1]])
    b = np.array([[ts * ts / 2], [ts]])
    eig = np.linalg.eigvals(a - b @ np.array([[g.Kp[0], g.Kv[0]]]))
    np.testing.assert_allclose(np.sort_complex(eig), np.sort_complex(target), atol=1e-9)
    # the closed loop holds the controller poles and the observer poles (separation)
    cl = np.sort_complex(np.asarray(control.poles(g.closed_loop(0))))
    w_o = 2 * np.pi * g.estimator_bandwidth_hz[0]
    obs = np.exp(np.roots([1, 2 * w_o, w_o * w_o]) * ts)
    np.testing.assert_allclose(cl, np.sort_complex(np.concatenate([target, obs])), atol=1e-5)
    # near-continuous gains for w Ts << 1
    assert g.Kp[0] == pytest.approx(w * w, rel=0.1)
    assert g.Kv[0] == pytest.approx(2 * zeta * w, rel=0.1)


def test_default_bandwidth_follows_the_encoder(paper_log):
    """fs/50 up to 1000 ppr (the paper's rigs unchanged), sqrt(N/1000) beyond, fs/25 at most."""
    import dataclasses

    from ctc.design import default_bandwidth_hz

    rig = paper_log.rig
    fs = 1.0 / rig.sample_time_s
    np.testing.assert_allclose(default_bandwidth_hz(rig), fs / 50)  # 800 / 1000 ppr
    np.testing.assert_allclose(default_bandwidth_hz(rig.sample_time_s), fs / 50)
    fine = dataclasses.replace(rig, encoder_ppr=(250, 2000))
    np.testing.assert_allclose(default_bandwidth_hz(fine), [fs / 50, fs / 50 * np.sqrt(2.0)])
    finest = dataclasses.replace(rig, encoder_ppr=(8192, 4096))
    np.testing.assert_allclose(default_bandwidth_hz(finest), [fs / 25, fs / 25])
    g = design_gains(fine)
    np.testing.assert_allclose(g.bandwidth_hz, default_bandwidth_hz(fine))
    assert g.stable and g.Kp[1] == pytest.approx(2.0 * g.Kp[0], rel=0.05)  # Kp ~ w^2
    # the paper rig's design is unchanged: the same gains with or without the rule
    np.testing.assert_array_equal(design_gains(rig).Kp, design_gains(rig, bandwidth_hz=fs / 50).Kp)


@pytest.mark.parametrize("estimator", ["observer", "difference"])
def test_design_with_integral_action_places_the_poles(paper_log, estimator):
    """The PID design's closed loop holds the two loop poles, the integral pole and the
    estimator's poles where the design put them; without it the gains are unchanged."""
    import control

    ts = paper_log.rig.sample_time_s
    g0 = design_gains(paper_log.rig, estimator=estimator)
    np.testing.assert_array_equal(g0.Ki, 0.0)
    np.testing.assert_array_equal(g0.integral_bandwidth_hz, 0.0)
    g = design_gains(paper_log.rig, estimator=estimator, integral_bandwidth_hz=g0.bandwidth_hz / 10)
    assert g.stable and np.all(g.Ki > 0)
    w, w_i = 2 * np.pi * g.bandwidth_hz[0], 2 * np.pi * g.integral_bandwidth_hz[0]
    loop = np.exp(np.r_[np.roots([1, 2 * w, w * w]), -w_i] * ts)
    # the augmented double integrator (q, qd, error sum) under a = -(Kp q + Kv qd + Ki z)
    a = np.array([[1, ts, 0], [0, 1, 0], [ts, 0, 1]])
    b = np.array([[ts * ts / 2], [ts], [0]])
    eig = np.linalg.eigvals(a - b @ np.array([[g.Kp[0], g.Kv[0], g.Ki[0]]]))
    np.testing.assert_allclose(np.sort_complex(eig), np.sort_complex(loop), atol=1e-9)
    if estimator == "observer":  # separation: the closed loop holds every designed pole
        cl = np.asarray(control.poles(g.closed_loop(0)))
        for z in loop:
            assert np.min(np.abs(cl - z)) < 1e-4
    assert g.phase_margin_deg[0] > 30.0 and g.gain_margin[0] > 1.5
    if estimator == "observer":  # the docs' figure: a tenth costs under 3 degrees of phase margin
        assert 0.0 < g0.phase_margin_deg[0] - g.phase_margin_deg[0] < 3.0
    assert "Ki =" in g.report() and "Ki =" not in g0.report()


def test_integral_action_removes_a_constant_model_error(paper_log, f_true):
    """A payload the model does not know leaves the PD loop a steady error; the integral
    action's sum removes it (mean error over the second half of the run)."""
    import plant

    robot = plant.add_payload(f_true, plant.Payload(3.0, (0.0, -0.4318), 0.0), paper_log.rig.a3_m)
    runs = {}
    for name, opts in (("pd", {}), ("pid", dict(integral_bandwidth_hz=2.0))):
        ctl = ComputedTorqueController.from_log(f_true, paper_log, **opts)
        runs[name] = simulate_closed_loop(paper_log, robot, ctl, substeps=8)
    half = len(runs["pd"].e_pulses) // 2
    bias = {k: np.abs(r.e_pulses[half:].mean(axis=0)) for k, r in runs.items()}
    j = int(np.argmax(bias["pd"]))
    assert bias["pd"][j] > 1.0  # the PD loop sits more than a pulse off on this joint
    assert bias["pid"][j] < 0.5 * bias["pd"][j]
    assert np.all(runs["pid"].max_abs_error(after_s=0.5) <= runs["pd"].max_abs_error(after_s=0.5))


def test_integral_action_frozen_while_saturated(paper_log, f_true):
    """Conditional integration: a sample whose current the drive's limit cuts leaves the error
    sum where it was; an unsaturated one adds Ts (q_d - q_hat)."""
    ctl = ComputedTorqueController.from_log(f_true, paper_log, integral_bandwidth_hz=2.0)
    p = ctl.parameters
    q = np.array([0.3, -0.2])
    for big, moves in ((0.0, True), (1e4, False)):
        ref = np.array([[q[0] + 1e-3, q[1] + 1e-3, 0.0, 0.0, big, big]])
        s = np.zeros(ctm.S_LEN)
        ctm._ctc_step(0, q, ctl.f, p, ref, s)
        if moves:  # q_hat: the count's cell centre, within a pulse of q
            np.testing.assert_allclose(s[ctm.S_I:ctm.S_I + 2],
                                       p.rig.sample_time_s * (ref[0, :2] - s[ctm.S_Q:ctm.S_Q + 2]),
                                       rtol=1e-12)
            assert np.all(s[ctm.S_I:ctm.S_I + 2] > 0)
        else:
            np.testing.assert_array_equal(s[ctm.S_I:ctm.S_I + 2], 0.0)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(integral_bandwidth_hz=30.0, bandwidth_hz=20.0), "integral_bandwidth_hz"),
        (dict(integral_bandwidth_hz=-1.0), "integral_bandwidth_hz"),
        (dict(bandwidth_hz=-1.0), "bandwidth_hz"),
        (dict(bandwidth_hz=np.nan), "bandwidth_hz"),
        (dict(bandwidth_hz=500.0), "fs/6"),
        (dict(damping=0.0), "damping"),
        (dict(estimator="kalman"), "estimator"),
        (dict(delay_samples=-1), "delay_samples"),
        (dict(estimator_bandwidth_hz=600.0), "fs/3"),
    ],
)
def test_design_bad_input(paper_log, kwargs, match):
    with pytest.raises(ValueError, match=match) as exc:
        design_gains(paper_log.rig, **kwargs)
    assert "\n" not in str(exc.value)


# --------------------------------------------------------------------------- bad input
@pytest.mark.parametrize(
    "f, match",
    [
        (np.ones(8), r"shape \(9,\)"),
        (np.ones((9, 1)), r"shape \(9,\)"),
        (np.r_[np.nan, np.ones(8)], "NaN"),
        (np.r_[-1.0, np.ones(8)], "positive definite"),
    ],
)
def test_ctc_bad_f(paper_log, f, match):
    with pytest.raises(ValueError, match=match) as exc:
        ComputedTorqueController.from_log(f, paper_log)
    assert "\n" not in str(exc.value)


def test_ctc_bad_options(paper_log, f_true, ctc_true):
    with pytest.raises(ValueError, match="nonlinear_velocity"):
        ComputedTorqueController.from_log(f_true, paper_log, nonlinear_velocity="x")
    with pytest.raises(ValueError, match="either gains or design"):
        ComputedTorqueController.from_log(f_true, paper_log, gains=ctc_true.gains, bandwidth_hz=10)
    with pytest.raises(ValueError, match="GainDesign"):
        ComputedTorqueController.from_log(f_true, paper_log, gains=(1.0, 2.0))
    with pytest.raises(ValueError, match=r"shape \(2,\)"):
        ctc_true(0, 0.0, np.zeros(3), np.zeros(2))
    with pytest.raises(ValueError, match="p_gain"):
        PController([0.1, -0.1])


# --------------------------------------------------------------------------- casadi
def test_friction_sx_matches_model():
    import casadi as ca

    from plant.simulation.twin import friction_sx

    x = ca.SX.sym("x")
    fn = ca.Function("fr", [x], [friction_sx(x, 0.8, 0.3, 0.5, 0.01)])
    for v in (-1.0, -0.01, -0.004, 0.0, 0.003, 0.01, 2.0):
        assert float(fn(v)) == pytest.approx(friction_torque(v, 0.8, 0.3, 0.5, 0.01), abs=1e-15)


@pytest.mark.parametrize("estimator, horizon_s, integral", [("observer", 1.0, None),
                                                              ("difference", 0.5, None),
                                                              ("observer", 1.0, 3.0)])
def test_casadi_and_numba_agree_sample_for_sample(paper_log, f_true, estimator, horizon_s, integral):
    from ctc.evaluate import evaluate_ctc

    ctl = ComputedTorqueController.from_log(f_true, paper_log, estimator=estimator,
                                            integral_bandwidth_hz=integral)
    n = int(round(horizon_s / paper_log.rig.sample_time_s))
    robot = f_true * 1.02  # model error, so the feedback does some work
    ev = evaluate_ctc(ctl, robot, n_samples=n, substeps=SUBSTEPS)
    r = simulate_closed_loop(paper_log, robot, ctl, n_samples=n, substeps=SUBSTEPS)
    np.testing.assert_array_equal(ev.e_pulses, r.e_pulses)
    np.testing.assert_allclose(ev.i_A, r.i_A, rtol=0, atol=1e-9)
    np.testing.assert_allclose(ev.q, r.q, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(ev.max_abs_error, r.max_abs_error(after_s=0.05))
    assert ev.within_one_pulse == r.within(pulses=1, after_s=0.05)
    assert "within" in ev.summary()


def test_casadi_evaluation_true_f(paper_log, ctc_true, f_true):
    from ctc.evaluate import evaluate_ctc

    ev = evaluate_ctc(ctc_true, f_true, n_samples=1430)
    assert ev.within_one_pulse
    assert ev.e_pulses.dtype == np.int64 and ev.e_pulses.shape == (1430, 2)
    with pytest.raises(ValueError, match="n_samples"):
        evaluate_ctc(ctc_true, f_true, n_samples=10**6)
    with pytest.raises(ValueError, match="ComputedTorqueController"):
        evaluate_ctc(PController.from_log(paper_log), f_true)


def test_every_controller_follows_any_reference(paper_log):
    """trajectory= on from_log / from_result / the adaptive CTC (issue 21, item 6)."""
    from plant.logs.trajectory import Trajectory

    import ctc

    f = np.array([1.2, 0.6, 0.0, -0.5, 0.0, -1.2, 4.8, -0.1, 3.8])
    other = Trajectory.from_terms([-0.3, 0.4], [[(0.2, 3.0, 0.0)], [(-0.25, 5.0, 1.0)]], 0.3)
    c = ctc.ComputedTorqueController.from_log(f, paper_log, trajectory=other)
    assert c.trajectory == other and c.trajectory != paper_log.trajectory
    k = 700
    q, qd, qdd = other.evaluate(np.array([k * paper_log.rig.sample_time_s]))
    assert np.allclose(c.reference_table[k], np.r_[q[0], qd[0], qdd[0]], rtol=0, atol=1e-12)
    r = ctc.ComputedTorqueController.from_result({"f": list(f)}, paper_log, trajectory=other)
    assert r.trajectory == other
    a = ctc.AdaptiveComputedTorqueController.from_log(f, paper_log, trajectory=other)
    assert a.trajectory == other and a._ctc.trajectory == other
    with pytest.raises(ValueError, match="trajectory must be a plant.logs.trajectory.Trajectory"):
        ctc.ComputedTorqueController.from_log(f, paper_log, trajectory="paper")
