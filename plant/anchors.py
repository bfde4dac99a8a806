"""Trigonometric anchors: sin/cos of the link angles by angle addition.

The stages of the core (:mod:`plant.core`) take sin/cos of the link angles by
angle addition from the sample's start angles (the *anchors*: q2, sin q2,
cos q2, q3, sin q3, cos q3, rows of an array ``A`` of shape (6, lanes)), with
the Taylor series of the small offset (exact to rounding for offsets up to
:data:`SINCOS_RANGE`).  The anchors' own sin/cos come from libm every
:data:`REANCHOR` samples and by angle addition in between (libm took a
quarter of the kernel's time; the rounding drift of the recurrence over
:data:`REANCHOR` samples stays at a few 1e-16).
"""
from __future__ import annotations

import math

import numba

__all__ = ["SINCOS_RANGE", "REANCHOR", "A_Q2", "A_S2", "A_C2", "A_Q3", "A_S3", "A_C3",
           "N_ANCHOR_ROWS", "sincos_offset", "update_anchors", "lane_sincos"]

#: Largest angle change (rad) from the anchor for which the stages take
#: sin/cos by angle addition; beyond it (a lane moving > 50 rad/s) libm.
SINCOS_RANGE = 0.05
#: Samples between libm evaluations of the anchors' sin/cos.
REANCHOR = 16

# Rows of the anchor array A.
A_Q2, A_S2, A_C2, A_Q3, A_S3, A_C3 = 0, 1, 2, 3, 4, 5
N_ANCHOR_ROWS = 6

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


@numba.njit(nogil=True, error_model="numpy", inline="always")  # IR-inlined (plant.core)
def update_anchors(X, A, n, reanchor):
    """Move the anchors of lanes ``0..n-1`` to the sample's start angles (rows 0, 1 of X).

    Parameters
    ----------
    X : ndarray, shape (n_x, lanes)
        State at the sample's start (rows 0, 1: q2, q3).
    A : ndarray, shape (6, lanes)
        Anchors, updated in place.
    n : int
        Lanes.
    reanchor : bool
        Take sin/cos from libm (else by angle addition from the old anchors).
    """
    far = 0
    if not reanchor:
        for j in range(n):
            dq2 = X[0, j] - A[A_Q2, j]
            dq3 = X[1, j] - A[A_Q3, j]
            far += not (abs(dq2) <= SINCOS_RANGE and abs(dq3) <= SINCOS_RANGE)
            A[A_S2, j], A[A_C2, j] = sincos_offset(dq2, A[A_S2, j], A[A_C2, j])
            A[A_S3, j], A[A_C3, j] = sincos_offset(dq3, A[A_S3, j], A[A_C3, j])
    if reanchor or far:
        for j in range(n):
            if reanchor or not (abs(X[0, j] - A[A_Q2, j]) <= SINCOS_RANGE
                                and abs(X[1, j] - A[A_Q3, j]) <= SINCOS_RANGE):
                A[A_S2, j] = math.sin(X[0, j])
                A[A_C2, j] = math.cos(X[0, j])
                A[A_S3, j] = math.sin(X[1, j])
                A[A_C3, j] = math.cos(X[1, j])
    for j in range(n):
        A[A_Q2, j] = X[0, j]
        A[A_Q3, j] = X[1, j]


@_jit
def lane_sincos(q2, q3, a, exact):
    """sin and cos of a lane's link angles at a stage, by angle addition from its anchors.

    The one place the stages of the core take their trigonometry: exact to
    rounding while the angles lie within :data:`SINCOS_RANGE` of the anchors;
    beyond it the result is reported as not near, and with ``exact`` taken
    from libm instead.

    Parameters
    ----------
    q2, q3 : float
        Stage link angles (rad).
    a : tuple of 6 float
        The lane's anchors (q2, sin q2, cos q2, q3, sin q3, cos q3).
    exact : bool
        Take sin/cos from libm when the angles are not near the anchors.

    Returns
    -------
    (float, float, float, float, bool)
        sin q2, cos q2, sin q3, cos q3, and whether the angles are near the anchors.
    """
    d2 = q2 - a[A_Q2]
    d3 = q3 - a[A_Q3]
    s2, c2 = sincos_offset(d2, a[A_S2], a[A_C2])
    s3, c3 = sincos_offset(d3, a[A_S3], a[A_C3])
    near = (abs(d2) <= SINCOS_RANGE) & (abs(d3) <= SINCOS_RANGE)
    if exact and not near:
        s2, c2, s3, c3 = math.sin(q2), math.cos(q2), math.sin(q3), math.cos(q3)
    return s2, c2, s3, c3, near
