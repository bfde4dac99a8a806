"""Exact closed-loop simulation of the logged P-control experiment.

The simulator reproduces what the rig's control card did, sample by sample
(paper section 3), as a driver of the one closed-loop core
(:mod:`plant.core`):

* at ``t_k = k Ts`` the motor encoders are read (:func:`plant.core.encoder_read`,
  ``act = trunc(q k N / 2 pi)``, trunc rounds toward zero) and the integer
  error ``e = ref - act`` is formed with ``ref = trunc(q_ref(t_k) k N / 2 pi)``;
* the motor current ``i = P e`` is held over ``[t_k, t_k + Ts)`` (ZOH) and the
  plant (rigid by default, :data:`plant.plants.RIGID`) is advanced by
  :func:`plant.core.advance_sample` (``substeps`` RK4 steps).

All rig constants come from the log's sidecar (:func:`plant.rig.rig_constants`),
the reference from its :class:`~plant.trajectory.Trajectory`, the start state
from ``start_state``.  A log that is a window of a longer run is simulated
from ``t = 0`` and compared on its own samples only.

Failed candidates
-----------------
The compiled kernels never raise.  A candidate fails when D(q) stops being
positive definite (``det D <= 0`` or ``f1 <= 0`` at any Runge-Kutta stage),
when the state becomes non-finite, or when a simulated error leaves
``bound`` pulses (by default 100 times the largest logged error, at least 100
pulses).  Its simulation stops there and its status is set
(:data:`~plant.core.STATUS_NOT_PD`, :data:`~plant.core.STATUS_NONFINITE`,
:data:`~plant.core.STATUS_DIVERGED`).  Its output error (paper eq. 4) is then
the **penalty**

    Y = sum over the samples compared so far of (e_log - e_model)^2
        + 2 * bound^2 * (number of log samples not yet compared)

which is finite, larger than the output error of any candidate that stays
within the bound for the whole run, and smaller the later the candidate
fails, so that a rank-based optimiser can still order failed candidates.

Early termination
-----------------
With a ``cap`` (:func:`simulate_batch`) a candidate whose running sum passes
the cap is stopped (:data:`~plant.core.STATUS_STOPPED`); its output error is
the running sum extrapolated to the whole log, ``Y n_samples / n_compared``
(> cap).
"""
from __future__ import annotations

import threading
import weakref
from dataclasses import dataclass
from typing import NamedTuple

import numba
import numpy as np

from ._errors import SimulationError
from .core import (
    N_ANCHOR_ROWS,
    REANCHOR,
    STATUS_DIVERGED,
    STATUS_MESSAGES,
    STATUS_OK,
    STATUS_STOPPED,
    advance_sample,
    encoder_read,
    new_workspace,
    padded_lanes,
)
from .parallel import as_float_array, check_workers, run_chunks
from .plants import RIGID
from .rig import RigConstants, rig_constants

__all__ = [
    "DEFAULT_SUBSTEPS",
    "ExperimentSimulation",
    "SimulationInputs",
    "simulation_inputs",
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
#: pulses stop changing from 48 substeps on (tested in
#: ``tests/test_simulate.py``, figures in ``benchmarks/bench_simulate.py``).
#: Identification integrates more coarsely
#: (:data:`identification.objective.IDENTIFICATION_SUBSTEPS`).
DEFAULT_SUBSTEPS = 48


class SimulationInputs(NamedTuple):
    """What the kernels need of a log, prepared once per log object.

    Attributes
    ----------
    constants : plant.rig.RigConstants
        The rig layout of the log's sidecar.
    ref_counts : ndarray, shape (n_total, 2)
        Unquantised reference counts ``q_ref(t_k) k N / 2 pi`` from t = 0.
    e_log : ndarray, shape (n_samples, 2)
        Logged errors (float64 pulses).
    start_index : int
        Index of the log's first sample in its run.
    """

    constants: RigConstants
    ref_counts: np.ndarray
    e_log: np.ndarray
    start_index: int


def reference_counts(log) -> np.ndarray:
    """Unquantised reference encoder counts ``q_ref(t_k) k N / 2 pi`` from t = 0.

    Evaluated from the log's trajectory at ``t_k = k Ts`` for
    ``k = 0 .. start_index + n_samples - 1`` (a window log is simulated from
    the start of its run).

    Parameters
    ----------
    log : plant.ExperimentLog

    Returns
    -------
    ndarray, shape (n_total, 2), float64
    """
    rig = log.rig
    t = np.arange(log.n_total) * rig.sample_time_s
    return np.ascontiguousarray(log.trajectory.position(t) * rig.pulses_per_rad)


_PREPARED: dict = {}
_PREPARED_LOCK = threading.Lock()


def simulation_inputs(log) -> SimulationInputs:
    """The prepared inputs of a log (computed once per log object, then cached).

    The cache is keyed by the log object (a weak reference: it never keeps a
    log alive and never writes onto the frozen log).

    Parameters
    ----------
    log : plant.ExperimentLog

    Returns
    -------
    SimulationInputs
    """
    key = id(log)
    with _PREPARED_LOCK:
        hit = _PREPARED.get(key)
        if hit is not None and hit[0]() is log:
            return hit[1]
    inputs = SimulationInputs(
        rig_constants(log.rig), reference_counts(log),
        np.ascontiguousarray(log.e_pulses, dtype=np.float64), int(log.start_index))
    try:
        ref = weakref.ref(log, lambda _, k=key: _PREPARED.pop(k, None))
    except TypeError:  # an object without weak references: not cached
        return inputs
    with _PREPARED_LOCK:
        _PREPARED[key] = (ref, inputs)
    return inputs


def default_bound(e_log) -> float:
    """Early-termination bound (pulses): 100 times the largest logged error, at least 100.

    Parameters
    ----------
    e_log : array_like, shape (n_samples, 2)

    Returns
    -------
    float
    """
    m = float(np.max(np.abs(e_log))) if np.size(e_log) else 0.0
    return max(100.0 * m, 100.0)


# ----------------------------------------------------------------------------
# Lane bookkeeping shared by the batch drivers
# ----------------------------------------------------------------------------
_jit = numba.njit(cache=True, nogil=True, error_model="numpy")


@_jit
def new_lanes(Pall, lo, hi, x0):
    """Lane arrays of candidates ``lo:hi``: one column per candidate.

    Returns ``(P, X, U, A, S, E, idx)``: parameters, state (start state
    ``x0`` in every column), held currents, anchors, status, running sum of
    squares and candidate index per lane.  Columns beyond ``hi - lo`` are
    padding (copies of the first candidate).
    """
    lanes = padded_lanes(hi - lo)
    npar = Pall.shape[0]
    nx = x0.shape[0]
    P = np.empty((npar, lanes))
    X = np.empty((nx, lanes))
    idx = np.empty(lanes, dtype=np.int64)
    for j in range(lanes):
        cnd = lo + j if lo + j < hi else lo
        idx[j] = cnd
        for p in range(npar):
            P[p, j] = Pall[p, cnd]
        for i in range(nx):
            X[i, j] = x0[i]
    return (P, X, np.zeros((2, lanes)), np.zeros((N_ANCHOR_ROWS, lanes)),
            np.zeros(lanes, dtype=np.int64), np.zeros(lanes), idx)


@_jit
def _move_lane(P, X, U, A, S, E, idx, dst, src):
    for i in range(P.shape[0]):
        P[i, dst] = P[i, src]
    for i in range(X.shape[0]):
        X[i, dst] = X[i, src]
    for i in range(2):
        U[i, dst] = U[i, src]
    for i in range(A.shape[0]):
        A[i, dst] = A[i, src]
    S[dst] = S[src]
    E[dst] = E[src]
    idx[dst] = idx[src]


@_jit
def retire_lane(P, X, U, A, S, E, idx, j, act):
    """Retire lane ``j``: the last active lane moves into it; returns the new count.

    The vacated column becomes padding, a copy of a running lane (lane 0), so
    the SIMD loops never compute on a failed state.
    """
    last = act - 1
    if j != last:
        _move_lane(P, X, U, A, S, E, idx, j, last)
    if last > 0:
        _move_lane(P, X, U, A, S, E, idx, last, 0)
    return last


@_jit
def _final_objective(sse, status, compared, n, bound):
    """Output error of a finished candidate, with the module docstring's penalties."""
    if status == STATUS_OK:
        return sse
    if status == STATUS_STOPPED:
        return sse * n / compared  # extrapolated to the whole log (> cap)
    return sse + 2.0 * bound * bound * (n - compared)


# ----------------------------------------------------------------------------
# The P-control experiment driver
# ----------------------------------------------------------------------------
@_jit
def _experiment_chunk(rhs, Pall, c, x0, enc, ref, e_log, k0, substeps, quantize, bound, cap,
                      err_out, write, continuous_out, obj, status, compared, lo, hi):
    """Simulate candidates ``lo:hi`` of the P experiment in lockstep (one lane each).

    ``ref`` (n_total, 2) unquantised reference counts; ``e_log`` (n, 2) logged
    errors compared from sample ``k0`` on.  With ``quantize`` the encoder and
    reference counts are truncated as on the rig; without, the loop is the
    smooth surrogate with continuous counts.  With ``continuous_out`` the
    compared (and written) output is the unquantised error
    ``ref - q k N / 2 pi``.  Results go to ``obj[i]``, ``status[i]``,
    ``compared[i]`` and ``err_out[i]`` of candidate i; a lane that fails or
    is stopped is retired at once (early termination pays).
    """
    P, X, U, A, S, E, idx = new_lanes(Pall, lo, hi, x0)
    W = new_workspace(X.shape[0], X.shape[1])
    n_total = ref.shape[0]
    n = e_log.shape[0]
    sc2, sc3 = c.pulses_per_rad
    p2, p3 = c.p_gain
    act = hi - lo
    cmp = 0
    for k in range(n_total):
        r2 = ref[k, 0]
        r3 = ref[k, 1]
        # divergence on the continuous error first, so truncation never sees a huge value
        for j in range(act - 1, -1, -1):
            if abs(r2 - X[enc, j] * sc2) > bound or abs(r3 - X[enc + 1, j] * sc3) > bound:
                c_ = idx[j]
                obj[c_] = _final_objective(E[j], STATUS_DIVERGED, cmp, n, bound)
                status[c_] = STATUS_DIVERGED
                compared[c_] = cmp
                act = retire_lane(P, X, U, A, S, E, idx, j, act)
        if act == 0:
            break
        _, t2 = encoder_read(r2, 1.0)
        _, t3 = encoder_read(r3, 1.0)
        i = k - k0
        el2 = e_log[i, 0] if i >= 0 else 0.0
        el3 = e_log[i, 1] if i >= 0 else 0.0
        for j in range(padded_lanes(act)):  # SIMD over the lanes
            c2, a2 = encoder_read(X[enc, j], sc2)
            c3, a3 = encoder_read(X[enc + 1, j], sc3)
            e2 = t2 - a2 if quantize else r2 - c2
            e3 = t3 - a3 if quantize else r3 - c3
            if i >= 0:
                d2 = el2 - (r2 - c2 if continuous_out else e2)
                d3 = el3 - (r3 - c3 if continuous_out else e3)
                E[j] += d2 * d2 + d3 * d3
            U[0, j] = p2 * e2
            U[1, j] = p3 * e3
        if i >= 0:
            cmp = i + 1
            if write:
                for j in range(act):
                    c2, a2 = encoder_read(X[enc, j], sc2)
                    c3, a3 = encoder_read(X[enc + 1, j], sc3)
                    if continuous_out or not quantize:
                        err_out[idx[j], i, 0] = r2 - c2
                        err_out[idx[j], i, 1] = r3 - c3
                    else:
                        err_out[idx[j], i, 0] = t2 - a2
                        err_out[idx[j], i, 1] = t3 - a3
            for j in range(act - 1, -1, -1):
                if E[j] > cap:
                    c_ = idx[j]
                    obj[c_] = _final_objective(E[j], STATUS_STOPPED, cmp, n, bound)
                    status[c_] = STATUS_STOPPED
                    compared[c_] = cmp
                    act = retire_lane(P, X, U, A, S, E, idx, j, act)
            if act == 0:
                break
        if k == n_total - 1:
            break
        advance_sample(rhs, P, c, X, U, A, S, W, padded_lanes(act), substeps, k % REANCHOR == 0)
        for j in range(act - 1, -1, -1):
            code = S[j]
            if code != STATUS_OK:
                c_ = idx[j]
                obj[c_] = _final_objective(E[j], code, cmp, n, bound)
                status[c_] = code
                compared[c_] = cmp
                act = retire_lane(P, X, U, A, S, E, idx, j, act)
        if act == 0:
            break
    for j in range(act):
        c_ = idx[j]
        obj[c_] = E[j]
        status[c_] = STATUS_OK
        compared[c_] = cmp


# ----------------------------------------------------------------------------
# Python API
# ----------------------------------------------------------------------------
@dataclass(frozen=True)
class ExperimentSimulation:
    """Simulated tracking errors of a batch of candidates on one log.

    Attributes
    ----------
    e_pulses : ndarray, shape (n_candidates, n_samples, 2) or None
        Simulated tracking errors (int64 pulses; float64 when simulated
        without quantisation or with continuous output).  Samples after a
        candidate failed are 0.  None when not requested.
    objective : ndarray, shape (n_candidates,)
        Output error (paper eq. 4) against the log, pulses^2, with the penalty
        of the module docstring for failed candidates.
    status : ndarray, shape (n_candidates,)
        :data:`~plant.core.STATUS_OK` or the failure code
        (:data:`~plant.core.STATUS_MESSAGES`).
    n_compared : ndarray, shape (n_candidates,)
        Log samples compared before the end of the run or the failure.
    """

    e_pulses: np.ndarray
    objective: np.ndarray
    status: np.ndarray
    n_compared: np.ndarray


def check_candidates(F) -> np.ndarray:
    """Candidates as a C-contiguous float64 array of shape (m, 9).

    Raises
    ------
    ValueError
        On a wrong shape or NaN/inf.
    """
    F = np.asarray(F, dtype=np.float64)
    if F.ndim != 2 or F.shape[1] != 9:
        raise ValueError(f"candidates must have shape (n_candidates, 9), got {F.shape}")
    return as_float_array(F, "candidate parameters")


def check_substeps(substeps) -> int:
    """``substeps`` as an int >= 1.

    Raises
    ------
    ValueError
        If it is not a whole number >= 1.
    """
    s = int(substeps)
    if s < 1 or s != substeps:
        raise ValueError(f"substeps must be a whole number >= 1, got {substeps!r}")
    return s


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
    cap=None,
    plant=None,
):
    """Simulate the logged closed-loop experiment for a population of candidates.

    Parallel over candidates: the population is split into one chunk per
    thread, and each chunk advances its candidates in lockstep, one SIMD
    lane each, through the one closed-loop core.

    Parameters
    ----------
    log : plant.ExperimentLog
        The experiment: rig, trajectory, start state and logged errors.
    F : array_like, shape (n_candidates, 9)
        Candidate base parameters f1..f9 (rigid-equivalent for a flexible
        plant).
    substeps : int
        RK4 steps per sample (>= 1); fewer is faster and less exact.
    errors : bool
        Return the simulated error sequences too (else only the output errors).
    quantize : bool
        Truncate encoder counts as the rig does (True: exact experiment).
        False gives the smooth surrogate closed loop with continuous counts.
    bound : float, optional
        Early-termination bound on abs(e) (pulses); default :func:`default_bound`.
    workers : int, optional
        Threads (default: the CPUs available to the process).
    continuous_output : bool
        Compare and return the unquantised model error ``ref - q k N / 2 pi``
        while the feedback stays as set by ``quantize``.
    cap : float, optional
        Early termination: a candidate whose running sum of squares passes
        ``cap`` (pulses^2) stops there with status ``STATUS_STOPPED`` and
        objective ``Y n_samples / n_compared`` (> ``cap``).  Default: no cap.
    plant : plant.plants.Plant, optional
        The simulated plant (default :data:`plant.plants.RIGID`; e.g. a
        :class:`plant.plants.FlexibleJoints`).

    Returns
    -------
    ExperimentSimulation

    Raises
    ------
    ValueError
        On a wrongly shaped or non-finite ``F``, ``substeps < 1``, a
        non-positive bound, a NaN cap or bad ``workers``.
    """
    F = check_candidates(F)
    substeps = check_substeps(substeps)
    workers = check_workers(workers)
    plant = RIGID if plant is None else plant
    inputs = simulation_inputs(log)
    e_log = inputs.e_log
    bound = default_bound(e_log) if bound is None else float(bound)
    if not bound > 0:
        raise ValueError(f"bound must be positive, got {bound}")
    cap = np.inf if cap is None else float(cap)
    if np.isnan(cap):
        raise ValueError("cap must be a number (or None), got NaN")
    m, n = F.shape[0], e_log.shape[0]
    err = np.zeros((m, n, 2)) if errors else np.zeros((m, 0, 2))
    obj = np.empty(m)
    status = np.empty(m, dtype=np.int64)
    compared = np.empty(m, dtype=np.int64)
    Pall = plant.lane_parameters(F, log.rig)
    x0 = plant.initial_state(inputs.constants)

    def chunk(lo, hi):
        _experiment_chunk(plant.rhs, Pall, inputs.constants, x0, plant.encoder_row,
                          inputs.ref_counts, e_log, inputs.start_index, substeps,
                          bool(quantize), bound, cap, err, bool(errors),
                          bool(continuous_output), obj, status, compared, lo, hi)

    run_chunks(chunk, m, workers)
    if errors and quantize and not continuous_output:
        err = err.astype(np.int64)
    return ExperimentSimulation(err if errors else None, obj, status, compared)


def output_error(log, F, *, substeps=DEFAULT_SUBSTEPS, bound=None, workers=None):
    """Output error of paper eq. 4 for one candidate or a population.

    ``Y(f) = sum_k sum_j (e_log[k, j] - e_model[k, j])^2`` in pulses^2, with
    the penalty of the module docstring for failed candidates.

    Parameters
    ----------
    log : plant.ExperimentLog
        The logged experiment.
    F : array_like, shape (9,) or (n_candidates, 9)
        Base parameters.
    substeps : int
        RK4 steps per sample.
    bound : float, optional
        Divergence bound (pulses).
    workers : int, optional
        Threads.

    Returns
    -------
    float or ndarray, shape (n_candidates,)
    """
    F = np.asarray(F, dtype=np.float64)
    single = F.ndim == 1
    sim = simulate_batch(log, F.reshape(1, -1) if single else F, substeps=substeps,
                         errors=False, bound=bound, workers=workers)
    return float(sim.objective[0]) if single else sim.objective


def simulate_experiment(log, f, *, substeps=DEFAULT_SUBSTEPS, quantize=True, bound=None,
                        plant=None):
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
    plant : plant.plants.Plant, optional
        Default :data:`plant.plants.RIGID`.

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
    sim = simulate_batch(log, f[None], substeps=substeps, quantize=quantize, bound=bound,
                         workers=1, plant=plant)
    st = int(sim.status[0])
    if st != STATUS_OK:
        k = int(log.start_index) + int(sim.n_compared[0])
        raise SimulationError(
            f"simulation of {getattr(log, 'name', 'log')} failed at t = "
            f"{k * log.rig.sample_time_s:.4f} s: {STATUS_MESSAGES[st]}"
        )
    return sim.e_pulses[0]


def _dummy_problem():
    """A three-sample problem in the kernels' exact argument types (warm-up)."""
    c = RigConstants(1e-3, (1.0, 1.0), (1.0, 1.0), (1.0, 1.0), (0.0, 0.0), (0.0, 0.0),
                     (0.0, 0.0), (1.0, 1.0), 9.81, (0.0, 0.0), (0.0, 0.0))
    Pall = np.ones((9, 1))
    return c, Pall, np.zeros((3, 2)), np.zeros((3, 2))


def _warm_arguments():
    """Arguments of :func:`_experiment_chunk` on the three-sample dummy problem."""
    c, Pall, ref, e_log = _dummy_problem()
    return (RIGID.rhs, Pall, c, RIGID.initial_state(c), RIGID.encoder_row, ref, e_log, 0, 1,
            True, 100.0, np.inf, np.zeros((1, 3, 2)), True, False, np.empty(1),
            np.empty(1, dtype=np.int64), np.empty(1, dtype=np.int64), 0, 1)


def _warm():
    _experiment_chunk(*_warm_arguments())
