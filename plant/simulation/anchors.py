"""Trigonometric anchors: sin/cos of the link angles by angle addition.

The stages of the core (:mod:`plant.simulation.core`) take sin/cos of the link angles by
angle addition from the sample's start angles (the *anchors*: per angle q,
sin q, cos q, rows of an array ``A`` of shape (3 m, lanes) for a plant with
m angles; for the PUMA 560 links 2-3 q2, sin q2, cos q2, q3, sin q3, cos q3), with
the Taylor series of the small offset (exact to rounding for offsets up to
:data:`SINCOS_RANGE`).  The anchors' own sin/cos come from libm every
:data:`REANCHOR` samples and by angle addition in between (libm took a
quarter of the kernel's time; the rounding drift of the recurrence over
:data:`REANCHOR` samples stays at a few 1e-16).
"""
from __future__ import annotations

import functools
import math

import numba
from numba import types
from numba.extending import overload

__all__ = ["SINCOS_RANGE", "REANCHOR", "A_Q2", "A_S2", "A_C2", "A_Q3", "A_S3", "A_C3",
           "N_ANCHOR_ROWS", "anchor_rows", "sincos_offset", "update_anchors", "update_anchors_impl",
           "lane_sincos"]

#: Largest angle change (rad) from the anchor for which the stages take
#: sin/cos by angle addition; beyond it (a lane moving > 50 rad/s) libm.
SINCOS_RANGE = 0.05
#: Samples between libm evaluations of the anchors' sin/cos.
REANCHOR = 16

# Rows of the anchor array A of the PUMA 560 links 2-3 (angles q2, q3).
A_Q2, A_S2, A_C2, A_Q3, A_S3, A_C3 = 0, 1, 2, 3, 4, 5
N_ANCHOR_ROWS = 6


def anchor_rows(n_angles: int) -> int:
    """Rows of the anchor array of a plant with ``n_angles`` angles (3 per angle).

    Parameters
    ----------
    n_angles : int

    Returns
    -------
    int
    """
    return 3 * int(n_angles)

# Helpers compiled into the kernels that call them (whose cache holds their code):
# not cached on their own, which saves a cache file and its write per helper.
# Scalar-only helpers are plain compiled functions that LLVM inlines into the
# SIMD loops (inlining them in numba's IR made the kernels slower to compile).
_jit = numba.njit(nogil=True, error_model="numpy")


@_jit
def sincos_offset(d, sb, cb):
    """sin and cos of ``qb + d`` from ``sb = sin qb`` and ``cb = cos qb``.

    Angle addition with the Taylor series of sin d and cos d (Horner forms,
    multiplications only): exact to rounding for ``abs(d) <= SINCOS_RANGE``
    (truncation < 1e-17).

    Parameters
    ----------
    d, sb, cb : float
        Offset (rad), sine and cosine of the anchor angle.

    Returns
    -------
    (float, float)
        sin(qb + d), cos(qb + d).
    """
    d2 = d * d
    sd = d * (1.0 - d2 * (1.0 / 6.0) * (1.0 - d2 * (1.0 / 20.0) * (1.0 - d2 * (1.0 / 42.0))))
    cd = 1.0 - d2 * 0.5 * (1.0 - d2 * (1.0 / 12.0) * (1.0 - d2 * (1.0 / 30.0)
                                                       * (1.0 - d2 * (1.0 / 56.0))))
    return sb * cd + cb * sd, cb * cd - sb * sd


def update_anchors(X, A, n, reanchor):
    """Move the anchors of lanes ``0..n-1`` to the sample's start angles (rows 0..m-1 of X).

    The reference implementation (Python); the core compiles
    :func:`update_anchors_impl` for its plant's number of angles m, the same
    operations written out per angle.

    Parameters
    ----------
    X : ndarray, shape (n_x, lanes)
        State at the sample's start (rows 0..m-1: the angles whose sine and
        cosine the plant needs).
    A : ndarray, shape (3 m, lanes)
        Anchors (rows 3 r, 3 r + 1, 3 r + 2: angle r, its sine and cosine),
        updated in place.
    n : int
        Lanes.
    reanchor : bool
        Take sin/cos from libm (else by angle addition from the old anchors).
    """
    m = A.shape[0] // 3
    far = 0
    if not reanchor:
        for j in range(n):
            d = [X[r, j] - A[3 * r, j] for r in range(m)]
            far += not all(abs(v) <= SINCOS_RANGE for v in d)
            for r in range(m):
                A[3 * r + 1, j], A[3 * r + 2, j] = sincos_offset(d[r], A[3 * r + 1, j], A[3 * r + 2, j])
    if reanchor or far:
        for j in range(n):
            if reanchor or not all(abs(X[r, j] - A[3 * r, j]) <= SINCOS_RANGE for r in range(m)):
                for r in range(m):
                    A[3 * r + 1, j] = math.sin(X[r, j])
                    A[3 * r + 2, j] = math.cos(X[r, j])
    for j in range(n):
        for r in range(m):
            A[3 * r, j] = X[r, j]


@functools.lru_cache(maxsize=None)
def update_anchors_impl(m):
    """The compiled :func:`update_anchors` for m angles: straight-line code per lane.

    For the core's overload (:func:`plant.simulation.core.anchors_update`): the
    operations of :func:`update_anchors`, each angle's written out, so that
    the lane loops have no inner loop (the PUMA's two angles give the code
    the core had before it took any number of angles, bit for bit).

    Parameters
    ----------
    m : int
        Angles (>= 1).

    Returns
    -------
    function
        ``impl(kind, X, A, n, reanchor)`` (Python source compiled by numba).
    """
    near = lambda a, b: " and ".join(f"abs({a(r)} - {b(r)}) <= SINCOS_RANGE" for r in range(m))
    lines = ["def impl(kind, X, A, n, reanchor):",
             "    far = 0",
             "    if not reanchor:",
             "        for j in range(n):"]
    for r in range(m):
        lines.append(f"            d{r} = X[{r}, j] - A[{3 * r}, j]")
    lines.append("            far += not (" + " and ".join(f"abs(d{r}) <= SINCOS_RANGE" for r in range(m))
                 + ")")
    for r in range(m):
        lines.append(f"            A[{3 * r + 1}, j], A[{3 * r + 2}, j] = "
                     f"sincos_offset(d{r}, A[{3 * r + 1}, j], A[{3 * r + 2}, j])")
    lines += ["    if reanchor or far:",
              "        for j in range(n):",
              "            if reanchor or not (" + near(lambda r: f"X[{r}, j]", lambda r: f"A[{3 * r}, j]")
              + "):"]
    for r in range(m):
        lines += [f"                A[{3 * r + 1}, j] = math.sin(X[{r}, j])",
                  f"                A[{3 * r + 2}, j] = math.cos(X[{r}, j])"]
    lines.append("    for j in range(n):")
    for r in range(m):
        lines.append(f"        A[{3 * r}, j] = X[{r}, j]")
    scope = {"math": math, "sincos_offset": sincos_offset, "SINCOS_RANGE": SINCOS_RANGE}
    exec(compile("\n".join(lines) + "\n", f"<plant.simulation.anchors.update_anchors m={m}>", "exec"),  # noqa: S102
         scope)
    return scope["impl"]


def lane_sincos(x, a, exact):
    """sin and cos of a lane's angles at a stage, by angle addition from its anchors.

    The one place the stages of the core take their trigonometry: exact to
    rounding while the angles lie within :data:`SINCOS_RANGE` of the anchors;
    beyond it the result is reported as not near, and with ``exact`` taken
    from libm instead.  Compiled, the number of angles m is ``len(a) // 3``
    (code generated per m).

    Parameters
    ----------
    x : tuple of float
        Stage state (its first m components are the angles, rad).
    a : tuple of 3 m float
        The lane's anchors (q, sin q, cos q per angle).
    exact : bool
        Take sin/cos from libm when the angles are not near the anchors.

    Returns
    -------
    sc : tuple of 2 m float
        (sin q_1, cos q_1, ..., sin q_m, cos q_m).
    near : bool
        Whether all angles are near the anchors.
    """
    m = len(a) // 3
    sc = []
    near = True
    for r in range(m):
        d = x[r] - a[3 * r]
        s, c = sincos_offset(d, a[3 * r + 1], a[3 * r + 2])
        near = near and abs(d) <= SINCOS_RANGE
        sc += [s, c]
    if exact and not near:
        sc = []
        for r in range(m):
            sc += [math.sin(x[r]), math.cos(x[r])]
    return tuple(sc), near


def _lane_sincos_source(m, exact=True):
    """Source of the compiled :func:`lane_sincos` for m angles (straight-line code).

    With ``exact=False`` (the argument known False at compile time: the
    core's fast stages) the libm branch is left out, so the code has no
    branch and compiles into the SIMD lane loop.
    """
    lines = ["def impl(x, a, exact):"]
    for r in range(m):
        lines += [f"    d{r} = x[{r}] - a[{3 * r}]",
                  f"    s{r}, c{r} = sincos_offset(d{r}, a[{3 * r + 1}], a[{3 * r + 2}])"]
    lines.append("    near = " + " & ".join(f"(abs(d{r}) <= SINCOS_RANGE)" for r in range(m)))
    if exact:
        lines.append("    if exact and not near:")
        for r in range(m):
            lines.append(f"        s{r}, c{r} = math.sin(x[{r}]), math.cos(x[{r}])")
    lines.append("    return (" + "".join(f"s{r}, c{r}, " for r in range(m)) + "), near")
    return "\n".join(lines) + "\n"


@functools.lru_cache(maxsize=None)
def _lane_sincos_impl(m, exact=True):
    scope = {"math": math, "sincos_offset": sincos_offset, "SINCOS_RANGE": SINCOS_RANGE}
    exec(compile(_lane_sincos_source(m, exact), "<plant.simulation.anchors.lane_sincos>", "exec"),  # noqa: S102
         scope)
    return scope["impl"]


def _fast(exact) -> bool:
    """Whether ``exact`` is known False at compile time (the core's fast stages)."""
    return isinstance(exact, types.BooleanLiteral) and not exact.literal_value


def _inline_fast(expr, caller, callee) -> bool:
    """numba's inlining cost model: inline the branch-free fast variant (IR level)."""
    exact = expr.args[2] if len(expr.args) > 2 else dict(expr.kws).get("exact")
    return exact is not None and _fast(caller.typemap[exact.name])


@overload(lane_sincos, prefer_literal=True, inline=_inline_fast,
          jit_options=dict(nogil=True, error_model="numpy"))
def _lane_sincos_overload(x, a, exact):
    return _lane_sincos_impl(len(a) // 3, not _fast(exact))
