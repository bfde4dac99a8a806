"""Unknown drive friction: the sidecar's null friction, the per-lane friction plant,
and its identification with f (issue 13, item 4)."""
from __future__ import annotations

import json

import numpy as np
import pytest

import plant
from identification import identify
from identification.friction import (FrictionParameters, default_friction_bounds,
                                     unknown_friction_indices)
from identification.result import IdentificationResult
from plant.simulation.friction import RIGID_FRICTION, friction_vector, joint_side_friction

WELL_EXCITED = np.array([1, 2, 4, 6, 7, 9]) - 1


def _unknown(keys):
    def edit(d):
        for key in keys:
            if key == "coulomb_friction_Nm":
                d.pop(key)  # absent
            else:
                d[key] = None  # null
    return edit


def test_null_or_absent_friction_loads_as_unknown(tmp_log):
    log = plant.load_log(tmp_log(json_edit=_unknown(["viscous_friction_Nms_per_rad",
                                                     "coulomb_friction_Nm"])))
    assert log.rig.viscous_friction_Nms_per_rad is None
    assert log.rig.coulomb_friction_Nm is None
    assert log.rig.unknown_friction == ("viscous_friction_Nms_per_rad", "coulomb_friction_Nm")
    c = plant.rig_constants(log.rig)
    assert c.viscous == (0.0, 0.0) and c.coulomb_pos == (0.0, 0.0) and c.coulomb_neg == (0.0, 0.0)
    # the ramp speed still comes from the note of the development sidecar
    assert log.rig.coulomb_ramp_speed_rad_per_s == 0.5
    assert unknown_friction_indices(log.rig) == [0, 1, 2, 3, 4, 5]


def test_unknown_friction_round_trips_as_null(tmp_log, tmp_path):
    log = plant.load_log(tmp_log(json_edit=_unknown(["coulomb_friction_Nm"])))
    assert log.rig.unknown_friction == ("coulomb_friction_Nm",)
    out = log.save(tmp_path / "copy")
    side = json.loads(out.with_suffix(".json").read_text())
    assert side["coulomb_friction_Nm"] is None
    assert plant.load_log(out).rig == log.rig


def test_unknown_coulomb_without_ramp_speed_uses_the_default(tmp_log):
    def edit(d):
        d["coulomb_friction_Nm"] = None
        d.pop("coulomb_friction_note", None)
        d.pop("coulomb_ramp_speed_rad_per_s", None)
    from plant.logs.sidecar import DEFAULT_UNKNOWN_RAMP_SPEED

    log = plant.load_log(tmp_log(json_edit=edit))
    assert log.rig.coulomb_ramp_speed_rad_per_s == DEFAULT_UNKNOWN_RAMP_SPEED


def test_malformed_coulomb_still_refused(tmp_log):
    with pytest.raises(plant.LogError, match="coulomb_friction_Nm"):
        plant.load_log(tmp_log(json_edit=lambda d: d.update(coulomb_friction_Nm=[1.0, 2.0])))


def test_friction_plant_with_the_rigs_friction_is_the_rigid_plant(paper_log, truth):
    """Same arithmetic: bit-identical errors to the rigid plant; friction changes them."""
    f = np.asarray(truth("puma560_paper_rigid")["f_vector"])
    F = f * (1 + 0.01 * np.random.default_rng(3).standard_normal((5, 9)))
    a = plant.simulate_batch(paper_log, F, substeps=1)
    b = plant.simulate_batch(paper_log, F, substeps=1, plant=RIGID_FRICTION)
    assert np.array_equal(a.e_pulses, b.e_pulses)
    v = friction_vector(paper_log.rig)
    c = plant.simulate_batch(paper_log, F, substeps=1, plant=RIGID_FRICTION,
                             plant_parameters={"friction": np.tile(v * 1.2, (5, 1))})
    assert not np.array_equal(a.e_pulses, c.e_pulses)
    eps, st = plant.prediction_errors(paper_log, F[:2], substeps=1, plant=RIGID_FRICTION,
                                      plant_parameters={"friction": np.tile(v, (2, 1))})
    eps0, _ = plant.prediction_errors(paper_log, F[:2], substeps=1)
    assert np.all(st == 0) and np.array_equal(eps, eps0)


def test_joint_side_friction_rows(paper_log):
    v = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
    rows = joint_side_friction(v, paper_log.rig)[:, 0]
    c = plant.rig_constants(paper_log.rig.__class__(**{
        **paper_log.rig.__dict__, "viscous_friction_Nms_per_rad": (1.0, 2.0),
        "coulomb_friction_Nm": ((3.0, 4.0), (5.0, 6.0))}))
    assert np.allclose(rows, np.r_[c.viscous, c.coulomb_pos, c.coulomb_neg])
    with pytest.raises(ValueError, match="friction"):
        joint_side_friction(np.ones(5), paper_log.rig)


def test_friction_parameters_map_and_box(tmp_log, truth):
    log = plant.load_log(tmp_log(json_edit=_unknown(["viscous_friction_Nms_per_rad"])))
    space = FrictionParameters()
    assert space.names(log)[9:] == ["B2_Nms_per_rad", "B3_Nms_per_rad"]
    b = space.bounds(log)
    assert b.shape == (11, 2) and np.all(b[9:, 0] == 0)
    # the box holds the true friction (it is physically implied by the log)
    full = default_friction_bounds(log)
    true_v = np.array([0.006817, 0.00738, 0.071, 0.126, 0.105, 0.132])
    assert np.all(true_v < full[:, 1])
    x = np.r_[truth("puma560_paper_rigid")["f_vector"], 0.01, 0.02]
    assert np.array_equal(space.to_f(x, log), x[:9])
    V = space.friction(x, log)
    assert np.allclose(V, [0.01, 0.02, 0.071, 0.126, 0.105, 0.132])
    assert space.plant(log) is RIGID_FRICTION


def test_rigid_result_echoes_the_sidecar_friction():
    log = plant.load_example()
    r = identify(log, rng=0, progress=False, ga_options={"n_gen": 2, "n_ind": 6},
                 refine_options={"n_starts": 1, "max_iter": 2})
    d = r.to_dict()
    assert d["friction_identified"] is False and d["model"] == "rigid"
    assert np.allclose(d["viscous_friction_Nms_per_rad"], log.rig.viscous_friction_Nms_per_rad)
    assert np.allclose(d["coulomb_friction_Nm"], log.rig.coulomb_friction_Nm)
    for key in ("joint_stiffness_Nm_per_rad", "joint_damping_Nms_per_rad",
                "motor_inertia_reflected_kgm2"):
        assert key in d and d[key] is None


@pytest.mark.slow
def test_friction_identified_with_f_when_the_sidecar_lacks_it(tmp_log, tmp_path, truth):
    """Acceptance: friction removed from a development sidecar; f within 2 %, friction 10 %."""
    src = plant.load_log(tmp_log())
    true_v = friction_vector(src.rig)
    log = plant.load_log(tmp_log(json_edit=_unknown(["viscous_friction_Nms_per_rad",
                                                     "coulomb_friction_Nm"])))
    r = identify(log, rng=1, progress=False)
    f_true = np.asarray(truth("puma560_paper_rigid")["f_vector"])
    rel = np.abs(r.f - f_true) / np.abs(f_true)
    assert np.all(rel[WELL_EXCITED] < 0.02), rel
    assert r.friction_identified is True and r.parameters == "base+friction"
    v = np.r_[np.ravel(r.viscous_friction_Nms_per_rad), np.ravel(r.coulomb_friction_Nm)]
    assert np.all(np.abs(v - true_v) < 0.10 * true_v), (v, true_v)
    path = r.save_json(tmp_path / "r.json").target
    d = json.loads(path.read_text())
    assert d["friction_identified"] is True and np.shape(d["coulomb_friction_Nm"]) == (2, 2)
    back = IdentificationResult.load_json(path)
    assert np.allclose(back["viscous_friction_Nms_per_rad"], v[:2])



def test_a_scheduled_friction_change_and_its_parameterisation(paper_log, truth):
    """``f_schedule``'s third element changes the drive friction mid-run; the rival
    hypothesis of the adaptive CTC (:class:`FrictionChangeParameters`) holds f and
    moves the friction within non-negative totals.
    """
    import ctc
    from identification.friction import FrictionChangeParameters
    from identification.parameters import PayloadParameters

    f = np.asarray(truth("puma560_paper_rigid")["f_vector"], dtype=float)
    v = friction_vector(paper_log.rig)
    law = ctc.ComputedTorqueController.from_log(f, paper_log)
    base = plant.simulate_closed_loop(paper_log, f, law, substeps=4)
    # the rig's own friction scheduled: the same run bit for bit (RIGID_FRICTION == RIGID)
    same = plant.simulate_closed_loop(paper_log, f, law, substeps=4, f_schedule=[(0.5, f, v)])
    np.testing.assert_array_equal(base.e_pulses, same.e_pulses)
    warm = plant.simulate_closed_loop(paper_log, f, law, substeps=4,
                                      f_schedule=[(0.5, f, 1.5 * v), (1.0, f)])
    k = int(np.ceil(1.2 / paper_log.rig.sample_time_s))
    # the change persists through a later f-only entry and shows in the tracking
    assert np.abs(warm.e_pulses[k:]).max() > np.abs(base.e_pulses[k:]).max() + 1
    with pytest.raises(ValueError, match="6 finite"):
        plant.simulate_closed_loop(paper_log, f, law, f_schedule=[(0.5, f, -v)])
    space = FrictionChangeParameters(PayloadParameters(f), f)
    b = space.bounds(paper_log)
    assert b.shape == (4, 2) and np.all(b[:, 0] <= 0) and np.all(b[:, 1] >= 0)
    np.testing.assert_array_equal(space.friction(np.zeros(4), paper_log), v)
    np.testing.assert_array_equal(space.to_f(np.zeros((3, 4)), paper_log), np.tile(f, (3, 1)))
    assert np.all(space.friction(b[:, 0], paper_log) >= 0)
    assert space.plant(paper_log) is RIGID_FRICTION
    pp = space.plant_parameters(np.zeros((2, 4)), paper_log)
    np.testing.assert_array_equal(pp["friction"], np.tile(v, (2, 1)))
    with pytest.raises(ValueError, match="9 finite"):
        FrictionChangeParameters(PayloadParameters(f), f[:8])
