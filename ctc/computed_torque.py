"""Computed-torque controller (CTC) built on the identified base parameters.

Control law (Craig, *Introduction to Robotics*, sec. 10.5; Spong,
Hutchinson & Vidyasagar, *Robot Modeling and Control*, sec. 8.3), per sample
``t_k = k Ts``::

    a   = qdd_d + Kv (qd_d - qd_hat) + Kp (q_d - q_hat) + Ki z   (outer loop)
    tau = D_hat(q_hat) a + h_hat(q_hat, v_h) + g_hat(q_hat) - tau_f(v_f)
    i   = tau / (k Kt)                                            (motor current)
    z  <- z + Ts (q_d - q_hat)   unless the current saturated     (error sum)

* ``D_hat``, ``h_hat`` (Coriolis/centrifugal) and ``g_hat`` are the model of
  :mod:`plant.robot.model` instantiated with the controller's ``f`` (9,): the
  compiled kernels ``mass_terms``, ``coriolis_terms`` and ``gravity_terms``
  are called from this module's compiled step -- there is no second copy of
  the dynamics.
* ``tau_f`` is the drive friction of the sidecar, :func:`plant.robot.model.friction_torque`
  with the joint-side constants of :func:`plant.logs.rig.rig_constants`; the
  feed-forward ``-tau_f`` cancels it.
* ``q_d, qd_d, qdd_d`` come from the log's trajectory (analytic), tabulated at
  ``t_k = k Ts`` when the controller is built.
* ``q_hat, qd_hat`` come from the velocity estimator (default: a current
  observer of the double integrator driven by the previous command ``a``
  and by the quantised position taken at the centre of its pulse cell;
  alternative: a low-pass filtered backward difference), see
  :mod:`ctc.design`.
* ``Ki z``: integral action, off by default (``Ki = 0``); with
  ``integral_bandwidth_hz`` (:func:`ctc.design.design_gains`) ``Kp, Kv, Ki``
  place the loop's poles and the sum's real pole (a PID outer loop, Craig
  sec. 10.5's "partitioned control" with the error integral added).  It
  removes the steady part of a torque the model gets wrong, which the PD law
  leaves as ``d / (D Kp)`` rad.  The sum is frozen on a sample whose current
  the drive's limit cuts (conditional integration, no windup).
* ``v_h``, ``v_f``: the velocity used in ``h_hat`` and in the friction
  feed-forward.  Default: the reference velocity ``qd_d`` (``nonlinear_velocity=
  "reference"``), because the robot tracks to a pulse and ``qd_d`` is
  noise-free; this matters for the Coulomb term, whose sign flips at each
  velocity reversal.  ``"estimate"`` uses ``qd_hat`` instead.

Choice of the velocity estimate (measured on the paper trajectory, rigid
robot, true f, default gains; max abs(e) after 50 ms and RMS abs(e) in pulses,
joint 2 / joint 3):

============================================  ==========  =============
estimator                                     max abs(e)  RMS abs(e)
============================================  ==========  =============
observer, cell centre, qd_d in h and tau_f    1 / 1       0.263 / 0.288
observer, cell centre, qd_hat in h and tau_f  1 / 1       0.269 / 0.284
observer, truncated count (no centring)       1 / 1       0.711 / 0.706
filtered difference (85.7 Hz), cell centre    2 / 2       0.660 / 1.261
============================================  ==========  =============

The observer wins because it uses the commanded acceleration, which after
feedback linearisation *is* the acceleration, so it needs the quantised
measurement only to correct slow drift; a difference of positions that
move by a fraction of a pulse per sample is mostly quantisation noise.
Taking the count at the centre of its cell removes the half-pulse bias of
truncation.  ``qd_d`` and ``qd_hat`` in the nonlinear terms are equivalent
here; ``qd_d`` is the default because it is noise-free.

Per-sample cost: one call of a compiled function on preallocated arrays;
the only allocation is the returned (2,) array (``benchmarks/bench_ctc.py``:
about 2.5 us per call, target <= 20 us).
"""
from __future__ import annotations


import math

import numba
import numpy as np

from typing import NamedTuple

from plant.simulation.core import cell_centre
from plant.robot.model import (
    checked_f,
    friction_torque,
    inverse_dynamics_terms,
    is_positive_definite,
    mass_terms,
)
from plant.simulation.controllers import LoggedController, register_control_law
from plant.logs.rig import RigConstants, rig_constants

from .design import ESTIMATORS, GainDesign, gains_for
from .guard import as_limit

__all__ = ["ComputedTorqueController", "CTCParameters", "CTCLaw", "CTCLawKind", "ctc_law",
           "reference_of", "model_f"]


class CTCParameters(NamedTuple):
    """Constants of the compiled CTC step, by name (a numba-typed value).

    Attributes
    ----------
    rig : plant.logs.rig.RigConstants
        Joint-side drive constants of the rig (the core's rig layout).
    kp, kv : tuple of 2 float
        Outer-loop gains (s^-2, s^-1).
    ki : tuple of 2 float
        Integral gains (s^-3) on the summed position error (0: no integral action).
    observer_q, observer_w : tuple of 2 float
        Current-observer gains on the position residual (position: 1,
        velocity: 1/s).
    alpha : tuple of 2 float
        Pole of the filtered backward difference (``estimator = 1``).
    estimator : int
        0 current observer, 1 filtered difference (index in
        :data:`ctc.design.ESTIMATORS`).
    estimate_in_nonlinear : bool
        Use the velocity estimate (True) instead of the reference velocity in
        h_hat and the friction feed-forward.
    friction : bool
        Friction feed-forward on.
    cell_centre : bool
        Take the quantised position at the centre of its pulse cell.
    """

    rig: RigConstants
    kp: tuple
    kv: tuple
    ki: tuple
    observer_q: tuple
    observer_w: tuple
    alpha: tuple
    estimator: int
    estimate_in_nonlinear: bool
    friction: bool
    cell_centre: bool


# Layout of the state vector.
S_INIT = 0
S_Q = 1  # 1, 2 position estimate
S_W = 3  # 3, 4 velocity estimate
S_A = 5  # 5, 6 previous outer-loop command
S_Y = 7  # 7, 8 previous measured position
S_I = 9  # 9, 10 sum of the position error times Ts (integral action)
S_LEN = 11

_NLV = {"reference": 0.0, "estimate": 1.0}


@numba.njit(nogil=True, error_model="numpy")
def saturated(i2, i3, c):
    """Currents clipped at the drive's full scale, and the joint torque the clip removed.

    The PUMA 560 CTC laws (rigid and flexible joints) end here (issue 21):
    ``i_s = clip(i, -I_fs, I_fs)`` with ``I_fs = c.current_limit``, and
    ``u = k Kt (i_s - i)``, the joint-side
    torque the drive did not give -- what an observer needs for anti-windup
    (back-calculation: K. J. Astrom and T. Hagglund, *Advanced PID Control*,
    2006, sec. 3.5).

    Parameters
    ----------
    i2, i3 : float
        Commanded motor currents (A).
    c : plant.logs.rig.RigConstants
        Rig layout (``current_limit``, ``torque_per_amp``).

    Returns
    -------
    i2s, i3s : float
        Applied currents (A).
    u2, u3 : float
        Joint torque removed by the clip (N m; 0 below the limit).
    """
    lim = c.current_limit
    i2s = min(max(i2, -lim), lim)
    i3s = min(max(i3, -lim), lim)
    return i2s, i3s, (i2s - i2) * c.torque_per_amp[0], (i3s - i3) * c.torque_per_amp[1]


@numba.njit(nogil=True)
def joint_update(j, k, qm, p, ref, S, lane):
    """Estimator and outer loop of joint ``j`` (0 or 1); returns (y, q_hat, qd_hat, a, v_nl).

    ``S`` (S_LEN, lanes): estimator states, column ``lane``.
    """
    ts = p.rig.sample_time_s
    sc = p.rig.pulses_per_rad[j]
    if p.cell_centre:
        y = cell_centre(float(round(qm * sc))) / sc
    else:
        y = qm
    if S[S_INIT, lane] == 0.0:
        qh = y
        wh = ref[k, 2 + j]
    elif p.estimator == 0:
        # current observer: predict with the previous command, correct with y
        qb = S[S_Q + j, lane] + ts * S[S_W + j, lane] + 0.5 * ts * ts * S[S_A + j, lane]
        wb = S[S_W + j, lane] + ts * S[S_A + j, lane]
        r = y - qb
        qh = qb + p.observer_q[j] * r
        wh = wb + p.observer_w[j] * r
    else:
        # low-pass filtered backward difference
        al = p.alpha[j]
        qh = y
        wh = al * S[S_W + j, lane] + (1.0 - al) * (y - S[S_Y + j, lane]) / ts
    a = (ref[k, 4 + j] + p.kv[j] * (ref[k, 2 + j] - wh) + p.kp[j] * (ref[k, j] - qh)
         + p.ki[j] * S[S_I + j, lane])
    vn = wh if p.estimate_in_nonlinear else ref[k, 2 + j]
    return y, qh, wh, a, vn


@numba.njit(nogil=True)
def integrate_error(j, k, qh, saturated_by, p, ref, S, lane):
    """Add ``Ts (q_d - q_hat)`` of joint ``j`` to its error sum, unless its current saturated.

    Conditional integration (anti-windup): while the drive's limit cuts the
    current (``saturated_by != 0``), the sum is frozen.
    """
    if p.ki[j] != 0.0 and saturated_by == 0.0:
        S[S_I + j, lane] += p.rig.sample_time_s * (ref[k, j] - qh)


@numba.njit(nogil=True)
def _ctc_currents(k, qm2, qm3, f, p, ref, S, lane):
    """The CTC law of one sample for estimator column ``lane`` of ``S``: currents (i2, i3).

    The one implementation of the law: the Python controller
    (:func:`_ctc_step`) and the compiled law of the logged-run driver
    (:func:`ctc_law`) call it.
    """
    c = p.rig
    y2, q2, w2, a2, v2 = joint_update(0, k, qm2, p, ref, S, lane)
    y3, q3, w3, a3, v3 = joint_update(1, k, qm3, p, ref, S, lane)
    t2, t3 = inverse_dynamics_terms(f, q2, q3, v2, v3, a2, a3, c.gravity)
    if p.friction:
        t2 -= friction_torque(v2, c.viscous[0], c.coulomb_pos[0], c.coulomb_neg[0], c.ramp_speed[0])
        t3 -= friction_torque(v3, c.viscous[1], c.coulomb_pos[1], c.coulomb_neg[1], c.ramp_speed[1])
    i2 = t2 / c.torque_per_amp[0]
    i3 = t3 / c.torque_per_amp[1]
    i2, i3, u2, u3 = saturated(i2, i3, c)
    if u2 != 0.0 or u3 != 0.0:
        # anti-windup: the observer predicts the next sample with the acceleration
        # the *saturated* current gives the model, a + D_hat(q_hat)^-1 u
        d11, d12, d22 = mass_terms(f, math.cos(q3), math.sin(q3))
        det = d11 * d22 - d12 * d12
        if det > 0.0:
            a2 += (d22 * u2 - d12 * u3) / det
            a3 += (d11 * u3 - d12 * u2) / det
    S[S_Q, lane] = q2
    S[S_Q + 1, lane] = q3
    S[S_W, lane] = w2
    S[S_W + 1, lane] = w3
    S[S_A, lane] = a2
    S[S_A + 1, lane] = a3
    S[S_Y, lane] = y2
    S[S_Y + 1, lane] = y3
    integrate_error(0, k, q2, u2, p, ref, S, lane)
    integrate_error(1, k, q3, u3, p, ref, S, lane)
    S[S_INIT, lane] = 1.0
    return i2, i3


@numba.njit(cache=True, nogil=True)
def _ctc_step(k, q_meas, f, p, ref, s):
    """One CTC sample: update the estimator state ``s`` ((S_LEN,) or (S_LEN, 1)) in place; currents (2,).

    ``ref`` (n, 6) holds q_d (2), qd_d (2), qdd_d (2) per sample; row ``k`` is
    used.  The only allocation is the returned array.
    """
    out = np.empty(2)
    out[0], out[1] = _ctc_currents(k, q_meas[0], q_meas[1], f, p, ref, s.reshape((s.size, 1)), 0)
    return out


class CTCLawKind(NamedTuple):
    """Type tag of the CTC law in the logged-run driver (:mod:`plant.simulation.controllers`).

    Attributes
    ----------
    code : int
        2 (informative only: the *type* is what the driver dispatches on).
    """

    code: int = 2


class CTCLaw(NamedTuple):
    """Parameters of the compiled CTC law in the logged-run driver.

    Attributes
    ----------
    parameters : CTCParameters
        Rig layout, gains and options.
    f : ndarray, shape (9,)
        The controller's model f (D_hat, h_hat, g_hat).
    reference : ndarray, shape (n_total, 6)
        q_d, qd_d, qdd_d at t_k = k Ts from the start of the run.
    """

    parameters: CTCParameters
    f: np.ndarray
    reference: np.ndarray


@numba.njit(nogil=True, inline="always")  # IR-inlined into the lane loop (no arrays passed per lane)
def ctc_law(lp, c, k, Y, E, CS, U, j):
    """The CTC as a compiled law of the logged-run driver (:mod:`plant.simulation.controllers`).

    Parameters
    ----------
    lp : CTCLaw
        Parameters, model f and reference table.
    c : plant.logs.rig.RigConstants
        Rig layout of the simulation (unused: the law's own is in ``lp``).
    k : int
        Sample index from the start of the run.
    Y : ndarray, shape (2, lanes)
        Measured joint-side motor angles (rad) of every lane (joints 2, 3).
    E : ndarray, shape (2, lanes)
        Pulse errors (unused).
    CS : ndarray, shape (S_LEN, lanes)
        Estimator states per lane.
    U : ndarray, shape (2, lanes)
        Currents (A): column ``j`` is written.
    j : int
        Lane.
    """
    U[0, j], U[1, j] = _ctc_currents(k, Y[0, j], Y[1, j], lp.f, lp.parameters, lp.reference, CS, j)


register_control_law(CTCLawKind, ctc_law)


def as_pair(values):
    a = np.broadcast_to(np.asarray(values, dtype=float), (2,))
    return (float(a[0]), float(a[1]))


def model_f(f) -> np.ndarray:
    """A controller's model f (9,) (:func:`plant.robot.model.checked_f`), pointing a result to
    ``from_result``.

    Parameters
    ----------
    f : array_like, shape (9,)

    Returns
    -------
    ndarray, shape (9,)

    Raises
    ------
    ValueError
        If ``f`` is an identification result or not 9 finite numbers.
    """
    return checked_f(f, "f", "use ComputedTorqueController.from_result(result, log)")


def reference_of(log, trajectory=None):
    """The reference a controller follows: ``trajectory``, or the log's.

    Parameters
    ----------
    log : plant.ExperimentLog
    trajectory : plant.logs.trajectory.Trajectory, optional

    Returns
    -------
    plant.logs.trajectory.Trajectory

    Raises
    ------
    ValueError
        If ``trajectory`` is not a :class:`plant.logs.trajectory.Trajectory`, or
        ``log`` is not a log.
    """
    from plant.logs.trajectory import Trajectory

    if trajectory is None:
        if not hasattr(log, "trajectory") or not hasattr(log, "rig"):
            raise ValueError(f"log must be a plant.ExperimentLog, got {type(log).__name__}")
        return log.trajectory
    if not isinstance(trajectory, Trajectory):
        raise ValueError("trajectory must be a plant.logs.trajectory.Trajectory (e.g. "
                         f"Trajectory.from_terms(...)), got {type(trajectory).__name__}")
    return trajectory


def tabulate_reference(trajectory, t):
    q, qd, qdd = trajectory.evaluate(t)
    return np.ascontiguousarray(np.hstack([q, qd, qdd]), dtype=np.float64)


#: The builder of a controller from an identification result (rigid or flexible):
#: :func:`ctc.flexible.controller_from_result` registers itself here when
#: :mod:`ctc.flexible` is imported (``import ctc`` does), so that this module
#: needs no import of the flexible-joint controller built on it.
RESULT_FACTORY = {"build": None}


class ComputedTorqueController:
    """Computed-torque controller following the sampled-controller protocol.

    Build it with :meth:`from_log` or :meth:`from_result`.  Calling it
    returns the motor currents (2,) A for sample ``k``; see the module
    docstring for the law.

    Parameters
    ----------
    f : array_like, shape (9,)
        Model base parameters f1..f9 (e.g. the identified ones).
    rig : plant.logs.rig.Rig
        Rig constants: Ts, gear ratios, encoders, Kt, friction, gravity.
    trajectory : plant.logs.trajectory.Trajectory
        Reference (analytic q, qd, qdd).
    gains : ctc.design.GainDesign
        Outer-loop gains and velocity estimator (:func:`ctc.design.design_gains`).
    n_samples : int
        Samples from t = 0 for which the reference is tabulated; later samples
        evaluate the trajectory on the fly (slower, allocates).
    nonlinear_velocity : {"reference", "estimate"}
        Velocity used in h_hat and the friction feed-forward.
    friction : bool
        Friction feed-forward on (default) or off.
    cell_centre : bool
        Take the quantised position at the centre of its pulse cell (default)
        rather than at the truncated count.

    Attributes
    ----------
    f : ndarray, shape (9,)
        The model's base parameters.
    parameters : CTCParameters
        Rig layout, gains and options of the compiled step, by name.
    reference_table : ndarray, shape (n_samples, 6)
        q_d (2), qd_d (2), qdd_d (2) at t_k = k Ts (rad, rad/s, rad/s^2).

    Raises
    ------
    ValueError
        Wrong shape or non-finite ``f``, D_hat(q) not positive definite for
        ``f`` (checked over a full turn of q3), bad options.

    Notes
    -----
    Sources: computed-torque / inverse-dynamics control, J. J. Craig,
    *Introduction to Robotics*, 3rd ed., sec. 10.5 (partitioned control,
    model-based part + servo part); M. W. Spong, S. Hutchinson, M. Vidyasagar,
    *Robot Modeling and Control*, sec. 8.3; the model is the paper's eq. 2
    (corrected) with f from eq. 3.
    """

    def __init__(self, f, rig, trajectory, gains, *, n_samples, nonlinear_velocity="reference",
                 friction=True, cell_centre=True):
        f = np.asarray(f, dtype=np.float64)
        if f.shape != (9,):
            raise ValueError(f"f must have shape (9,) (f1..f9), got {f.shape}")
        if not np.all(np.isfinite(f)):
            raise ValueError("f contains NaN or inf")
        if not is_positive_definite(f):
            raise ValueError("D_hat(q) is not positive definite for this f (checked over a full turn of q3)")
        if not isinstance(gains, GainDesign):
            raise ValueError(f"gains must be a ctc.design.GainDesign, got {type(gains).__name__}")
        if gains.estimator not in ESTIMATORS:
            raise ValueError(f"unknown estimator {gains.estimator!r}")
        if nonlinear_velocity not in _NLV:
            raise ValueError(f"nonlinear_velocity must be one of {tuple(_NLV)}, got {nonlinear_velocity!r}")
        if abs(gains.ts - rig.sample_time_s) > 1e-12 * rig.sample_time_s:
            raise ValueError(f"gains designed for Ts = {gains.ts} s, rig has {rig.sample_time_s} s")
        n = int(n_samples)
        if n < 1:
            raise ValueError(f"n_samples must be >= 1, got {n_samples}")
        self.f = np.ascontiguousarray(f)
        self.rig = rig
        self.trajectory = trajectory
        self.gains = gains
        self.nonlinear_velocity = nonlinear_velocity
        self.friction = bool(friction)
        self.cell_centre = bool(cell_centre)
        self.parameters = CTCParameters(
            rig=rig_constants(rig),
            kp=as_pair(gains.Kp), kv=as_pair(gains.Kv), ki=as_pair(gains.Ki),
            observer_q=as_pair(gains.observer_gain[:, 0]), observer_w=as_pair(gains.observer_gain[:, 1]),
            alpha=as_pair(gains.alpha), estimator=ESTIMATORS.index(gains.estimator),
            estimate_in_nonlinear=nonlinear_velocity == "estimate",
            friction=self.friction, cell_centre=self.cell_centre,
        )
        self._ts = float(rig.sample_time_s)
        self.reference_table = tabulate_reference(trajectory, np.arange(n) * self._ts)
        if not np.all(np.isfinite(self.reference_table)):
            raise ValueError("the reference trajectory is not finite")
        self._n = n
        self._scratch = np.zeros((1, 6))
        self._state = np.zeros((S_LEN, 1))
        #: following-error limit (:class:`ctc.guard.FollowingErrorLimit`) or None: see :meth:`from_result`
        self.following_error = None
        #: when the limit handed the arm to the rig's P law (s; None: never)
        self.fallback_t_s = None
        self._following_above = None  # the samples beyond the limit (ctc.guard)

    @classmethod
    def from_log(cls, f, log, *, gains=None, nonlinear_velocity="reference", friction=True,
                 cell_centre=True, n_samples=None, trajectory=None, following_error_limit=None,
                 **design):
        """Build the CTC of a log's rig and reference.

        Parameters
        ----------
        f : array_like, shape (9,)
            Model base parameters f1..f9 (e.g. ``identification.identify(log).f``).
        log : plant.ExperimentLog
            Source of the rig constants (gear, encoder, Kt, Ts, friction,
            gravity) and of the reference trajectory.
        gains : ctc.design.GainDesign, optional
            Ready-made gains; otherwise ``design_gains(log.rig, **design)``.
        nonlinear_velocity, friction, cell_centre
            See the class docstring.
        n_samples : int, optional
            Samples to tabulate (default ``log.n_total``; later samples are
            evaluated on the fly).
        trajectory : plant.logs.trajectory.Trajectory, optional
            The reference to follow (default the log's): any reference, e.g.
            ``Trajectory.from_terms(...)`` or ``Trajectory.paper(T)``.
        following_error_limit : None, 'log', float, array_like (2,) or ctc.guard.FollowingErrorLimit
            A following-error limit (:mod:`ctc.guard`; default none, the
            paper's CTC): from the sample at which it trips (a joint's
            pulse error beyond it for longer than its dwell time, or beyond
            twice it), the rig's P law ``i = P e`` holds the arm until
            :meth:`reset` (``fallback_t_s``, a
            :class:`ctc.guard.FollowingErrorWarning`).  ``'log'``: twice the
            log's largest P-law error per joint, at least
            :data:`ctc.guard.MIN_LIMIT_PULSES` (:func:`ctc.guard.lost_bound`; the default of
            :meth:`from_result`); see :func:`ctc.guard.as_limit`.
        **design
            Keyword arguments of :func:`ctc.design.design_gains`
            (``bandwidth_hz``, ``damping``, ``estimator``,
            ``estimator_bandwidth_hz``, ``delay_samples``).

        Returns
        -------
        ComputedTorqueController

        Raises
        ------
        ValueError
            See the class docstring; also for ``gains`` given together with
            design keywords.
        """
        f = model_f(f)
        traj = reference_of(log, trajectory)
        limit = as_limit(following_error_limit, log)
        gains = gains_for(log.rig, gains, **design)
        ctrl = cls(
            f, log.rig, traj, gains,
            n_samples=log.n_total if n_samples is None else n_samples,
            nonlinear_velocity=nonlinear_velocity, friction=friction, cell_centre=cell_centre,
        )
        ctrl.following_error = limit
        return ctrl

    @classmethod
    def from_result(cls, result, log, **options):
        """Build the CTC from everything an identification found.

        * ``f``: the identified base parameters (rigid-equivalent for a
          flexible result);
        * friction: the identified one when ``friction_identified`` is true
          (the log's rig with its friction replaced), otherwise the log's;
        * joints: for a result with ``model == "flexible"``, the identified
          stiffness K, damping D and reflected motor inertia ``Jm k^2`` go
          into the motor-side computed torque of
          :class:`ctc.flexible.FlexibleJointComputedTorqueController`
          (a subclass: the motor follows the reference, the spring torque
          comes from a link model in the controller; see :mod:`ctc.flexible`
          for the design and the measurements that chose it).

        Safety: the controller is armed with a following-error limit
        (``following_error_limit='log'``, :class:`ctc.guard.FollowingErrorLimit`:
        twice the log's largest P-law error per joint, tripping after 20 ms
        beyond it within 100 ms or at once beyond twice it): a robot the model no
        longer describes (a tool it does not know of, a badly identified
        model) is handed to the rig's P law, the loop the log was recorded
        with, instead of being destabilised.  Pass
        ``following_error_limit=None`` for the bare law.

        A rigid result with the sidecar's friction gives exactly
        ``ComputedTorqueController.from_log(result.f, log, following_error_limit='log',
        **options)``.

        Parameters
        ----------
        result : identification.IdentificationResult, ctc.contract.IdentifiedModel, dict or path
            The result (read through :class:`ctc.contract.IdentifiedModel`), its
            :meth:`~identification.IdentificationResult.to_dict`,
            or a JSON file written by ``save_json`` / the CLI's ``--output``
            (read with :meth:`~identification.IdentificationResult.load_json`).
        log : plant.ExperimentLog
            Source of the rig constants and of the reference trajectory.
        **options
            Keyword arguments of :meth:`from_log` (``gains``,
            ``nonlinear_velocity``, ``friction``, ``cell_centre``,
            ``n_samples`` and the gain-design keywords); for a flexible
            result also ``link_substeps``.

        Returns
        -------
        ComputedTorqueController
            A :class:`ctc.flexible.FlexibleJointComputedTorqueController`
            for a flexible result.

        Raises
        ------
        ValueError
            A result that is not a dict or a readable result file
            (:class:`identification.result.ResultFileError`), an unknown
            ``model``, a flexible result without its joints, malformed
            friction, or anything :meth:`from_log` refuses.
        """
        if RESULT_FACTORY["build"] is None:  # pragma: no cover - ctc/__init__ imports ctc.flexible
            raise RuntimeError("no controller factory registered (import ctc, not ctc.computed_torque alone)")
        options.setdefault("following_error_limit", "log")
        return RESULT_FACTORY["build"](result, log, **options)

    # ------------------------------------------------------------ protocol
    def reset(self) -> None:
        """Clear the estimator state and re-arm the following-error limit (call before a new run)."""
        self._state[:] = 0.0
        self.fallback_t_s = None
        self._following_above = None  # the samples beyond the limit (ctc.guard)

    def set_model_f(self, f) -> np.ndarray:
        """Switch the controller's model (D_hat, h_hat, g_hat) to ``f`` (on-line adaptation).

        Parameters
        ----------
        f : array_like, shape (9,)

        Returns
        -------
        ndarray, shape (9,)
            The array now held as ``self.f``.
        """
        self.f = np.ascontiguousarray(f, dtype=float)
        return self.f

    def logged_law_with(self, log, state, f):
        """:meth:`logged_controller` with the model ``f`` in the law (a window run under ``f``).

        Parameters
        ----------
        log : plant.ExperimentLog
        state : array_like, shape (9,)
        f : array_like, shape (9,)

        Returns
        -------
        plant.simulation.controllers.LoggedController
        """
        import dataclasses

        law = self.logged_controller(log, state=state)
        return dataclasses.replace(law, parameters=law.parameters._replace(
            f=np.ascontiguousarray(f, dtype=float)))

    def __call__(self, k, t, q_meas, e_pulses) -> np.ndarray:
        """Motor currents (2,) A for sample ``k`` at time ``t`` (s).

        Parameters
        ----------
        k : int
            Sample index (t = k Ts); samples must come in order after :meth:`reset`.
        t : float
            Sample time (s); used only beyond the tabulated reference.
        q_meas : ndarray, shape (2,)
            Quantised joint angles (rad) from the encoder counts.
        e_pulses : ndarray, shape (2,)
            Pulse errors: read by the following-error limit only (the CTC
            forms its error from the continuous reference and the position
            estimate).

        Returns
        -------
        ndarray, shape (2,)
            Motor currents (A): the rig's P law once the following-error
            limit has tripped.
        """
        if self.following_error is not None:
            i = self.following_error.hold(self, t, e_pulses)
            if i is not None:
                return i
        if type(q_meas) is not np.ndarray or q_meas.dtype != np.float64:
            q_meas = np.asarray(q_meas, dtype=np.float64)
        if q_meas.shape != (2,):
            raise ValueError(f"q_meas must have shape (2,), got {q_meas.shape}")
        if 0 <= k < self._n:
            return _ctc_step(k, q_meas, self.f, self.parameters, self.reference_table, self._state)
        self._scratch[:] = tabulate_reference(self.trajectory, np.array([float(t)]))
        return _ctc_step(0, q_meas, self.f, self.parameters, self._scratch, self._state)

    def logged_controller(self, log, state=None):
        """This controller as a compiled law of the logged-run driver.

        :func:`plant.simulate_batch` then simulates a log (a window of a run
        under this CTC) with the CTC in the loop of every lane
        (:mod:`plant.simulation.controllers`).

        Parameters
        ----------
        log : plant.ExperimentLog
            The log (its trajectory and ``n_total`` size the reference table).
        state : array_like, shape (9,), optional
            Estimator state at the log's first simulated sample (default:
            none yet -- the estimator starts from the first measurement and
            the reference velocity, as after :meth:`reset`).

        Returns
        -------
        plant.simulation.controllers.LoggedController
        """
        n = int(log.n_total)
        if log.trajectory == self.trajectory and self.reference_table.shape[0] >= n:
            table = self.reference_table
        else:
            table = tabulate_reference(log.trajectory, np.arange(n) * self._ts)
        s0 = np.zeros(S_LEN) if state is None else np.asarray(state, dtype=float).reshape(S_LEN)
        return LoggedController(kind=CTCLawKind(), parameters=CTCLaw(self.parameters, self.f, table),
                                state=s0, name="CTC", n_joints=2)

    def estimator_state(self) -> np.ndarray:
        """A copy of the estimator state (9,) (for :meth:`logged_controller`).

        Returns
        -------
        ndarray, shape (9,)
        """
        return self._state[:, 0].copy()

    def torque(self, q, qd, qdd) -> np.ndarray:
        """Model torque ``D_hat(q) qdd + h_hat(q, qd) + g_hat(q)`` (N m), friction excluded.

        Convenience for checks; calls :func:`plant.robot.model.inverse_dynamics`.

        Parameters
        ----------
        q, qd, qdd : array_like, shape (2,) or (n, 2)
            Joint angles (rad), rates (rad/s), accelerations (rad/s^2).

        Returns
        -------
        ndarray, shape (2,) or (n, 2)
        """
        from plant.robot.model import inverse_dynamics

        return inverse_dynamics(self.f, q, qd, qdd, self.rig.gravity_m_s2)

    def __repr__(self) -> str:
        g = self.gains
        return (
            f"ComputedTorqueController(estimator={g.estimator!r}, "
            f"bandwidth_hz={g.bandwidth_hz.tolist()}, damping={g.damping.tolist()}, "
            f"nonlinear_velocity={self.nonlinear_velocity!r}, friction={self.friction})"
        )
