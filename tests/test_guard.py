"""The following-error limit (ctc.guard): the rig's P law takes over when a controller loses the arm."""
from __future__ import annotations

import warnings

import numpy as np
import pytest

import plant

from conftest import PAPER_RIGID
from ctc import (AdaptiveComputedTorqueController, ComputedTorqueController, FollowingErrorGuard,
                 FollowingErrorWarning, PController)
from ctc.guard import DWELL_S, DWELL_WINDOW_S, HARD_FACTOR, MIN_LIMIT_PULSES, FollowingErrorLimit, lost_bound
from plant.simulation.closed_loop import simulate_closed_loop

SUBSTEPS = 32


class Destabilising:
    """A law that pushes the wrong way (positive feedback): it loses the arm."""

    def __init__(self, p):
        self.p = np.asarray(p, dtype=float)

    def reset(self):
        pass

    def __call__(self, k, t, q_meas, e_pulses):
        return -0.5 * self.p * e_pulses


@pytest.fixture(scope="module")
def f_true(truth):
    return np.array(truth(PAPER_RIGID)["f_vector"])


def test_default_limit_is_the_logs_p_error(paper_log):
    lim = FollowingErrorLimit(paper_log)
    expected = np.maximum(2 * np.abs(paper_log.e_pulses).max(axis=0), MIN_LIMIT_PULSES)
    np.testing.assert_array_equal(lost_bound(paper_log.e_pulses), expected)
    np.testing.assert_array_equal(lim.limit_pulses, expected)
    e = np.array([3, -5])
    np.testing.assert_allclose(lim.p_current(e), np.asarray(paper_log.rig.p_gain_A_per_pulse) * e)
    big = np.array([10 ** 6, 0])
    assert np.all(np.abs(lim.p_current(big)) <= paper_log.rig.current_full_scale_A)
    assert lim.exceeded(expected + 1) and not lim.exceeded(expected)


def test_guard_hands_a_lost_arm_to_the_p_law(paper_log, f_true):
    """Unguarded, the destabilising law runs away; guarded, the P law holds the arm from
    the sample at which the limit trips, at the error level of the rig's own P run."""
    n = 2000
    p = paper_log.rig.p_gain_A_per_pulse
    lost = simulate_closed_loop(paper_log, f_true, Destabilising(p), n_samples=n, substeps=SUBSTEPS)
    guard = FollowingErrorGuard(Destabilising(p), paper_log)
    with pytest.warns(FollowingErrorWarning, match="P law"):
        held = simulate_closed_loop(paper_log, f_true, guard, n_samples=n, substeps=SUBSTEPS)
    p_run = simulate_closed_loop(paper_log, f_true, PController.from_log(paper_log), n_samples=n,
                                 substeps=SUBSTEPS)
    limit = guard.limit.limit_pulses
    assert np.abs(lost.e_pulses).max() > 3 * limit.max()
    assert guard.fallback_t_s is not None and [e["kind"] for e in guard.events] == ["fallback"]
    ts = paper_log.rig.sample_time_s
    k_trip = int(round(guard.fallback_t_s / ts))
    beyond = np.flatnonzero(np.any(np.abs(held.e_pulses) > limit, axis=1))
    # tripped within the dwell time after the first sample past the limit, or at twice
    # the limit, whichever came first; never far beyond it; then the P run's level
    assert beyond.size and beyond[0] <= k_trip <= beyond[0] + int(np.ceil(DWELL_S / ts))
    assert np.all(np.abs(held.e_pulses[:k_trip]) <= HARD_FACTOR * limit)
    # the arm's momentum at the trip carries it on for a few samples (266 / 204 pulses for
    # a limit of 94 / 82)
    assert np.abs(held.e_pulses).max() <= 1.5 * HARD_FACTOR * limit.max()
    settle = k_trip + 1000  # 0.7 s: the P law settles from the larger runaway of a later trip
    assert np.all(np.abs(held.e_pulses[settle:]).max(axis=0) <= np.abs(p_run.e_pulses).max(axis=0) + 2)
    guard.reset()
    assert guard.fallback_t_s is None and guard.events == [] and guard._following_above is None


def test_guard_leaves_a_good_controller_alone(paper_log, f_true):
    ctl = FollowingErrorGuard(ComputedTorqueController.from_log(f_true, paper_log), paper_log)
    with warnings.catch_warnings():
        warnings.simplefilter("error", FollowingErrorWarning)
        r = simulate_closed_loop(paper_log, f_true, ctl, substeps=SUBSTEPS)
    assert ctl.fallback_t_s is None
    k = int(np.ceil(0.1 / paper_log.rig.sample_time_s))
    assert np.abs(r.e_pulses[k:]).max() <= 1


@pytest.mark.parametrize("limit, match", [
    ("loose", "'log' or pulses"), (0.0, "> 0"), ([1.0, np.nan], "> 0"), ([1.0, 2.0, 3.0], "2 numbers"),
])
def test_bad_limit(paper_log, limit, match):
    with pytest.raises(ValueError, match=match):
        FollowingErrorLimit(paper_log, limit)


def test_guard_refuses_a_non_controller(paper_log):
    with pytest.raises(ValueError, match="sampled-controller protocol"):
        FollowingErrorGuard(object(), paper_log)


def test_p_controller_saturates_at_full_scale(paper_log):
    pc = PController.from_log(paper_log)
    assert pc.current_full_scale_A == paper_log.rig.current_full_scale_A
    i = pc(0, 0.0, np.zeros(2), np.array([10 ** 6, -10 ** 6]))
    np.testing.assert_allclose(np.abs(i), paper_log.rig.current_full_scale_A)
    with pytest.raises(ValueError, match="current_full_scale_A"):
        PController([0.1, 0.1], current_full_scale_A=-1.0)


def test_adaptive_ctc_bad_following_error_limit(paper_log, f_true):
    with pytest.raises(ValueError, match="limit_pulses"):
        AdaptiveComputedTorqueController.from_log(f_true, paper_log, following_error_limit=-3)


def test_adaptive_ctc_falls_back_to_the_p_law(paper_log, f_true):
    """A limit below one pulse with no dwell time trips on the first error: from then on the
    adaptive CTC is the P law (no further identification), says so once, and reset() re-arms
    it."""
    ctl = AdaptiveComputedTorqueController.from_log(
        f_true, paper_log, following_error_limit=FollowingErrorLimit(paper_log, 0.5, dwell_s=0.0))
    n = 1500
    with pytest.warns(FollowingErrorWarning):
        r = simulate_closed_loop(paper_log, f_true, ctl, n_samples=n, substeps=SUBSTEPS)
    assert ctl.fallback_t_s is not None
    kinds = [e["kind"] for e in ctl.events]
    assert kinds.count("fallback") == 1
    k_trip = int(round(ctl.fallback_t_s / paper_log.rig.sample_time_s))
    assert all(w["window_s"][1] <= ctl.fallback_t_s + 1e-12 for w in ctl.identifications)
    p = np.asarray(paper_log.rig.p_gain_A_per_pulse)
    fs = paper_log.rig.current_full_scale_A
    np.testing.assert_allclose(r.i_A[k_trip:], np.clip(p * r.e_pulses[k_trip:], -fs, fs))
    # the P law's windows are diagnosed (step 6): the robot is its model, so nothing is named
    assert len(ctl.diagnoses) >= 10 and ctl.diagnosis is None, ctl.diagnoses
    ctl.reset()
    assert ctl.fallback_t_s is None and ctl.events == [] and ctl.diagnoses == []


def _tripped_run(log, f, limit, schedule):
    ctl = AdaptiveComputedTorqueController.from_log(f, log, following_error_limit=limit)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = simulate_closed_loop(log, f, ctl, n_samples=3000, substeps=SUBSTEPS,
                                 f_schedule=schedule)
    assert r.success and ctl.fallback_t_s is not None and ctl.fallback_t_s >= 1.0
    # the diagnosis reports, it never switches back: the P law from the trip on
    k_trip = int(round(ctl.fallback_t_s / log.rig.sample_time_s))
    fs = log.rig.current_full_scale_A
    np.testing.assert_allclose(r.i_A[k_trip:], np.clip(
        np.asarray(log.rig.p_gain_A_per_pulse) * r.e_pulses[k_trip:], -fs, fs))
    return ctl


def test_after_the_fallback_the_p_law_windows_name_a_friction_change(paper_log, f_true):
    """Supervisor step 6's diagnosis: the motors' viscous friction tripled at 1.0 s trips a
    30-pulse limit; the P law's windows then name a friction change (an ``'unexplained'``
    event with its cause and fitted change, after the fallback), not a payload."""
    from identification.friction import friction_vector

    v = np.array(friction_vector(paper_log.rig), dtype=float)
    v[:2] *= 3.0
    ctl = _tripped_run(paper_log, f_true, 30.0, [(1.0, f_true, v)])
    named = [e for e in ctl.events if e["kind"] == "unexplained" and e["t_s"] > ctl.fallback_t_s]
    assert ctl.diagnosis == "friction" and len(named) == 1, ctl.events
    assert named[0]["cause"] == "friction"
    change = named[0]["friction_change"]
    assert change["dB2_Nms_per_rad"] > 0 and change["dB3_Nms_per_rad"] > 0, change
    assert not [e for e in ctl.events if e["kind"] == "diagnosis"]


def test_after_the_fallback_the_p_law_windows_name_a_payload(paper_log, f_true):
    """The same diagnosis when a 4 kg tool trips a 1.5-pulse limit: the windows name a
    payload of its mass (a ``'diagnosis'`` event), and no rival change."""
    tool = plant.Payload(4.0, (0.05, 0.02), 0.002)
    loaded = plant.add_payload(f_true, tool, paper_log.rig.a3_m)
    ctl = _tripped_run(paper_log, f_true, 1.5, [(1.0, loaded)])
    named = [e for e in ctl.events if e["kind"] == "diagnosis"]
    assert ctl.diagnosis == "payload" and len(named) == 1, ctl.events
    assert named[0]["mass_kg"] == pytest.approx(4.0, rel=0.1)
    assert not [e for e in ctl.events if e["kind"] == "unexplained"], ctl.events


def test_from_result_arms_the_limit(paper_log, f_true):
    """Every CTC built from a result carries the log's following-error limit (the arm's too);
    ``following_error_limit=None`` gives the bare law; the adaptive CTC's inner law has none."""
    from ctc.arm import log_envelope

    res = dict(f=list(f_true), model="rigid", success=True)
    ctl = ComputedTorqueController.from_result(res, paper_log)
    np.testing.assert_array_equal(ctl.following_error.limit_pulses,
                                  FollowingErrorLimit(paper_log).limit_pulses)
    np.testing.assert_array_equal(log_envelope(paper_log), ctl.following_error.limit_pulses)
    assert ComputedTorqueController.from_result(res, paper_log,
                                                following_error_limit=None).following_error is None
    assert ComputedTorqueController.from_log(f_true, paper_log).following_error is None
    assert AdaptiveComputedTorqueController.from_log(f_true, paper_log)._ctc.following_error is None
    with pytest.raises(ValueError, match="limit_pulses"):
        ComputedTorqueController.from_result(res, paper_log, following_error_limit=[1.0, 2.0, 3.0])


def test_flexible_ctc_from_a_wrong_result_hands_over(drill_log, truth):
    """Issue 21: a flexible-joint CTC whose joints are far off (stiffness x3) runs the compliant
    arm away; built by ``from_result`` it hands the arm to the P law, which holds it near the
    logged P run's own errors, and ``reset()`` re-arms it."""
    from plant.simulation.closed_loop import simulate_closed_loop as run

    tr = truth("puma560_paper_drill_flex")
    f = np.array(tr["f_vector"])
    emu = tr["emulator"]["variant"]
    k, d = np.array(emu["flex_stiffness"]), np.array(emu["flex_damping"])
    robot = plant.FlexibleJoints(k, d, 200e-6)
    wrong = dict(f=list(f), model="flexible", success=True,
                 joint_stiffness_Nm_per_rad=list(3 * k), joint_damping_Nms_per_rad=list(d),
                 motor_inertia_reflected_kgm2=list(200e-6 * np.asarray(drill_log.rig.gear_ratio) ** 2))
    n = 3000
    bare = ComputedTorqueController.from_result(wrong, drill_log, robust=None,
                                                following_error_limit=None)
    lost = run(drill_log, f, bare, flexible=robot, substeps=16, n_samples=n)
    ctl = ComputedTorqueController.from_result(wrong, drill_log, robust=None)
    with pytest.warns(FollowingErrorWarning, match="P law holds the arm"):
        held = run(drill_log, f, ctl, flexible=robot, substeps=16, n_samples=n)
    limit = ctl.following_error.limit_pulses
    assert np.abs(lost.e_pulses).max() > 5 * limit.max()
    assert ctl.fallback_t_s is not None and held.success
    # tripped at twice the limit or after the dwell time: the arm's momentum carries it a
    # little further (179 / 189 pulses for a limit of 108 / 94)
    assert np.all(np.abs(held.e_pulses).max(axis=0) <= (HARD_FACTOR + 0.5) * limit)
    ctl.reset()
    assert ctl.fallback_t_s is None


def test_lost_bound_is_the_robustness_checks_bound(paper_log):
    """One definition of a lost loop: the guard's default and the flexible design's check."""
    e = np.array([[3, -50], [-7, 12]])
    np.testing.assert_array_equal(lost_bound(e), [20, 100])
    assert int(lost_bound(paper_log.e_pulses).max()) == max(20, 2 * int(np.abs(paper_log.e_pulses).max()))
    with pytest.raises(ValueError, match="n_samples, n_joints"):
        lost_bound([1, 2, 3])


class _Holder:
    fallback_t_s = None


def test_the_limit_trips_on_a_level_or_a_time(paper_log):
    """A transient beyond the limit shorter than the dwell time is let through; errors beyond
    it for longer than the dwell time within the window, or beyond twice it, trip it."""
    ts = paper_log.rig.sample_time_s
    lim = FollowingErrorLimit(paper_log, [10.0, 10.0])
    assert (lim.dwell_s, lim.window_s, lim.hard_factor) == (DWELL_S, DWELL_WINDOW_S, HARD_FACTOR)
    n_dwell = int(np.floor(DWELL_S / ts + 1e-9))  # samples beyond the limit that do not trip it
    inside, beyond = np.array([3.0, -9.0]), np.array([0.0, -15.0])

    def first_trip(errors):
        h = _Holder()
        for k, e in enumerate(errors):
            if lim.trips(h, k * ts, e):
                return k
        return None

    assert first_trip([inside] * 50) is None
    assert first_trip([beyond] * n_dwell + [inside] * 50) is None          # a transient
    assert first_trip([inside] * 5 + [beyond] * 100) == 5 + n_dwell       # held beyond it
    assert first_trip([inside] * 5 + [np.array([21.0, 0.0])]) == 5         # beyond twice it
    assert first_trip([inside] * 5 + [np.array([20.0, -20.0])]) is None    # twice it exactly
    # samples beyond the limit count within the window only: a short excursion once per
    # window never adds up, two close together do
    gap = int(np.ceil(DWELL_WINDOW_S / ts)) + 1
    half = n_dwell // 2 + 1
    spaced = ([beyond] * half + [inside] * gap) * 4
    assert first_trip(spaced) is None
    assert first_trip([beyond] * half + [inside] * 3 + [beyond] * half) is not None
    # a new run (time back at its start) counts afresh
    h = _Holder()
    for k in range(n_dwell):
        assert not lim.trips(h, k * ts, beyond)
    assert not lim.trips(h, 0.0, beyond)
    # the same time again (a controller called twice in a sample) counts once
    h = _Holder()
    for k in range(n_dwell):
        assert not lim.trips(h, k * ts, beyond) and not lim.trips(h, k * ts, beyond)
    assert lim.trips(h, n_dwell * ts, beyond)
    # no dwell: the first sample beyond the limit trips it
    assert FollowingErrorLimit(paper_log, 10.0, dwell_s=0.0).trips(_Holder(), 0.0, beyond)


@pytest.mark.parametrize("kw, match", [
    (dict(dwell_s=-0.01), "dwell_s"), (dict(dwell_s=np.inf), "dwell_s"),
    (dict(dwell_s=0.05, window_s=0.02), "window_s"), (dict(hard_factor=0.5), "hard_factor"),
    (dict(hard_factor="x"), "hard_factor must be a number"), (dict(dwell_s="0.02"), "a number"),
    (dict(dwell_s=0.02, window_s=0.02), "window_s"),
])
def test_bad_dwell_or_hard_factor(paper_log, kw, match):
    with pytest.raises(ValueError, match=match):
        FollowingErrorLimit(paper_log, 10.0, **kw)


def test_reset_clears_the_time_beyond_the_limit(paper_log, f_true):
    """A controller's reset() forgets the samples beyond the limit of its last run."""
    ctl = ComputedTorqueController.from_result(dict(f=list(f_true), model="rigid", success=True),
                                               paper_log, following_error_limit=1.0)
    ts = paper_log.rig.sample_time_s
    for k in range(5):
        assert ctl.following_error.hold(ctl, 10.0 + k * ts, np.array([1.5, 0.0])) is None
    assert len(ctl._following_above) == 5
    ctl.reset()
    assert ctl._following_above is None and ctl.fallback_t_s is None
