"""Computed-torque control of any serial arm from its identified base parameters.

The law of :mod:`ctc.computed_torque`, for the n joints of a robot model
(:class:`plant.robot.robot_model.RobotModel`) whose base parameters beta were
identified (:func:`identification.arm.identify_arm`)::

    a   = qdd_d(t_k + Ts/2) + Kv (qd_d - qd_hat) + Kp (q_d - q_hat) + Ki z   (outer loop)
    tau = D_hat(q_m) a + n_hat(q_m, qd_d(t_k + Ts/2)) - tau_f(qd_d(t_k + Ts/2))
    i   = clip(tau / (k Kt), -I_fs, I_fs)                                  (motor current)

with ``q_m = q_hat + q_d(t_k + Ts/2) - q_d(t_k)``: the feed-forward and the
model are taken at the middle of the sample over which the current is held
(zero-order hold), where the mean acceleration of the reference lies
(``qd_d(t_k + Ts) - qd_d(t_k) = Ts qdd_d(t_k + Ts/2) + O(Ts^3)``).  Measured:
on a PUMA 560 joints 1-3 draw with 4096-pulse encoders at 4.8 rad/s, the
feed-forward at ``t_k`` left 3-4 pulses of lag with the *true* parameters,
the mid-sample one +-1 (``benchmarks/independent_arm.py``, ``draw("puma123", 1)``).

* ``D_hat`` and ``n_hat`` (Coriolis/centrifugal plus gravity) are the
  robot model's, instantiated with beta: the same casadi expressions in the
  joints' sines and cosines that the plant of :mod:`plant.simulation.arm` compiles
  (Craig, *Introduction to Robotics*, sec. 10.5; Spong, Hutchinson &
  Vidyasagar, *Robot Modeling and Control*, sec. 8.3), evaluated through
  the casadi function's call buffer (its numbers, at 0.14-0.19 ms a
  sample for the whole law on two to six joints instead of 0.34-0.42 ms,
  ``benchmarks/bench_ctc.py``);
* ``tau_f`` the sidecar's drive friction (:func:`plant.robot.model.friction_torque`),
  cancelled by feed-forward at the reference velocity;
* ``q_hat, qd_hat`` the current observer of :mod:`ctc.design` per joint
  (double integrator driven by the commanded acceleration, measurement at
  the centre of the count's cell);
* Kp, Kv (and Ki, with ``integral_bandwidth_hz``: the error sum ``z``, frozen on a
  joint whose current saturates) and the observer gains by :func:`ctc.design.design_gains` per joint
  (default bandwidth :func:`ctc.design.default_bandwidth_hz`);
* the current is saturated at the drive's full scale; the observer is then
  driven by the acceleration the saturated current gives (no windup).

**Held feedback** (``set_beta(beta, feedback_beta=...)``): the model's
feed-forward with the feedback multiplied by another model's inertia
matrix::

    tau = D_hat(q_m) qdd_d + D_f(q_m) (a - qdd_d) + n_hat(q_m, qd_d) - tau_f(qd_d)

a computed torque whose feedback keeps the design model's inertia, between
computed torque and the feedforward scheme with fixed feedback gains
(Khosla & Kanade, "Experimental evaluation of nonlinear feedback and
feedforward control schemes for manipulators", IJRR 7(1), 1988; An,
Atkeson & Hollerbach, *Model-Based Control of a Robot Manipulator*, MIT
Press 1988).  The observer is driven by the acceleration ``a`` the
feedback model gives (saturated: ``qdd_d + D_f^-1 (tau - D_hat qdd_d -
n_hat + tau_f)``), not by the one the model in use predicts (``qdd_d +
D_hat^-1 D_f (a - qdd_d)``): a trade-off, the observer's correction
absorbing that bias, for a controller whose map from the measured counts
to the feedback current is the design's -- gains, observer and ``D_f``
-- whichever model is in use; the model in use adds ``D_hat qdd_d +
n_hat``, torque along the reference (at the estimated configuration, so
its gravity still feeds the position back, as any computed torque's
does).  Why: where a two-mass joint's motor moves alone against its
spring, the feedback torque, ``D_hat`` times the outer loop's
acceleration, drives the motor inertia only, so the loop gain there
grows with the model's inertia (the two-mass joint of Spong, "Modeling
and control of elastic joint robots", ASME JDSMC 109(4), 1987); a
payload's model raises it.  Measured on a compliant planar arm (``benchmarks/bench_arm_adaptive.py --compliant``, seed 20261831,
draw 20261835) the rigid-equivalent CTC given the right 2.09 kg model
diverged on the identified two-mass arm carrying the tool
(``docs/figures/bench_arm_adaptive_compliant_20261831.json``, its switch
check); with the feedback held it tracks that arm within 36 pulses
(``..._20261831_held_feedback.json``; the adaptive CTC of such a design
holds it so, :mod:`ctc.arm_adaptive`).

Safety: :meth:`ArmComputedTorque.from_result` arms the following-error
limit (``envelope``, :func:`log_envelope`, :class:`ctc.guard.FollowingErrorLimit`,
the same rule as the PUMA controllers' ``from_result``): a tracking error
beyond twice the largest error of the P loop the log was recorded with
(:func:`ctc.guard.lost_bound`) for more than 20 ms of the last 100 ms, or
beyond twice that, hands the arm to that P law for the rest of the run, with a
:class:`ctc.guard.FollowingErrorWarning` (the model does not fit).  A
flexible result gives :class:`ArmFlexibleComputedTorque` (the motor-side
CTC with the spring torque of the identified link model) only when it holds
a model-error set (stiffness +-30 %, damping x0.5 .. x2, and the robots its
log allows beside the fit) at least as well as the rigid-equivalent CTC
(:data:`FLEXIBLE_CHECK_SCENARIOS`, :func:`check_scenarios`); its design is
the robust one, the PUMA path's (:func:`ctc.flexible.select_robust_design`):
of the default gains and the faster motor loops of
:data:`ctc.flexible.ROBUST_DESIGNS`, the one with the smallest worst case
over that set -- to a pulse: of the designs within
:data:`ctc.flexible.DESIGN_TIE_PULSES` of it (and no worse than the
rigid-equivalent CTC), the one with the smallest current step for one
pulse (:func:`ctc.flexible.tied_choice`).

The controller follows the sampled-controller protocol (``reset()``,
``__call__(k, t, q_meas, e_pulses) -> (n,) A``), so
:func:`plant.simulate_closed_loop` (``plant=`` the arm) and the independent
simulator of ``benchmarks/`` run it; :class:`ctc.PController` is the rig's
P loop for any number of joints.  Both controllers also exist compiled, as
laws of the arm's logged-run driver (``logged_controller``:
:func:`arm_ctc_law`, :func:`arm_flexible_ctc_law`, generated per robot with
its own copy of the driver): :func:`plant.simulation.arm.simulate_arm` runs
them in the loop of many robots at once with the Python controller's pulses,
sample for sample -- the flexible result's model-error check runs each
design's five robots so.
"""
from __future__ import annotations


import math
import threading
from typing import NamedTuple

import numba
import numpy as np

from plant.logs.rig import RigConstants, rig_constants
from plant.robot.model import friction_torque, friction_torques
from plant.simulation.controllers import LoggedController
from plant.simulation.core import cell_centre, cell_centres

from .contract import IdentifiedModel
from .design import gains_for
from .guard import FollowingErrorLimit, lost_bound

__all__ = ["ArmComputedTorque", "ArmFlexibleComputedTorque", "ArmCTCParameters", "arm_ctc_law",
           "ArmFlexibleCTCParameters", "arm_flexible_ctc_law", "log_envelope",
           "FLEXIBLE_CHECK_SCENARIOS", "FLEXIBLE_CHECK_S", "GOAL_PULSES", "check_scenarios"]


def log_envelope(log) -> np.ndarray:
    """The watchdog's envelope of a log: twice its largest P-control error per joint (pulses), (n,).

    The limit of :class:`ctc.guard.FollowingErrorLimit`
    (:func:`ctc.guard.lost_bound`): the P loop the log was recorded with
    held the arm within its largest errors; a computed torque whose error
    passes twice them has lost the arm (a transient after a change the
    model does not describe passes the P law's own errors too, and
    recovers).  At least :data:`ctc.guard.MIN_LIMIT_PULSES` per joint.

    Parameters
    ----------
    log : plant.logs.arm_log.ArmLog

    Returns
    -------
    ndarray, shape (n,)
    """
    return FollowingErrorLimit(log).limit_pulses


class _CallBuffer:
    """A casadi function's call buffer over fixed numpy arrays (``Function.buffer``).

    ``arrays`` is ``(input_0, ..., input_k, (output_0, ...))``: write the inputs
    in place, call :meth:`evaluate`, read the outputs.  The same evaluation as
    calling the function (its virtual machine, the same numbers) without the
    conversion of every argument and result to casadi's ``DM``: a microsecond
    or so a call instead of 50-100 (plus the evaluation itself).
    """

    def __init__(self, fn):
        self._buffer, self.evaluate = fn.buffer()
        ins = [np.zeros(fn.nnz_in(k)) for k in range(fn.n_in())]
        outs = tuple(np.zeros(fn.nnz_out(k)) for k in range(fn.n_out()))
        for k, a in enumerate(ins):
            self._buffer.set_arg(k, memoryview(a))
        for k, a in enumerate(outs):
            self._buffer.set_res(k, memoryview(a))
        self.arrays = (*ins, outs)


#: The compiled link-model sample of :class:`ArmFlexibleComputedTorque`, per robot
#: (keyed by the plant's generated module; cached on disk with it).
_LINK_SAMPLES = {}


@numba.njit(cache=True, nogil=True, error_model="numpy")
def solve_dense(a, b):
    """``numpy.linalg.solve`` of a square (n, n) system, compiled once and cached on disk
    (the robots' link-sample kernels link it instead of compiling LAPACK's binding again)."""
    return np.linalg.solve(a, b)


def link_rates(s, th, v, a, q, w, K, D, hb, beta):
    """Link accelerations and spring torques at ``s`` seconds into the sample (a kernel's template).

    Copied into a robot's generated module (:func:`_link_sample_kernel`),
    where ``dynamics`` is the robot's dynamics kernel.
    """
    n = q.shape[0]
    m = th + v * s + 0.5 * a * s * s
    d = m - q
    ts = K * (d - np.minimum(np.maximum(d, -hb), hb)) + D * (v + a * s - w)
    sc = np.empty(2 * n)
    for j in range(n):
        sc[2 * j] = np.sin(q[j])
        sc[2 * j + 1] = np.cos(q[j])
    lower, nvec = dynamics(sc, w, beta)  # noqa: F821 - the generated module's
    M = np.zeros((n, n))
    k = 0
    for j in range(n):
        for i in range(j + 1):
            M[j, i] = lower[k]
            M[i, j] = lower[k]
            k += 1
    return solve_dense(M + 0.0, ts - nvec), ts


def link_sample(th, v, a, q, w, K, D, hb, beta, h, n_steps):
    """The link model over one sample (a kernel's template; see :func:`_link_sample_kernel`)."""
    mean_ts = np.zeros(q.shape[0])
    for i in range(n_steps):
        s0 = i * h
        k1, t1 = link_rates(s0, th, v, a, q, w, K, D, hb, beta)
        k2, t2 = link_rates(s0 + 0.5 * h, th, v, a, q + 0.5 * h * w, w + 0.5 * h * k1, K, D, hb,
                            beta)
        k3, t3 = link_rates(s0 + 0.5 * h, th, v, a, q + 0.5 * h * (w + 0.5 * h * k1),
                            w + 0.5 * h * k2, K, D, hb, beta)
        k4, t4 = link_rates(s0 + h, th, v, a, q + h * (w + 0.5 * h * k2), w + h * k3, K, D, hb,
                            beta)
        mean_ts += (t1 + 2 * t2 + 2 * t3 + t4) / (6.0 * n_steps)
        q = q + h * w + h * h * (k1 + k2 + k3) / 6.0
        w = w + h * (k1 + 2 * k2 + 2 * k3 + k4) / 6.0
    return q, w, mean_ts


def _link_sample_kernel(plant):
    """The flexible CTC's link model over one sample, compiled for a robot's dynamics kernel.

    ``sample(th, v, a, q, w, K, D, half_backlash, beta, h, n_steps) -> (q, w, mean_ts)``:
    ``n_steps`` RK4 steps of ``h`` seconds of ``D_link(q) q'' + n_link(q, q') = tau_s`` with
    the motor on its commanded path ``th + v s + a s^2 / 2`` and the spring torque
    ``tau_s = K dz(th - q, b) + D (th' - q')``, and the spring torque's RK4 mean over the
    sample -- the same operations in the same order as the Python law it replaces (the
    same numbers), at a few microseconds a step instead of a few hundred.  Copies of
    :func:`link_rates` and :func:`link_sample` in a module generated for the robot
    (:mod:`plant.simulation.generated`), with its dynamics kernel
    (:attr:`plant.simulation.arm.ArmPlant.dynamics_kernel`), cached on disk by numba.  A
    non-finite inertia matrix or spring torque raises ``numpy.linalg.LinAlgError``
    (numba's ``solve`` checks).
    """
    from plant.simulation.generated import load, module_text

    robot = plant.kernels.__name__
    fn = _LINK_SAMPLES.get(robot)
    if fn is not None:
        return fn
    text = module_text(f"The flexible-joint CTC's link model of {plant.name}: generated by ctc.arm.",
                       imports=["", f"from {robot} import dynamics"],
                       copies=[(link_rates, "_inline"), (link_sample, "_kernel")])
    fn = _LINK_SAMPLES[robot] = load("link", text).link_sample
    return fn


class ArmCTCParameters(NamedTuple):
    """Parameters of the arm's compiled computed-torque law (:func:`arm_ctc_law`), by name.

    Attributes
    ----------
    rig : plant.logs.rig.RigConstants
        The controller's rig constants (its sample time, encoders, ``k Kt``,
        friction feed-forward and current limit; n joints).
    beta : ndarray, shape (r,)
        Base parameters of the controller's model.
    beta_feedback : ndarray, shape (r,)
        Base parameters of the inertia matrix that multiplies the feedback
        when ``held_feedback`` (else unused).
    held_feedback : bool
        The feedback held at ``beta_feedback``'s inertia matrix (module docstring).
    reference : ndarray, shape (n_samples, 5 n)
        Per sample ``k``: ``q_d, qd_d`` at ``t_k = k Ts`` and ``q, qd, qdd``
        at ``t_k + Ts / 2`` (rad, rad/s, rad/s^2), n columns each.
    kp, kv, ki : ndarray, shape (n,)
        Outer-loop gains (s^-2, s^-1, s^-3).
    lq, lw : ndarray, shape (n,)
        Current-observer gains on the position residual.
    integral : bool
        Integral action on (some ``ki`` is not 0).
    watchdog : bool
        The following-error limit is armed.
    limit_pulses : ndarray, shape (n,)
        Its limit per joint (pulses).
    hard_factor, dwell_s, window_s : float
        Its rule (:class:`ctc.guard.FollowingErrorLimit`).
    p_gain : ndarray, shape (n,)
        The P law it hands the arm to (A per pulse) ...
    p_limit : float
        ... and that law's current limit (A).
    """

    rig: RigConstants
    beta: np.ndarray
    beta_feedback: np.ndarray
    held_feedback: bool
    reference: np.ndarray
    kp: np.ndarray
    kv: np.ndarray
    ki: np.ndarray
    lq: np.ndarray
    lw: np.ndarray
    integral: bool
    watchdog: bool
    limit_pulses: np.ndarray
    hard_factor: float
    dwell_s: float
    window_s: float
    p_gain: np.ndarray
    p_limit: float


def watchdog_current(lp, k, E, CS, U, j, o):
    """The following-error watchdog of a compiled CTC law (a kernel's template): True when the
    limit has tripped -- lane ``j``'s currents are then the P law's, written to ``U[:, j]``.

    ``lp`` has the watchdog's fields of :class:`ArmCTCParameters`; ``CS[o, j]`` is the trip
    flag and the rows after it the ring of the last times beyond the limit
    (:meth:`ctc.guard.FollowingErrorLimit.trips`, the same comparisons).
    """
    if not lp.watchdog:
        return False
    n = U.shape[0]
    ts = lp.rig.sample_time_s
    t = k * ts
    tripped = CS[o, j] != 0.0
    if not tripped:
        over = False
        hard = False
        for m in range(n):
            ae = abs(E[m, j])
            over = over or ae > lp.limit_pulses[m]
            hard = hard or ae > lp.hard_factor * lp.limit_pulses[m]
        if hard:
            tripped = True
        elif over:
            w = CS.shape[0] - (o + 1)
            CS[o + 1 + k % w, j] = t
            count = 0
            for s in range(w):
                if CS[o + 1 + s, j] > t - lp.window_s + 0.5 * ts:
                    count += 1
            tripped = count * ts > lp.dwell_s + 1e-12
        if tripped:
            CS[o, j] = 1.0
    if tripped:
        for m in range(n):
            U[m, j] = min(max(lp.p_gain[m] * E[m, j], -lp.p_limit), lp.p_limit)
    return tripped


def observer_prediction(rc, Y, CS, j, m, n):
    """Joint ``m`` of lane ``j``: the measured angle (the centre of its count's cell) and the
    current observer's prediction ``(y, q_p, w_p)`` from the state in ``CS`` (rows ``q_hat``,
    ``qd_hat``, previous acceleration; a kernel's template: the compiled laws' common step)."""
    ts = rc.sample_time_s
    spr = rc.pulses_per_rad[m]
    y = cell_centre(float(round(Y[m, j] * spr))) / spr
    q_p = CS[m, j] + ts * CS[n + m, j] + 0.5 * ts * ts * CS[2 * n + m, j]
    w_p = CS[n + m, j] + ts * CS[2 * n + m, j]
    return y, q_p, w_p


def outer_loop(p, k, m, n, q_h, w_h, z):
    """The outer loop's acceleration of joint ``m`` at sample ``k``: the reference's at
    mid-sample plus the PD (and integral, error sum ``z``) terms on the estimate ``q_h, w_h``
    (``p`` an :class:`ArmCTCParameters`; a kernel's template)."""
    ref = p.reference
    return (ref[k, 4 * n + m] + p.kv[m] * (ref[k, n + m] - w_h) + p.kp[m] * (ref[k, m] - q_h)
            + p.ki[m] * z)


def limit_and_integrate(p, k, cur, CS, j, n):
    """Whether a commanded current ``cur`` (n,) exceeds the drive's limit; the error sums of
    the joints within it integrate ``q_ref - q_hat`` over the sample (conditional
    integration: frozen where the limit cuts); ``p`` an :class:`ArmCTCParameters`, ``CS``
    the law's states (estimates in rows 0..n-1, sums in 3n..4n-1; a kernel's template)."""
    rc = p.rig
    saturated = False
    for m in range(n):
        if abs(cur[m]) > rc.current_limit:
            saturated = True
        elif p.integral:
            CS[3 * n + m, j] += rc.sample_time_s * (p.reference[k, m] - CS[m, j])
    return saturated


def arm_ctc_law(lp, c, k, Y, E, CS, U, j):
    """The arm's computed torque as a compiled law of the logged-run driver (a kernel's template).

    Copied into a module generated per robot (by :meth:`ArmComputedTorque.logged_controller`),
    where ``dynamics`` is the controller's robot's dynamics kernel; the
    law of ``ArmComputedTorque.__call__`` (watchdog, observer, outer
    loop at mid-sample, model, friction feed-forward, current limit with
    the observer driven by the saturated current, conditional integration),
    operation for operation.  ``lp`` is :class:`ArmCTCParameters`; ``CS``
    ((4 n + 1 + w), lanes) holds per lane the observer ``q_hat``, ``qd_hat``,
    the previous acceleration, the error sums, the watchdog's trip flag and
    its ring of the last ``w`` times beyond the limit (s).  Writes lane
    ``j``'s currents to ``U[:, j]`` (A) (see :mod:`plant.simulation.controllers`).

    Parameters
    ----------
    lp : ArmCTCParameters
        The controller's model (and, with ``held_feedback``, the feedback
        model), reference table, gains and watchdog.
    c : plant.logs.rig.RigConstants
        Rig layout of the simulation (unused: the controller's own is ``lp.rig``).
    k : int
        Sample index from the start of the run (row of ``lp.reference``).
    Y : ndarray, shape (n, lanes)
        Measured joint angles (rad): encoder counts over pulses per radian.
    E : ndarray, shape (n, lanes)
        Pulse errors (the watchdog's and the P fallback's input).
    CS : ndarray, shape (4 n + 1 + w, lanes)
        Controller states (updated in place).
    U : ndarray, shape (n, lanes)
        Currents (A): column ``j`` is written.
    j : int
        Lane.
    """
    n = U.shape[0]
    rc = lp.rig
    if watchdog_current(lp, k, E, CS, U, j, 4 * n):
        return
    ref = lp.reference
    sc = np.empty(2 * n)
    v = np.empty(n)
    a = np.empty(n)
    for m in range(n):
        y, q_p, w_p = observer_prediction(rc, Y, CS, j, m, n)
        r = y - q_p
        q_h = q_p + lp.lq[m] * r
        CS[m, j] = q_h
        CS[n + m, j] = w_p + lp.lw[m] * r
        a[m] = outer_loop(lp, k, m, n, q_h, CS[n + m, j], CS[3 * n + m, j])
        q_m = q_h + (ref[k, 2 * n + m] - ref[k, m])
        sc[2 * m] = math.sin(q_m)
        sc[2 * m + 1] = math.cos(q_m)
        v[m] = ref[k, 3 * n + m]
    lower, nvec = dynamics(sc, v, lp.beta)  # noqa: F821 - the generated module's
    D = np.empty((n, n))
    held = lp.held_feedback
    if held:  # the feedback model's inertia matrix beside the model's
        lower_f, _ = dynamics(sc, v, lp.beta_feedback)  # noqa: F821 - the generated module's
        Df = np.empty((n, n))
    else:
        lower_f = lower
        Df = D
    o = 0
    for m in range(n):
        for i in range(m + 1):
            D[m, i] = lower[o] + 0.0
            D[i, m] = lower[o] + 0.0
            if held:
                Df[m, i] = lower_f[o] + 0.0
                Df[i, m] = lower_f[o] + 0.0
            o += 1
    tf = np.empty(n)
    cur = np.empty(n)
    ffw = np.empty(n)  # held: the model's D_hat qdd_d
    for m in range(n):
        tf[m] = friction_torque(v[m], rc.viscous[m], rc.coulomb_pos[m], rc.coulomb_neg[m],
                                rc.ramp_speed[m])
        tau = 0.0
        if held:  # the model's feed-forward, the feedback at the feedback model's inertia
            tau_fb = 0.0
            for i in range(n):
                tau += D[m, i] * ref[k, 4 * n + i]
                tau_fb += Df[m, i] * (a[i] - ref[k, 4 * n + i])
            ffw[m] = tau
            tau = tau + tau_fb
        else:
            for i in range(n):
                tau += D[m, i] * a[i]
        cur[m] = (tau + nvec[m] - tf[m]) / rc.torque_per_amp[m]
    # saturated: the observer sees the acceleration the saturated current gives the model
    if limit_and_integrate(lp, k, cur, CS, j, n):
        lim = rc.current_limit
        rhs = np.empty(n)
        for m in range(n):
            cur[m] = min(max(cur[m], -lim), lim)
            rhs[m] = cur[m] * rc.torque_per_amp[m] - nvec[m] + tf[m]
        if held:  # ... as the feedback model's: qdd_d + D_f^-1 (tau - D_hat qdd_d - n + tf)
            for m in range(n):
                rhs[m] = rhs[m] - ffw[m]
        try:
            a = solve_dense(Df, rhs)
        except Exception:  # non-finite (numpy's solve gives NaN there) or singular: this lane fails
            a = np.full(n, np.nan)
        if held:
            for m in range(n):
                a[m] += ref[k, 4 * n + m]
    for m in range(n):
        CS[2 * n + m, j] = a[m]
        U[m, j] = cur[m]


class ArmFlexibleCTCParameters(NamedTuple):
    """Parameters of the arm's compiled flexible-joint CTC law (:func:`arm_flexible_ctc_law`).

    Attributes
    ----------
    ctc : ArmCTCParameters
        The motor loop's: rig, reference, gains, observer, watchdog (its
        ``beta`` the rigid-equivalent model's).
    stiffness, damping, motor_inertia, half_backlash : ndarray, shape (n,)
        The joints' springs (N m/rad), dampers (N m s/rad), reflected motor
        inertias ``Jm k^2`` (kg m^2) and half backlash gaps (rad).
    link_beta : ndarray, shape (r,)
        Base parameters of the link model (beta minus the motor inertias).
    link_gq, link_gw : ndarray, shape (n,)
        The link estimate's gains on the motor's position residual.
    link_substeps : int
        RK4 steps of the link model per sample.
    """

    ctc: ArmCTCParameters
    stiffness: np.ndarray
    damping: np.ndarray
    motor_inertia: np.ndarray
    half_backlash: np.ndarray
    link_beta: np.ndarray
    link_gq: np.ndarray
    link_gw: np.ndarray
    link_substeps: int


def arm_flexible_ctc_law(lp, c, k, Y, E, CS, U, j):
    """The arm's flexible-joint computed torque as a compiled law of the driver (a template).

    Copied into the module generated per robot (by
    :meth:`ArmFlexibleComputedTorque.logged_controller`) with its link model over a sample (``link_sample``);
    the law of ``ArmFlexibleComputedTorque.__call__`` (watchdog, motor
    observer and link estimate, outer loop, the link model over the sample
    with the motor on its commanded path, ``Jm k^2 a + mean tau_s - tau_f``,
    the current limit, conditional integration, zero current and a restart
    of the link estimate when the link model fails), operation for
    operation.  ``CS`` ((6 n + 2 + w), lanes): per lane the motor observer
    ``th_hat``, ``thd_hat``, the previous acceleration, the error sums, the
    link estimate ``q_l``, ``qd_l``, the restart flag, the watchdog's trip flag and
    ring.

    Parameters
    ----------
    lp : ArmFlexibleCTCParameters
        The controller's models, reference, gains and watchdog.
    c : plant.logs.rig.RigConstants
        Rig layout of the simulation (unused: the controller's own is ``lp.ctc.rig``).
    k : int
        Sample index from the start of the run.
    Y : ndarray, shape (n, lanes)
        Measured motor angles, joint side (rad).
    E : ndarray, shape (n, lanes)
        Pulse errors.
    CS : ndarray, shape (6 n + 2 + w, lanes)
        Controller states (updated in place).
    U : ndarray, shape (n, lanes)
        Currents (A): column ``j`` is written.
    j : int
        Lane.
    """
    n = U.shape[0]
    p = lp.ctc
    rc = p.rig
    ts = rc.sample_time_s
    if watchdog_current(p, k, E, CS, U, j, 6 * n + 1):
        return
    ref = p.reference
    th = np.empty(n)
    v = np.empty(n)
    a = np.empty(n)
    ql = np.empty(n)
    wl = np.empty(n)
    first = CS[6 * n, j] != 0.0
    for m in range(n):
        y, q_p, w_p = observer_prediction(rc, Y, CS, j, m, n)
        if first:  # springs relaxed: the link where the motor is
            th[m] = y
            v[m] = ref[k, n + m]
            ql[m] = y
            wl[m] = ref[k, n + m]
        else:
            r = y - q_p
            th[m] = q_p + p.lq[m] * r
            v[m] = w_p + p.lw[m] * r
            ql[m] = CS[4 * n + m, j] + lp.link_gq[m] * r
            wl[m] = CS[5 * n + m, j] + lp.link_gw[m] * r
        CS[m, j] = th[m]
        CS[n + m, j] = v[m]
        a[m] = outer_loop(p, k, m, n, th[m], v[m], CS[3 * n + m, j])
    CS[6 * n, j] = 0.0
    if first:  # the link estimate as the Python law keeps it while its model runs
        for m in range(n):
            CS[4 * n + m, j] = ql[m]
            CS[5 * n + m, j] = wl[m]
    ok = True
    try:
        q, w, mean_ts = link_sample(th, v, a, ql, wl, lp.stiffness, lp.damping,
                                    lp.half_backlash, lp.link_beta,
                                    ts / lp.link_substeps, lp.link_substeps)
    except Exception:  # a non-finite or singular link model
        ok = False
        q, w, mean_ts = ql, wl, np.full(n, np.nan)
    cur = np.empty(n)
    tf = np.empty(n)
    for m in range(n):
        tf[m] = friction_torque(ref[k, 3 * n + m], rc.viscous[m], rc.coulomb_pos[m],
                                rc.coulomb_neg[m], rc.ramp_speed[m])
        cur[m] = (lp.motor_inertia[m] * a[m] + mean_ts[m] - tf[m]) / rc.torque_per_amp[m]
        ok = ok and math.isfinite(cur[m])
    if not ok:
        # the link model diverged (a robot far from the model): never a NaN to the drive;
        # the link estimate restarts at the motor
        CS[6 * n, j] = 1.0
        for m in range(n):
            U[m, j] = 0.0
        return
    saturated = limit_and_integrate(p, k, cur, CS, j, n)  # CS[m, j] is th[m]
    lim = rc.current_limit
    for m in range(n):
        if saturated:
            cur[m] = min(max(cur[m], -lim), lim)
            a[m] = (cur[m] * rc.torque_per_amp[m] - mean_ts[m] + tf[m]) / lp.motor_inertia[m]
        CS[2 * n + m, j] = a[m]
        CS[4 * n + m, j] = q[m]
        CS[5 * n + m, j] = w[m]
        U[m, j] = cur[m]


#: The compiled computed-torque laws of :class:`ArmComputedTorque` and
#: :class:`ArmFlexibleComputedTorque`, per (controller's robot, simulated plant) generated
#: module pair (cached on disk with them); built under a lock (threads share the process).
_CTC_LAWS = {}
_CTC_LAWS_LOCK = threading.Lock()


def _ctc_law_module(plant, simulated=None):
    """The module generated for a robot's computed-torque laws in the logged-run driver.

    It holds the laws' kinds (``ArmCTCKind``, ``ArmFlexibleCTCKind``),
    copies of :func:`arm_ctc_law` and :func:`arm_flexible_ctc_law` with the
    robot's dynamics kernel, registered in
    :data:`plant.simulation.controllers.CONTROL_LAWS`, and a copy of the
    logged-run driver (:func:`plant.simulation.simulate.logged_run`)
    compiled with them: the laws' kinds live with the driver copy whose
    on-disk cache names them
    (:attr:`plant.simulation.controllers.LoggedController.driver`).  With
    ``simulated`` (the arm plant the laws will run in, when it is not the
    robot's own module: its two-mass plant, another robot) the module
    imports that plant's module too, so the driver copy's cache may name
    its kind (:func:`plant.simulation.simulate.for_kinds`).
    """
    robot = plant.kernels.__name__
    other = None if simulated is None else simulated.kernels.__name__
    if other == robot:
        other = None
    with _CTC_LAWS_LOCK:  # one thread generates and loads it, the others wait
        module = _CTC_LAWS.get((robot, other))
        if module is None:
            module = _CTC_LAWS[(robot, other)] = _build_ctc_law_module(plant, robot, other)
    return module


def _build_ctc_law_module(plant, robot, other):
    """Generate and load the module of :func:`_ctc_law_module` (robot and simulated plant given
    by their generated modules' names; ``other`` None: the robot's own)."""
    from plant.simulation.generated import load, module_text
    from plant.simulation.simulate import logged_run

    imports = ["", f"from {robot} import dynamics",
               "from plant.simulation.controllers import register_control_law"]
    if other is not None:
        imports.append(f"from {other} import ArmKind as SimulatedArmKind  # noqa: F401")
    text = module_text(
        f"The computed-torque laws of {plant.name} in the logged-run driver: generated by "
        "ctc.arm.",
        imports=imports,
        body=["class ArmCTCKind(NamedTuple):",
              "    \"\"\"This robot's computed-torque law kind (its type selects the law).\"\"\"",
              "", "    code: int = 3", "", "",
              "class ArmFlexibleCTCKind(NamedTuple):",
              "    \"\"\"This robot's flexible-joint computed-torque law kind.\"\"\"",
              "", "    code: int = 4", "", ""],
        copies=[(watchdog_current, "_inline"), (observer_prediction, "_inline"),
                (outer_loop, "_inline"), (limit_and_integrate, "_inline"),
                (arm_ctc_law, "_inline"),
                (link_rates, "_inline"), (link_sample, "_inline"),
                (arm_flexible_ctc_law, "_inline"), (logged_run, "_kernel")],
        tail=["register_control_law(ArmCTCKind, arm_ctc_law)",
              "register_control_law(ArmFlexibleCTCKind, arm_flexible_ctc_law)"])
    return load("ctclaw", text)


class ArmComputedTorque:
    """Computed-torque controller of a robot model's arm with identified base parameters.

    Parameters
    ----------
    plant : plant.simulation.arm.ArmPlant
        The robot (:func:`plant.simulation.arm.arm_plant`); its base parameters define beta.
    beta : array_like, shape (r,)
        Base parameters of the controller's model (identified).
    rig : plant.Rig
        The rig (sample time, gears, encoders, Kt, friction, current limit).
    trajectory : plant.Trajectory
        Reference of the n joints.
    gains : ctc.design.GainDesign, optional
        Ready-made gains (default: :func:`ctc.design.design_gains` for the rig).
    envelope : array_like, shape (n,), optional
        The safety watchdog (default none): pulses per joint beyond which
        (for more than 20 ms of the last 100 ms, or beyond twice them; the
        rule of :class:`ctc.guard.FollowingErrorLimit`) the controller no
        longer trusts its model and hands the arm to the
        rig's P law ``i = P e`` (its gains from ``rig``), for the rest of
        the run, with a :class:`ctc.guard.FollowingErrorWarning` (a
        ``RuntimeWarning``); ``tripped_at`` is the sample, ``fallback_t_s``
        its time (the :class:`ctc.guard.FollowingErrorLimit` is
        ``following_error``).
        :meth:`from_result` takes twice the log's largest P-control errors
        (:func:`log_envelope`): the P loop the log was recorded with is
        known to hold the arm within them, and a computed torque that
        tracks worse rests on a model that does not fit.
    **design
        Keywords of :func:`ctc.design.design_gains` (instead of ``gains``).

    Raises
    ------
    ValueError
        beta of the wrong size or not finite, a rig or trajectory with another
        joint count, a model whose D_hat is not positive definite at the
        reference's start, or an envelope that is not n positive numbers.
    """

    def __init__(self, plant, beta, rig, trajectory, *, gains=None, envelope=None, **design):
        from plant.simulation.arm import ArmPlant

        if not isinstance(plant, ArmPlant):
            raise ValueError(f"plant must be a plant.simulation.arm.ArmPlant, got {type(plant).__name__}")
        self.plant = plant
        self.n = plant.n_joints
        self.beta = plant.lane_parameters(beta)[:, 0].copy()
        c = rig_constants(rig, q0=np.zeros(self.n), qd0=np.zeros(self.n))
        if len(c.pulses_per_rad) != self.n:
            raise ValueError(f"the rig has {len(c.pulses_per_rad)} joints, the robot {self.n}")
        self.c = c
        self.trajectory = trajectory
        self.gains = gains_for(rig, gains, **design)
        self._integral = bool(np.any(self.gains.Ki))  # the error sum only where it acts
        if self.gains.estimator != "observer":
            raise ValueError("ArmComputedTorque uses the observer estimator")
        self.ts = c.sample_time_s
        self.spr = np.asarray(c.pulses_per_rad)
        self.torque_per_amp = np.asarray(c.torque_per_amp)
        self.limit = c.current_limit
        # the drive friction's constants per joint (joint side), for the feed-forward
        self._friction = tuple(np.asarray(v, dtype=float) for v in (
            c.viscous, c.coulomb_pos, c.coulomb_neg, c.ramp_speed))
        self._dyn = plant.dynamics_function
        self._buffer = None  # the casadi function's call buffer (built on first use)
        self._il = np.tril_indices(self.n)
        q, _, _ = trajectory.evaluate(np.zeros(1))
        if np.asarray(q).shape != (1, self.n):
            raise ValueError(f"the trajectory has {np.asarray(q).shape[1]} joints, the robot {self.n}")
        D, _ = self.terms(q[0], np.zeros(self.n))
        if np.any(np.linalg.eigvalsh(D) <= 0):
            raise ValueError("the controller's D_hat(q) is not positive definite at the reference's start")
        self._rig = rig
        self.feedback_beta = None  # the feedback at the model's own inertia (set_beta)
        self.envelope = envelope
        self.reset()

    @property
    def envelope(self):
        """The following-error limit (n,) pulses, or None (no watchdog)."""
        return None if self.following_error is None else self.following_error.limit_pulses

    @envelope.setter
    def envelope(self, envelope):
        if envelope is not None:
            envelope = np.asarray(envelope, dtype=float).reshape(-1)
            if envelope.shape != (self.n,) or not np.all(envelope > 0):
                raise ValueError(f"envelope must be {self.n} positive numbers (pulses), got "
                                 f"{envelope!r}")
        self.following_error = None if envelope is None else FollowingErrorLimit(self._rig, envelope)

    @property
    def rig(self):
        """The rig the controller was built for (:class:`plant.Rig`: sample time, gears,
        encoders, ``Kt``, friction, current limit, start state)."""
        return self._rig

    @property
    def tripped_at(self):
        """The sample at which the watchdog handed the arm to the P law (None: never)."""
        return None if self.fallback_t_s is None else int(round(self.fallback_t_s / self.ts))

    @classmethod
    def from_result(cls, result, log, **design):
        """The controller of an identification result on its log's rig and reference.

        Parameters
        ----------
        result : identification.arm.ArmIdentificationResult
        log : plant.logs.arm_log.ArmLog
        **design
            As the constructor (``gains=`` or :func:`ctc.design.design_gains` keywords);
            for a flexible result also ``max_current_per_pulse`` (None or a fraction
            of full scale > 0: a faster candidate design is checked only when its
            one-pulse current step, :func:`ctc.protocol.current_per_pulse`, stays
            within it; see :func:`ctc.flexible.controller_from_result`).

        Returns
        -------
        ArmComputedTorque
            With the safety watchdog at twice the log's largest P-control
            errors (``envelope``, :func:`log_envelope`; pass ``envelope=None``
            for none).

        Raises
        ------
        ValueError
            As the constructor, or a result that is not a success.

        Notes
        -----
        A flexible result (``result["model"] == "flexible"``) gives an
        :class:`ArmFlexibleComputedTorque`, checked first (the robust design
        of issue 21, item 3, as :func:`ctc.flexible.select_robust_design`
        for the PUMA path): the flexible-joint CTC with the default gains
        and, unless ``design`` fixes the design (a key of
        :data:`ctc.flexible.DESIGN_KEYS`: ``gains``, ``bandwidth_hz``,
        ``link_damping``, ...), with each faster motor
        loop of :data:`ctc.flexible.ROBUST_DESIGNS`
        (:func:`ctc.flexible.robust_design_gains`; up to the first that
        holds +-1 pulse, :data:`GOAL_PULSES`, on every scenario), and the
        rigid-equivalent CTC (this class with the rigid-equivalent beta) run on the
        identified two-mass arm along the first :data:`FLEXIBLE_CHECK_S`
        seconds of the log's reference (:func:`plant.simulate_closed_loop`)
        over the model-error set :data:`FLEXIBLE_CHECK_SCENARIOS` (stiffness
        +-30 %, damping x0.5 .. x2) and the robots the log allows beside the
        fit (:func:`check_scenarios`: a joint whose spring or motor its log
        leaves open, at the ends of its ranges; the returned controller then
        warns with its worst case over them).  The flexible design with the smallest
        worst error after 0.1 s (minimax over the scenarios that at least
        one controller holds) is returned when it is no
        worse than the rigid-equivalent CTC's -- or, of the designs within
        :data:`ctc.flexible.DESIGN_TIE_PULSES` of it and no worse than the
        rigid-equivalent CTC, the one with the smallest current step for one
        pulse (:func:`ctc.flexible.tied_choice`, as on the PUMA 560 path; a
        design that holds the goal, ``GOAL_PULSES``, over the set can give
        way to a slower one that holds a pulse more) -- else the rigid-equivalent
        CTC with a ``RuntimeWarning``.  A run that fails, or goes beyond
        the following-error limit on some joint
        (:func:`ctc.guard.lost_bound`: it has lost the arm), counts as an
        infinite error: a scenario no controller holds does not count, and
        when both lose a scenario that counts, the first flexible design
        that holds the nominal robot is returned, with a
        ``RuntimeWarning``, if the rigid-equivalent CTC does not hold it.
        A design stops being simulated as
        soon as one scenario's error exceeds, by more than that resolution,
        the largest error of a controller that ran them all (it can no
        longer be the minimax one nor tied with it).
        The returned controller's ``selection`` holds the errors: per
        scenario ``flexible`` (of the chosen flexible design, ``design``)
        and ``rigid_equivalent``, ``designs`` (each flexible design's
        ``name``, ``errors``, ``worst``; None for a scenario not run),
        ``counted``, ``worst_flexible``, ``worst_rigid_equivalent``,
        ``check_s``, ``held_back`` (the faster designs the current cap kept
        out, each with its ``current_per_pulse_A``),
        ``current_per_pulse_limit_A`` and ``tied`` (when designs were tied,
        each one's ``name``, ``worst`` and ``current_per_pulse_A``).  Safety first: a flexible design that does not
        tolerate the identified robot's likely errors is used only when the
        rigid-equivalent CTC loses the nominal robot and the design holds it
        (with a warning).
        Measured on the compliant draws of ``benchmarks/bench_arms.py
        --compliant`` (independent simulator): the faster designs took a
        PUMA 560 joints 1-3 arm with backlash from 5 / 3 / 4 pulses (the
        rigid-equivalent CTC, the default design failing the softer
        gearbox) to 1 / 1 / 1, and a planar arm from 3 / 3 to 1 / 1.
        """
        if not result.get("success", False):
            raise ValueError(f"the identification did not succeed: {result.get('message')}")
        m = IdentifiedModel.from_result(result, n_joints=result["plant"].n_joints)
        design.setdefault("envelope", log_envelope(log))
        from .flexible import current_step_limit

        cap = design.pop("max_current_per_pulse", None)  # the robust design's candidates only
        current_step_limit(result["rig"], cap)  # a bad cap is refused on every kind of result
        if cls is ArmComputedTorque and m.flexible:
            # a flexible result: the motor-side CTC with the spring torque of its link model,
            # unless it tracks the identified robot worse than the rigid-equivalent CTC
            return _checked_flexible(result, log, max_current_per_pulse=cap, **design)
        # the result's rig: the log's, with the friction the identification found
        return cls(result["plant"], m.f, result["rig"], log.trajectory, **design)

    def set_beta(self, beta, *, feedback_beta=None) -> np.ndarray:
        """Switch the controller's model to the base parameters ``beta`` (the observer keeps its state).

        Parameters
        ----------
        beta : array_like, shape (r,)
        feedback_beta : array_like, shape (r,), optional
            Hold the feedback at this model's inertia matrix: ``beta`` then
            gives the feed-forward ``D_hat qdd_d + n_hat`` only (held
            feedback, module docstring).  Default: none, the computed
            torque ``D_hat a + n_hat`` of ``beta`` (a call without it ends a
            held feedback).

        Returns
        -------
        ndarray, shape (r,)
            The parameters now in use.

        Raises
        ------
        ValueError
            beta or feedback_beta of the wrong size or not finite, or a
            feedback model whose inertia matrix is not positive definite at
            the reference's start.
        """
        beta = self.plant.lane_parameters(beta)[:, 0].copy()
        if feedback_beta is not None:
            feedback_beta = self.plant.lane_parameters(feedback_beta)[:, 0].copy()
            q, _, _ = self.trajectory.evaluate(np.zeros(1))
            if np.any(np.linalg.eigvalsh(self.inertia_matrix(q[0], feedback_beta)) <= 0):
                raise ValueError("the feedback model's inertia matrix is not positive definite "
                                 "at the reference's start")
        self.beta, self.feedback_beta = beta, feedback_beta
        return self.beta

    def inertia_matrix(self, q, beta=None) -> np.ndarray:
        """The inertia matrix ``D(q)`` (n, n) kg m^2 of the controller's model, or of ``beta``.

        Parameters
        ----------
        q : array_like, shape (n,)
            Joint angles (rad).
        beta : array_like, shape (r,), optional
            Base parameters (default: the model in use).

        Returns
        -------
        ndarray, shape (n, n)
        """
        return self._evaluate(q, np.zeros(self.n), self.beta if beta is None else beta)[0]

    def terms(self, q, qd):
        """``D_hat(q)`` (n, n) and ``n_hat(q, qd)`` (n,) of the controller's model.

        Parameters
        ----------
        q, qd : array_like, shape (n,)
            Joint angles (rad) and rates (rad/s).

        Returns
        -------
        (ndarray, ndarray)
            Inertia matrix (kg m^2) and Coriolis/centrifugal plus gravity torques (N m).
        """
        return self._evaluate(q, qd, self.beta)

    def _evaluate(self, q, qd, beta):
        """``D(q)`` and ``n(q, qd)`` of the base parameters ``beta`` (the casadi function's call
        buffer)."""
        if self._buffer is None:
            self._buffer = _CallBuffer(self._dyn)
        sc, qd_in, beta_in, (lower, nvec) = self._buffer.arrays
        q = np.asarray(q, dtype=float)
        sc[0::2] = np.sin(q)
        sc[1::2] = np.cos(q)
        qd_in[:] = qd
        beta_in[:] = beta
        self._buffer.evaluate()
        return self._symmetric(lower), nvec.copy()

    def __getstate__(self):
        # the call buffer points into its own arrays: a copy (copy.deepcopy) builds its own
        state = dict(self.__dict__)
        state["_buffer"] = None
        return state

    def _measurement(self, q_meas) -> np.ndarray:
        """The joint angles (n,) rad the encoders say: the centre of each count's cell
        (:func:`plant.simulation.core.cell_centres`)."""
        return cell_centres(np.rint(np.asarray(q_meas, dtype=float) * self.spr)) / self.spr

    def _reference(self, t):
        """The reference at ``t`` and ``t + Ts/2``: ``q_d, qd_d`` at ``t`` and ``q_m, qd_m,
        qdd_m`` at mid-sample, each (n,)."""
        q, qd, qdd = self.trajectory.evaluate(np.array([t, t + 0.5 * self.ts]))
        return q[0], qd[0], q[1], qd[1], qdd[1]

    def _friction_torque(self, qd) -> np.ndarray:
        """The drive friction (n,) N m at joint rates ``qd``
        (:func:`plant.robot.model.friction_torques`)."""
        return friction_torques(qd, *self._friction)

    def _symmetric(self, lower):
        """The symmetric (n, n) matrix of a lower triangle given row by row (``+ 0.0`` turns a
        -0.0 into 0.0, as adding the two triangles did)."""
        il = self._il
        D = np.zeros((self.n, self.n))
        D[il] = lower
        D[il[1], il[0]] = lower
        return D + 0.0

    def reset(self):
        """Observer at the reference's start (the robot starts on it), no previous command;
        the watchdog re-armed."""
        q, qd, _ = self.trajectory.evaluate(np.zeros(1))
        self.x = np.vstack([q[0], qd[0]])  # rows: q_hat, qd_hat
        self.a_prev = np.zeros(self.n)
        self.z = np.zeros(self.n)  # error sum of the integral action (rad s)
        self.fallback_t_s = None
        self._following_above = None  # the samples beyond the limit (ctc.guard)

    def __call__(self, k, t, q_meas, e_pulses):
        """Motor currents (n,) A for sample ``k`` at time ``t`` (sampled-controller protocol).

        The computed torque, unless the watchdog has tripped (``envelope``):
        then the rig's P law ``clip(P e, -I_fs, I_fs)``.
        """
        if self.following_error is not None:
            i = self.following_error.hold(self, t, e_pulses)
            if i is not None:
                return i
        return self._law(k, t, q_meas, e_pulses)

    def _law(self, k, t, q_meas, e_pulses):
        """The computed-torque law of one sample (currents (n,) A)."""
        ts = self.ts
        y = self._measurement(q_meas)
        # current estimator: predict with the applied acceleration, correct with y
        q_p = self.x[0] + ts * self.x[1] + 0.5 * ts * ts * self.a_prev
        w_p = self.x[1] + ts * self.a_prev
        L = self.gains.observer_gain
        r = y - q_p
        self.x = np.vstack([q_p + L[:, 0] * r, w_p + L[:, 1] * r])
        q_d, qd_d, q_m, qd_m, qdd_m = self._reference(t)
        a = (qdd_m + self.gains.Kv * (qd_d - self.x[1]) + self.gains.Kp * (q_d - self.x[0])
             + self.gains.Ki * self.z)
        q_mid = self.x[0] + (q_m - q_d)
        D, nv = self.terms(q_mid, qd_m)
        tf = self._friction_torque(qd_m)
        if self.feedback_beta is None:
            tau = D @ a + nv - tf
        else:  # held feedback: the model's feed-forward, the feedback model's inertia
            Df = self.inertia_matrix(q_mid, self.feedback_beta)
            ffw = D @ qdd_m
            tau = (ffw + Df @ (a - qdd_m)) + nv - tf
        i = tau / self.torque_per_amp
        self._integrate(q_d, self.x[0], i)
        if np.any(np.abs(i) > self.limit):  # saturated: the observer sees what the drive gives
            i = np.clip(i, -self.limit, self.limit)
            if self.feedback_beta is None:
                a = np.linalg.solve(D, i * self.torque_per_amp - nv + tf)
            else:  # ... as the feedback model's
                a = np.linalg.solve(Df, i * self.torque_per_amp - nv + tf - ffw) + qdd_m
        self.a_prev = a
        return i

    def logged_controller(self, n_samples, plant=None) -> LoggedController:
        """This controller as a compiled law of the logged-run driver, for runs of ``n_samples``.

        The law of ``__call__`` compiled per robot (:func:`arm_ctc_law`):
        :func:`plant.simulation.arm.simulate_arm` (``controller=``) runs it in
        the loop of every candidate robot at once, e.g. the tracking of this
        model on a set of robots it may meet.  Each lane starts as
        :meth:`reset` leaves the controller (observer on the reference's
        start, the watchdog re-armed), with the model (and held feedback),
        gains and watchdog in use now.  The model evaluation is the robot's dynamics kernel
        (:attr:`plant.simulation.arm.ArmPlant.dynamics_kernel`: the casadi
        function's operations), the matrix product a plain sum: the currents
        are ``__call__``'s to rounding.

        Parameters
        ----------
        n_samples : int or log
            Samples from t = 0 the reference table covers (a log: its
            ``n_total`` when it has one, a window's start plus its rows,
            else its ``n_samples``).
        plant : plant.simulation.arm.ArmPlant, optional
            The arm the law will run in, when it is not the controller's own
            rigid arm (e.g. the robot's two-mass arm): its generated module
            goes with the law's, so numba's on-disk cache serves the pair (any
            other plant runs the driver's in-memory twin).

        Returns
        -------
        plant.simulation.controllers.LoggedController
            With ``n_joints`` the robot's, ``n_samples``, ``state_at`` 0 (its
            state is the controller's at t = 0: a run from a window's start
            state is refused) and the law's own copy of the driver
            (``driver``).

        Raises
        ------
        ValueError
            ``n_samples`` not a positive integer.
        """
        lp, ring = self._law_parameters(n_samples)
        n = self.n
        state = np.concatenate([lp.reference[0, :2 * n], np.zeros(2 * n + 1),
                                np.full(ring, -np.inf)])
        module = _ctc_law_module(self.plant, plant)
        return LoggedController(kind=module.ArmCTCKind(), parameters=lp, state=state,
                                name=f"computed torque of {self.plant.name}", n_joints=n,
                                n_samples=lp.reference.shape[0], state_at=0,
                                driver=module.logged_run)

    def reference_table(self, n_samples) -> np.ndarray:
        """The reference the law reads, per sample ``k`` of a run from t = 0.

        Parameters
        ----------
        n_samples : int
            Samples.

        Returns
        -------
        ndarray, shape (n_samples, 5 n)
            ``q_d, qd_d`` at ``t_k = k Ts`` and ``q, qd, qdd`` at ``t_k + Ts/2``
            (rad, rad/s, rad/s^2), n columns each (:class:`ArmCTCParameters`).
        """
        nt, n, ts = int(n_samples), self.n, self.ts
        t = np.arange(nt) * ts
        q, qd, _ = self.trajectory.evaluate(t)
        qm, qdm, qddm = self.trajectory.evaluate(t + 0.5 * ts)
        return np.ascontiguousarray(np.hstack([np.asarray(v, dtype=float).reshape(nt, n)
                                               for v in (q, qd, qm, qdm, qddm)]))

    def _law_parameters(self, n_samples):
        """The compiled law's :class:`ArmCTCParameters` for ``n_samples`` samples, and the
        length of the watchdog's ring (0 without a watchdog)."""
        n_samples = getattr(n_samples, "n_total", getattr(n_samples, "n_samples", n_samples))
        try:
            nt = int(n_samples)
        except (TypeError, ValueError, OverflowError):
            nt = 0
        if nt < 1 or nt != n_samples:
            raise ValueError(f"n_samples must be a positive integer, got {n_samples!r}")
        n, ts = self.n, self.ts
        table = self.reference_table(nt)
        g = self.gains
        fe = self.following_error
        if fe is None:
            watch = (False, np.ones(n), 1.0, 0.0, 1.0, np.zeros(n), 0.0)
            ring = 0
        else:
            watch = (True, np.asarray(fe.limit_pulses, dtype=float).copy(), fe.hard_factor,
                     fe.dwell_s, fe.window_s, np.asarray(fe.p_gain, dtype=float).copy(),
                     fe.current_limit)
            ring = int(math.ceil(fe.window_s / ts)) + 2
        held = self.feedback_beta is not None
        lp = ArmCTCParameters(self.c, self.beta.copy(),
                              (self.feedback_beta if held else self.beta).copy(), held, table, *(
            np.ascontiguousarray(v, dtype=float) for v in (
                g.Kp, g.Kv, g.Ki, g.observer_gain[:, 0], g.observer_gain[:, 1])),
            self._integral, *watch)
        return lp, ring

    def _integrate(self, q_d, q_hat, i):
        """The integral action's error sum: ``+ Ts (q_d - q_hat)`` on the joints whose current
        ``i`` is within the limit (conditional integration: no windup)."""
        if self._integral:
            self.z = np.where(np.abs(i) > self.limit, self.z, self.z + self.ts * (q_d - q_hat))


class ArmFlexibleComputedTorque(ArmComputedTorque):
    """Motor-side computed torque of a flexible-joint arm (n joints, with backlash).

    The n-joint form of :class:`ctc.flexible.FlexibleJointComputedTorqueController`
    (see its module for the design and its measurements).  The encoders read
    the motors, so the law makes each motor follow the reference with the
    motor's own computed torque, the spring torque coming from a link model
    inside the controller::

        a   = qdd_d(t_k + Ts/2) + Kv (qd_d - th_hat') + Kp (q_d - th_hat)
        tau = Ia a + mean(tau_s_hat over the sample) - tau_f(qd_d(t_k + Ts/2))
        i   = clip(tau / (k Kt), -I_fs, I_fs)

    * ``th_hat, th_hat'``: the motor observer of :mod:`ctc.design` per joint;
    * ``tau_s_hat``: the spring torque ``K dz(th - q, b) + D (th' - q')`` of
      the link model ``D_link(q) q'' + n_link(q, q') = tau_s`` (the
      identified link beta, ``beta - Ia @ columns``), driven by the motor's
      commanded path ``th(t_k + s) = th_hat + th_hat' s + a s^2 / 2`` and
      integrated by RK4 (``link_substeps`` per sample; one compiled call a
      sample, built with the controller: 0.15-0.18 ms for the whole law on
      two to six joints instead of 0.52-0.63 ms, for 4-5 s more build,
      ``benchmarks/bench_ctc.py``); the current uses its average over the
      sample (the RK4 quadrature);
    * the link estimate is corrected by the motor observer's residual with
      the gains of :func:`ctc.flexible.two_mass_observer_gains` (per joint,
      the link's diagonal inertia at the reference's start): the link
      estimate's own ringing decays within a few periods; a better estimate
      from elsewhere is taken over by :meth:`set_link_estimate` (the adaptive
      CTC's replay of its window when its model changes, :mod:`ctc.arm_adaptive`);
    * the current is saturated at the drive's full scale; the motor
      observer is then driven by the acceleration the saturated current
      gives (no windup).

    Source: M. W. Spong, "Modeling and control of elastic joint robots",
    J. Dyn. Syst. Meas. Control 109 (1987) (the motor-side inner loop with
    the spring torque fed forward).

    Parameters
    ----------
    plant : plant.simulation.arm.ArmPlant
        The robot's rigid arm (:func:`plant.simulation.arm.arm_plant`; its base
        parameters define beta).
    beta : array_like, shape (r,)
        Rigid-equivalent base parameters (link plus ``Ia``), identified.
    rig : plant.Rig
    trajectory : plant.Trajectory
    stiffness, damping, motor_inertia : array_like, shape (n,)
        K (N m/rad), D (N m s/rad), Ia = Jm k^2 (kg m^2), joint side.
    backlash : array_like, shape (n,), optional
        Backlash widths b (rad, joint side; default none).
    link_substeps : int, optional
        RK4 steps per sample of the link model (default: enough for its
        fastest mode along the reference's first 10 s, ``w Ts / n <= 0.5``,
        at least 2).
    link_damping : float
        Damping ratio of the link-estimate error poles (default 0.5).
    gains : ctc.design.GainDesign, optional
    **design
        Keywords of :func:`ctc.design.design_gains`.

    Raises
    ------
    ValueError
        As :class:`ArmComputedTorque`; joints of the wrong size or not
        positive (K, Ia > 0; D, b >= 0); a link model whose inertia matrix
        is not positive definite at the reference's start.
    """

    def __init__(self, plant, beta, rig, trajectory, *, stiffness, damping, motor_inertia,
                 backlash=None, link_substeps=None, link_damping=0.5, gains=None, **design):
        from .flexible import two_mass_observer_gains

        super().__init__(plant, beta, rig, trajectory, gains=gains, **design)
        n = self.n
        vals = {}
        for name, v, strict in (("stiffness", stiffness, True), ("damping", damping, False),
                                ("motor_inertia", motor_inertia, True),
                                ("backlash", np.zeros(n) if backlash is None else backlash, False)):
            a = np.asarray(v, dtype=float).reshape(-1)
            if a.shape != (n,) or not np.all(np.isfinite(a)) or np.any(a <= 0 if strict else a < 0):
                raise ValueError(f"{name} must be {n} finite numbers {'>' if strict else '>='} 0, "
                                 f"got {v!r}")
            vals[name] = a
        self.K, self.D, self.Ia, self.b = (vals[k] for k in ("stiffness", "damping",
                                                             "motor_inertia", "backlash"))
        self.link_beta = self.beta - self.Ia @ plant.motor_inertia_columns
        # the link model is evaluated 4 link_substeps times a sample: the compiled kernel of
        # the plant's dynamics (the same numbers as the casadi function), compiled here
        self._link_dyn = plant.dynamics_kernel
        q0 = np.asarray(trajectory.evaluate(np.zeros(1))[0])[0]
        Dl, _ = self._link_terms(q0, np.zeros(n))
        if np.any(np.linalg.eigvalsh(Dl) <= 0):
            raise ValueError("the link model's inertia matrix (beta minus the motor inertias) is "
                             "not positive definite at the reference's start")
        if link_substeps is None:
            from plant.simulation.arm import link_mode_bound

            qs = np.asarray(trajectory.position(np.linspace(0.0, 10.0, 32)), dtype=float)
            Ds = [self._link_terms(q, np.zeros(n))[0] for q in qs]
            if all(np.all(np.linalg.eigvalsh(D) > 0) for D in Ds):
                w = link_mode_bound(np.log10(self.K), np.array([Dl] + Ds))
            else:
                w = link_mode_bound(np.log10(self.K), Dl[None])
            link_substeps = max(2, int(np.ceil(w * self.ts / 0.5)))
        self.link_substeps = int(link_substeps)
        if self.link_substeps < 1:
            raise ValueError(f"link_substeps must be >= 1, got {link_substeps!r}")
        self.link_damping = float(link_damping)
        self._q_start = q0
        L = two_mass_observer_gains(np.diag(Dl), self.K, self.D, self.Ia, self.gains, link_damping)
        self.link_gain = L[:, 2:4]
        # the link model over a sample, compiled here (never inside the loop)
        self._link_sample = _link_sample_kernel(plant)
        z = np.zeros(n)
        self._link_sample(q0, z, z, q0, z, self.K, self.D, 0.5 * self.b, self.link_beta, self.ts, 1)
        self.reset()

    @classmethod
    def from_result(cls, result, log, **options):
        """The flexible controller of a flexible identification result.

        Parameters
        ----------
        result : identification.arm.ArmIdentificationResult
            With ``model == "flexible"`` and its joints.
        log : plant.logs.arm_log.ArmLog
        **options
            As the constructor (``envelope`` by default twice the log's
            largest P-control errors, :func:`log_envelope`).

        Returns
        -------
        ArmFlexibleComputedTorque

        Raises
        ------
        ValueError
            A result that is not a success or not flexible.
        """
        if not result.get("success", False):
            raise ValueError(f"the identification did not succeed: {result.get('message')}")
        m = IdentifiedModel.from_result(result, n_joints=result["plant"].n_joints)
        if not m.flexible:
            raise ValueError("ArmFlexibleComputedTorque needs a flexible result (model 'flexible')")
        options.setdefault("envelope", log_envelope(log))
        return cls(result["plant"], m.f, result["rig"], log.trajectory,
                   stiffness=m.stiffness_Nm_per_rad, damping=m.damping_Nms_per_rad,
                   motor_inertia=m.motor_inertia_reflected_kgm2, backlash=m.backlash_rad,
                   **options)

    def set_beta(self, beta, *, feedback_beta=None) -> np.ndarray:
        """Switch the model to the rigid-equivalent ``beta``; the link model follows.

        The link's beta becomes ``beta - Ia @ columns`` and the link estimate's
        observer gains are placed anew for its diagonal inertia at the
        reference's start (:func:`ctc.flexible.two_mass_observer_gains`; a
        payload lowers the link mode the link poles sit at), as
        :meth:`ctc.flexible.FlexibleJointComputedTorqueController.set_model_f`
        does on the PUMA path; the motor loop keeps its gains and every
        estimate its state.

        Parameters
        ----------
        beta : array_like, shape (r,)
            Rigid-equivalent base parameters (link plus ``Ia``).
        feedback_beta : None
            Not taken: the flexible-joint CTC's feedback is its motor loop on
            the link model (held feedback is the rigid CTC's,
            :meth:`ArmComputedTorque.set_beta`).

        Returns
        -------
        ndarray, shape (r,)

        Raises
        ------
        ValueError
            beta of the wrong size or not finite, or whose link model's inertia
            matrix is not positive definite at the reference's start (the model
            in use is then kept); a ``feedback_beta``.
        """
        from .flexible import two_mass_observer_gains

        if feedback_beta is not None:
            raise ValueError("the flexible-joint CTC takes no feedback_beta (held feedback is the "
                             "rigid CTC's)")

        old = self.beta, self.link_beta
        super().set_beta(beta)
        self.link_beta = self.beta - self.Ia @ self.plant.motor_inertia_columns
        Dl, _ = self._link_terms(self._q_start, np.zeros(self.n))
        if np.any(np.linalg.eigvalsh(Dl) <= 0):
            self.beta, self.link_beta = old
            raise ValueError("the link model's inertia matrix (beta minus the motor inertias) is "
                             "not positive definite at the reference's start")
        L = two_mass_observer_gains(np.diag(Dl), self.K, self.D, self.Ia, self.gains,
                                    self.link_damping)
        self.link_gain = L[:, 2:4]
        return self.beta

    def logged_controller(self, n_samples, plant=None) -> LoggedController:
        """This controller as a compiled law of the logged-run driver (:func:`arm_flexible_ctc_law`).

        As :meth:`ArmComputedTorque.logged_controller`: each lane starts as
        :meth:`reset` leaves the controller (the link estimate restarting at
        the motor on the first sample), with the models, gains and watchdog
        in use now; the link model over a sample is a compiled copy of the
        same ``link_sample`` source the controller calls, so the currents are
        ``__call__``'s to rounding.

        Parameters
        ----------
        n_samples : int or log
            Samples from t = 0 the reference table covers.
        plant : plant.simulation.arm.ArmPlant, optional
            The arm the law will run in (typically the robot's two-mass arm,
            :func:`plant.simulation.arm.arm_plant` with ``flexible=True``):
            its generated module goes with the law's, so numba's on-disk
            cache serves the pair.

        Returns
        -------
        plant.simulation.controllers.LoggedController

        Raises
        ------
        ValueError
            ``n_samples`` not a positive integer.
        """
        base, ring = self._law_parameters(n_samples)
        n = self.n
        lp = ArmFlexibleCTCParameters(
            base, *(np.ascontiguousarray(v, dtype=float) for v in (
                self.K, self.D, self.Ia, 0.5 * self.b, self.link_beta, self.link_gain[:, 0],
                self.link_gain[:, 1])), int(self.link_substeps))
        q0, qd0 = base.reference[0, :n], base.reference[0, n:2 * n]
        state = np.concatenate([q0, qd0, np.zeros(2 * n), q0, qd0, [1.0, 0.0],
                                np.full(ring, -np.inf)])
        module = _ctc_law_module(self.plant, plant)
        return LoggedController(kind=module.ArmFlexibleCTCKind(), parameters=lp, state=state,
                                name=f"flexible-joint computed torque of {self.plant.name}",
                                n_joints=n, n_samples=base.reference.shape[0],
                                state_at=0, driver=module.logged_run)

    def _link_terms(self, q, qd):
        """The link model's ``D_link(q)`` (n, n) and ``n_link(q, qd)`` (n,)."""
        sc = np.empty(2 * self.n)
        sc[0::2] = np.sin(q)
        sc[1::2] = np.cos(q)
        lower, nvec = self._link_dyn(sc, np.asarray(qd, dtype=float), self.link_beta)
        return self._symmetric(lower), nvec

    def reset(self):
        """Motor observer at the reference's start; link estimate set at the first sample."""
        super().reset()
        self.first = True
        self.ql = self.x[0].copy()
        self.wl = self.x[1].copy()

    def link_estimate(self) -> np.ndarray:
        """The link model's state ``(q, qd)`` at the next sample, shape (2 n,) (rad, rad/s)."""
        return np.concatenate([self.ql, self.wl])

    def set_link_estimate(self, q, qd) -> None:
        """Take over a link estimate for the next sample (a state estimate from elsewhere).

        The link estimate follows the link model from the motor's path, and
        the motor observer's residual corrects it slowly (at the link mode):
        after a change of model (:meth:`set_beta`) the old model's estimate
        can sit hundreds of pulses from the links, ringing as they do not,
        and the spring torque the law feeds forward is then wrong for as
        long as the correction takes.  A controller that knows the links'
        state better -- the adaptive CTC's replay of the identified arm over
        its window (:func:`identification.arm_payload.replay_arm_state`) --
        hands it over here at the change (a bumpless transfer: L. Zaccarian
        and A. R. Teel, Automatica 41, 2005).

        Parameters
        ----------
        q, qd : array_like, shape (n,)
            The links' angles (rad) and rates (rad/s), joint side, at the
            next sample's read (a law that restarts its link estimate at the
            motor -- the first sample, a link model that diverged -- does so
            still).

        Raises
        ------
        ValueError
            Not n finite numbers each.
        """
        q = np.asarray(q, dtype=float).reshape(-1)
        qd = np.asarray(qd, dtype=float).reshape(-1)
        if q.shape != (self.n,) or qd.shape != (self.n,) or not (
                np.all(np.isfinite(q)) and np.all(np.isfinite(qd))):
            raise ValueError(f"the link estimate must be {self.n} finite angles and {self.n} "
                             "finite rates")
        self.ql, self.wl = q.copy(), qd.copy()

    def _law(self, k, t, q_meas, e_pulses):
        """The flexible-joint computed-torque law of one sample (currents (n,) A)."""
        ts = self.ts
        y = self._measurement(q_meas)
        q_d, qd_d, q_m, qd_m, qdd_m = self._reference(t)
        q_p = self.x[0] + ts * self.x[1] + 0.5 * ts * ts * self.a_prev
        w_p = self.x[1] + ts * self.a_prev
        if self.first:  # springs relaxed: the link where the motor is
            self.x = np.vstack([y, qd_d])
            self.ql, self.wl = y.copy(), qd_d.copy()
            self.first = False
        else:
            L = self.gains.observer_gain
            r = y - q_p
            self.x = np.vstack([q_p + L[:, 0] * r, w_p + L[:, 1] * r])
            self.ql = self.ql + self.link_gain[:, 0] * r
            self.wl = self.wl + self.link_gain[:, 1] * r
        th, v = self.x[0], self.x[1]
        a = qdd_m + self.gains.Kv * (qd_d - v) + self.gains.Kp * (q_d - th) + self.gains.Ki * self.z
        # the link model over the sample with the motor on its commanded path (RK4), and the
        # spring torque averaged over the sample (the same quadrature)
        try:
            q, w, mean_ts = self._link_sample(th, v, a, self.ql, self.wl, self.K, self.D,
                                              0.5 * self.b, self.link_beta,
                                              ts / self.link_substeps, self.link_substeps)
        except np.linalg.LinAlgError:  # a non-finite or singular link model
            mean_ts = np.full(self.n, np.nan)
        tf = self._friction_torque(qd_m)
        i = (self.Ia * a + mean_ts - tf) / self.torque_per_amp
        if not np.all(np.isfinite(i)):
            # the link model diverged (a robot far from the model): never a NaN to the drive;
            # the link estimate restarts at the motor
            self.first = True
            return np.zeros(self.n)
        self._integrate(q_d, th, i)
        if np.any(np.abs(i) > self.limit):  # saturated: the observer sees what the drive gives
            i = np.clip(i, -self.limit, self.limit)
            a = (i * self.torque_per_amp - mean_ts + tf) / self.Ia
        self.ql, self.wl = q, w
        self.a_prev = a
        return i


#: The model-error set of the flexible CTC's check (issue 21's: stiffness +-30 %,
#: damping x0.5 .. x2), as (name, stiffness factor, damping factor).
FLEXIBLE_CHECK_SCENARIOS = (("nominal", 1.0, 1.0), ("stiffness x0.7", 0.7, 1.0),
                            ("stiffness x1.3", 1.3, 1.0), ("damping x0.5", 1.0, 0.5),
                            ("damping x2", 1.0, 2.0))

#: Seconds of the log's reference the check simulates (from t = 0).
FLEXIBLE_CHECK_S = 3.0

#: The tracking goal (pulses): the check stops at the first flexible design (the default
#: gains first, then ever faster loops) that holds it on every scenario, without simulating
#: the others; a design checked before it within :data:`ctc.flexible.DESIGN_TIE_PULSES`
#: (a worst case of 2 pulses) is tied with it and kept if its current step is smaller
#: (``_tied_design``: the goal is met to the selection's resolution).
GOAL_PULSES = 1



def _flexible_candidates(result, log, design):
    """The flexible designs :func:`_checked_flexible` compares: (name, factory) pairs.

    The caller's design (the default gains without design keywords) first, then -- unless
    the caller fixed the design -- the robust candidates of :data:`ctc.flexible.ROBUST_DESIGNS`
    (faster motor loops, :func:`ctc.flexible.robust_design_options`), as the PUMA path's
    robust design (:func:`ctc.flexible.select_robust_design`).
    """
    from .flexible import DESIGN_KEYS, robust_design_options

    out = [("default", {})]
    if not DESIGN_KEYS & set(design):
        out += robust_design_options(result["rig"])
    return [(name, lambda extra=extra: ArmFlexibleComputedTorque.from_result(
        result, log, **extra, **design)) for name, extra in out]


def _tied_design(runs, worst, counted, best, log):
    """The flexible design kept among those the minimax rule cannot tell apart.

    The designs that ran every counted scenario with a worst case within
    :data:`ctc.flexible.DESIGN_TIE_PULSES` of the best one's, and no worse
    than the rigid-equivalent CTC's (the flexible design is chosen only when
    it holds the set at least as well), are one at the encoder's resolution;
    the one with the smallest current step for one pulse
    (:func:`ctc.protocol.current_per_pulse`) is kept, as on the PUMA 560 path
    (:func:`ctc.flexible.tied_choice`).

    Parameters
    ----------
    runs : list of (str, controller or None, list of float)
        The flexible designs of :func:`_checked_flexible`: name, controller, errors per scenario.
    worst : list of float
        Their worst cases and the rigid-equivalent CTC's (last), from :func:`_minimax_choice`.
    counted : ndarray of bool, shape (n_scenarios,)
        The scenarios that count.
    best : int
        The minimax design.
    log : plant.logs.arm_log.ArmLog
        Rig and reference (the current step is measured on them).

    Returns
    -------
    (int, list of dict)
        The design kept and, when more than one was tied, each tied design's
        ``name``, ``worst`` and ``current_per_pulse_A``.
    """
    from .flexible import DESIGN_TIE_PULSES, tied_choice
    from .protocol import current_per_pulse

    cap = min(worst[best] + DESIGN_TIE_PULSES, worst[-1])  # worst[-1]: the rigid CTC's
    tied = [i for i, (_, c, e) in enumerate(runs)
            if c is not None and len(e) and np.isfinite(worst[i]) and worst[i] <= cap
            and not np.any(np.isnan(np.asarray(e, dtype=float)[counted]))]
    if best not in tied or len(tied) < 2:
        return best, []
    steps = [current_per_pulse(runs[i][1], log) for i in tied]
    kept = tied[tied_choice([worst[i] for i in tied], steps)]
    return kept, [dict(name=runs[i][0], worst=worst[i], current_per_pulse_A=np.round(st, 4).tolist())
                  for i, st in zip(tied, steps)]


def _minimax_choice(flexible, rigid, n_scenarios):
    """The rule of :func:`_checked_flexible`: which controller its scenario errors pick.

    A scenario *counts* where at least one controller ran it finitely (a
    robot no controller holds is beyond what the check resolves); a
    controller's worst case is its largest error over the counted
    scenarios, infinite when it failed or lost one (a skipped scenario,
    nan, is no failure).  The flexible design with the smallest worst case
    (the first on a tie) is compared with the rigid-equivalent CTC
    (minimax, the flexible one on a tie); when every flexible design loses
    a counted scenario, the first that holds the nominal robot is the one
    compared, and it is chosen when the rigid-equivalent CTC loses a
    counted scenario and the nominal robot too.

    Parameters
    ----------
    flexible : list of list of float
        Per flexible design, its max abs(e) (pulses) per scenario of
        :data:`FLEXIBLE_CHECK_SCENARIOS`: inf for a failed or lost run, nan
        for a skipped one; empty for a design that could not be built.
    rigid : list of float
        The rigid-equivalent CTC's, the same way.
    n_scenarios : int
        Number of scenarios.

    Returns
    -------
    best : int
        Index of the flexible design compared.
    choice : str
        ``"flexible"`` (the minimax choice), ``"nominal"`` (every
        controller loses a counted scenario; the flexible design is the one
        that holds the nominal robot) or ``"rigid"``.
    worst : list of float
        Worst case per flexible design, then the rigid-equivalent CTC's.
    counted : ndarray of bool, shape (n_scenarios,)
        The scenarios that count.
    """
    nominal = [i for i, sc in enumerate(FLEXIBLE_CHECK_SCENARIOS) if sc[0] == "nominal"][0]
    rows = [e if len(e) else [np.inf] * n_scenarios for e in list(flexible) + [rigid]]
    E = np.array(rows, dtype=float)
    counted = np.isfinite(E).any(axis=0)
    worst = [float(np.nanmax(np.where(counted, row, -np.inf))) if counted.any() else np.inf
             for row in E]

    def holds_nominal(errs):
        return len(errs) > nominal and np.isfinite(errs[nominal])

    best = int(np.argmin(worst[:-1]))
    if not np.isfinite(worst[best]):
        best = next((i for i, e in enumerate(flexible) if holds_nominal(e)), best)
    w_f, w_r = worst[best], worst[-1]
    if np.isfinite(w_f) and w_f <= w_r:
        choice = "flexible"
    elif not np.isfinite(w_r) and holds_nominal(flexible[best]) and not holds_nominal(rigid):
        choice = "nominal"
    else:
        choice = "rigid"
    return best, choice, worst, counted


def _checked_flexible(result, log, *, max_current_per_pulse=None, **design):
    """The flexible CTC of a flexible result with the smallest worst case over the model-error
    set, to a pulse (:func:`_tied_design`), or the rigid-equivalent one when that holds the
    set better (minimax; :meth:`ArmComputedTorque.from_result`)."""
    import warnings

    from plant.simulation.arm import simulate_arm

    rig = result["rig"]
    n = int(min(log.n_samples, round(FLEXIBLE_CHECK_S / rig.sample_time_s)))
    sub = int(result.get("flexible_substeps") or 8)
    nb = result["plant"].base.rank
    nj = result["plant"].n_joints
    row0 = np.asarray(result["plant_row"], dtype=float)
    scenarios = check_scenarios(result, log)
    n_sc = len(scenarios)
    # the softer gearbox first (the scenario loose designs fail, so a design that cannot win
    # stops after one run), the nominal robot last
    order = sorted(range(n_sc), key=lambda i: (scenarios[i][0] == "nominal",
                                               float(np.min(scenarios[i][1])) >= 1.0))

    fplant = result["flexible_plant"]
    rows = np.tile(row0, (n_sc, 1))  # [beta (rigid-equivalent), K, D, Ia, b, friction]
    for i, (_, fk, fd, fi) in enumerate(scenarios):
        rows[i, nb:nb + nj] *= fk
        rows[i, nb + nj:nb + 2 * nj] *= fd
        rows[i, nb + 2 * nj:nb + 3 * nj] *= fi
    after = np.arange(n) * rig.sample_time_s >= 0.1 - 1e-12  # the samples from 0.1 s on

    # a run beyond the following-error limit has lost the arm, as a failed run: both are inf
    # (the minimax of finite errors once chose, for the random compliant chain 20262915 of
    # benchmarks/bench_arms.py, a rigid-equivalent CTC that lost the nominal robot: 960-1327
    # pulses on the independent robot, docs/figures/bench_arms_random_compliant_20262911_
    # wide_first_box.txt)
    lost = lost_bound(log.e_pulses)

    def scenario_errors(ctrl):
        """Max abs(e) (pulses) after 0.1 s of every scenario, inf for a failed run or one
        beyond the following-error limit on some joint: the controller's compiled law in the
        loop of the scenarios' robots at once (the pulses of plant.simulate_closed_loop with
        the controller, sample for sample)."""
        if not after.any():
            return [np.inf] * n_sc
        try:
            law = ctrl.logged_controller(n, plant=fplant)
        except ValueError:
            return [np.inf] * n_sc

        def run(lanes):
            sim = simulate_arm(fplant, rows[lanes], rig, log.trajectory, n, substeps=sub,
                               controller=law)
            return [float(np.abs(e[after]).max())
                    if st == 0 and np.all(np.abs(e[after]).max(axis=0) <= lost) else np.inf
                    for e, st in zip(sim.errors, sim.status)]

        try:
            return run(slice(None))
        except ValueError:  # one scenario's robot refused: each alone, as the sequential check
            errs = []
            for i in range(n_sc):
                try:
                    errs += run(slice(i, i + 1))
                except ValueError:
                    errs.append(np.inf)
            return errs

    def check(make, bound=np.inf):
        """(controller or None, errors per scenario): nan where the sequential check would have
        skipped the run, after the first scenario (in the check's order) whose finite
        error exceeds ``bound`` (finite: the largest error of a candidate that ran every
        scenario finitely, plus the selection's resolution) -- the candidate can be
        neither the minimax one nor tied with it.  A failed run (inf)
        stops nothing: no controller may run that scenario, and then it does not count."""
        try:
            ctrl = make()
        except ValueError:
            return None, []
        env, ctrl.envelope = ctrl.envelope, None  # the check sees the law itself
        every = scenario_errors(ctrl)
        ctrl.envelope = env
        errs = [np.nan] * n_sc
        for i in order:
            errs[i] = every[i]
            if np.isfinite(errs[i]) and errs[i] > bound:
                break
        return ctrl, errs

    # the rigid-equivalent CTC first: its errors bound the flexible candidates' search
    rigid, err_r = check(lambda: ArmComputedTorque(result["plant"], result["beta"], rig,
                                                   log.trajectory, **{
                                                       k: v for k, v in design.items()
                                                       if k not in ("link_substeps",
                                                                    "link_damping")}))
    from .flexible import DESIGN_TIE_PULSES, current_step_limit
    from .protocol import current_per_pulse

    step_limit = current_step_limit(rig, max_current_per_pulse)
    runs = []  # (name, controller, errors) of the flexible candidates
    held_back = []  # (name, current per pulse) of the faster designs the drive cannot carry
    for name, make in _flexible_candidates(result, log, design):
        if name != "default" and np.isfinite(step_limit):
            # with a cap, a faster candidate only when one pulse of quantisation moves the
            # current by at most that fraction of full scale (as ctc.flexible.select_robust_design)
            try:
                cand = make()
            except ValueError:
                cand = None  # check() records the design as not built
            if cand is not None:
                step = current_per_pulse(cand, log)
                if np.max(step) > step_limit:
                    held_back.append(dict(name=name,
                                          current_per_pulse_A=np.round(step, 4).tolist()))
                    continue
                make = (lambda c: (lambda: c))(cand)
        done = [e for _, c, e in runs if c is not None and len(e) and np.all(np.isfinite(e))]
        if len(err_r) and np.all(np.isfinite(err_r)):
            done.append(err_r)
        # a design within the selection's resolution of the best so far runs every scenario
        # (:func:`_tied_design` may keep it for its smaller current step)
        ctrl, errs = check(make, min((max(e) for e in done), default=np.inf) + DESIGN_TIE_PULSES)
        runs.append((name, ctrl, errs))
        if ctrl is not None and len(errs) and np.all(np.isfinite(errs)) and max(errs) <= GOAL_PULSES:
            break  # this design holds the tracking goal over the whole set: none can do better
    # a scenario counts where at least one controller runs it (otherwise the scaled robot is
    # beyond what the check's integration resolves); a controller that fails a counted
    # scenario has an infinite worst case; a skipped scenario is no failure (the candidate
    # already exceeded a finite worst case elsewhere)
    best, choice, worst, counted = _minimax_choice([r[2] for r in runs], err_r, n_sc)
    tied = []
    if choice == "flexible":
        best, tied = _tied_design(runs, worst, counted, best, log)
    name, flex, err_f = runs[best]
    w_f, w_r = worst[best], worst[-1]

    def listed(errs):
        return [None if np.isnan(e) else e for e in errs]

    selection = dict(scenarios=[s[0] for s in scenarios],
                     flexible=listed(err_f), rigid_equivalent=listed(err_r),
                     check_s=n * rig.sample_time_s, design=name,
                     designs=[dict(name=nm, errors=listed(e), worst=worst[i],
                                   built=c is not None)
                              for i, (nm, c, e) in enumerate(runs)],
                     held_back=held_back, current_per_pulse_limit_A=step_limit, tied=tied)
    selection.update(counted=[bool(c) for c in counted], worst_flexible=w_f,
                     worst_rigid_equivalent=w_r)
    if choice == "flexible":
        flex.selection = selection  # the minimax choice
        _warn_log_corners(scenarios, err_f)
        return flex
    if choice == "nominal":
        # each loses a scenario that counts: the one that holds the nominal robot, said
        warnings.warn(f"no controller holds the whole model-error set "
                      f"({', '.join(selection['scenarios'])}): the flexible-joint CTC ({name}) "
                      f"is used, which holds the nominal robot and the rigid-equivalent CTC "
                      f"does not", RuntimeWarning, stacklevel=3)
        flex.selection = selection
        _warn_log_corners(scenarios, err_f)
        return flex
    if rigid is None:
        raise ValueError("neither the flexible nor the rigid-equivalent CTC can be built from "
                         "this result")
    warnings.warn(f"the flexible-joint CTC holds the model-error set worse than the "
                  f"rigid-equivalent CTC (worst {w_f} vs {w_r} pulses after 0.1 s over "
                  f"{', '.join(selection['scenarios'])}, best of {len(runs)} flexible "
                  f"design(s)): the rigid-equivalent CTC is used", RuntimeWarning, stacklevel=3)
    rigid.selection = selection
    _warn_log_corners(scenarios, err_r)
    return rigid


def check_scenarios(result, log):
    """The model-error set of a flexible arm result's check: the standard set and the log's corners.

    :data:`FLEXIBLE_CHECK_SCENARIOS` (every joint's stiffness and damping
    scaled), then the robots the log allows beside the fit
    (``joint_intervals['corners']``,
    :func:`identification.arm_flexible.arm_joint_intervals`): one joint's
    stiffness, damping and reflected motor inertia at the ends of ranges the
    log leaves open, the rigid-equivalent beta held (a heavier motor is a
    lighter link), as :func:`ctc.flexible.log_range_scenarios` on the PUMA
    560 path.

    Parameters
    ----------
    result : identification.arm.ArmIdentificationResult or dict
        A flexible arm result.
    log : plant.logs.arm.ArmLog
        Its log (the joints' names).

    Returns
    -------
    list of (str, ndarray, ndarray, ndarray)
        Per scenario its name and the per-joint factors of the stiffness,
        the damping and the reflected motor inertia (shape (n,) each); the
        nominal robot first.
    """
    nj = result["plant"].n_joints
    one = np.ones(nj)
    out = [(name, fk * one, fd * one, one.copy()) for name, fk, fd in FLEXIBLE_CHECK_SCENARIOS]
    m = IdentifiedModel.from_result(result, n_joints=nj)
    return out + m.corner_scenarios(log.joint_names)


def _warn_log_corners(scenarios, errors):
    """Warn with the returned controller's worst case over the robots the log allows."""
    import warnings

    from .contract import LOG_RANGE, log_range_warning

    rows = [(s[0], e) for s, e in zip(scenarios, errors) if s[0].endswith(LOG_RANGE)]
    if not rows:
        return
    ran = [e for _, e in rows if np.isfinite(e)]
    warnings.warn(log_range_warning(f"{max(ran):g}" if ran else None,
                                    [nm for nm, e in rows if np.isinf(e)], len(rows),
                                    ".selection"), RuntimeWarning, stacklevel=4)
