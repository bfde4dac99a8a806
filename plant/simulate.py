"""Exact closed-loop simulation of the logged P-control experiment.

The simulator reproduces what the rig's control card did, sample by sample
(issue 3, paper section 3):

* at ``t_k = k Ts`` the motor encoders are read, ``act = trunc(q k N / 2 pi)``
  (trunc rounds toward zero), and the integer error ``e = ref - act`` is formed
  with ``ref = trunc(q_ref(t_k) k N / 2 pi)``;
* the motor current ``i = P e`` is held over ``[t_k, t_k + Ts)`` (ZOH); the
  joint torque is ``k Kt i`` plus the joint-side drive friction (viscous and
  asymmetric Coulomb with a linear ramp below the sidecar's motor speed);
* the rigid model of :mod:`plant.model` is integrated over the sample by
  ``substeps`` fixed steps of the classical 4th-order Runge-Kutta method.

All rig constants come from the log's sidecar (:class:`plant.rig.Rig`), the
reference from its :class:`~plant.trajectory.Trajectory`, the start state from
``start_state``.  A log that is a window of a longer run is simulated from
``t = 0`` and compared on its own samples only.

Failed candidates
-----------------
The compiled kernels never raise.  A candidate ``f`` fails when D(q) stops
being positive definite (``det D <= 0`` or ``f1 <= 0`` at any Runge-Kutta
stage), when the state becomes non-finite, or when a simulated error leaves
``bound`` pulses (by default 100 times the largest logged error, at least 100
pulses).  The simulation of that candidate stops there and its status is set
(:data:`STATUS_NOT_PD`, :data:`STATUS_NONFINITE`, :data:`STATUS_DIVERGED`).
Its output error (paper eq. 4) is then the **penalty**

    Y = sum over the samples compared so far of (e_log - e_model)^2
        + 2 * bound^2 * (number of log samples not yet compared)

which is finite, larger than the output error of any candidate that stays
within the bound for the whole run, and smaller the later the candidate fails,
so that a rank-based optimiser can still order failed candidates.

Early termination
-----------------
With a ``cap`` (:func:`simulate_batch`) a candidate whose running sum passes
the cap is stopped (:data:`STATUS_STOPPED`); its output error is the running
sum extrapolated to the whole log, ``Y n_samples / n_compared`` (> cap).

Kernels
-------
The reference path simulates one candidate at a time with
:func:`integrate_sample`.  The default lockstep path advances the candidates
of a chunk together, one SIMD lane each (see the comments at ``_chunk`` and
``_lanes_sample``); it performs the same operations per candidate with the
stages' sin/cos by angle addition, and gives the same pulses (tested).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
from numba import prange

from ._errors import SimulationError
from .model import friction_torque, joint_acceleration, joint_acceleration_sc

__all__ = [
    "DEFAULT_SUBSTEPS",
    "STATUS_OK",
    "STATUS_NOT_PD",
    "STATUS_NONFINITE",
    "STATUS_DIVERGED",
    "STATUS_STOPPED",
    "STATUS_MESSAGES",
    "ExperimentSimulation",
    "rig_vector",
    "reference_counts",
    "default_bound",
    "simulate_experiment",
    "simulate_batch",
    "output_error",
]

#: Runge-Kutta substeps per sample for the exact reproduction of a log.  The
#: quantised loop is chaotic at the pulse level (an integration error of
#: 1e-10 rad can flip a count, and a flip changes later counts), so the
#: substeps are chosen by convergence: on the development logs the simulated
#: pulses stop changing from 48 substeps on (identical up to 128; tested in
#: ``tests/test_simulate.py``, figures in ``benchmarks/bench_simulate.py``).
#: Identification integrates more coarsely
#: (:data:`identification.objective.IDENTIFICATION_SUBSTEPS`).
DEFAULT_SUBSTEPS = 48

STATUS_OK = 0
STATUS_NOT_PD = 1
STATUS_NONFINITE = 2
STATUS_DIVERGED = 3
STATUS_STOPPED = 4
STATUS_MESSAGES = {
    STATUS_OK: "ok",
    STATUS_NOT_PD: "D(q) not positive definite",
    STATUS_NONFINITE: "state not finite",
    STATUS_DIVERGED: "simulated tracking error left the bound",
    STATUS_STOPPED: "output error passed the early-termination cap",
}

# Layout of the rig vector passed to the kernels (joint-side quantities).
_R_TS = 0  # sample time (s)
_R_SCALE = 1  # 1, 2: encoder pulses per joint rad, k N / 2 pi
_R_P = 3  # 3, 4: P gain (A / pulse)
_R_KKT = 5  # 5, 6: joint torque per amp, k Kt (N m / A)
_R_VISC = 7  # 7, 8: joint viscous friction k^2 B (N m s / rad)
_R_CPOS = 9  # 9, 10: joint Coulomb |k| Tc+ (N m)
_R_CNEG = 11  # 11, 12: joint Coulomb |k| Tc- (N m)
_R_VREG = 13  # 13, 14: joint-side ramp speed v / |k| (rad / s)
_R_G = 15  # gravity (m/s^2)
_R_Q0 = 16  # 16, 17: start angles (rad)
_R_QD0 = 18  # 18, 19: start rates (rad/s)
_R_LEN = 20


def rig_vector(rig) -> np.ndarray:
    """Pack a :class:`~plant.rig.Rig` into the flat joint-side vector the kernels use.

    Returns
    -------
    ndarray, shape (20,)
    """
    k = np.asarray(rig.gear_ratio, dtype=float)
    n = np.asarray(rig.encoder_ppr, dtype=float)
    kt = np.asarray(rig.torque_constant_Nm_per_A, dtype=float)
    b = np.asarray(rig.viscous_friction_Nms_per_rad, dtype=float)
    tc = np.asarray(rig.coulomb_friction_Nm, dtype=float).reshape(2, 2)
    r = np.empty(_R_LEN)
    r[_R_TS] = rig.sample_time_s
    r[_R_SCALE : _R_SCALE + 2] = k * n / (2.0 * math.pi)
    r[_R_P : _R_P + 2] = rig.p_gain_A_per_pulse
    r[_R_KKT : _R_KKT + 2] = k * kt
    r[_R_VISC : _R_VISC + 2] = k * k * b
    r[_R_CPOS : _R_CPOS + 2] = np.abs(k) * tc[:, 0]
    r[_R_CNEG : _R_CNEG + 2] = np.abs(k) * tc[:, 1]
    r[_R_VREG : _R_VREG + 2] = rig.coulomb_ramp_speed_rad_per_s / np.abs(k)
    r[_R_G] = rig.gravity_m_s2
    r[_R_Q0 : _R_Q0 + 2] = rig.q0_rad
    r[_R_QD0 : _R_QD0 + 2] = rig.qd0_rad_per_s
    return r


def reference_counts(log) -> np.ndarray:
    """Unquantised reference encoder counts ``q_ref(t_k) k N / 2 pi`` from t = 0.

    Evaluated from the log's trajectory at ``t_k = k Ts`` for
    ``k = 0 .. start_index + n_samples - 1`` (a window log is simulated from
    the start of its run).

    Returns
    -------
    ndarray, shape (n_total, 2), float64
    """
    rig = log.rig
    t = np.arange(log.n_total) * rig.sample_time_s
    return np.ascontiguousarray(log.trajectory.position(t) * rig.pulses_per_rad)


def default_bound(e_log) -> float:
    """Early-termination bound (pulses): 100 times the largest logged error, at least 100."""
    m = float(np.max(np.abs(e_log))) if np.size(e_log) else 0.0
    return max(100.0 * m, 100.0)


# ----------------------------------------------------------------------------
# Compiled kernels
# ----------------------------------------------------------------------------
_jit = numba.njit(cache=True, nogil=True)


@_jit
def _accel(f, r, q2, q3, w2, w3, u2, u3):
    tau2 = u2 + friction_torque(w2, r[_R_VISC], r[_R_CPOS], r[_R_CNEG], r[_R_VREG])
    tau3 = u3 + friction_torque(w3, r[_R_VISC + 1], r[_R_CPOS + 1], r[_R_CNEG + 1], r[_R_VREG + 1])
    return joint_acceleration(f, q2, q3, w2, w3, tau2, tau3, r[_R_G])


#: Largest angle change (rad) from a sample's start for which the lockstep
#: kernels take sin/cos by angle addition (:func:`_sincos_offset`); beyond it
#: (a candidate moving > 50 rad/s) they call libm.
_SINCOS_RANGE = 0.05
#: Samples between libm evaluations of the lockstep kernels' anchor sin/cos.
_REANCHOR = 16
#: The lockstep loops run over a multiple of this many lanes (AVX2: 4 doubles
#: per vector, twice that for AVX-512), so that no lane falls into a scalar
#: remainder loop.
_LANE_PAD = 8


@_jit
def _sincos_offset(d, sb, cb):
    """sin, cos of ``qb + d`` from ``sb = sin qb``, ``cb = cos qb``.

    Angle addition with the Taylor series of sin d and cos d (Horner forms,
    multiplications only): exact to rounding for ``abs(d) <= 0.05`` rad
    (truncation < 1e-17).
    """
    d2 = d * d
    sd = d * (1.0 - d2 * (1.0 / 6.0) * (1.0 - d2 * (1.0 / 20.0) * (1.0 - d2 * (1.0 / 42.0))))
    cd = 1.0 - d2 * 0.5 * (1.0 - d2 * (1.0 / 12.0) * (1.0 - d2 * (1.0 / 30.0)
                                                       * (1.0 - d2 * (1.0 / 56.0))))
    return sb * cd + cb * sd, cb * cd - sb * sd


# ----------------------------------------------------------------------------
# Lockstep kernels: several candidates advanced together ("lanes")
# ----------------------------------------------------------------------------
# One RK4 stage is a dependent chain (trigonometry -> D, h, g -> 2x2 solve ->
# next stage), so a single candidate leaves the CPU waiting on latencies.  The
# lockstep kernels keep one column per candidate in small (rows, lanes) arrays
# and run every step of a sample as a loop over the lanes: the loops have no
# calls and no data-dependent control flow, so LLVM turns them into SIMD
# instructions over several candidates at once.  Per lane they perform exactly
# the floating-point operations of the scalar path, in the same order, so a
# lane's result does not depend on its neighbours.

@_jit
def integrate_sample(f, r, q2, q3, w2, w3, u2, u3, substeps):
    """Advance the rigid robot over one sample with constant drive torques.

    Classical RK4 with ``substeps`` equal steps over ``Ts = r[0]``.  ``u2, u3``
    are the joint torques from the motors (k Kt i), held over the sample;
    friction is added inside.  Returns ``(q2, q3, w2, w3, status)``.
    """
    h = r[_R_TS] / substeps
    ok = f[0] > 0.0
    for _ in range(substeps):
        a12, a13, d1 = _accel(f, r, q2, q3, w2, w3, u2, u3)
        v12 = w2 + 0.5 * h * a12
        v13 = w3 + 0.5 * h * a13
        a22, a23, d2 = _accel(f, r, q2 + 0.5 * h * w2, q3 + 0.5 * h * w3, v12, v13, u2, u3)
        v22 = w2 + 0.5 * h * a22
        v23 = w3 + 0.5 * h * a23
        a32, a33, d3 = _accel(f, r, q2 + 0.5 * h * v12, q3 + 0.5 * h * v13, v22, v23, u2, u3)
        v32 = w2 + h * a32
        v33 = w3 + h * a33
        a42, a43, d4 = _accel(f, r, q2 + h * v22, q3 + h * v23, v32, v33, u2, u3)
        if not (ok and d1 > 0.0 and d2 > 0.0 and d3 > 0.0 and d4 > 0.0):
            return q2, q3, w2, w3, STATUS_NOT_PD
        q2 += h / 6.0 * (w2 + 2.0 * v12 + 2.0 * v22 + v32)
        q3 += h / 6.0 * (w3 + 2.0 * v13 + 2.0 * v23 + v33)
        w2 += h / 6.0 * (a12 + 2.0 * a22 + 2.0 * a32 + a42)
        w3 += h / 6.0 * (a13 + 2.0 * a23 + 2.0 * a33 + a43)
    if not (math.isfinite(q2) and math.isfinite(q3) and math.isfinite(w2) and math.isfinite(w3)):
        return q2, q3, w2, w3, STATUS_NONFINITE
    return q2, q3, w2, w3, STATUS_OK


@_jit
def _loop_constants(r):
    """Counts per rad, joint torque per pulse of error (P k Kt) and start state."""
    return (r[_R_SCALE], r[_R_SCALE + 1], r[_R_P] * r[_R_KKT], r[_R_P + 1] * r[_R_KKT + 1],
            r[_R_Q0], r[_R_Q0 + 1], r[_R_QD0], r[_R_QD0 + 1])


@_jit
def _run(f, r, ref, e_log, k0, substeps, quantize, bound, cap, err_out, write, continuous_out):
    """Simulate one candidate; return (output error, status, samples compared).

    ``ref`` (n_total, 2) unquantised reference counts; ``e_log`` (n, 2) logged
    errors compared from sample ``k0`` on.  With ``quantize`` the encoder and
    reference counts are truncated as on the rig; without, the closed loop is
    the smooth surrogate with continuous counts (used for Jacobians).
    ``err_out`` (n, 2) receives the simulated errors when ``write``.  With
    ``continuous_out`` the compared (and written) model output is the
    unquantised error ``ref - q k N / 2 pi`` even when the feedback is
    quantised.
    """
    n_total = ref.shape[0]
    n = e_log.shape[0]
    s2, s3, p2, p3, q2, q3, w2, w3 = _loop_constants(r)
    sse = 0.0
    status = STATUS_OK
    compared = 0
    for k in range(n_total):
        c2 = q2 * s2
        c3 = q3 * s3
        e2 = ref[k, 0] - c2
        e3 = ref[k, 1] - c3
        # Bound checked on the continuous error first, so truncation never sees a huge value.
        if abs(e2) > bound or abs(e3) > bound:
            status = STATUS_DIVERGED
            break
        if quantize:
            e2 = float(math.trunc(ref[k, 0]) - math.trunc(c2))
            e3 = float(math.trunc(ref[k, 1]) - math.trunc(c3))
        if k >= k0:
            i = k - k0
            o2 = ref[k, 0] - c2 if continuous_out else e2
            o3 = ref[k, 1] - c3 if continuous_out else e3
            d2 = e_log[i, 0] - o2
            d3 = e_log[i, 1] - o3
            sse += d2 * d2 + d3 * d3
            compared += 1
            if write:
                err_out[i, 0] = o2
                err_out[i, 1] = o3
            if sse > cap:
                status = STATUS_STOPPED
                break
        if k == n_total - 1:
            break
        q2, q3, w2, w3, st = integrate_sample(f, r, q2, q3, w2, w3, p2 * e2, p3 * e3, substeps)
        if st != STATUS_OK:
            status = st
            break
    return _final_objective(sse, status, compared, n, bound), status, compared


@_jit
def _final_objective(sse, status, compared, n, bound):
    """Output error of a finished candidate, with the module docstring's penalties."""
    if status == STATUS_OK:
        return sse
    if status == STATUS_STOPPED:
        return sse * n / compared  # extrapolated to the whole log (> cap)
    return sse + 2.0 * bound * bound * (n - compared)


# One chunk's lanes live in a few 2D arrays, a row per quantity and a column
# per candidate, indexed ``[row, lane]`` with constant rows:
#   FT (9, lanes) f1..f9 | X (4, lanes) q2, q3, qd2, qd3 | U (2, lanes) held
#   joint torques k Kt i | A (6, lanes) anchors q2, sin, cos, q3, sin, cos |
#   ACC (12, lanes) qdd2, qdd3, det D of the four RK4 stages | XS (2, lanes)
#   stage angles | V (6, lanes) stage rates v12, v13, v22, v23, v32, v33 |
#   E (2, lanes) running sum of squares, status.
# A SIMD loop writes one array and reads others, which keeps LLVM's run-time
# overlap checks few enough for it to vectorise (one array holding all rows
# made the checks too many and the loops stayed scalar).  Creating row views,
# or passing arrays to a compiled call inside a loop over the lanes, costs
# NRT reference-count updates (atomic) that took more time than the
# arithmetic (measured): the arrays are passed once per sample, and the lane
# loops call scalar functions only.
_A_Q2, _A_S2, _A_C2, _A_Q3, _A_S3, _A_C3 = 0, 1, 2, 3, 4, 5


@numba.njit(nogil=True, inline="always")  # inlined in the numba IR: the loops stay call-free
def _stage_accel(f, q2, q3, w2, w3, u2, u3, q2b, s2b, c2b, q3b, s3b, c3b, fr, g):
    """One lane's joint accelerations at an RK4 stage, sin/cos by angle addition.

    Scalars in (``fr``: the joints' friction constants), scalars out: no
    arrays, hence no reference counting inside the SIMD loops.  Returns
    ``(qdd2, qdd3, det D, far)``; ``far`` is True when an angle moved more
    than :data:`_SINCOS_RANGE` from its anchor (the caller then recomputes
    the lane with libm).
    """
    tau2 = u2 + friction_torque(w2, fr[0], fr[1], fr[2], fr[3])
    tau3 = u3 + friction_torque(w3, fr[4], fr[5], fr[6], fr[7])
    d2 = q2 - q2b
    d3 = q3 - q3b
    s2, c2 = _sincos_offset(d2, s2b, c2b)
    s3, c3 = _sincos_offset(d3, s3b, c3b)
    a2, a3, det = joint_acceleration_sc(f, s2, c2, s3, c3, w2, w3, tau2, tau3, g)
    return a2, a3, det, not (abs(d2) <= _SINCOS_RANGE and abs(d3) <= _SINCOS_RANGE)


@_jit
def _lanes_libm_stage(FT, Q, rq, W, rw, U, A, ACC, ra, n, fr, g):
    """Recompute a stage with libm sin/cos for the lanes that moved too far (rare)."""
    for j in range(n):
        q2 = Q[rq, j]
        q3 = Q[rq + 1, j]
        if not (abs(q2 - A[_A_Q2, j]) <= _SINCOS_RANGE
                and abs(q3 - A[_A_Q3, j]) <= _SINCOS_RANGE):
            w2 = W[rw, j]
            w3 = W[rw + 1, j]
            tau2 = U[0, j] + friction_torque(w2, fr[0], fr[1], fr[2], fr[3])
            tau3 = U[1, j] + friction_torque(w3, fr[4], fr[5], fr[6], fr[7])
            f = (FT[0, j], FT[1, j], FT[2, j], FT[3, j], FT[4, j], FT[5, j], FT[6, j], FT[7, j],
                 FT[8, j])
            ACC[ra, j], ACC[ra + 1, j], ACC[ra + 2, j] = joint_acceleration(
                f, q2, q3, w2, w3, tau2, tau3, g)


@numba.njit(nogil=True, inline="always")
def _lane_stage(FT, Q, rq, W, rw, U, A, ACC, ra, n, fr, g):
    """One RK4 stage for lanes ``0..n-1`` (SIMD): angles ``Q[rq:rq+2]``, rates
    ``W[rw:rw+2]`` -> (qdd2, qdd3, det D) in ``ACC[ra:ra+3]``.

    Inlined with constant rows, so that LLVM sees fixed rows (a runtime row
    defeats its overlap analysis and the loop stays scalar).
    """
    far = 0
    for j in range(n):
        ACC[ra, j], ACC[ra + 1, j], ACC[ra + 2, j], fj = _stage_accel(
            (FT[0, j], FT[1, j], FT[2, j], FT[3, j], FT[4, j], FT[5, j], FT[6, j], FT[7, j],
             FT[8, j]), Q[rq, j], Q[rq + 1, j], W[rw, j], W[rw + 1, j],
            U[0, j], U[1, j], A[0, j], A[1, j], A[2, j], A[3, j], A[4, j], A[5, j], fr, g)
        far += fj
    if far:
        _lanes_libm_stage(FT, Q, rq, W, rw, U, A, ACC, ra, n, fr, g)


@numba.njit(nogil=True, inline="always")
def _lane_stage_inputs(X, ACC, ra, W, rw, c, V, rv, XS, n):
    """Next stage's rates ``V[rv:rv+2] = qd + c qdd`` and angles ``XS = q + c W[rw:rw+2]``."""
    for j in range(n):
        V[rv, j] = X[2, j] + c * ACC[ra, j]
        V[rv + 1, j] = X[3, j] + c * ACC[ra + 1, j]
    for j in range(n):
        XS[0, j] = X[0, j] + c * W[rw, j]
        XS[1, j] = X[1, j] + c * W[rw + 1, j]


@numba.njit(nogil=True, inline="always")
def _lanes_sample(FT, X, U, A, ACC, XS, V, E, r, n, substeps, reanchor):
    """Advance lanes ``0..n-1`` over one sample (RK4, ``substeps`` steps).

    The same operations as :func:`integrate_sample`, with the stages' sin/cos
    by angle addition from the sample's start angles (the anchors ``A``).
    The anchors' own sin/cos come from libm when ``reanchor``, else by angle
    addition from the previous sample's anchors: libm took a quarter of the
    kernel's time (perf), and the rounding drift of the recurrence over
    :data:`_REANCHOR` samples stays at a few 1e-16.  A lane whose D(q) is not
    positive definite at a stage keeps the state of the step's start and gets
    status :data:`STATUS_NOT_PD` (``E[1]``); a non-finite state gets
    :data:`STATUS_NONFINITE`.  Arrays as in the layout comment above.
    """
    h = r[_R_TS] / substeps
    hh = 0.5 * h
    h6 = h * (1.0 / 6.0)
    g = r[_R_G]
    fr = (r[_R_VISC], r[_R_CPOS], r[_R_CNEG], r[_R_VREG],
          r[_R_VISC + 1], r[_R_CPOS + 1], r[_R_CNEG + 1], r[_R_VREG + 1])
    far = 0
    if not reanchor:
        for j in range(n):
            dq2 = X[0, j] - A[_A_Q2, j]
            dq3 = X[1, j] - A[_A_Q3, j]
            far += not (abs(dq2) <= _SINCOS_RANGE and abs(dq3) <= _SINCOS_RANGE)
            A[_A_S2, j], A[_A_C2, j] = _sincos_offset(dq2, A[_A_S2, j], A[_A_C2, j])
            A[_A_S3, j], A[_A_C3, j] = _sincos_offset(dq3, A[_A_S3, j], A[_A_C3, j])
    if reanchor or far:
        for j in range(n):
            if reanchor or not (abs(X[0, j] - A[_A_Q2, j]) <= _SINCOS_RANGE
                                and abs(X[1, j] - A[_A_Q3, j]) <= _SINCOS_RANGE):
                A[_A_S2, j] = math.sin(X[0, j])
                A[_A_C2, j] = math.cos(X[0, j])
                A[_A_S3, j] = math.sin(X[1, j])
                A[_A_C3, j] = math.cos(X[1, j])
    for j in range(n):
        A[_A_Q2, j] = X[0, j]
        A[_A_Q3, j] = X[1, j]
    for _ in range(substeps):
        # stage s: angles (rows of X or XS), rates (rows of X or V) -> ACC rows 3 (s - 1) ..
        _lane_stage(FT, X, 0, X, 2, U, A, ACC, 0, n, fr, g)
        _lane_stage_inputs(X, ACC, 0, X, 2, hh, V, 0, XS, n)
        _lane_stage(FT, XS, 0, V, 0, U, A, ACC, 3, n, fr, g)
        _lane_stage_inputs(X, ACC, 3, V, 0, hh, V, 2, XS, n)
        _lane_stage(FT, XS, 0, V, 2, U, A, ACC, 6, n, fr, g)
        _lane_stage_inputs(X, ACC, 6, V, 2, h, V, 4, XS, n)
        _lane_stage(FT, XS, 0, V, 4, U, A, ACC, 9, n, fr, g)
        for j in range(n):
            if (FT[0, j] > 0.0 and ACC[2, j] > 0.0 and ACC[5, j] > 0.0 and ACC[8, j] > 0.0
                    and ACC[11, j] > 0.0):
                X[0, j] += h6 * (X[2, j] + 2.0 * V[0, j] + 2.0 * V[2, j] + V[4, j])
                X[1, j] += h6 * (X[3, j] + 2.0 * V[1, j] + 2.0 * V[3, j] + V[5, j])
                X[2, j] += h6 * (ACC[0, j] + 2.0 * ACC[3, j] + 2.0 * ACC[6, j] + ACC[9, j])
                X[3, j] += h6 * (ACC[1, j] + 2.0 * ACC[4, j] + 2.0 * ACC[7, j] + ACC[10, j])
            elif E[1, j] == STATUS_OK:
                E[1, j] = STATUS_NOT_PD
    for j in range(n):
        if E[1, j] == STATUS_OK and not (math.isfinite(X[0, j]) and math.isfinite(X[1, j])
                                         and math.isfinite(X[2, j]) and math.isfinite(X[3, j])):
            E[1, j] = STATUS_NONFINITE


@_jit
def _lane_memory(lanes):
    """The per-lane arrays of one chunk: FT, X, U, A, ACC, XS, V, E (layout above)."""
    return (np.zeros((9, lanes)), np.zeros((4, lanes)), np.zeros((2, lanes)),
            np.zeros((6, lanes)), np.zeros((12, lanes)), np.zeros((2, lanes)),
            np.zeros((6, lanes)), np.zeros((2, lanes)))


@_jit
def _move_lane(FT, X, U, A, E, idx, dst, src):
    """Copy lane ``src`` into lane ``dst`` (the scratch arrays need no copy)."""
    for rows in (FT, X, U, A, E):
        for i in range(rows.shape[0]):
            rows[i, dst] = rows[i, src]
    idx[dst] = idx[src]


@_jit
def _retire(FT, X, U, A, E, idx, j, act):
    """Retire lane ``j``: the last active lane moves into it; returns the new count.

    The vacated column becomes padding, a copy of a running lane (lane 0), so
    the SIMD loops never compute on a failed state.
    """
    last = act - 1
    if j != last:
        _move_lane(FT, X, U, A, E, idx, j, last)
    if last > 0:
        _move_lane(FT, X, U, A, E, idx, last, 0)
    return last


@_jit
def _stop_lane(FT, X, U, A, E, idx, j, act, code, cmp, n, bound, obj, status, compared):
    """Record lane ``j``'s result with status ``code`` and retire it (see :func:`_retire`)."""
    c = idx[j]
    obj[c] = _final_objective(E[0, j], code, cmp, n, bound)
    status[c] = code
    compared[c] = cmp
    return _retire(FT, X, U, A, E, idx, j, act)


@_jit
def _padded(n):
    """Lanes a SIMD loop runs over for ``n`` active lanes.

    A multiple of :data:`_LANE_PAD` from ``_LANE_PAD`` lanes on; fewer lanes
    are not padded (they run in the loops' scalar remainder, at the cost of
    the scalar path, instead of paying for a whole vector of copies).
    """
    if n < _LANE_PAD:
        return n
    return (n + _LANE_PAD - 1) // _LANE_PAD * _LANE_PAD


@_jit
def _chunk_range(c, m, n_chunks):
    """Candidates ``lo:hi`` of chunk ``c`` when ``m`` are split into ``n_chunks``."""
    size = (m + n_chunks - 1) // n_chunks
    lo = c * size
    return lo, min(m, lo + size)


@_jit
def _chunk(F, lo, hi, r):
    """Lane arrays (see the layout comment) and candidate indices of one chunk.

    Columns beyond ``hi - lo`` are padding (copies of the first candidate).
    The state rows hold the rig's start state.
    """
    lanes = _padded(hi - lo)
    mem = _lane_memory(lanes)
    FT, X = mem[0], mem[1]
    idx = np.empty(lanes, dtype=np.int64)
    for j in range(lanes):
        c = lo + j if lo + j < hi else lo
        idx[j] = c
        for p in range(9):
            FT[p, j] = F[c, p]
        X[0, j] = r[_R_Q0]
        X[1, j] = r[_R_Q0 + 1]
        X[2, j] = r[_R_QD0]
        X[3, j] = r[_R_QD0 + 1]
    return mem, idx


@_jit
def _lanes_run(mem, idx, n_act, r, ref, e_log, k0, substeps, quantize, bound, cap, err_out,
               write, continuous_out, obj, status, compared):
    """Simulate the candidates of one chunk in lockstep (one lane per candidate).

    Same semantics as :func:`_run` for every lane; the results go to
    ``obj[idx[j]]``, ``status[idx[j]]``, ``compared[idx[j]]`` and
    ``err_out[idx[j]]``.  A lane that fails or is stopped is retired at once
    and the last active lane moves into its column, so the loops only run
    over the candidates still being simulated (early termination pays).
    """
    FT, X, U, A, ACC, XS, V, E = mem
    n_total = ref.shape[0]
    n = e_log.shape[0]
    s2, s3, p2, p3, _, _, _, _ = _loop_constants(r)
    act = n_act
    cmp = 0
    for k in range(n_total):
        r2 = ref[k, 0]
        r3 = ref[k, 1]
        # Divergence (continuous error, before truncation), as in _run.
        for j in range(act - 1, -1, -1):
            if abs(r2 - X[0, j] * s2) > bound or abs(r3 - X[1, j] * s3) > bound:
                act = _stop_lane(FT, X, U, A, E, idx, j, act, STATUS_DIVERGED, cmp, n, bound, obj, status,
                                 compared)
        if act == 0:
            break
        t2 = float(math.trunc(r2))
        t3 = float(math.trunc(r3))
        i = k - k0
        el2 = e_log[i, 0] if i >= 0 else 0.0
        el3 = e_log[i, 1] if i >= 0 else 0.0
        for j in range(_padded(act)):  # SIMD over the lanes
            c2 = X[0, j] * s2
            c3 = X[1, j] * s3
            e2 = r2 - c2
            e3 = r3 - c3
            if quantize:
                e2 = t2 - float(math.trunc(c2))
                e3 = t3 - float(math.trunc(c3))
            if i >= 0:
                d2 = el2 - (r2 - c2 if continuous_out else e2)
                d3 = el3 - (r3 - c3 if continuous_out else e3)
                E[0, j] += d2 * d2 + d3 * d3
            U[0, j] = p2 * e2
            U[1, j] = p3 * e3
        if i >= 0:
            cmp = i + 1
            if write:
                for j in range(act):
                    c2 = X[0, j] * s2
                    c3 = X[1, j] * s3
                    if continuous_out or not quantize:
                        err_out[idx[j], i, 0] = r2 - c2
                        err_out[idx[j], i, 1] = r3 - c3
                    else:
                        err_out[idx[j], i, 0] = t2 - float(math.trunc(c2))
                        err_out[idx[j], i, 1] = t3 - float(math.trunc(c3))
            for j in range(act - 1, -1, -1):
                if E[0, j] > cap:
                    act = _stop_lane(FT, X, U, A, E, idx, j, act, STATUS_STOPPED, cmp, n, bound, obj, status,
                                     compared)
            if act == 0:
                break
        if k == n_total - 1:
            break
        _lanes_sample(FT, X, U, A, ACC, XS, V, E, r, _padded(act), substeps, k % _REANCHOR == 0)
        for j in range(act - 1, -1, -1):
            code = int(E[1, j])
            if code != STATUS_OK:
                act = _stop_lane(FT, X, U, A, E, idx, j, act, code, cmp, n, bound, obj, status,
                                 compared)
        if act == 0:
            break
    for j in range(act):
        c = idx[j]
        obj[c] = E[0, j]
        status[c] = STATUS_OK
        compared[c] = cmp


@numba.njit(cache=True, nogil=True, parallel=True)
def _batch(F, r, ref, e_log, k0, substeps, quantize, bound, cap, err_out, write, continuous_out,
           fast, n_chunks):
    m = F.shape[0]
    obj = np.empty(m)
    status = np.empty(m, dtype=np.int64)
    compared = np.empty(m, dtype=np.int64)
    if fast:
        for c in prange(n_chunks):
            lo, hi = _chunk_range(c, m, n_chunks)
            if lo < hi:
                mem, idx = _chunk(F, lo, hi, r)
                _lanes_run(mem, idx, hi - lo, r, ref, e_log, k0, substeps, quantize, bound, cap,
                           err_out, write, continuous_out, obj, status, compared)
    else:
        for c in prange(m):
            o, s, n_c = _run(F[c], r, ref, e_log, k0, substeps, quantize, bound, cap, err_out[c],
                             write, continuous_out)
            obj[c] = o
            status[c] = s
            compared[c] = n_c
    return obj, status, compared


# ----------------------------------------------------------------------------
# Python API
# ----------------------------------------------------------------------------
@dataclass(frozen=True)
class ExperimentSimulation:
    """Simulated tracking errors of a batch of candidates on one log.

    Attributes
    ----------
    e_pulses : ndarray, shape (n_candidates, n_samples, 2)
        Simulated tracking errors (int64 pulses; float64 when simulated without
        quantisation).  Samples after a candidate failed are set to 0.
    objective : ndarray, shape (n_candidates,)
        Output error (paper eq. 4) against the log, pulses^2, with the penalty
        of the module docstring for failed candidates.
    status : ndarray, shape (n_candidates,)
        :data:`STATUS_OK` or the failure code (see :data:`STATUS_MESSAGES`).
    n_compared : ndarray, shape (n_candidates,)
        Log samples compared before the end of the run or the failure.
    """

    e_pulses: np.ndarray
    objective: np.ndarray
    status: np.ndarray
    n_compared: np.ndarray


def _kernel(fn, *args):
    """Call a compiled kernel; a Ctrl-C inside it surfaces as KeyboardInterrupt.

    numba reports a signal that arrives while compiled code runs as
    ``SystemError: ... returned a result with an exception set`` chained to
    the KeyboardInterrupt; callers (the GA, the CLI) expect the interrupt.
    """
    try:
        return fn(*args)
    except SystemError as exc:
        cause = exc
        while cause is not None:  # numba chains several SystemErrors to the interrupt
            if isinstance(cause, KeyboardInterrupt):
                raise KeyboardInterrupt() from None
            cause = cause.__cause__ or cause.__context__
        raise


def _prepare(log, F, substeps, bound, workers):
    F = np.asarray(F, dtype=np.float64)
    if F.ndim != 2 or F.shape[1] != 9:
        raise ValueError(f"candidates must have shape (n_candidates, 9), got {F.shape}")
    if not np.all(np.isfinite(F)):
        raise ValueError("candidate parameters contain NaN or inf")
    substeps = int(substeps)
    if substeps < 1:
        raise ValueError(f"substeps must be >= 1, got {substeps}")
    e_log = np.ascontiguousarray(log.e_pulses, dtype=np.float64)
    if bound is None:
        bound = default_bound(e_log)
    if not bound > 0:
        raise ValueError(f"bound must be positive, got {bound}")
    if workers is not None:
        numba.set_num_threads(max(1, min(int(workers), numba.config.NUMBA_NUM_THREADS)))
    return np.ascontiguousarray(F), substeps, e_log, float(bound)


def _lockstep_plan(m, fast):
    """(use the lockstep kernel, number of chunks) for ``m`` candidates.

    One chunk per thread.  Chunks of fewer than :data:`_LANE_PAD` candidates
    run the plain per-candidate loop instead: lockstep pays from about that
    many lanes on, below it its per-sample bookkeeping costs more than it
    saves (measured: 1 candidate 3.8 ms lockstep vs 1.6 ms plain; 40 lanes
    0.39 ms per candidate vs 2.3 ms).  Both give the same pulses (tested).
    """
    chunks = max(1, min(m, numba.get_num_threads()))
    return bool(fast) and -(-m // chunks) >= _LANE_PAD, chunks


def _cached_inputs(log):
    """Rig vector and reference counts of a log, computed once per log object."""
    cache = getattr(log, "_sim_cache", None)
    if cache is None:
        cache = (rig_vector(log.rig), reference_counts(log))
        try:
            object.__setattr__(log, "_sim_cache", cache)
        except (AttributeError, TypeError):  # slotted or foreign log objects
            pass
    return cache


def simulate_batch(
    log,
    F,
    *,
    substeps=DEFAULT_SUBSTEPS,
    errors=True,
    quantize=True,
    bound=None,
    workers=None,
    continuous_output=False,
    fast=True,
    cap=None,
):
    """Simulate the logged closed-loop experiment for a population of candidates.

    Parallel over candidates: the population is split into one chunk per
    thread (``numba.prange``), and the fast path advances the candidates of a
    chunk in lockstep, one SIMD lane each.

    Parameters
    ----------
    log : plant.ExperimentLog
        The experiment: rig, trajectory, start state and logged errors.
    F : array_like, shape (n_candidates, 9)
        Candidate base parameters f1..f9.
    substeps : int
        RK4 steps per sample (>= 1); fewer is faster and less exact.
    errors : bool
        Return the simulated error sequences too (else only the output errors,
        which avoids allocating ``n_candidates * n_samples * 2`` values).
    quantize : bool
        Truncate encoder counts as the rig does (True: exact experiment).  False
        gives the smooth surrogate closed loop with continuous counts.
    bound : float, optional
        Early-termination bound on abs(e) (pulses); default :func:`default_bound`.
    workers : int, optional
        Number of threads (default: numba's current setting).
    continuous_output : bool
        Compare and return the unquantised model error ``ref - q k N / 2 pi``
        (float) while the feedback stays as set by ``quantize``.  This output
        varies smoothly with f where the integer one flips by whole pulses.
    fast : bool
        Lockstep kernel (default; the stages' sin/cos by angle addition from
        the sample's start angles, several candidates per SIMD instruction)
        instead of the plain reference loop over :func:`integrate_sample`.
        Both give the same pulses (tested).  Batches with fewer than
        ``_LANE_PAD`` (8) candidates per thread run the plain loop, which is
        faster there.
    cap : float, optional
        Early termination of hopeless candidates: a candidate whose running
        sum of squares passes ``cap`` (pulses^2) stops there, with status
        :data:`STATUS_STOPPED` and as objective its sum extrapolated to the
        whole log, ``Y * n_samples / n_compared`` (> ``cap``).  Candidates
        below the cap are unaffected.  Default: no cap.

    Returns
    -------
    ExperimentSimulation
        ``e_pulses`` is ``None`` when ``errors`` is False.

    Raises
    ------
    ValueError
        On a wrongly shaped or non-finite ``F``, ``substeps < 1``, a
        non-positive bound or a NaN cap.
    """
    F, substeps, e_log, bound = _prepare(log, F, substeps, bound, workers)
    cap = np.inf if cap is None else float(cap)
    if np.isnan(cap):
        raise ValueError("cap must be a number (or None), got NaN")
    r, ref = _cached_inputs(log)
    m, n = F.shape[0], e_log.shape[0]
    err = np.zeros((m, n, 2)) if errors else np.zeros((m, 0, 2))
    obj, status, compared = _kernel(
        _batch, F, r, ref, e_log, int(log.start_index), substeps, bool(quantize), bound, cap,
        err, bool(errors), bool(continuous_output), *_lockstep_plan(m, fast),
    )
    if errors and quantize and not continuous_output:
        err = err.astype(np.int64)
    return ExperimentSimulation(err if errors else None, obj, status, compared)


def output_error(log, F, *, substeps=DEFAULT_SUBSTEPS, bound=None, workers=None):
    """Output error of paper eq. 4 for one candidate or a population.

    ``Y(f) = sum_k sum_j (e_log[k, j] - e_model[k, j])^2`` in pulses^2, with the
    penalty of the module docstring for failed candidates.

    Parameters
    ----------
    log : plant.ExperimentLog
    F : array_like, shape (9,) or (n_candidates, 9)
    substeps, bound, workers
        As in :func:`simulate_batch`.

    Returns
    -------
    float or ndarray, shape (n_candidates,)
    """
    F = np.asarray(F, dtype=np.float64)
    single = F.ndim == 1
    sim = simulate_batch(
        log, F.reshape(1, -1) if single else F, substeps=substeps, errors=False,
        bound=bound, workers=workers,
    )
    return float(sim.objective[0]) if single else sim.objective


def simulate_experiment(log, f, *, substeps=DEFAULT_SUBSTEPS, quantize=True, bound=None):
    """Simulate the logged P-control experiment for one parameter vector.

    Parameters
    ----------
    log : plant.ExperimentLog
        Rig, trajectory, start state (and, for the bound, the logged errors).
    f : array_like, shape (9,)
        Base parameters f1..f9.
    substeps : int
        RK4 steps per sample.
    quantize : bool
        Truncate counts as the rig does (default); False gives float errors of
        the smooth surrogate.
    bound : float, optional
        Divergence bound on abs(e) in pulses (default :func:`default_bound`).

    Returns
    -------
    ndarray, shape (n_samples, 2)
        Simulated tracking errors at the log's samples (int64 pulses).

    Raises
    ------
    ValueError
        If ``f`` is not 9 finite numbers.
    plant.SimulationError
        If D(q) stops being positive definite, the state diverges, or the
        error leaves the bound; the message gives the time and reason.
    """
    f = np.asarray(f, dtype=np.float64)
    if f.shape != (9,):
        raise ValueError(f"f must have shape (9,) (f1..f9), got {f.shape}")
    sim = simulate_batch(log, f[None], substeps=substeps, quantize=quantize, bound=bound)
    st = int(sim.status[0])
    if st != STATUS_OK:
        k = int(log.start_index) + int(sim.n_compared[0])
        raise SimulationError(
            f"simulation of {getattr(log, 'name', 'log')} failed at t = "
            f"{k * log.rig.sample_time_s:.4f} s: {STATUS_MESSAGES[st]}"
        )
    return sim.e_pulses[0]


# ----------------------------------------------------------------------------
# Logged-input replay: one-step prediction errors (refinement stage)
# ----------------------------------------------------------------------------
def measured_counts(log):
    """Centres of the count intervals the log allows, shape (n_samples, 2) (pulses).

    The logged error gives the integer count ``a = trunc(ref) - e``; the
    continuous count c satisfies ``trunc(c) == a``, an interval of width 1
    (width 2 around 0) whose centre is returned.
    """
    ref = _cached_inputs(log)[1][log.start_index :]
    a = np.trunc(ref) - log.e_pulses
    return np.where(a > 0, a + 0.5, np.where(a < 0, a - 0.5, 0.0))


@_jit
def _count_interval_centre(a):
    """Centre of the continuous counts c with trunc(c) == a (a an integer count)."""
    if a > 0.0:
        return a + 0.5
    if a < 0.0:
        return a - 0.5
    return 0.0


@_jit
def _replay_run(f, r, ref, e_log, k0, substeps, gain, bound, out, x0, use_x0):
    n_total = ref.shape[0]
    s2, s3, p2, p3, q2, q3, w2, w3 = _loop_constants(r)
    status = STATUS_OK
    done = 0
    k_start = 0
    if use_x0:
        # given state at the first logged sample: no simulation before it
        k_start = k0
        q2 = x0[0]
        q3 = x0[1]
        w2 = x0[2]
        w3 = x0[3]
    for k in range(k_start, n_total):
        c2 = q2 * s2
        c3 = q3 * s3
        if abs(ref[k, 0] - c2) > bound or abs(ref[k, 1] - c3) > bound:
            status = STATUS_DIVERGED
            break
        if k < k0:
            # Before a window: the run's own P loop from t = 0, with continuous
            # counts (the smooth closed loop) so that the state reached at the
            # window is a smooth function of f.
            u2 = ref[k, 0] - c2
            u3 = ref[k, 1] - c3
        else:
            i = k - k0
            m2 = _count_interval_centre(float(math.trunc(ref[k, 0])) - e_log[i, 0])
            m3 = _count_interval_centre(float(math.trunc(ref[k, 1])) - e_log[i, 1])
            out[i, 0] = m2 - c2
            out[i, 1] = m3 - c3
            done = i + 1
            # Logged input (the current the rig applied) plus the predictor correction.
            u2 = e_log[i, 0] + gain * (m2 - c2)
            u3 = e_log[i, 1] + gain * (m3 - c3)
        if k == n_total - 1:
            break
        q2, q3, w2, w3, st = integrate_sample(f, r, q2, q3, w2, w3, p2 * u2, p3 * u3, substeps)
        if st != STATUS_OK:
            status = st
            break
    _fill_failed(out, done, bound)
    return status


@_jit
def _fill_failed(out, done, bound):
    """Prediction errors of a failed candidate from sample ``done`` on: ``bound``."""
    for i in range(done, out.shape[0]):
        out[i, 0] = bound
        out[i, 1] = bound


@_jit
def _lanes_replay(mem, idx, n_act, r, ref, e_log, k0, substeps, gain, bound, out, X0, use_x0,
                  status):
    """:func:`_replay_run` for the candidates of one chunk in lockstep (see :func:`_lanes_run`)."""
    FT, X, U, A, ACC, XS, V, E = mem
    n_total = ref.shape[0]
    s2, s3, p2, p3, _, _, _, _ = _loop_constants(r)
    k_start = k0 if use_x0 else 0
    if use_x0:  # given state at the first logged sample: no simulation before it
        for j in range(X.shape[1]):
            for p in range(4):
                X[p, j] = X0[idx[j], p]
    act = n_act
    for k in range(k_start, n_total):
        r2 = ref[k, 0]
        r3 = ref[k, 1]
        i = k - k0
        for j in range(act - 1, -1, -1):
            if abs(r2 - X[0, j] * s2) > bound or abs(r3 - X[1, j] * s3) > bound:
                status[idx[j]] = STATUS_DIVERGED
                _fill_failed(out[idx[j]], max(i, 0), bound)
                act = _retire(FT, X, U, A, E, idx, j, act)
        if act == 0:
            break
        if i < 0:
            # Before a window: the run's own P loop with continuous counts (see _replay_run).
            for j in range(_padded(act)):
                U[0, j] = p2 * (r2 - X[0, j] * s2)
                U[1, j] = p3 * (r3 - X[1, j] * s3)
        else:
            m2 = _count_interval_centre(float(math.trunc(r2)) - e_log[i, 0])
            m3 = _count_interval_centre(float(math.trunc(r3)) - e_log[i, 1])
            for j in range(_padded(act)):
                U[0, j] = p2 * (e_log[i, 0] + gain * (m2 - X[0, j] * s2))
                U[1, j] = p3 * (e_log[i, 1] + gain * (m3 - X[1, j] * s3))
            for j in range(act):
                out[idx[j], i, 0] = m2 - X[0, j] * s2
                out[idx[j], i, 1] = m3 - X[1, j] * s3
        if k == n_total - 1:
            break
        _lanes_sample(FT, X, U, A, ACC, XS, V, E, r, _padded(act), substeps, (k - k_start) % _REANCHOR == 0)
        for j in range(act - 1, -1, -1):
            code = int(E[1, j])
            if code != STATUS_OK:
                status[idx[j]] = code
                _fill_failed(out[idx[j]], max(i + 1, 0), bound)
                act = _retire(FT, X, U, A, E, idx, j, act)
        if act == 0:
            break
    for j in range(act):
        status[idx[j]] = STATUS_OK


@numba.njit(cache=True, nogil=True, parallel=True)
def _replay_batch(F, r, ref, e_log, k0, substeps, gain, bound, out, X0, use_x0, fast, n_chunks):
    m = F.shape[0]
    status = np.empty(m, dtype=np.int64)
    if fast:
        for c in prange(n_chunks):
            lo, hi = _chunk_range(c, m, n_chunks)
            if lo < hi:
                mem, idx = _chunk(F, lo, hi, r)
                _lanes_replay(mem, idx, hi - lo, r, ref, e_log, k0, substeps, gain, bound, out, X0,
                              use_x0, status)
    else:
        for c in prange(m):
            status[c] = _replay_run(F[c], r, ref, e_log, k0, substeps, gain, bound, out[c],
                                    X0[c], use_x0)
    return status


def prediction_errors(
    log, F, *, gain=0.02, substeps=DEFAULT_SUBSTEPS, bound=None, workers=None,
    initial_state=None, fast=True,
):
    """One-step prediction errors of the rigid model replaying the logged input.

    The P controller's current is known exactly from the logged integer error
    (``i_k = P e_k``), so the model can be driven by the current the rig
    applied instead of by its own, quantised, feedback.  The model's
    continuous encoder count ``c_k = q_k k N / 2 pi`` is compared with the
    centre ``m_k`` of the unit interval of counts that the log allows
    (``trunc(c) = trunc(ref_k) - e_k``), and a weak output-injection correction
    ``gain * P * (m_k - c_k)`` keeps the replay from drifting (an observer in
    the sense of prediction-error methods; Ljung, *System Identification*,
    2nd ed., sec. 7).  The prediction errors ``m_k - c_k`` are smooth in f:
    unlike the integer output error of eq. 4 they do not flip by whole pulses,
    so a Gauss-Newton method can use them.  A window log is first simulated
    under its P loop from t = 0 up to the window (with continuous counts in
    the feedback: the quantised loop is not smooth in f, the smooth one
    reaches the same state to a fraction of a pulse), unless
    ``initial_state`` gives the state at its first sample.

    Parameters
    ----------
    log : plant.ExperimentLog
    F : array_like, shape (n_candidates, 9) or (9,)
        Candidate base parameters.
    gain : float
        Output-injection gain as a fraction of the P gain (>= 0).  0 is the
        pure replay (unbiased, but a gravity error makes it drift); large
        values approach the smooth closed loop (biased by the missing
        quantisation).  0.02 is the measured compromise (docs, identification).
    substeps : int
        RK4 steps per sample.
    bound : float, optional
        Divergence bound (counts); failed candidates get ``bound`` as their
        prediction error from the failure on.
    workers : int, optional
        Threads for the parallel loop over candidates.
    initial_state : array_like, shape (n_candidates, 4) or (4,), optional
        State (q2, q3, qd2, qd3) in rad, rad/s at the log's first sample, per
        candidate; the replay then starts there.
    fast : bool
        Lockstep kernel (default) or the plain reference loop, as in
        :func:`simulate_batch`; the two agree to rounding (tested).

    Returns
    -------
    eps : ndarray, shape (n_candidates, n_samples, 2) or (n_samples, 2)
        Prediction errors in pulses.
    status : ndarray, shape (n_candidates,) or int
        :data:`STATUS_OK` or a failure code.
    """
    F = np.asarray(F, dtype=np.float64)
    single = F.ndim == 1
    F2, substeps, e_log, bound = _prepare(log, F.reshape(1, -1) if single else F,
                                           substeps, bound, workers)
    if not gain >= 0:
        raise ValueError(f"gain must be >= 0, got {gain}")
    r, ref = _cached_inputs(log)
    m = F2.shape[0]
    if initial_state is None:
        X0, use_x0 = np.zeros((m, 4)), False
    else:
        X0 = np.ascontiguousarray(np.broadcast_to(np.asarray(initial_state, float), (m, 4)))
        if not np.all(np.isfinite(X0)):
            raise ValueError("initial_state contains NaN or inf")
        use_x0 = True
    out = np.empty((m, e_log.shape[0], 2))
    status = _kernel(_replay_batch, F2, r, ref, e_log, int(log.start_index), substeps,
                     float(gain), bound, out, X0, use_x0, *_lockstep_plan(m, fast))
    if single:
        return out[0], int(status[0])
    return out, status


def warm_up():
    """Compile (or load from numba's cache) the simulation kernels.

    Runs every kernel once on a three-sample dummy problem so that a timed
    run afterwards excludes JIT compilation.  Returns the seconds it took.
    """
    import time

    t0 = time.perf_counter()
    r = np.zeros(_R_LEN)
    r[_R_TS] = 1e-3
    r[_R_SCALE : _R_SCALE + 2] = 1.0
    r[_R_VREG : _R_VREG + 2] = 1.0
    F = np.ones((1, 9))
    ref = np.zeros((3, 2))
    e_log = np.zeros((3, 2))
    err = np.zeros((1, 3, 2))
    for fast in (True, False):
        for write in (False, True):
            for quantize in (False, True):
                _batch(F, r, ref, e_log, 0, 1, quantize, 100.0, np.inf, err, write, False, fast,
                       1)
        _batch(F, r, ref, e_log, 0, 1, True, 100.0, np.inf, err, True, True, fast, 1)
        for use_x0 in (False, True):
            _replay_batch(F, r, ref, e_log, 0, 1, 0.02, 100.0, err, np.zeros((1, 4)), use_x0,
                          fast, 1)
    return time.perf_counter() - t0
