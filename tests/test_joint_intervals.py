"""The ranges of the joint parameters a log leaves open (identification.flexible.joint_intervals).

``indep_20261327_0021`` (``tests/data/independent``, a draw of the robustness
suite, seed 20261327) is a compliant robot whose joint 3 is stiff (75 kN m/rad)
on 250 ppr encoders: its P-control log predicts to the quantisation floor with
a spring twice as stiff and a motor a quarter as heavy as the truth, and the
Gauss-Newton standard errors do not show it.  The scan must, and the
flexible-joint CTC built on the result must check its design over those
ranges and say so.  ``indep_b_flex_friction_known_2kg`` is a compliant robot
whose log determines every spring and motor.
"""
from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

import plant

DATA = Path(__file__).parent / "data" / "independent"
_RESULTS: dict = {}


def _identify(stem):
    if stem not in _RESULTS:
        import identification

        log = plant.load_log(DATA / f"{stem}.csv")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            _RESULTS[stem] = (identification.identify(log, rng=0, progress=False), log)
    return _RESULTS[stem]


def _truth_joints(stem):
    j = json.loads((DATA / f"{stem}.truth.json").read_text())["joints"]
    return np.array(j["stiffness_Nm_per_rad"] + j["damping_Nms_per_rad"]
                    + j["motor_inertia_reflected_kgm2"])


def test_floor_ranges_walks_out_to_the_allowance():
    from identification.flexible import floor_ranges

    # cost (10 (x0 - 1))^2 + (0.01 x1)^2: x0 is pinned, x1 (a log10) is free within the allowance
    def residuals(X):
        return np.stack([10.0 * (X[:, 0] - 1.0), 0.01 * X[:, 1]], axis=1)

    box = np.array([[0.0, 10.0], [-5.0, 5.0]])
    scan = floor_ranges(residuals, np.array([1.0, 0.0]), [0, 1], [False, True], box,
                        allowance=1.0, factors=(1.25, 2.0, 8.0))
    assert scan["cost"] == 0.0
    assert scan["low_x"][0][0] == 1.0 and scan["high_x"][0][0] == 1.0  # x1.25 costs 6.25 > 1
    # log10 8 = 0.9 costs 8e-5: the whole scan is admissible, no box end reached
    assert scan["low_x"][1][1] == pytest.approx(-np.log10(8.0))
    assert scan["high_x"][1][1] == pytest.approx(np.log10(8.0))
    assert not scan["at_box"].any()
    # a walk stops at the first inadmissible move even if a later one is admissible again
    def bumpy(X):
        return np.where(np.isclose(X[:, :1], 2.0), 100.0, 0.0)

    s2 = floor_ranges(bumpy, np.array([1.0]), [0], [False], np.array([[0.0, 10.0]]), 1.0,
                      factors=(1.25, 2.0, 8.0))
    assert s2["high_x"][0][0] == 1.25
    with pytest.raises(ValueError, match="increasing numbers > 1"):
        floor_ranges(residuals, np.zeros(2), [0], [False], box, 1.0, factors=(2.0, 1.5))


@pytest.mark.slow
def test_a_spring_and_motor_the_log_leaves_open_are_flagged_and_checked(tmp_path):
    import ctc
    from ctc.flexible import log_range_scenarios

    stem = "indep_20261327_0021"
    res, log = _identify(stem)
    assert res["model"] == "flexible"
    ji = res["joint_intervals"]
    assert {"K3_Nm_per_rad", "Jm3k3^2_kgm2"} <= set(ji["undetermined"])
    assert not {"K2_Nm_per_rad", "Jm2k2^2_kgm2"} & set(ji["undetermined"])
    assert "does not determine K3_Nm_per_rad" in res["message"]
    # the truth lies in the ranges of the open parameters (where the fit itself does not)
    truth = _truth_joints(stem)
    lo, hi, v = (np.asarray(ji[k]) for k in ("low", "high", "value"))
    for p in (1, 5):  # K3, Jm3 k3^2
        assert lo[p] <= truth[p] <= hi[p], (ji["names"][p], lo[p], truth[p], hi[p])
        assert abs(v[p] / truth[p] - 1) > 0.5  # the fit is off: the ranges are what is known
    # the determined ones: within the scan's first step of the fit, and the fit near the truth
    for p in (0, 4):
        assert lo[p] == v[p] == hi[p]
        assert abs(v[p] / truth[p] - 1) < 0.05
    # the JSON contract keeps them
    import identification

    res.save_json(tmp_path / "r.json")
    back = identification.IdentificationResult.load_json(tmp_path / "r.json")
    assert back["joint_intervals"]["undetermined"] == ji["undetermined"]
    # the controller checks its design at the ranges' ends of joint 3 and says what it found
    scenarios = log_range_scenarios(back)
    assert scenarios and all(s["name"].startswith("joint 3 ") for s in scenarios)
    corner = [s for s in scenarios if "K x0.5" in s["name"] and "Jm k^2 x4" in s["name"]]
    assert corner and np.allclose(corner[0]["stiffness"], [1.0, 0.5])
    with pytest.warns(RuntimeWarning, match="does not determine every joint parameter"):
        c = ctc.ComputedTorqueController.from_result(back, log, robust="check")
    names = [s["name"] for s in c.robustness["scenarios"]]
    assert set(s["name"] for s in scenarios) <= set(names)


@pytest.mark.slow
def test_a_log_that_determines_its_joints_adds_no_scenario():
    from ctc.contract import IdentifiedModel
    from ctc.flexible import log_range_scenarios

    stem = "indep_b_flex_friction_known_2kg"
    res, _ = _identify(stem)
    assert res["model"] == "flexible"
    ji = res["joint_intervals"]
    assert not [n for n in ji["undetermined"] if not n.startswith("D")]
    truth = _truth_joints(stem)
    for p in (0, 1, 4, 5):  # K and Jm k^2: determined, and the fit within 5 % of the truth
        assert abs(ji["value"][p] / truth[p] - 1) < 0.05
    assert IdentifiedModel.from_result(res).joint_ranges.shape == (3, 2, 2)
    assert log_range_scenarios(res) == ()


def test_the_contract_reads_the_ranges_as_factors():
    from ctc.contract import IdentifiedModel

    base = dict(f=np.ones(9).tolist(), model="flexible", joint_stiffness_Nm_per_rad=[1e4, 2e4],
                joint_damping_Nms_per_rad=[1.0, 2.0], motor_inertia_reflected_kgm2=[0.5, 0.25])
    ji = dict(value=[1e4, 2e4, 1.0, 2.0, 0.5, 0.25], low=[1e4, 1e4, 0.5, 2.0, 0.5, 0.2],
              high=[1e4, 4e4, 1.0, 4.0, 0.5, 1.0])
    m = IdentifiedModel.from_result(dict(base, joint_intervals=ji))
    assert np.allclose(m.joint_ranges[:, :, 0], [[1.0, 0.5], [0.5, 1.0], [1.0, 0.8]])
    assert np.allclose(m.joint_ranges[:, :, 1], [[1.0, 2.0], [1.0, 2.0], [1.0, 4.0]])
    assert IdentifiedModel.from_result(base).joint_ranges is None
    assert IdentifiedModel.from_result(dict(base, joint_intervals={"low": [1]})).joint_ranges is None
    from ctc.flexible import log_range_scenarios

    names = [s["name"] for s in log_range_scenarios(dict(base, joint_intervals=ji))]
    # joint 3: K x0.5 and x2, Jm k^2 x4, D x2 (open with them); joint 2: damping alone, none
    assert names and all(n.startswith("joint 3 ") for n in names)
    assert len(names) == 3 * 2 * 2 - 1
