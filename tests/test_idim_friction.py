"""IDIM-LS / IDIM-IV with the drive friction unknown (issue 20).

A sidecar with ``"viscous_friction_Nms_per_rad": null`` and/or
``"coulomb_friction_Nm": null`` used to run IDIM with zero friction (f2 off
by more than 1000 % in a user trial).  The friction is now identified with f
as regressor columns (:func:`identification.idim.friction_columns`) and
reported in the GA path's result keys.
"""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

import plant
from identification import identify
from identification.idim import friction_columns, idim_ls
from identification.uncertainty import PoorExcitationWarning
from plant.simulation.friction import FRICTION_NAMES, friction_vector
from plant.robot.model import friction_torque

WELL_EXCITED = np.array([1, 2, 4, 6, 7, 9]) - 1

#: f of IDIM-LS and IDIM-IV on ``puma560_paper_rigid`` (friction known), computed
#: with identification/idim.py before the friction columns were added (issue 20):
#: the known-friction path must not move.
PAPER_LS_F = [0.9370317987316046, 0.3582481894746261, 0.012044978800937972,
              -0.38622852467969815, 0.02534443134861575, -0.8967131691369848,
              4.419076353833259, -0.10627201711841983, 3.797605816613551]
PAPER_IV_F = [0.9374085009183982, 0.3589659272216746, 0.011716613311301149,
              -0.3863260992666806, 0.025396285410925302, -0.8961577338014309,
              4.446526362455376, -0.10035200729807774, 3.7916181259759]


def _null_friction(d):
    d["viscous_friction_Nms_per_rad"] = None
    d["coulomb_friction_Nm"] = None


@pytest.fixture
def unknown_log(tmp_log):
    """``puma560_paper_rigid`` with both friction fields null in its sidecar."""
    return plant.load_log(tmp_log(json_edit=_null_friction))


def _friction_of(r):
    return np.r_[np.ravel(r.viscous_friction_Nms_per_rad), np.ravel(r.coulomb_friction_Nm)]


def test_friction_columns_are_the_friction_model(paper_log):
    """Columns times the motor-side friction = minus plant.robot.model.friction_torque (ramp too)."""
    c = plant.rig_constants(paper_log.rig)
    rng = np.random.default_rng(0)
    ramp = np.asarray(c.ramp_speed)
    qd = rng.uniform(-3, 3, (400, 2)) * ramp  # through the ramp and beyond it
    qd[:3] = 0.0
    cols = friction_columns(qd, c, paper_log.rig.gear_ratio, range(6))
    assert cols.shape == (400, 2, 6)
    v = friction_vector(paper_log.rig)
    want = np.array([[friction_torque(qd[i, j], c.viscous[j], c.coulomb_pos[j], c.coulomb_neg[j],
                                      c.ramp_speed[j]) for j in range(2)] for i in range(400)])
    assert np.allclose(cols @ v, -want, rtol=1e-12, atol=1e-12)
    # a subset is those columns, in FRICTION_NAMES order
    assert np.array_equal(friction_columns(qd, c, paper_log.rig.gear_ratio, [1, 4]),
                          cols[:, :, [1, 4]])


@pytest.mark.parametrize("method", ["idim-ls", "idim-iv"])
def test_idim_identifies_unknown_friction(unknown_log, paper_log, truth, method, tmp_path):
    """Acceptance: well-excited f within 3 %, friction within 15 %, reported like the GA's."""
    assert unknown_log.rig.unknown_friction  # the loaded sidecar says so
    f_true = np.asarray(truth("puma560_paper_rigid")["f_vector"])
    v_true = friction_vector(paper_log.rig)
    with pytest.warns(PoorExcitationWarning):  # f8 (and f3): the paper trajectory's
        r = identify(unknown_log, method=method)
    rel = np.abs(r.f - f_true) / np.abs(f_true)
    assert np.all(rel[WELL_EXCITED] < 0.03), rel
    v = _friction_of(r)
    assert np.all(np.abs(v - v_true) < 0.15 * v_true), (v, v_true)
    assert r.friction_identified is True and r.parameters == "base+friction"
    assert r.x_names == ["f1", "f2", "f3", "f4", "f5", "f6", "f7", "f8", "f9", *FRICTION_NAMES]
    assert np.array_equal(r.x[9:], v) and np.array_equal(r.x[:9], r.f)
    assert r.x_std.shape == (15,) and np.all(np.isfinite(r.x_std)) and np.all(r.x_std > 0)
    assert np.allclose(r.x_std[:9], r.f_std) and r.x_correlation.shape == (15, 15)
    assert r.uncertainty["x_names"] == r.x_names
    if method == "idim-iv":
        assert r.settings["idim"]["iv_iterations"] > 0 and "IV" in r.uncertainty["method"]
    d = json.loads(r.save_json(tmp_path / "r.json").target.read_text())
    assert d["friction_identified"] is True and np.shape(d["coulomb_friction_Nm"]) == (2, 2)
    assert np.allclose(d["viscous_friction_Nms_per_rad"], v[:2]) and len(d["x_std"]) == 15


def test_idim_partly_unknown_friction_keeps_the_known_part(paper_log, truth):
    """Only the viscous friction unknown: two columns, the Coulomb stays the sidecar's."""
    log = dataclasses.replace(paper_log, rig=dataclasses.replace(
        paper_log.rig, viscous_friction_Nms_per_rad=None))
    res = idim_ls(log)
    assert res["friction_unknown"] == [0, 1] and res["x"].shape == (11,)
    v_true = friction_vector(paper_log.rig)
    assert np.array_equal(res["friction"][2:], v_true[2:])
    assert np.all(np.abs(res["friction"][:2] - v_true[:2]) < 0.05 * v_true[:2])
    f_true = np.asarray(truth("puma560_paper_rigid")["f_vector"])
    rel = np.abs(res["f"] - f_true) / np.abs(f_true)
    assert np.all(rel[WELL_EXCITED] < 0.03), rel


def test_known_friction_path_unchanged(paper_log, monkeypatch):
    """A rig that knows its friction: no friction column, f as before issue 20 (LS 1e-12, IV 1e-9)."""
    import identification.idim as idim

    def boom(*a, **k):
        raise AssertionError("friction columns built for a rig that knows its friction")

    monkeypatch.setattr(idim, "friction_columns", boom)
    ls = idim_ls(paper_log)
    iv = idim_ls(paper_log, iv_iterations=idim.IV_ITERATIONS)
    assert np.allclose(ls["f"], PAPER_LS_F, rtol=1e-12, atol=0)
    # the IV iterations amplify the BLAS build's rounding (1e-11 seen between two
    # installs of the same numpy/scipy versions): the same path, to 1e-9
    assert np.allclose(iv["f"], PAPER_IV_F, rtol=1e-9, atol=0)
    assert ls["friction_unknown"] == [] and np.array_equal(ls["x"], ls["f"])
    with pytest.warns(PoorExcitationWarning):
        r = identify(paper_log, method="idim-ls")
    assert np.array_equal(r.f, ls["f"])
    assert r.friction_identified is False and r.parameters == "base"
    assert np.allclose(_friction_of(r), friction_vector(paper_log.rig))
