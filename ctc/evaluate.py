"""Closed-loop evaluation of the computed-torque controller with casadi (design card).

:func:`evaluate_ctc` builds the sampled closed loop -- computed-torque
controller (the same law, estimator and options as a
:class:`~ctc.ComputedTorqueController`) acting on the model robot -- as a
casadi graph and evaluates it over a run:

* one sample is a casadi ``Function`` ``step(x_k, u_k) -> (x_{k+1}, y_k)``:
  encoder truncation ``trunc(x) = sign(x) floor(|x|)`` of the robot angles
  and of the reference counts, the pulse errors, the controller (centre of
  the pulse cell, current observer or filtered difference, outer loop,
  ``D_hat a + h_hat + g_hat - tau_f``, division by ``k Kt``), the clip at
  the current full scale, and the robot advanced over the sample by the
  casadi twin of the core's sample step (:func:`plant.simulation.twin.sample_step_function`,
  ``substeps`` RK4 steps);
* the run is ``step.mapaccum(n)``, evaluated once on the tabulated
  reference.

State ``x`` (15,): robot ``q2, q3, qd2, qd3``; controller ``init``,
``q_hat`` (2), ``qd_hat`` (2), previous command ``a`` (2), previous position
``y`` (2), error sum of the integral action (2).  Per-sample input ``u`` (8,): ``q_d, qd_d, qdd_d`` (6) and the
unquantised reference counts (2).  Output ``y`` (6,): pulse errors (2),
currents (2), robot angles (2) at ``t_k``.

The rigid-body model is the casadi model of :mod:`plant.robot.symbolic`
(``derive_base_model``), which the plant's tests prove equal to the numeric
model of :mod:`plant.robot.model` to 1e-12; the drive friction is the casadi form of
:func:`plant.robot.model.friction_torque` (:func:`plant.simulation.twin.friction_sx`, tested
against it).

Any serial arm (:class:`ctc.arm.ArmComputedTorque`, issue 23): the same
functions take the arm's controller and its robot's base parameters beta.
Its step is :func:`build_arm_step_function`: state ``x`` (6 n,): robot
``q, qd``; observer ``q_hat, qd_hat``; previous acceleration; error sum.
Input ``u`` (6 n,): ``q_d, qd_d`` at ``t_k``, ``q, qd, qdd`` at ``t_k +
Ts/2`` and the unquantised reference counts.  Output ``y`` (3 n,): pulse
errors, currents, robot angles.  The model is the robot model's casadi
function (:attr:`plant.simulation.arm.ArmPlant.dynamics_function`, the
expressions the arm's plant and the controller compile) and the robot the
casadi twin of the arm's sample step (``sample_step_function(..., plant=)``).
The law is the controller's without its following-error watchdog (the
evaluation is of the model-based law, as the flexible CTC's check runs it).

Agreement with the numba simulator.  Both evaluate the same arithmetic up to
rounding (1e-16); the quantised loop is chaotic at the pulse level, so after
a while a rounding difference flips one count at a pulse boundary and the
two runs then differ by single pulses at scattered samples.  With 32 RK4
substeps in both, they agree sample for sample over the first second of the
paper trajectory (``tests/test_ctc.py``).
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from plant.logs.rig import rig_constants
from plant.simulation.twin import cell_centre_sx, friction_sx, sample_step_function, trunc_sx
from plant.robot.symbolic import derive_base_model

from .computed_torque import ComputedTorqueController

__all__ = ["CasadiEvaluation", "evaluate_ctc", "build_step_function", "build_arm_step_function"]

_NX = 15
_NU = 8
_NY = 6


def build_step_function(controller: ComputedTorqueController, f_robot, *, substeps=32,
                        current_full_scale_A=None):
    """The one-sample closed-loop step as a casadi Function.

    Parameters
    ----------
    controller : ComputedTorqueController
        Supplies the model f, rig constants, gains and options.
    f_robot : array_like, shape (9,)
        True f of the model robot.
    substeps : int
        RK4 steps per sample.
    current_full_scale_A : float, optional
        Current clip (default: the rig's, none if it gives none).

    Returns
    -------
    casadi.Function
        ``step(x (15,), u (8,)) -> (x_next (15,), y (6,))`` (layout in the
        module docstring).
    """
    p = controller.parameters
    c = p.rig
    fm = ca.DM(controller.f)
    fr = ca.DM(np.asarray(f_robot, dtype=float))
    rig = controller.rig
    model = derive_base_model()
    grav = c.gravity
    ts = c.sample_time_s
    i_fs = rig.current_full_scale_A if current_full_scale_A is None else current_full_scale_A

    x = ca.SX.sym("x", _NX)
    u = ca.SX.sym("u", _NU)
    q = x[0:2]
    w = x[2:4]
    init = x[4]
    qd_ref = u[0:2]
    wd_ref = u[2:4]
    ad_ref = u[4:6]
    refc = u[6:8]

    e_out = []
    y_list, qh_list, wh_list, a_list, vn_list = [], [], [], [], []
    for j in range(2):
        sc = c.pulses_per_rad[j]
        cnt = trunc_sx(q[j] * sc)
        e_out.append(trunc_sx(refc[j]) - cnt)
        yj = (cell_centre_sx(cnt) if p.cell_centre else cnt) / sc
        if p.estimator == 0:
            qb = x[5 + j] + ts * x[7 + j] + 0.5 * ts * ts * x[9 + j]
            wb = x[7 + j] + ts * x[9 + j]
            res = yj - qb
            qh_run = qb + p.observer_q[j] * res
            wh_run = wb + p.observer_w[j] * res
        else:
            al = p.alpha[j]
            qh_run = yj
            wh_run = al * x[7 + j] + (1.0 - al) * (yj - x[11 + j]) / ts
        qh = ca.if_else(init == 0, yj, qh_run)
        wh = ca.if_else(init == 0, wd_ref[j], wh_run)
        a = (ad_ref[j] + p.kv[j] * (wd_ref[j] - wh) + p.kp[j] * (qd_ref[j] - qh)
             + p.ki[j] * x[13 + j])
        vn = wh if p.estimate_in_nonlinear else wd_ref[j]
        y_list.append(yj)
        qh_list.append(qh)
        wh_list.append(wh)
        a_list.append(a)
        vn_list.append(vn)
    qh = ca.vertcat(*qh_list)
    vn = ca.vertcat(*vn_list)
    a = ca.vertcat(*a_list)
    zero2 = ca.DM.zeros(2)
    tau = model.D(fm, qh, vn, zero2, grav) @ a + model.h(fm, qh, vn, zero2, grav) + model.g(fm, qh, vn, zero2, grav)
    cur, z_next = [], []
    for j in range(2):
        tj = tau[j]
        if p.friction:
            tj = tj - friction_sx(vn[j], c.viscous[j], c.coulomb_pos[j], c.coulomb_neg[j],
                                  c.ramp_speed[j])
        ij = tj / c.torque_per_amp[j]
        # error sum of the integral action, frozen while the current saturates
        z_run = x[13 + j] + ts * (qd_ref[j] - qh[j])
        if i_fs is not None:
            z_run = ca.if_else(ca.fabs(ij) > float(i_fs), x[13 + j], z_run)
            ij = ca.fmin(ca.fmax(ij, -float(i_fs)), float(i_fs))
        cur.append(ij)
        z_next.append(z_run if p.ki[j] != 0.0 else x[13 + j])
    cur = ca.vertcat(*cur)
    # the robot: the casadi twin of the core's sample step (plant.simulation.twin)
    x_robot = sample_step_function(c, substeps)(ca.vertcat(q, w), cur, fr)
    qq, ww = x_robot[0:2], x_robot[2:4]
    x_next = ca.vertcat(qq, ww, 1.0, qh, ca.vertcat(*wh_list), a, ca.vertcat(*y_list),
                        ca.vertcat(*z_next))
    y = ca.vertcat(ca.vertcat(*e_out), cur, q)
    return ca.Function("ctc_step", [x, u], [x_next, y], ["x", "u"], ["x_next", "y"])


def build_arm_step_function(controller, beta_robot, *, substeps=32, current_full_scale_A=None):
    """One sample of an arm's computed-torque closed loop as a casadi Function.

    The law of ``ArmComputedTorque.__call__`` without its
    watchdog (measurement at the count's cell centre, current observer,
    outer loop at mid-sample, ``D_hat a + n_hat - tau_f``, or with the
    feedback held at another model's inertia ``D_f`` (``feedback_beta``)
    ``D_hat qdd_d + D_f (a - qdd_d) + n_hat - tau_f``, the clip at the
    current full scale with the observer driven by the saturated current
    and the error sum frozen) on the robot model's rigid arm, advanced by the
    casadi twin of the core's sample step.

    Parameters
    ----------
    controller : ctc.arm.ArmComputedTorque
        Supplies the model beta (and a held feedback's ``feedback_beta``), rig
        constants, gains and reference.
    beta_robot : array_like, shape (r,)
        Base parameters of the simulated robot (the controller's robot model).
    substeps : int
        RK4 steps per sample.
    current_full_scale_A : float, optional
        Current clip (default: the controller's rig's; none if it gives none).

    Returns
    -------
    casadi.Function
        ``step(x (6 n,), u (6 n,)) -> (x_next (6 n,), y (3 n,))`` (layout in
        the module docstring).

    Raises
    ------
    ValueError
        A flexible-joint controller, or beta_robot not r finite numbers.
    """
    from plant.simulation.arm import arm_plant

    from .arm import ArmFlexibleComputedTorque

    if isinstance(controller, ArmFlexibleComputedTorque):
        raise ValueError("the casadi evaluation takes the rigid arm's CTC (ArmComputedTorque), "
                         "not ArmFlexibleComputedTorque")
    plant = controller.plant
    n, r = controller.n, plant.base.rank
    beta_robot = np.asarray(beta_robot, dtype=float).reshape(-1)
    if beta_robot.shape != (r,) or not np.all(np.isfinite(beta_robot)):
        raise ValueError(f"beta_robot must be {r} finite numbers, got shape {beta_robot.shape}")
    c = controller.c
    ts = c.sample_time_s
    g = controller.gains
    lim = c.current_limit if current_full_scale_A is None else float(current_full_scale_A)
    limited = bool(np.isfinite(lim))
    integral = bool(np.any(g.Ki))  # the error sum only where it acts, as the controller
    x = ca.SX.sym("x", 6 * n)
    u = ca.SX.sym("u", 6 * n)
    q, w = x[0:n], x[n:2 * n]
    q_d, qd_d, q_m, qd_m, qdd_m, refc = (u[k * n:(k + 1) * n] for k in range(6))
    e_out, ys, qh, wh, a, sc = [], [], [], [], [], []
    for j in range(n):
        spr = c.pulses_per_rad[j]
        cnt = trunc_sx(q[j] * spr)
        e_out.append(trunc_sx(refc[j]) - cnt)
        y = cell_centre_sx(cnt) / spr
        q_p = x[2 * n + j] + ts * x[3 * n + j] + 0.5 * ts * ts * x[4 * n + j]
        w_p = x[3 * n + j] + ts * x[4 * n + j]
        res = y - q_p
        qh.append(q_p + float(g.observer_gain[j, 0]) * res)
        wh.append(w_p + float(g.observer_gain[j, 1]) * res)
        a.append(qdd_m[j] + float(g.Kv[j]) * (qd_d[j] - wh[j]) + float(g.Kp[j]) * (q_d[j] - qh[j])
                 + float(g.Ki[j]) * x[5 * n + j])
        qmid = qh[j] + (q_m[j] - q_d[j])
        sc += [ca.sin(qmid), ca.cos(qmid)]
        ys.append(y)

    def inertia(lower):
        return ca.vertcat(*[ca.horzcat(*[lower[j * (j + 1) // 2 + k] if k <= j
                                         else lower[k * (k + 1) // 2 + j] for k in range(n)])
                            for j in range(n)])

    lower, nvec = plant.dynamics_function(ca.vertcat(*sc), qd_m, ca.DM(controller.beta))
    D = inertia(lower)
    held = getattr(controller, "feedback_beta", None) is not None
    if held:
        Df = inertia(plant.dynamics_function(ca.vertcat(*sc), qd_m,
                                             ca.DM(controller.feedback_beta))[0])
    av = ca.vertcat(*a)
    tf = ca.vertcat(*[friction_sx(qd_m[j], c.viscous[j], c.coulomb_pos[j], c.coulomb_neg[j],
                                  c.ramp_speed[j]) for j in range(n)])
    ffw = D @ qdd_m if held else None  # held: the model's feed-forward D_hat qdd_d
    tau = ((ffw + Df @ (av - qdd_m)) if held else D @ av) + nvec - tf
    cur, z_next, over = [], [], []
    for j in range(n):
        ij = tau[j] / c.torque_per_amp[j]
        z_run = x[5 * n + j] + ts * (q_d[j] - qh[j]) if integral else x[5 * n + j]
        if limited:
            over.append(ca.fabs(ij) > lim)
            z_run = ca.if_else(over[-1], x[5 * n + j], z_run)
            ij = ca.fmin(ca.fmax(ij, -lim), lim)
        cur.append(ij)
        z_next.append(z_run)
    cur = ca.vertcat(*cur)
    if limited:  # saturated: the observer sees the acceleration the clipped current gives the model
        tpa = ca.DM(np.asarray(c.torque_per_amp, dtype=float))
        a_sat = (ca.solve(Df, cur * tpa - nvec + tf - ffw) + qdd_m if held
                 else ca.solve(D, cur * tpa - nvec + tf))
        any_over = over[0]
        for o in over[1:]:
            any_over = ca.logic_or(any_over, o)
        av = ca.if_else(any_over, a_sat, av)
    robot = arm_plant(plant.model, plant.base)  # the rigid arm the twin takes
    x_robot = sample_step_function(c, substeps, plant=robot)(ca.vertcat(q, w), cur,
                                                              ca.DM(beta_robot))
    x_next = ca.vertcat(x_robot, ca.vertcat(*qh), ca.vertcat(*wh), av, ca.vertcat(*z_next))
    y = ca.vertcat(ca.vertcat(*e_out), cur, q)
    return ca.Function("arm_ctc_step", [x, u], [x_next, y], ["x", "u"], ["x_next", "y"])


def _evaluate_arm(controller, beta_robot, *, n_samples, substeps, after_s, pulses, q0, qd0):
    """:func:`evaluate_ctc` for an arm's computed torque (:func:`build_arm_step_function`)."""
    if n_samples is None:
        raise ValueError("n_samples is required for an arm's controller (it has no reference table)")
    try:
        n, sub = int(n_samples), int(substeps)
    except (TypeError, ValueError, OverflowError):
        raise ValueError(f"n_samples and substeps must be positive integers, got {n_samples!r} "
                         f"and {substeps!r}") from None
    if n < 1 or n != n_samples:
        raise ValueError(f"n_samples must be a positive integer, got {n_samples!r}")
    if sub < 1 or sub != substeps:
        raise ValueError(f"substeps must be an integer >= 1, got {substeps!r}")
    nj, ts, c = controller.n, controller.ts, controller.c
    start = rig_constants(controller.rig)  # the rig's start state (the controller's c has zeros)
    step = build_arm_step_function(controller, beta_robot, substeps=sub)
    run = step.mapaccum("arm_ctc_run", n)
    t = np.arange(n) * ts
    refc = np.asarray(controller.trajectory.position(t), dtype=float) * np.asarray(c.pulses_per_rad)
    U = np.hstack([controller.reference_table(n), refc]).T
    x0 = np.zeros(6 * nj)
    for k, (given, default) in enumerate(((q0, start.q0), (qd0, start.qd0))):
        v = np.asarray(default if given is None else given, dtype=float).reshape(-1)
        if v.shape != (nj,) or not np.all(np.isfinite(v)):
            raise ValueError(f"the start state must be {nj} finite numbers per joint, got {v!r}")
        x0[k * nj:(k + 1) * nj] = v
    x0[2 * nj:4 * nj] = U[:2 * nj, 0]  # the observer on the reference's start (reset())
    _, Y = run(x0, U)
    Y = np.asarray(Y).T
    e = np.rint(Y[:, :nj]).astype(np.int64)
    mask = t >= after_s - 1e-12
    if not np.any(mask):
        raise ValueError(f"no sample at or after after_s = {after_s} s")
    m = np.max(np.abs(e[mask]), axis=0)
    return CasadiEvaluation(
        t=t, e_pulses=e, i_A=Y[:, nj:2 * nj], q=Y[:, 2 * nj:3 * nj], max_abs_error=m,
        max_abs_error_all=np.max(np.abs(e), axis=0), within_one_pulse=bool(np.all(m <= pulses)),
        after_s=float(after_s), function=run)


@dataclass(frozen=True)
class CasadiEvaluation:
    """Result of :func:`evaluate_ctc`.

    Attributes
    ----------
    t : ndarray, shape (n,)
        Sample times (s).
    e_pulses : ndarray, shape (n, n_joints), int64
        Pulse errors ref - act at t_k (n_joints = 2 for the PUMA 560 links 2-3).
    i_A : ndarray, shape (n, n_joints)
        Motor currents (A).
    q : ndarray, shape (n, n_joints)
        Robot joint angles at t_k (rad).
    max_abs_error : ndarray, shape (n_joints,)
        max abs(e) per joint over t >= after_s (pulses).
    max_abs_error_all : ndarray, shape (n_joints,)
        max abs(e) per joint over the whole run.
    within_one_pulse : bool
        Whether abs(e) <= pulses on every joint for t >= after_s.
    after_s : float
        Start of the evaluated part (s).
    function : casadi.Function
        The run Function ``(x0, U) -> (X, Y)`` (``step.mapaccum(n)``;
        ``x0`` (15,), ``U`` (8, n), ``Y`` (6, n) for the PUMA 560 links
        2-3, ``x0`` (6 n_joints,), ``U`` (6 n_joints, n), ``Y`` (3 n_joints,
        n) for an arm).
    """

    t: np.ndarray
    e_pulses: np.ndarray
    i_A: np.ndarray
    q: np.ndarray
    max_abs_error: np.ndarray
    max_abs_error_all: np.ndarray
    within_one_pulse: bool
    after_s: float
    function: object

    def summary(self) -> str:
        """One line: max abs(e) per joint and the ±1 pulse verdict."""
        m = " / ".join(str(v) for v in self.max_abs_error)
        a = " / ".join(str(v) for v in self.max_abs_error_all)
        return (
            f"casadi CTC evaluation over {self.t[-1] + (self.t[1] - self.t[0] if len(self.t) > 1 else 0):.3f} s: "
            f"max |e| = {m} pulses after {self.after_s * 1e3:.0f} ms "
            f"({a} whole run); within ±1 pulse: {'yes' if self.within_one_pulse else 'no'}"
        )


def evaluate_ctc(controller: ComputedTorqueController, f_robot, *, n_samples=None, substeps=32,
                 after_s=0.05, pulses=1, q0=None, qd0=None) -> CasadiEvaluation:
    """Evaluate the CTC closed loop on the model robot with casadi.

    Parameters
    ----------
    controller : ComputedTorqueController or ctc.arm.ArmComputedTorque
        The controller (its model f, rig, reference, gains and options); an
        arm's (any serial arm, :func:`build_arm_step_function`: its law
        without the watchdog, on its robot model's rigid arm).
    f_robot : array_like, shape (9,) or (r,)
        True f of the simulated robot; for an arm's controller its base
        parameters beta (r,).
    n_samples : int, optional
        Samples from t = 0 (default: all tabulated in the controller; an
        arm's controller has no table: required).
    substeps : int
        RK4 steps per sample (use the same as the numba simulator to compare).
    after_s : float
        The ±``pulses`` check starts at this time (s); default 50 ms.
    pulses : int
        Tolerance of the check (pulses).
    q0, qd0 : array_like, shape (n_joints,), optional
        Start state (default: the rig's).

    Returns
    -------
    CasadiEvaluation

    Raises
    ------
    ValueError
        Wrong controller type, f_robot not 9 (r) finite numbers, n_samples out of
        range or missing, substeps < 1, no sample at or after ``after_s``.
    """
    from .arm import ArmComputedTorque

    if isinstance(controller, ArmComputedTorque):
        return _evaluate_arm(controller, f_robot, n_samples=n_samples, substeps=substeps,
                             after_s=after_s, pulses=pulses, q0=q0, qd0=qd0)
    if not isinstance(controller, ComputedTorqueController):
        raise ValueError("controller must be a ComputedTorqueController or a "
                         f"ctc.arm.ArmComputedTorque, got {type(controller).__name__}")
    f_robot = np.asarray(f_robot, dtype=float)
    if f_robot.shape != (9,) or not np.all(np.isfinite(f_robot)):
        raise ValueError(f"f_robot must be 9 finite numbers, got shape {f_robot.shape}")
    n_max = controller.reference_table.shape[0]
    n = n_max if n_samples is None else int(n_samples)
    if not 1 <= n <= n_max:
        raise ValueError(f"n_samples must be in 1..{n_max} (the controller's reference table), got {n_samples}")
    if int(substeps) < 1:
        raise ValueError(f"substeps must be >= 1, got {substeps}")
    rig = controller.rig
    step = build_step_function(controller, f_robot, substeps=substeps)
    run = step.mapaccum("ctc_run", n)
    t = np.arange(n) * rig.sample_time_s
    refc = controller.trajectory.position(t) * rig.pulses_per_rad
    U = np.hstack([controller.reference_table[:n], refc]).T
    x0 = np.zeros(_NX)
    x0[0:2] = rig.q0_rad if q0 is None else np.asarray(q0, float)
    x0[2:4] = rig.qd0_rad_per_s if qd0 is None else np.asarray(qd0, float)
    _, Y = run(x0, U)
    Y = np.asarray(Y).T
    e = np.rint(Y[:, 0:2]).astype(np.int64)
    mask = t >= after_s - 1e-12
    if not np.any(mask):
        raise ValueError(f"no sample at or after after_s = {after_s} s")
    m = np.max(np.abs(e[mask]), axis=0)
    return CasadiEvaluation(
        t=t, e_pulses=e, i_A=Y[:, 2:4], q=Y[:, 4:6], max_abs_error=m,
        max_abs_error_all=np.max(np.abs(e), axis=0), within_one_pulse=bool(np.all(m <= pulses)),
        after_s=float(after_s), function=run,
    )
