"""Tests of plant.simulation.closed_loop: the protocol-driven closed-loop simulator."""
from __future__ import annotations

import math

import numpy as np
import pytest

from conftest import DRILL_FLEX, PAPER_RIGID
from plant.simulation.closed_loop import ClosedLoopResponse, FlexibleJoints, simulate_closed_loop
from plant.simulation.simulate import simulate_experiment
from ctc import PController

SUBSTEPS = 24


@pytest.fixture(scope="module")
def f_true(truth):
    return np.array(truth(PAPER_RIGID)["f_vector"])


@pytest.fixture(scope="module")
def p_response(paper_log, f_true):
    return simulate_closed_loop(paper_log, f_true, PController.from_log(paper_log), substeps=SUBSTEPS)


@pytest.mark.parametrize("substeps", [4, 8])
def test_p_via_protocol_equals_simulate_experiment_any_substeps(paper_log, f_true, substeps):
    r = simulate_closed_loop(paper_log, f_true, PController.from_log(paper_log), substeps=substeps)
    np.testing.assert_array_equal(r.e_pulses, simulate_experiment(paper_log, f_true, substeps=substeps))


def test_p_via_protocol_equals_simulate_experiment(paper_log, f_true, p_response):
    e_ref = simulate_experiment(paper_log, f_true, substeps=SUBSTEPS)
    assert p_response.success
    assert p_response.e_pulses.dtype == np.int64
    assert p_response.e_pulses.shape == (paper_log.n_total, 2)
    np.testing.assert_array_equal(p_response.e_pulses, e_ref)
    # and therefore the logged experiment (simulate_experiment reproduces it at 24 substeps)
    np.testing.assert_array_equal(p_response.e_pulses, paper_log.e_pulses)
    # currents are P e
    np.testing.assert_allclose(p_response.i_A, 0.15 * p_response.e_pulses, rtol=0, atol=1e-12)


def test_window_log_runs_from_t0(paper_log, f_true):
    win = paper_log.window(1.0, 1.2)
    r = simulate_closed_loop(win, f_true, PController.from_log(win), substeps=SUBSTEPS)
    assert r.t.shape == (win.n_total,)
    np.testing.assert_array_equal(r.e_pulses[win.start_index:], simulate_experiment(win, f_true, substeps=SUBSTEPS))


def test_response_api(p_response):
    r = p_response
    n = r.t.size
    assert r.q.shape == r.qd.shape == r.q_ref.shape == r.i_A.shape == (n, 2)
    np.testing.assert_array_equal(r.max_abs_error(), [47, 41])
    m = r.max_abs_error(after_s=1.0)
    assert m.shape == (2,) and np.all(m <= r.max_abs_error())
    rms = r.rms_error()
    assert rms.shape == (2,) and np.all(rms > 0) and np.all(rms < r.max_abs_error())
    assert not r.within(pulses=1)
    assert r.within(pulses=47)
    assert r.outputs.shape == (2, n) and r.inputs.shape == (2, n) and r.states.shape == (4, n)
    tr = r.to_time_response()
    assert tr.outputs.shape == (2, n)
    with pytest.raises(ValueError, match="no sample"):
        r.max_abs_error(after_s=100.0)


def test_plot_returns_figure_without_show(p_response, monkeypatch):
    import matplotlib.pyplot as plt
    from matplotlib.figure import Figure

    monkeypatch.setattr(plt, "show", lambda *a, **k: pytest.fail("plt.show() called"))
    fig = p_response.plot()
    assert isinstance(fig, Figure)
    assert len(fig.axes) == 4


class _Constant:
    def __init__(self, i):
        self.i = i
        self.resets = 0
        self.calls = []

    def reset(self):
        self.resets += 1

    def __call__(self, k, t, q_meas, e_pulses):
        self.calls.append((k, t, q_meas.copy(), e_pulses.copy()))
        return self.i


def test_protocol_arguments_and_current_clip(paper_log, f_true):
    c = _Constant([100.0, -100.0])
    r = simulate_closed_loop(paper_log, f_true, c, n_samples=5, substeps=4)
    assert c.resets == 1
    assert [k for k, *_ in c.calls] == list(range(5))
    k, t, q, e = c.calls[3]
    assert t == pytest.approx(3 * paper_log.rig.sample_time_s)
    assert q.shape == (2,) and e.shape == (2,) and e.dtype == np.int64
    # q_meas is a whole number of pulses
    counts = q * paper_log.rig.pulses_per_rad
    np.testing.assert_allclose(counts, np.round(counts), atol=1e-9)
    fs = paper_log.rig.current_full_scale_A
    np.testing.assert_array_equal(r.i_A, np.tile([fs, -fs], (5, 1)))
    assert r.n_clipped == 5


def test_rig_needs_trajectory_and_length(paper_log, f_true):
    ctl = PController.from_log(paper_log)
    with pytest.raises(ValueError, match="trajectory is required"):
        simulate_closed_loop(paper_log.rig, f_true, ctl, n_samples=10)
    with pytest.raises(ValueError, match="n_samples is required"):
        simulate_closed_loop(paper_log.rig, f_true, ctl, trajectory=paper_log.trajectory)
    r = simulate_closed_loop(paper_log.rig, f_true, ctl, trajectory=paper_log.trajectory, n_samples=50)
    assert isinstance(r, ClosedLoopResponse) and r.t.size == 50


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(f_robot=np.ones(8)), r"shape \(9,\)"),
        (dict(f_robot=np.full(9, np.nan)), "NaN"),
        (dict(substeps=0), "substeps"),
        (dict(q0=[0.0]), "q0"),
        (dict(n_samples=0), "n_samples"),
    ],
)
def test_bad_input(paper_log, f_true, kwargs, match):
    args = dict(f_robot=f_true)
    args.update(kwargs)
    f = args.pop("f_robot")
    with pytest.raises(ValueError, match=match) as exc:
        simulate_closed_loop(paper_log, f, PController.from_log(paper_log), **args)
    assert "\n" not in str(exc.value)


def test_bad_controller(paper_log, f_true):
    with pytest.raises(ValueError, match="reset"):
        simulate_closed_loop(paper_log, f_true, lambda k, t, q, e: [0.0, 0.0], n_samples=3)
    with pytest.raises(ValueError, match="2 currents"):
        simulate_closed_loop(paper_log, f_true, _Constant([1.0]), n_samples=3)
    with pytest.raises(ValueError, match="non-finite"):
        simulate_closed_loop(paper_log, f_true, _Constant([np.nan, 0.0]), n_samples=3)


def test_non_pd_robot_stops_with_message(paper_log, f_true):
    f = f_true.copy()
    f[0] = -1.0  # D22 < 0
    r = simulate_closed_loop(paper_log, f, PController.from_log(paper_log), n_samples=20, substeps=4)
    assert not r.success and "positive definite" in r.message
    assert not r.within(pulses=1000)


def test_flexible_robot_reproduces_drill_log(drill_log, truth):
    """The two-mass robot with the truth file's emulator constants replays the drill/flex log."""
    tr = truth(DRILL_FLEX)
    v = tr["emulator"]["variant"]
    flex = FlexibleJoints(v["flex_stiffness"], v["flex_damping"], 200e-6)
    f = np.array(tr["f_vector"])
    r = simulate_closed_loop(drill_log, f, PController.from_log(drill_log), flexible=flex, substeps=16)
    assert r.success
    d = np.abs(r.e_pulses - drill_log.e_pulses)
    assert d.max() <= 1 and np.mean(d == 0) > 0.95


def test_flexible_joints_validation(paper_log):
    with pytest.raises(ValueError, match="stiffness"):
        FlexibleJoints((0.0, 1.0), (1.0, 1.0), 200e-6).vector(paper_log.rig)
    fx = FlexibleJoints((3e4, 6e3), (4.0, 0.4), 200e-6)
    fl = fx.link_parameters(np.ones(9) * 5, paper_log.rig)
    assert fl[6] == pytest.approx(5 - 200e-6 * 107.8**2)
    assert fl[0] == pytest.approx(5 - 200e-6 * 53.7**2)
    assert math.isclose(fl[1], 5.0)


def test_scheduled_joints_change_a_flexible_robot(drill_log, truth):
    """An ``f_schedule`` entry's third element may be the flexible robot's joints from then
    on (a gearbox that wears): the run is the robot's until then, and the new joints'
    after; the same joints scheduled give the run bit for bit; a rigid robot refuses it."""
    tr = truth(DRILL_FLEX)
    v = tr["emulator"]["variant"]
    flex = FlexibleJoints(v["flex_stiffness"], v["flex_damping"], 200e-6)
    softer = FlexibleJoints([0.5 * k for k in v["flex_stiffness"]], v["flex_damping"], 200e-6)
    f = np.array(tr["f_vector"])
    p = PController.from_log(drill_log)
    ts = drill_log.rig.sample_time_s
    base = simulate_closed_loop(drill_log, f, p, flexible=flex, substeps=8)
    same = simulate_closed_loop(drill_log, f, p, flexible=flex, substeps=8, f_schedule=[(1.0, f, flex)])
    np.testing.assert_array_equal(base.e_pulses, same.e_pulses)
    worn = simulate_closed_loop(drill_log, f, p, flexible=flex, substeps=8,
                                f_schedule=[(1.0, f, softer), (2.0, f)])
    k = int(np.ceil(1.0 / ts))
    np.testing.assert_array_equal(worn.e_pulses[:k], base.e_pulses[:k])
    assert np.any(worn.e_pulses[k:] != base.e_pulses[k:])
    # the softer joints persist through a later f-only entry: the same as softer from 1.0 s on
    only = simulate_closed_loop(drill_log, f, p, flexible=flex, substeps=8, f_schedule=[(1.0, f, softer)])
    np.testing.assert_array_equal(worn.e_pulses, only.e_pulses)
    with pytest.raises(ValueError, match="flexible="):
        simulate_closed_loop(drill_log, f, p, substeps=8, f_schedule=[(1.0, f, softer)])
