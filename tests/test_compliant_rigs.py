"""Compliant rigs (issue 20): backlash, the drive's current limit, the model judge."""
from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import plant
from ctc import PController
from identification.flexible import INADEQUATE_FACTOR, FlexibleParameters, _judge
from plant.simulation.plants import dead_zone


def test_dead_zone_of_zero_width_is_the_identity_bit_for_bit():
    rng = np.random.default_rng(0)
    for d in np.r_[rng.normal(0, 1e-3, 50), 0.0, -0.0, 1e-300]:
        assert dead_zone(d, 0.0) == d
    assert dead_zone(0.004, 0.002) == pytest.approx(0.003)
    assert dead_zone(-0.004, 0.002) == pytest.approx(-0.003)
    assert dead_zone(0.0009, 0.002) == 0.0


def test_backlash_is_validated_and_changes_the_flexible_plant():
    with pytest.raises(ValueError, match="backlash"):
        plant.FlexibleJoints(3e4, 1.0, 2e-4, backlash_rad=-1e-3)
    base = plant.load_example()
    f = np.array([1.2, 0.6, 0.0, -0.5, 0.0, -1.2, 4.8, -0.1, 3.8])
    flex0 = plant.FlexibleJoints((3e4, 1e4), (3.0, 1.0), 2e-4)
    flex2 = plant.FlexibleJoints((3e4, 1e4), (3.0, 1.0), 2e-4, backlash_rad=(2e-3, 0.0))
    e0 = plant.emulate_log(base, f, flexible=flex0, duration_s=0.6).e_pulses
    e2 = plant.emulate_log(base, f, flexible=flex2, duration_s=0.6).e_pulses
    assert not np.array_equal(e0[:, 0], e2[:, 0])
    # lane parameters: the backlash rows, and the rig's friction on the motor side
    P = flex2.lane_parameters(f[None], base.rig)
    assert P.shape == (23, 1) and P[21, 0] == 2e-3 and P[22, 0] == 0.0


def test_the_logged_run_saturates_at_the_drive_full_scale(paper_log, truth):
    """The compiled P experiment and the Python-controller loop (which clips) agree
    pulse for pulse on a rig whose full scale (80 % of the log's peak current) the
    paper trajectory exceeds."""
    f = np.asarray(truth("puma560_paper_rigid")["f_vector"])
    i_fs = 0.8 * float(np.max(np.abs(paper_log.i_A)))
    small = paper_log.replace(rig=dataclasses.replace(paper_log.rig, current_full_scale_A=i_fs))
    e_core = plant.simulate_experiment(small, f, substeps=8)
    r = plant.simulate_closed_loop(small, f, PController.from_log(small), substeps=8)
    assert r.n_clipped > 10
    n = min(len(e_core), len(r.e_pulses))
    assert np.array_equal(e_core[:n], r.e_pulses[:n])
    # without the limit the run differs
    assert not np.array_equal(plant.simulate_experiment(paper_log, f, substeps=8)[:n], e_core[:n])


def test_an_inadequate_model_is_flagged_and_its_f_std_covers_the_other_model():
    res = {"f": np.ones(9), "f_std": np.full(9, 1e-3)}
    other = {"f": np.full(9, 1.1)}
    choice = dict(model="flexible", held_back_cost_flexible_pulses2=10 * INADEQUATE_FACTOR * 100.0,
                  floor_pulses2=100.0, reason="r")
    out = _judge(res, None, choice, alternative=other)
    assert out["model_choice"]["adequate"] is False
    assert "does not describe the log" in out["warnings"][0]
    assert np.allclose(out["f_std"], np.hypot(1e-3, 0.1))
    ok = _judge({"f": np.ones(9), "f_std": np.full(9, 1e-3)}, None,
                dict(choice, held_back_cost_flexible_pulses2=150.0), alternative=other)
    assert ok["model_choice"]["adequate"] is True and not ok.get("warnings")
    assert np.allclose(ok["f_std"], 1e-3)


def test_flexible_parameters_with_unknown_friction_and_backlash():
    log = plant.load_example()
    rig = dataclasses.replace(log.rig, viscous_friction_Nms_per_rad=None, coulomb_friction_Nm=None)
    unk = log.replace(rig=rig)
    space = FlexibleParameters(backlash=True)
    names = space.names(unk)
    assert names[15:17] == ["b2_rad", "b3_rad"] and len(names) == 23
    xb = space.bounds(unk)
    assert xb.shape == (23, 2) and np.all(xb[:, 0] < xb[:, 1])
    x = xb.mean(axis=1)
    pp = space.plant_parameters(x[None], unk)
    assert pp["friction"].shape == (1, 6) and np.allclose(pp["friction"][0], x[17:])
    assert np.allclose(pp["backlash"][0], x[15:17])
    ex = space.extras(x, unk)
    assert ex["friction_identified"] and ex["joint_backlash_rad"] == list(x[15:17])
    # known friction: no friction components, the rig's in the lanes
    assert len(FlexibleParameters(backlash=False).names(log)) == 15


@pytest.mark.parametrize("flexible", [False, True])
def test_controllers_saturate_at_the_full_scale_with_anti_windup(paper_log, truth, flexible):
    """Issue 21 item 4: no commanded current beyond the full scale; the observer
    predicts with the saturated acceleration, so tracking recovers after the limit."""
    import ctc

    f = np.asarray(truth("puma560_paper_rigid")["f_vector"])
    i_fs = 3.0
    rig = dataclasses.replace(paper_log.rig, current_full_scale_A=i_fs)
    log = paper_log.replace(rig=rig)
    if flexible:
        flex = plant.FlexibleJoints((3e4, 1e4), (3.0, 1.0), 2e-4)
        c = ctc.FlexibleJointComputedTorqueController.from_log(
            f, log, stiffness_Nm_per_rad=flex.stiffness_Nm_per_rad,
            damping_Nms_per_rad=flex.damping_Nms_per_rad,
            motor_inertia_reflected_kgm2=flex.reflected_inertia(rig))
    else:
        flex = None
        c = ctc.ComputedTorqueController.from_log(f, log)
    raw = []

    class Spy:
        def reset(self):
            c.reset()

        def __call__(self, k, t, q, e):
            i = c(k, t, q, e)
            raw.append(np.array(i))
            return i

    r = plant.simulate_closed_loop(log, f, Spy(), flexible=flex, substeps=8)
    raw = np.abs(np.array(raw))
    assert raw.max() <= i_fs
    assert r.n_clipped > 0 and np.abs(r.i_A).max() <= i_fs
