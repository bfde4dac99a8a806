"""The numeric (numba) model plant.robot.model against the casadi derivation plant.robot.symbolic.

Random base parameters are drawn from the paper's search ranges; every check
runs at >= 200 random states.  Tolerance: 1e-12 relative to the size of the
terms that make up a value (absolute below magnitude 1).
"""
from __future__ import annotations

import numpy as np
import pytest

from plant.robot import model, symbolic

#: Search ranges of f1..f9 (the paper's, as in the development logs' sidecars).
F_RANGES = np.array(
    [
        [0.28, 4.07],
        [0.0, 2.33],
        [-0.2, 0.2],
        [-1.25, 0.0],
        [-0.4, 0.4],
        [-2.5, 0.0],
        [2.23, 17.95],
        [-1.75, 1.75],
        [-2.7, 11.25],
    ]
)
RTOL = 1e-12
N_F = 64  # random parameter vectors
N_S = 4  # random states per parameter vector (N_F * N_S = 256 states)


@pytest.fixture(scope="module")
def f_true(truth):
    """True f1..f9 of ``puma560_paper_rigid`` (its truth file, conftest's ``truth``)."""
    return np.asarray(truth("puma560_paper_rigid")["f_vector"], dtype=float)


@pytest.fixture(scope="module")
def base():
    return symbolic.derive_base_model()


@pytest.fixture(scope="module")
def samples():
    """(f, grav, q, qd, qdd, tau) per parameter vector: f (9,), states (N_S, 2)."""
    rng = np.random.default_rng(2024)
    out = []
    for _ in range(N_F):
        f = rng.uniform(F_RANGES[:, 0], F_RANGES[:, 1])
        grav = rng.uniform(9.7, 9.9)
        q = rng.uniform(-2 * np.pi, 2 * np.pi, (N_S, 2))
        qd = rng.uniform(-4, 4, (N_S, 2))
        qdd = rng.uniform(-20, 20, (N_S, 2))
        tau = rng.uniform(-60, 60, (N_S, 2))
        out.append((f, grav, q, qd, qdd, tau))
    return out


def _cas(fun, *args):
    """Evaluate a casadi Function at one sample; returns a squeezed ndarray."""
    res = np.asarray(fun(*args))
    return res[:, 0] if res.shape[1] == 1 else res


def _close(a, b, scale):
    scale = np.maximum(1.0, scale)
    err = np.max(np.abs(np.asarray(a) - np.asarray(b)) / scale)
    assert err <= RTOL, f"max scaled error {err:.3e} > {RTOL}"


def _term_scale(f, q, qd, qdd, grav):
    """Sum of |Y_ij f_j| per joint: the size of the terms that add up to tau."""
    return np.abs(model.regressor(q, qd, qdd, grav)) @ np.abs(f)


# ---------------------------------------------------------------------------
# numba == casadi
# ---------------------------------------------------------------------------
def test_numba_equals_casadi(base, samples):
    n_states = 0
    for f, grav, q, qd, qdd, _ in samples:
        D = model.inertia_matrix(f, q)
        h = model.coriolis_centrifugal(f, q, qd)
        g = model.gravity_vector(f, q, grav)
        tau = model.inverse_dynamics(f, q, qd, qdd, grav)
        Y = model.regressor(q, qd, qdd, grav)
        scale = _term_scale(f, q, qd, qdd, grav)
        for k in range(len(q)):
            args = (f, q[k], qd[k], qdd[k], grav)
            _close(D[k], _cas(base.D, *args), np.abs(f).max())
            _close(h[k], _cas(base.h, *args), scale[k])
            _close(g[k], _cas(base.g, *args), scale[k])
            _close(tau[k], _cas(base.tau, *args), scale[k])
            Yc = _cas(base.Y, *args)
            _close(Y[k], Yc, np.abs(Yc))
            n_states += 1
    assert n_states >= 200


def test_forward_dynamics_equals_casadi(base):
    """forward_dynamics == casadi solve(D, tau - h - g) at >= 200 states with D PD."""
    rng = np.random.default_rng(7)
    n = 0
    while n < 256:
        f = rng.uniform(F_RANGES[:, 0], F_RANGES[:, 1])
        q = rng.uniform(-np.pi, np.pi, 2)
        if model.min_inertia_eigenvalue(f, q[1]) <= 0:
            continue  # the ranges allow f2 > f1: D not PD, tested below
        qd = rng.uniform(-4, 4, 2)
        tau = rng.uniform(-60, 60, 2)
        qdd = model.forward_dynamics(f, q, qd, tau, 9.81)
        qdd_c = _cas(base.forward, f, q, qd, tau, 9.81)
        D = model.inertia_matrix(f, q)
        cond = np.linalg.cond(D)
        # error bound of a 2x2 solve: cond(D) times the size of the terms
        rhs_scale = np.abs(tau) + _term_scale(f, q, qd, np.zeros(2), 9.81)
        scale = cond * (np.abs(qdd_c) + np.linalg.norm(np.linalg.inv(D), 2) * rhs_scale)
        _close(qdd, qdd_c, scale)
        # and it inverts inverse_dynamics
        tau_back = model.inverse_dynamics(f, q, qd, qdd, 9.81)
        _close(tau_back, tau, cond * rhs_scale)
        n += 1


def test_forward_dynamics_batch_matches_single(f_true):
    f = f_true
    rng = np.random.default_rng(3)
    q, qd, tau = (rng.uniform(-3, 3, (50, 2)) for _ in range(3))
    batch = model.forward_dynamics(f, q, qd, tau)
    single = np.array([model.forward_dynamics(f, q[k], qd[k], tau[k]) for k in range(50)])
    np.testing.assert_array_equal(batch, single)


# ---------------------------------------------------------------------------
# Model properties
# ---------------------------------------------------------------------------
def test_regressor_times_f_is_inverse_dynamics(samples):
    for f, grav, q, qd, qdd, _ in samples:
        Y = model.regressor(q, qd, qdd, grav)
        D = model.inertia_matrix(f, q)
        rhs = (
            np.einsum("nij,nj->ni", D, qdd)
            + model.coriolis_centrifugal(f, q, qd)
            + model.gravity_vector(f, q, grav)
        )
        scale = _term_scale(f, q, qd, qdd, grav)
        _close(Y @ f, rhs, scale)
        _close(Y @ f, model.inverse_dynamics(f, q, qd, qdd, grav), scale)


def test_inertia_symmetric_positive_definite_for_true_f(base, f_true):
    f = f_true
    assert model.is_positive_definite(f)
    rng = np.random.default_rng(11)
    q = np.column_stack([rng.uniform(-np.pi, np.pi, 400), np.linspace(-np.pi, np.pi, 400)])
    D = model.inertia_matrix(f, q)
    np.testing.assert_array_equal(D, D.transpose(0, 2, 1))
    eig = np.linalg.eigvalsh(D)
    assert np.all(eig[:, 0] > 0)
    np.testing.assert_allclose(eig[:, 0], model.min_inertia_eigenvalue(f, q[:, 1]), rtol=1e-10)
    det = D[:, 0, 0] * D[:, 1, 1] - D[:, 0, 1] ** 2
    assert np.all(det > 0) and f[0] > 0
    for k in range(0, 400, 40):  # the casadi D too
        Dc = _cas(base.D, f, q[k], np.zeros(2), np.zeros(2), 9.81)
        assert np.all(np.linalg.eigvalsh(Dc) > 0)


def test_christoffel_h_matches_numba(samples):
    """h == C(q, qd) qd with C from the Christoffel symbols of D (plant.robot.symbolic)."""
    Cf = symbolic.derive_coriolis_matrix()
    for f, grav, q, qd, qdd, _ in samples[:16]:
        h = model.coriolis_centrifugal(f, q, qd)
        for k in range(len(q)):
            C = np.asarray(Cf(f, q[k], qd[k])[0])
            _close(C @ qd[k], h[k], np.abs(f).max() * np.abs(qd[k]).max() ** 2)


def test_non_pd_detected_and_forward_dynamics_raises(f_true):
    f = f_true.copy()
    f[0], f[1], f[6] = 0.3, 2.3, 2.23  # f2 > f1: D12^2 > D11 D22
    assert not model.is_positive_definite(f)
    assert model.min_inertia_eigenvalue(f, 0.0) < 0
    with pytest.raises(ValueError, match="positive definite"):
        model.forward_dynamics(f, [0.1, 0.2], [0.0, 0.0], [1.0, 1.0])
    with pytest.raises(ValueError, match="positive definite"):
        model.forward_dynamics(f, np.zeros((3, 2)), np.zeros((3, 2)), np.ones((3, 2)))
    g = f_true.copy()
    g[0] = -0.1  # f1 = D22 <= 0
    with pytest.raises(ValueError, match="positive definite"):
        model.forward_dynamics(g, [0.1, 0.2], [0.0, 0.0], [1.0, 1.0])


# ---------------------------------------------------------------------------
# Shapes of the public wrappers
# ---------------------------------------------------------------------------
def test_single_and_batch_shapes(f_true):
    f = f_true
    rng = np.random.default_rng(5)
    q, qd, qdd = (rng.uniform(-2, 2, (7, 2)) for _ in range(3))
    assert model.inertia_matrix(f, q[0]).shape == (2, 2)
    assert model.inertia_matrix(f, q).shape == (7, 2, 2)
    assert model.coriolis_centrifugal(f, q[0], qd[0]).shape == (2,)
    assert model.coriolis_centrifugal(f, q, qd).shape == (7, 2)
    assert model.gravity_vector(f, q[0]).shape == (2,)
    assert model.gravity_vector(f, q).shape == (7, 2)
    assert model.inverse_dynamics(f, q[0], qd[0], qdd[0]).shape == (2,)
    assert model.inverse_dynamics(f, q, qd, qdd).shape == (7, 2)
    assert model.forward_dynamics(f, q[0], qd[0], qdd[0]).shape == (2,)
    assert model.forward_dynamics(f, q, qd, qdd).shape == (7, 2)
    assert model.regressor(q[0], qd[0], qdd[0]).shape == (2, 9)
    assert model.regressor(q, qd, qdd).shape == (7, 2, 9)
    # batch rows equal single evaluations; lists are accepted
    tau = model.inverse_dynamics(f, q, qd, qdd)
    for k in range(7):
        np.testing.assert_array_equal(
            model.inverse_dynamics(list(f), list(q[k]), list(qd[k]), list(qdd[k])), tau[k]
        )
    # a single (2,) state broadcasts against an (n, 2) batch
    mixed = model.inverse_dynamics(f, q[0], qd, qdd)
    np.testing.assert_array_equal(mixed, model.inverse_dynamics(f, np.tile(q[0], (7, 1)), qd, qdd))


BAD_STATES = [np.zeros(3), np.zeros((4, 3)), np.zeros((2, 2, 2)), np.float64(0.0), np.zeros((2, 1))]


@pytest.mark.parametrize("bad", BAD_STATES, ids=lambda a: str(np.shape(a)))
def test_bad_state_shapes_raise(bad, f_true):
    f = f_true
    ok = np.zeros(2)
    calls = [
        lambda: model.inertia_matrix(f, bad),
        lambda: model.coriolis_centrifugal(f, bad, ok),
        lambda: model.coriolis_centrifugal(f, ok, bad),
        lambda: model.gravity_vector(f, bad),
        lambda: model.inverse_dynamics(f, ok, ok, bad),
        lambda: model.forward_dynamics(f, ok, bad, ok),
        lambda: model.regressor(bad, ok, ok),
    ]
    for call in calls:
        with pytest.raises(ValueError, match=r"shape \(2,\) or \(n, 2\)"):
            call()


@pytest.mark.parametrize("bad_f", [np.zeros(8), np.zeros(10), np.zeros((9, 1)), np.zeros((1, 9))],
                         ids=lambda a: str(a.shape))
def test_bad_f_shape_raises(bad_f):
    ok = np.zeros(2)
    for call in (
        lambda: model.inertia_matrix(bad_f, ok),
        lambda: model.coriolis_centrifugal(bad_f, ok, ok),
        lambda: model.gravity_vector(bad_f, ok),
        lambda: model.inverse_dynamics(bad_f, ok, ok, ok),
        lambda: model.forward_dynamics(bad_f, ok, ok, ok),
        lambda: model.is_positive_definite(bad_f),
    ):
        with pytest.raises(ValueError, match=r"f must have shape \(9,\)"):
            call()


def test_mismatched_batch_lengths_raise(f_true):
    f = f_true
    with pytest.raises(ValueError):
        model.inverse_dynamics(f, np.zeros((3, 2)), np.zeros((4, 2)), np.zeros((3, 2)))
