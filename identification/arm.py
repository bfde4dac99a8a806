"""Identification of any serial arm's base parameters from a P-control log.

The paper's method -- the simulated closed loop must reproduce the logged
encoder pulses -- for a robot model (:class:`plant.robot.robot_model.RobotModel`)
of n joints with r base parameters beta (numerical QR, Gautier 1990), in two
steps:

1. **IDIM-LS start** (Khalil & Dombre, *Modeling, Identification and Control
   of Robots*, 2002, sec. 12.4): the encoder counts taken at the centres of
   their cells, a zero-phase Butterworth low-pass at the quantisation-floor
   cut-off (:func:`identification.idim.idim_cutoff_hz`'s rule), rates and
   accelerations by central differences, the joint torque ``k Kt i`` of the
   logged current (at the sample's midpoint) plus the sidecar's friction,
   filtered alike (parallel filtering); equations near a rate reversal are
   dropped (Coulomb sign unknown there); least squares with the base
   regressor, each joint weighted by 1 / its residual rms.
2. **Output-error refinement** on the logged-input predictor
   (:mod:`identification.refinement`'s bounded Levenberg--Marquardt, all
   Jacobian columns of an iteration as one batch of SIMD lanes): the arm,
   driven by the current the drive applied plus a weak output injection
   (:func:`plant.simulation.arm.replay_arm`), must keep its continuous encoder count in
   the count cells the log allows.  The applied current is the P law's on
   the logged integer error, clipped at the drive's full scale -- known
   exactly, where the logged current carries the current sensor's noise
   (the PUMA 560 path's replay does the same).  The residuals are smooth in
   beta (the quantised feedback is replaced by the applied current), so a
   local method converges; their sum of squares is in pulses^2.

Standard errors: Gauss--Newton sandwich with a Newey--West long-run
covariance of the scores (:func:`identification.uncertainty.sandwich_covariance`),
the relative standard error of each base parameter says how well the log
excites it.

Compliant joints: a log that the rigid model does not predict to the
encoder's quantisation floor goes through the model choice of
:func:`identify_arm` (``model="auto"``): the two-mass joints with gearbox
backlash of :mod:`identification.arm_flexible`, compared with the rigid
model on held-back blocks, as the PUMA 560 path does
(:mod:`identification.flexible`).

The result is a :class:`scipy.optimize.OptimizeResult` with the arm's
names (:class:`ArmIdentificationResult`).
"""
from __future__ import annotations

import dataclasses
import math
import time

import numpy as np
from scipy import signal
from scipy.optimize import OptimizeResult

from plant.simulation.arm import ARM_SUBSTEPS as ARM_SUBSTEPS_SIM
from plant.simulation.arm import ArmPlant, arm_plant, link_mode_bound, replay_arm, simulate_arm
from plant.simulation.core import cell_centre
from plant.robot.model import friction_torque
from plant.logs.rig import F_NAMES, p_law_current, rig_constants

from .flexible import (CONTINUATION_FTOL, CONTINUATION_GAINS, INADEQUATE_FACTOR,
                       MAX_RESTARTS, RESTART_FRACTION, quantisation_floor)
from .friction import FRICTION_COMPONENTS, friction_layout, joint_friction_columns
from .ga import PAPER_GA
from .model_choice import ARM_FLOOR_FACTOR, BACKLASH_T, CHOICE_RATIO, CHOICE_T, ModelImprovement
from .objective import IDENTIFICATION_SUBSTEPS
from .idim import (IDIM_FILTER_ORDER, IV_ITERATIONS, REVERSAL_GUARD, cutoff_from_counts,
                   reversal_mask)
from .refinement import DEFAULT_GAIN, refine, refine_through_gains, widen_guessed_box
from .result_schema import jsonable
from .uncertainty import RSE_WARN, sandwich_covariance

__all__ = ["identify_arm", "arm_idim_ls", "rig_search_box", "ArmIdentificationResult",
           "ArmPredictionErrorProblem", "ARM_REFINE_SUBSTEPS", "ARM_OUTPUT_ERROR_SUBSTEPS", "ARM_FTOL",
           "ARM_METHODS", "ARM_DEFAULT_METHOD", "IDIM_FALLBACK_SEED", "friction_layout",
           "output_error_substeps",
           "ARM_DAMPING_STEP", "ARM_REPORT_SUBSTEPS", "motor_side_friction", "rig_with_friction",
           "FRICTION_COMPONENTS", "ARM_MODELS",
           "ARM_MAX_RESTARTS"]

#: Names that moved below this module (no import circles, issue 23), by their new module.
_MOVED = {"EXCESS_T": "identification.model_choice",
          "held_back_paired_t": "identification.model_choice",
          "BOX_WIDENINGS": "identification.refinement",
          "BOX_EDGE": "identification.refinement"}


def __getattr__(name):
    """A name that moved below this module (:data:`_MOVED`) is still importable from here,
    with a DeprecationWarning naming its module (PEP 562)."""
    if name in _MOVED:
        import importlib
        import warnings

        warnings.warn(f"identification.arm.{name} is {_MOVED[name]}.{name}", DeprecationWarning,
                      stacklevel=2)
        return getattr(importlib.import_module(_MOVED[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

#: Methods of :func:`identify_arm`; the default.
ARM_METHODS = ("idim+pem", "ga+pem", "paper", "idim-ls", "idim-iv")
ARM_DEFAULT_METHOD = "idim+pem"

#: Seed of the GA that replaces an IDIM-LS start that does not simulate (``"idim+pem"``
#: with ``rng=None``): the same log gives the same result.
IDIM_FALLBACK_SEED = 0

#: Relative cost decrease below which the refinement has converged: 1e-6 of a
#: cost of ~1e3 pulses^2 is ~1e-3 pulses^2, far below what moves an estimate
#: by its standard error.
ARM_FTOL = 1e-6

#: RK4 substeps per sample of the refinement's replay (the predictor's
#: dynamics are the slow arm's: the applied current carries the fast P loop).
ARM_REFINE_SUBSTEPS = 2

#: RK4 substeps per sample of the GA's objective, the output error of eq. 4
#: (methods ``"ga+pem"`` and ``"paper"``), at least: the PUMA 560 path's
#: (:data:`identification.objective.IDENTIFICATION_SUBSTEPS`, 1), so that both
#: paths run the same GA on the PUMA 560 links 2-3 instance.  It is the
#: default, not a fixed value: :func:`output_error_substeps` takes more steps
#: for an arm whose P loop is fast for its sample time.  One step per sample
#: rests on the PUMA path's measurement (the integer output error is
#: dominated by whole-pulse flips of the quantised loop: 1 and 2 substeps
#: identify f1 f2 f4 f6 f7 f9 to the same 0.03 % on the paper log) and on
#: the P loop's fastest mode there, ``omega Ts = 0.10``.  (It was 8, with
#: which the arm path's GA could not reproduce the PUMA path's.)
ARM_OUTPUT_ERROR_SUBSTEPS = IDENTIFICATION_SUBSTEPS

#: RK4 substeps per sample, at least, of the result's ``output_error`` (eq. 4)
#: -- what the flexible-versus-rigid model choice compares and the plot
#: shows -- as opposed to the GA's objective (:data:`ARM_OUTPUT_ERROR_SUBSTEPS`):
#: at one step the rigid model's output error at the truth carries hundreds
#: of pulses^2 of integration error (524 and 671 on two six-joint draws of
#: ``benchmarks/bench_arms.py``, 0 at 48), which a flexible fit simulated at
#: its own finer steps would not, so the two would not be compared like with
#: like.  8, the value the model choice was measured with.
ARM_REPORT_SUBSTEPS = 8

#: Largest ``|lambda| h`` of the drive friction's mode (real and damped: the
#: viscous term plus the Coulomb ramp, ``D(q)^-1 diag(v + Tc / v_ramp)``)
#: that :func:`output_error_substeps` lets one RK4 step take: RK4 is stable on
#: the real axis to 2.785; a margin below it (the accuracy of a step inside
#: the ramp's narrow band matters little: a lane only crosses it at rate
#: reversals).  The PUMA 560's ramp mode is 0.77 at 0.7 ms.
ARM_DAMPING_STEP = 2.5


def output_error_substeps(log, plant, beta, friction=None) -> int:
    """RK4 substeps per sample of the output error of eq. 4 for an arm and its log.

    The GA's objective and the result's ``output_error`` of
    :func:`identify_arm`: :data:`ARM_OUTPUT_ERROR_SUBSTEPS` (the PUMA 560
    path's :data:`~identification.objective.IDENTIFICATION_SUBSTEPS`, one
    step per sample) unless the arm needs more:

    * **accuracy** on the P loop's fastest mode ``omega``, the largest over
      the log's configurations of ``det(diag(kp) - omega^2 D(q)) = 0``
      (:func:`plant.simulation.arm.link_mode_bound`) with ``kp_j = k_j Kt_j
      P_j k_j N_j / 2 pi`` (N m/rad) the P law's stiffness:
      ``ceil(omega Ts / H_OMEGA)`` steps
      (:data:`identification.flexible.H_OMEGA`, the flexible fits' rule:
      prediction errors within 0.01 pulse when the steps are doubled);
    * **stability** on the friction's damped mode ``lambda``, the largest
      eigenvalue of ``D(q)^-1 diag(v_j + max |Tc_j| / v_ramp,j)``:
      ``ceil(lambda Ts / ARM_DAMPING_STEP)`` steps.

    ``D(q)`` is the arm's at ``beta`` (the IDIM start in
    :func:`identify_arm`), or at the model's own parameters when beta's is
    not positive definite on the log; when neither is, the exact
    reproduction's :data:`plant.simulation.arm.ARM_SUBSTEPS`.  On the PUMA
    560 links 2-3 logs: ``omega Ts = 0.10``, ``lambda Ts = 0.77``, one step
    -- the PUMA path's; on the tests' planar arm (1 ms): 0.15 and 0.14; on
    ``benchmarks/bench_arms.py``'s draws (planar, PUMA joints 1-3, six
    joints, 0.5 and 1 ms) ``omega Ts`` 0.05 .. 0.12: one step everywhere
    (the output error at the truth at one step: 524 and 671 pulses^2 on
    two six-joint draws, 1192 on the PUMA paper log; 0 at 48).

    Parameters
    ----------
    log : plant.logs.arm_log.ArmLog
    plant : plant.simulation.arm.ArmPlant
        The rigid arm.
    beta : array_like, shape (r,) or longer
        Base parameters (only the first r are read).
    friction : array_like, shape (n, 3), optional
        Joint-side viscous, Coulomb +, Coulomb - per joint (default the
        rig's; :func:`identify_arm` passes the box's upper ends of the
        unknown ones).

    Returns
    -------
    int
        At least :data:`ARM_OUTPUT_ERROR_SUBSTEPS`.
    """
    from .arm_flexible import inertia_matrices
    from .flexible import H_OMEGA

    c = rig_constants(log.rig)
    ts = float(c.sample_time_s)
    q = np.asarray(log.q_ref, dtype=float)
    q = q[np.linspace(0, q.shape[0] - 1, min(64, q.shape[0])).astype(int)]
    D = None
    for b in (np.asarray(beta, dtype=float)[:plant.base.rank], plant.beta()):
        Dq = inertia_matrices(plant, b, q)
        if np.all(np.isfinite(Dq)) and np.all(np.linalg.eigvalsh(Dq)[:, 0] > 0):
            D = Dq
            break
    if D is None:
        return int(ARM_SUBSTEPS_SIM)
    kp = np.abs(np.asarray(c.torque_per_amp) * np.asarray(c.p_gain) * np.asarray(c.pulses_per_rad))
    w = link_mode_bound(np.log10(np.maximum(kp, 1e-300)), D)
    fr = (np.column_stack([c.viscous, c.coulomb_pos, c.coulomb_neg]) if friction is None
          else np.asarray(friction, dtype=float).reshape(-1, 3))
    damp = np.abs(fr[:, 0]) + np.maximum(np.abs(fr[:, 1]), np.abs(fr[:, 2])) / np.asarray(c.ramp_speed)
    lam = max(float(np.max(np.linalg.eigvals(np.linalg.solve(Dq_, np.diag(damp))).real)) for Dq_ in D)
    return max(int(ARM_OUTPUT_ERROR_SUBSTEPS), int(math.ceil(w * ts / H_OMEGA)),
               int(math.ceil(lam * ts / ARM_DAMPING_STEP)))


#: :func:`plant.simulation.core.cell_centre` element by element (the one definition of a cell's centre).
_cell_centres = np.vectorize(cell_centre, otypes=[float])


def rig_search_box(rig, base):
    """The sidecar's search ranges of the base parameters, or None (shape (r, 2)).

    A rig that gives search ranges (``rig.f_bounds``, the sidecar's
    ``f_search_ranges`` of f1..f9) gives them for parameters with those
    names; they are the default box of :func:`identify_arm` when the
    model's base parameters are exactly those (same count and names: the
    PUMA 560 links 2-3 instance), as :func:`identification.identify` takes
    them.

    Parameters
    ----------
    rig : plant.Rig
    base : plant.robot.robot_model.BaseParameterSet
        The model's base parameters.

    Returns
    -------
    ndarray, shape (r, 2), or None
    """
    names = tuple(base.names)
    if not rig.f_bounds or len(rig.f_bounds) != len(names) or names != F_NAMES[:len(names)]:
        return None
    return np.array(rig.f_bounds, dtype=float).reshape(len(names), 2)


def _plant_of(log, plant):
    if plant is None:
        return arm_plant(log.model)
    if not isinstance(plant, ArmPlant):
        raise ValueError(f"plant must be a plant.simulation.arm.ArmPlant, got {type(plant).__name__}")
    return plant


def arm_idim_ls(log, *, plant=None, cutoff_hz=None, trim_s=0.1, decimate=1,
                reversal_guard=REVERSAL_GUARD, iv_iterations=0) -> dict:
    """Base parameters of an arm by IDIM-LS (inverse dynamic model, least squares), or IDIM-IV.

    Parameters
    ----------
    log : plant.logs.arm_log.ArmLog
        The logged experiment (rig friction known).
    plant : plant.simulation.arm.ArmPlant, optional
        The arm (default :func:`plant.simulation.arm.arm_plant` of the log's robot).
    cutoff_hz : float, optional
        Low-pass cut-off (Hz); default: where the encoder counts meet the
        quantisation floor (:func:`identification.idim.idim_cutoff_hz`'s rule).
    trim_s : float
        Seconds dropped at both ends (filter transients).
    decimate : int
        Keep every ``decimate``-th sample.
    reversal_guard : float or None
        Equations within ``reversal_guard / cutoff_hz`` s of a rate reversal
        are dropped (None keeps all).
    iv_iterations : int
        IDIM-IV (:mod:`identification.idim`'s, for any arm): instruments
        the regressor of the rig's P loop simulated at the current estimate
        (:func:`plant.simulate_closed_loop` on the arm, the same reference,
        the unknown friction at its estimate clipped at 0; noise-free
        positions through the same filter and differences), ``x = (Z^T
        W)^-1 Z^T tau``, started from the weighted least squares and
        iterated this many times (0: IDIM-LS; a failed simulation keeps the
        previous estimate).  Standard errors: the IV sandwich.

    Returns
    -------
    dict
        ``x`` (r + u,): beta, then the u unknown friction components
        (joint side, :func:`identification.friction.friction_layout`); ``x_std``, ``cov`` (r + u,
        r + u), ``cutoff_hz``, ``n_equations``, ``residual_rms_Nm`` (n,),
        ``condition_number``, ``iv_iterations`` (the IV steps done).

    Raises
    ------
    ValueError
        A log too short, a bad cut-off, or unknown friction of a joint that
        never moves in one direction among the equations kept.

    Notes
    -----
    When the sidecar leaves the friction unknown (``null``), its joint-side
    components are identified with beta (the paper: friction constants, "if
    unknown, have to be included as unknown parameters"): the model ``Y beta
    + v qd + Tc+ r [qd > 0] + Tc- r [qd <= 0] = k Kt i`` with ``r = clip(qd /
    v_ramp, -1, 1)`` gets their columns, filtered like the torque.
    """
    pl = _plant_of(log, plant)
    rig = log.rig
    ts = rig.sample_time_s
    n = log.n_joints
    counts = log.measured_counts()
    fc = cutoff_from_counts(counts, ts) if cutoff_hz is None else float(cutoff_hz)
    if not (0.0 < fc < 0.5 / ts):
        raise ValueError(f"cutoff_hz must lie in (0, {0.5 / ts:.4g}) Hz, got {cutoff_hz}")
    c = rig_constants(rig)
    spr = np.asarray(c.pulses_per_rad)
    n_trim = int(round(trim_s / ts))
    ns = counts.shape[0]
    if ns - 2 * n_trim < 50:
        raise ValueError(f"log too short for IDIM ({ns} samples)")
    sos = signal.butter(IDIM_FILTER_ORDER, fc, fs=1.0 / ts, output="sos")
    qf = signal.sosfiltfilt(sos, _cell_centres(counts) / spr, axis=0)
    qd = np.gradient(qf, ts, axis=0)
    qdd = np.gradient(qd, ts, axis=0)
    i = np.asarray(log.i_A, dtype=float)
    i_mid = np.vstack([i[:1], 0.5 * (i[1:] + i[:-1])])
    fr = np.empty_like(qd)
    for j in range(n):
        fr[:, j] = [friction_torque(v, c.viscous[j], c.coulomb_pos[j], c.coulomb_neg[j],
                                    c.ramp_speed[j]) for v in qd[:, j]]
    tauf = signal.sosfiltfilt(sos, i_mid * np.asarray(c.torque_per_amp) + fr, axis=0)
    sl = slice(n_trim, ns - n_trim, int(decimate))
    keep = (np.ones(qd.shape, dtype=bool) if reversal_guard is None
            else reversal_mask(qd, round(reversal_guard / (fc * ts))))
    weight = keep[sl].reshape(-1).astype(float)
    Y = pl.model.stacked_regressor(qf[sl], qd[sl], qdd[sl])[:, pl.base.independent]
    unknown = friction_layout(rig)[1]
    if unknown:  # the unknown friction's columns, joint by joint, filtered like the torque
        cols = signal.sosfiltfilt(sos, joint_friction_columns(qd, c.ramp_speed, unknown),
                                  axis=0)[sl].reshape(-1, len(unknown))
        empty = [k for k in range(len(unknown)) if not np.any(cols[weight > 0, k] != 0)]
        if empty:
            j, what = unknown[empty[0]]
            raise ValueError(f"the log cannot identify the unknown friction of joint "
                             f"{log.joint_names[j]}: it never moves "
                             f"{'down' if what == 2 else 'up'} in the equations kept")
        Y = np.hstack([Y, cols])
    W = Y * weight[:, None]
    y = tauf[sl].reshape(-1) * weight
    scale = np.linalg.norm(W, axis=0)
    scale[scale == 0] = 1.0
    x = np.linalg.lstsq(W / scale, y, rcond=None)[0] / scale
    # each joint weighted by 1 / its residual rms (torques of different sizes)
    r0 = (W @ x - y).reshape(-1, n)
    kept = weight.reshape(-1, n) > 0
    sigma = np.array([math.sqrt(np.mean(r0[kept[:, j], j] ** 2)) if kept[:, j].any() else 1.0
                      for j in range(n)])
    sigma[sigma <= 0] = 1.0
    rw = np.tile(1.0 / sigma, W.shape[0] // n)
    Ww, yw = W * rw[:, None], y * rw
    x = np.linalg.lstsq(Ww / scale, yw, rcond=None)[0] / scale
    done = 0
    for _ in range(int(iv_iterations)):
        Z = _arm_instruments(log, pl, x, sos, sl, unknown)
        if Z is None:
            break
        Z = Z * (weight * rw)[:, None]
        x = np.linalg.solve(Z.T @ Ww, Z.T @ yw)
        done += 1
    r = Ww @ x - yw
    if done:
        # the IV sandwich (Z^T W)^-1 S (W^T Z)^-1 with S of the scores Z_t r_t;
        # sandwich_covariance(Z, r) returns (Z^T Z)^-1 S (Z^T Z)^-1
        A = np.linalg.inv(Z.T @ Ww)
        cz, _ = sandwich_covariance(Z, r, n_channels=n)
        ZZ = Z.T @ Z
        cov = A @ ZZ @ cz @ ZZ @ A.T
    else:
        cov, _ = sandwich_covariance(Ww, r, n_channels=n)
    sv = np.linalg.svd(Ww / np.linalg.norm(Ww, axis=0).clip(1e-300), compute_uv=False)
    res = (W @ x - y).reshape(-1, n)
    return dict(x=x, x_std=np.sqrt(np.maximum(np.diag(cov), 0.0)), cov=cov, cutoff_hz=fc,
                n_equations=int(np.count_nonzero(weight)),
                residual_rms_Nm=np.sqrt(np.mean(res[kept.reshape(-1, n).any(axis=1)] ** 2, axis=0)),
                condition_number=float(sv[0] / sv[-1]), iv_iterations=done)


def _arm_instruments(log, pl, x, sos, sl, unknown):
    """IDIM-IV instruments of an arm: the regressor of its P loop simulated at x, or None.

    The rig's P law on the arm with beta = x[:r] and the unknown friction at
    x[r:] (joint side, clipped at 0), the log's reference; the simulated
    positions through the same filter and differences as the measured
    ones, the same equations (``sl``), unweighted: shape (n_eq n, r + u).
    """
    from plant.simulation.closed_loop import simulate_closed_loop
    from plant.simulation.synthetic import CardPLaw

    rig, r = log.rig, pl.base.rank
    ts = rig.sample_time_s
    if unknown:  # the simulated robot has the current friction estimate (motor side in the rig)
        xf = np.concatenate([x[:r], np.maximum(x[r:], 0.0)])
        rig = rig_with_friction(rig, motor_side_friction(rig, xf, r))
    try:
        resp = simulate_closed_loop(rig, x[:r], CardPLaw(log.rig.p_gain_A_per_pulse),
                                    trajectory=log.trajectory, n_samples=log.n_samples,
                                    plant=pl, label="IDIM-IV instruments")
    except ValueError:
        return None
    if not resp.success or resp.q.shape[0] < log.n_samples:
        return None
    qs = signal.sosfiltfilt(sos, resp.q, axis=0)
    qds = np.gradient(qs, ts, axis=0)
    qdds = np.gradient(qds, ts, axis=0)
    Z = pl.model.stacked_regressor(qs[sl], qds[sl], qdds[sl])[:, pl.base.independent]
    if unknown:
        c = rig_constants(log.rig)
        cols = signal.sosfiltfilt(sos, joint_friction_columns(qds, c.ramp_speed, unknown),
                                  axis=0)[sl]
        Z = np.hstack([Z, cols.reshape(-1, len(unknown))])
    return Z


def _lane_friction(rig, X, r):
    """Lane parameters ``[beta, joint-side friction (3 n)]`` from ``X = [beta, unknown]`` (m, r + u)."""
    known, unknown = friction_layout(rig)
    F = np.tile(known.reshape(-1), (X.shape[0], 1))
    for k, (j, w) in enumerate(unknown):
        F[:, 3 * j + w] = X[:, r + k]
    return np.hstack([X[:, :r], F])


def motor_side_friction(rig, X, r) -> dict:
    """The sidecar's friction keys (motor side) with the identified values filled in.

    Parameters
    ----------
    rig : plant.Rig
    X : ndarray, shape (r + u,)
        beta, then the unknown joint-side friction components.
    r : int
        Base parameters.

    Returns
    -------
    dict
        ``viscous_friction_Nms_per_rad`` (n,) and ``coulomb_friction_Nm``
        (n, 2) as lists, motor side (joint side / k^2 and / abs(k)).
    """
    F = _lane_friction(rig, np.asarray(X, dtype=float)[None], r)[0, r:].reshape(-1, 3)
    k = np.abs(np.asarray(rig.gear_ratio, dtype=float))
    return dict(viscous_friction_Nms_per_rad=(F[:, 0] / k ** 2).tolist(),
                coulomb_friction_Nm=np.column_stack([F[:, 1] / k, F[:, 2] / k]).tolist())


def rig_with_friction(rig, friction):
    """The rig with the sidecar's friction keys of :func:`motor_side_friction` (motor side).

    Parameters
    ----------
    rig : plant.Rig
    friction : dict
        ``viscous_friction_Nms_per_rad`` (n,) and ``coulomb_friction_Nm``
        (n, 2), motor side (a result's ``friction``).

    Returns
    -------
    plant.Rig
        A copy with those values (the sidecar's ``null`` friction filled in).

    Raises
    ------
    KeyError, TypeError, ValueError
        A dict without those keys or with values that are not numbers.
    """
    return dataclasses.replace(
        rig, viscous_friction_Nms_per_rad=tuple(friction["viscous_friction_Nms_per_rad"]),
        coulomb_friction_Nm=tuple(tuple(v) for v in friction["coulomb_friction_Nm"]))


class ArmPredictionErrorProblem:
    """Residuals of the arm's logged-input predictor, in batches (:func:`identification.refinement.refine`).

    The input is the current the drive applied during the log: the rig's P
    law ``i = P e`` on the logged integer errors, clipped at the drive's full
    scale (exact; the logged current ``i_A`` may carry sensor noise).

    Parameters
    ----------
    log : plant.logs.arm_log.ArmLog
    plant : plant.simulation.arm.ArmPlant
    gain : float
        Output-injection gain (fraction of the P gain).
    substeps : int
        RK4 steps per sample.
    k_start : int
        First compared sample.
    workers : int, optional
        Threads (default: the CPUs this process may use).
    to_lanes : callable, optional
        Maps the searched vectors X (m, k) to the plant's rows (m,
        ``plant.n_parameters``) (default: beta, then the unknown friction
        into the rig's, :func:`~identification.friction.friction_layout`).
    feasible : callable, optional
        ``feasible(X) -> (m,) bool``: candidates outside it are not
        simulated and get the failed candidate's residuals (e.g. a link
        model that is no robot, :meth:`~identification.arm_flexible.ArmFlexibleSpace.feasible`).

    Attributes
    ----------
    nfev : int
        Candidates simulated so far.
    """

    def __init__(self, log, plant, *, gain=DEFAULT_GAIN, substeps=ARM_REFINE_SUBSTEPS, k_start=0,
                 workers=None, to_lanes=None, feasible=None):
        self.log = log
        self.to_lanes = to_lanes
        self.feasible = feasible
        self.workers = workers
        self.plant = plant
        self.gain = float(gain)
        self.substeps = int(substeps)
        self.k_start = int(k_start)
        self.ref = log.reference_counts()
        self.e = np.asarray(log.e_pulses, dtype=float)
        # the current the drive applied: the P law's on the logged integer error, clipped at
        # the drive's full scale -- known exactly, where the logged current carries the
        # current sensor's noise (the PUMA path's replay, plant.simulation.simulate.log_chunk)
        self.i = p_law_current(log.rig, self.e)
        self.nfev = 0
        # a failed candidate's residuals: a bound far beyond any prediction error
        self.bound = 1e6

    def residuals(self, X) -> np.ndarray:
        """Prediction errors (pulses) of a batch of base-parameter vectors.

        Parameters
        ----------
        X : array_like, shape (m, r) or (r,)

        Returns
        -------
        ndarray, shape (m, n_samples n) or (n_samples n,)
        """
        X = np.asarray(X, dtype=float)
        single = X.ndim == 1
        X = np.atleast_2d(X)
        ok = np.ones(X.shape[0], dtype=bool) if self.feasible is None else \
            np.asarray(self.feasible(X), dtype=bool)
        R = np.full((X.shape[0], (self.ref.shape[0] - self.k_start) * self.ref.shape[1]),
                    self.bound)
        if np.any(ok):
            Xs = X[ok]
            if self.to_lanes is not None:
                P = self.to_lanes(Xs)
            else:
                P = Xs if not self.plant.lane_friction else _lane_friction(self.log.rig, Xs,
                                                                            self.plant.base.rank)
            sim = replay_arm(self.plant, P, self.log.rig, self.ref, self.e, self.i, gain=self.gain,
                             substeps=self.substeps, k_start=self.k_start, bound=self.bound,
                             workers=self.workers)
            Rs = sim.errors[:, self.k_start:, :].reshape(Xs.shape[0], -1).copy()
            Rs[sim.status != 0] = self.bound
            Rs[~np.isfinite(Rs)] = self.bound
            R[ok] = Rs
        self.nfev += X.shape[0]
        return R[0] if single else R


class ArmIdentificationResult(OptimizeResult):
    """Base parameters of an arm identified from a log (scipy ``OptimizeResult``).

    Attributes
    ----------
    x : ndarray, shape (r + u,)
        Identified base parameters beta, then the u friction components the
        sidecar left unknown (joint side; none when it knows them).
    beta : ndarray, shape (r,)
        The base parameters (``x[:r]``): the controller's model.
    fun : float
        Sum of squared prediction errors at x (pulses^2).
    output_error : float
        Output error of the simulated P loop with x against the log (paper
        eq. 4, pulses^2), at ``output_error_substeps`` RK4 steps per sample
        (a flexible result: at least its ``flexible_substeps``).
    output_error_substeps : int
        RK4 steps per sample of ``output_error`` (and of the model choice
        and the plot): the GA's (:func:`output_error_substeps`, or the
        call's ``output_substeps``), at least :data:`ARM_REPORT_SUBSTEPS`.
    nfev, nit : int
        Simulated candidates (GA and refinement) and refinement iterations
        (GA generations for ``method="paper"``).
    method : str
        The method that ran.
    ga : dict or None
        With a GA: its best ``x``, ``output_error`` (pulses^2), ``nfev``,
        ``generations``, ``substeps`` (RK4 steps per sample of its
        objective) and ``best`` (the population's best output error after
        each generation, index 0 the initial population; pulses^2).
    bounds : ndarray, shape (r, 2)
        The search box.
    interrupted : bool
        A Ctrl-C stopped the refinement (x is the best point so far).
    friction : dict
        The drive friction, motor side, in the sidecar's keys
        (``viscous_friction_Nms_per_rad``, ``coulomb_friction_Nm``): the
        sidecar's known values, the identified unknown ones.
    friction_identified : bool
        Whether any friction was identified.
    rig : plant.Rig
        The log's rig with that friction (for the controller's feed-forward).
    success : bool
    message : str
    names : tuple of str
        Base-parameter names (:meth:`plant.robot.robot_model.RobotModel.base_parameters`),
        then ``viscous_<joint>``, ``coulomb_pos_<joint>``, ``coulomb_neg_<joint>``
        of the unknown friction.
    expressions : tuple of str
        Each base parameter in the standard inertial parameters.
    x_std : ndarray, shape (r,)
        Standard errors (HAC sandwich).
    x_rse : ndarray, shape (r,)
        Relative standard errors ``x_std / abs(x)``.
    well_excited : ndarray of bool, shape (r,)
        ``x_rse < RSE_WARN`` (the library's poor-excitation threshold, 10 %).
    x_idim : ndarray, shape (r,)
        The IDIM-LS start.
    cutoff_hz : float
        IDIM low-pass cut-off.
    plant : plant.simulation.arm.ArmPlant
        The arm (for the controller: :class:`ctc.arm.ArmComputedTorque`);
        not in results sent between processes
        (:func:`identification.distributed.identify_many`: rebuild it with
        ``plant.simulation.arm.arm_plant(log.model)``).
    robot : str
        The robot's name.
    joint_names : tuple of str
        Its joint names.
    log_name : str
    elapsed_s : float
        Wall time of the identification (every stage).
    stage_times_s : dict
        Wall time per stage (``rigid``, ``model_choice_and_flexible_fit``,
        ``search_restart``).
    model : str
        ``"rigid"`` or ``"flexible"`` (:mod:`identification.arm_flexible`).
    model_choice : dict or None
        The model choice: ``model`` (``"rigid"``, ``"flexible"`` or
        ``"flexible+backlash"``), ``reason``, the held-back costs
        (pulses^2: ``held_back_cost_rigid_pulses2``,
        ``held_back_cost_springs_pulses2``, ``held_back_cost_backlash_pulses2``
        when the backlash was fitted, and ``held_back_cost_flexible_pulses2``,
        the chosen flexible model's), ``floor_pulses2``, ``floor_ratio`` (the
        chosen model's held-back cost in floors), ``adequate``; the tests of
        :func:`identify_arm`'s rule: ``flexible_paired_t`` and
        ``flexible_test`` (springs against the rigid model; the test passed:
        ``"ratio"``, ``"paired_t"``, ``"floor"``, ``"excess"`` or None;
        :class:`~identification.model_choice.ModelImprovement`), ``backlash_paired_t``,
        ``backlash_test`` and ``backlash_against`` (``"springs"`` or
        ``"rigid"``, the model chosen before the backlash).
    warnings : list of str
        E.g. a chosen model that does not describe the log.
    search_restart : dict or None
        When the default identification ended on a model that does not
        describe the log and the rigid model was searched again from the
        GA's start (:func:`identify_arm`, ``method``): ``floors_first`` (the
        first search's chosen model's cost in quantisation floors),
        ``rigid_floors`` (each GA seed's rigid fit, whole log), ``seed`` (the
        seed whose rigid fit beat the first search's, or None),
        ``floors_again`` (the identification from it, or None), ``kept``
        (whether that result replaced the first), ``reason``, ``elapsed_s``.
        None otherwise.  ``stage_times_s`` then has ``search_restart`` (and,
        when the second identification is kept, ``first_search``).
    joint_stiffness_Nm_per_rad, joint_damping_Nms_per_rad, motor_inertia_reflected_kgm2 : list or None
        A flexible result's joints (n each); x then holds
        ``[beta, log10 K, D, Ia, (b), friction]``, and beta is the
        rigid-equivalent (link plus ``Ia``).
    joint_backlash_rad : list or None
        Its backlash widths (n), None without backlash.
    joint_intervals : dict or None
        A flexible result's ranges of each joint's K, D and ``Ia`` whose
        prediction-error cost stays within a tenth of a quantisation floor of
        the fit's, with the robots the log allows beside the fit
        (:func:`identification.arm_flexible.arm_joint_intervals`); None for a
        rigid result.
    flexible_plant : plant.simulation.arm.ArmPlant or None
        A flexible result's two-mass arm, ``plant_row`` its lane
        parameters (:meth:`plant.simulation.arm.ArmPlant.lane_parameters`) and
        ``flexible_substeps`` the RK4 steps per sample of its fit.
    """

    def to_dict(self) -> dict:
        """The result as JSON-ready data (no plant, no arrays).

        Returns
        -------
        dict
            ``x``, ``names``, ``expressions``, ``x_std``, ``x_rse``,
            ``well_excited``, ``x_idim``, ``fun`` (pulses^2), ``output_error``
            (pulses^2, eq. 4), ``nfev``, ``nit``, ``success``, ``message``,
            ``interrupted``, ``output_error_substeps``, ``method``, ``robot``, ``joint_names``, ``log_name``,
            ``cutoff_hz``, ``elapsed_s``, ``bounds``, ``beta``, ``friction``,
            ``friction_identified``, ``model``, ``model_choice``, ``warnings``,
            ``stage_times_s``, ``flexible_substeps``, ``search_restart`` and the joints
            (``joint_stiffness_Nm_per_rad``, ``joint_damping_Nms_per_rad``,
            ``motor_inertia_reflected_kgm2``, ``joint_backlash_rad``,
            ``joint_intervals``; None for a rigid result) -- what
            :func:`identification.arm_payload.prior_from_file` reads back as a
            payload's prior.
        """
        def floats(v):
            return [None if not np.isfinite(a) else float(a) for a in np.asarray(v, dtype=float)]

        return dict(x=floats(self.x), names=list(self.names), expressions=list(self.expressions),
                    x_std=floats(self.x_std), x_rse=floats(self.x_rse),
                    well_excited=[bool(b) for b in self.well_excited], x_idim=floats(self.x_idim),
                    fun=float(self.fun), output_error=float(self.output_error),
                    output_error_substeps=self.get("output_error_substeps"), nfev=int(self.nfev),
                    nit=int(self.nit), success=bool(self.success), message=str(self.message),
                    interrupted=bool(self.get("interrupted", False)),
                    method=self.get("method"), robot=self.robot,
                    joint_names=list(self.joint_names), log_name=self.log_name,
                    cutoff_hz=float(self.cutoff_hz), elapsed_s=float(self.elapsed_s),
                    bounds=np.asarray(self.bounds, dtype=float).tolist(), beta=floats(self.beta),
                    friction=self.friction, friction_identified=bool(self.friction_identified),
                    model=self.get("model", "rigid"), model_choice=jsonable(self.get("model_choice")),
                    warnings=list(self.get("warnings") or []),
                    stage_times_s=jsonable(self.get("stage_times_s")),
                    flexible_substeps=self.get("flexible_substeps"),
                    search_restart=jsonable(self.get("search_restart")),
                    **{k: self.get(k) for k in _NO_JOINTS})

    def save_json(self, path, *, create_dirs=False):
        """Write :meth:`to_dict` as JSON, atomically (:func:`plant.logs.fileio.write_text_atomic`).

        Parameters
        ----------
        path : path-like
        create_dirs : bool
            Create a missing directory.

        Returns
        -------
        plant.logs.fileio.OutputTarget
        """
        import json

        from plant.logs.fileio import write_text_atomic

        return write_text_atomic(path, json.dumps(self.to_dict(), indent=1) + "\n",
                                 create_dirs=create_dirs)

    def table(self) -> str:
        """The base parameters with their standard errors, as text (one line each), and a
        flexible result's joint ranges (:func:`identification.flexible.joint_range_lines`)."""
        lines = [f"{'param':<8}{'value':>14}{'± std':>12}{'rse %':>9}  expression"]
        for name, v, sd, r, ex in zip(self.names, self.x, self.x_std, self.x_rse, self.expressions):
            lines.append(f"{name:<8}{v:>14.6g}  ± {sd:<8.2g}{100 * r:>8.3g}  {ex}")
        from .flexible import joint_range_lines

        lines.extend(joint_range_lines(self.get("joint_intervals")))  # a flexible result's
        lines.append(f"prediction-error cost: {self.fun:.6g} pulses^2   output error Y (eq. 4): "
                     f"{self.output_error:.6g} pulses^2")
        lines.append(f"simulations: {self.nfev}   iterations: {self.nit}   wall time: "
                     f"{self.elapsed_s:.2f} s")
        return "\n".join(lines)

    def plot(self, log, ax=None):
        """Logged and simulated tracking errors per joint (P loop with x, as ``output_error``).

        Parameters
        ----------
        log : plant.logs.arm_log.ArmLog
            The log identified.
        ax : array of matplotlib Axes, optional
            One per joint (default: a new figure).

        Returns
        -------
        matplotlib.figure.Figure
        """
        n = log.n_joints
        sub = int(self.get("output_error_substeps") or ARM_REPORT_SUBSTEPS)
        if ax is None:
            from matplotlib.figure import Figure

            fig = Figure(figsize=(4 * n, 3), layout="constrained")
            axes = fig.subplots(1, n, squeeze=False)[0]
        else:
            axes = np.asarray(ax, dtype=object).reshape(-1)
            if axes.size != n:
                raise ValueError(f"ax must hold {n} axes, got {axes.size}")
            fig = axes[0].figure
        if self.get("flexible_plant") is not None:
            sim = simulate_arm(self.flexible_plant, np.asarray(self.plant_row)[None], log.rig,
                               log.trajectory, log.n_samples,
                               substeps=max(sub, int(self.get("flexible_substeps") or 0)))
        else:
            sim = simulate_arm(self.plant, self.beta[None], self.rig, log.trajectory, log.n_samples,
                               substeps=sub)
        for j, a in enumerate(axes):
            a.step(log.t, log.e_pulses[:, j], where="post", lw=0.8, label="log")
            a.step(log.t, sim.errors[0, :, j], where="post", lw=0.8, ls="--", label="identified")
            a.set_title(log.joint_names[j])
            a.set_xlabel("t (s)")
            a.set_ylabel("e (pulses)")
            a.grid(True, alpha=0.3)
        axes[0].legend()
        return fig


def identify_arm(log, *, method=ARM_DEFAULT_METHOD, plant=None, gain=DEFAULT_GAIN,
                 substeps=ARM_REFINE_SUBSTEPS, max_iter=40, ftol=ARM_FTOL, cutoff_hz=None,
                 bounds=None, ranges=None, rng=None, ga_options=None,
                 workers=None, model="auto", output_substeps=None, callback=None,
                 progress=False) -> ArmIdentificationResult:
    """Identify an arm's base parameters from a P-control log (module docstring).

    Parameters
    ----------
    log : plant.logs.arm_log.ArmLog
        The logged experiment of a robot model (:func:`plant.logs.arm_log.load_arm_log`).
    method : {"idim+pem", "ga+pem", "paper", "idim-ls", "idim-iv"}
        ``"idim+pem"`` (default): IDIM-LS start, output-error refinement;
        when the IDIM-LS start does not simulate the log (an inertia matrix
        that is not positive definite, a diverging predictor: measured on a
        random planar arm of ``benchmarks/independent_arm.py`` whose joint-1
        drive friction, 1054 N m s/rad at the joint, dwarfed its link
        torques), the ``"ga+pem"`` GA supplies the start (its seed ``rng``,
        or :data:`IDIM_FALLBACK_SEED`) and ``warnings`` says so.
        ``"idim-ls"`` and ``"idim-iv"``: the classical inverse-model
        estimate alone (:func:`arm_idim_ls`; IDIM-IV with
        :data:`~identification.idim.IV_ITERATIONS` instrumental-variable
        steps), its own standard errors, the rigid model (``model`` other
        than ``"auto"`` or ``"rigid"`` is refused), ``fun`` the
        prediction-error cost at it; as :func:`identification.identify`'s
        methods of the same names.
        ``"paper"``: the paper's GA (:func:`identification.ga.run_ga` with
        its settings: 4 x 20 individuals, 40 generations) on the output
        error of eq. 4 -- the simulated P loop's integer errors against the
        logged ones -- in the search box, and nothing else.  ``"ga+pem"``:
        the same GA (Gray-coded, offspring whose running output error
        passes the population's worst stop early: ``early_stop=1.0``), then
        the refinement from its best individual and from the IDIM start
        (the better end wins).  Both GAs are :func:`identification.identify`'s
        (same settings, encoding, random stream, objective and failure
        penalty): on the PUMA 560 links 2-3 instance with the sidecar's box
        they give its f for the same seed.  With either start, a refinement
        that explains less than 90 % of the log's errors
        (:data:`~identification.flexible.RESTART_FRACTION` of ``sum e^2``: a
        wrong basin, e.g. IDIM-LS on a compliant arm whose motor encoders
        ring) is run again from the same starts through the predictor-gain
        continuation :data:`~identification.flexible.CONTINUATION_GAINS`
        (strongly corrected replays first); the better end is kept and
        ``warnings`` says so.  When the default identification
        (``"idim+pem"``, ``model="auto"``) ends, after the model choice, on
        a model that does not describe the log (its cost above
        :data:`~identification.flexible.INADEQUATE_FACTOR` quantisation
        floors: held back for a model choice, else the whole log's), the
        rigid model is searched again with ``"ga+pem"`` from
        :data:`ARM_MAX_RESTARTS` new seeds (``IDIM_FALLBACK_SEED + i``,
        ``rng + i``, or drawn from the caller's Generator; stopping at one
        at the floor); when one predicts the whole log better than the first
        search's rigid fit, the identification runs again from it, model
        choice included, and the result of fewer floors is kept: a
        refinement from IDIM-LS, or from one GA, can settle in a wrong
        basin that still explains most of a large P-loop error (measured on
        a random compliant four-joint chain of ``benchmarks/bench_arms.py``
        whose P loop lags by 7255 pulses: the rigid model kept at 7.8e4
        floors after the fallback GA of seed 0; after the restart, the
        springs at 1.02 floors and every well-excited base parameter within
        1 %, ``docs/tutorial_your_robot.rst``).  ``search_restart`` and
        ``warnings`` say so; a stop (callback, Ctrl-C) during these searches
        keeps the best result so far, marked ``interrupted``; a log that no
        search describes costs these searches' time.
    plant : plant.simulation.arm.ArmPlant, optional
        The arm (default :func:`plant.simulation.arm.arm_plant` of the log's robot).
    gain : float
        Output-injection gain of the predictor (fraction of the P gain).
    substeps : int
        RK4 steps per sample of the predictor.
    max_iter : int
        Refinement iterations at most.
    ftol : float
        Converged when an accepted step lowers the cost by less than ``ftol``
        relative (:func:`identification.refinement.refine`).
    cutoff_hz : float, optional
        IDIM low-pass cut-off (default: the quantisation-floor rule).
    bounds : array_like, shape (r, 2), optional
        Box of beta.  Default: from ``ranges`` if given; else the
        sidecar's search ranges when they name the model's base parameters
        (:func:`rig_search_box`: the PUMA 560 links 2-3 instance's f1..f9,
        the box of :func:`identification.identify`); else the IDIM
        estimate +- (50 % + 10 standard errors), a guess that is widened
        where the refinement ends on one of its bounds
        (:data:`~identification.refinement.BOX_WIDENINGS`; ``warnings`` names the parameters, ``bounds``
        of the result is the box the fit ran in).
    ranges : dict, optional
        Physical ranges of the links (masses, centres of mass, inertias,
        motor inertias) -> the box of beta by interval arithmetic, the
        paper's section 3.6 (:meth:`plant.robot.robot_model.RobotModel.parameter_ranges`).
    rng : numpy.random.Generator or int, optional
        The GA's random numbers (methods with a GA, and the default
        method's GA fallback and search restarts); the same seed gives the
        same result.
    ga_options : dict, optional
        Settings of :func:`identification.ga.run_ga` overriding the paper's
        (and ``gray``, ``early_stop`` above).
    workers : int, optional
        Threads of the simulations (default: the CPUs this process may use).
    model : {"auto", "rigid", "flexible"}
        The robot model (:mod:`identification.arm_flexible`): ``"rigid"``;
        ``"flexible"``, two-mass joints; ``"auto"`` (default): rigid when
        its prediction errors sit at the encoder's quantisation floor
        (within :data:`~identification.model_choice.ARM_FLOOR_FACTOR` floors), otherwise the springs when
        their held-back prediction-error cost is below
        :data:`~identification.model_choice.CHOICE_RATIO` times the rigid
        model's or lower per held-back block by more than :data:`~identification.model_choice.CHOICE_T`
        standard errors (a paired t test), or reach the floor where the
        rigid model does not, or leave less than ``CHOICE_RATIO`` of its
        excess over the floor (:class:`~identification.model_choice.ModelImprovement`).  When the model chosen so far (the springs, or
        the rigid model) leaves the held-back samples above the floor, the
        gearbox backlash is fitted too and kept by the same tests against it
        (:data:`~identification.model_choice.BACKLASH_T`); a model at the floor leaves the backlash
        nothing to explain, and it is not tried.  A flexible
        fit whose link model is no robot near the log's configurations
        (:meth:`~identification.arm_flexible.ArmFlexibleSpace.link_check`)
        or whose output error exceeds the rigid model's by more than a
        quantisation floor is rejected, with the reason.  ``model_choice``
        says which model and why.
    output_substeps : int, optional
        RK4 steps per sample of the GA's objective, the output error of
        eq. 4; default :func:`output_error_substeps` at the IDIM start (one
        step, the PUMA 560 path's, unless the arm's P loop or friction is
        fast for the sample time).  The result's ``output_error`` takes at
        least :data:`ARM_REPORT_SUBSTEPS`.
    callback : callable, optional
        ``callback(intermediate_result) -> bool``, :func:`identification.identify`'s
        convention: an ``OptimizeResult`` with ``x``, ``fun`` and ``stage``
        -- ``"ga"`` after every generation (``generation``, ``n_gen``;
        ``fun`` the output error, pulses^2), ``"refine"`` when a start of
        the rigid refinement ends (``start``, ``n_starts``; ``fun`` the
        prediction-error cost, pulses^2), ``"model"`` before each fit of the
        model choice (``step``, what is fitted, and ``fun`` None), when
        one of its starts ends (``step``, ``start``, ``n_starts``), and
        after every iteration of its flexible fits (no ``step``: a poll,
        so that a stop takes effect within an iteration).  True
        stops: a GA or rigid refinement returns its best point so far, a
        stopped model choice keeps the rigid result; ``interrupted`` is then
        True.  A KeyboardInterrupt stops the same way.
    progress : bool
        A tqdm bar over the GA's generations.

    Returns
    -------
    ArmIdentificationResult
        ``success`` False (with a message) when the refinement's simulations
        fail at the start point.  With a GA: ``ga`` (its best individual,
        output error and generations).  ``model``, ``model_choice`` and,
        for a flexible result, the joints (``joint_stiffness_Nm_per_rad``,
        ``joint_damping_Nms_per_rad``, ``motor_inertia_reflected_kgm2``,
        ``joint_backlash_rad``, n each); a chosen model that does not
        predict the held-back samples within
        :data:`~identification.flexible.INADEQUATE_FACTOR` quantisation
        floors says so in ``warnings`` and ``model_choice['adequate']``.

    Raises
    ------
    ValueError
        As :func:`arm_idim_ls`, an unknown method or model, malformed bounds or
        ``output_substeps``.
    """
    from .ga import run_ga

    t0 = time.perf_counter()
    if method not in ARM_METHODS:
        raise ValueError(f"unknown method {method!r}; choose one of {', '.join(ARM_METHODS)}")
    if model not in ARM_MODELS:
        raise ValueError(f"unknown model {model!r}; choose one of {', '.join(ARM_MODELS)}")
    idim_only = method in ("idim-ls", "idim-iv")
    if idim_only and model not in ("auto", "rigid"):
        raise ValueError(f"method {method!r} identifies the rigid model; model {model!r} needs "
                         "the output-error methods")
    pl = _plant_of(log, plant)
    rig = log.rig
    nb = pl.base.rank
    unknown = friction_layout(rig)[1]
    # the simulated plant: the rig's friction, or the lane's when the sidecar does not know it
    sim_plant = arm_plant(pl.model, pl.base, lane_friction=True) if unknown else pl

    def lane(X):
        X = np.atleast_2d(X)
        return _lane_friction(rig, X, nb) if unknown else X

    idim = arm_idim_ls(log, plant=pl, cutoff_hz=cutoff_hz,
                       iv_iterations=IV_ITERATIONS if method == "idim-iv" else 0)
    x0 = idim["x"]
    r = x0.size
    if bounds is None and ranges is not None:
        bounds = pl.model.parameter_ranges(ranges)
        wide = bounds[:, 1] - bounds[:, 0] <= 0  # a parameter the ranges pin: a sliver around it
        pad = 1e-6 * np.maximum(np.abs(bounds[:, 0]), 1e-9)
        bounds[wide, 0] -= pad[wide]
        bounds[wide, 1] += pad[wide]
    if bounds is None and ranges is None:
        bounds = rig_search_box(rig, pl.base)  # None when the sidecar names none of beta
    hw = 0.5 * np.abs(x0) + 10.0 * idim["x_std"]
    hw = np.maximum(hw, 1e-9 * max(1.0, float(np.max(np.abs(x0)))))
    around = np.column_stack([x0 - hw, x0 + hw])
    around[nb:, 0] = np.maximum(around[nb:, 0], 0.0)  # friction is not negative
    guessed_box = bounds is None  # the box around the IDIM estimate: widened at need
    if bounds is None:
        bounds = around
    elif np.shape(bounds)[0] == nb and unknown:  # ranges or bounds of beta: friction around IDIM
        bounds = np.vstack([np.asarray(bounds, dtype=float), around[nb:]])
    bounds = np.asarray(bounds, dtype=float)
    if bounds.shape != (r, 2) or not np.all(np.isfinite(bounds)) or np.any(bounds[:, 0] >= bounds[:, 1]):
        raise ValueError(f"bounds must have shape ({r}, 2) with low < high")
    if output_substeps is None:  # the box's upper ends of any unknown friction
        oe_substeps = output_error_substeps(
            log, pl, x0, _lane_friction(rig, bounds[:, 1][None], nb)[0, nb:])
    else:
        oe_substeps = int(output_substeps)
        if oe_substeps < 1 or oe_substeps != output_substeps:
            raise ValueError(f"output_substeps must be a whole number >= 1, got {output_substeps!r}")
    names = tuple(pl.base.names) + tuple(
        f"{FRICTION_COMPONENTS[w]}_{log.joint_names[j]}" for j, w in unknown)
    ga_info = None
    starts = x0[None]
    problem = ArmPredictionErrorProblem(log, sim_plant, gain=gain, substeps=substeps, workers=workers)
    notes = []
    report = _reporter(callback)
    refine_cb = None if callback is None else (
        lambda i, m, xs, c: report("refine", xs, c, start=i, n_starts=m))

    def ga_start(paper, generator):
        # the PUMA 560 path's GA (identification.identify): the paper's binary GA, or Gray-coded
        # with early termination of offspring past the population's worst before a refinement
        settings = dict(PAPER_GA, gray=not paper, early_stop=None if paper else 1.0)
        settings.update(ga_options or {})
        e_log = np.asarray(log.e_pulses, dtype=float)

        def output_error(X, cap=None):
            return simulate_arm(sim_plant, lane(X), rig, log.trajectory, log.n_samples,
                                e_log=e_log, errors=False, substeps=oe_substeps, cap=cap,
                                workers=workers).objective

        n_gen = settings.get("n_gen")
        ga = run_ga(output_error, bounds, rng=generator, progress=progress,
                    callback=None if callback is None else (
                        lambda st: report("ga", st.x, st.fun, generation=st.generation,
                                          n_gen=n_gen)), **settings)
        info = dict(x=np.asarray(ga.x, dtype=float), output_error=float(ga.fun),
                    nfev=int(ga.nfev), generations=int(ga.nit), substeps=oe_substeps,
                    best=np.asarray(ga.history["best"], dtype=float),
                    interrupted=bool(ga.interrupted), message=ga.message)
        return info, np.vstack([info["x"], np.clip(x0, bounds[:, 0], bounds[:, 1])])

    if method in ("ga+pem", "paper"):
        ga_info, starts = ga_start(method == "paper", np.random.default_rng(rng))
    elif not idim_only and not np.all(problem.residuals(np.clip(x0, bounds[:, 0], bounds[:, 1]))
                                      < problem.bound):
        # the IDIM start does not simulate (an inertia matrix that is not positive definite,
        # a predictor that diverges: a drive whose friction dominates the link torques leaves
        # IDIM-LS's inertial parameters loose): the GA's start over the box, then the refinement
        ga_info, starts = ga_start(False, np.random.default_rng(
            IDIM_FALLBACK_SEED if rng is None else rng))
        notes.append("the IDIM-LS start does not simulate the log (its predictor fails); the "
                     "refinement started from the GA's best individual over the box "
                     "(method 'ga+pem')")
    ga_only = method == "paper" or (ga_info is not None and ga_info["interrupted"])
    if idim_only:  # the inverse-model estimate as it is, with the predictor's cost at it
        ref = OptimizeResult(x=x0, fun=float(np.sum(problem.residuals(x0) ** 2)), nfev=1,
                             nit=int(idim["iv_iterations"]), interrupted=False, jac=None,
                             residuals=None,
                             message="IDIM-LS" if method == "idim-ls" else
                             f"IDIM-IV ({idim['iv_iterations']} instrumental-variable steps)")
    elif ga_only:
        # the paper's GA, or a GA stopped early: its best individual, not refined
        ref = OptimizeResult(x=ga_info["x"], fun=float(np.sum(problem.residuals(ga_info["x"]) ** 2)),
                             nfev=ga_info["nfev"], nit=ga_info["generations"],
                             message=(ga_info["message"] if ga_info["interrupted"] else "the paper's GA"),
                             interrupted=ga_info["interrupted"], jac=None, residuals=None)
    else:
        ref = refine(problem, starts, bounds, max_iter=max_iter, ftol=ftol, callback=refine_cb)
        energy = float(np.sum(np.asarray(log.e_pulses, dtype=float) ** 2))
        if not ref.interrupted and not (ref.fun <= RESTART_FRACTION * energy):
            # the refinement explains less than 90 % of the log's errors: a wrong basin, not a
            # model-form limit (a compliant arm whose motor encoders ring leaves IDIM-LS far
            # off).  Again from the same starts through the predictor-gain continuation of the
            # flexible fit (strongly corrected replays first, few local minima); the better
            # of the two is kept.
            cont = refine_through_gains(
                lambda g: problem if g == gain else ArmPredictionErrorProblem(
                    log, sim_plant, gain=g, substeps=substeps, workers=workers),
                starts, bounds, CONTINUATION_GAINS + (gain,), max_iter=max_iter, ftol=ftol,
                stage_ftol=CONTINUATION_FTOL, callback=refine_cb)
            if cont.fun < ref.fun or cont.interrupted:
                notes.append(f"the refinement explained {1 - ref.fun / energy:.1%} of the log's "
                             f"errors (a wrong basin); refined again through the predictor-gain "
                             f"continuation {CONTINUATION_GAINS}: {1 - cont.fun / energy:.1%}")
                cont.nfev += int(ref.nfev)
                ref = cont
            else:
                ref.nfev = int(ref.nfev) + int(cont.nfev)
        if guessed_box and not ref.interrupted:
            ref, bounds, widened = widen_guessed_box(
                problem, ref, bounds, nonnegative=np.arange(len(bounds)) >= nb,
                max_iter=max_iter, ftol=ftol, callback=refine_cb)
            if widened:
                notes.append(f"the refinement ended on the bound of the box around the IDIM "
                             f"estimate for {', '.join(names[i] for i in widened)}; the box "
                             f"was widened there and the fit refined again")
    x = np.asarray(ref.x, dtype=float)
    ok = bool(np.isfinite(ref.fun) and ref.fun < problem.bound ** 2)
    n = log.n_joints
    if ref.jac is not None and ok:
        cov, _ = sandwich_covariance(ref.jac, ref.residuals, n_channels=n)
        x_std = np.sqrt(np.maximum(np.diag(cov), 0.0))
    elif idim_only:  # the inverse model's own (sandwich) standard errors
        cov, x_std = idim["cov"], np.asarray(idim["x_std"], dtype=float)
    else:
        cov, x_std = None, np.full(r, np.nan)
    with np.errstate(divide="ignore", invalid="ignore"):
        rse = x_std / np.abs(x)
    report_substeps = max(oe_substeps, ARM_REPORT_SUBSTEPS)
    sim = simulate_arm(sim_plant, lane(x), rig, log.trajectory, log.n_samples, e_log=log.e_pulses,
                       errors=False, substeps=report_substeps, workers=workers)
    nfev = int(ref.nfev) + (ga_info["nfev"] if ga_info and not ga_only else 0)
    start = "the IDIM start" if ga_info is None else "every start"
    friction = motor_side_friction(rig, x, nb)
    expressions = tuple(pl.base.expressions) + tuple(
        f"joint-side {FRICTION_COMPONENTS[w]} friction of {log.joint_names[j]}" for j, w in unknown)
    res = ArmIdentificationResult(
        x=x, beta=x[:nb].copy(), fun=float(ref.fun), output_error=float(sim.objective[0]),
        nfev=nfev, nit=int(ref.nit), success=ok, method=method, ga=ga_info, bounds=bounds,
        interrupted=bool(getattr(ref, "interrupted", False)), message=(ref.message or "ok") if ok else
        f"the predictor failed at {start}: the log does not fit the robot model",
        names=names, expressions=expressions, x_std=x_std, x_rse=rse, cov=cov,
        well_excited=rse < RSE_WARN, x_idim=x0, cutoff_hz=idim["cutoff_hz"], plant=pl,
        friction=friction, friction_identified=bool(unknown), robot=pl.model.name,
        joint_names=tuple(pl.model.joint_names),
        rig=rig if not unknown else rig_with_friction(rig, friction),
        log_name=log.name, elapsed_s=0.0, model="rigid", model_choice=None, warnings=notes,
        flexible_plant=None, plant_row=None, flexible_substeps=None, search_restart=None,
        output_error_substeps=report_substeps, stage_times_s=dict(rigid=time.perf_counter() - t0),
        **_NO_JOINTS)
    rigid_fun = float(res.fun) if ok else float("inf")
    if ok and model != "rigid" and not res.interrupted and not idim_only:
        t1 = time.perf_counter()
        try:
            res = _apply_arm_model(res, log, model, problem, bounds, workers=workers,
                                   max_iter=max_iter, ftol=ftol, report=report)
        except _Stopped:  # a stop (callback, Ctrl-C) in the model choice: the rigid result
            res.interrupted = True
            res.message = f"{res.message}; model choice interrupted: the rigid result is kept"
            res.model_choice = dict(model="rigid", reason="model choice interrupted")
        res.stage_times_s["model_choice_and_flexible_fit"] = time.perf_counter() - t1
    level = _floors(res, log)
    if (method == ARM_DEFAULT_METHOD and model == "auto" and not res.interrupted
            and not level <= INADEQUATE_FACTOR):
        res = _restart_search(res, level, rigid_fun, log, dict(
            plant=pl, gain=gain, substeps=substeps, max_iter=max_iter, ftol=ftol,
            cutoff_hz=cutoff_hz, bounds=bounds, ga_options=ga_options, workers=workers,
            model=model, output_substeps=output_substeps, callback=callback, progress=progress),
            rng, t0)
    res.elapsed_s = time.perf_counter() - t0
    return res


#: GA seeds of the rigid search run again (``"ga+pem"``, a new seed each) after a default
#: identification that ends on a model that does not describe the log: the PUMA 560 path's
#: :data:`identification.flexible.MAX_RESTARTS`.
ARM_MAX_RESTARTS = MAX_RESTARTS


def _restart_search(res, level, rigid_fun, log, options, rng, t0):
    """The default identification's rigid search again from the GA's start (:func:`identify_arm`).

    The rigid model is searched from :data:`ARM_MAX_RESTARTS` GA seeds
    (``"ga+pem"``, ``model="rigid"``; seeds ``IDIM_FALLBACK_SEED + i``,
    ``rng + i`` for an int, or drawn from the caller's Generator), stopping
    at one that predicts the log to the quantisation floor.  When the best
    of them predicts the whole log better than the first search's rigid fit
    (``rigid_fun``, pulses^2), the identification runs again from its seed
    with the model choice, and the result of fewer floors (:func:`_floors`)
    is kept; ``search_restart`` and ``warnings`` say what was run.
    """
    t1 = time.perf_counter()
    floor = quantisation_floor(log.n_samples * log.n_joints)
    if rng is None or isinstance(rng, (int, np.integer)):
        base = IDIM_FALLBACK_SEED if rng is None else int(rng)
        seeds = [base + i for i in range(1, ARM_MAX_RESTARTS + 1)]
    else:  # a Generator: seeds from its stream (the same state gives the same seeds)
        seeds = [int(v) for v in np.random.default_rng(rng).integers(0, 2 ** 32, ARM_MAX_RESTARTS)]
    first, nfev, rigid, best_seed, best_fun = _chosen(res), int(res.nfev), [], None, rigid_fun
    interrupted = False
    for seed in seeds:
        alt = identify_arm(log, method="ga+pem", rng=seed, **dict(options, model="rigid"))
        nfev += int(alt.nfev)
        if alt.interrupted:  # a stop (callback, Ctrl-C): what there is so far
            interrupted = True
            break
        fun = float(alt.fun) if alt.success else float("inf")
        rigid.append(fun / floor)
        if fun < best_fun:
            best_seed, best_fun = seed, fun
        if fun / floor <= ARM_FLOOR_FACTOR:
            break
    best, again, name = res, None, None
    if best_seed is not None and not interrupted:
        alt = identify_arm(log, method="ga+pem", rng=best_seed, **options)
        nfev += int(alt.nfev)
        interrupted = bool(alt.interrupted)
        again, name = _floors(alt, log), _chosen(alt)
        if not interrupted and alt.success and again < level:
            best = alt
    start = "the GA that replaced its IDIM-LS start" if res.get("ga") is not None else "IDIM-LS"
    reason = (f"the first search (from {start}) left the {first} model at {level:.4g} "
              f"quantisation floors (> {INADEQUATE_FACTOR:g}; its rigid fit {rigid_fun / floor:.4g} "
              f"floors over the log); the rigid model searched again from the GA's start (method "
              f"'ga+pem', {len(rigid)} seed(s)): " + ", ".join(f"{v:.4g}" for v in rigid) + " floors"
              + ("; no better rigid fit" if best_seed is None else
                 f"; seed {best_seed}'s rigid fit better" if again is None else
                 f"; identified again from seed {best_seed}: the {name} model at {again:.4g} floors")
              + ("; interrupted" if interrupted else "")
              + ("; kept" if best is not res else "; the first search kept"))
    best.search_restart = dict(floors_first=level, rigid_floors=rigid, seed=best_seed,
                               floors_again=again, kept=best is not res, reason=reason,
                               elapsed_s=time.perf_counter() - t1)
    best.warnings = list(best.warnings) + [reason]
    best.method = ARM_DEFAULT_METHOD
    best.nfev = nfev
    best.interrupted = bool(best.interrupted or interrupted)
    # the stages of the result kept; a kept second identification's first search before them
    best.stage_times_s = dict(best.stage_times_s, search_restart=time.perf_counter() - t1,
                              **({} if best is res else dict(first_search=t1 - t0)))
    return best


def _floors(res, log) -> float:
    """A result's cost in quantisation floors: its chosen model's held-back cost when the model
    choice compared models on held-back blocks, else its whole-log prediction-error cost
    (a rigid fit at the floor, or no flexible fit possible: both kinds are about 1 at the
    floor, so the restart compares them as they are)."""
    mc = res.get("model_choice") or {}
    if "floor_ratio" in mc and np.isfinite(mc["floor_ratio"]):
        return float(mc["floor_ratio"])
    if not res.success:
        return float("inf")
    return float(res.fun) / quantisation_floor(log.n_samples * log.n_joints)


def _chosen(res) -> str:
    """The model a result chose (its model choice's name, with the backlash)."""
    return (res.get("model_choice") or {}).get("model") or res.get("model", "rigid")


#: Models of :func:`identify_arm`.
ARM_MODELS = ("auto", "rigid", "flexible")


class _Stopped(Exception):
    """A stop requested during the model choice (callback or KeyboardInterrupt)."""


def _reporter(callback):
    """``report(stage, x, fun, **info) -> bool``: the caller's callback (False without one)."""
    def report(stage, x, fun, **info):
        if callback is None:
            return False
        return bool(callback(OptimizeResult(
            x=None if x is None else np.array(x, dtype=float), fun=fun, stage=stage, **info)))
    return report

_NO_JOINTS = dict(joint_stiffness_Nm_per_rad=None, joint_damping_Nms_per_rad=None,
                  motor_inertia_reflected_kgm2=None, joint_backlash_rad=None,
                  joint_intervals=None)


def _held_cost(problem, x, held, residuals=False):
    """Prediction-error cost of x on the held-back residuals (and the residuals, if asked)."""
    r = problem.residuals(np.asarray(x, dtype=float)[None])[0]
    cost = float(r[held] @ r[held])
    return (cost, r) if residuals else cost


def _apply_arm_model(res, log, model, problem, bounds, *, workers, max_iter, ftol, report):
    """The model choice and the flexible fit of :func:`identify_arm` (its docstring).

    ``report`` is :func:`_reporter`'s; a stop raises :class:`_Stopped`.
    """
    from .arm_flexible import (ARM_BACKLASH_GRID, IA_FRACTION_BOUNDS, IA_FRACTION_MAX, N_STARTS,
                               ArmFlexibleSpace, fit_flexible_arm)
    from .refinement import MaskedProblem, held_back_mask

    n, nb = log.n_joints, res.plant.base.rank
    floor = quantisation_floor(log.n_samples * n)
    level = res.fun / floor
    if model == "auto" and level <= ARM_FLOOR_FACTOR:
        res.model_choice = dict(
            model="rigid", floor_ratio=level, adequate=True,
            reason=f"the rigid model predicts the log to the quantisation floor "
                   f"(prediction-error cost {level:.3g} x n/12 <= {ARM_FLOOR_FACTOR})")
        return res
    def stage(step):
        """Say what is fitted next (a stop ends the model choice); that fit's refine callback."""
        if report("model", None, None, step=step):
            raise _Stopped
        return lambda i, m, xs, c: report("model", xs, c, step=step, start=i, n_starts=m)

    def poll():
        """Between refinement iterations: does the caller stop (a Ctrl-C in the CLI)?"""
        return report("model", None, None)

    def checked(ref):
        """ref, unless a stop (callback, KeyboardInterrupt) ended it."""
        if getattr(ref, "interrupted", False):
            raise _Stopped
        return ref

    fit_mask, held = held_back_mask(log.n_samples, n, log.rig.sample_time_s)
    floor_h = quantisation_floor(held.sum())
    # the rigid model refit without the held-back blocks
    cb = stage(f"model choice: the rigid model refitted without the held-back samples "
               f"(the rigid cost is {level:.3g} quantisation floors)")
    ref_r = checked(refine(MaskedProblem(problem, fit_mask), res.x[None], bounds, max_iter=20,
                           ftol=ftol, callback=cb))
    c_rigid, r_rigid = _held_cost(problem, ref_r.x, held, residuals=True)
    if not np.isfinite(c_rigid):
        c_rigid = np.inf  # a failed rigid prediction: any model that predicts beats it
    try:
        space = ArmFlexibleSpace(log, res.plant, res.beta, bounds[nb:])
    except ValueError as exc:
        res.model_choice = dict(model="rigid", reason=f"no flexible fit: {exc}")
        return res
    problems = {}

    def problem_at(sp, box):
        sub = sp.substeps(box)

        def make(g):
            key = (sp.backlash, g)
            if key not in problems:
                problems[key] = ArmPredictionErrorProblem(
                    log, sp.plant, gain=g, substeps=sub, workers=workers, to_lanes=sp.to_lanes,
                    feasible=lambda X: sp.feasible(X, sub))
            return problems[key]
        return make

    box = space.bounds(bounds[:nb])
    at = problem_at(space, box)
    pool = space.pool(res.beta, res.x[nb:])
    cb = stage(f"model choice: two-mass joints ({box.shape[0]} parameters, the best "
               f"{N_STARTS} of {len(pool)} starts, {space.substeps(box)} RK4 steps per sample)")
    flex = fit_flexible_arm(space, at, box, pool=pool, mask=fit_mask, max_iter=max_iter, ftol=ftol,
                            callback=cb, poll=poll)
    checked(flex["refine"])

    def heavier_motors(sp, box_, fit, at_):
        """A fit with a motor inertia on the box's upper bound, refitted from its point with
        the bound at IA_FRACTION_MAX: (fit, box, widened) -- the refit when it predicts the
        held-back samples better (a fit that presses on the bound for a model it lacks, the
        backlash, predicts them worse beyond it: the near-floor test log of
        tests/test_arm_flexible.py)."""
        wide = sp.bounds(bounds[:nb], ia_max=IA_FRACTION_MAX)
        if np.array_equal(box_, wide) or not sp.at_motor_inertia_bound(box_, fit["x"]):
            return fit, box_, False  # already the widest box, or not on its bound
        cb_ = stage(f"model choice: a motor inertia of the {'backlash' if sp.backlash else 'springs'}' "
                    f"fit on the bound of the two-mass box "
                    f"({IA_FRACTION_BOUNDS[1]:g} of the smallest diagonal inertia): refitted "
                    f"with the bound at {IA_FRACTION_MAX:g}")
        again = fit_flexible_arm(sp, at_, wide, starts=fit["x"][None], mask=fit_mask,
                                 max_iter=max_iter, ftol=ftol, continuation=(), callback=cb_,
                                 poll=poll)
        checked(again["refine"])
        better = (again["cost"] < fit["cost"]
                  and _held_cost(at_(DEFAULT_GAIN), again["x"], held)
                  < _held_cost(at_(DEFAULT_GAIN), fit["x"], held))
        return (again, wide, True) if better else (fit, box_, False)

    flex, box, ia_wide = heavier_motors(space, box, flex, at)
    c_flex, r_flex = _held_cost(at(DEFAULT_GAIN), flex["x"], held, residuals=True)
    if not np.isfinite(c_flex):
        c_flex = np.inf
    floor_at = ARM_FLOOR_FACTOR * floor_h
    spring = ModelImprovement(c_flex, r_flex, c_rigid, r_rigid, floor_h, log, CHOICE_T)
    choice = dict(rule=(f"a richer model if its held-back cost is below {CHOICE_RATIO} x the "
                        f"simpler's, lower per held-back block by paired t > {CHOICE_T:g}, or "
                        f"at the quantisation floor (<= {ARM_FLOOR_FACTOR:g} floors) where the "
                        f"simpler is not, or its excess over the floor below {CHOICE_RATIO} x the "
                        "simpler's (identification.model_choice.ModelImprovement)"),
                  held_back_cost_rigid_pulses2=c_rigid, held_back_cost_flexible_pulses2=c_flex,
                  held_back_cost_springs_pulses2=c_flex, floor_pulses2=floor_h,
                  flexible_paired_t=spring.t, flexible_test=spring.test)
    fspace, fbox, fat, fx, c_f = space, box, at, flex["x"], c_flex
    spring_chosen = spring.better or model == "flexible"
    # the model the backlash must improve on: the springs when chosen, else the rigid model
    c_best, r_best = (c_flex, r_flex) if spring_chosen else (c_rigid, r_rigid)
    verdict = f"springs: {spring.why}"
    if c_best <= floor_at:
        # a model that predicts the held-back samples to the quantisation floor leaves the
        # backlash nothing to explain (the rule that skips the springs after a rigid fit at
        # the floor): lowering its cost further would fit the encoder's own noise
        who = "springs predict" if spring_chosen else "rigid model predicts"
        verdict += (f"; backlash not tried: the {who} the held-back samples to the quantisation floor "
                    f"({c_best / floor_h:.3g} x {floor_h:.4g} pulses^2 <= {ARM_FLOOR_FACTOR:g})")
    else:
        # the gearbox backlash (the paper's second cause of the oscillations), from the spring
        # fit's point at a few widths: when the model chosen so far (the springs, or the rigid
        # model) does not predict the held-back samples to the floor
        bspace = ArmFlexibleSpace(log, res.plant, res.beta, bounds[nb:], backlash=True)
        bbox = bspace.bounds(bounds[:nb], ia_max=IA_FRACTION_MAX if ia_wide else None)
        bat = problem_at(bspace, bbox)
        starts = bspace.with_backlash(flex["x"], (0.0,) + ARM_BACKLASH_GRID)
        # and the link-mode pool at each width: a spring fitted without the backlash is
        # softer than the gearbox (the dead zone passes for compliance), so its point alone
        # can miss the backlash basin
        bpool = bspace.pool(res.beta, res.x[nb:], widths=ARM_BACKLASH_GRID)
        cb = stage(f"model choice: two-mass joints with backlash ({bbox.shape[0]} parameters, "
                   f"{len(starts)} starts from the springs' fit and the best {N_STARTS} of "
                   f"{len(bpool)}, {bspace.substeps(bbox)} RK4 steps per sample)")
        bl = fit_flexible_arm(bspace, bat, bbox, starts=starts, pool=bpool, mask=fit_mask,
                              max_iter=max_iter, ftol=ftol, continuation=CONTINUATION_BACKLASH,
                              callback=cb, poll=poll)
        checked(bl["refine"])
        bl, bbox, _ = heavier_motors(bspace, bbox, bl, bat)
        c_bl, r_bl = _held_cost(bat(DEFAULT_GAIN), bl["x"], held, residuals=True)
        if not np.isfinite(c_bl):
            c_bl = np.inf
        backlash = ModelImprovement(c_bl, r_bl, c_best, r_best, floor_h, log, BACKLASH_T)
        choice["backlash_test"] = backlash.test
        choice["held_back_cost_backlash_pulses2"] = c_bl
        choice["backlash_paired_t"] = backlash.t
        choice["backlash_against"] = "springs" if spring_chosen else "rigid"
        side = "springs" if spring_chosen else "rigid model"
        if backlash.better:
            fspace, fbox, fat, fx, c_f = bspace, bbox, bat, bl["x"], c_bl
            verdict += f"; with backlash, against the {side}: {backlash.why}"
        else:
            verdict += f"; backlash tried, against the {side}: {backlash.why}: no backlash"
    ratio = c_f / c_rigid if c_rigid > 0 else 1.0
    chosen = "flexible" if (spring_chosen or fspace.backlash) else "rigid"
    name = "flexible+backlash" if fspace.backlash else "flexible"
    choice.update(held_back_cost_flexible_pulses2=c_f, ratio=ratio,
                  reason=(f"held-back prediction-error cost {name}/rigid = {ratio:.3g} "
                          f"({c_f:.4g} / {c_rigid:.4g} pulses^2); {verdict}"
                          + ("; model='flexible' requested" if model == "flexible" else "")))
    if chosen == "rigid":
        res.nfev = int(problem.nfev) + sum(int(p.nfev) for p in problems.values())
        return _judge_arm(res, dict(choice, model="rigid"), c_rigid, floor_h)
    # the full fit from the held-back fit's point
    cb = stage(f"{name} chosen: fitted to the whole log")
    full = fit_flexible_arm(fspace, fat, fbox, starts=fx[None], max_iter=max_iter, ftol=ftol,
                            continuation=(), callback=cb, poll=poll)
    checked(full["refine"])
    flex_res = _flexible_arm_result(res, log, fspace, fbox, full, workers,
                                    residuals=fat(DEFAULT_GAIN).residuals)
    # every simulated candidate of the model choice and the fits (the rigid ones included)
    flex_res.nfev = int(problem.nfev) + sum(int(p.nfev) for p in problems.values())
    allowance = floor
    physical, unphysical = fspace.link_check(full["x"], fspace.substeps(fbox))
    if not physical or not flex_res.success or flex_res.output_error > res.output_error + allowance:
        why = (unphysical if not physical else
               "its predictor or closed loop fails" if not flex_res.success else
               f"its output error {flex_res.output_error:.4g} pulses^2 exceeds the rigid model's "
               f"{res.output_error:.4g} by more than the quantisation floor {allowance:.4g}")
        if model == "flexible":
            flex_res.success = False
            flex_res.message = f"flexible fit rejected: {why}"
            return _judge_arm(flex_res, dict(choice, model=name), c_f, floor_h)
        res.nfev = flex_res.nfev
        return _judge_arm(res, dict(choice, model="rigid",
                                    reason=f"flexible fit rejected: {why}; " + choice["reason"]),
                          c_rigid, floor_h)
    return _judge_arm(flex_res, dict(choice, model=name), c_f, floor_h)


#: Gains of the backlash fit's continuation (it starts from the spring fit's point).
CONTINUATION_BACKLASH = (0.1,)


def _judge_arm(res, choice, cost, floor_h):
    """Flag a chosen model whose held-back cost stays far above the quantisation floor."""
    level = float(cost) / float(floor_h)
    choice["floor_ratio"] = level
    choice["adequate"] = bool(level <= INADEQUATE_FACTOR)
    if not choice["adequate"]:
        res.warnings = list(res.warnings) + [
            f"the {choice['model']} model does not describe the log: its held-back "
            f"prediction-error cost is {level:.3g} x the quantisation floor ({float(cost):.4g} / "
            f"{float(floor_h):.4g} pulses^2, limit {INADEQUATE_FACTOR:g}); beta may be biased"]
    res.model_choice = choice
    return res


def _flexible_arm_result(rigid, log, space, box, fit, workers, residuals=None):
    """The ArmIdentificationResult of a flexible fit (the rigid result's bookkeeping kept;
    with the fit problem's ``residuals``, its ``joint_intervals``)."""
    x = np.asarray(fit["x"], dtype=float)
    ref = fit["refine"]
    nb, n = space.r, space.n
    ok = bool(np.isfinite(ref.fun) and ref.fun < 1e12)
    if ref.jac is not None and ok:
        cov, _ = sandwich_covariance(ref.jac, ref.residuals, n_channels=n)
        x_std = np.sqrt(np.maximum(np.diag(cov), 0.0))
    else:
        cov, x_std = None, np.full(x.size, np.nan)
    with np.errstate(divide="ignore", invalid="ignore"):
        rse = x_std / np.abs(x)
    row = space.to_lanes(x)
    sim = simulate_arm(space.plant, row, log.rig, log.trajectory, log.n_samples,
                       e_log=log.e_pulses, errors=False,
                       substeps=max(int(rigid.output_error_substeps), space.substeps(box)),
                       workers=workers)
    ok = ok and sim.status[0] == 0
    o = nb + (4 if space.backlash else 3) * n
    fr_x = np.concatenate([x[:nb], x[o:]])
    friction = motor_side_friction(log.rig, fr_x, nb)
    unknown = bool(space.unknown)
    names = tuple(space.names())
    rig = log.rig if not unknown else rig_with_friction(log.rig, friction)
    joint_what = (("log10 stiffness (N m/rad)", "damping (N m s/rad)",
                   "reflected motor inertia Jm k^2 (kg m^2)")
                  + (("backlash width (rad)",) if space.backlash else ()))
    expressions = (tuple(rigid.expressions[:nb])
                   + tuple(f"joint {what} of {j}" for what in joint_what for j in log.joint_names)
                   + tuple(rigid.expressions[nb:]))
    out = ArmIdentificationResult(dict(rigid))
    out.update(x=x, beta=x[:nb].copy(), fun=float(ref.fun), output_error=float(sim.objective[0]),
               nfev=int(rigid.nfev) + int(fit["nfev"]), nit=int(rigid.nit) + int(ref.nit),
               success=ok, message=(ref.message or "ok") if ok else
               "the flexible fit's simulated closed loop fails",
               names=names, expressions=expressions, x_std=x_std, x_rse=rse, cov=cov,
               well_excited=rse < RSE_WARN, bounds=box, friction=friction, rig=rig,
               model="flexible", flexible_plant=space.plant, plant_row=row[0],
               flexible_substeps=space.substeps(box),
               warnings=list(rigid.warnings), stage_times_s=dict(rigid.stage_times_s),
               **space.joints(x))
    if residuals is not None and ok:
        # the joint parameters the log leaves open (identification.flexible.joint_intervals)
        from .arm_flexible import arm_joint_intervals
        from .flexible import open_joints_text

        ji = arm_joint_intervals(log, x, space, box, residuals)
        out["joint_intervals"] = ji
        text = open_joints_text(ji)
        if text:
            out["warnings"].append(text)
    return out
