"""Logged-input replay: one-step prediction errors for the refinement stage.

The P controller's current is known exactly from the logged integer error
(``i_k = P e_k``), so the model can be driven by the current the rig applied
instead of by its own, quantised, feedback.  This module is the driver of the
one closed-loop core (:mod:`plant.core`) that does so; the refinement of
:mod:`identification.refine` least-squares its prediction errors.
"""
from __future__ import annotations

import numpy as np

from .core import (
    REANCHOR,
    STATUS_DIVERGED,
    STATUS_OK,
    advance_sample,
    cell_centre,
    encoder_read,
    new_workspace,
    padded_lanes,
)
from .parallel import as_float_array, check_workers, run_chunks
from .plants import RIGID
from .simulate import (
    DEFAULT_SUBSTEPS,
    _dummy_problem,
    _jit,
    check_candidates,
    check_substeps,
    default_bound,
    new_lanes,
    retire_lane,
    simulation_inputs,
)

__all__ = ["measured_counts", "prediction_errors", "DEFAULT_REPLAY_GAIN"]

#: Output-injection gain of the replay as a fraction of the P gain (the
#: measured compromise between drift and bias; docs, identification).
DEFAULT_REPLAY_GAIN = 0.02


def measured_counts(log) -> np.ndarray:
    """Centres of the count intervals the log allows, shape (n_samples, 2) (pulses).

    The logged error gives the integer count ``a = trunc(ref) - e``; the
    continuous count c satisfies ``trunc(c) == a``, an interval of width 1
    (width 2 around 0) whose centre is returned (:func:`plant.core.cell_centre`).

    Parameters
    ----------
    log : plant.ExperimentLog

    Returns
    -------
    ndarray, shape (n_samples, 2)
    """
    inputs = simulation_inputs(log)
    a = np.trunc(inputs.ref_counts[inputs.start_index:]) - inputs.e_log
    return np.vectorize(cell_centre, otypes=[float])(a)


@_jit
def _fill_failed(out, done, bound):
    """Prediction errors of a failed candidate from sample ``done`` on: ``bound``."""
    for i in range(done, out.shape[0]):
        out[i, 0] = bound
        out[i, 1] = bound


@_jit
def _replay_chunk(rhs, Pall, c, x0, enc, ref, e_log, k0, substeps, gain, bound, out, X0,
                  use_x0, status, lo, hi):
    """Replay candidates ``lo:hi`` in lockstep; prediction errors into ``out[i]``."""
    P, X, U, A, S, E, idx = new_lanes(Pall, lo, hi, x0)
    W = new_workspace(X.shape[0], X.shape[1])
    n_total = ref.shape[0]
    sc2, sc3 = c.pulses_per_rad
    p2, p3 = c.p_gain
    k_start = k0 if use_x0 else 0
    if use_x0:  # given state at the first logged sample: no simulation before it
        for j in range(X.shape[1]):
            for r in range(X0.shape[1]):
                X[r, j] = X0[idx[j], r]
    act = hi - lo
    for k in range(k_start, n_total):
        r2 = ref[k, 0]
        r3 = ref[k, 1]
        i = k - k0
        for j in range(act - 1, -1, -1):
            if abs(r2 - X[enc, j] * sc2) > bound or abs(r3 - X[enc + 1, j] * sc3) > bound:
                status[idx[j]] = STATUS_DIVERGED
                _fill_failed(out[idx[j]], max(i, 0), bound)
                act = retire_lane(P, X, U, A, S, E, idx, j, act)
        if act == 0:
            break
        if i < 0:
            # Before a window: the run's own P loop with continuous counts (the
            # smooth closed loop), so that the state reached is smooth in f.
            for j in range(padded_lanes(act)):
                c2, _ = encoder_read(X[enc, j], sc2)
                c3, _ = encoder_read(X[enc + 1, j], sc3)
                U[0, j] = p2 * (r2 - c2)
                U[1, j] = p3 * (r3 - c3)
        else:
            _, t2 = encoder_read(r2, 1.0)
            _, t3 = encoder_read(r3, 1.0)
            m2 = cell_centre(t2 - e_log[i, 0])
            m3 = cell_centre(t3 - e_log[i, 1])
            for j in range(padded_lanes(act)):
                c2, _ = encoder_read(X[enc, j], sc2)
                c3, _ = encoder_read(X[enc + 1, j], sc3)
                # logged input (the current the rig applied) plus the predictor correction
                U[0, j] = p2 * (e_log[i, 0] + gain * (m2 - c2))
                U[1, j] = p3 * (e_log[i, 1] + gain * (m3 - c3))
            for j in range(act):
                c2, _ = encoder_read(X[enc, j], sc2)
                c3, _ = encoder_read(X[enc + 1, j], sc3)
                out[idx[j], i, 0] = m2 - c2
                out[idx[j], i, 1] = m3 - c3
        if k == n_total - 1:
            break
        advance_sample(rhs, P, c, X, U, A, S, W, padded_lanes(act), substeps,
                       (k - k_start) % REANCHOR == 0)
        for j in range(act - 1, -1, -1):
            code = S[j]
            if code != STATUS_OK:
                status[idx[j]] = code
                _fill_failed(out[idx[j]], max(i + 1, 0), bound)
                act = retire_lane(P, X, U, A, S, E, idx, j, act)
        if act == 0:
            break
    for j in range(act):
        status[idx[j]] = STATUS_OK


def prediction_errors(
    log, F, *, gain=DEFAULT_REPLAY_GAIN, substeps=DEFAULT_SUBSTEPS, bound=None, workers=None,
    initial_state=None, plant=None,
):
    """One-step prediction errors of the model replaying the logged input.

    The model is driven by the current the rig applied (``i_k = P e_k`` from
    the logged integer error); its continuous encoder count
    ``c_k = q_k k N / 2 pi`` is compared with the centre ``m_k`` of the unit
    interval of counts that the log allows (``trunc(c) = trunc(ref_k) - e_k``),
    and a weak output-injection correction ``gain P (m_k - c_k)`` keeps the
    replay from drifting (an observer in the sense of prediction-error
    methods; Ljung, *System Identification*, 2nd ed., sec. 7).  The prediction
    errors ``m_k - c_k`` are smooth in f: unlike the integer output error of
    eq. 4 they do not flip by whole pulses, so a Gauss-Newton method can use
    them.  A window log is first simulated under its P loop from t = 0 up to
    the window (with continuous counts in the feedback), unless
    ``initial_state`` gives the state at its first sample.

    Parameters
    ----------
    log : plant.ExperimentLog
        The logged experiment.
    F : array_like, shape (n_candidates, 9) or (9,)
        Candidate base parameters.
    gain : float
        Output-injection gain as a fraction of the P gain (>= 0).  0 is the
        pure replay (unbiased, but a gravity error makes it drift); large
        values approach the smooth closed loop (biased by the missing
        quantisation).
    substeps : int
        RK4 steps per sample.
    bound : float, optional
        Divergence bound (counts); failed candidates get ``bound`` as their
        prediction error from the failure on.
    workers : int, optional
        Threads for the loop over candidates.
    initial_state : array_like, shape (n_candidates, n_x) or (n_x,), optional
        State (q2, q3, qd2, qd3 for the rigid plant) in rad, rad/s at the
        log's first sample, per candidate; the replay then starts there.
    plant : plant.plants.Plant, optional
        Default :data:`plant.plants.RIGID`.

    Returns
    -------
    eps : ndarray, shape (n_candidates, n_samples, 2) or (n_samples, 2)
        Prediction errors in pulses.
    status : ndarray, shape (n_candidates,) or int
        :data:`~plant.core.STATUS_OK` or a failure code.

    Raises
    ------
    ValueError
        On wrong shapes, NaN/inf, ``gain < 0``, ``substeps < 1``.
    """
    F = np.asarray(F, dtype=np.float64)
    single = F.ndim == 1
    F2 = check_candidates(F.reshape(1, -1) if single else F)
    substeps = check_substeps(substeps)
    workers = check_workers(workers)
    if not gain >= 0:
        raise ValueError(f"gain must be >= 0, got {gain}")
    plant = RIGID if plant is None else plant
    inputs = simulation_inputs(log)
    bound = default_bound(inputs.e_log) if bound is None else float(bound)
    if not bound > 0:
        raise ValueError(f"bound must be positive, got {bound}")
    m, nx = F2.shape[0], plant.n_states
    if initial_state is None:
        X0, use_x0 = np.zeros((m, nx)), False
    else:
        X0 = as_float_array(np.broadcast_to(np.asarray(initial_state, float), (m, nx)),
                            "initial_state")
        use_x0 = True
    out = np.empty((m, inputs.e_log.shape[0], 2))
    status = np.empty(m, dtype=np.int64)
    Pall = plant.lane_parameters(F2, log.rig)
    x0 = plant.initial_state(inputs.constants)

    def chunk(lo, hi):
        _replay_chunk(plant.rhs, Pall, inputs.constants, x0, plant.encoder_row,
                      inputs.ref_counts, inputs.e_log, inputs.start_index, substeps,
                      float(gain), bound, out, X0, use_x0, status, lo, hi)

    run_chunks(chunk, m, workers)
    if single:
        return out[0], int(status[0])
    return out, status


def _warm():
    c, Pall, ref, e_log = _dummy_problem()
    out = np.zeros((1, 3, 2))
    for use_x0 in (False, True):
        _replay_chunk(RIGID.rhs, Pall, c, RIGID.initial_state(c), RIGID.encoder_row, ref,
                      e_log, 0, 1, 0.02, 100.0, out, np.zeros((1, 4)), use_x0,
                      np.empty(1, dtype=np.int64), 0, 1)
