"""Lanes: the per-candidate columns that the core advances side by side.

A chunk of candidates lives in a few arrays, one column (a *lane*) per
candidate (:class:`Lanes`, allocated in Python so that no allocation is
compiled); a lane that fails, diverges or is stopped leaves at once
(:func:`retire_lane`), the last active lane moving into its column, so that
the SIMD loops of the core run only over the candidates still being
simulated.
"""
from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np

from plant.simulation.anchors import anchor_rows
from plant.simulation.core import STATUS_OK, STATUS_STOPPED, new_workspace, padded_lanes
from plant.simulation.parallel import as_float_array

__all__ = ["Lanes", "new_lanes", "start_states", "lanes_from", "retire_lane", "final_objective"]

_jit = numba.njit(nogil=True, error_model="numpy")


class Lanes(NamedTuple):
    """The arrays of one chunk of lanes (one column per candidate).

    Allocated in Python (numpy), so that no allocation is compiled.

    Attributes
    ----------
    P : ndarray, shape (n_par, lanes)
        Plant parameters.
    X : ndarray, shape (n_x, lanes)
        State (the start state in every column).
    U : ndarray, shape (n_u, lanes)
        Held motor currents (A).
    A : ndarray, shape (3 m, lanes)
        Trigonometric anchors (:mod:`plant.simulation.anchors`).
    S : ndarray, shape (lanes,), int64
        Status per lane.
    E : ndarray, shape (lanes,)
        Running sum of squares per lane (pulses^2).
    idx : ndarray, shape (lanes,), int64
        Candidate index of each lane.
    W : tuple of ndarray
        Scratch of :func:`plant.simulation.core.advance_sample`: K1..K4 (n_x + 1,
        lanes), XS (n_x, lanes).
    """

    P: np.ndarray
    X: np.ndarray
    U: np.ndarray
    A: np.ndarray
    S: np.ndarray
    E: np.ndarray
    idx: np.ndarray
    W: tuple


def new_lanes(Pall, lo, hi, x0, n_inputs=2, n_angles=2) -> Lanes:
    """Lane arrays of candidates ``lo:hi`` of ``Pall`` (n_par, m).

    Columns beyond ``hi - lo`` (SIMD padding, :func:`plant.simulation.core.padded_lanes`)
    are copies of the first candidate.

    Parameters
    ----------
    Pall : ndarray, shape (n_par, m)
        Plant parameters of all candidates.
    lo, hi : int
        The chunk's candidates.
    x0 : ndarray, shape (n_x,)
        Start state.
    n_inputs, n_angles : int
        The plant's motor currents and angles (its registration,
        :class:`plant.simulation.plants.RightHandSide`; 2 and 2 for the PUMA links 2-3).

    Returns
    -------
    Lanes
    """
    lanes = int(padded_lanes(hi - lo))
    idx = np.arange(lo, lo + lanes, dtype=np.int64)
    idx[hi - lo:] = lo
    nx = x0.shape[0]
    return Lanes(np.ascontiguousarray(Pall[:, idx]), np.ascontiguousarray(np.tile(x0[:, None], (1, lanes))),
                 np.zeros((int(n_inputs), lanes)), np.zeros((anchor_rows(n_angles), lanes)),
                 np.zeros(lanes, dtype=np.int64), np.zeros(lanes), idx,
                 new_workspace(nx, lanes))


def start_states(log, initial_state, m, nx):
    """Per-candidate states at a log's first sample, or None (start at t = 0).

    Parameters
    ----------
    log : plant.ExperimentLog
    initial_state : array_like, shape (m, nx) or (nx,), or None
        State at the log's first sample (rad, rad/s).
    m, nx : int
        Candidates and state components.

    Returns
    -------
    ndarray, shape (m, nx), or None

    Raises
    ------
    ValueError
        On a wrong shape or NaN/inf, or no ``initial_state`` for a window
        log without a start state.
    """
    if initial_state is None:
        if log.rig.q0_rad is None or log.rig.qd0_rad_per_s is None:
            raise ValueError(f"{getattr(log, 'name', 'log')} is a window without a start state: "
                             "give initial_state= (the state at its first sample)")
        return None
    x = np.asarray(initial_state, dtype=float)
    if x.shape not in ((nx,), (m, nx)):
        raise ValueError(f"initial_state must have shape ({nx},) or ({m}, {nx}), got {x.shape}")
    return as_float_array(np.broadcast_to(x, (m, nx)), "initial_state")


def lanes_from(Pall, lo, hi, x0, X0):
    """:func:`new_lanes`, each lane started from its candidate's row of ``X0`` if given.

    Parameters
    ----------
    Pall : ndarray, shape (n_par, m)
        Plant parameters of all candidates.
    lo, hi : int
        The chunk's candidates.
    x0 : ndarray, shape (n_x,)
        Start state shared by all lanes.
    X0 : ndarray, shape (m, n_x), or None
        Per-candidate start states (override ``x0``).

    Returns
    -------
    Lanes
    """
    lanes = new_lanes(Pall, lo, hi, x0)
    if X0 is not None:
        lanes.X[:] = X0[lanes.idx].T
    return lanes


@_jit
def _move_lane(P, X, U, A, S, E, idx, CS, dst, src):
    for i in range(CS.shape[0]):
        CS[i, dst] = CS[i, src]
    for i in range(P.shape[0]):
        P[i, dst] = P[i, src]
    for i in range(X.shape[0]):
        X[i, dst] = X[i, src]
    for i in range(U.shape[0]):
        U[i, dst] = U[i, src]
    for i in range(A.shape[0]):
        A[i, dst] = A[i, src]
    S[dst] = S[src]
    E[dst] = E[src]
    idx[dst] = idx[src]


@_jit
def retire_lane(P, X, U, A, S, E, idx, CS, j, act):
    """Retire lane ``j``: the last active lane moves into it; returns the new count.

    The vacated column becomes padding, a copy of a running lane (lane 0), so
    the SIMD loops never compute on a failed state.

    Parameters
    ----------
    P, X, U, A, S, E, idx : ndarray
        The lane arrays of :class:`Lanes`.
    CS : ndarray, shape (n_cs, lanes)
        The lanes' controller states (:mod:`plant.simulation.controllers`).
    j : int
        Lane to retire.
    act : int
        Active lanes before.

    Returns
    -------
    int
        Active lanes after (``act - 1``).
    """
    last = act - 1
    if j != last:
        _move_lane(P, X, U, A, S, E, idx, CS, j, last)
    if last > 0:
        _move_lane(P, X, U, A, S, E, idx, CS, last, np.int64(0))
    return last


@_jit
def final_objective(sse, status, compared, n, bound):
    """Output error (pulses^2) of a finished candidate, with the penalties of :mod:`plant.simulation.simulate`.

    Parameters
    ----------
    sse : float
        Running sum of squares when the candidate finished.
    status : int
        Its status code (:mod:`plant.simulation.core`).
    compared : int
        Log samples compared.
    n : int
        Log samples.
    bound : float
        Divergence bound (pulses).

    Returns
    -------
    float
    """
    if status == STATUS_OK:
        return sse
    if status == STATUS_STOPPED:
        return sse * n / compared  # extrapolated to the whole log (> cap)
    return sse + 2.0 * bound * bound * (n - compared)
