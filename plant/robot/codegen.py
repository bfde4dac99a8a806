"""Numeric code generated from casadi expressions: straight-line Python for numba.

The compiled closed-loop core (:mod:`plant.simulation.core`) evaluates a robot's
dynamics millions of times per identification, inside SIMD loops over
candidates where no array may be allocated and no Python object touched.
:func:`function_source` turns a casadi ``SX`` :class:`casadi.Function`
into the source of a plain Python function of scalars and tuples -- one
assignment per casadi instruction, casadi's common subexpressions kept --
that numba compiles like hand-written code.  :mod:`plant.simulation.arm` generates the
right-hand side of a robot model's rigid arm with it.

The translation walks the function's algorithm (``n_instructions``,
``instruction_id``, ``instruction_input``, ``instruction_output``,
``instruction_constant``: casadi's documented interface to an SX function's
instruction list) and supports the operations a robot's dynamics use
(arithmetic, powers, square roots, trigonometric and hyperbolic functions,
absolute value, sign, min and max).

:func:`multiple_angle_form` is a simplification pass before it: a
polynomial in the sines and cosines of the joint angles (the Newton--Euler
model written in ``s = sin q``, ``c = cos q``) rewritten as a trigonometric
polynomial in multiple angles, ``sum_k a_k(x) cos(k . q) + b_k(x) sin(k . q)``
with integer vectors k, by the product-to-sum identities.  That form is
canonical (``s^2 + c^2 = 1`` and the angle-sum identities are built in), so
terms that cancel in the model cancel in the code; for the arms of a few
joints it is several times shorter than the Newton--Euler graph
(:func:`plant.simulation.arm.arm_plant` keeps the shorter of the two).
"""
from __future__ import annotations

import math

import casadi as ca

__all__ = ["function_source", "multiple_angle_form", "PRUNE_RELATIVE", "UnsupportedOperation"]


class UnsupportedOperation(ValueError):
    """A casadi instruction that :func:`function_source` cannot translate."""


def _unary(fmt):
    return lambda a: fmt.format(a=a)


def _binary(fmt):
    return lambda a, b: fmt.format(a=a, b=b)


_UNARY = {
    ca.OP_ASSIGN: _unary("{a}"),
    ca.OP_NEG: _unary("-{a}"),
    ca.OP_SQ: _unary("{a} * {a}"),
    ca.OP_TWICE: _unary("2.0 * {a}"),
    ca.OP_INV: _unary("1.0 / {a}"),
    ca.OP_SQRT: _unary("math.sqrt({a})"),
    ca.OP_EXP: _unary("math.exp({a})"),
    ca.OP_LOG: _unary("math.log({a})"),
    ca.OP_SIN: _unary("math.sin({a})"),
    ca.OP_COS: _unary("math.cos({a})"),
    ca.OP_TAN: _unary("math.tan({a})"),
    ca.OP_ASIN: _unary("math.asin({a})"),
    ca.OP_ACOS: _unary("math.acos({a})"),
    ca.OP_ATAN: _unary("math.atan({a})"),
    ca.OP_SINH: _unary("math.sinh({a})"),
    ca.OP_COSH: _unary("math.cosh({a})"),
    ca.OP_TANH: _unary("math.tanh({a})"),
    ca.OP_FABS: _unary("abs({a})"),
    ca.OP_SIGN: _unary("(1.0 if {a} > 0.0 else (-1.0 if {a} < 0.0 else 0.0))"),
}
_BINARY = {
    ca.OP_ADD: _binary("{a} + {b}"),
    ca.OP_SUB: _binary("{a} - {b}"),
    ca.OP_MUL: _binary("{a} * {b}"),
    ca.OP_DIV: _binary("{a} / {b}"),
    ca.OP_POW: _binary("{a} ** {b}"),
    ca.OP_CONSTPOW: _binary("{a} ** {b}"),
    ca.OP_ATAN2: _binary("math.atan2({a}, {b})"),
    ca.OP_FMIN: _binary("min({a}, {b})"),
    ca.OP_FMAX: _binary("max({a}, {b})"),
}


def function_source(fn: ca.Function, name: str, indent: str = "    ") -> tuple:
    """Body of a straight-line evaluation of an SX function, as Python source lines.

    The generated lines read the inputs as ``in0, in1, ...`` (each a tuple
    or sequence of the input's nonzeros, column-major) and assign the
    outputs' nonzeros to the scalars ``out{i}_{k}``.

    Parameters
    ----------
    fn : casadi.Function
        An SX function (``fn.is_a("SXFunction")``); outputs should be dense
        (``casadi.densify``), otherwise structural zeros get ``0.0``.
    name : str
        Prefix of the work variables (keeps several generated blocks apart
        in one function).
    indent : str
        Prefix of every line.

    Returns
    -------
    lines : list of str
        The assignments, in casadi's evaluation order.
    outputs : list of list of str
        ``outputs[i][k]``: the variable holding nonzero k of output i.

    Raises
    ------
    UnsupportedOperation
        For an operation outside the supported set (e.g. a call node or a
        conditional).
    ValueError
        If ``fn`` is not an SX function.
    """
    if not fn.is_a("SXFunction"):
        raise ValueError(f"function_source needs an SX function, got {fn.class_name()}")
    lines = []
    outputs = [[f"{name}_o{i}_{k}" for k in range(fn.nnz_out(i))] for i in range(fn.n_out())]
    assigned = set()
    for k in range(fn.n_instructions()):
        op = fn.instruction_id(k)
        ins = fn.instruction_input(k)
        outs = fn.instruction_output(k)
        if op == ca.OP_INPUT:
            lines.append(f"{indent}{name}_w{outs[0]} = in{ins[0]}[{ins[1]}]")
        elif op == ca.OP_OUTPUT:
            var = outputs[outs[0]][outs[1]]
            lines.append(f"{indent}{var} = {name}_w{ins[0]}")
            assigned.add(var)
        elif op == ca.OP_CONST:
            v = float(fn.instruction_constant(k))
            text = repr(v) if math.isfinite(v) else f"float({str(v)!r})"
            lines.append(f"{indent}{name}_w{outs[0]} = {text}")
        elif op in _UNARY:
            lines.append(f"{indent}{name}_w{outs[0]} = {_UNARY[op](f'{name}_w{ins[0]}')}")
        elif op in _BINARY:
            lines.append(f"{indent}{name}_w{outs[0]} = "
                         f"{_BINARY[op](f'{name}_w{ins[0]}', f'{name}_w{ins[1]}')}")
        else:
            raise UnsupportedOperation(f"casadi operation {op} is not supported by the code generator")
    for out in outputs:
        for var in out:
            if var not in assigned:
                lines.append(f"{indent}{var} = 0.0")
    return lines, outputs


# ----------------------------------------------------------------------------- multiple angles
#: Terms whose coefficient is below this fraction of the largest in the same
#: intermediate polynomial are dropped: the rounding of the model's constants
#: (``cos(pi / 2) = 6.1e-17`` in a DH rotation), not terms of the model.  The
#: coefficients are compared across monomials, so this assumes they are of like
#: size: in a robot's dynamics, whose other symbols are rates, accelerations and
#: parameters, they are products of its lengths, gear ratios and gravity, within a
#: few decades of one another (a term 1e-12 of its neighbours would need lengths
#: of micrometres).  (Pruning per monomial would keep a monomial made of rounding
#: alone: PUMA 560 joints 1-3 then grow past the Newton--Euler graph.)
PRUNE_RELATIVE = 1e-12


class _TooLong(Exception):
    """An intermediate polynomial grew beyond ``max_terms``."""


def _normalised(k):
    """``(k, +1)`` or ``(-k, -1)``: the vector whose first nonzero entry is positive."""
    for v in k:
        if v:
            return (k, 1) if v > 0 else (tuple(-x for x in k), -1)
    return k, 1


def _accumulate(out, key, v):
    out[key] = out.get(key, 0.0) + v


def _product(A, B, limit=None):
    """Product of two trigonometric polynomials (dicts ``(k, kind, monomial) -> coefficient``).

    Raises :class:`_TooLong` as soon as the product holds more than ``limit`` terms.
    """
    out = {}
    for (ka, ta, ma), va in A.items():
        if limit is not None and len(out) > limit:
            raise _TooLong
        for (kb, tb, mb), vb in B.items():
            v = 0.5 * va * vb
            m = tuple(sorted(ma + mb)) if ma and mb else (ma or mb)
            kp, sp = _normalised(tuple(x + y for x, y in zip(ka, kb)))
            km, sm = _normalised(tuple(x - y for x, y in zip(ka, kb)))
            if ta == 0 and tb == 0:    # cos a cos b = (cos(a - b) + cos(a + b)) / 2
                _accumulate(out, (km, 0, m), v)
                _accumulate(out, (kp, 0, m), v)
            elif ta == 1 and tb == 1:  # sin a sin b = (cos(a - b) - cos(a + b)) / 2
                _accumulate(out, (km, 0, m), v)
                _accumulate(out, (kp, 0, m), -v)
            else:                      # sin a cos b = (sin(a + b) + sin(a - b)) / 2
                sign = 1.0 if ta == 1 else -1.0
                if any(kp):
                    _accumulate(out, (kp, 1, m), sp * v)
                if any(km):
                    _accumulate(out, (km, 1, m), sign * sm * v)
    return out


def _combination(A, B, b):
    out = dict(A)
    for key, v in B.items():
        _accumulate(out, key, b * v)
    return out


def _pruned(P):
    if not P:
        return P
    big = max(abs(v) for v in P.values())
    return {key: v for key, v in P.items() if abs(v) > PRUNE_RELATIVE * big}


def multiple_angle_form(expr, s, c, symbols, *, max_terms=None):
    """A polynomial in sines and cosines rewritten in multiple angles, or None.

    ``expr`` must be built from ``s = (sin q_1, ..., sin q_n)``,
    ``c = (cos q_1, ..., cos q_n)``, the other symbols and constants by
    sums, differences and products only (a rigid arm's inverse dynamics in
    :meth:`plant.RobotModel` form are).  Each entry is expanded into terms
    ``a x^m cos(k . q)`` and ``a x^m sin(k . q)`` (``x`` the other symbols,
    k an integer vector whose first nonzero entry is positive) by the
    product-to-sum identities ``cos a cos b = (cos(a - b) + cos(a + b)) / 2``,
    ``sin a sin b = (cos(a - b) - cos(a + b)) / 2``, ``sin a cos b =
    (sin(a + b) + sin(a - b)) / 2``; like terms are summed and terms below
    :data:`PRUNE_RELATIVE` of the largest dropped.  The result is rebuilt
    with each ``cos(k . q)``, ``sin(k . q)`` computed once from ``s`` and
    ``c`` by angle addition, the terms grouped by angle, and casadi's common
    subexpressions eliminated.

    Parameters
    ----------
    expr : casadi.SX
        Column of the expressions, shape (p, 1).
    s, c : casadi.SX
        The sine and cosine symbols, shape (n, 1) each.
    symbols : sequence of casadi.SX
        The other symbols ``expr`` may contain (e.g. rates, accelerations,
        parameters), each a column of symbols.
    max_terms : int, optional
        Give up (return None) as soon as an intermediate expression has more
        terms: the form is not worth it for this expression (e.g. six joints,
        where the Newton--Euler graph shares far more than the expanded sum;
        the product that crosses the bound is abandoned as it does).

    Returns
    -------
    casadi.SX or None
        The same expressions, shape (p, 1) (equal to rounding); None if
        ``expr`` holds another operation (division, a function) or a
        non-finite constant, or grows beyond ``max_terms``.

    Raises
    ------
    ValueError
        If ``expr`` is not a column, or ``s`` and ``c`` differ in length.
    RuntimeError
        From casadi, if ``expr`` holds a symbol that is not in ``s``, ``c``
        or ``symbols``.

    Notes
    -----
    The expansion is exact polynomial algebra on the coefficients; only the
    pruning drops anything.  It is the "customised symbolic model" idea of
    W. Khalil and E. Dombre, *Modeling, Identification and Control of
    Robots* (2002), ch. 9 -- write the model in the fewest operations -- by
    the trigonometric canonical form rather than by rules.
    """
    n = int(s.numel())
    if int(c.numel()) != n:
        raise ValueError(f"multiple_angle_form needs as many cosines as sines, got {c.numel()} and {n}")
    if expr.shape[1] != 1:
        raise ValueError(f"multiple_angle_form needs a column of expressions, got shape {expr.shape}")
    syms = [s, c] + list(symbols)
    fn = ca.Function("multiple_angle_form", syms, [ca.densify(expr)])
    offsets = [0]
    for sym in symbols:
        offsets.append(offsets[-1] + int(sym.numel()))
    zero = (0,) * n
    unit = [tuple(1 if t == j else 0 for t in range(n)) for j in range(n)]
    work, out = {}, [{} for _ in range(fn.nnz_out(0))]
    for k in range(fn.n_instructions()):
        op, ins, outs = fn.instruction_id(k), fn.instruction_input(k), fn.instruction_output(k)
        if op == ca.OP_INPUT:
            i, j = ins[0], ins[1]
            value = ({(unit[j], 1 if i == 0 else 0, ()): 1.0} if i < 2 else
                     {(zero, 0, (offsets[i - 2] + j,)): 1.0})
        elif op == ca.OP_CONST:
            v = float(fn.instruction_constant(k))
            if not math.isfinite(v):
                return None
            value = {(zero, 0, ()): v} if v else {}
        elif op == ca.OP_OUTPUT:
            out[outs[1]] = work[ins[0]]
            continue
        elif op == ca.OP_ASSIGN:
            value = work[ins[0]]
        elif op == ca.OP_ADD:
            value = _combination(work[ins[0]], work[ins[1]], 1.0)
        elif op == ca.OP_SUB:
            value = _combination(work[ins[0]], work[ins[1]], -1.0)
        elif op == ca.OP_NEG:
            value = {key: -v for key, v in work[ins[0]].items()}
        elif op == ca.OP_TWICE:
            value = {key: 2.0 * v for key, v in work[ins[0]].items()}
        elif op in (ca.OP_MUL, ca.OP_SQ):
            b = work[ins[1]] if op == ca.OP_MUL else work[ins[0]]
            try:
                value = _product(work[ins[0]], b, max_terms)
            except _TooLong:
                return None
        else:
            return None
        value = _pruned(value)
        if max_terms is not None and len(value) > max_terms:
            return None
        work[outs[0]] = value
    flat = [sym[i] for sym in symbols for i in range(int(sym.numel()))]
    angles = {zero: (ca.SX(0.0), ca.SX(1.0))}

    def sin_cos(kv):  # sin and cos of k . q by angle addition, each k once
        if kv not in angles:
            j = max(i for i in range(n) if kv[i])
            step = 1 if kv[j] > 0 else -1
            prev, sign = _normalised(tuple(v - step if i == j else v for i, v in enumerate(kv)))
            sp, cp = sin_cos(prev)
            sp = sp if sign > 0 else -sp
            sj = s[j] if step > 0 else -s[j]
            angles[kv] = (sp * c[j] + cp * sj, cp * c[j] - sp * sj)
        return angles[kv]

    rows = []
    for P in out:
        groups = {}
        for (kv, kind, m), v in P.items():
            groups.setdefault((kv, kind), []).append((m, v))
        row = ca.SX(0.0)
        for (kv, kind), terms in sorted(groups.items()):
            inner = ca.SX(0.0)
            for m, v in terms:
                term = ca.SX(v)
                for i in m:
                    term = term * flat[i]
                inner = inner + term
            row = row + (inner if not any(kv) else sin_cos(kv)[0 if kind else 1] * inner)
        rows.append(row)
    res = ca.vertcat(*rows) if rows else ca.SX(0, 1)
    return ca.cse(res) if hasattr(ca, "cse") else res
