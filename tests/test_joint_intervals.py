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
    # ... so both ends are open (the scan's last factor), and x0's are not
    assert scan["low_open"].tolist() == [False, True] and scan["high_open"].tolist() == [False, True]
    # a walk stops at the first inadmissible move even if a later one is admissible again
    def bumpy(X):
        return np.where(np.isclose(X[:, :1], 2.0), 100.0, 0.0)

    s2 = floor_ranges(bumpy, np.array([1.0]), [0], [False], np.array([[0.0, 10.0]]), 1.0,
                      factors=(1.25, 2.0, 8.0))
    assert s2["high_x"][0][0] == 1.25
    with pytest.raises(ValueError, match="increasing numbers > 1"):
        floor_ranges(residuals, np.zeros(2), [0], [False], box, 1.0, factors=(2.0, 1.5))


def test_a_value_at_zero_moves_up_only_and_a_factor_of_two_is_reached():
    from identification.flexible import _reaches, floor_ranges, range_record

    # a damping fitted at 0 whose cost is flat up to 0.05: [0, 0.05] fits, the low end is 0
    def residuals(X):
        return np.maximum(X[:, :1] - 0.05, 0.0) * 100.0

    # (moves from 1 % of the box's upper end: 0.0125, 0.02, then 0.08, which costs 3^2)
    scan = floor_ranges(residuals, np.array([0.0]), [0], [False], np.array([[0.0, 1.0]]), 1.0,
                        factors=(1.25, 2.0, 8.0))
    assert scan["low_x"][0][0] == 0.0 and not scan["low_open"][0]
    assert scan["high_x"][0][0] == pytest.approx(0.02) and not scan["high_open"][0]
    rec = range_record(["D2"], [0.0], [scan["low_x"][0][0]], [scan["high_x"][0][0]], scan, 1.0,
                       "test", floor=100.0)
    assert rec["undetermined"] == ["D2"] and rec["low_factor"] == [1.0]
    assert rec["high_factor"] == [None]  # a range leaving 0 has no factor
    # a steep cost away from 0: determined
    steep = floor_ranges(lambda X: X[:, :1] * 1e6, np.array([0.0]), [0], [False],
                         np.array([[0.0, 10.0]]), 1.0, factors=(1.25, 2.0))
    rec = range_record(["D2"], [0.0], [0.0], [steep["high_x"][0][0]], steep, 1.0, "t", 100.0)
    assert rec["undetermined"] == []
    # the x2 scan step of a log10 column is x2 up to rounding, and counts
    assert _reaches(10.0 ** (4.123 + np.log10(2.0)) / 10.0 ** 4.123)
    # a fit far above the floor is not judged
    far = range_record(["K2"], [1.0], [0.1], [10.0], dict(scan, cost=5000.0), 1.0, "t", 100.0)
    assert far["judged"] is False and far["undetermined"] == [] and far["fit_floors"] == 50.0


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
    # the CLI's table lists every joint parameter with its range, flagging the open ones
    from identification.cli import format_result_table

    rows = {ln.split()[0]: ln for ln in format_result_table(res, log).splitlines()
            if ln.startswith("  ")}
    assert "(not determined by this log)" in rows["K3"] and "(not determined" not in rows["K2"]
    assert rows["Jm3k3^2"].endswith("kg m^2   (not determined by this log)")
    # the truth lies in the ranges of the open parameters (at the scan's x1.25 resolution),
    # where the fit itself does not
    truth = _truth_joints(stem)
    lo, hi, v = (np.asarray(ji[k]) for k in ("low", "high", "value"))
    for p in (1, 5):  # K3, Jm3 k3^2
        assert lo[p] / 1.25 <= truth[p] <= hi[p] * 1.25, (ji["names"][p], lo[p], truth[p], hi[p])
        assert abs(v[p] / truth[p] - 1) > 0.5  # the fit is off: the ranges are what is known
    # the determined ones: within the scan's first step of the fit, and the fit near the truth
    for p in (0, 4):
        assert lo[p] == v[p] == hi[p]
        assert abs(v[p] / truth[p] - 1) < 0.05
    # the robots the log allows beside the fit: joint 3 changed, each within the allowance
    corners = ji["corners"]
    assert corners and all(c["joint"] == 1 for c in corners)
    assert all(c["cost_pulses2"] <= ji["cost_pulses2"] + ji["allowance_pulses2"] for c in corners)
    assert any(c["stiffness"] < 0.75 and c["motor_inertia"] > 2.0 for c in corners), corners
    # the JSON contract keeps them
    import identification

    res.save_json(tmp_path / "r.json")
    back = identification.IdentificationResult.load_json(tmp_path / "r.json")
    assert back["joint_intervals"]["undetermined"] == ji["undetermined"]
    # the controller checks its design at the ranges' ends of joint 3 and says what it found
    scenarios = log_range_scenarios(back)
    assert len(scenarios) == len(corners)
    assert all(s["name"].startswith("joint 3 ") and s["stiffness"][0] == 1.0 for s in scenarios)
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
    assert ji["corners"] == [] and IdentifiedModel.from_result(res).joint_corners == ()
    assert log_range_scenarios(res) == ()


def test_the_contract_reads_the_corners_the_log_allows():
    from ctc.contract import IdentifiedModel
    from ctc.flexible import log_range_scenarios

    base = dict(f=np.ones(9).tolist(), model="flexible", joint_stiffness_Nm_per_rad=[1e4, 2e4],
                joint_damping_Nms_per_rad=[1.0, 2.0], motor_inertia_reflected_kgm2=[0.5, 0.25])
    corners = [dict(joint=1, stiffness=0.5, damping=1.0, motor_inertia=4.0, cost_pulses2=1.0),
               dict(joint=1, stiffness=0.5, damping=0.125, motor_inertia=4.0, cost_pulses2=2.0),
               dict(joint=5, stiffness=0.5, damping=1.0, motor_inertia=1.0),  # no such joint
               dict(joint=0, stiffness=-1.0, damping=1.0, motor_inertia=1.0),  # no such robot
               dict(joint=0, stiffness=2.0)]  # malformed
    m = IdentifiedModel.from_result(dict(base, joint_intervals=dict(corners=corners)))
    assert m.joint_corners == ((1, 0.5, 1.0, 4.0), (1, 0.5, 0.125, 4.0))
    assert IdentifiedModel.from_result(base).joint_corners == ()
    assert IdentifiedModel.from_result(dict(base, joint_intervals={"corners": 3})).joint_corners == ()
    sc = log_range_scenarios(dict(base, joint_intervals=dict(corners=corners)))
    assert [s["name"] for s in sc] == ["joint 3 K x0.5, Jm k^2 x4 (log range)",
                                       "joint 3 K x0.5, D x0.125, Jm k^2 x4 (log range)"]
    assert sc[1]["damping"] == [1.0, 0.125] and sc[1]["motor_inertia"] == [1.0, 4.0]
