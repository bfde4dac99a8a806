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
STATUS_MESSAGES = {
    STATUS_OK: "ok",
    STATUS_NOT_PD: "D(q) not positive definite",
    STATUS_NONFINITE: "state not finite",
    STATUS_DIVERGED: "simulated tracking error left the bound",
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


@_jit
def _sincos_near(q, qb, sb, cb):
    """sin q, cos q from sin/cos of a nearby angle qb (angle addition, Taylor in q - qb).

    Exact to rounding for |q - qb| < 0.05 rad (truncation < 1e-17); falls back
    to libm beyond.
    """
    d = q - qb
    if abs(d) > 0.05:
        return math.sin(q), math.cos(q)
    d2 = d * d
    # Horner forms of the Taylor series, multiplications only (hot loop)
    sd = d * (1.0 - d2 * (1.0 / 6.0) * (1.0 - d2 * (1.0 / 20.0) * (1.0 - d2 * (1.0 / 42.0))))
    cd = 1.0 - d2 * 0.5 * (1.0 - d2 * (1.0 / 12.0) * (1.0 - d2 * (1.0 / 30.0)
                                                       * (1.0 - d2 * (1.0 / 56.0))))
    return sb * cd + cb * sd, cb * cd - sb * sd


@_jit
def _accel_fast(f, r, q2, q3, w2, w3, u2, u3, q2b, s2b, c2b, q3b, s3b, c3b):
    tau2 = u2 + friction_torque(w2, r[_R_VISC], r[_R_CPOS], r[_R_CNEG], r[_R_VREG])
    tau3 = u3 + friction_torque(w3, r[_R_VISC + 1], r[_R_CPOS + 1], r[_R_CNEG + 1], r[_R_VREG + 1])
    s2, c2 = _sincos_near(q2, q2b, s2b, c2b)
    s3, c3 = _sincos_near(q3, q3b, s3b, c3b)
    return joint_acceleration_sc(f, s2, c2, s3, c3, w2, w3, tau2, tau3, r[_R_G])


@_jit
def integrate_sample_fast(f, r, q2, q3, w2, w3, u2, u3, substeps):
    """:func:`integrate_sample` with one libm sin/cos per joint and sample.

    The Runge-Kutta stages inside the sample take their sines and cosines by
    angle addition from the sample's start angle (:func:`_sincos_near`): the
    same integrator, with trigonometric values equal to rounding; the tests
    check that it gives the same pulses as the reference path.  The two are
    kept as separate functions on purpose: the reference stays the plain
    implementation the fast one is checked against, and a runtime switch
    inside the stage function cost 3-9 % in this hottest loop (measured).
    """
    h = r[_R_TS] / substeps
    hh = 0.5 * h
    h6 = h * (1.0 / 6.0)
    ok = f[0] > 0.0
    q2b = q2
    q3b = q3
    s2b = math.sin(q2)
    c2b = math.cos(q2)
    s3b = math.sin(q3)
    c3b = math.cos(q3)
    for _ in range(substeps):
        a12, a13, d1 = _accel_fast(f, r, q2, q3, w2, w3, u2, u3, q2b, s2b, c2b, q3b, s3b, c3b)
        v12 = w2 + hh * a12
        v13 = w3 + hh * a13
        a22, a23, d2 = _accel_fast(f, r, q2 + hh * w2, q3 + hh * w3, v12, v13, u2, u3,
                                   q2b, s2b, c2b, q3b, s3b, c3b)
        v22 = w2 + hh * a22
        v23 = w3 + hh * a23
        a32, a33, d3 = _accel_fast(f, r, q2 + hh * v12, q3 + hh * v13, v22, v23, u2,
                                   u3, q2b, s2b, c2b, q3b, s3b, c3b)
        v32 = w2 + h * a32
        v33 = w3 + h * a33
        a42, a43, d4 = _accel_fast(f, r, q2 + h * v22, q3 + h * v23, v32, v33, u2, u3,
                                   q2b, s2b, c2b, q3b, s3b, c3b)
        if not (ok and d1 > 0.0 and d2 > 0.0 and d3 > 0.0 and d4 > 0.0):
            return q2, q3, w2, w3, STATUS_NOT_PD
        q2 += h6 * (w2 + 2.0 * v12 + 2.0 * v22 + v32)
        q3 += h6 * (w3 + 2.0 * v13 + 2.0 * v23 + v33)
        w2 += h6 * (a12 + 2.0 * a22 + 2.0 * a32 + a42)
        w3 += h6 * (a13 + 2.0 * a23 + 2.0 * a33 + a43)
    if not (math.isfinite(q2) and math.isfinite(q3) and math.isfinite(w2) and math.isfinite(w3)):
        return q2, q3, w2, w3, STATUS_NONFINITE
    return q2, q3, w2, w3, STATUS_OK


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
def _run(f, r, ref, e_log, k0, substeps, quantize, bound, err_out, write, continuous_out,
         fast):
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
        if k == n_total - 1:
            break
        if fast:
            q2, q3, w2, w3, st = integrate_sample_fast(f, r, q2, q3, w2, w3, p2 * e2, p3 * e3,
                                                       substeps)
        else:
            q2, q3, w2, w3, st = integrate_sample(f, r, q2, q3, w2, w3, p2 * e2, p3 * e3,
                                                  substeps)
        if st != STATUS_OK:
            status = st
            break
    if status != STATUS_OK:
        sse += 2.0 * bound * bound * (n - compared)
    return sse, status, compared


@numba.njit(cache=True, nogil=True, parallel=True)
def _batch(F, r, ref, e_log, k0, substeps, quantize, bound, err_out, write, continuous_out,
           fast):
    m = F.shape[0]
    obj = np.empty(m)
    status = np.empty(m, dtype=np.int64)
    compared = np.empty(m, dtype=np.int64)
    for c in prange(m):
        o, s, n_c = _run(
            F[c], r, ref, e_log, k0, substeps, quantize, bound, err_out[c], write, continuous_out,
            fast,
        )
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
):
    """Simulate the logged closed-loop experiment for a population of candidates.

    Parallel over candidates (``numba.prange``).

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
        Use :func:`integrate_sample_fast` (default) instead of the reference
        :func:`integrate_sample`; both give the same pulses (tested).

    Returns
    -------
    ExperimentSimulation
        ``e_pulses`` is ``None`` when ``errors`` is False.

    Raises
    ------
    ValueError
        On a wrongly shaped or non-finite ``F``, ``substeps < 1`` or a
        non-positive bound.
    """
    F, substeps, e_log, bound = _prepare(log, F, substeps, bound, workers)
    r, ref = _cached_inputs(log)
    m, n = F.shape[0], e_log.shape[0]
    err = np.zeros((m, n, 2)) if errors else np.zeros((m, 0, 2))
    obj, status, compared = _kernel(
        _batch, F, r, ref, e_log, int(log.start_index), substeps, bool(quantize), bound, err,
        bool(errors), bool(continuous_output), bool(fast),
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
        q2, q3, w2, w3, st = integrate_sample_fast(f, r, q2, q3, w2, w3, p2 * u2, p3 * u3,
                                                   substeps)
        if st != STATUS_OK:
            status = st
            break
    for i in range(done, e_log.shape[0]):
        out[i, 0] = bound
        out[i, 1] = bound
    return status


@numba.njit(cache=True, nogil=True, parallel=True)
def _replay_batch(F, r, ref, e_log, k0, substeps, gain, bound, out, X0, use_x0):
    m = F.shape[0]
    status = np.empty(m, dtype=np.int64)
    for c in prange(m):
        status[c] = _replay_run(F[c], r, ref, e_log, k0, substeps, gain, bound, out[c],
                                X0[c], use_x0)
    return status


def prediction_errors(
    log, F, *, gain=0.02, substeps=DEFAULT_SUBSTEPS, bound=None, workers=None,
    initial_state=None,
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
                     float(gain), bound, out, X0, use_x0)
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
                _batch(F, r, ref, e_log, 0, 1, quantize, 100.0, err, write, False, fast)
        _batch(F, r, ref, e_log, 0, 1, True, 100.0, err, True, True, fast)
    for use_x0 in (False, True):
        _replay_batch(F, r, ref, e_log, 0, 1, 0.02, 100.0, err, np.zeros((1, 4)), use_x0)
    return time.perf_counter() - t0
