"""Exact closed-loop simulation of the logged P-control experiment.

The simulator reproduces what the rig's control card did, sample by sample
(paper section 3), as a driver of the one closed-loop core
(:mod:`plant.simulation.core`):

* at ``t_k = k Ts`` the motor encoders are read (:func:`plant.simulation.core.encoder_read`,
  ``act = trunc(q k N / 2 pi)``, trunc rounds toward zero) and the integer
  error ``e = ref - act`` is formed with ``ref = trunc(q_ref(t_k) k N / 2 pi)``;
* the motor current ``i = P e`` is held over ``[t_k, t_k + Ts)`` (ZOH) and the
  plant (rigid by default, :data:`plant.simulation.plants.RIGID`) is advanced by
  :func:`plant.simulation.core.advance_sample` (``substeps`` RK4 steps).

All rig constants come from the log's sidecar (:func:`plant.logs.rig.rig_constants`),
the reference from its :class:`~plant.logs.trajectory.Trajectory`, the start state
from ``start_state``.  A log that is a window of a longer run is simulated
from ``t = 0`` and compared on its own samples only -- unless the state at
the window's first sample is given (``initial_state=``): then the simulation
starts there.  A window whose sidecar gives no start state (the rig's
``q0_rad`` is None) needs ``initial_state``.

Failed candidates
-----------------
The compiled kernels never raise.  A candidate fails when D(q) stops being
positive definite (``det D <= 0`` or ``f1 <= 0`` at any Runge-Kutta stage),
when the state becomes non-finite, or when a simulated error leaves
``bound`` pulses (by default 100 times the largest logged error, at least 100
pulses).  Its simulation stops there and its status is set
(:data:`~plant.simulation.core.STATUS_NOT_PD`, :data:`~plant.simulation.core.STATUS_NONFINITE`,
:data:`~plant.simulation.core.STATUS_DIVERGED`).  Its output error (paper eq. 4) is then
the **penalty**

    Y = sum over the samples compared so far of (e_log - e_model)^2
        + 2 * bound^2 * (number of log samples not yet compared)

which is finite, larger than the output error of any candidate that stays
within the bound for the whole run, and smaller the later the candidate
fails, so that a rank-based optimiser can still order failed candidates.

Early termination
-----------------
With a ``cap`` (:func:`simulate_batch`) a candidate whose running sum passes
the cap is stopped (:data:`~plant.simulation.core.STATUS_STOPPED`); its output error is
the running sum extrapolated to the whole log, ``Y n_samples / n_compared``
(> cap).
"""
from __future__ import annotations

import math
import sys
import threading
import weakref
from dataclasses import dataclass
from typing import NamedTuple

import numba
import numpy as np

from plant._errors import SimulationError
from plant.simulation.anchors import REANCHOR
from plant.simulation.core import (
    STATUS_DIVERGED,
    STATUS_MESSAGES,
    STATUS_OK,
    STATUS_STOPPED,
    advance_sample,
    cell_centre,
    encoder_read,
    padded_lanes,
)
from plant.simulation.controllers import (P_LAW, as_logged_controller, control_law, is_p_law,
                                          p_current)
from plant.simulation.lanes import (  # noqa: F401 (Lanes, new_lanes re-exported for the other drivers)
    Lanes,
    final_objective,
    lanes_from,
    new_lanes,
    retire_lane,
    start_states,
)
from plant.simulation.parallel import as_float_array, check_workers, run_chunks
from plant.simulation.plants import RIGID
from plant.logs.rig import RigConstants, rig_constants

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
    "for_kinds",
    "CACHEABLE_PACKAGES",
    "GENERATED_PREFIX",
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
    constants : plant.logs.rig.RigConstants
        The rig layout of the log's sidecar.
    ref_counts : ndarray, shape (n_total, 2)
        Unquantised reference counts ``q_ref(t_k) k N / 2 pi`` from t = 0.
    e_log : ndarray, shape (n_samples, 2)
        Logged errors (float64 pulses).
    start_index : int
        Index of the log's first sample in its run.
    i_log : ndarray, shape (n_samples, 2)
        Logged currents (A), a writable copy (the kernels take one array
        type, so a read-only log array would compile a second kernel).
    """

    constants: RigConstants
    ref_counts: np.ndarray
    e_log: np.ndarray
    start_index: int
    i_log: np.ndarray


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
        np.ascontiguousarray(log.e_pulses, dtype=np.float64), int(log.start_index),
        np.array(log.i_A, dtype=np.float64, order="C"))
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
#: Kernels called from Python (cached on disk) and helpers compiled into them.
kernel = numba.njit(cache=True, nogil=True, error_model="numpy")
_jit = numba.njit(nogil=True, error_model="numpy")

#: Packages whose plant and control-law kinds a kernel cached on disk is compiled for.
#: numba pickles a cached kernel's signatures, kind classes included, into the
#: kernel's index file; a kind class from any other module (a user's script, a test)
#: would make every later process that loads the index fail to import it.  A robot
#: model's generated kinds live in ``plant.simulation.generated`` (importable while
#: their file is kept: see :func:`for_kinds`).
CACHEABLE_PACKAGES = ("plant", "ctc", "identification")

#: Prefix of the modules generated per robot (:mod:`plant.simulation.generated`).
GENERATED_PREFIX = "plant.simulation.generated."

_UNCACHED = {}
_UNCACHED_LOCK = threading.Lock()
_HOMES = {}


def _importable(value, homes=frozenset()) -> bool:
    """Whether every class in ``value`` (through tuples) is the library's, numpy's or builtin,
    and a generated module's only when that module is one of ``homes``."""
    module = type(value).__module__
    if module.split(".")[0] not in CACHEABLE_PACKAGES + ("builtins", "numpy"):
        return False
    if module.startswith(GENERATED_PREFIX) and module not in homes:
        return False
    return not isinstance(value, tuple) or all(_importable(v, homes) for v in value)


def _homes(dispatcher) -> frozenset:
    """The generated modules whose classes ``dispatcher``'s on-disk cache may name: its own
    module, if generated, and the generated modules that one imports from (they exist
    whenever it does: it cannot be imported without them)."""
    name = dispatcher.py_func.__module__
    homes = _HOMES.get(name)
    if homes is None:
        homes = set()
        if name.startswith(GENERATED_PREFIX):
            homes.add(name)
            for v in vars(sys.modules[name]).values():
                source = getattr(getattr(v, "py_func", v), "__module__", None)
                if isinstance(source, str) and source.startswith(GENERATED_PREFIX):
                    homes.add(source)
        homes = _HOMES[name] = frozenset(homes)
    return homes


def for_kinds(dispatcher, *kinds):
    """``dispatcher`` (a kernel cached on disk), or its twin compiled in memory only.

    The twin (same source, numba's ``cache=False``) serves any call with a
    class defined outside :data:`CACHEABLE_PACKAGES` among ``kinds`` (through
    tuples): a user's plant (:func:`plant.simulation.plants.register_plant`)
    or control law (:func:`plant.simulation.controllers.register_control_law`),
    or a law's parameters of a user's class, compiles in each process, and
    the library's on-disk cache is never written with it.  So does a kind of
    a module generated per robot (:mod:`plant.simulation.generated`) that
    is neither ``dispatcher``'s own module nor one that module imports from:
    generated modules beyond the kept number are deleted, and an index that
    named a deleted one would fail to load (e.g. the computed-torque law
    generated for one robot, :func:`ctc.arm.ArmComputedTorque.logged_controller`,
    in the loop of another robot's plant).

    Parameters
    ----------
    dispatcher : numba dispatcher
        A kernel of this module (numba's ``cache=True``, ``nogil``).
    *kinds : object
        The plant and law kinds the call passes, and the law's parameters.

    Returns
    -------
    numba dispatcher
    """
    homes = _homes(dispatcher)
    if all(_importable(k, homes) for k in kinds):
        return dispatcher
    with _UNCACHED_LOCK:
        twin = _UNCACHED.get(dispatcher.py_func)
        if twin is None:
            twin = _UNCACHED[dispatcher.py_func] = numba.njit(
                nogil=True, error_model="numpy")(dispatcher.py_func)
    return twin


# ----------------------------------------------------------------------------
# The P-control experiment driver
# ----------------------------------------------------------------------------
@_jit
def finish_lane(idx, j, code, E, rows, skip, n, bound, obj, status, compared, replay, write, out,
                fill_from):
    """Record lane ``j``'s result (status ``code``) after ``rows`` log rows, of which the first
    ``skip`` are not compared (``n`` compared in all); a failed replay lane's errors := bound."""
    c_ = idx[j]
    obj[c_] = final_objective(E[j], code, max(rows - skip, 0), n, bound)
    status[c_] = code
    compared[c_] = rows
    if replay and write and code != STATUS_OK:
        for i in range(max(fill_from, 0), out.shape[1]):
            for m in range(out.shape[2]):
                out[c_, i, m] = bound


def logged_run(kind, lanes, c, enc, ref, e_log, k0, k_cmp, k_start, substeps, replay, quantize,
               gain, bound, cap, out, write, continuous_out, obj, status, compared, n_act, law,
               law_params, CS, i_log, logged_current):
    """Simulate the candidates of one chunk of lanes against a log, in lockstep.

    The driver of the logged run, in two modes (one source), for any robot
    and any number of joints (``ref.shape[1]``; the encoders read state
    rows ``enc .. enc + n_joints - 1``): compiled here for the PUMA 560
    plants (:data:`log_chunk`), and copied into each robot model's generated
    module for its arm (:func:`plant.simulation.arm.simulate_arm`,
    :func:`plant.simulation.arm.replay_arm`).

    * experiment (``replay`` False): the closed loop of the control law
      ``law`` (:func:`plant.simulation.controllers.control_law`; the rig's P loop ``i =
      P e`` for :data:`plant.simulation.controllers.P_LAW`) with the integer error ``e
      = trunc(ref) - trunc(c)`` and the measured angles ``trunc(c) / (kN /
      2 pi)`` (``quantize``; otherwise the smooth surrogate ``ref - c`` and
      ``c / (kN / 2 pi)``), per-lane controller state ``CS``, the current
      saturated at the drive's full scale ``c.current_limit``; ``obj`` the output error of eq. 4
      against ``e_log``; with ``write`` the model errors go to ``out``
      (unquantised ``ref - c`` with ``continuous_out``);
    * replay (``replay`` True): the logged input ``i = sat(P e_log) + P gain (m -
      c)`` (``sat``: the drive's current limit; ``logged_current``: ``i = i_log + P gain (m - c)``) with ``m`` the centre of the count cell the log allows; ``out``
      the prediction errors ``m - c`` (a failed lane's remaining ones are
      ``bound``); ``obj`` their sum of squares.  Before a window the run's
      own P loop with continuous counts (``quantize`` False).

    ``ref`` (n_total, n_joints) unquantised reference counts; ``e_log``,
    ``i_log`` (n_total - k0, n_joints) logged errors and currents from sample
    ``k0`` on (``out`` has their rows); the simulation starts at sample
    ``k_start`` from the lanes' state; the output error sums from sample
    ``k_cmp >= k0`` on (an arm's window: the logged input from ``k0 = 0``,
    compared from ``k_cmp``).  Results go to ``obj[i]``, ``status[i]``,
    ``compared[i]`` (the log rows run: the sample the run ended at, minus
    ``k0``) and, with ``write``, ``out[i]`` of candidate i; a lane that fails, diverges or
    passes ``cap`` is retired at once (early termination pays).  Each joint
    is one loop over the lanes (SIMD); a lane's sum of squares adds the
    joints in their order, and the last joint's pass adds it to the lane's
    running sum.  The rig's P law is computed in that loop (the
    identification's hot loop); any other law is called per lane after it,
    with every joint's measured angle ``Y`` and pulse error ``E``.
    """
    P, X, U, A, S, E, idx, W = lanes
    n_total = ref.shape[0]
    skip = k_cmp - k0           # log rows not compared
    n = e_log.shape[0] - skip   # rows compared in all
    nj = ref.shape[1]
    i_lim = c.current_limit
    act = n_act
    width = max(padded_lanes(act), 1)
    Ym = np.zeros((nj, width))   # measured angles (rad), the law's input
    Ep = np.zeros((nj, width))   # pulse errors, the law's input
    Ssq = np.zeros(width)        # this sample's sum of squares per lane
    rows = np.int64(0)  # log rows run (not a literal: one signature of finish_lane)
    # the rig's P law runs inside the joint loop (the identification's hot loop); any
    # other law is called per lane with every joint's measured angle and error
    fused = is_p_law(law)
    for k in range(k_start, n_total):
        i = k - k0
        # divergence on the continuous error first, so truncation never sees a huge value
        for j in range(act - 1, -1, -1):
            for m in range(nj):
                if abs(ref[k, m] - X[enc + m, j] * c.pulses_per_rad[m]) > bound:
                    finish_lane(idx, j, np.int64(STATUS_DIVERGED), E, rows, skip, n, bound, obj,
                                status, compared, replay, write, out, i)
                    act = retire_lane(P, X, U, A, S, E, idx, CS, j, act)
                    break
        if act == 0:
            break
        lanes_run = padded_lanes(act)
        within = True  # replay: no joint's logged P current beyond the drive's limit
        if replay and i >= 0:
            for m in range(nj):
                within = within and abs(c.p_gain[m] * e_log[i, m]) <= i_lim
        for m in range(nj):
            sc = c.pulses_per_rad[m]
            r = ref[k, m]
            _, t = encoder_read(r, 1.0)
            el = e_log[i, m] if i >= 0 else 0.0
            # a lane's sum of squares adds the joints in their order; the last joint's pass
            # adds it to the running sum of a compared sample
            first, to_sum = m == 0, m == nj - 1 and i >= skip
            # two lane loops, one per mode, each with the sum of squares' lines: one loop with
            # the mode as a branch inside, or those lines in an inlined helper, kept the GA's
            # loop from vectorising (measured 20 % and 4-7x slower)
            if replay and i >= 0:
                mid = cell_centre(t - el)
                p_m = c.p_gain[m]
                i_m = i_log[i, m]
                p_e = min(max(p_m * el, -i_lim), i_lim)
                for j in range(lanes_run):  # SIMD over the lanes
                    cc, _ = encoder_read(X[enc + m, j], sc)
                    d = mid - cc
                    sq = d * d if first else Ssq[j] + d * d
                    if to_sum:
                        E[j] += sq
                    else:
                        Ssq[j] = sq
                    # logged input (the current the rig applied) plus the predictor correction
                    if logged_current:
                        U[m, j] = i_m + p_m * gain * d
                    elif within:
                        U[m, j] = p_m * (el + gain * d)
                    else:  # the P current the drive applied (saturated), plus the correction
                        U[m, j] = p_e + p_m * gain * d
                if write:
                    for j in range(act):
                        cc, _ = encoder_read(X[enc + m, j], sc)
                        out[idx[j], i, m] = mid - cc
            else:
                for j in range(lanes_run):  # SIMD over the lanes
                    cc, a = encoder_read(X[enc + m, j], sc)
                    e = t - a if quantize else r - cc
                    d = el - (r - cc if continuous_out else e)
                    sq = d * d if first else Ssq[j] + d * d
                    if to_sum:
                        E[j] += sq
                    else:
                        Ssq[j] = sq
                    if fused:
                        U[m, j] = min(max(p_current(c, m, e), -i_lim), i_lim)
                    else:
                        Ym[m, j] = (a if quantize else cc) / sc
                        Ep[m, j] = e
                if write and i >= 0:
                    for j in range(act):
                        cc, a = encoder_read(X[enc + m, j], sc)
                        if continuous_out or not quantize:
                            out[idx[j], i, m] = r - cc
                        else:
                            out[idx[j], i, m] = t - a
        if not (fused or (replay and i >= 0)):
            for j in range(lanes_run):
                control_law(law, law_params, c, k, Ym, Ep, CS, U, j)
                for m in range(nj):
                    U[m, j] = min(max(U[m, j], -i_lim), i_lim)  # the drive's current limit
        if i >= 0:
            rows = i + 1
        if i >= skip:
            for j in range(act - 1, -1, -1):
                if E[j] > cap:
                    finish_lane(idx, j, np.int64(STATUS_STOPPED), E, rows, skip, n, bound, obj,
                                status, compared, replay, write, out, i + 1)
                    act = retire_lane(P, X, U, A, S, E, idx, CS, j, act)
            if act == 0:
                break
        if k == n_total - 1:
            break
        advance_sample(kind, P, c, X, U, A, S, W, padded_lanes(act), substeps,
                       (k - k_start) % REANCHOR == 0)
        for j in range(act - 1, -1, -1):
            if S[j] != STATUS_OK:
                finish_lane(idx, j, S[j], E, rows, skip, n, bound, obj, status, compared, replay,
                            write, out, i + 1)
                act = retire_lane(P, X, U, A, S, E, idx, CS, j, act)
        if act == 0:
            break
    for j in range(act):
        finish_lane(idx, j, np.int64(STATUS_OK), E, rows, skip, n, bound, obj, status, compared,
                    replay, write, out, e_log.shape[0])


#: :func:`logged_run` compiled for the PUMA 560 plants (cached on disk).
log_chunk = kernel(logged_run)


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
        :data:`~plant.simulation.core.STATUS_OK` or the failure code
        (:data:`~plant.simulation.core.STATUS_MESSAGES`).
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
    plant_parameters=None,
    initial_state=None,
    controller=None,
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
    plant : plant.simulation.plants.Plant, optional
        The simulated plant (default :data:`plant.simulation.plants.RIGID`; e.g. a
        :class:`plant.simulation.plants.FlexibleJoints`).
    plant_parameters : dict, optional
        Per-candidate plant parameters beyond f, as keyword arguments of the
        plant's ``lane_parameters`` (e.g. ``friction`` (m, 6) of
        :data:`plant.simulation.friction.RIGID_FRICTION`, or ``joints`` (m, 6) of a
        flexible plant).
    initial_state : array_like, shape (n_candidates, n_x) or (n_x,), optional
        State (q2, q3, qd2, qd3 for the rigid plant; rad, rad/s) at the log's
        first sample, per candidate: the simulation then starts there instead
        of at t = 0 (required for a window log without a start state).
    controller : object, optional
        The controller that ran (default: the rig's P law ``i = P e``): a
        :class:`plant.simulation.controllers.LoggedController` or an object with a
        ``logged_controller(log)`` method returning one (e.g. a
        :class:`ctc.ComputedTorqueController`); its compiled law runs in
        the loop of every lane.

    Returns
    -------
    ExperimentSimulation

    Raises
    ------
    ValueError
        On a wrongly shaped or non-finite ``F`` or ``initial_state``,
        ``substeps < 1``, a non-positive bound, a NaN cap, bad ``workers``,
        or a window without a start state and no ``initial_state``.
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
    Pall = plant.lane_parameters(F, log.rig, **(plant_parameters or {}))
    x0 = plant.initial_state(inputs.constants)
    X0 = start_states(log, initial_state, m, plant.n_states)
    k_start = 0 if X0 is None else inputs.start_index
    law = as_logged_controller(controller, log)
    law.check_joints(inputs.ref_counts.shape[1])
    law.check_samples(inputs.ref_counts.shape[0])
    law.check_start(k_start)
    i_log = inputs.i_log

    # the driver's copy compiled with the law (a law generated per robot), else this module's
    run = for_kinds(log_chunk if law.driver is None else law.driver, plant.kind, law.kind,
                    law.parameters)

    def chunk(lo, hi):
        lanes = lanes_from(Pall, lo, hi, x0, X0)
        k0 = inputs.start_index  # the log's rows, compared from their first
        run(plant.kind, lanes, inputs.constants, plant.encoder_row, inputs.ref_counts, e_log,
            k0, k0, k_start, substeps, False, bool(quantize), 0.0, bound, cap, err, bool(errors),
            bool(continuous_output), obj, status, compared, hi - lo, law.kind, law.parameters,
            law.lane_states(lanes.X.shape[1]), i_log, False)

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
                        plant=None, plant_parameters=None, initial_state=None, controller=None):
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
    plant : plant.simulation.plants.Plant, optional
        Default :data:`plant.simulation.plants.RIGID`.
    plant_parameters : dict, optional
        Plant parameters beyond f (see :func:`simulate_batch`), for this one
        candidate.
    initial_state : array_like, shape (n_x,), optional
        State at the log's first sample (see :func:`simulate_batch`).
    controller : object, optional
        The controller that ran (see :func:`simulate_batch`; default the
        rig's P law).

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
    extra = {k: np.asarray(v, dtype=float)[None] for k, v in (plant_parameters or {}).items()}
    sim = simulate_batch(log, f[None], substeps=substeps, quantize=quantize, bound=bound,
                         workers=1, plant=plant, plant_parameters=extra,
                         initial_state=initial_state, controller=controller)
    st = int(sim.status[0])
    if st != STATUS_OK:
        k = int(log.start_index) + int(sim.n_compared[0])
        when = f"at t = {k * log.rig.sample_time_s:.4f} s"
        if int(sim.n_compared[0]) == 0 and log.start_index > 0 and initial_state is None:
            # the run from t = 0 failed before the window's rows were compared
            when = f"before the log's window (at or before its first sample, t = " \
                   f"{k * log.rig.sample_time_s:.4f} s)"
        raise SimulationError(
            f"simulation of {getattr(log, 'name', 'log')} failed {when}: {STATUS_MESSAGES[st]}"
        )
    return sim.e_pulses[0]


def dummy_problem():
    """A three-sample problem in the kernels' exact argument types (warm-up)."""
    c = RigConstants(1e-3, (1.0, 1.0), (1.0, 1.0), (1.0, 1.0), (0.0, 0.0), (0.0, 0.0),
                     (0.0, 0.0), (1.0, 1.0), 9.81, (0.0, 0.0), (0.0, 0.0), math.inf)
    Pall = np.ones((RIGID.n_parameters, 1))
    return c, Pall, np.zeros((3, 2)), np.zeros((3, 2))


def warm_arguments():
    """Arguments of :func:`log_chunk` on the three-sample dummy problem."""
    c, Pall, ref, e_log = dummy_problem()
    return (RIGID.kind, new_lanes(Pall, 0, 1, RIGID.initial_state(c)), c, RIGID.encoder_row,
            ref, e_log, 0, 0, 0, 1, False, True, 0.0, 100.0, np.inf, np.zeros((1, 3, 2)), True,
            False, np.empty(1), np.empty(1, dtype=np.int64), np.empty(1, dtype=np.int64), 1,
            P_LAW.kind, P_LAW.parameters, P_LAW.lane_states(1), np.zeros((3, 2)), False)


def warm_kernels():
    log_chunk(*warm_arguments())
