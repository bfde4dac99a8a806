"""The casadi Lagrange derivation (plant.robot.symbolic) against the base-parameter model.

Shows that the dynamics derived from the physical parameters depend on them
only through the nine base parameters of eq. 3, that the model is linear in
f (regressor), that h follows from D by the Christoffel symbols, and that the
paper's eq. 2 *as printed* disagrees with the derivation.
"""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from plant.robot import symbolic

N = 256  # random states / parameter sets per check
RTOL = 1e-12


@pytest.fixture(scope="module")
def phys():
    return symbolic.derive_physical_model()


@pytest.fixture(scope="module")
def base():
    return symbolic.derive_base_model()


@pytest.fixture(scope="module")
def fbase():
    return symbolic.base_parameters_expr()


def _random_physical(rng, n):
    """(14, n) physical parameter sets of PUMA-like magnitude (both gear signs)."""
    sign = lambda: rng.choice([-1.0, 1.0], n)  # noqa: E731
    p = np.vstack(
        [
            rng.uniform(5, 25, n),  # m2
            rng.uniform(-0.4, 0.4, n),  # x2
            rng.uniform(-0.1, 0.1, n),  # y2
            rng.uniform(0.05, 1.0, n),  # Izz2
            rng.uniform(1e-4, 4e-4, n),  # Jm2
            sign() * rng.uniform(50, 120, n),  # k2
            rng.uniform(1, 8, n),  # m3
            rng.uniform(-0.05, 0.05, n),  # x3
            rng.uniform(-0.3, 0.0, n),  # y3
            rng.uniform(0.01, 0.3, n),  # Izz3
            rng.uniform(1e-4, 4e-4, n),  # Jm3
            sign() * rng.uniform(30, 80, n),  # k3
            rng.uniform(0.3, 0.5, n),  # a3
            rng.uniform(9.7, 9.9, n),  # g
        ]
    )
    assert p.shape == (len(symbolic.PHYSICAL_PARAMETER_NAMES), n)
    return p


def _random_states(rng, n):
    q = rng.uniform(-2 * np.pi, 2 * np.pi, (2, n))
    qd = rng.uniform(-4, 4, (2, n))
    qdd = rng.uniform(-20, 20, (2, n))
    return q, qd, qdd


def _eval(fun, *args, out=0):
    """Evaluate a casadi Function column-wise over n samples; returns (n, rows) or (n, rows, cols).

    Each argument is (rows, n) or (rows, 1) / scalar (broadcast to all samples).
    """
    n = max(np.shape(a)[-1] if np.ndim(a) == 2 else 1 for a in args)
    args = [np.broadcast_to(np.atleast_2d(a), (np.atleast_2d(a).shape[0], n)) for a in args]
    res = fun.map(n)(*args)
    res = np.asarray(res[out] if isinstance(res, (tuple, list)) else res)  # (rows, cols * n)
    r, c = fun.size_out(out)
    res = res.reshape(r, c, n, order="F").transpose(2, 0, 1)
    return res[:, :, 0] if c == 1 else res


def _close(a, b, scale):
    """|a - b| <= RTOL * max(1, scale), element-wise, with a helpful message."""
    scale = np.maximum(1.0, scale)
    err = np.max(np.abs(a - b) / scale)
    assert err <= RTOL, f"max scaled error {err:.3e} > {RTOL}"


def test_parameter_names():
    assert symbolic.PHYSICAL_PARAMETER_NAMES == (
        "m2", "x2", "y2", "Izz2", "Jm2", "k2", "m3", "x3", "y3", "Izz3", "Jm3", "k3", "a3", "g"
    )
    assert len(symbolic.BASE_PARAMETER_NAMES) == 9
    assert symbolic.GRAVITY_DIRECTION == (0.0, 1.0)


def test_derivation_is_cached(phys, base):
    assert symbolic.derive_physical_model() is phys
    assert symbolic.derive_base_model() is base
    assert symbolic.derive_base_model("corrected") is base


def test_unknown_variant_raises():
    with pytest.raises(ValueError, match="variant"):
        symbolic.derive_base_model("typo")


def test_base_parameters_eq3(fbase):
    rng = np.random.default_rng(1)
    p = _random_physical(rng, N)
    f = _eval(fbase, p)
    m2, x2, y2, izz2, jm2, k2, m3, x3, y3, izz3, jm3, k3, a3, _ = p
    expected = np.column_stack(
        [
            jm3 * k3**2 + izz3 + m3 * (x3**2 + y3**2),
            izz3 + m3 * (x3**2 + y3**2),
            m3 * x3 * a3,
            m3 * y3 * a3,
            m3 * x3,
            m3 * y3,
            jm2 * k2**2 + izz2 + m2 * (x2**2 + y2**2) + m3 * a3**2 + izz3 + m3 * (x3**2 + y3**2),
            m2 * y2,
            m2 * x2 + m3 * a3,
        ]
    )
    _close(f, expected, np.abs(expected))
    # physical consistency of eq. 3
    _close(f[:, 2], a3 * f[:, 4], np.abs(f[:, 2]))
    _close(f[:, 3], a3 * f[:, 5], np.abs(f[:, 3]))
    assert np.all(f[:, 0] - f[:, 1] > 0)


def test_h_independent_of_qdd(phys):
    q, qd, qdd = (ca.SX.sym(n, 2) for n in ("q", "qd", "qdd"))
    p = ca.SX.sym("p", 14)
    assert not ca.depends_on(phys.h(q, qd, qdd, p), qdd)
    assert not ca.depends_on(phys.D(q, qd, qdd, p), ca.vertcat(qd, qdd))
    assert not ca.depends_on(phys.g(q, qd, qdd, p), ca.vertcat(qd, qdd))
    # D depends on q3 only (numerically: the graph holds cos^2 q2 + sin^2 q2)
    rng = np.random.default_rng(9)
    pn = _random_physical(rng, N)
    qn, qdn, qddn = _random_states(rng, N)
    D1 = _eval(phys.D, qn, qdn, qddn, pn)
    D2 = _eval(phys.D, qn + np.array([[1.234], [0.0]]), qdn, qddn, pn)
    _close(D1, D2, np.abs(D1))


def test_physical_equals_base_model(phys, base, fbase):
    """Lagrange from the physical parameters == eq. 2 (corrected) with f = eq. 3."""
    rng = np.random.default_rng(2)
    p = _random_physical(rng, N)
    q, qd, qdd = _random_states(rng, N)
    f = _eval(fbase, p).T
    grav = p[13:14]
    tau_p = _eval(phys.tau, q, qd, qdd, p)
    D_p = _eval(phys.D, q, qd, qdd, p)
    h_p = _eval(phys.h, q, qd, qdd, p)
    g_p = _eval(phys.g, q, qd, qdd, p)
    Y = _eval(base.Y, f, q, qd, qdd, grav)
    scale = np.einsum("nij,jn->ni", np.abs(Y), np.abs(f))  # sum of |terms| of tau
    _close(tau_p, _eval(base.tau, f, q, qd, qdd, grav), scale)
    _close(D_p, _eval(base.D, f, q, qd, qdd, grav), np.abs(f).max(0)[:, None, None])
    _close(h_p, _eval(base.h, f, q, qd, qdd, grav), scale)
    _close(g_p, _eval(base.g, f, q, qd, qdd, grav), scale)
    # Lagrange's tau is affine in qdd with coefficient D: tau = D qdd + h + g
    _close(tau_p, np.einsum("nij,jn->ni", D_p, qdd) + h_p + g_p, scale)


def test_physical_model_symmetric_pd(phys):
    rng = np.random.default_rng(3)
    p = _random_physical(rng, N)
    q, qd, qdd = _random_states(rng, N)
    D = _eval(phys.D, q, qd, qdd, p)
    np.testing.assert_array_equal(D, D.transpose(0, 2, 1))
    assert np.all(np.linalg.eigvalsh(D)[:, 0] > 0)


def test_regressor_is_jacobian_and_independent_of_f(base):
    f, q, qd, qdd, g = (ca.SX.sym(n, k) for n, k in
                        (("f", 9), ("q", 2), ("qd", 2), ("qdd", 2), ("g", 1)))
    Y = base.Y(f, q, qd, qdd, g)
    assert Y.shape == (2, 9)
    assert not ca.depends_on(Y, f)  # tau is linear in f ...
    tau = base.tau(f, q, qd, qdd, g)
    # ... and homogeneous: tau(f=0) == 0, so tau == Y f exactly
    assert ca.substitute(tau, f, ca.DM.zeros(9)).is_zero()
    rng = np.random.default_rng(4)
    fn = rng.uniform(-3, 3, (9, N))
    qn, qdn, qddn = _random_states(rng, N)
    Yn = _eval(base.Y, fn, qn, qdn, qddn, 9.81)
    scale = np.einsum("nij,jn->ni", np.abs(Yn), np.abs(fn))
    _close(np.einsum("nij,jn->ni", Yn, fn), _eval(base.tau, fn, qn, qdn, qddn, 9.81), scale)


def test_forward_inverts_tau(base):
    rng = np.random.default_rng(5)
    p = _random_physical(rng, N)
    f = _eval(symbolic.base_parameters_expr(), p).T
    q, qd, qdd = _random_states(rng, N)
    tau = _eval(base.tau, f, q, qd, qdd, 9.81).T
    qdd2 = _eval(base.forward, f, q, qd, tau, 9.81).T
    D = _eval(base.D, f, q, qd, qdd, 9.81)
    cond = np.linalg.cond(D)
    assert np.all(np.abs(qdd2 - qdd) <= 1e-12 * cond * np.maximum(1, np.abs(tau).max(0)))


def test_christoffel_coriolis_matrix(base):
    """h == C(q, qd) qd with C from the Christoffel symbols of D; dD/dt - 2C skew."""
    Cf = symbolic.derive_coriolis_matrix()
    rng = np.random.default_rng(6)
    f = rng.uniform(-3, 3, (9, N))
    q, qd, qdd = _random_states(rng, N)
    C = _eval(Cf, f, q, qd)
    Ddot = _eval(Cf, f, q, qd, out=1)
    h = _eval(base.h, f, q, qd, qdd, 9.81)
    scale = np.abs(f).max(0)[:, None] * (np.abs(qd).max(0) ** 2)[:, None]
    _close(np.einsum("nij,jn->ni", C, qd), h, scale)
    N_ = Ddot - 2 * C
    _close(N_ + N_.transpose(0, 2, 1), 0 * N_, scale[:, :, None])


def _max_rel_diff(a, b):
    return np.max(np.abs(a - b)) / max(1.0, np.max(np.abs(b)))


@pytest.mark.parametrize("variant", ["printed", "printed_D11", "printed_h2"])
def test_printed_eq2_disagrees_with_lagrange(phys, fbase, variant):
    """The equation as printed cannot be the Lagrange model of eq. 3's parameters."""
    printed = symbolic.derive_base_model(variant)
    rng = np.random.default_rng(7)
    p = _random_physical(rng, N)
    f = _eval(fbase, p).T
    q, qd, qdd = _random_states(rng, N)
    tau_p = _eval(phys.tau, q, qd, qdd, p)
    tau_pr = _eval(printed.tau, f, q, qd, qdd, p[13:14])
    assert _max_rel_diff(tau_pr, tau_p) > 1e-2
    if variant in ("printed", "printed_D11"):
        # D11 printed with f1: off by f7 - f1, which is the whole link-2 side
        D_pr = _eval(printed.D, f, q, qd, qdd, 9.81)
        D_p = _eval(phys.D, q, qd, qdd, p)
        np.testing.assert_allclose(D_p[:, 0, 0] - D_pr[:, 0, 0], f[6] - f[0], rtol=1e-12)
    if variant in ("printed", "printed_h2"):
        # printed h2 is not C(q, qd) qd for the Christoffel C of D
        Cf = symbolic.derive_coriolis_matrix(variant)
        C = _eval(Cf, f, q, qd)
        h_pr = _eval(printed.h, f, q, qd, qdd, 9.81)
        assert _max_rel_diff(np.einsum("nij,jn->ni", C, qd)[:, 1], h_pr[:, 1]) > 1e-2


def test_printed_h2_hides_at_q3_quarter_pi_only(phys, base, fbase):
    """At q3 = pi/4 sin q3 == cos q3, so the h2 misprint is invisible there; elsewhere not."""
    p = _random_physical(np.random.default_rng(8), 1)
    f = _eval(fbase, p).T
    q = np.array([[0.3], [np.pi / 4]])
    qd = np.array([[1.5], [0.0]])
    printed_h2 = symbolic.derive_base_model("printed_h2")
    h_p = _eval(phys.h, q, qd, 0 * qd, p)
    scale = np.abs(f).max() * 1.5**2
    _close(_eval(printed_h2.h, f, q, qd, 0 * qd, 9.81), h_p, scale)
    _close(_eval(base.h, f, q, qd, 0 * qd, 9.81), h_p, scale)
    q[1] = 0.3  # away from pi/4 the printed h2 is wrong
    h_p = _eval(phys.h, q, qd, 0 * qd, p)
    _close(_eval(base.h, f, q, qd, 0 * qd, 9.81), h_p, scale)
    assert abs(_eval(printed_h2.h, f, q, qd, 0 * qd, 9.81)[0, 1] - h_p[0, 1]) > 1e-3
