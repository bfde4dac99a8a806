"""On-line payload identification and adaptation under CTC (issue 14, items 2-3).

The robot (the emulated plant of :func:`plant.simulate_closed_loop`) picks
up a payload mid-run (``f_schedule``); the adaptive CTC must track to +-1
pulse from 0.5 s after the pick-up on, end with the payload's mass within
5 %, and before the pick-up track no worse than the static CTC.
"""
from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

import ctc
import plant

SUBSTEPS = 8
#: Identification latency of the acceptance runs (s): the per-window budget.
LATENCY_S = ctc.adaptive.DEFAULT_LATENCY_S


def _static_and_adaptive(log, prior, schedule, warns):
    """The static CTC's and the adaptive CTC's runs of ``log`` from ``prior`` through the
    changes ``schedule``; the adaptive run must warn ``UnmodelledChangeWarning`` matching
    ``warns``.  Returns (static response, adaptive controller, adaptive response)."""
    static = plant.simulate_closed_loop(log, prior, ctc.ComputedTorqueController.from_log(prior, log),
                                        f_schedule=schedule, substeps=SUBSTEPS)
    adaptive = ctc.AdaptiveComputedTorqueController.from_log(prior, log)
    with pytest.warns(ctc.UnmodelledChangeWarning, match=warns):
        resp = plant.simulate_closed_loop(log, prior, adaptive, f_schedule=schedule,
                                          substeps=SUBSTEPS)
    return static, adaptive, resp


@pytest.fixture(scope="module")
def prior(truth):
    return np.asarray(truth("puma560_paper_rigid")["f_vector"], dtype=float)


@pytest.mark.parametrize("mass_kg, com_m, izz, t_pick", [
    (2.0, (0.10, 0.02), 0.01, 1.0),   # the case
    (0.5, (0.05, -0.03), 0.002, 1.3),
    (4.0, (0.15, 0.05), 0.03, 0.8),
])
def test_adaptive_ctc_after_a_pick_up(paper_log, prior, mass_kg, com_m, izz, t_pick):
    """Acceptance with the identification latency fixed at its 0.2 s budget.

    The measured wall time depends on the machine's load at test time (the
    model switch is delayed by it, by design); the budget itself is measured
    by ``benchmarks/bench_online_payload.py``, and the measured-latency path
    by ``test_measured_latency_delays_the_switch``.
    """
    a3 = paper_log.rig.a3_m
    f_loaded = plant.add_payload(prior, plant.Payload(mass_kg, com_m, izz), a3)
    schedule = [(t_pick, f_loaded)]
    static = plant.simulate_closed_loop(paper_log, prior,
                                        ctc.ComputedTorqueController.from_log(prior, paper_log),
                                        f_schedule=schedule, substeps=SUBSTEPS)
    adaptive = ctc.AdaptiveComputedTorqueController.from_log(prior, paper_log,
                                                             latency_s=LATENCY_S)
    resp = plant.simulate_closed_loop(paper_log, prior, adaptive, f_schedule=schedule,
                                      substeps=SUBSTEPS)
    assert resp.success and static.success
    ts = paper_log.rig.sample_time_s
    k_pick = int(np.ceil(t_pick / ts))
    k_settled = int(np.ceil((t_pick + 0.5) / ts))
    assert np.all(np.abs(resp.e_pulses[k_settled:]).max(axis=0) <= 1)
    # no false update before the pick-up: no worse than the static CTC
    assert np.all(np.abs(resp.e_pulses[:k_pick]).max(axis=0)
                  <= np.abs(static.e_pulses[:k_pick]).max(axis=0))
    assert adaptive.payload_history, adaptive.identifications
    t_last, m_last = adaptive.payload_history[-1]
    assert m_last == pytest.approx(mass_kg, rel=0.05)
    assert adaptive.payload_mass_kg == m_last
    # every accepted update took effect only after its identification's wall time
    for rec in adaptive.identifications:
        assert rec["wall_time_s"] > 0
    starts = [t for t, _ in adaptive.payload_history]
    ends = [r["window_s"][1] + LATENCY_S for r in adaptive.identifications if r["accepted"]]
    for t_eff, t_min in zip(starts, ends):
        assert t_eff >= t_min - ts


def _put_down(log, prior):
    """The adaptive CTC's run of ``log`` with a 2 kg tool picked up at 0.8 s and put down at
    2.2 s.  Returns (controller, response)."""
    f_loaded = plant.add_payload(prior, plant.Payload(2.0, (0.10, 0.02), 0.01), log.rig.a3_m)
    schedule = [(0.8, f_loaded), (2.2, np.asarray(prior, dtype=float))]
    adaptive = ctc.AdaptiveComputedTorqueController.from_log(prior, log, latency_s=LATENCY_S)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ctc.UnmodelledChangeWarning)
        resp = plant.simulate_closed_loop(log, prior, adaptive, f_schedule=schedule,
                                          substeps=SUBSTEPS)
    return adaptive, resp


def test_a_put_down_returns_to_the_empty_gripper(paper_log, prior):
    """After a put-down the window's mass is below its resolution: the empty gripper
    (the prior itself, no payload) is the update when it explains the window, never a
    few grams with the centre of mass at the box edge."""
    adaptive, resp = _put_down(paper_log, prior)
    assert resp.success
    masses = [m for _, m in adaptive.payload_history]
    assert any(m == pytest.approx(2.0, rel=0.05) for m in masses), adaptive.identifications
    t_last, m_last = adaptive.payload_history[-1]
    assert m_last == 0.0 and adaptive.payload is None
    np.testing.assert_array_equal(adaptive.f, prior)
    assert any(r["empty_gripper"] and r["accepted"] for r in adaptive.identifications)
    k = int(np.ceil(2.7 / paper_log.rig.sample_time_s))
    assert np.all(np.abs(resp.e_pulses[k:]).max(axis=0) <= 1)


def test_a_put_down_read_above_the_mass_resolution_yields_to_the_empty_gripper(
        paper_log, prior, monkeypatch):
    """While a payload is in use the empty gripper is the nested null of every estimate:
    with the mass-resolution rule switched off (SMALL_MASS_FRACTION = 0), a put-down's
    estimates, whatever mass they read, do not explain their windows significantly better
    than no payload, and the update is still to the empty gripper."""
    monkeypatch.setattr(ctc.adaptive, "SMALL_MASS_FRACTION", 0.0)
    adaptive, resp = _put_down(paper_log, prior)
    assert resp.success
    assert any(m == pytest.approx(2.0, rel=0.05) for _, m in adaptive.payload_history)
    assert adaptive.payload_history[-1][1] == 0.0 and adaptive.payload is None
    np.testing.assert_array_equal(adaptive.f, prior)
    emptied = [r for r in adaptive.identifications if r["empty_gripper"] and r["accepted"]]
    # installed by the nested test: with no mass resolution no estimate is sub-resolution
    assert emptied and all(r["window_s"][0] > 2.0 for r in emptied)
    k = int(np.ceil(2.7 / paper_log.rig.sample_time_s))
    assert np.all(np.abs(resp.e_pulses[k:]).max(axis=0) <= 1)


def test_measured_latency_delays_the_switch(paper_log, prior):
    """``latency_s='measured'``: a new model takes effect after the measured wall time."""
    a3 = paper_log.rig.a3_m
    f_loaded = plant.add_payload(prior, plant.Payload(2.0, (0.10, 0.02), 0.01), a3)
    adaptive = ctc.AdaptiveComputedTorqueController.from_log(prior, paper_log,
                                                             latency_s="measured")
    resp = plant.simulate_closed_loop(paper_log, prior, adaptive, f_schedule=[(1.0, f_loaded)],
                                      substeps=SUBSTEPS, n_samples=int(2.2 / paper_log.rig.sample_time_s))
    assert resp.success and adaptive.identifications
    ts = paper_log.rig.sample_time_s
    t_end = resp.t[-1]
    accepted = [r for r in adaptive.identifications if r["accepted"]]
    # every accepted model takes effect only after its measured wall time; one whose
    # wall time runs past the end of the run (a loaded machine) never takes effect
    due = [r for r in accepted if r["window_s"][1] + r["wall_time_s"] <= t_end - ts]
    # the model switches that were updates (a rollback or a return to the prior is one too)
    switches = [e["t_s"] for e in adaptive.events if e["kind"] == "update" and e["t_s"] <= t_end]
    assert len(switches) >= len(due)
    assert set(switches) <= {t for t, _ in adaptive.payload_history}
    for t_eff, rec in zip(switches, accepted):
        assert rec["wall_time_s"] > 0
        assert t_eff >= rec["window_s"][1] + rec["wall_time_s"] - ts


def test_adaptive_ctc_protocol_and_prior_forms(paper_log, prior, tmp_path):
    path = tmp_path / "prior.json"
    path.write_text(json.dumps({"f": list(map(float, prior))}))
    for p in (prior, {"f": list(prior)}, path, str(path)):
        c = ctc.AdaptiveComputedTorqueController.from_log(p, paper_log, window_s=0.1)
        assert isinstance(c, ctc.SampledController)
        np.testing.assert_array_equal(c.prior_f, prior)
    c.reset()
    i = c(0, 0.0, np.zeros(2), np.zeros(2, dtype=np.int64))
    assert i.shape == (2,) and np.all(np.isfinite(i))
    assert c.payload_history == [] and c.payload_mass_kg == 0.0
    with pytest.raises(ValueError, match="prior"):
        ctc.AdaptiveComputedTorqueController.from_log(prior[:8], paper_log)
    with pytest.raises(ValueError, match="window_s"):
        ctc.AdaptiveComputedTorqueController.from_log(prior, paper_log, window_s=0.001)


def test_fixed_latency_repeats_bit_for_bit(paper_log, prior):
    """Issue 21 item 5: with the default (fixed) latency two runs are identical."""
    a3 = paper_log.rig.a3_m
    f_loaded = plant.add_payload(prior, plant.Payload(2.0, (0.10, 0.02), 0.01), a3)
    n = int(2.0 / paper_log.rig.sample_time_s)
    runs = []
    for _ in range(2):
        adaptive = ctc.AdaptiveComputedTorqueController.from_log(prior, paper_log)
        resp = plant.simulate_closed_loop(paper_log, prior, adaptive, f_schedule=[(1.0, f_loaded)],
                                          substeps=SUBSTEPS, n_samples=n)
        runs.append((resp, adaptive))
    (r1, a1), (r2, a2) = runs
    assert np.array_equal(r1.e_pulses, r2.e_pulses) and np.array_equal(r1.i_A, r2.i_A)
    assert a1.payload_history == a2.payload_history and a1.payload_history
    with pytest.raises(ValueError, match="latency_s"):
        ctc.AdaptiveComputedTorqueController.from_log(prior, paper_log, latency_s="soon")


def test_a_flexible_prior_without_its_joints_is_refused_in_one_line(paper_log, prior, tmp_path):
    flex = {"f": list(prior), "model": "flexible"}
    with pytest.raises(ValueError, match="a flexible prior needs joint_stiffness_Nm_per_rad"):
        ctc.AdaptiveComputedTorqueController.from_log(flex, paper_log)
    path = tmp_path / "flex.json"
    path.write_text(json.dumps(flex))
    with pytest.raises(ValueError, match="never reduced to its rigid f"):
        ctc.AdaptiveComputedTorqueController.from_log(path, paper_log)
    with pytest.raises(ValueError, match="rigid or flexible prior"):
        ctc.AdaptiveComputedTorqueController.from_log(dict(flex, model="spring"), paper_log)
    ctc.AdaptiveComputedTorqueController.from_log(dict(flex, model="rigid"), paper_log)


@pytest.fixture(scope="module")
def drill_result(drill_log):
    """The drill/flex log identified with no options (the flexible model)."""
    import warnings as _w

    import identification

    with _w.catch_warnings():
        _w.simplefilter("ignore")
        return (identification.identify(drill_log, rng=0, progress=False),)


def test_flexible_prior_flexible_inner_loop_and_payload(drill_log, drill_result):
    """Issue 21 item 2: a flexible prior runs the flexible-joint CTC, and the payload is
    identified through the two-mass plant with it in the loop (a 2 kg pick-up at 1.0 s on
    the identified two-mass robot): the arm tracks within +-1 pulse again from 0.5 s after
    the pick-up with the mass within 5 %, and no other change is reported.  The first
    update is within 5 % already: on the 86 Hz design the robust selection kept before its
    resolution (ctc.flexible.tied_choice), each window's residual stayed near the baseline,
    the update came from PERSISTENCE_WINDOWS agreeing windows and installed their pooled
    estimate (an earlier version installed the last window's 2.10 kg, and the 5 % missed
    payload then read as a stiffness change of the joints, x1.17 / x0.57 -- a false report);
    on the 71 Hz design the first window after the pick-up is significant on its own and
    reads 2.00 kg."""
    import warnings as _w

    from ctc.flexible import FlexibleJointComputedTorqueController

    res = drill_result[0]
    d = res.to_dict() if hasattr(res, "to_dict") else dict(res)
    assert d["model"] == "flexible"
    f = np.asarray(d["f"], dtype=float)
    jk = np.asarray(d["motor_inertia_reflected_kgm2"], dtype=float)
    robot = plant.FlexibleJoints(d["joint_stiffness_Nm_per_rad"], d["joint_damping_Nms_per_rad"],
                                 jk / np.asarray(drill_log.rig.gear_ratio) ** 2)
    loaded = plant.add_payload(f, plant.Payload(2.0, (0.1, 0.02), 0.01), drill_log.rig.a3_m)
    adaptive = ctc.AdaptiveComputedTorqueController.from_log(d, drill_log)
    assert isinstance(adaptive._ctc, FlexibleJointComputedTorqueController)
    assert adaptive.flexible_joints is not None
    with _w.catch_warnings():
        _w.simplefilter("ignore")
        r = plant.simulate_closed_loop(drill_log, f, adaptive, flexible=robot,
                                       f_schedule=[(1.0, loaded)], substeps=SUBSTEPS)
    assert r.success
    ts = drill_log.rig.sample_time_s
    before = np.abs(r.e_pulses[int(0.1 / ts):int(1.0 / ts)]).max(axis=0)
    assert np.all(before <= 1), before  # no false update before the pick-up
    assert all(m <= 0.05 for t, m in adaptive.payload_history if t < 1.0)
    assert adaptive.payload_history, adaptive.identifications
    assert adaptive.payload_mass_kg == pytest.approx(2.0, rel=0.05)
    update = next(i for i in adaptive.identifications if i["accepted"])
    # the first update is right, not only the last (pooled agreeing windows or one window)
    assert update["mass_kg"] == pytest.approx(2.0, rel=0.05), update
    assert adaptive.payload_history[0][1] == pytest.approx(2.0, rel=0.05)
    assert not [e for e in adaptive.events if e["kind"] == "unexplained"], adaptive.events
    assert np.all(np.isfinite(r.i_A)) and np.abs(r.i_A).max() <= drill_log.rig.current_full_scale_A
    # the robust (fast) design keeps this pick-up's residual near the baseline: the update
    # comes from successive significant windows agreeing on the mass (PERSISTENCE_WINDOWS)
    after = np.abs(r.e_pulses[int(1.5 / ts):]).max(axis=0)
    assert np.all(after <= 1), after
    # the likelihood ratio is a generalised one (step 1): the model in use at its best start
    # state in the estimate's box too, which on a two-mass arm is wider -- and some windows
    # need it (in its own box alone, five quiet windows before the pick-up read LR 18.5 to 147
    # with an estimate within 12 g of no payload; two do now)
    records = adaptive.identifications
    assert all(i["fun_current"] <= i["fun_current_own"] for i in records)
    assert any(i["fun_current"] < i["fun_current_own"] for i in records if i["window_s"][1] < 1.0)
    quiet = [i for i in records if i["window_s"][1] < 1.0 and i["mass_kg"] < 0.05]
    assert sum(i["lr"] > i["threshold"] for i in quiet) <= len(quiet) / 2, records


def test_a_stiffness_change_on_a_flexible_arm_is_reported_not_adapted(drill_log, drill_result):
    """Issue 21 item 1: both gearboxes of the identified two-mass drill robot lose 30 % of
    their stiffness at 1.0 s.  The flexible-joint CTC keeps the arm near its band, so no
    window's residual shows a change a payload could answer; the drive check (the
    drive-change hypothesis against the model in use, PERSISTENCE_WINDOWS windows agreeing)
    names it -- an ``'unexplained'`` event with ``cause='drive'`` and the factors -- and the
    model is kept: no payload update, tracking as the static CTC's within a pulse.

    On the robust design the controller keeps by default, windows seconds after the
    change read payloads of tens of grams, within :func:`ctc.adaptive.same_payload` of the
    empty gripper in use; such an update used to meet no rival and was installed until the
    empty gripper explained the windows again.  After a named stiffness change it meets the
    rival changes, and the named drive change wins a tie."""
    import warnings as _w

    d = drill_result[0]
    d = d.to_dict() if hasattr(d, "to_dict") else dict(d)
    f = np.asarray(d["f"], dtype=float)
    jk = np.asarray(d["motor_inertia_reflected_kgm2"], dtype=float)
    jm = jk / np.asarray(drill_log.rig.gear_ratio) ** 2
    K = np.asarray(d["joint_stiffness_Nm_per_rad"], dtype=float)
    robot = plant.FlexibleJoints(K, d["joint_damping_Nms_per_rad"], jm)
    softer = plant.FlexibleJoints(0.7 * K, d["joint_damping_Nms_per_rad"], jm)
    schedule = [(1.0, f, softer)]
    with _w.catch_warnings():
        _w.simplefilter("ignore")
        static = plant.simulate_closed_loop(drill_log, f, ctc.ComputedTorqueController.from_result(
            d, drill_log), flexible=robot, f_schedule=schedule, substeps=SUBSTEPS)
        adaptive = ctc.AdaptiveComputedTorqueController.from_log(d, drill_log)
    with pytest.warns(ctc.UnmodelledChangeWarning, match="stiffness"):
        r = plant.simulate_closed_loop(drill_log, f, adaptive, flexible=robot, f_schedule=schedule,
                                       substeps=SUBSTEPS)
    assert r.success and static.success
    named = [e for e in adaptive.events if e.get("cause") == "drive"]
    assert len(named) == 1 and named[0]["t_s"] > 1.0, adaptive.events
    factors = list(named[0]["drive_change"].values())
    np.testing.assert_allclose(factors, [0.7, 0.7], rtol=0.15)
    assert adaptive.payload_history == [], adaptive.events
    assert not [e for e in adaptive.events if e["kind"] == "update"], adaptive.events
    ts = drill_log.rig.sample_time_s
    after = slice(int(1.5 / ts), None)
    assert np.all(np.abs(r.e_pulses[after]).max(axis=0)
                  <= np.abs(static.e_pulses[after]).max(axis=0) + 1)


def test_after_a_fallback_on_a_flexible_arm_the_p_law_names_the_stiffness_change(drill_log,
                                                                                  drill_result):
    """Supervisor step 6's diagnosis on a two-mass arm: the joints lose 60 % of their
    stiffness at 1.0 s and trip a 1.5-pulse following-error limit; the P law's windows,
    identified through the two-mass plant with the P law in the loop, name a change of the
    joints' stiffness and damping (softer), not a payload or friction.  (A limit with a dwell
    time trips later, after the supervisor has read the change as a payload: the test is of
    the diagnosis, so the limit trips at once.)"""
    import warnings as _w

    d = drill_result[0]
    d = d.to_dict() if hasattr(d, "to_dict") else dict(d)
    f = np.asarray(d["f"], dtype=float)
    jm = (np.asarray(d["motor_inertia_reflected_kgm2"], dtype=float)
          / np.asarray(drill_log.rig.gear_ratio) ** 2)
    K = np.asarray(d["joint_stiffness_Nm_per_rad"], dtype=float)
    D = d["joint_damping_Nms_per_rad"]
    from ctc.guard import FollowingErrorLimit

    # no dwell time: the limit trips at the first sample beyond it
    adaptive = ctc.AdaptiveComputedTorqueController.from_log(
        d, drill_log, following_error_limit=FollowingErrorLimit(drill_log, 1.5, dwell_s=0.0))
    with _w.catch_warnings():
        _w.simplefilter("ignore")
        r = plant.simulate_closed_loop(drill_log, f, adaptive,
                                       flexible=plant.FlexibleJoints(K, D, jm),
                                       f_schedule=[(1.0, f, plant.FlexibleJoints(0.4 * K, D, jm))],
                                       substeps=SUBSTEPS)
    assert r.success and adaptive.fallback_t_s is not None and adaptive.fallback_t_s >= 1.0
    named = [e for e in adaptive.events if e["t_s"] > adaptive.fallback_t_s]
    assert adaptive.diagnosis == "drive" and len(named) == 1, adaptive.events
    assert named[0]["kind"] == "unexplained" and named[0]["cause"] == "drive"
    change = named[0]["drive_change"]
    assert change["lnK2"] < 0 and change["lnK3"] < 0, change


def test_two_agreeing_estimates_away_from_the_model_are_evidence():
    """The persistence rule of the supervisor's step 3: successive estimates on one
    side of the model's mass, closer to each other than to it, agree; the scatter of
    estimates around the model in use (quiet windows) does not."""
    from ctc.adaptive import _agree_off_model

    assert _agree_off_model(1.96, 1.40, 0.0)         # a pick-up the loop hides
    assert _agree_off_model(0.1, 0.12, 2.0) is True  # a put-down
    assert not _agree_off_model(3.84, 2.84, 3.98)    # scatter around a 4 kg model
    assert not _agree_off_model(4.08, 3.9, 3.98)     # on both sides of it
    assert not _agree_off_model(0.03, 0.04, 0.0)     # within 50 g of it


def test_three_updates_of_no_one_mass_are_not_a_payload():
    """The consistency rule of the supervisor's step 5: a pick-up's updates (one window
    spanning it, then agreeing estimates) and a put-down (an update to no payload) are
    one payload's; three successive updates of which no two agree are not."""
    from ctc.adaptive import _one_payload

    assert _one_payload([2.37, 3.64, 3.37])      # spanning window, then a refinement
    assert _one_payload([0.93, 1.84, 0.0])       # pick-up, then put down
    assert _one_payload([4.12, 2.49])            # fewer than three: no verdict
    assert not _one_payload([4.12, 2.49, 0.73])  # a friction change read as payloads
    assert not _one_payload([2.09, 1.43, 0.71])


def test_the_window_after_an_update_judges_it():
    """Supervisor step 5's trial: the first window under an update that disagrees with it
    twice in a row is no constant payload, unless the second disagreeing estimate
    corroborates the update before the one on trial (A, B, then C ~ A: B the outlier,
    the changes benchmark's 0014), and only once."""
    from ctc.adaptive import _one_payload, _trial_strike

    assert _trial_strike(3.05, 3.02, [3.02], 0) == (0, False)        # confirmed
    assert _trial_strike(1.65, 3.64, [3.64], 0) == (1, False)        # one strike
    # 3.64, 1.65, then 3.02: corroborates 3.64, which _one_payload reads as one payload too
    assert _trial_strike(3.02, 1.65, [3.64, 1.65], 1) == (2, False)
    assert _one_payload([3.64, 1.65, 3.02])
    # a second disagreement that is nobody's payload, or a third in a row: inconsistent
    assert _trial_strike(2.40, 1.65, [3.64, 1.65], 1) == (2, True)
    assert _trial_strike(1.70, 3.02, [3.64, 1.65, 3.02], 2) == (3, True)
    # the empty gripper corroborates nothing (a put-down is an update of its own)
    assert _trial_strike(0.0, 1.0, [0.02, 1.0], 1) == (2, True)


def test_a_refinement_pools_the_estimates_of_the_payload(paper_log, prior):
    """Step 3: a refinement installs the mean payload of its estimates; f is affine in the
    linear payload vector, so the mean f is the model of the mean payload."""
    from ctc.adaptive import _pooled
    from identification.parameters import PayloadParameters

    space = PayloadParameters(prior)
    X = np.array([[3.64, 0.10, 0.02, 0.010], [3.37, 0.12, -0.01, 0.012], [3.89, 0.08, 0.03, 0.008]])
    estimates = [(space.to_f(x, paper_log), space.extras(x, paper_log)["payload"]) for x in X]
    f, payload = _pooled(estimates)
    p_mean = PayloadParameters.linear(X).mean(axis=0)
    np.testing.assert_allclose(payload["vector"], p_mean)
    assert payload["mass_kg"] == pytest.approx(X[:, 0].mean()) and payload["pooled"] == 3
    x_mean = np.array([payload["mass_kg"], *payload["com_m"], 0.0])
    x_mean[3] = p_mean[3] - x_mean[0] * (x_mean[1] ** 2 + x_mean[2] ** 2)  # Jc of the mean
    np.testing.assert_allclose(f, space.to_f(x_mean, paper_log), rtol=1e-12, atol=1e-12)
    assert _pooled(estimates[:1]) is estimates[0]


def test_a_refinement_weighs_each_estimate_by_its_information(paper_log, prior):
    """Step 3: with each window's covariance, the pooled payload vector is the best linear
    unbiased combination (inverse-covariance weights): a window whose centre of mass is
    poorly determined (standard error 0.3 m, as benchmark case 0029's outlier window)
    lends it almost no weight; equal covariances give the plain mean; the model is the
    pooled vector's (f affine in it)."""
    from ctc.adaptive import _pooled
    from identification.parameters import PayloadParameters
    from plant.robot.payload import payload_delta_matrix

    space = PayloadParameters(prior)
    a3 = paper_log.rig.a3_m
    X = np.array([[1.43, 0.007, -0.36, 0.01], [1.36, 0.012, -0.32, 0.01],
                  [1.36, -0.315, -0.43, 0.01]])
    P = PayloadParameters.linear(X)
    sd = [np.array([0.02, 0.02, 0.03, 0.002]), np.array([0.02, 0.02, 0.03, 0.002]),
          np.array([0.15, 0.32, 0.19, 0.02])]

    def estimate(x, c):
        payload = dict(space.extras(x, paper_log)["payload"], vector_cov=c)
        return space.to_f(x, paper_log), payload

    covs = [np.diag(v ** 2) for v in sd]
    f, payload = _pooled([estimate(x, c) for x, c in zip(X, covs)], a3=a3)
    W = [np.linalg.inv(c) for c in covs]
    expected = np.linalg.solve(sum(W), sum(w @ v for w, v in zip(W, P)))
    np.testing.assert_allclose(payload["vector"], expected, rtol=1e-9)
    # the pooled vector's covariance: the inverse of the summed information
    np.testing.assert_allclose(payload["vector_cov"], np.linalg.inv(sum(W)), rtol=1e-9)
    assert abs(payload["com_m"][0]) < 0.02 < abs(P[:, 1].mean() / P[:, 0].mean())
    np.testing.assert_allclose(f, prior + np.asarray(payload["vector"]) @ payload_delta_matrix(a3).T,
                               rtol=1e-12, atol=1e-12)
    same = [estimate(x, covs[0]) for x in X]
    np.testing.assert_allclose(_pooled(same, a3=a3)[1]["vector"], P.mean(axis=0), rtol=1e-9)
    # without covariances (or a3): the plain mean
    np.testing.assert_allclose(_pooled(same)[1]["vector"], P.mean(axis=0), rtol=1e-12)
    assert _pooled(same)[1]["vector_cov"] is None


#: A window's covariance of the linear payload vector [m, m xp, m yp, J] (standard errors
#: 0.05 kg, 0.01 kg m, 0.006 kg m, 0.004 kg m^2): the model's payload as one window knows it.
ONE_WINDOW_COV = np.diag(np.array([0.05, 0.01, 0.006, 0.004]) ** 2).tolist()


def test_the_quiet_refinement_holds_its_false_alarm_rate_and_finds_a_model_off(paper_log, prior):
    """Step 3's quiet refinement: the windows since the model took effect, pooled with the
    payload in use by their information, replace it when it lies outside the
    combination's confidence region at ``false_alarm``.  With the model and the windows
    drawn with their covariances around the truth, the model as informative as the
    windows, it installs in about ``false_alarm`` of the trials; a model 10 % heavy (its
    moments right) is replaced by the information-weighted combination; never on fewer
    than PERSISTENCE_WINDOWS windows, nor for a model without a covariance."""
    from plant.robot.payload import payload_delta_matrix

    rng = np.random.default_rng(20261127)
    A = payload_delta_matrix(paper_log.rig.a3_m)
    m, xp, yp, izz = 2.0, 0.10, 0.02, 0.01
    p_true = np.array([m, m * xp, m * yp, izz + m * (xp * xp + yp * yp)])
    C = np.asarray(ONE_WINDOW_COV)
    L = np.linalg.cholesky(C)

    def estimate(p, cov):
        return prior + A @ p, dict(mass_kg=float(p[0]), com_m=[float(p[1] / p[0]), float(p[2] / p[0])],
                                   izz_kgm2=float(p[3] - (p[1] ** 2 + p[2] ** 2) / p[0]),
                                   vector=[float(v) for v in p], vector_cov=cov.tolist())

    c = ctc.AdaptiveComputedTorqueController.from_log(prior, paper_log)
    n_windows = 5
    trials, installed = 1000, 0
    for _ in range(trials):
        # the model: as informative as the windows since it took effect
        c.f, c.payload = estimate(p_true + L @ rng.standard_normal(4) / np.sqrt(n_windows),
                                  C / n_windows)
        c._since = [estimate(p_true + L @ rng.standard_normal(4), C) for _ in range(n_windows)]
        refined, q = c._quiet_refinement()
        installed += refined is not None
    assert installed <= 5 * trials * c.false_alarm + 2, installed
    # a model 10 % heavy, its moments m xp, m yp and J right, worth four windows
    p0 = p_true * np.array([1.1, 1.0, 1.0, 1.0])
    c.f, c.payload = estimate(p0, C / 4)
    c._since = [estimate(p_true + L @ rng.standard_normal(4), C)
                for _ in range(ctc.adaptive.PERSISTENCE_WINDOWS - 1)]
    assert c._quiet_refinement() == (None, None)
    c._since += [estimate(p_true + L @ rng.standard_normal(4), C) for _ in range(12)]
    refined, q = c._quiet_refinement()
    assert q > c._lr_threshold and refined is not None
    # a model whose payload has no covariance: how much it knows is unknown, no refinement
    c.payload = dict(c.payload, vector_cov=None)
    assert c._quiet_refinement() == (None, None)
    f, payload = refined
    P = np.array([e[1]["vector"] for e in c._since])
    info = 4 * np.linalg.inv(C) + len(P) * np.linalg.inv(C)
    expected = np.linalg.solve(info, np.linalg.inv(C) @ (4 * p0 + P.sum(axis=0)))
    np.testing.assert_allclose(payload["vector"], expected, rtol=1e-9)
    assert payload["mass_kg"] == pytest.approx(m, rel=0.05)
    np.testing.assert_allclose(f, prior + A @ np.asarray(payload["vector"]), rtol=1e-12, atol=1e-12)


def _run_from_model(log, prior, model, f_robot, schedule=()):
    """The adaptive CTC's run of ``log`` with the payload ``model`` (a plant.Payload) in use
    from the start (its covariance ONE_WINDOW_COV), the robot ``f_robot`` changed by
    ``schedule``; every sample within +-1 pulse before the first change.  Returns the
    controller and the response."""
    m, (xp, yp), izz = model.mass_kg, model.com_m, model.izz_kgm2
    installed = (plant.add_payload(prior, model, log.rig.a3_m),
                 dict(mass_kg=m, com_m=[xp, yp], izz_kgm2=izz, vector_cov=ONE_WINDOW_COV,
                      vector=[m, m * xp, m * yp, izz + m * (xp * xp + yp * yp)]))

    class FromModel(ctc.AdaptiveComputedTorqueController):
        def reset(self):
            super().reset()
            self._pending = (0, installed[0], installed[1], "update")
            self._pending_trigger_mse = 1.0

    c = FromModel.from_log(prior, log, latency_s=LATENCY_S)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ctc.UnmodelledChangeWarning)
        resp = plant.simulate_closed_loop(log, f_robot, c, f_schedule=list(schedule),
                                          substeps=SUBSTEPS)
    assert resp.success
    k = int(np.ceil(schedule[0][0] / log.rig.sample_time_s)) if schedule else None
    assert np.abs(resp.e_pulses[:k]).max() <= 1
    assert c.payload_history[0] == (0.0, m), c.identifications
    return c, resp


def test_windows_the_model_describes_refine_a_payload_they_do_not_reject_one_by_one(
        paper_log, prior, monkeypatch):
    """A payload model 5 % heavy (2.1 kg for the 2 kg carried from t = 0) shows in no
    window as a change (each 'no change'); the windows since it took effect, pooled with
    it, reject it and their combination is installed (decision 'refinement') --
    switched off, the model stays 5 % heavy until a window's estimate makes an update,
    later."""
    true = plant.Payload(2.0, (0.10, 0.02), 0.01)
    heavy = plant.Payload(2.1, (0.10, 0.02), 0.01)
    f_loaded = plant.add_payload(prior, true, paper_log.rig.a3_m)
    c, _ = _run_from_model(paper_log, prior, heavy, f_loaded)
    t_fix, m_fix = c.payload_history[1]
    assert m_fix == pytest.approx(2.0, rel=0.01)
    first = next(r for r in c.identifications if r["accepted"])
    assert first["decision"] == "refinement" and first["quiet_wald"] > first["threshold"]
    assert first["mass_kg"] == pytest.approx(m_fix) and first["pooled"] >= 3
    assert all(r["decision"] in ("baseline", "no change") for r in c.identifications
               if r["window_s"][0] < first["window_s"][0])
    monkeypatch.setattr(ctc.AdaptiveComputedTorqueController, "_quiet_refinement",
                        lambda self: (None, None))
    off, _ = _run_from_model(paper_log, prior, heavy, f_loaded)
    assert len(off.payload_history) >= 2 and off.payload_history[1][0] > t_fix


def test_a_second_tool_of_a_similar_mass_is_found(paper_log, prior):
    """The 2 kg tool's right model in use, the tool exchanged at 2.0 s for one of 2.45 kg
    (within 25 % + 50 g of it: estimates of the new tool refine the payload in use).  The
    quiet refinement pools the windows since the model took effect, not the old tool's:
    the last mass within 5 % of 2.45 kg (pooled with the earlier windows, the new tool was
    outvoted: 2.20 kg at the end of the run).  A refinement pools only the estimates that
    are one payload with its window's (Wald's test; when it pooled every estimate of a
    mass within 25 % + 50 g, the first window of the new tool, 2.44 kg, and an estimate of
    the old one, 2.03 kg, combined to 1.60 kg, in use for 0.2 s, and one sample reached 2
    pulses 0.55 s after the exchange): after the exchange no model lighter than the old
    tool's; tracking within +-1 pulse from 0.5 s after the exchange."""
    a3 = paper_log.rig.a3_m
    old, new = plant.Payload(2.0, (0.10, 0.02), 0.01), plant.Payload(2.45, (0.10, 0.02), 0.01)
    schedule = [(2.0, plant.add_payload(prior, new, a3))]
    c, resp = _run_from_model(paper_log, prior, old, plant.add_payload(prior, old, a3), schedule)
    assert c.payload_history[-1][1] == pytest.approx(2.45, rel=0.05)
    ts = paper_log.rig.sample_time_s
    assert np.abs(resp.e_pulses[int(np.ceil(2.5 / ts)):]).max() <= 1
    assert min(m for t, m in c.payload_history if t >= 2.0) > 1.95, c.payload_history


def test_one_payload_test_holds_its_false_alarm_rate():
    """Supervisor step 3: two windows' estimates of one payload pass Wald's test at its
    stated false-alarm rate (estimates drawn with their covariances: rejected in about
    ``false_alarm`` of the pairs); estimates ten standard errors apart, or without a
    covariance, are not one payload."""
    from scipy.stats import chi2

    from ctc.adaptive import _N_PAYLOAD, _one_payload_test

    rng = np.random.default_rng(5)
    p = np.array([2.87, -0.33, -1.39, 0.72])
    A = rng.normal(size=(4, 4))
    Ca = 0.01 * (A @ A.T + 0.1 * np.eye(4))
    Cb = np.diag([0.1, 0.05, 0.02, 0.03]) ** 2

    def est(v, C):
        return dict(vector=v, vector_cov=C)

    n, alpha = 4000, 0.05
    La, Lb = np.linalg.cholesky(Ca), np.linalg.cholesky(Cb)
    q_alpha, q_strict = chi2.isf(alpha, _N_PAYLOAD), chi2.isf(1e-3, _N_PAYLOAD)
    rejected = sum(not _one_payload_test(est(p + La @ rng.normal(size=4), Ca),
                                         est(p + Lb @ rng.normal(size=4), Cb), q_alpha)
                   for _ in range(n))
    assert abs(rejected / n - alpha) < 4 * np.sqrt(alpha * (1 - alpha) / n)
    far = p + 10 * np.sqrt(np.diag(Ca + Cb)) * np.array([1, 0, 0, 0])
    assert not _one_payload_test(est(p, Ca), est(far, Cb), q_strict)
    assert _one_payload_test(est(p, Ca), est(p, Cb), q_strict)
    assert not _one_payload_test(est(p, None), est(p, Cb), q_strict)


def test_a_window_estimates_covariance_follows_the_linear_payload_vector():
    """The covariance a window's estimate carries into the pooling: the standard errors
    and correlations of x = [m, xp, yp, Jc] through the Jacobian of p = [m, m xp, m yp,
    J] (checked by central differences); None without standard errors."""
    from types import SimpleNamespace

    from ctc.adaptive import _vector_covariance
    from identification.parameters import PayloadParameters

    x = np.array([1.4, 0.05, -0.3, 0.01])
    std = np.array([0.02, 0.03, 0.05, 0.004])
    corr = np.array([[1.0, 0.3, -0.2, 0.0], [0.3, 1.0, 0.1, 0.0],
                     [-0.2, 0.1, 1.0, 0.5], [0.0, 0.0, 0.5, 1.0]])
    cov = _vector_covariance(SimpleNamespace(x=x, x_std=std, x_correlation=corr))
    h = 1e-6
    G = np.stack([(PayloadParameters.linear(x + h * e) - PayloadParameters.linear(x - h * e))
                  / (2 * h) for e in np.eye(4)], axis=1)
    np.testing.assert_allclose(cov, G @ (np.outer(std, std) * corr) @ G.T, rtol=1e-6, atol=1e-12)
    assert _vector_covariance(SimpleNamespace(x=x, x_std=None, x_correlation=None)) is None
    assert _vector_covariance(SimpleNamespace(x=x, x_std=std * np.nan, x_correlation=corr)) is None


def test_after_an_isolation_only_agreeing_estimates_update(paper_log, prior):
    """Step 5: once a change no payload explained was isolated, one window's evidence no
    longer updates; a real pick-up still does, after PERSISTENCE_WINDOWS agreeing estimates."""
    adaptive = ctc.AdaptiveComputedTorqueController.from_log(prior, paper_log)
    reset = adaptive.reset

    def isolated_reset():  # as after an inconsistent episode
        reset()
        adaptive._isolated = True

    adaptive.reset = isolated_reset
    loaded = plant.add_payload(prior, plant.Payload(2.0, (0.1, 0.02), 0.01), paper_log.rig.a3_m)
    with pytest.warns(ctc.UnmodelledChangeWarning):
        resp = plant.simulate_closed_loop(paper_log, prior, adaptive, f_schedule=[(1.0, loaded)],
                                          substeps=SUBSTEPS)
    assert resp.success
    records = adaptive.identifications
    first = next(i for i, r in enumerate(records) if r["accepted"])
    n = ctc.adaptive.PERSISTENCE_WINDOWS
    waited = records[first - (n - 1):first]
    # the update is the last of n agreeing estimates; the windows before it waited (one
    # window's evidence after an isolation, or -- the change was reported -- a payload a
    # rival change explains better: held until the payload explains the window better)
    assert records[first]["persistent"]
    assert all(r["decision"] in ("unexplained", "held") for r in waited)
    assert all(("agreeing" in r["reason"]) == (r["decision"] == "unexplained") for r in waited)
    assert adaptive.payload_mass_kg == pytest.approx(2.0, rel=0.05)


def test_supervisor_keeps_the_model_without_a_change(paper_log, prior):
    """Issue 21 item 1: windows without a change never move the mass (likelihood-ratio test)."""
    adaptive = ctc.AdaptiveComputedTorqueController.from_log(prior, paper_log)
    resp = plant.simulate_closed_loop(paper_log, prior, adaptive, substeps=SUBSTEPS)
    assert resp.success and len(adaptive.identifications) >= 5
    assert adaptive.payload_history == [] and adaptive.events == []
    decisions = [r["decision"] for r in adaptive.identifications]
    n = ctc.adaptive.CALIBRATION_WINDOWS
    assert decisions[:n] == ["baseline"] * n and set(decisions[n:]) == {"no change"}
    assert all(r["threshold"] > 18 for r in adaptive.identifications)  # chi2(4) at 1e-3
    assert adaptive.baseline is not None and adaptive.baseline < ctc.adaptive.QUANTISATION_VARIANCE
    # a rigid arm's start-state box is one for both hypotheses (step 1)
    assert all(r["fun_current"] == r["fun_current_own"] for r in adaptive.identifications)


def _spoil_start_state(adaptive, shift_rad=4e-4):
    """Move the model in use's start state on every window after the calibration windows by
    ``shift_rad`` per joint (a misread window, without a change of the robot)."""
    own = adaptive._start_state_of
    n = ctc.adaptive.CALIBRATION_WINDOWS

    def spoiled(window, law, substeps, guess, space):
        x0 = own(window, law, substeps, guess, space)
        if len(adaptive._calibration) >= n:
            x0 = np.array(x0, dtype=float)
            x0[:2] += shift_rad
        return x0

    adaptive._start_state_of = spoiled


def test_an_update_to_the_model_in_use_is_none(paper_log, prior):
    """Supervisor step 3: when a window's misfit is the model's own start state (its
    prediction-error start state worse in output error than the estimate's) and the
    empty gripper explains the window, the model in use -- the prior -- describes it:
    no 'update' to itself (on the changes benchmark such 0 kg updates came before 12 of
    96 changes, each costing a window).  The model's start state is spoiled here by
    0.4 mrad per joint after the calibration windows; later windows, whose estimates
    are not below the mass resolution, can still be misread (0.3-0.5 kg on this run):
    the likelihood ratio trusts the model's own start state (module docstring)."""
    adaptive = ctc.AdaptiveComputedTorqueController.from_log(prior, paper_log)
    n = ctc.adaptive.CALIBRATION_WINDOWS
    _spoil_start_state(adaptive)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ctc.UnmodelledChangeWarning)
        resp = plant.simulate_closed_loop(paper_log, prior, adaptive, substeps=SUBSTEPS)
    assert resp.success
    records = adaptive.identifications
    first = next((i for i, r in enumerate(records) if r["accepted"]), len(records))
    quiet = records[n:first]
    # the model's residual is spoiled (several times the estimate's), the empty gripper
    # explains the window, and the decision is the model's: no change
    assert sum(r["empty_gripper"] and r["fun_current"] > 4.0 * r["fun"] for r in quiet) >= 3
    assert all(r["decision"] == "no change" for r in quiet if r["empty_gripper"])
    # (a misread the arm tracks within +-1 pulse and a rival explains better is held)
    assert {r["decision"] for r in quiet} <= {"no change", "held"}
    assert all(m > 0.0 for _, m in adaptive.payload_history[:1])


def _friction_rival_ahead(window, law, space, substeps, opts, e_est):
    """In place of the fitted rivals: a friction change that explains every window slightly
    better than the payload (z = 1 / 2 per window, far below the threshold)."""
    return [dict(cause="friction", y=0.0, z=0.5, terms=[1.0, 4.0], x=[0.0] * 4,
                 change=dict(dB2=0.0, dB3=0.0, dTc2=0.0, dTc3=0.0))]


def test_a_calm_window_a_rival_explains_better_is_held(paper_log, prior):
    """Supervisor step 5: a window the arm tracks within +-1 pulse, whose payload estimate a
    rival change beats (Vuong's z of the run above zero, not significantly), does not
    switch the model on its own.  The windows of an unchanged robot are misread as
    payloads here by spoiling the model's start state (as in the test above); a friction
    rival that explains each window slightly better is put in place of the fitted ones."""
    adaptive = ctc.AdaptiveComputedTorqueController.from_log(prior, paper_log)
    _spoil_start_state(adaptive)
    adaptive._rival_hypotheses = _friction_rival_ahead
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ctc.UnmodelledChangeWarning)
        resp = plant.simulate_closed_loop(paper_log, prior, adaptive, substeps=SUBSTEPS)
    assert resp.success and np.abs(resp.e_pulses).max() <= 1
    held = [r for r in adaptive.identifications if r["decision"] == "held"]
    assert held and not any(r["accepted"] for r in held)
    assert all("waits for" in r["reason"] and r["rivals"][0]["z_run"] > 0 for r in held)
    # no misread became a model: the robot never changed
    assert adaptive.payload_history == []


def test_one_window_a_rival_explains_better_is_held_however_the_arm_tracks(paper_log, prior):
    """Supervisor step 5: an update that rests on one window, whose payload estimate a rival
    change explains better (Vuong's z of the run above zero, not significantly), waits for
    agreeing estimates when no payload is in use, even when the arm does not track within
    +-1 pulse (a gearbox that loses stiffness reads as a payload).  A 2 kg pick-up at 1.0 s with a
    friction rival put in place of the fitted ones, slightly ahead of every estimate: the
    windows after the pick-up are held, and PERSISTENCE_WINDOWS agreeing estimates then
    install the payload."""
    f_loaded = plant.add_payload(prior, plant.Payload(2.0, (0.10, 0.02), 0.01),
                                 paper_log.rig.a3_m)
    adaptive = ctc.AdaptiveComputedTorqueController.from_log(prior, paper_log,
                                                             latency_s=LATENCY_S)
    adaptive._rival_hypotheses = _friction_rival_ahead
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ctc.UnmodelledChangeWarning)
        resp = plant.simulate_closed_loop(paper_log, prior, adaptive, f_schedule=[(1.0, f_loaded)],
                                          substeps=SUBSTEPS)
    assert resp.success
    held = [r for r in adaptive.identifications if r["decision"] == "held"]
    # held windows the arm did not track within +-1 pulse (the rule before held only those
    # it did)
    ts = paper_log.rig.sample_time_s

    def peak(r):
        k0, k1 = (int(round(t / ts)) for t in r["window_s"])
        return np.abs(resp.e_pulses[k0 + 1:k1 - 1]).max()

    assert any(peak(r) > 1 for r in held), [
        (r["window_s"][0], r["decision"], peak(r)) for r in adaptive.identifications]
    assert all("waits for" in r["reason"] and not r["accepted"] for r in held)
    # no update on one window's evidence: the first rests on agreeing estimates
    first = next((r for r in adaptive.identifications if r["accepted"]), None)
    assert first is not None, "no update at all"
    assert first["persistent"] and first["window_s"][0] > held[0]["window_s"][0]
    assert adaptive.payload_mass_kg == pytest.approx(2.0, rel=0.05)


def test_a_model_that_stops_describing_the_robot_returns_to_the_prior(paper_log, prior):
    """Supervisor step 5, STALE_WINDOWS: a 2 kg tool picked up at 1.0 s is adapted to; at
    2.0 s the joint-2 gravity changes (f8, f9 x1.3: a counterbalance, no payload on link
    3 describes it).  Once the model in use -- an update's -- leaves STALE_WINDOWS
    successive windows undescribed with no payload explaining them, the controller
    returns to the prior (the static CTC's model), reports it, and tracks as the static
    CTC does."""
    loaded = plant.add_payload(prior, plant.Payload(2.0, (0.1, 0.02), 0.01), paper_log.rig.a3_m)
    changed = np.array(loaded)
    changed[7:9] *= 1.3
    static, adaptive, r = _static_and_adaptive(paper_log, prior, [(1.0, loaded), (2.0, changed)],
                                               warns="has not described the robot")
    assert r.success
    # the tool was found first
    assert any(abs(m - 2.0) < 0.1 and t < 2.0 for t, m in adaptive.payload_history)
    stale = [i for i, rec in enumerate(adaptive.identifications) if rec["decision"] == "stale"]
    assert stale and adaptive.identifications[stale[0]]["window_s"][0] > 2.0
    n = ctc.adaptive.STALE_WINDOWS
    before = adaptive.identifications[stale[0] - (n - 1):stale[0]]
    assert all(rec["decision"] in ("unexplained", "implausible", "friction", "drive")
               for rec in before)
    np.testing.assert_array_equal(adaptive.f, prior)
    assert adaptive.payload_history[-1][1] == 0.0
    k = int(np.ceil(2.5 / paper_log.rig.sample_time_s))
    assert np.all(np.abs(r.e_pulses[k:]).max(axis=0) <= np.abs(static.e_pulses[k:]).max(axis=0) + 1)


def test_a_change_no_payload_explains_is_reported_not_adapted(paper_log, prior):
    """A joint-2 gravity change (f8, f9: a counterbalance, not a payload on link 3).

    A payload on link 3 cannot change f8 or f9; with 0.2 s windows the
    successive estimates disagree and the supervisor reports the change
    (event + UnmodelledChangeWarning), goes back to the model it had before,
    and tracks as the static CTC does (within one pulse).  (With the default
    0.1 s windows the estimates scatter as much for a true payload, and such a
    change is followed as a drifting payload: documented in the tutorial.)
    """
    f_changed = np.array(prior, dtype=float)
    f_changed[7:9] *= 1.3
    schedule = [(1.0, f_changed)]
    static = plant.simulate_closed_loop(paper_log, prior,
                                        ctc.ComputedTorqueController.from_log(prior, paper_log),
                                        f_schedule=schedule, substeps=SUBSTEPS)
    adaptive = ctc.AdaptiveComputedTorqueController.from_log(prior, paper_log, window_s=0.2,
                                                             latency_s=0.2)
    with pytest.warns(ctc.UnmodelledChangeWarning, match="does not explain"):
        resp = plant.simulate_closed_loop(paper_log, prior, adaptive, f_schedule=schedule,
                                          substeps=SUBSTEPS)
    assert resp.success
    # the default (0.1 s windows) is never worse than the static CTC by more than a pulse
    default = ctc.AdaptiveComputedTorqueController.from_log(prior, paper_log)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ctc.UnmodelledChangeWarning)
        r_def = plant.simulate_closed_loop(paper_log, prior, default, f_schedule=schedule,
                                           substeps=SUBSTEPS)
    k1 = int(np.ceil(1.5 / paper_log.rig.sample_time_s))
    assert np.all(np.abs(r_def.e_pulses[k1:]).max(axis=0)
                  <= np.abs(static.e_pulses[k1:]).max(axis=0) + 1)
    kinds = [e["kind"] for e in adaptive.events]
    assert "unexplained" in kinds, adaptive.identifications
    # transient updates may happen while the windows look like payloads; once the
    # estimates disagree the controller is back at the model it had before the change
    assert adaptive.payload_history and adaptive.payload_history[-1][1] == 0.0
    np.testing.assert_array_equal(adaptive.f, prior)
    k = int(np.ceil(1.5 / paper_log.rig.sample_time_s))
    assert np.all(np.abs(resp.e_pulses[k:]).max(axis=0)
                  <= np.abs(static.e_pulses[k:]).max(axis=0) + 1)


@pytest.mark.parametrize("resume", [True, False])
def test_agreeing_estimates_that_describe_the_robot_end_an_inconsistent_pause(
        paper_log, prior, monkeypatch, resume):
    """Supervisor step 5: after an episode declared inconsistent (here forced on the first
    update of a 2 kg pick-up at 1.0 s, as when a window spanning a pick-up misreads it and
    the next estimate disagrees: benchmark case 0055 of seed 20261130), the controller is
    back at the prior and no window shows "no change" under it again -- the robot carries
    the tool.  PERSISTENCE_WINDOWS agreeing estimates, each explaining its window to the
    no-change level and none beaten by a rival change, end the pause: the tool is
    installed and the arm tracks within a pulse.  Without that rule (``resume`` False:
    ``_described_run`` always False) the controller stays on the prior for the rest of
    the run."""
    import ctc.adaptive as ad

    calls = []

    def first_update_inconsistent(masses):
        calls.append(list(masses))
        return len(calls) > 1

    monkeypatch.setattr(ad, "_one_payload", first_update_inconsistent)
    if not resume:
        monkeypatch.setattr(ad, "_described_run", lambda *a: False)
    a3 = paper_log.rig.a3_m
    f_loaded = plant.add_payload(prior, plant.Payload(2.0, (0.10, 0.02), 0.01), a3)
    adaptive = ctc.AdaptiveComputedTorqueController.from_log(prior, paper_log,
                                                             latency_s=LATENCY_S)
    with pytest.warns(ctc.UnmodelledChangeWarning, match="not a constant payload"):
        resp = plant.simulate_closed_loop(paper_log, prior, adaptive,
                                          f_schedule=[(1.0, f_loaded)], substeps=SUBSTEPS)
    assert resp.success
    decisions = [r["decision"] for r in adaptive.identifications]
    i = decisions.index("inconsistent")
    assert adaptive.identifications[i]["window_s"][0] >= 0.9
    later = adaptive.identifications[i + 1:]
    if not resume:
        assert not any(r["accepted"] for r in later)
        np.testing.assert_array_equal(adaptive.f, prior)
        return
    resumed = [r for r in later if r["accepted"]]
    assert resumed, decisions
    assert adaptive.payload_history[-1][1] == pytest.approx(2.0, rel=0.05)
    # the run that resumed: agreeing estimates that each explained their window
    assert all(r["rivals"] and all(h["z_run"] < 0 for h in r["rivals"]) for r in resumed[:1])
    k = int(np.ceil((resumed[0]["window_s"][1] + 2 * LATENCY_S) / paper_log.rig.sample_time_s))
    assert np.abs(resp.e_pulses[k:]).max() <= 1


@pytest.mark.parametrize("factor", [1.15, 0.85])
def test_a_friction_change_is_reported_not_adapted(paper_log, prior, factor):
    """The drive friction x1.15 / x0.85 at 1.0 s (supervisor step 3's rival hypothesis).

    A friction change of this size reads as a plausible 2-5 kg payload in
    single windows.  The friction change fitted beside the payload (dB, dTc
    per joint) explains successive windows significantly better (Vuong's
    test), so the change is named: an ``'unexplained'`` event with
    ``cause='friction'`` and a warning.  At x0.85 the first window's 4.9 kg
    estimate, which friction explains better (not significantly), is held
    (step 5: no payload is in use) -- before, it was installed, the next
    estimates disagreed (1.8, 1.9 kg) and the episode was isolated as
    inconsistent, the change never named.  The change is reported as not a
    payload, the controller ends on the prior, and it tracks as the static
    CTC does (within a pulse).
    """
    from plant.simulation.friction import friction_vector

    static, adaptive, resp = _static_and_adaptive(
        paper_log, prior, [(1.0, prior, factor * friction_vector(paper_log.rig))],
        warns="does not explain")
    assert resp.success and static.success
    causes = [e.get("cause") for e in adaptive.events if e["kind"] == "unexplained"]
    assert "friction" in causes, adaptive.identifications
    assert adaptive.payload_history == []
    fr = [r["friction"] for r in adaptive.identifications if r["decision"] == "friction"]
    # the fitted change has the friction's sign and beat the payload at the test's level
    assert any(np.sign(r["change"]["dTc2_Nm"]) == np.sign(factor - 1.0) for r in fr)
    assert all(r["z_run"] > 3.0 for r in fr)
    np.testing.assert_array_equal(adaptive.f, prior)
    k = int(np.ceil(1.5 / paper_log.rig.sample_time_s))
    assert np.all(np.abs(resp.e_pulses[k:]).max(axis=0)
                  <= np.abs(static.e_pulses[k:]).max(axis=0) + 1)


def test_after_a_reported_change_a_payload_must_beat_the_rival(paper_log, prior):
    """Supervisor step 5: once the episode's change has been reported as one no payload
    explains, a payload estimate that a rival change explains better (Vuong's ``z`` of
    the run above zero, if not significantly) is held, agreeing estimates or not, and an
    estimate at the search bound is no evidence of a payload.  The drive friction x1.3
    at 1.0 s: its windows read as 5 kg at the mass bound, then as 3-5 kg payloads that
    friction explains better; before these rules the at-bound windows and one 4.97 kg
    estimate made a 'persistent' update, which went stale 0.3 s later."""
    from plant.simulation.friction import friction_vector

    static, adaptive, resp = _static_and_adaptive(
        paper_log, prior, [(1.0, prior, 1.3 * friction_vector(paper_log.rig))],
        warns="does not explain")
    assert resp.success
    first = min(e["t_s"] for e in adaptive.events if e["kind"] == "unexplained")
    after = [r for r in adaptive.identifications if r["window_s"][0] >= first]
    assert "no change" not in {r["decision"] for r in after}  # the change stays reported
    held = [r for r in after if r["decision"] == "held"]
    assert held and all("reported in this episode" in r["reason"] for r in held)
    assert all(max(h["z_run"] for h in r["rivals"]) > 0.0 for r in held)
    # no estimate a rival explains better reached the arm, and none did at all
    assert not any(r["accepted"] and any(h["z_run"] > 0.0 for h in r["rivals"] or ())
                   for r in after)
    assert adaptive.payload_history == []
    np.testing.assert_array_equal(adaptive.f, prior)
    k = int(np.ceil(1.5 / paper_log.rig.sample_time_s))
    assert np.all(np.abs(resp.e_pulses[k:]).max(axis=0)
                  <= np.abs(static.e_pulses[k:]).max(axis=0) + 1)


def test_an_update_that_tracks_worse_is_rolled_back(paper_log, prior):
    """Probation (supervisor step 4): a wrong model put in by an update is replaced by the last good one."""
    a3 = paper_log.rig.a3_m
    wrong = plant.add_payload(prior, plant.Payload(4.5, (0.4, 0.3), 0.04), a3)
    k_eff = int(round(0.4 / paper_log.rig.sample_time_s))

    class Misled(ctc.AdaptiveComputedTorqueController):
        def reset(self):
            super().reset()
            # as if the window ending at 0.4 s had been read as a 4.5 kg payload
            # while the arm tracked perfectly
            self._pending = (k_eff, wrong, {"mass_kg": 4.5}, "update")
            self._pending_trigger_mse = 0.0

    adaptive = Misled(prior, paper_log)
    run = plant.simulate_closed_loop(paper_log, prior, adaptive, substeps=SUBSTEPS,
                                     n_samples=int(1.2 / paper_log.rig.sample_time_s))
    assert run.success
    rollbacks = [e for e in adaptive.events if e["kind"] == "rollback"]
    assert rollbacks and rollbacks[0]["mse_after"] > 1.0
    assert adaptive.payload_mass_kg == 0.0 and adaptive.payload_history[-1][1] == 0.0
    np.testing.assert_array_equal(adaptive.f, prior)


def test_vuong_statistic():
    """Vuong's z: 0 for models alike, antisymmetric, positive when b fits better, grows with n."""
    from ctc.adaptive import vuong_statistic

    rng = np.random.default_rng(3)
    e_log = rng.integers(-3, 4, size=(200, 2))
    e_a = e_log + rng.integers(-1, 2, size=(200, 2))
    assert vuong_statistic(e_log, e_a, e_a) == 0.0
    e_b = e_log.copy()
    e_b[::4] += 1  # b misses a quarter of the samples by one pulse, a misses two thirds
    z = vuong_statistic(e_log, e_a, e_b)
    assert z > 0
    assert vuong_statistic(e_log, e_b, e_a) == pytest.approx(-z)
    # the same evidence twice as long is sqrt(2) times as strong (tau permitting)
    z2 = vuong_statistic(np.vstack([e_log, e_log]), np.vstack([e_a, e_a]), np.vstack([e_b, e_b]))
    assert z2 > z
    assert vuong_statistic(e_log, e_log + 1, e_log) == np.inf


def test_window_statistics():
    rng = np.random.default_rng(0)
    e_log = rng.integers(-3, 4, size=(200, 2))
    s = ctc.adaptive.window_statistics(e_log, e_log, e_log)
    assert s["lr"] == 0.0 and s["y_now"] == 0.0 and s["tau"] == 1.0
    s = ctc.adaptive.window_statistics(e_log, np.zeros_like(e_log), e_log)
    assert s["y_now"] == float(np.sum(e_log ** 2)) and s["lr"] > 100
    assert s["variance"] == ctc.adaptive.QUANTISATION_VARIANCE


def test_probation_judges_the_update_after_its_switching_transient(paper_log, prior):
    """Supervisor step 4: the first window under an update is judged on its second half.

    A model switch starts a transient that decays within the loop's time
    constants (a flexible arm's error still building from the pick-up the
    update answers); an update that is wrong keeps the error up.
    """
    adaptive = ctc.AdaptiveComputedTorqueController.from_log(prior, paper_log)
    n = adaptive._n_window
    state = adaptive._ctc.estimator_state()

    def window(first, second):
        return [(k, e, -e, 0.0, 0.0, state, adaptive.f)
                for k, e in enumerate([first] * (n // 2) + [second] * (n - n // 2))]

    adaptive._probation = (adaptive.f, 1.0)
    assert adaptive._supervise_tracking(window(6, 0), n - 1) is False  # transient, decayed
    assert adaptive.events == []
    adaptive._probation = (adaptive.f, 1.0)
    assert adaptive._supervise_tracking(window(0, 6), n - 1) is True   # the update tracks worse
    assert [e["kind"] for e in adaptive.events] == ["rollback"]
    assert adaptive.events[0]["mse_after"] == 36.0
    # single windows misled: until a window shows no change, only persistent estimates update
    assert adaptive._frozen == "rolled back"


def test_a_worker_as_fast_as_the_window_identifies_every_window(paper_log, prior):
    """The window is at least ``window_s`` long, so a latency of one window keeps up
    with every window (a window rounded down to whole samples made the worker finish
    a sample late and skip every other one)."""
    ts = paper_log.rig.sample_time_s
    window_s = 143.3 * ts  # rounds down to 143 samples, up to 144
    adaptive = ctc.AdaptiveComputedTorqueController.from_log(prior, paper_log, window_s=window_s,
                                                             latency_s=window_s)
    assert adaptive._n_window * ts >= window_s
    n_samples = int(1.2 / ts)
    resp = plant.simulate_closed_loop(paper_log, prior, adaptive, substeps=SUBSTEPS,
                                      n_samples=n_samples)
    assert resp.success
    assert len(adaptive.identifications) == n_samples // adaptive._n_window


def test_tracking_that_diverges_under_the_last_good_model_returns_to_the_prior(paper_log, prior):
    """Supervisor step 4: a window can call a wrong model good; when tracking then diverges
    under it, the controller returns to the prior (the static CTC's model), not to it."""
    adaptive = ctc.AdaptiveComputedTorqueController.from_log(prior, paper_log)
    wrong = plant.add_payload(prior, plant.Payload(3.0, (0.1, 0.0), 0.01), paper_log.rig.a3_m)
    adaptive._install(wrong)
    adaptive.payload = {"mass_kg": 3.0}
    adaptive._good = (adaptive.f, adaptive.payload)  # as if a window had found no change
    adaptive._mse_normal = 0.5
    n = adaptive._n_window
    state = adaptive._ctc.estimator_state()

    def window(e):
        return [(k, e, -e, 0.0, 0.0, state, adaptive.f) for k in range(n)]

    assert adaptive._supervise_tracking(window(5), n - 1) is False  # one whole window: no trend
    assert adaptive._supervise_tracking(window(8), 2 * n - 1) is True  # growing, 64 > 16 x 1
    assert [e["kind"] for e in adaptive.events] == ["rollback"]
    assert "the prior" in adaptive.events[0]["message"]
    k, f_back, payload_back, kind = adaptive._pending
    np.testing.assert_array_equal(f_back, prior)
    assert payload_back is None and kind == "rollback" and adaptive._frozen == "diverging"


def test_growing_tracking_error_under_the_prior_is_left_to_the_guard(paper_log, prior):
    """The prior is the static CTC: nothing to return to (the following-error limit,
    :mod:`ctc.guard`, is the last resort there)."""
    adaptive = ctc.AdaptiveComputedTorqueController.from_log(prior, paper_log)
    adaptive._mse_normal = 0.5
    n = adaptive._n_window
    state = adaptive._ctc.estimator_state()
    rows = [[(k, e, -e, 0.0, 0.0, state, adaptive.f) for k in range(n)] for e in (5, 8)]
    assert adaptive._supervise_tracking(rows[0], n - 1) is False
    assert adaptive._supervise_tracking(rows[1], 2 * n - 1) is False
    assert adaptive.events == [] and adaptive._pending is None


def test_the_window_link_box_holds_any_payload_deflection(drill_log):
    """A payload changes the spring deflection at a flexible window's start by its torque
    over the stiffness: the candidates' link box is widened by twice the interval bound of
    that torque, the model's own (the controller's link estimate) is not."""
    from identification.flexible import FlexiblePayloadParameters
    from identification.parameters import DEFAULT_PAYLOAD_BOUNDS, PayloadParameters
    from plant.robot.model import regressor
    from plant.robot.payload import payload_delta_matrix

    import dataclasses

    k = slice(1000, 1150)
    window = drill_log.replace(
        t=drill_log.t[k], q_ref=drill_log.q_ref[k], e_pulses=drill_log.e_pulses[k],
        i_A=drill_log.i_A[k], start_index=1000,
        window_s=(float(drill_log.t[1000]), float(drill_log.t[1150])),
        rig=dataclasses.replace(drill_log.rig, q0_rad=None, qd0_rad_per_s=None))
    joints = np.array([2.0e4, 1.5e4, 2.0, 1.0, 0.5, 0.3])
    space = FlexiblePayloadParameters(np.zeros(9), joints)
    g, box = space.initial_state(window)
    g0, box0 = space.model_initial_state(window)
    np.testing.assert_array_equal(g, g0)
    np.testing.assert_array_equal(box[4:], box0[4:])  # the motor's: the same
    bound = space.payload_torque_bound(window, g[4:])
    grown = (box[:2, 1] - box[:2, 0]) - (box0[:2, 1] - box0[:2, 0])
    np.testing.assert_allclose(grown, 2 * 2 * bound / joints[:2])
    np.testing.assert_array_equal(box[2:4], box0[2:4])  # velocities not widened
    # the bound holds every payload in the box, and is not loose by more than 2
    rng = np.random.default_rng(1)
    lo, hi = DEFAULT_PAYLOAD_BOUNDS.T
    x = lo + (hi - lo) * rng.random((4000, 4))
    x[:8, :3] = [[hi[0], s1 * hi[1], s2 * hi[2]] for s1 in (-1, 1) for s2 in (-1, 1)] * 2
    _, _, qdd = window.trajectory.evaluate(window.t[:1])
    Y = regressor(g[4:6], g[6:8], qdd[0], window.rig.gravity_m_s2) @ payload_delta_matrix(
        window.rig.a3_m)
    tau = np.abs(PayloadParameters.linear(x) @ Y.T).max(axis=0)
    assert np.all(tau <= bound * (1 + 1e-12)) and np.all(tau >= 0.5 * bound), (tau, bound)


def test_a_window_admits_the_payload_it_carries_and_rejects_another(paper_log, prior):
    """Supervisor step 3, the pooled update's own check: a window of a run with a 2 kg
    tool admits the loaded model beside an estimate that simulates it (likelihood ratio
    within the threshold) and rejects the same tool 1.5 kg heavier."""
    a3 = paper_log.rig.a3_m
    loaded = plant.add_payload(prior, plant.Payload(2.0, (0.1, 0.02), 0.01), a3)
    heavier = plant.add_payload(prior, plant.Payload(3.5, (0.1, 0.02), 0.01), a3)
    adaptive = ctc.AdaptiveComputedTorqueController.from_log(prior, paper_log)
    windows = []
    identify = adaptive._identify

    def capture(rows, k_end):
        windows.append(list(rows))
        identify(rows, k_end)

    adaptive._identify = capture
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ctc.UnmodelledChangeWarning)
        resp = plant.simulate_closed_loop(paper_log, prior, adaptive, f_schedule=[(1.0, loaded)],
                                          substeps=SUBSTEPS)
    assert resp.success
    rows = next(r for r in windows if r[0][0] * paper_log.rig.sample_time_s > 1.5)
    window = adaptive.window_log(rows)
    law = adaptive._ctc.logged_law_with(window, rows[0][5], rows[0][6])
    space = adaptive._space(rows[0][5])
    trend, _ = space.model_initial_state(window)
    x0 = adaptive._refined_start(loaded, window, law, SUBSTEPS, trend, space)
    F = np.asarray(loaded, dtype=float)[None]
    e_own = plant.simulate_batch(window, F, substeps=SUBSTEPS, errors=True, workers=1,
                                 initial_state=x0[None], controller=law,
                                 plant=space.plant(window),
                                 plant_parameters=space.plant_parameters(F, window)).e_pulses[0]
    assert adaptive._window_admits(window, law, space, SUBSTEPS, x0, loaded, e_own)
    assert not adaptive._window_admits(window, law, space, SUBSTEPS, x0, heavier, e_own)
