"""casadi twin of the closed-loop core: the same sample step as a symbolic graph.

The twin mirrors :mod:`plant.simulation.core` with the casadi model of
:mod:`plant.robot.symbolic` (derived by Lagrange's equations): encoder read,
cell centre, and the one-sample step -- the motor current held over the
sample, joint torque ``k Kt i`` plus the drive friction, ``substeps``
classical RK4 steps of the rigid right-hand side with the same stage
arithmetic as :func:`plant.simulation.core.advance_sample`.  It serves two purposes:

* an independent check of the compiled core: :func:`simulate_experiment_twin`
  runs the logged P experiment through it, and the tests compare its pulses
  with :func:`plant.simulate_experiment` sample for sample;
* the plant side of :func:`ctc.evaluate.evaluate_ctc`, the casadi closed-loop
  evaluation of the computed-torque controller (design card).

Any robot model's rigid arm has its twin too (``plant=`` an
:class:`~plant.simulation.arm.ArmPlant`): the arm's casadi dynamics
(:attr:`~plant.simulation.arm.ArmPlant.dynamics_function`, ``D(q)`` and
``n(q, qd)`` in the base parameters) solved by casadi's own linear solve,
not by the generated kernels' ``L diag(d) L^T`` (:mod:`plant.simulation.arm`),
so the twin checks the code generation as well; :func:`simulate_experiment_twin`
takes an :class:`~plant.logs.arm_log.ArmLog`.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from plant.logs.rig import RigConstants, rig_constants
from plant.robot.symbolic import derive_base_model

__all__ = [
    "friction_sx",
    "trunc_sx",
    "cell_centre_sx",
    "rigid_rhs_sx",
    "arm_rhs_sx",
    "sample_step_function",
    "simulate_experiment_twin",
]


def friction_sx(qd, viscous, coulomb_pos, coulomb_neg, ramp_speed):
    """casadi form of :func:`plant.robot.model.friction_torque` (joint side, N m).

    ``-(viscous qd + Tc clip(qd / ramp_speed, -1, 1))`` with ``Tc =
    coulomb_pos`` for qd > 0 and ``coulomb_neg`` otherwise.

    Parameters
    ----------
    qd : casadi.SX
        Joint rate (rad/s).
    viscous, coulomb_pos, coulomb_neg, ramp_speed : float
        Joint-side constants (:class:`plant.logs.rig.RigConstants`).

    Returns
    -------
    casadi.SX
    """
    r = ca.fmin(ca.fmax(qd / ramp_speed, -1.0), 1.0)
    tc = ca.if_else(qd > 0, coulomb_pos, coulomb_neg)
    return -(viscous * qd + tc * r)


def trunc_sx(x):
    """Truncation toward zero, ``sign(x) floor(abs(x))`` (the encoder count).

    Parameters
    ----------
    x : casadi.SX

    Returns
    -------
    casadi.SX
    """
    return ca.sign(x) * ca.floor(ca.fabs(x))


def cell_centre_sx(count):
    """casadi form of :func:`plant.simulation.core.cell_centre`: ``count + 0.5 sign(count)``.

    Parameters
    ----------
    count : casadi.SX
        An integer count.

    Returns
    -------
    casadi.SX
    """
    return count + 0.5 * ca.sign(count)


def rigid_rhs_sx(f, c: RigConstants, x, i):
    """Right-hand side of the rigid robot (twin of :func:`plant.simulation.plants.rigid_rhs`).

    Parameters
    ----------
    f : casadi.SX or DM, shape (9,)
        Base parameters.
    c : plant.logs.rig.RigConstants
        Rig layout.
    x : casadi.SX, shape (4,)
        State (q2, q3, qd2, qd3).
    i : casadi.SX, shape (2,)
        Held motor currents (A).

    Returns
    -------
    casadi.SX, shape (4,)
        (qd2, qd3, qdd2, qdd3).
    """
    model = derive_base_model()
    q, w = x[0:2], x[2:4]
    tau = ca.vertcat(*[
        c.torque_per_amp[j] * i[j]
        + friction_sx(w[j], c.viscous[j], c.coulomb_pos[j], c.coulomb_neg[j], c.ramp_speed[j])
        for j in range(2)])
    return ca.vertcat(w, model.forward(f, q, w, tau, c.gravity))


def arm_rhs_sx(plant, beta, c: RigConstants, x, i):
    """Right-hand side of a robot model's rigid arm (twin of the generated one, :mod:`plant.simulation.arm`).

    ``qdd = D(q)^-1 (k Kt i + friction(qd) - n(q, qd))`` with ``D`` and
    ``n`` from the arm's casadi :attr:`~plant.simulation.arm.ArmPlant.dynamics_function`,
    solved by ``casadi.solve``.

    Parameters
    ----------
    plant : plant.simulation.arm.ArmPlant
        The rigid arm (n joints, r base parameters).
    beta : casadi.SX or DM, shape (r,)
        Base parameters.
    c : plant.logs.rig.RigConstants
        Rig layout.
    x : casadi.SX, shape (2 n,)
        State (q, qd).
    i : casadi.SX, shape (n,)
        Held motor currents (A).

    Returns
    -------
    casadi.SX, shape (2 n,)
        (qd, qdd).
    """
    n = plant.n_joints
    q, w = x[:n], x[n:]
    sc = ca.vertcat(*[v for j in range(n) for v in (ca.sin(q[j]), ca.cos(q[j]))])
    lower, nvec = plant.dynamics_function(sc, w, beta)
    rows = []
    for j in range(n):
        rows.append(ca.horzcat(*[lower[j * (j + 1) // 2 + k] if k <= j
                                 else lower[k * (k + 1) // 2 + j] for k in range(n)]))
    D = ca.vertcat(*rows)
    tau = ca.vertcat(*[
        c.torque_per_amp[j] * i[j]
        + friction_sx(w[j], c.viscous[j], c.coulomb_pos[j], c.coulomb_neg[j], c.ramp_speed[j])
        for j in range(n)])
    return ca.vertcat(w, ca.solve(D, tau - nvec))


def sample_step_function(c: RigConstants, substeps: int, plant=None) -> ca.Function:
    """One sample of the rigid plant under held currents, as a casadi Function.

    The twin of :func:`plant.simulation.core.advance_sample` for the rigid plant: RK4
    with ``substeps`` steps of ``Ts / substeps``, stages ``X + c K`` as in
    the core.

    Parameters
    ----------
    c : plant.logs.rig.RigConstants
        Rig layout (Ts, drive constants, gravity).
    substeps : int
        RK4 steps per sample (>= 1).
    plant : plant.simulation.arm.ArmPlant, optional
        A robot model's rigid arm (default the PUMA 560 links 2--3 of
        :mod:`plant.robot.symbolic`, f1..f9).

    Returns
    -------
    casadi.Function
        ``step(x (2 n,), i (n,), f (r,)) -> x_next (2 n,)``: n = 2, r = 9 by
        default.

    Raises
    ------
    ValueError
        If ``substeps < 1``, or the plant is not a rigid arm.
    """
    substeps = int(substeps)
    if substeps < 1:
        raise ValueError(f"substeps must be >= 1, got {substeps}")
    if plant is None:
        n, r = 2, 9

        def rhs(f, xk, i):
            return rigid_rhs_sx(f, c, xk, i)
    else:
        if getattr(plant, "flexible", True) or getattr(plant, "lane_friction", True):
            raise ValueError("the twin takes a robot model's rigid arm (arm_plant(model))")
        n, r = plant.n_joints, plant.base.rank

        def rhs(f, xk, i):
            return arm_rhs_sx(plant, f, c, xk, i)
    x = ca.SX.sym("x", 2 * n)
    i = ca.SX.sym("i", n)
    f = ca.SX.sym("f", r)
    h = c.sample_time_s / substeps
    hh = 0.5 * h
    h6 = h * (1.0 / 6.0)
    xk = x
    for _ in range(substeps):
        k1 = rhs(f, xk, i)
        k2 = rhs(f, xk + hh * k1, i)
        k3 = rhs(f, xk + hh * k2, i)
        k4 = rhs(f, xk + h * k3, i)
        xk = xk + h6 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    return ca.Function("sample_step", [x, i, f], [xk], ["x", "i", "f"], ["x_next"])


def simulate_experiment_twin(log, f, *, substeps: int = 48) -> np.ndarray:
    """The logged P experiment simulated through the casadi twin.

    The same loop as :func:`plant.simulate_experiment` (encoder read,
    ``i = P e``, held over the sample, ``substeps`` RK4 steps), evaluated as
    one casadi ``mapaccum`` over the run; for a robot model's log
    (:class:`~plant.logs.arm_log.ArmLog`) the loop of
    :func:`plant.simulation.arm.simulate_arm` on its rigid arm.

    Parameters
    ----------
    log : plant.ExperimentLog or plant.logs.arm_log.ArmLog
        The experiment (rig, trajectory, start state).
    f : array_like, shape (r,)
        Base parameters (f1..f9 of a PUMA 560 links 2--3 log).
    substeps : int
        RK4 steps per sample.

    Returns
    -------
    ndarray, shape (n_samples, n), int64
        Simulated tracking errors at the log's samples (pulses).

    Raises
    ------
    ValueError
        If ``f`` is not r finite numbers or ``substeps < 1``.
    """
    from plant.logs.arm_log import ArmLog

    arm = isinstance(log, ArmLog)
    plant = None
    if arm:
        from plant.simulation.arm import arm_plant

        plant = arm_plant(log.model)
    n_j, r = (plant.n_joints, plant.base.rank) if arm else (2, 9)
    f = np.asarray(f, dtype=float)
    if f.shape != (r,) or not np.all(np.isfinite(f)):
        raise ValueError(f"f must be {r} finite numbers, got shape {f.shape}")
    c = rig_constants(log.rig)
    step = sample_step_function(c, substeps, plant=plant)
    x = ca.SX.sym("x", 2 * n_j)
    refc = ca.SX.sym("ref", n_j)
    e = ca.vertcat(*[trunc_sx(refc[j]) - trunc_sx(x[j] * c.pulses_per_rad[j])
                     for j in range(n_j)])
    lim = c.current_limit  # the drive's full scale, as the compiled core
    cur = ca.vertcat(*[c.p_gain[j] * e[j] if not np.isfinite(lim)
                       else ca.fmin(ca.fmax(c.p_gain[j] * e[j], -lim), lim)
                       for j in range(n_j)])
    loop = ca.Function("p_loop", [x, refc], [step(x, cur, ca.DM(f)), e])
    if arm:
        n, start = log.n_samples, 0
        ref = log.reference_counts()
    else:
        n, start = log.n_total, log.start_index
        t = np.arange(n) * c.sample_time_s
        ref = log.trajectory.position(t) * log.rig.pulses_per_rad
    _, E = loop.mapaccum("p_run", n)(np.r_[c.q0, c.qd0], ref.T)
    e_all = np.rint(np.asarray(E).T).astype(np.int64)
    return e_all[start:]
