"""Tests of plant.robot.payload: casadi derivation from eq. 3, closed form, inverse."""
from __future__ import annotations

import dataclasses
from fractions import Fraction

import casadi as ca
import numpy as np
import pytest

from plant.robot.payload import (
    LINK_PARAMETER_NAMES,
    Payload,
    add_payload,
    delta_from_payload_vector,
    payload_delta,
    payload_delta_function,
    payload_delta_matrix,
    payload_derivation_function,
    payload_from_vector,
    payload_vector,
    payload_vector_from_delta,
    recover_payload,
)

A3 = 0.4318
N_RANDOM = 50


# ---------------------------------------------------------------- helpers
def random_link(rng):
    """Random physical link parameters, ordered as LINK_PARAMETER_NAMES."""
    return np.array([
        rng.uniform(1e-4, 5e-4), rng.uniform(50, 120) * rng.choice([-1, 1]),   # Jm2, k2
        rng.uniform(1e-4, 5e-4), rng.uniform(30, 80) * rng.choice([-1, 1]),    # Jm3, k3
        rng.uniform(5, 20), rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3),    # m2, x2, y2
        rng.uniform(0.05, 1.0),                                                # Izz2
        rng.uniform(1, 10), rng.uniform(-0.3, 0.3), rng.uniform(-0.3, 0.3),    # m3, x3, y3
        rng.uniform(0.01, 0.5),                                                # Izz3
    ])


def random_payload(rng):
    izz = 0.0 if rng.random() < 0.2 else rng.uniform(0.0, 0.05)
    return Payload(rng.uniform(0.05, 5.0), tuple(rng.uniform(-0.6, 0.6, 2)), izz)


def closed_form(m, xp, yp, izz, a3):
    """The expected Δf, written out by hand (the issue's formulas)."""
    j = izz + m * (xp**2 + yp**2)
    return [j, j, m * xp * a3, m * yp * a3, m * xp, m * yp, m * a3**2 + j, 0, m * a3]


_BINARY = {
    ca.OP_ADD: lambda a, b: a + b,
    ca.OP_SUB: lambda a, b: a - b,
    ca.OP_MUL: lambda a, b: a * b,
    ca.OP_DIV: lambda a, b: a / b,
}
_UNARY = {
    ca.OP_ASSIGN: lambda a: a,
    ca.OP_NEG: lambda a: -a,
    ca.OP_SQ: lambda a: a * a,
    ca.OP_TWICE: lambda a: 2 * a,
}


def eval_graph(fn, inputs, const=Fraction):
    """Evaluate an SXFunction's instruction graph on arbitrary scalar objects.

    ``inputs`` holds one list of scalars per function input (its nonzeros);
    the arithmetic is done by the scalar type itself, e.g. exact rationals
    (``fractions.Fraction``) or sympy symbols.  Returns one list per output.
    """
    work = {}
    out = [[None] * fn.nnz_out(i) for i in range(fn.n_out())]
    for k in range(fn.n_instructions()):
        op = fn.instruction_id(k)
        i_in, i_out = fn.instruction_input(k), fn.instruction_output(k)
        if op == ca.OP_INPUT:
            work[i_out[0]] = inputs[i_in[0]][i_in[1]]
        elif op == ca.OP_OUTPUT:
            out[i_out[0]][i_out[1]] = work[i_in[0]]
        elif op == ca.OP_CONST:
            work[i_out[0]] = const(fn.instruction_constant(k))
        elif op in _BINARY:
            work[i_out[0]] = _BINARY[op](work[i_in[0]], work[i_in[1]])
        elif op in _UNARY:
            work[i_out[0]] = _UNARY[op](work[i_in[0]])
        else:  # pragma: no cover - would need a new op in the evaluator
            raise NotImplementedError(f"casadi op {op}")
    return out


def rational(x):
    return Fraction(x).limit_denominator(10**6)


# ------------------------------------------------- casadi derivation = closed form
def test_derivation_equals_closed_form_at_random_points():
    rng = np.random.default_rng(1)
    deriv = payload_derivation_function()
    dfun = payload_delta_function()
    for _ in range(N_RANDOM):
        link, pl = random_link(rng), random_payload(rng)
        a3 = rng.uniform(0.2, 0.8)
        pay = [pl.mass_kg, *pl.com_m, pl.izz_kgm2]
        f0, f1, delta = (np.array(v).ravel() for v in deriv(link, pay, a3))
        expected = payload_delta(pl, a3)
        np.testing.assert_allclose(delta, expected, rtol=0, atol=1e-12)
        np.testing.assert_allclose(f1 - f0, expected, rtol=0, atol=1e-12)
        np.testing.assert_allclose(f1, add_payload(f0, pl, a3), rtol=0, atol=1e-12)
        np.testing.assert_allclose(np.array(dfun(*pay, a3)).ravel(), expected, rtol=0, atol=1e-12)
        np.testing.assert_allclose(expected, closed_form(*pay, a3), rtol=0, atol=1e-15)


def test_expected_components():
    pl = Payload(1.5, (0.1, -0.05), 0.01)
    d = payload_delta(pl, A3)
    j = 0.01 + 1.5 * (0.1**2 + 0.05**2)
    assert d[7] == 0.0                                # f8 unaffected
    assert d[8] == pytest.approx(1.5 * A3, abs=1e-15)  # Δf9 = m a3
    assert d[0] == d[1] == pytest.approx(j, abs=1e-15)
    assert d[6] - d[1] == pytest.approx(1.5 * A3**2, abs=1e-15)
    assert d.shape == (9,)


def test_derivation_exact_in_rational_arithmetic():
    """Exact evaluation of the casadi graph: Δf equals the closed form exactly."""
    rng = np.random.default_rng(2)
    deriv = payload_derivation_function()
    dfun = payload_delta_function()
    for _ in range(10):
        link = [rational(v) for v in random_link(rng)]
        m, xp, yp, izz, a3 = (rational(v) for v in (
            rng.uniform(0.05, 5), *rng.uniform(-0.6, 0.6, 2), rng.uniform(0, 0.05), rng.uniform(0.2, 0.8)))
        expected = closed_form(m, xp, yp, izz, a3)
        _, _, delta = eval_graph(deriv, [link, [m, xp, yp, izz], [a3]])
        assert delta == expected
        (delta2,) = eval_graph(dfun, [[m], [xp], [yp], [izz], [a3]])
        assert delta2 == expected


# ---------------------------------------------------- independence of the link
def test_delta_independent_of_link_symbolically():
    """sympy simplification of the casadi graph: no link symbol survives."""
    sp = pytest.importorskip("sympy")
    link = sp.symbols(" ".join(LINK_PARAMETER_NAMES), real=True)
    m, xp, yp, izz, a3 = sp.symbols("m xp yp izz_p a3", real=True)
    _, _, delta = eval_graph(payload_derivation_function(),
                             [list(link), [m, xp, yp, izz], [a3]], const=sp.nsimplify)
    for got, want in zip(delta, closed_form(m, xp, yp, izz, a3)):
        got = sp.cancel(sp.together(got))
        assert not (got.free_symbols & set(link))
        assert sp.expand(got - want) == 0


def test_delta_independent_of_link_numerically():
    rng = np.random.default_rng(3)
    deriv = payload_derivation_function()
    link = ca.SX.sym("link", len(LINK_PARAMETER_NAMES))
    pay = ca.SX.sym("pay", 4)
    a3 = ca.SX.sym("a3")
    _, _, delta = deriv(link, pay, a3)
    jac = ca.Function("dlink", [link, pay, a3], [ca.jacobian(delta, link)])
    for _ in range(N_RANDOM):
        pl = random_payload(rng)
        pay_v = [pl.mass_kg, *pl.com_m, pl.izz_kgm2]
        a3_v = rng.uniform(0.2, 0.8)
        J = np.array(jac(random_link(rng), pay_v, a3_v))
        assert J.shape == (9, len(LINK_PARAMETER_NAMES))
        assert np.max(np.abs(J)) < 1e-12
        # same Δf for two different robots
        d1 = np.array(deriv(random_link(rng), pay_v, a3_v)[2]).ravel()
        d2 = np.array(deriv(random_link(rng), pay_v, a3_v)[2]).ravel()
        np.testing.assert_allclose(d1, d2, rtol=0, atol=1e-12)


# ------------------------------------------------------------------ linearity
def test_linear_in_payload_vector():
    rng = np.random.default_rng(4)
    for _ in range(N_RANDOM):
        p, q = rng.normal(size=4), rng.normal(size=4)
        a, b = rng.normal(size=2)
        a3 = rng.uniform(0.2, 0.8)
        lhs = delta_from_payload_vector(a * p + b * q, a3)
        rhs = a * delta_from_payload_vector(p, a3) + b * delta_from_payload_vector(q, a3)
        np.testing.assert_allclose(lhs, rhs, rtol=0, atol=1e-12)
        pl = random_payload(rng)
        np.testing.assert_allclose(payload_delta(pl, a3),
                                   payload_delta_matrix(a3) @ payload_vector(pl), rtol=0, atol=1e-15)


def test_casadi_delta_is_linear_in_payload_vector():
    """The casadi Δf, written in p = [m, m xp, m yp, J], has Jacobian A(a3)."""
    rng = np.random.default_rng(5)
    dfun = payload_delta_function()
    for _ in range(10):
        pl, a3 = random_payload(rng), rng.uniform(0.2, 0.8)
        m, (xp, yp), izz = pl.mass_kg, pl.com_m, pl.izz_kgm2
        # d(Δf)/d(m, xp, yp, izz) = A(a3) d(p)/d(m, xp, yp, izz)
        x = ca.SX.sym("x", 4)
        a3s = ca.SX.sym("a3")
        d = dfun(x[0], x[1], x[2], x[3], a3s)
        jd = np.array(ca.Function("j", [x, a3s], [ca.jacobian(d, x)])([m, xp, yp, izz], a3))
        jp = np.array([[1, 0, 0, 0],
                       [xp, m, 0, 0],
                       [yp, 0, m, 0],
                       [xp**2 + yp**2, 2 * m * xp, 2 * m * yp, 1]])
        np.testing.assert_allclose(jd, payload_delta_matrix(a3) @ jp, rtol=0, atol=1e-12)


def test_delta_batch_shape():
    rng = np.random.default_rng(6)
    P = rng.normal(size=(7, 4))
    D = delta_from_payload_vector(P, A3)
    assert D.shape == (7, 9)
    for row_p, row_d in zip(P, D):
        np.testing.assert_allclose(row_d, delta_from_payload_vector(row_p, A3), atol=1e-15)


# --------------------------------------------------------------- round trip
def test_add_then_recover_gives_same_payload():
    rng = np.random.default_rng(7)
    for _ in range(200):
        f = rng.uniform(-2, 10, 9)
        pl = random_payload(rng)
        a3 = rng.uniform(0.2, 0.8)
        back = recover_payload(add_payload(f, pl, a3), f, a3)
        assert back.mass_kg == pytest.approx(pl.mass_kg, rel=1e-10)
        np.testing.assert_allclose(back.com_m, pl.com_m, rtol=0, atol=1e-10)
        assert back.izz_kgm2 == pytest.approx(pl.izz_kgm2, abs=1e-10)


def test_round_trip_point_mass_and_vector():
    pl = Payload(2.0, (0.1, 0.0))  # izz 0: recovered Izz_p may round to -eps
    f = np.linspace(1, 2, 9)
    back = recover_payload(add_payload(f, pl, A3), f, A3)
    assert back.izz_kgm2 >= 0.0 and back.izz_kgm2 == pytest.approx(0.0, abs=1e-12)
    p = payload_vector(pl)
    np.testing.assert_allclose(payload_vector(payload_from_vector(p)), p, atol=1e-15)


def test_estimator_is_scaled_least_squares():
    """The documented estimator equals lstsq of the kg-scaled equations."""
    rng = np.random.default_rng(8)
    for _ in range(20):
        a3 = rng.uniform(0.2, 0.8)
        d = rng.normal(size=9)
        rows = [0, 1, 2, 3, 4, 5, 6, 8]            # Δf8 carries no information
        w = np.array([a3**-2, a3**-2, a3**-2, a3**-2, a3**-1, a3**-1, a3**-2, a3**-1])
        S = np.diag([1, a3, a3, a3**2])             # p = S q
        A = payload_delta_matrix(a3)[rows] @ S * w[:, None]
        q = np.linalg.lstsq(A, d[rows] * w, rcond=None)[0]
        np.testing.assert_allclose(payload_vector_from_delta(d, a3), S @ q, rtol=1e-12, atol=1e-12)
        # Δf8 is ignored
        d2 = d.copy()
        d2[7] += 5.0
        np.testing.assert_allclose(payload_vector_from_delta(d2, a3), payload_vector_from_delta(d, a3))


# ----------------------------------------------------------------- Payload
def test_payload_properties():
    pl = Payload(2, [0.1, -0.2], 0.03)
    assert pl.com_m == (0.1, -0.2) and isinstance(pl.mass_kg, float)
    np.testing.assert_allclose(pl.first_moments, [0.2, -0.4])
    assert pl.inertia_about_joint3 == pytest.approx(0.03 + 2 * 0.05)
    assert pl.to_dict() == {"mass_kg": 2.0, "com_m": [0.1, -0.2], "izz_kgm2": 0.03}
    with pytest.raises(dataclasses.FrozenInstanceError):
        pl.mass_kg = 3.0
    assert Payload(0.0, (0, 0)).izz_kgm2 == 0.0  # zero mass is a valid (empty) payload
    np.testing.assert_array_equal(payload_delta(Payload(0.0, (0.3, 0.1)), A3), np.zeros(9))


# ------------------------------------------------------------------- errors
@pytest.mark.parametrize("args", [
    (-1.0, (0, 0), 0.0),
    (float("nan"), (0, 0), 0.0),
    (float("inf"), (0, 0), 0.0),
    ("heavy", (0, 0), 0.0),
    (1.0, (0, 0, 0), 0.0),
    (1.0, (0,), 0.0),
    (1.0, 0.1, 0.0),
    (1.0, (float("nan"), 0), 0.0),
    (1.0, (0, 0), -1e-3),
    (1.0, (0, 0), float("inf")),
])
def test_payload_validation(args):
    with pytest.raises(ValueError) as exc:
        Payload(*args)
    assert "\n" not in str(exc.value)


def test_bad_inputs():
    pl = Payload(1.0, (0.1, 0.0), 0.01)
    f = np.ones(9)
    for a3 in (0.0, -0.4, float("nan"), "x"):
        with pytest.raises(ValueError):
            payload_delta(pl, a3)
    with pytest.raises(ValueError):
        payload_delta((1.0, (0, 0), 0), A3)
    with pytest.raises(ValueError):
        add_payload(np.ones(8), pl, A3)
    with pytest.raises(ValueError):
        add_payload(np.r_[np.ones(8), np.nan], pl, A3)
    with pytest.raises(ValueError):
        delta_from_payload_vector(np.ones(3), A3)
    with pytest.raises(ValueError):
        delta_from_payload_vector([1, 2, np.inf, 4], A3)
    with pytest.raises(ValueError):
        recover_payload(f, np.ones(10), A3)
    with pytest.raises(ValueError):
        payload_from_vector([1, 2, 3])


def test_recover_without_payload_raises():
    f = np.linspace(0.5, 3, 9)
    with pytest.raises(ValueError, match="mass"):
        recover_payload(f, f, A3)                    # m = 0: no payload
    f_neg = add_payload(f, Payload(1.0, (0.0, 0.0)), A3)
    with pytest.raises(ValueError, match="mass"):
        recover_payload(f, f_neg, A3)                # m < 0: payload removed


def test_negative_inertia_raises_or_clips():
    p = [1.0, 0.3, 0.0, 0.05]                         # J < (m xp)^2 / m = 0.09
    with pytest.raises(ValueError, match="inertia"):
        payload_from_vector(p)
    pl = payload_from_vector(p, clip_negative_inertia=True)
    assert pl.izz_kgm2 == 0.0 and pl.mass_kg == 1.0 and pl.com_m == (0.3, 0.0)
    f = np.zeros(9)
    with pytest.raises(ValueError, match="inertia"):
        recover_payload(delta_from_payload_vector(p, A3), f, A3)
    assert recover_payload(delta_from_payload_vector(p, A3), f, A3,
                           clip_negative_inertia=True).izz_kgm2 == 0.0
