"""The one closed-loop core: one sample step that every simulation drives.

Every simulation in the library -- the logged P-control experiment
(:mod:`plant.simulate`), the logged-input replay of the refinement
(:mod:`plant.replay`), the loop with any sampled controller
(:mod:`plant.closed_loop`), rigid or two-mass flexible plant, one candidate
or a batch of candidates in SIMD lanes -- advances the robot through the
functions of this module and nothing else::

        encoder_read          the rig's card at t_k: counts trunc(q k N / 2 pi)
             |
        (driver: the control law, e.g. i = P e, or a Python controller)
             |
        advance_sample        the current i held over [t_k, t_k + Ts):
             |                RK4 substeps of the plant's right-hand side
             v
        next sample

* :func:`encoder_read` reads an angle as the card does (continuous count and
  its truncation toward zero); :func:`cell_centre` gives the centre of the
  continuous counts an integer count allows.
* :func:`advance_sample` advances lanes ``0..n-1`` of a state array ``X``
  (rows: state components, columns: lanes) over one sample with the held
  motor currents ``U`` (2, lanes), by ``substeps`` classical RK4 steps of
  ``rhs``, the plant's right-hand side (:mod:`plant.plants`: rigid or
  flexible).  The right-hand side is a *parameter*, a compiled function
  passed in (numba specialises the core for it), not a copy of the loop.

A plant's right-hand side has the signature ``rhs(P, c, X, U, A, K, n)``:
per-lane parameters ``P`` (n_par, lanes), the rig layout ``c``
(:class:`plant.rig.RigConstants`), the stage state ``X`` (n_x, lanes), the
held currents ``U`` (2, lanes), the trigonometric anchors ``A`` (6, lanes)
and the output ``K`` (n_x + 1, lanes): rows ``0..n_x-1`` the state
derivative, row ``n_x`` a positive-definiteness margin (det D(q); a stage
with a margin <= 0 is rejected).  Rows 0 and 1 of every plant's state are
the link angles q2, q3 (the only angles whose sine and cosine the dynamics
need).

Lanes
-----
One RK4 stage is a dependent chain (trigonometry -> D, h, g -> 2x2 solve ->
next stage), so a single candidate leaves the CPU waiting on latencies.
The core keeps one column per candidate and runs every step as a loop over
the lanes with no calls that stay calls and no data-dependent control flow,
so that LLVM turns them into SIMD instructions over several candidates at
once.  A loop writes one array and reads others, which keeps LLVM's run-time
overlap checks few enough for it to vectorise.  Per lane the floating-point
operations are the same whatever the number of lanes, so a lane's result
does not depend on its neighbours (tested): one candidate is one lane.

Trigonometry by angle addition
------------------------------
The stages take sin/cos of the link angles by angle addition from the
sample's start angles (the *anchors* ``A``: q2, sin q2, cos q2, q3, sin q3,
cos q3), with the Taylor series of the small offset (exact to rounding for
offsets up to :data:`SINCOS_RANGE`).  The anchors' own sin/cos come from
libm every :data:`REANCHOR` samples and by angle addition in between (libm
took a quarter of the kernel's time).  A lane that moved further than
:data:`SINCOS_RANGE` within a sample is recomputed with libm.

Status codes
------------
:data:`STATUS_OK`, :data:`STATUS_NOT_PD` (D(q) not positive definite at some
stage; the lane keeps the state of the step's start), :data:`STATUS_NONFINITE`,
and the drivers' :data:`STATUS_DIVERGED`, :data:`STATUS_STOPPED`; messages in
:data:`STATUS_MESSAGES`.
"""
from __future__ import annotations

import math

import numba
import numpy as np

__all__ = [
    "STATUS_OK",
    "STATUS_NOT_PD",
    "STATUS_NONFINITE",
    "STATUS_DIVERGED",
    "STATUS_STOPPED",
    "STATUS_MESSAGES",
    "SINCOS_RANGE",
    "REANCHOR",
    "encoder_read",
    "cell_centre",
    "sincos_offset",
    "advance_sample",
    "new_workspace",
    "padded_lanes",
]

STATUS_OK = 0
STATUS_NOT_PD = 1
STATUS_NONFINITE = 2
STATUS_DIVERGED = 3
STATUS_STOPPED = 4
#: Human-readable reason of each status code.
STATUS_MESSAGES = {
    STATUS_OK: "ok",
    STATUS_NOT_PD: "D(q) not positive definite",
    STATUS_NONFINITE: "state not finite",
    STATUS_DIVERGED: "simulated tracking error left the bound",
    STATUS_STOPPED: "output error passed the early-termination cap",
}

#: Largest angle change (rad) from the anchor for which the stages take
#: sin/cos by angle addition; beyond it (a lane moving > 50 rad/s) libm.
SINCOS_RANGE = 0.05
#: Samples between libm evaluations of the anchors' sin/cos.
REANCHOR = 16
#: Lane loops run over a multiple of this many lanes from this many on (AVX2:
#: 4 doubles per vector, twice that for AVX-512), so that no lane falls into
#: a scalar remainder loop; the extra columns are padding copies.
LANE_PAD = 8

# Rows of the anchor array A.
A_Q2, A_S2, A_C2, A_Q3, A_S3, A_C3 = 0, 1, 2, 3, 4, 5
N_ANCHOR_ROWS = 6

_jit = numba.njit(cache=True, nogil=True, error_model="numpy")


@_jit
def encoder_read(angle, pulses_per_rad):
    """Read one motor encoder as the rig's card does.

    Parameters
    ----------
    angle : float
        Joint-side angle the encoder sees (rad): the joint angle of a rigid
        robot, the motor angle divided by k of a flexible one.
    pulses_per_rad : float
        k N / (2 pi) (pulses per joint radian).

    Returns
    -------
    continuous : float
        ``angle k N / 2 pi`` (pulses).
    count : float
        ``trunc(continuous)`` (an integer; trunc rounds toward zero).
    """
    c = angle * pulses_per_rad
    return c, float(math.trunc(c))


@_jit
def cell_centre(count):
    """Centre of the continuous counts c with ``trunc(c) == count`` (pulses).

    The cell of a count a > 0 is [a, a + 1), of a < 0 (a - 1, a], of 0 the
    interval (-1, 1): centres a + 0.5, a - 0.5 and 0.

    Parameters
    ----------
    count : float
        An integer count.

    Returns
    -------
    float
    """
    if count > 0.0:
        return count + 0.5
    if count < 0.0:
        return count - 0.5
    return 0.0


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


@_jit
def padded_lanes(n):
    """Lanes a SIMD loop runs over for ``n`` active lanes.

    A multiple of :data:`LANE_PAD` from ``LANE_PAD`` lanes on; fewer lanes
    are not padded (they run in the loops' scalar remainder instead of paying
    for a whole vector of copies).

    Parameters
    ----------
    n : int
        Active lanes.

    Returns
    -------
    int
    """
    if n < LANE_PAD:
        return n
    return (n + LANE_PAD - 1) // LANE_PAD * LANE_PAD


@_jit
def new_workspace(nx, lanes):
    """Scratch arrays of :func:`advance_sample` for ``nx`` states and ``lanes`` lanes.

    Parameters
    ----------
    nx : int
        State components.
    lanes : int
        Lanes (columns).

    Returns
    -------
    tuple of ndarray
        ``(K1, K2, K3, K4, XS)``: the four stage derivatives (nx + 1, lanes)
        and the stage state (nx, lanes).
    """
    return (np.zeros((nx + 1, lanes)), np.zeros((nx + 1, lanes)), np.zeros((nx + 1, lanes)),
            np.zeros((nx + 1, lanes)), np.zeros((nx, lanes)))


@_jit
def _update_anchors(X, A, n, reanchor):
    """Move the anchors to the sample's start angles (rows 0, 1 of X)."""
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
def _stage_state(X, K, c, XS, nx, n):
    """Next stage's state ``XS = X + c K`` (rows 0..nx-1)."""
    for i in range(nx):
        for j in range(n):
            XS[i, j] = X[i, j] + c * K[i, j]


@_jit
def advance_sample(rhs, P, c, X, U, A, S, W, n, substeps, reanchor):
    """Advance lanes ``0..n-1`` over one sample with the held currents ``U``.

    Classical 4th-order Runge-Kutta with ``substeps`` equal steps over
    ``Ts = c.sample_time_s`` of the plant's right-hand side ``rhs`` (see the
    module docstring for its signature); the currents are held constant over
    the sample (zero-order hold, as the rig's amplifiers do).

    Parameters
    ----------
    rhs : numba dispatcher
        The plant's right-hand side (:data:`plant.plants.RIGID` ``.rhs`` ...).
    P : ndarray, shape (n_par, lanes)
        Per-lane plant parameters (column j: lane j).
    c : plant.rig.RigConstants
        Rig layout.
    X : ndarray, shape (n_x, lanes)
        State at the sample's start; advanced in place.
    U : ndarray, shape (2, lanes)
        Motor currents (A) held over the sample.
    A : ndarray, shape (6, lanes)
        Trigonometric anchors (see the module docstring); updated in place.
    S : ndarray, shape (lanes,), int64
        Status per lane: set to :data:`STATUS_NOT_PD` or
        :data:`STATUS_NONFINITE` on failure (a lane already failed keeps its
        code).
    W : tuple of ndarray
        Scratch from :func:`new_workspace`.
    n : int
        Number of lanes to advance (columns ``0..n-1``).
    substeps : int
        RK4 steps per sample (>= 1).
    reanchor : bool
        Take the anchors' sin/cos from libm at this sample.
    """
    K1, K2, K3, K4, XS = W
    nx = X.shape[0]
    h = c.sample_time_s / substeps
    hh = 0.5 * h
    h6 = h * (1.0 / 6.0)
    _update_anchors(X, A, n, reanchor)
    for _ in range(substeps):
        rhs(P, c, X, U, A, K1, n)
        _stage_state(X, K1, hh, XS, nx, n)
        rhs(P, c, XS, U, A, K2, n)
        _stage_state(X, K2, hh, XS, nx, n)
        rhs(P, c, XS, U, A, K3, n)
        _stage_state(X, K3, h, XS, nx, n)
        rhs(P, c, XS, U, A, K4, n)
        for i in range(nx):
            for j in range(n):
                ok = K1[nx, j] > 0.0 and K2[nx, j] > 0.0 and K3[nx, j] > 0.0 and K4[nx, j] > 0.0
                x = X[i, j]
                X[i, j] = (x + h6 * (K1[i, j] + 2.0 * K2[i, j] + 2.0 * K3[i, j] + K4[i, j])
                           if ok else x)
        for j in range(n):
            if not (K1[nx, j] > 0.0 and K2[nx, j] > 0.0 and K3[nx, j] > 0.0
                    and K4[nx, j] > 0.0) and S[j] == STATUS_OK:
                S[j] = STATUS_NOT_PD
    for j in range(n):
        if S[j] == STATUS_OK:
            for i in range(nx):
                if not math.isfinite(X[i, j]):
                    S[j] = STATUS_NONFINITE
                    break
