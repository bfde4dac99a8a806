"""Tests of plant.logs.trajectory: the reference against the logs, analytic derivatives, parsing."""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from plant._errors import LogError
from plant.logs.trajectory import Trajectory

PAPER_RIGID = "puma560_paper_rigid"
VALIDATION_RIGID = "puma560_validation_rigid"
DRILL_FLEX = "puma560_paper_drill_flex"
DEV_STEMS = (PAPER_RIGID, VALIDATION_RIGID, DRILL_FLEX)


def _csv_columns(path):
    """t and (q2_ref, q3_ref) read straight from the CSV, independent of plant.logs.log."""
    data = np.loadtxt(path, delimiter=",", skiprows=1)
    return data[:, 0], data[:, 1:3]


def _sidecar(data_dir, stem):
    return json.loads((data_dir / f"{stem}.json").read_text())


# ----------------------------------------------------------------- against the logs
@pytest.mark.parametrize("stem", DEV_STEMS)
def test_trajectory_matches_csv_reference_columns(data_dir, stem):
    traj = Trajectory.from_sidecar(_sidecar(data_dir, stem))
    t, q_ref = _csv_columns(data_dir / f"{stem}.csv")
    err = np.abs(traj.position(t) - q_ref).max()
    assert err <= 1e-12
    q, qd, qdd = traj.evaluate(t)
    assert np.abs(q - q_ref).max() <= 1e-12
    assert q.shape == qd.shape == qdd.shape == (t.size, 2)


def test_validation_trajectory_is_ramped_and_ramp_multiplies_offset(data_dir):
    side = _sidecar(data_dir, VALIDATION_RIGID)
    # the formula in the sidecar: the ramp w(t) multiplies the whole bracket, c included
    assert "w(t)*(-pi/6" in side["trajectory"]["formula"]
    traj = Trajectory.from_sidecar(side)
    assert traj.t_ramp_s == 0.8
    q, qd, qdd = traj.evaluate(np.array([0.0]))
    np.testing.assert_array_equal(q, 0.0)  # c != 0, so the ramp must multiply c
    np.testing.assert_array_equal(qd, 0.0)
    np.testing.assert_array_equal(qdd, 0.0)
    # w(s = 1/2) = 1/2
    u = traj.c + np.sum(traj.amplitude * np.cos(traj.omega * 0.4 + traj.phase), axis=1)
    np.testing.assert_allclose(traj.position(0.4)[0], 0.5 * u, rtol=0, atol=1e-15)
    # after the ramp: the plain cosine series
    t = np.array([0.8, 1.0, 3.3])
    u = traj.c + np.sum(
        traj.amplitude[None] * np.cos(traj.omega[None] * t[:, None, None] + traj.phase[None]), axis=2
    )
    np.testing.assert_allclose(traj.position(t), u, rtol=0, atol=1e-15)


@pytest.mark.parametrize("stem", [PAPER_RIGID, DRILL_FLEX])
def test_paper_eq6_equals_sidecar_trajectory(data_dir, stem):
    side_traj = Trajectory.from_sidecar(_sidecar(data_dir, stem))
    paper = Trajectory.paper()
    np.testing.assert_allclose(paper.omega, side_traj.omega, rtol=1e-15, atol=0)
    np.testing.assert_array_equal(paper.c, side_traj.c)
    np.testing.assert_array_equal(paper.amplitude, side_traj.amplitude)
    assert paper.t_ramp_s == 0.0
    t, q_ref = _csv_columns(data_dir / f"{stem}.csv")
    assert np.abs(paper.position(t) - q_ref).max() <= 1e-12


def test_paper_formula_and_period():
    T = 2.0
    traj = Trajectory.paper(T)
    t = np.linspace(0, 3, 101)
    q = traj.position(t)
    np.testing.assert_allclose(q[:, 0], -np.pi / 4 + np.pi / 4 * np.cos(2 * np.pi * t / T), atol=1e-15)
    np.testing.assert_allclose(q[:, 1], np.pi / 4 - np.pi / 4 * np.cos(4 * np.pi * t / T), atol=1e-15)
    with pytest.raises(ValueError):
        Trajectory.paper(0.0)


# --------------------------------------------------------------------- derivatives
def _fd_check(traj, t, h, tol_qd, tol_qdd):
    q, qd, qdd = traj.evaluate(t)
    qp, qdp, _ = traj.evaluate(t + h)
    qm, qdm, _ = traj.evaluate(t - h)
    fd_qd = (qp - qm) / (2 * h)
    fd_qdd = (qdp - qdm) / (2 * h)
    assert np.abs(fd_qd - qd).max() <= tol_qd
    assert np.abs(fd_qdd - qdd).max() <= tol_qdd


def _multi_term():
    # different term counts per joint, a ramp, nonzero phases
    return Trajectory.from_terms(
        [0.3, -0.2],
        [[(0.5, 2.0, 0.1), (0.1, 7.0, -0.4), (0.05, 13.0, 1.0)], [(0.7, 3.0, 0.5)]],
        t_ramp_s=0.5,
    )


@pytest.mark.parametrize("which", ["paper", "validation", "multi"])
def test_derivatives_match_central_differences(data_dir, which):
    if which == "paper":
        traj = Trajectory.paper()
    elif which == "validation":
        traj = Trajectory.from_sidecar(_sidecar(data_dir, VALIDATION_RIGID))
    else:
        traj = _multi_term()
    h = 1e-5
    t = np.linspace(0.0, 5.0, 2001)
    if traj.t_ramp_s:
        # away from the ramp's end points (w''' jumps there; see the next test)
        keep = (np.abs(t - traj.t_ramp_s) > 3 * h) & (t > 3 * h)
        t = np.concatenate([t[keep], traj.t_ramp_s + np.array([-1e-3, -1e-4, 1e-4, 1e-3])])
    _fd_check(traj, t, h, tol_qd=1e-7, tol_qdd=1e-6)


@pytest.mark.parametrize("which", ["validation", "multi"])
def test_derivatives_across_the_ramp_end(data_dir, which):
    traj = (
        Trajectory.from_sidecar(_sidecar(data_dir, VALIDATION_RIGID)) if which == "validation" else _multi_term()
    )
    tr = traj.t_ramp_s
    # q, qd, qdd continuous at t_ramp (w is C2 there; w''' jumps)
    eps = 1e-12
    for a, b in zip(traj.evaluate(np.array([tr - eps])), traj.evaluate(np.array([tr + eps]))):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-9)
    # differences straddling t_ramp: qd from q is O(h^2) accurate (q is C2), qdd from qd is
    # O(h) at the jump of q''' (|jump| <= 60/tr^3 * |u|)
    h = 1e-7
    u_max = np.max(np.abs(traj.c) + np.abs(traj.amplitude).sum(axis=1))
    kink = h / 4 * (60.0 / tr**3) * u_max  # bound of the O(h) term of the central difference
    t = tr + np.array([-0.5 * h, 0.0, 0.5 * h])
    _fd_check(traj, t, h, tol_qd=1e-7, tol_qdd=kink + 1e-7)
    # and the same at the start of the ramp, t = 0 (w = 0 for t < 0)
    _fd_check(traj, np.array([0.0, 0.5 * h]), h, tol_qd=1e-7, tol_qdd=kink + 1e-7)


def test_ramp_values_and_before_start(data_dir):
    traj = Trajectory.from_sidecar(_sidecar(data_dir, VALIDATION_RIGID))
    q, qd, qdd = traj.evaluate(np.array([-0.3, -1e-3]))
    assert np.all(q == 0) and np.all(qd == 0) and np.all(qdd == 0)
    # without a ramp the series holds for t < 0 too
    paper = Trajectory.paper()
    np.testing.assert_allclose(paper.position(-0.5), paper.position(3.65 - 0.5), atol=1e-12)


# ------------------------------------------------------------- construction, parsing
def test_padding_and_to_parameters_round_trip():
    traj = _multi_term()
    assert traj.amplitude.shape == traj.omega.shape == traj.phase.shape == (2, 3)
    assert traj.n_terms == (3, 1)
    np.testing.assert_array_equal(traj.amplitude[1, 1:], 0.0)
    params = traj.to_parameters()
    assert len(params["terms_A_omega_phi"][1]) == 1
    assert Trajectory.from_sidecar(params) == traj
    assert Trajectory.from_sidecar({"trajectory": {"parameters": params}}) == traj
    assert Trajectory.from_sidecar({"parameters": params}) == traj
    assert traj != Trajectory.paper()


def test_scalar_and_shapes():
    traj = Trajectory.paper()
    assert traj.position(0.1).shape == (1, 2)
    assert all(a.shape == (1, 2) for a in traj.evaluate(0.1))
    assert traj.position(np.zeros(0)).shape == (0, 2)
    with pytest.raises(ValueError):
        traj.position(np.zeros((2, 2)))
    np.testing.assert_array_equal(traj(np.array([0.2])), traj.position(np.array([0.2])))


def test_immutable():
    traj = Trajectory.paper()
    with pytest.raises(dataclasses.FrozenInstanceError):
        traj.t_ramp_s = 1.0
    with pytest.raises(ValueError):
        traj.c[0] = 1.0


def test_no_terms_joint():
    traj = Trajectory.from_sidecar({"c": [0.1, 0.2], "terms_A_omega_phi": [[], []], "t_ramp_s": 0.0})
    q, qd, qdd = traj.evaluate(np.array([0.0, 1.0]))
    np.testing.assert_array_equal(q, [[0.1, 0.2], [0.1, 0.2]])
    assert np.all(qd == 0) and np.all(qdd == 0)


_GOOD = {"c": [0.0, 0.0], "terms_A_omega_phi": [[[1.0, 2.0, 0.0]], [[1.0, 2.0, 0.0]]], "t_ramp_s": 0.0}


@pytest.mark.parametrize(
    "params, fragment",
    [
        ({k: v for k, v in _GOOD.items() if k != "c"}, "parameters.c' is missing"),
        ({**_GOOD, "c": [0.0]}, "parameters.c' must be a list of 2 numbers"),
        ({**_GOOD, "c": [0.0, "x"]}, "parameters.c' must be a list of 2 numbers"),
        ({**_GOOD, "c": [0.0, float("nan")]}, "parameters.c' has non-finite"),
        ({k: v for k, v in _GOOD.items() if k != "terms_A_omega_phi"}, "parameters.terms_A_omega_phi' is missing"),
        ({**_GOOD, "terms_A_omega_phi": [[[1.0, 2.0, 0.0]]]}, "parameters.terms_A_omega_phi' must be a list of 2"),
        ({**_GOOD, "terms_A_omega_phi": [[[1.0, 2.0]], []]}, "parameters.terms_A_omega_phi[0][0]' must be [A, omega, phi]"),
        ({**_GOOD, "terms_A_omega_phi": [[], [[1.0, float("inf"), 0.0]]]}, "parameters.terms_A_omega_phi[1]' has non-finite"),
        ({**_GOOD, "t_ramp_s": -1.0}, "parameters.t_ramp_s' must be finite and >= 0"),
        ({**_GOOD, "t_ramp_s": "1"}, "parameters.t_ramp_s' must be a number"),
    ],
)
def test_from_sidecar_bad_parameters(params, fragment):
    with pytest.raises(LogError) as exc:
        Trajectory.from_sidecar({"trajectory": {"parameters": params}}, source="run.json")
    msg = str(exc.value)
    assert fragment in msg and msg.startswith("run.json: ") and "\n" not in msg
    assert "trajectory.parameters." in msg


def test_from_sidecar_missing_sections():
    with pytest.raises(LogError, match="'trajectory' is missing"):
        Trajectory.from_sidecar({"sample_time_s": 0.0007}, source="x.json")
    with pytest.raises(LogError, match=r"'trajectory\.parameters' is missing"):
        Trajectory.from_sidecar({"trajectory": {"formula": "q = 0"}}, source="x.json")
