"""Logged-input replay: one-step prediction errors for the refinement stage.

The P controller's current is known exactly from the logged integer error
(``i_k = P e_k``), so the model can be driven by the current the rig applied
instead of by its own, quantised, feedback.  The replay is the second mode
of the logged-run driver of the one closed-loop core
(:func:`plant.simulation.simulate.log_chunk`; one compiled kernel for both modes); the
refinement of :mod:`identification.refinement` least-squares its prediction
errors.
"""
from __future__ import annotations

import numpy as np

from plant.simulation.core import cell_centres
from plant.simulation.parallel import check_workers, run_chunks
from plant.simulation.controllers import as_logged_controller
from plant.simulation.plants import RIGID
from plant.simulation.simulate import (
    DEFAULT_SUBSTEPS,
    log_chunk,
    check_candidates,
    check_substeps,
    default_bound,
    for_kinds,
    lanes_from,
    simulation_inputs,
    start_states,
)

__all__ = ["measured_counts", "prediction_errors", "DEFAULT_REPLAY_GAIN"]

#: Output-injection gain of the replay as a fraction of the P gain (the
#: measured compromise between drift and bias; docs, identification).
DEFAULT_REPLAY_GAIN = 0.02


def measured_counts(log) -> np.ndarray:
    """Centres of the count intervals the log allows, shape (n_samples, 2) (pulses).

    The logged error gives the integer count ``a = trunc(ref) - e``; the
    continuous count c satisfies ``trunc(c) == a``, an interval of width 1
    (width 2 around 0) whose centre is returned (:func:`plant.simulation.core.cell_centre`).

    Parameters
    ----------
    log : plant.ExperimentLog

    Returns
    -------
    ndarray, shape (n_samples, 2)
    """
    inputs = simulation_inputs(log)
    a = np.trunc(inputs.ref_counts[inputs.start_index:]) - inputs.e_log
    return cell_centres(a)


def prediction_errors(
    log, F, *, gain=DEFAULT_REPLAY_GAIN, substeps=DEFAULT_SUBSTEPS, bound=None, workers=None,
    initial_state=None, plant=None, plant_parameters=None, controller=None,
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
        log's first sample, per candidate; the replay then starts there
        (required for a window log without a start state).
    plant : plant.simulation.plants.Plant, optional
        Default :data:`plant.simulation.plants.RIGID`.
    plant_parameters : dict, optional
        Per-candidate plant parameters beyond f (see
        :func:`plant.simulate_batch`).
    controller : object, optional
        The controller that ran (see :func:`plant.simulate_batch`; default
        the rig's P law).  The rig's P law is replayed as ``P e_log``;
        any other controller by the logged currents ``i_A`` (what it
        applied), both with the output injection ``gain P (m - c)``.

    Returns
    -------
    eps : ndarray, shape (n_candidates, n_samples, 2) or (n_samples, 2)
        Prediction errors in pulses.
    status : ndarray, shape (n_candidates,) or int
        :data:`~plant.simulation.core.STATUS_OK` or a failure code.

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
    X0 = start_states(log, initial_state, m, nx)
    use_x0 = X0 is not None
    out = np.empty((m, inputs.e_log.shape[0], 2))
    status = np.empty(m, dtype=np.int64)
    cost = np.empty(m)
    compared = np.empty(m, dtype=np.int64)
    Pall = plant.lane_parameters(F2, log.rig, **(plant_parameters or {}))
    x0 = plant.initial_state(inputs.constants)
    k0 = inputs.start_index
    law = as_logged_controller(controller, log)
    law.check_joints(inputs.ref_counts.shape[1])
    law.check_samples(inputs.ref_counts.shape[0])
    i_log = inputs.i_log

    run = for_kinds(log_chunk if law.driver is None else law.driver, plant.kind, law.kind,
                    law.parameters)

    def chunk(lo, hi):
        # with X0, the given state at the first logged sample: no simulation before it
        lanes = lanes_from(Pall, lo, hi, x0, X0)
        run(plant.kind, lanes, inputs.constants, plant.encoder_row, inputs.ref_counts,
            inputs.e_log, k0, k0, k0 if use_x0 else 0, substeps, True, False, float(gain),
            bound, np.inf, out, True, False, cost, status, compared, hi - lo, law.kind,
            law.parameters, law.lane_states(lanes.X.shape[1]), i_log, not law.is_p_law)

    run_chunks(chunk, m, workers)
    if single:
        return out[0], int(status[0])
    return out, status
