"""A robot model's rigid arm in the closed-loop core: generated right-hand side and logged runs.

:func:`arm_plant` turns a :class:`plant.robot.robot_model.RobotModel` (any serial
arm of revolute joints, from a DH table or a URDF) into a plant of the one
closed-loop core (:mod:`plant.simulation.core`): the rigid multibody dynamics of its
active joints in its **base parameters** beta (numerical QR, Gautier 1990;
:meth:`~plant.robot.robot_model.RobotModel.base_parameters`),

.. math::

    D(q; \\beta)\\,\\ddot q + n(q, \\dot q; \\beta) = k K_t\\, i + \\tau_f(\\dot q),

with the drive's joint-side friction ``tau_f`` (:func:`plant.robot.model.friction_torque`,
the rig's, per joint) and the torque ``k Kt i`` of the held motor current.
casadi writes D and n in the sines and cosines of the joint angles
(:attr:`~plant.robot.robot_model.RobotModel`'s Newton--Euler derivation), the
code generator :mod:`plant.robot.codegen` turns them into straight-line code, and
the generated right-hand side solves ``D qdd = tau - n`` by an unrolled
square-root-free Cholesky factorisation ``D = L diag(d) L^T`` (n divisions,
no square root) whose smallest pivot is the core's
positive-definiteness margin.  The code is generated once per robot (the
kind class and its right-hand side are cached by the generated source), so
one robot's kernels are specialised at its joint count; two robots live
side by side in one process (each its own kind).  numba caches them on disk
(see below).

Drivers of the core for the arm, both in lanes (one candidate beta per
column, :mod:`plant.simulation.lanes`):

* :func:`simulate_arm` -- the logged experiment: the rig's P loop ``i = P e``
  with the integer error ``e = trunc(q_ref k N / 2 pi) - trunc(q k N / 2
  pi)``, current clipped at the drive's full scale; returns the simulated
  errors in pulses and the output error (paper eq. 4) against a log;
* :func:`replay_arm` -- the one-step-ahead predictor of the refinement
  (:mod:`identification.arm`): the logged current plus output injection
  ``P gain (m - c)`` toward the centre ``m`` of the count cell the log
  allows; returns the continuous prediction errors ``m - c`` (pulses).

Both run the candidates in the PUMA 560 path's logged-run driver -- one
source, :func:`plant.simulation.simulate.logged_run`, compiled into the
robot's generated module -- so that the two paths give the same objective
for the same pulses: a lane that fails (D not
positive definite, a non-finite state, a count beyond the divergence
bound) or passes the early-termination cap is retired at once, with that
driver's finite penalty (:func:`plant.simulation.lanes.final_objective`;
``simulate_arm``'s default bound against a log is
:func:`plant.simulation.simulate.default_bound`).

The robot's kernels -- its kind class, right-hand side, dynamics kernel
and the copies of the drivers compiled for it -- are one generated module
(:mod:`plant.simulation.generated`, :attr:`ArmPlant.kernels`) written to a
cache directory, so numba caches them on disk: the next process that
builds the same robot loads them instead of compiling them again.
"""
from __future__ import annotations

import hashlib
import inspect
import math
import sys
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from plant.robot.codegen import function_source, multiple_angle_form
from plant.simulation.core import LANE_PAD, STATUS_MESSAGES, STATUS_OK, hold_and_advance
from plant.simulation.generated import load, module_text
from plant.simulation.lanes import new_lanes
from plant.simulation.controllers import P_LAW, LoggedController
from plant.simulation.parallel import run_chunks
from plant.simulation.plants import Plant
from plant.simulation.simulate import DEFAULT_SUBSTEPS, default_bound, for_kinds
from plant.logs.rig import rig_constants

__all__ = ["ArmPlant", "arm_plant", "ArmSimulation", "simulate_arm", "replay_arm",
           "reference_counts", "ARM_SUBSTEPS", "link_mode_bound", "kernels_cached", "sin_cos",
           "symmetric_from_lower", "INLINE_MAX_INSTRUCTIONS", "TINY_PIVOT"]

#: RK4 substeps per sample of the arm's logged runs by default: the exact
#: reproduction of a log, the same rule as the PUMA 560 path's
#: ``plant.simulate_experiment`` (``plant.simulation.simulate.DEFAULT_SUBSTEPS``,
#: 48: chosen by the convergence of the quantised loop's pulses), so both
#: paths simulate a log the same way (on the development logs: the same
#: pulses).  The searches integrate more coarsely
#: (``identification.arm.ARM_OUTPUT_ERROR_SUBSTEPS``, ``ARM_REFINE_SUBSTEPS``).
ARM_SUBSTEPS = DEFAULT_SUBSTEPS


@dataclass(frozen=True)
class ArmPlant(Plant):
    """The rigid arm of a robot model as a plant of the closed-loop core.

    Build it with :func:`arm_plant`.  State ``(q_1..q_n, qd_1..qd_n)`` of the
    model's active joints (rad, rad/s); per-lane parameters the base
    parameters beta (``base``); the encoders read ``q``.

    Parameters
    ----------
    name : str
        The robot's name.
    kind : NamedTuple
        The kind registered for this robot's right-hand side (a class of its own).
    encoder_row : int
        First state row the encoders read: 0 (the joint angles) for a rigid
        arm, 2 n (the motor angles) for a flexible one.
    model : plant.robot.robot_model.RobotModel
        The robot.
    base : plant.robot.robot_model.BaseParameterSet
        Its base parameters (names, regrouping ``beta = K p``).
    source : str
        The generated right-hand side (Python source compiled by numba).
    lane_friction : bool
        The drive friction is per lane, after beta (:func:`arm_plant`).
    flexible : bool
        Two-mass flexible joints with gearbox backlash (:func:`arm_plant`):
        state ``(q, qd, th, thd)`` (4 n), the encoders read the motor angles
        ``th`` (rows 2 n .. 3 n - 1).
    """

    model: object = None
    base: object = None
    source: str = field(default="", repr=False)
    lane_friction: bool = False
    flexible: bool = False

    @property
    def n_joints(self) -> int:
        """Active joints n (motor currents, encoders)."""
        return self.model.n_joints

    @property
    def parameter_names(self) -> tuple:
        """Names of the lane parameters, in order (:meth:`lane_parameters`)."""
        names = tuple(self.base.names)
        j = self.model.joint_names
        if self.flexible:
            names += tuple(f"{w}_{a}" for w in ("K", "D", "Ia", "b") for a in j)
        if self.lane_friction:
            names += tuple(f"{w}_{a}" for a in j for w in ("viscous", "coulomb_pos", "coulomb_neg"))
        return names

    @property
    def n_parameters(self) -> int:
        """Per-lane parameters: r base parameters, then 4 n joint constants when
        ``flexible``, then 3 n friction with ``lane_friction``."""
        n = self.n_joints
        return self.base.rank + (4 * n if self.flexible else 0) + (3 * n if self.lane_friction else 0)

    @property
    def motor_inertia_columns(self) -> np.ndarray:
        """How each reflected motor inertia ``Ia_j = Jm_j k_j^2`` enters beta, shape (n, r).

        Row j is ``K`` of the regrouping ``beta = K p``
        (:class:`~plant.robot.robot_model.BaseParameterSet`) times the way
        ``Ia_j`` enters the model's parameters p
        (:meth:`~plant.robot.robot_model.RobotModel.motor_inertia_columns`:
        the column of ``Ia<j>`` among the standard parameters, or, for a
        model in a named basis, that basis' definition in the chain's
        standard parameters): the rigid-equivalent beta of a flexible arm
        is its link's beta plus ``Ia @ columns``.
        """
        cols = np.asarray(self.base.K, dtype=float) @ self.model.motor_inertia_columns()
        return np.ascontiguousarray(cols.T)

    def lane_parameters(self, B, rig=None) -> np.ndarray:
        """Per-lane parameter array of candidates ``B`` (m, n_parameters), one row each.

        Parameters
        ----------
        B : array_like, shape (m, n_parameters) or (n_parameters,)
            Base parameters beta per candidate -- the rigid-equivalent ones
            (link plus reflected motor inertias) also for a flexible arm;
            then, with ``flexible``, per joint the spring stiffness K (N
            m/rad), damping D (N m s/rad), reflected motor inertia ``Ia = Jm
            k^2`` (kg m^2) and backlash width b (rad), each a block of n;
            then, with ``lane_friction``, the joint-side friction (per joint
            viscous, Coulomb +, Coulomb -; on the motor for a flexible arm).
        rig : ignored
            (The rig's friction is the plant's; kept for the :class:`Plant` protocol.)

        Returns
        -------
        ndarray, shape (n_parameters, m)
            For a flexible arm the first r rows hold the link's beta
            (``beta - Ia @`` :attr:`motor_inertia_columns`).

        Raises
        ------
        ValueError
            On a wrong shape or NaN/inf.
        """
        B = np.atleast_2d(np.asarray(B, dtype=np.float64))
        r = self.n_parameters
        if B.ndim != 2 or B.shape[1] != r:
            raise ValueError(f"base parameters must have shape (n_candidates, {r}), got {B.shape}")
        if not np.all(np.isfinite(B)):
            raise ValueError("base parameters contain NaN or inf")
        P = np.array(B.T, order="C")
        if self.flexible:
            nb, n = self.base.rank, self.n_joints
            P[:nb] -= self.motor_inertia_columns.T @ B[:, nb + 2 * n:nb + 3 * n].T
        return P


    @property
    def dynamics_function(self) -> ca.Function:
        """casadi ``(sc, qd, beta) -> (D lower triangle, n)`` of the arm (the plant's own expressions).

        ``sc = (sin q_1, cos q_1, ..., sin q_n, cos q_n)``; the first output
        holds ``D(q)``'s lower triangle row by row (n (n + 1) / 2,), the
        second the Coriolis/centrifugal plus gravity torques ``n(q, qd)``
        (n,) in N m, both for base parameters beta (r,).
        """
        fn = _DYNAMICS.get(type(self.kind))
        if fn is None:
            fn = _DYNAMICS[type(self.kind)] = _dynamics_function(self.model, self.base)
        return fn

    @property
    def kernels(self):
        """The robot's generated module (:mod:`plant.simulation.generated`).

        It holds the kind class, the right-hand side ``rhs``, the dynamics
        kernel ``dynamics`` and the drivers compiled for this robot
        (``logged_run``, ``hold_and_advance``), with numba's on-disk cache.
        """
        return sys.modules[type(self.kind).__module__]

    @property
    def dynamics_kernel(self):
        """:attr:`dynamics_function` compiled by numba: ``(sc, qd, beta) -> (lower, n)``.

        ``sc`` (2 n,), ``qd`` (n,) and ``beta`` (r,) float arrays; ``lower``
        (n (n + 1) / 2,) and ``n`` (n,) new arrays.  The casadi function's
        instructions in its own order (:func:`plant.robot.codegen.function_source`),
        so the numbers are the casadi function's, at a few microseconds a
        call instead of a hundred -- for a controller's law, which evaluates
        its model several times a sample.  Compiled (or loaded from numba's
        cache) on the first access in a process, not at its first call.
        """
        fn = self.kernels.dynamics
        if not fn.signatures:
            n, r = self.n_joints, self.base.rank
            fn(np.zeros(2 * n), np.zeros(n), np.zeros(r))
        return fn

    @property
    def base_regressor_function(self) -> ca.Function:
        """casadi ``(sc, qd, qdd) -> Y`` (n, r): the regressor of the base parameters.

        ``tau = Y(q, qd, qdd) beta`` is the plant's inverse dynamics
        (:attr:`dynamics_function`: ``D(q) qdd + n(q, qd)``), ``sc`` as there.
        Derived from the same expressions: ``Y = d tau / d beta``.
        """
        fn = _BASE_REGRESSOR.get(type(self.kind))
        if fn is None:
            fn = _BASE_REGRESSOR[type(self.kind)] = _base_regressor_function(self.model, self.base)
        return fn

    def base_regressor(self, q, qd, qdd) -> np.ndarray:
        """The base parameters' regressor at many states, time-first: shape (m, n, r).

        ``tau_k = Y[k] @ beta`` (N m) is the rigid arm's inverse dynamics at
        state k (Gautier 1990: the base regressor is the standard one's
        independent columns, the dependent ones regrouped into them).

        Parameters
        ----------
        q, qd, qdd : array_like, shape (m, n)
            Joint angles (rad), rates (rad/s) and accelerations (rad/s^2).

        Raises
        ------
        ValueError
            Arrays that are not (m, n) of the plant's n joints.
        """
        n = self.n_joints
        arrs = [np.asarray(v, dtype=float) for v in (q, qd, qdd)]
        if any(a.ndim != 2 or a.shape[1] != n or a.shape != arrs[0].shape for a in arrs):
            raise ValueError(f"q, qd and qdd must have the same shape (m, {n}), got "
                             f"{[a.shape for a in arrs]}")
        m, r = arrs[0].shape[0], self.base.rank
        if m == 0:
            return np.zeros((0, n, r))
        fn = self.base_regressor_function.map(m)
        Y = np.asarray(fn(sin_cos(arrs[0]).T, arrs[1].T, arrs[2].T))
        # map() puts the (n, r) blocks side by side: [Y(s0) | Y(s1) | ...]
        return Y.reshape(n, m, r).transpose(1, 0, 2)

    def inverse_dynamics(self, q, qd, qdd, beta) -> np.ndarray:
        """The rigid arm's joint torques ``D(q) qdd + n(q, qd)`` at many states (N m), shape (m, n).

        Evaluated by the generated module's ``dynamics_batch``:
        :attr:`dynamics_kernel` (the plant's own expressions, compiled; the
        same numbers as ``base_regressor(q, qd, qdd) @ beta`` to rounding)
        state by state in one compiled loop.

        Parameters
        ----------
        q, qd, qdd : array_like, shape (m, n)
            Joint angles (rad), rates (rad/s) and accelerations (rad/s^2).
        beta : array_like, shape (r,)
            Base parameters.

        Raises
        ------
        ValueError
            Arrays of the wrong shape.
        """
        n, r = self.n_joints, self.base.rank
        q, qd, qdd = (np.asarray(v, dtype=float) for v in (q, qd, qdd))
        beta = np.ascontiguousarray(beta, dtype=float)
        if any(a.ndim != 2 or a.shape[1] != n or a.shape != q.shape for a in (q, qd, qdd)) \
                or beta.shape != (r,):
            raise ValueError(f"q, qd, qdd must be (m, {n}) and beta ({r},), got "
                             f"{q.shape}, {qd.shape}, {qdd.shape}, {beta.shape}")
        if q.shape[0] == 0:
            return np.zeros((0, n))
        lower, tau = self.kernels.dynamics_batch(np.ascontiguousarray(sin_cos(q)),
                                                 np.ascontiguousarray(qd), beta)
        return tau + np.einsum("mjk,mk->mj", symmetric_from_lower(lower, n), qdd)

    def beta(self, p=None) -> np.ndarray:
        """Base parameters of standard parameters ``p`` (default the model's own), shape (r,).

        Parameters
        ----------
        p : array_like, shape (n_std,), optional
        """
        p = self.model.standard_parameters() if p is None else p
        return self.base(p)


def _tau_of_beta(model, base):
    """casadi SX ``tau(sc, qd, qdd; beta)`` of a model's base parameters, with its symbols.

    Returns ``(tau, sc, qd, qdd, beta)``: ``sc = (sin q_1, cos q_1, ..., sin q_n,
    cos q_n)``.  Derived once per model and set of independent columns (kept on
    the model: every :func:`arm_plant` call, the dynamics and the regressor
    functions ask for it).
    """
    cache = model.__dict__.setdefault("_arm_tau_of_beta", {})
    key = None if base.independent is None else tuple(int(col) for col in base.independent)
    if key in cache:  # tau depends on the base only through its independent columns
        return cache[key]
    _, qd, qdd, p = model._symbols
    s, c = model._trig_symbols
    n = model.n_joints
    beta = ca.SX.sym("beta", base.rank)
    if base.independent is None:
        raise ValueError("the arm plant needs the QR base parameters (RobotModel.base_parameters())")
    # Y p = Y[:, independent] beta for every p: take the p that holds beta in the independent
    # columns and zeros elsewhere (the Newton-Euler graph at that p, zeros folded away)
    p_beta = [0] * p.shape[0]
    for k, col in enumerate(base.independent):
        p_beta[int(col)] = beta[k]
    tau_b = ca.substitute(model._tau_sc, p, ca.vertcat(*p_beta))
    sc = ca.vertcat(*[v for k in range(n) for v in (s[k], c[k])])
    out = (_shorter_form(model, tau_b, s, c, (qd, qdd, beta)), sc, qd, qdd, beta)
    cache[key] = out
    return out


def _shorter_form(model, tau, s, c, symbols):
    """``tau`` or its multiple-angle form (:func:`plant.robot.codegen.multiple_angle_form`),
    whichever casadi evaluates in fewer instructions.

    A named basis' torque (:class:`plant.robot.robot_model.BasisModel`, e.g.
    the paper's f1..f9) is its author's closed form and is kept as written.
    """
    from plant.robot.robot_model import BasisModel

    if isinstance(model, BasisModel):
        return tau
    syms = [s, c] + list(symbols)
    size = ca.Function("tau", syms, [ca.cse(tau) if hasattr(ca, "cse") else tau]).n_instructions()
    alt = multiple_angle_form(tau, s, c, symbols, max_terms=size)
    if alt is None or ca.Function("tau", syms, [alt]).n_instructions() >= size:
        return tau
    return alt


def _dynamics_function(model, base) -> ca.Function:
    """casadi ``(sc, qd, beta) -> (D lower triangle row by row, n)`` of a model's base parameters."""
    tau_b, sc, qd, qdd, beta = _tau_of_beta(model, base)
    n = model.n_joints
    D = ca.jacobian(tau_b, qdd)
    nvec = ca.substitute(tau_b, qdd, ca.SX.zeros(n))
    lower = ca.vertcat(*[D[j, k] for j in range(n) for k in range(j + 1)])
    outs = [ca.densify(lower), ca.densify(nvec)]
    if hasattr(ca, "cse"):
        outs = [ca.cse(o) for o in outs]
    return ca.Function("arm_dynamics", [sc, qd, beta], outs)


def _base_regressor_function(model, base) -> ca.Function:
    """casadi ``(sc, qd, qdd) -> Y (n, r)``: the regressor of the base parameters, ``tau = Y beta``."""
    tau_b, sc, qd, qdd, beta = _tau_of_beta(model, base)
    Y = ca.densify(ca.jacobian(tau_b, beta))  # tau is linear in beta: Y holds no beta
    if hasattr(ca, "cse"):
        Y = ca.cse(Y)
    return ca.Function("arm_base_regressor", [sc, qd, qdd], [Y])


def symmetric_from_lower(lower, n) -> np.ndarray:
    """Symmetric (n, n) matrices from their lower triangles given row by row.

    The layout of :attr:`ArmPlant.dynamics_function`'s first output (``D(q)``).
    A -0.0 comes out as 0.0.

    Parameters
    ----------
    lower : array_like, shape (..., n (n + 1) / 2)
        Lower triangles, row by row (``D11, D21, D22, D31, ...``).
    n : int
        Matrix size.

    Returns
    -------
    ndarray, shape (..., n, n)
    """
    lower = np.asarray(lower, dtype=float)
    il = np.tril_indices(n)
    out = np.zeros(lower.shape[:-1] + (n, n))
    out[..., il[0], il[1]] = lower
    out[..., il[1], il[0]] = lower
    return out + 0.0


def sin_cos(q) -> np.ndarray:
    """``(sin q_1, cos q_1, ..., sin q_n, cos q_n)`` per state: the arm kernels' ``sc`` input.

    Parameters
    ----------
    q : array_like, shape (..., n)
        Joint angles (rad), the joints along the last axis.

    Returns
    -------
    ndarray, shape (..., 2 n)
    """
    q = np.asarray(q, dtype=float)
    return np.stack([np.sin(q), np.cos(q)], axis=-1).reshape(q.shape[:-1] + (2 * q.shape[-1],))


def _dynamics_source(code) -> str:
    """Source of ``dynamics(in0, in1, in2) -> (lower, nvec)`` (:attr:`ArmPlant.dynamics_kernel`).

    ``code`` is :func:`plant.robot.codegen.function_source` of :func:`_dynamics_function`.
    """
    lines, (lower, nvec) = code
    src = (["def dynamics(in0, in1, in2):"] + lines
           + [f"    lower = np.empty({len(lower)})"]
           + [f"    lower[{k}] = {v}" for k, v in enumerate(lower)]
           + [f"    nvec = np.empty({len(nvec)})"]
           + [f"    nvec[{k}] = {v}" for k, v in enumerate(nvec)]
           + ["    return lower, nvec"])
    return "\n".join(src) + "\n"


#: The smallest pivot magnitude the generated right-hand side divides by (the smallest
#: positive normal double): ``v = 1 / max(abs(d), TINY_PIVOT)``.  A pivot d <= 0 makes
#: the margin <= 0 and the step is not taken; dividing by its magnitude keeps that
#: lane's stages finite and near its anchors, so it is settled in the SIMD loop like
#: the others instead of going the libm path of far lanes.
TINY_PIVOT = 2.2250738585072014e-308


def _rhs_source(model, base, code, lane_friction=False, flexible=False) -> str:
    """Python source of the arm's right-hand side ``rhs(p, c, x, u, sc)`` (:mod:`plant.simulation.core`).

    With ``lane_friction`` the joint-side friction of joint j is the lane's
    ``p[o + 3 j : o + 3 j + 3]`` (viscous, Coulomb for positive and for
    negative rate; ``o`` after beta and the flexible joints) instead of the
    rig's.  With ``flexible``, Spong's two-mass joint with backlash per
    joint (:func:`arm_plant`): the link is driven by the spring torque, the
    motor by the current, its friction and the spring's reaction.  ``code`` is
    :func:`plant.robot.codegen.function_source` of :func:`_dynamics_function`.
    """
    n = model.n_joints
    r = base.rank
    lines, (Dl, nv) = code
    src = ["def rhs(p, c, x, u, sc):",
           "    in0 = sc",
           "    in1 = (" + "".join(f"x[{n + j}], " for j in range(n)) + ")",
           "    in2 = p"]
    src += lines
    o = r + (4 * n if flexible else 0)
    for j in range(n):
        fr = (f"p[{o + 3 * j}], p[{o + 3 * j + 1}], p[{o + 3 * j + 2}]" if lane_friction else
              f"c.viscous[{j}], c.coulomb_pos[{j}], c.coulomb_neg[{j}]")
        if flexible:  # spring torque through the gearbox dead zone, motor acceleration
            k_, d_, ia, b_ = (r + j, r + n + j, r + 2 * n + j, r + 3 * n + j)
            src.append(f"    dl{j} = x[{2 * n + j}] - x[{j}]")
            src.append(f"    hb{j} = 0.5 * p[{b_}]")
            src.append(f"    ts{j} = p[{k_}] * (dl{j} - min(max(dl{j}, -hb{j}), hb{j})) + "
                       f"p[{d_}] * (x[{3 * n + j}] - x[{n + j}])")
            src.append(f"    t{j} = ts{j} - {nv[j]}")
            src.append(f"    m{j} = (c.torque_per_amp[{j}] * u[{j}] + friction_torque(x[{3 * n + j}], "
                       f"{fr}, c.ramp_speed[{j}]) - ts{j}) / p[{ia}]")
        else:
            src.append(f"    t{j} = c.torque_per_amp[{j}] * u[{j}] + friction_torque(x[{n + j}], "
                       f"{fr}, c.ramp_speed[{j}]) - {nv[j]}")
    # unrolled square-root-free Cholesky D = L diag(d) L^T (D's lower triangle row by row;
    # unit L, pivots d; G. H. Golub and C. F. Van Loan, Matrix Computations, 4th ed.,
    # alg. 4.1.2): n divisions, no square root; then the two unit triangular solves
    idx = {}
    m = 0
    for j in range(n):
        for k in range(j + 1):
            idx[j, k] = Dl[m]
            m += 1
    for j in range(n):
        for k in range(j):  # W_jk = L_jk d_k
            acc = idx[j, k] + "".join(f" - W{j}_{i} * L{k}_{i}" for i in range(k))
            src.append(f"    W{j}_{k} = {acc}")
            src.append(f"    L{j}_{k} = W{j}_{k} * v{k}")
        src.append(f"    d{j} = {idx[j, j]}" + "".join(f" - W{j}_{i} * L{j}_{i}" for i in range(j)))
        # a pivot <= 0 is reported by the margin (the step is not taken); max and abs, not a
        # branch, keep the code branch-free, so it inlines into the SIMD lane loop
        # (plant.simulation.core, "Lanes"; TINY_PIVOT)
        src.append(f"    v{j} = 1.0 / max(abs(d{j}), {TINY_PIVOT!r})")
    for j in range(n):
        src.append(f"    y{j} = t{j}" + "".join(f" - L{j}_{i} * y{i}" for i in range(j)))
    for j in reversed(range(n)):
        src.append(f"    a{j} = y{j} * v{j}" + "".join(f" - L{i}_{j} * a{i}" for i in range(j + 1, n)))
    margin = "d0"
    for j in range(1, n):
        margin = f"min({margin}, d{j})"
    if flexible:  # a motor inertia <= 0 is no plant either
        for j in range(n):
            margin = f"min({margin}, p[{r + 2 * n + j}])"
    src.append(f"    margin = {margin}")
    tail = ("".join(f"x[{3 * n + j}], " for j in range(n)) + "".join(f"m{j}, " for j in range(n))
            if flexible else "")
    src.append("    return (" + "".join(f"x[{n + j}], " for j in range(n))
               + "".join(f"a{j}, " for j in range(n)) + tail + "), margin")
    return "\n".join(src) + "\n"


#: A right-hand side whose dynamics take at most this many casadi instructions is
#: inlined by numba at every RK4 stage (``_inline_always``), so the core's lane loop
#: vectorises (SIMD over the candidates); a longer one is left to LLVM, which calls it
#: (one lane at a time), since eight inlined copies per driver would take minutes to
#: compile.  Measured on the development machine (``benchmarks/bench_arm_kernels.py``):
#: the planar arm (84 instructions) and PUMA 560 joints 1-3 (316) vectorise; the
#: six-joint PUMA 560 (6053) inlined runs 6 times faster from 8 candidates on but
#: compiles for 226 s, against 19 s.  Raise it before building a plant to trade
#: compile time (once per robot: the disk cache keeps the kernels) for speed.
INLINE_MAX_INSTRUCTIONS = 1000


def _module_text(model, rhs_source, code, n_states, n_parameters, flexible) -> str:
    """The robot's generated module (:mod:`plant.simulation.generated`): kind, kernels, drivers.

    Its right-hand side (inlined into the drivers' lane loops up to
    :data:`INLINE_MAX_INSTRUCTIONS`) and dynamics kernel, and copies of the
    drivers :func:`plant.simulation.simulate.logged_run` and
    :func:`plant.simulation.core.hold_and_advance` compiled for its kind,
    all with numba's on-disk cache.
    """
    from plant.simulation.simulate import logged_run

    n = model.n_joints
    what = "two-mass flexible" if flexible else "rigid"
    return module_text(
        f"The {what} arm of {model.name} ({n} joints): its kernels, generated by "
        "plant.simulation.arm.arm_plant.",
        imports=["", "from plant.robot.model import friction_torque",
                 "from plant.simulation.plants import register_plant"],
        body=["class ArmKind(NamedTuple):",
              "    \"\"\"This robot's plant kind (its type selects :func:`rhs` in the core).\"\"\"",
              "", "    code: int", "", "",
              "@_inline_always" if len(code[0]) <= INLINE_MAX_INSTRUCTIONS else "@_inline", rhs_source,
              f"register_plant(ArmKind, rhs, {n_states}, {n_parameters}, n_inputs={n}, "
              f"n_angles={n})", "", "",
              "@_kernel", _dynamics_source(code), "",
              "@_kernel", _DYNAMICS_BATCH_SOURCE],
        copies=[(logged_run, "_kernel"), (hold_and_advance, "_kernel")])


#: Source of ``dynamics_batch(sc, qd, beta) -> (lower, nvec)``: :func:`dynamics` state by
#: state in one compiled loop (:meth:`ArmPlant.inverse_dynamics`), ``sc`` (m, 2 n), ``qd``
#: (m, n), m >= 1.
_DYNAMICS_BATCH_SOURCE = """def dynamics_batch(sc, qd, beta):
    m = sc.shape[0]
    first, nfirst = dynamics(sc[0], qd[0], beta)
    lower = np.empty((m, first.shape[0]))
    nvec = np.empty((m, nfirst.shape[0]))
    for k in range(m):
        a, b = dynamics(sc[k], qd[k], beta)
        lower[k, :] = a
        nvec[k, :] = b
    return lower, nvec
"""


_PLANTS: dict = {}
_DYNAMICS: dict = {}
#: The base regressor per robot kind (:attr:`ArmPlant.base_regressor_function`), built on first use.
_BASE_REGRESSOR: dict = {}


def arm_plant(model, base=None, *, lane_friction=False, flexible=False) -> ArmPlant:
    """A robot model's arm as a plant of the core (generated once per robot).

    Rigid (default), or with ``flexible=True`` Spong's two-mass joints with
    gearbox backlash, per joint j::

        Ia_j th_j'' = k_j Kt_j i_j + tau_f,j(th_j') - tau_s,j          (motor)
        D_link(q) q'' + n_link(q, q') = tau_s                           (link)
        tau_s,j = K_j (d_j - clip(d_j, -b_j / 2, b_j / 2)) + D_j (th_j' - q_j'),  d_j = th_j - q_j

    with ``th`` the motor angle divided by the gear ratio (what the encoder
    reads), ``D_link`` and ``n_link`` the rigid model without the reflected
    motor inertias ``Ia = Jm k^2`` (:attr:`ArmPlant.motor_inertia_columns`),
    and the drive friction on the motor.  Source: M. W. Spong, "Modeling and
    control of elastic joint robots", J. Dyn. Syst. Meas. Control 109 (1987);
    backlash as a dead zone: M. Nordin and P.-O. Gutman, Automatica 38
    (2002).  The PUMA 560 links 2-3 instance is
    :class:`plant.simulation.plants.FlexibleJoints`.

    Parameters
    ----------
    model : plant.robot.robot_model.RobotModel
        The robot (its active joints are the plant's joints).
    base : plant.robot.robot_model.BaseParameterSet, optional
        Its QR base parameters (default ``model.base_parameters()``).
    lane_friction : bool
        Take the joint-side drive friction per lane, as parameters after beta
        (per joint: viscous N m s/rad, Coulomb for positive and for negative
        rate N m; :attr:`ArmPlant.n_parameters` ``= r + 3 n``), for
        identifying it when the rig does not know it; else the rig's.
    flexible : bool
        Two-mass joints with backlash: the lane parameters get K, D, Ia and
        b per joint after beta (:meth:`ArmPlant.lane_parameters`), the state
        is ``(q, qd, th, thd)`` and the encoders read ``th``.

    Returns
    -------
    ArmPlant
        Registered in :data:`plant.simulation.plants.RIGHT_HAND_SIDES` under a kind of
        its own; the same robot (same generated code) gives the same plant.

    Raises
    ------
    ValueError
        If ``model`` is not a RobotModel, or ``base`` is a named basis.
    """
    from plant.robot.robot_model import RobotModel

    if not isinstance(model, RobotModel):
        raise ValueError(f"arm_plant needs a plant.RobotModel, got {type(model).__name__}")
    base = model.base_parameters() if base is None else base
    dynamics = _dynamics_function(model, base)
    code = function_source(dynamics, "g")  # its straight-line code, for rhs and dynamics kernel
    src = _rhs_source(model, base, code, lane_friction, flexible)
    key = hashlib.sha1(src.encode()).hexdigest()[:16]
    n = model.n_joints
    enc = 2 * n if flexible else 0
    if key in _PLANTS:
        old = _PLANTS[key]
        return ArmPlant(name=model.name, kind=old.kind, encoder_row=enc, model=model, base=base,
                        source=src, lane_friction=lane_friction, flexible=flexible)
    n_states = (4 if flexible else 2) * n
    n_par = base.rank + (4 * n if flexible else 0) + (3 * n if lane_friction else 0)
    module = load("arm", _module_text(model, src, code, n_states, n_par, flexible))
    kind_class = module.ArmKind
    _DYNAMICS.setdefault(kind_class, dynamics)  # derived once (ArmPlant.dynamics_function)
    plant = ArmPlant(name=model.name, kind=kind_class(0), encoder_row=enc, model=model, base=base,
                     source=src, lane_friction=lane_friction, flexible=flexible)
    _PLANTS[key] = plant
    return plant


def kernels_cached(model, base=None, *, lane_friction=False, flexible=False) -> bool:
    """Whether a robot's arm plant has compiled kernels in numba's on-disk cache.

    The generated module of ``arm_plant(model, base, lane_friction=...,
    flexible=...)`` (written now if it is not there) and
    :func:`plant.simulation.generated.compiled`: False means that the
    plant's first simulation compiles its kernels (tens of seconds for a new
    robot on a 2-core machine), which a command line says beforehand.

    Parameters
    ----------
    model : plant.robot.robot_model.RobotModel
    base : plant.robot.robot_model.BaseParameterSet, optional
    lane_friction, flexible : bool
        As :func:`arm_plant`.

    Returns
    -------
    bool
    """
    from .generated import compiled

    return compiled(arm_plant(model, base, lane_friction=lane_friction, flexible=flexible).kernels)


def link_mode_bound(log10_k, inertia) -> float:
    """Fastest link mode (rad/s): the largest ``w`` of ``det(diag(K) - w^2 D_link(q)) = 0``.

    Parameters
    ----------
    log10_k : array_like, shape (n,)
        log10 of the joint stiffnesses (N m/rad).
    inertia : array_like, shape (p, n, n)
        Link inertia matrices at p configurations (positive definite).

    Returns
    -------
    float
        The largest over the configurations.
    """
    k = np.sqrt(10.0 ** np.asarray(log10_k, dtype=float))
    D = np.asarray(inertia, dtype=float).reshape(-1, k.size, k.size)
    return math.sqrt(float(np.max(np.linalg.eigvalsh(k[:, None] * np.linalg.inv(D) * k[None, :])
                                  [:, -1])))



# ----------------------------------------------------------------------------
# Drivers
# ----------------------------------------------------------------------------
def reference_counts(trajectory, rig, n_samples) -> np.ndarray:
    """Unquantised reference counts ``q_ref(t_k) k N / 2 pi``, shape (n_samples, n).

    Parameters
    ----------
    trajectory : plant.Trajectory
    rig : plant.Rig
    n_samples : int
    """
    t = np.arange(int(n_samples)) * rig.sample_time_s
    return np.ascontiguousarray(trajectory.position(t) * rig.pulses_per_rad)


@dataclass(frozen=True)
class ArmSimulation:
    """Simulated runs of a batch of candidates on one rig (a driver's result).

    Attributes
    ----------
    errors : ndarray, shape (n_candidates, n_samples, n_joints) or None
        Experiment: the simulated tracking errors (pulses, integers; 0
        after a candidate failed or stopped); replay: the prediction errors
        ``m - c`` (pulses, continuous; ``bound`` after a candidate failed).
        None when not requested.
    objective : ndarray, shape (n_candidates,)
        Sum of squares from the first compared sample (experiment: output
        error, paper eq. 4, against the log; replay: prediction errors).
        A failed candidate (D not positive definite, a non-finite state, or
        a count beyond the bound) gets the PUMA 560 path's finite penalty
        (:mod:`plant.simulation.simulate`): its sum so far plus ``2 bound^2``
        per compared sample it did not reach -- larger than any candidate
        that stays within the bound, smaller the later it fails, so that a
        rank-based search still orders failed candidates; one stopped at the
        early-termination ``cap``: its running sum extrapolated to all
        compared samples (> cap).
    status : ndarray, shape (n_candidates,), int
        :data:`plant.simulation.core.STATUS_OK` or a failure code
        (:data:`plant.simulation.core.STATUS_STOPPED` at the cap).
    message : tuple of str
        Per candidate, ``"ok"`` or the failure and its time.
    final_state : ndarray, shape (n_candidates, n_states) or None
        With ``final_state=True``: each candidate's state at the last sample
        (the instant its encoders are read; the plant's layout, rad and
        rad/s), NaN for a candidate that failed or stopped.  None otherwise.
    """

    errors: np.ndarray | None
    objective: np.ndarray
    status: np.ndarray
    message: tuple
    final_state: np.ndarray | None = None


def _run(plant, B, rig, ref, e_log, i_log, *, replay, gain, substeps, errors, q0, qd0, k_start,
         bound, cap=None, workers=None, initial_state=None, controller=None, final_state=False):
    if not isinstance(plant, ArmPlant):
        raise ValueError(f"plant must be an ArmPlant (plant.simulation.arm.arm_plant), got {type(plant).__name__}")
    n = plant.n_joints
    if initial_state is not None and q0 is None and qd0 is None:
        q0 = qd0 = np.zeros(n)  # every lane starts from its own state
    c = rig_constants(rig, q0=q0, qd0=qd0)
    if len(c.pulses_per_rad) != n:
        raise ValueError(f"the rig has {len(c.pulses_per_rad)} joints, the robot {n}")
    Pall = plant.lane_parameters(B)
    m = Pall.shape[1]
    x0 = plant.initial_state(c)
    X0 = None
    if initial_state is not None:
        X0 = np.asarray(initial_state, dtype=float)
        if X0.shape not in ((x0.size,), (m, x0.size)) or not np.all(np.isfinite(X0)):
            raise ValueError(f"initial_state must be finite, shape ({x0.size},) or ({m}, {x0.size}), "
                             f"got {X0.shape}")
        X0 = np.ascontiguousarray(np.broadcast_to(X0, (m, x0.size)))
    elif not np.all(np.isfinite(x0)):
        raise ValueError("the rig has no start state: give q0 and qd0")
    ref = np.ascontiguousarray(ref, dtype=float)
    nt = ref.shape[0]
    e_log = np.zeros((nt, n)) if e_log is None else np.ascontiguousarray(e_log, dtype=float)
    i_log = np.zeros((nt, n)) if i_log is None else np.ascontiguousarray(i_log, dtype=float)
    if ref.shape != (nt, n) or e_log.shape != (nt, n) or i_log.shape != (nt, n):
        raise ValueError(f"reference, errors and currents must have shape (n_samples, {n})")
    substeps = int(substeps)
    if substeps < 1:
        raise ValueError(f"substeps must be >= 1, got {substeps}")
    bound = float(bound) if bound is not None else 1e12
    if not bound > 0:
        raise ValueError(f"bound must be positive, got {bound}")
    cap = math.inf if cap is None else float(cap)
    if math.isnan(cap):
        raise ValueError("cap must be a number (or None), got NaN")
    out = np.zeros((m if errors else 0, nt if errors else 0, n))
    obj = np.zeros(m)
    status = np.zeros(m, dtype=np.int64)
    compared = np.zeros(m, dtype=np.int64)
    final = np.full((m, x0.size), np.nan) if final_state else None

    law = P_LAW if controller is None else controller
    make = getattr(law, "logged_controller", None)
    takes = inspect.signature(make).parameters if callable(make) else {}
    if not isinstance(law, LoggedController) and "n_samples" in takes:
        # e.g. a ctc.arm.ArmComputedTorque: its law for this run, with this plant when it takes one
        law = make(nt, plant=plant) if "plant" in takes else make(nt)
    if not isinstance(law, LoggedController):
        raise ValueError("controller must be a plant.simulation.controllers.LoggedController "
                         "(a compiled law), an object with logged_controller(n_samples) (an "
                         f"arm's controller), or None, got {type(controller).__name__}")
    law.check_joints(n)
    law.check_samples(nt)
    law.check_start(0)
    # the logged-run driver compiled for this robot, or the law's own copy (a law generated
    # per robot); its in-memory twin for a law defined outside the library, which the
    # on-disk cache must not name
    run = for_kinds(plant.kernels.logged_run if law.driver is None else law.driver, plant.kind,
                    law.kind, law.parameters)
    k_cmp = int(k_start)
    if not 0 <= k_cmp <= nt:
        raise ValueError(f"k_start must be within 0..{nt}, got {k_start}")

    def chunk(lo, hi):  # one chunk of candidates in its own lanes (the kernel releases the GIL)
        lanes = new_lanes(Pall, lo, hi, x0, n_inputs=n, n_angles=n)
        if X0 is not None:
            lanes.X[:] = X0[lanes.idx].T
        # the logged data from sample 0 (k0 = 0), compared from k_start on
        run(plant.kind, lanes, c, int(plant.encoder_row), ref, e_log, 0, k_cmp, 0, substeps,
            bool(replay), True, float(gain), bound, cap, out, bool(errors), False, obj, status,
            compared, hi - lo, law.kind, law.parameters, law.lane_states(lanes.X.shape[1]),
            i_log, True)
        if final is not None:
            # the running lanes are the first columns, with their states at the last sample;
            # a retired lane's column became padding, a stale copy of a running lane's (the
            # first column of a candidate is its own)
            done = set()
            for j in range(hi - lo):
                cand = int(lanes.idx[j])
                if cand not in done and status[cand] == STATUS_OK:
                    final[cand] = lanes.X[:, j]
                done.add(cand)

    # the arm's lanes cost per lane: two threads as soon as there is more than one SIMD block
    run_chunks(chunk, m, workers, block=LANE_PAD)
    msgs = tuple("ok" if s == STATUS_OK else
                 f"{STATUS_MESSAGES[int(s)]} at t = {k * rig.sample_time_s:.4f} s"
                 for s, k in zip(status, compared))
    if final is not None:
        final[status != STATUS_OK] = np.nan
    return ArmSimulation(errors=(out if errors else None), objective=obj, status=status, message=msgs,
                         final_state=final)


def simulate_arm(plant, B, rig, trajectory, n_samples, *, e_log=None, substeps=ARM_SUBSTEPS,
                 errors=True, q0=None, qd0=None, k_start=0, bound=None, cap=None,
                 workers=None, controller=None, final_state=False) -> ArmSimulation:
    """Simulate the logged P-control experiment of an arm for candidates ``B``.

    At each sample ``t_k = k Ts`` the motor encoders are read
    (``act = trunc(q k N / 2 pi)``), the integer error ``e = trunc(q_ref k N
    / 2 pi) - act`` sets the current ``i = P e`` (clipped at the drive's
    full scale), held over the sample while the core advances the arm
    (``substeps`` RK4 steps; :func:`plant.simulation.core.advance_sample`).

    Parameters
    ----------
    plant : ArmPlant
        The robot (:func:`arm_plant`).
    B : array_like, shape (m, r) or (r,)
        Base parameters per candidate.
    rig : plant.Rig
        Rig constants (per-joint tuples of n entries).
    trajectory : plant.Trajectory
        Reference of the n joints.
    n_samples : int
        Samples from t = 0.
    e_log : array_like, shape (n_samples, n), optional
        Logged errors (pulses) for the output error (default zeros).
    substeps : int
        RK4 steps per sample.
    errors : bool
        Return the simulated errors.
    q0, qd0 : array_like, shape (n,), optional
        Start state (default the rig's).
    k_start : int
        First sample of the output error (the run and its errors start at
        t = 0).
    bound : float, optional
        Divergence bound on ``abs(ref - c)`` (pulses): a candidate beyond it
        fails with the penalty of :class:`ArmSimulation`.  Default: with
        ``e_log``, the PUMA 560 path's
        (:func:`plant.simulation.simulate.default_bound`: 100 times the
        largest logged error, at least 100 pulses); without, 1e12.
    cap : float, optional
        Early termination (as :func:`plant.simulate_batch`): a candidate
        whose running output error passes ``cap`` (pulses^2) after a
        compared sample stops there (status
        :data:`plant.simulation.core.STATUS_STOPPED`, objective its running
        sum times compared samples / samples compared so far, > cap).
        Default: none.
    workers : int, optional
        Threads (default: the CPUs this process may use); candidates are
        split into one chunk per thread.
    controller : plant.simulation.controllers.LoggedController or controller, optional
        The compiled control law in the loop instead of the rig's P law: any
        law registered with
        :func:`plant.simulation.controllers.register_control_law`, called
        every sample with every joint's measured angle and pulse error
        (``law(lp, c, k, Y, E, CS, U, j)``); it must write all n joints'
        currents (the driver clips them at the drive's full scale).  Or a
        controller with a ``logged_controller(n_samples[, plant])`` method,
        e.g. a :class:`ctc.arm.ArmComputedTorque` or
        :class:`ctc.arm.ArmFlexibleComputedTorque` (its computed torque,
        compiled, in the loop of every candidate robot ``B``: the
        controller's model stays its own).
    final_state : bool
        Also return each candidate's state at the last sample
        (``ArmSimulation.final_state``).

    Returns
    -------
    ArmSimulation

    Raises
    ------
    ValueError
        Wrong shapes, a rig of another joint count, no start state, a
        non-positive bound, a NaN cap, a ``k_start`` outside the run, or a
        ``controller`` that is not a compiled law, writes another number of
        joints (:meth:`~plant.simulation.controllers.LoggedController.check_joints`)
        or whose tables are shorter than the run.
    """
    ref = reference_counts(trajectory, rig, n_samples)
    if bound is None and e_log is not None:
        bound = default_bound(e_log)
    return _run(plant, B, rig, ref, e_log, None, replay=False, gain=0.0, substeps=substeps,
                errors=errors, q0=q0, qd0=qd0, k_start=k_start, bound=bound, cap=cap,
                workers=workers, controller=controller, final_state=final_state)


def replay_arm(plant, B, rig, ref, e_log, i_log, *, gain, substeps=ARM_SUBSTEPS, errors=True,
               q0=None, qd0=None, k_start=0, bound=None, workers=None,
               initial_state=None, final_state=False) -> ArmSimulation:
    """One-step-ahead predictor of a logged run: logged current plus output injection.

    The current ``i_log + P gain (m - c)`` is held over each sample, with
    ``m`` the centre of the count cell the logged error allows and ``c`` the
    continuous count of the simulated arm; the prediction errors ``m - c``
    (pulses) are smooth in the parameters (the refinement's residuals,
    :mod:`identification.arm`).

    Parameters
    ----------
    plant : ArmPlant
    B : array_like, shape (m, r) or (r,)
    rig : plant.Rig
    ref : array_like, shape (n_samples, n)
        Unquantised reference counts (:func:`reference_counts`).
    e_log, i_log : array_like, shape (n_samples, n)
        Logged errors (pulses) and currents (A).
    gain : float
        Output-injection gain (fraction of the P gain).
    substeps, errors, q0, qd0, k_start, workers
        As :func:`simulate_arm` (the logged input drives the arm from t = 0;
        the prediction errors are summed from ``k_start`` on).
    bound : float, optional
        Divergence bound on ``abs(ref - c)`` (pulses; default 1e12): a
        candidate beyond it fails (penalty of :class:`ArmSimulation`; its
        remaining prediction errors are ``bound``).
    initial_state : array_like, shape (m, n_states) or (n_states,), optional
        Each candidate's own start state (the plant's state layout: ``(q,
        qd)``, then the motors' ``(th, thd)`` of a two-mass arm; rad,
        rad/s), instead of ``q0``, ``qd0`` for all -- a window's start state
        refined per candidate (:class:`identification.arm_payload.ArmPayloadProblem`).
        A lane's numbers do not depend on the other lanes of its batch.
    final_state : bool
        Also return each candidate's state at the last sample
        (``ArmSimulation.final_state``): the predictor as a state estimator,
        e.g. the loaded arm's link state a flexible-joint controller takes
        over when its model changes
        (:func:`identification.arm_payload.replay_arm_state`).

    Returns
    -------
    ArmSimulation

    Raises
    ------
    ValueError
        As :func:`simulate_arm`; an ``initial_state`` of another shape or not finite.
    """
    return _run(plant, B, rig, ref, e_log, i_log, replay=True, gain=gain, substeps=substeps,
                errors=errors, q0=q0, qd0=qd0, k_start=k_start, bound=bound, workers=workers,
                initial_state=initial_state, final_state=final_state)
