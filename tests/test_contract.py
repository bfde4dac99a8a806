"""The result -> controller contract (ctc.contract.IdentifiedModel): one reader of results."""
from __future__ import annotations

import json

import numpy as np
import pytest

import ctc
from ctc.contract import IdentifiedModel

F = [1.3, 0.75, 0.02, -0.7, 0.05, -1.6, 5.0, -0.1, 4.4]
FLEX = dict(f=F, model="flexible", joint_stiffness_Nm_per_rad=[3e4, 6e3],
            joint_damping_Nms_per_rad=[4.0, 0.4], motor_inertia_reflected_kgm2=[2.3, 0.58])


def test_rigid_result_dict_and_file(tmp_path):
    m = IdentifiedModel.from_result(dict(f=F))
    assert m.model == "rigid" and not m.flexible and not m.friction_identified
    np.testing.assert_array_equal(m.f, F)
    assert m.joints() == {} and m.adequate is None
    assert IdentifiedModel.from_result(m) is m
    path = tmp_path / "missing.json"
    with pytest.raises(ValueError, match="not found"):
        IdentifiedModel.from_result(path)
    with pytest.raises(ValueError, match="prior must be"):
        IdentifiedModel.from_result(42, what="prior")


def test_flexible_result_gives_the_controllers_joints():
    m = IdentifiedModel.from_result(dict(FLEX, joint_backlash_rad=[1e-3, 2e-3],
                                         model_choice={"adequate": False}))
    assert m.flexible and m.adequate is False
    j = m.joints()
    assert set(j) == {"stiffness_Nm_per_rad", "damping_Nms_per_rad",
                      "motor_inertia_reflected_kgm2", "backlash_rad"}
    np.testing.assert_array_equal(j["stiffness_Nm_per_rad"], [3e4, 6e3])
    assert "backlash_rad" not in m.joints(backlash=False)
    for key in ("joint_stiffness_Nm_per_rad", "joint_damping_Nms_per_rad",
                "motor_inertia_reflected_kgm2"):
        bad = dict(FLEX)
        del bad[key]
        with pytest.raises(ValueError, match="never reduced to its rigid f"):
            IdentifiedModel.from_result(bad)
    with pytest.raises(ValueError, match="3 values each"):
        IdentifiedModel.from_result(FLEX, n_joints=3)
    with pytest.raises(ValueError, match="unknown model 'spring'"):
        IdentifiedModel.from_result(dict(FLEX, model="spring"))


def test_identified_friction_goes_into_the_rig(paper_log):
    d = dict(f=F, friction_identified=True, viscous_friction_Nms_per_rad=[1e-3, 2e-3],
             coulomb_friction_Nm=[[0.1, -0.2], [0.3, -0.4]])
    rig = IdentifiedModel.from_result(d).rig(paper_log.rig)
    assert rig.viscous_friction_Nms_per_rad == (1e-3, 2e-3)
    assert rig.coulomb_friction_Nm == ((0.1, -0.2), (0.3, -0.4))
    assert rig.p_gain_A_per_pulse == paper_log.rig.p_gain_A_per_pulse
    assert IdentifiedModel.from_result(dict(f=F)).rig(paper_log.rig) is paper_log.rig
    # an arm result keeps its friction in "friction" and its base parameters in "beta"
    arm = dict(beta=[1.0, 2.0, 3.0], friction_identified=True,
               friction={k: d[k] for k in ("viscous_friction_Nms_per_rad", "coulomb_friction_Nm")})
    m = IdentifiedModel.from_result(arm)
    np.testing.assert_array_equal(m.f, [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(m.coulomb_friction_Nm, d["coulomb_friction_Nm"])
    with pytest.raises(ValueError, match="not finite"):
        IdentifiedModel.from_result(dict(d, viscous_friction_Nms_per_rad=[np.nan, 1.0]))
    with pytest.raises(ValueError, match="coulomb_friction_Nm"):
        IdentifiedModel.from_result(dict(d, coulomb_friction_Nm=[0.1, 0.2]))


def test_every_controller_reads_a_result_the_same_way(paper_log, truth, tmp_path):
    """from_result takes a result, its dict, its file or the contract object: the same CTC."""
    f = list(truth("puma560_paper_rigid")["f_vector"])
    d = dict(f=f, friction_identified=True, viscous_friction_Nms_per_rad=[1e-3, 2e-3],
             coulomb_friction_Nm=[[0.1, -0.2], [0.3, -0.4]])
    a = ctc.ComputedTorqueController.from_result(d, paper_log)
    b = ctc.ComputedTorqueController.from_result(IdentifiedModel.from_result(d), paper_log)
    assert a.rig == b.rig and a.rig.viscous_friction_Nms_per_rad == (1e-3, 2e-3)
    np.testing.assert_array_equal(a.f, b.f)
    adaptive = ctc.AdaptiveComputedTorqueController.from_log(d, paper_log)
    assert adaptive.log.rig == a.rig
    path = tmp_path / "prior.json"
    path.write_text(json.dumps(d))
    assert ctc.AdaptiveComputedTorqueController.from_log(path, paper_log).log.rig == a.rig
