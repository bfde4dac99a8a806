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
"""
from __future__ import annotations

import math

import casadi as ca

__all__ = ["function_source", "UnsupportedOperation"]


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
