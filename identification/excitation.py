"""Excitation design: a reference trajectory that identifies a robot's base parameters.

:func:`design_excitation` returns a :class:`plant.Trajectory` in the
sidecar's form (``c``, ``terms_A_omega_phi``, ``t_ramp_s``) that starts at
rest at the rig's start state, stays within joint, rate and current limits
and minimises the predicted relative standard error of the *worst*
determined parameter (a minimax, "E-like" criterion on relative errors: the
quantity the acceptance of a design is judged on, and the one a user reads
in the result's ``f_rse``).

The robot is the PUMA 560 links 2--3 of the paper (f1..f9, the closed
forms of :mod:`plant.robot.model`) by default, or any robot model
(``model=``: a :class:`plant.RobotModel` from a DH table or a URDF, e.g. an
:class:`~plant.logs.arm_log.ArmLog`'s ``model``): the same family, limits,
criterion and search, its regressor and inverse dynamics those of its arm
plant (:meth:`plant.simulation.arm.ArmPlant.base_regressor`,
:meth:`~plant.simulation.arm.ArmPlant.inverse_dynamics`) in its base
parameters beta, and the prediction-error criterion that of
:func:`identification.arm.identify_arm`'s refinement.

Trajectory family
-----------------
Per joint j a finite Fourier series of ``n_harmonics`` harmonics of the run,
``q_j = w(t) (c_j + sum_l A_jl cos(l omega_f t + phi_jl))``,
``omega_f = 2 pi / duration`` (J. Swevers, C. Ganseman, D. B. Tukel,
J. De Schutter, H. Van Brussel, "Optimal robot excitation and
identification", IEEE Trans. Robot. Autom. 13, 1997), band-limited far below
the P loop's ~10 Hz mode.  The start at rest:

* start state q0 = 0 (the PUMA rigs): the quintic ramp ``w`` of
  :mod:`plant.logs.trajectory` (``t_ramp_s``, default ``min(0.3 s, duration / 5)``)
  gives q(0) = 0, qd(0) = 0, qdd(0) = 0 with free offsets and phases;
* any other q0: no ramp, phases 0 or pi (signed amplitudes: qd(0) = 0) and
  ``c_j = q0_j - sum_l A_jl`` (q(0) = q0).

Limits (checked on a grid of the reference: 2 ms for the PUMA 560 links
2--3, ``max(2 ms, duration / 500)`` for a robot model): the joint range
(default: the paper trajectory's, ``[-pi/2, 0]`` for the first joint and
``[0, pi/2]`` for the second, on the PUMA 560 links 2--3 -- the default
robot, or a model whose base parameters are f1..f9; a quarter turn each
way of the start state on any other robot), the rate (default none) and the
current the rigid model needs along the reference, ``(Y(q, qd, qdd) f -
tau_friction(qd)) / (k Kt)``, at ``f_prior`` (default the centre of the
rig's search box; a robot model without one: its own base parameters, from
its DH table or URDF) kept below ``CURRENT_MARGIN`` times the drive's full
scale (the P loop's tracking transients come on top of the feed-forward
current; friction the sidecar leaves unknown, ``null``, counts at the
``friction_prior`` given, else as zero).

Criterion and why
-----------------
The predicted standard errors of the default identification are those of
its refinement: the Gauss-Newton covariance ``sigma^2 (J^T J)^-1`` of the
logged-input prediction errors (:mod:`identification.refinement`), ``J`` their
sensitivity to f, ``sigma^2 = 1/12`` pulse^2 (encoder quantisation).  That
needs an emulated log and 10 replays per candidate (~0.5 s); the search
instead minimises the same criterion computed from the information matrix of
the *regressor* along the reference, ``Y^T Y`` (:func:`plant.robot.model.regressor`,
or a robot model's base regressor; equation error of constant variance),
~0.3 ms per candidate on the PUMA 560 links 2--3, and the
``RERANK`` best distinct candidates of the GA's final population are then
ranked by the prediction-error criterion (:func:`predicted_f_std`), which
also gives ``predicted_f_std``.  Measured (``benchmarks/bench_excitation.py
--agreement``) over random feasible trajectories on the drill/flex rig: the
two criteria's Spearman rank correlation is 0.95 over 12 random feasible
trajectories (``docs/optimisers.rst``).  Relative errors are taken relative to
``max(|f_prior|, 5 % of the search range)`` (a parameter near zero in the
prior still gets a finite scale); without a search range (a robot model
whose sidecar gives none) ``max(|f_prior|, 5 % of the rms of |f_prior|)``.

Unknown friction: the identification estimates the components a sidecar
leaves ``null`` with the base parameters (the paper: "if unknown, have to be
included as unknown parameters"), so both criteria count them as nuisance
parameters -- their regressor columns
(:func:`identification.friction.joint_friction_columns`) join the
information matrix, and the prediction-error Jacobian (the arm emulated at
``friction_prior``; on the PUMA 560 links 2--3, through its instance
``RobotModel.puma560_links23``); the minimax is over the base parameters
alone.

The search is the project's GA (:func:`identification.ga.run_ga`, Gray-coded,
4 x 20 individuals).  A candidate outside the limits is repaired, not
penalised: its amplitudes are scaled by the largest factor in [0, 1] that
keeps it within them (bisection), and when the start ramp to its offsets
alone breaks them (from q = 0, a move across the range in ``t_ramp_s``),
its offsets first by the largest such factor towards the start state; at
factors 0 the reference holds the start state.  (Scaling the amplitudes
alone left most random individuals of a three-joint arm from rest
infeasible, and the GA searched among a few.)

The GA's best is then *polished*: SLSQP (scipy) from it on the regressor
criterion, the limits as smooth inequality constraints on the grid (angles,
rates, feed-forward current) instead of the repair -- whose bisection makes
the repaired criterion piecewise flat, so that a derivative-free polish of
it stalls -- and the minimax smoothed to the ``POLISH_P``-norm of the
relative standard errors; kept when the repaired criterion improves.  What
the two changes did on the independent simulator's draws is in
:doc:`tutorial_your_robot` (section 13, ``benchmarks/bench_arm_excitation.py``).
Weighting each joint's torque rows by the inverse of its drive's
newton-metres per pulse (``|k| Kt P``, the P loop's conversion of a torque
error into a pulse error) was tried on two development draws and did not
do better, so the rows are not weighted.
"""
from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np

import plant
from plant.robot.model import friction_torques, regressor
from plant.logs.rig import F_NAMES, rig_constants

from .friction import friction_layout, joint_friction_columns

__all__ = ["design_excitation", "predicted_f_std", "trajectory_limits", "regressor_rse",
           "DEFAULT_HARMONICS", "CURRENT_MARGIN", "POLISH_P", "POLISH_ITER"]

#: Harmonics per joint of a designed trajectory.
DEFAULT_HARMONICS = 3
#: The feed-forward current of the reference is kept below this fraction of the limit.
CURRENT_MARGIN = 0.8
#: Candidates of the GA's final population re-ranked by the prediction-error criterion.
RERANK = 6
#: Grid step of the limit checks and the regressor criterion (s).
GRID_S = 0.002
#: Floor of a parameter's scale in the relative errors, fraction of its search range.
SCALE_FLOOR = 0.05
#: Bisection steps of the amplitude factor that brings a candidate within the limits.
REPAIR_STEPS = 10
#: Variance of the prediction errors at the true f: uniform quantisation (pulse^2).
QUANTISATION_VAR = 1.0 / 12.0


def _paper_range():
    q = math.pi / 2
    return np.array([[-q, 0.0], [0.0, q]])


def _scale(f_prior, bounds):
    if bounds is None:  # no search box: a floor from the prior's own size
        return np.maximum(np.abs(f_prior), SCALE_FLOOR * math.sqrt(np.mean(f_prior ** 2)))
    return np.maximum(np.abs(f_prior), SCALE_FLOOR * (bounds[:, 1] - bounds[:, 0]))


class _Robot:
    """What a design needs of its robot: the regressor and inverse dynamics along a reference.

    ``model`` None: the PUMA 560 links 2--3 of :mod:`plant.robot.model`
    (f1..f9, the closed forms); else a robot model (or its rigid arm plant),
    through :func:`plant.simulation.arm.arm_plant`.
    """

    def __init__(self, rig, model=None, *, gravity=None, friction_prior=None):
        self.rig = rig
        self.c = None if rig is None else rig_constants(rig)
        self.unknown, self.friction = [], None
        if model is None:
            self.plant, self.names, self.n = None, F_NAMES, 2
            self.gravity = self.c.gravity if gravity is None else float(gravity)
            self.box = rig.bounds if rig is not None and rig.f_bounds else None
            self.paper = True
        else:
            self._model(rig, model)
        if rig is not None:
            self._friction(rig, friction_prior)

    def _friction(self, rig, prior):
        """Joint-side friction (n, 3): the rig's, its unknown components from ``prior`` (or 0)."""
        known, self.unknown = friction_layout(rig)
        self.friction = known.copy()
        if prior is None:
            return
        prior = np.asarray(prior, dtype=float)
        if prior.shape != (self.n, 3) or not np.all(np.isfinite(prior)) or np.any(prior < 0):
            raise ValueError(f"friction_prior must be ({self.n}, 3) finite values >= 0 (joint "
                             f"side: viscous N m s/rad, Coulomb + and - N m), got shape "
                             f"{prior.shape}")
        for j, w in self.unknown:
            self.friction[j, w] = prior[j, w]

    def friction_columns(self, qd):
        """The unknown friction components' regressor columns along the states, (m n, u).

        :func:`identification.friction.joint_friction_columns`: the identification
        estimates them with the base parameters, nuisance parameters here.
        """
        cols = joint_friction_columns(qd, self.c.ramp_speed, self.unknown)
        return cols.reshape(qd.shape[0] * self.n, -1)

    def _model(self, rig, model):
        from plant.robot.robot_model import RobotModel
        from plant.simulation.arm import ArmPlant, arm_plant

        from .arm import rig_search_box

        if isinstance(model, ArmPlant):
            pl = model if not (model.flexible or model.lane_friction) else \
                arm_plant(model.model, model.base)
        elif isinstance(model, RobotModel):
            pl = arm_plant(model)
        else:
            raise ValueError(f"model must be a plant.RobotModel (or its arm plant), got "
                             f"{type(model).__name__}")
        self.plant, self.names, self.n = pl, tuple(pl.base.names), pl.n_joints
        if len(rig.gear_ratio) != self.n:
            raise ValueError(f"the rig has {len(rig.gear_ratio)} joints, the robot model "
                             f"{self.n} ({', '.join(pl.model.joint_names)})")
        self.box = rig_search_box(rig, pl.base)
        self.paper = self.names == F_NAMES  # the PUMA 560 links 2-3 instance

    @property
    def r(self) -> int:
        """Base parameters."""
        return len(self.names)

    def default_limits(self, q0):
        """The paper trajectory's range (PUMA 560 links 2-3), else q0 +- pi/4."""
        if self.paper:
            return _paper_range()
        return np.column_stack([q0 - math.pi / 4, q0 + math.pi / 4])

    def default_prior(self):
        """The centre of the search box, else the model's own base parameters."""
        if self.box is not None:
            return self.box.mean(axis=1)
        return self.plant.beta()

    def regressor(self, q, qd, qdd):
        """Stacked regressor along the states, (m n, r)."""
        if self.plant is None:
            return regressor(q, qd, qdd, self.gravity).reshape(-1, 9)
        return self.plant.base_regressor(q, qd, qdd).reshape(-1, self.r)

    def torque(self, q, qd, qdd, f):
        """Rigid inverse dynamics along the states, (m, n) N m."""
        if self.plant is None:
            return regressor(q, qd, qdd, self.gravity) @ f
        return self.plant.inverse_dynamics(q, qd, qdd, f)

    def grid(self, duration_s):
        """Time step of the limit checks and the regressor criterion (s)."""
        return GRID_S if self.plant is None else max(GRID_S, float(duration_s) / 500.0)


class _Family:
    """The trajectory family: x (searched, in a box) -> Trajectory."""

    def __init__(self, q0, duration, n_harmonics, limits, t_ramp_s):
        self.q0 = np.asarray(q0, dtype=float)
        self.n = self.q0.shape[0]
        self.L = int(n_harmonics)
        self.duration = float(duration)
        self.omega = 2 * math.pi * np.arange(1, self.L + 1) / self.duration
        self.ramp = bool(np.all(self.q0 == 0.0))
        self.t_ramp = (min(0.3, self.duration / 5) if t_ramp_s is None else float(t_ramp_s)) \
            if self.ramp else 0.0
        half = 0.5 * (limits[:, 1] - limits[:, 0])
        rows = []
        for j in range(self.n):
            # amplitudes fall off with the harmonic (same peak acceleration share)
            amax = half[j] / np.arange(1, self.L + 1)
            if self.ramp:
                rows += [[limits[j, 0], limits[j, 1]]]
                rows += [[0.0, a] for a in amax] + [[-math.pi, math.pi]] * self.L
            else:
                rows += [[-a, a] for a in amax]
        self.bounds = np.array(rows)

    def scaled(self, x, s):
        """``x`` with its offsets and amplitudes scaled by ``s`` (see :meth:`trajectory`).

        The point whose unscaled reference is ``trajectory(x, s)``.
        """
        so, sa = (1.0, s) if np.ndim(s) == 0 else s
        z = np.array(x, dtype=float)
        k = 0
        for _ in range(self.n):
            if self.ramp:
                z[k] *= so
                z[k + 1:k + 1 + self.L] *= sa
                k += 1 + 2 * self.L
            else:
                z[k:k + self.L] *= sa
                k += self.L
        return z

    def trajectory(self, x, s=1.0):
        """The reference of ``x``; ``s`` scales its amplitudes, or ``(s_offset, s_amplitude)``.

        ``s_offset`` (ramp family only) scales the offsets towards the start
        state 0: at ``(0, 0)`` the reference holds the start state.
        """
        z = self.scaled(x, s)
        c, terms, k = [], [], 0
        for j in range(self.n):
            if self.ramp:
                cj = z[k]
                amp = z[k + 1:k + 1 + self.L]
                ph = z[k + 1 + self.L:k + 1 + 2 * self.L]
                k += 1 + 2 * self.L
            else:
                amp = z[k:k + self.L]
                ph = np.zeros(self.L)
                cj = self.q0[j] - amp.sum()
                k += self.L
            c.append(float(cj))
            terms.append([(float(a), float(w), float(p)) for a, w, p in zip(amp, self.omega, ph)])
        return plant.Trajectory.from_terms(c, terms, self.t_ramp)


def trajectory_limits(trajectory, duration_s, rig, f, *, joint_limits_rad=None,
                      max_velocity_rad_s=None, max_current_A=None, grid_s=None, model=None,
                      friction_prior=None):
    """Peak excursions of a reference and its normalised limit violation.

    Parameters
    ----------
    trajectory : plant.Trajectory
        The reference (n joints).
    duration_s : float
        Length of the run (s).
    rig : plant.logs.rig.Rig
        Gear, torque constants, friction and gravity of the current check.
    f : array_like, shape (r,)
        Base parameters of the rigid model's inverse dynamics (f1..f9 by
        default; the model's base parameters with ``model``).
    joint_limits_rad : array_like, shape (n, 2), optional
        ``[[q_min, q_max], ...]`` per joint (rad); default the paper
        trajectory's range on the PUMA 560 links 2--3, else the start state
        +- pi/4 (module docstring).
    max_velocity_rad_s : float or array_like (n,), optional
        Rate limit per joint (default none).
    max_current_A : float or array_like (n,), optional
        Current limit (default the rig's ``current_full_scale_A``; none if
        the rig gives none).
    grid_s : float, optional
        Time step of the check (s); default 2 ms, for a robot model
        ``max(2 ms, duration_s / 500)``.
    model : plant.RobotModel, optional
        The robot (default the PUMA 560 links 2--3 of :mod:`plant.robot.model`).
    friction_prior : array_like, shape (n, 3), optional
        Joint-side friction of the components the rig leaves unknown
        (default 0; :func:`design_excitation`).

    Returns
    -------
    dict
        ``q_min``, ``q_max``, ``qd_max``, ``i_max`` (feed-forward current,
        A), each (n,), and ``violation`` (>= 0; 0 when every limit holds,
        the current against ``CURRENT_MARGIN`` times its limit).

    Raises
    ------
    ValueError
        A model that is not a robot model or does not match the rig's joints, or a
        malformed friction prior.
    """
    robot = _Robot(rig, model, friction_prior=friction_prior)
    q0 = np.zeros(robot.n) if rig.q0_rad is None else np.asarray(rig.q0_rad, float)
    lim = robot.default_limits(q0) if joint_limits_rad is None else \
        np.asarray(joint_limits_rad, float)
    grid = robot.grid(duration_s) if grid_s is None else float(grid_s)
    t = np.arange(0.0, float(duration_s) + 1e-12, grid)
    q, qd, qdd = trajectory.evaluate(t)
    return _limits(robot, q, qd, qdd, np.asarray(f, float), lim,
                   _per_joint(max_velocity_rad_s, robot.n),
                   _per_joint(rig.current_full_scale_A if max_current_A is None
                              else max_current_A, robot.n))


def _per_joint(v, n):
    return None if v is None else np.broadcast_to(np.asarray(v, dtype=float), (n,))


def _current(robot, q, qd, qdd, f):
    """Feed-forward current of the rigid model along the states, (m, n) A (signed)."""
    c, fr = robot.c, robot.friction
    tau = robot.torque(q, qd, qdd, f) - friction_torques(
        qd, fr[:, 0], fr[:, 1], fr[:, 2], c.ramp_speed)
    return tau / np.asarray(c.torque_per_amp, dtype=float)


def _limits(robot, q, qd, qdd, f, lim, vmax, imax):
    i = np.abs(_current(robot, q, qd, qdd, f))
    out = dict(q_min=q.min(0), q_max=q.max(0), qd_max=np.abs(qd).max(0), i_max=i.max(0))
    span = lim[:, 1] - lim[:, 0]
    v = np.sum(np.maximum(lim[:, 0] - out["q_min"], 0) / span)
    v += np.sum(np.maximum(out["q_max"] - lim[:, 1], 0) / span)
    if vmax is not None:
        v += np.sum(np.maximum(out["qd_max"] / vmax - 1.0, 0))
    if imax is not None:
        v += np.sum(np.maximum(out["i_max"] / (CURRENT_MARGIN * imax) - 1.0, 0))
    out["violation"] = float(v)
    return out


def regressor_rse(trajectory, duration_s, f_scale, *, g=9.81, grid_s=None, model=None, rig=None):
    """Relative standard errors from the regressor's information matrix (up to one factor).

    ``sqrt(diag((Y^T Y)^-1)) / f_scale`` with Y the regressor stacked along
    the reference on a ``grid_s`` grid: the errors of least squares on the
    inverse dynamic model with an equation error of unit variance.  Only
    ratios between trajectories mean something.

    Parameters
    ----------
    trajectory : plant.Trajectory
        The reference (n joints).
    duration_s : float
        Length of the run (s).
    f_scale : array_like, shape (r,)
        Scale of each parameter (its prior magnitude).
    g : float
        Gravity (m/s^2) of the PUMA 560 links 2--3's closed forms (a robot
        model carries its own).
    grid_s : float, optional
        Time step (s); default as :func:`trajectory_limits`.
    model : plant.RobotModel, optional
        The robot (default the PUMA 560 links 2--3: f1..f9).
    rig : plant.logs.rig.Rig, optional
        The rig of ``model`` (needed with it: its joint count is checked).

    Returns
    -------
    ndarray, shape (r,)

    Raises
    ------
    ValueError
        A model without its rig, or one that does not match it.
    """
    if model is not None and rig is None:
        raise ValueError("regressor_rse needs the rig with a robot model (rig=)")
    robot = _Robot(rig, model, gravity=g)
    grid = robot.grid(duration_s) if grid_s is None else float(grid_s)
    t = np.arange(0.0, float(duration_s) + 1e-12, grid)
    q, qd, qdd = trajectory.evaluate(t)
    return _rse_from_states(robot, q, qd, qdd, np.asarray(f_scale, float))


def _rse_from_states(robot, q, qd, qdd, scale):
    r = scale.shape[0]
    Y = robot.regressor(q, qd, qdd) * scale
    if robot.unknown:  # unknown friction: nuisance columns, each of unit norm
        F = robot.friction_columns(qd)
        norm = np.linalg.norm(F, axis=0)
        Y = np.hstack([Y, F / np.where(norm > 0, norm, 1.0)])
    try:
        M = np.linalg.inv(Y.T @ Y)
    except np.linalg.LinAlgError:
        return np.full(r, np.inf)
    d = np.diag(M)[:r]
    return np.where(d > 0, np.sqrt(np.abs(d)), np.inf)


def _template(rig, name="excitation", path="excitation.csv"):
    """A two-sample log carrying the rig (template of :func:`plant.emulate_log`)."""
    from plant.logs.log import ExperimentLog

    z = np.zeros((2, 2))
    traj = plant.Trajectory.paper()
    return ExperimentLog(path=Path(path), name=name, t=np.array([0.0, rig.sample_time_s]),
                         q_ref=z, e_pulses=np.zeros((2, 2), dtype=np.int64), i_A=z,
                         rig=rig, trajectory=traj).replace()


def predicted_f_std(rig, trajectory, duration_s, f, *, flexible=None, base=None,
                    substeps=None, workers=None, model=None, friction_prior=None):
    """Predicted standard errors of the default identification on a trajectory.

    Emulates the P experiment at ``f`` (:func:`plant.emulate_log`, optionally
    on flexible joints; with ``model``, :func:`plant.simulation.synthetic.emulate_arm_log`
    on the robot model's rigid arm), then forms the forward-difference
    Jacobian of the refinement's prediction errors at ``f``
    (:class:`~identification.refinement.PredictionErrorProblem`, the
    identification's substeps; with ``model``,
    :class:`~identification.arm.ArmPredictionErrorProblem`, the arm
    refinement's) and returns ``sqrt(diag(sigma^2 (J^T J)^-1))`` with
    ``sigma^2`` the mean square prediction error at ``f`` (quantisation:
    ~1/12 pulse^2 on a rigid plant).

    Parameters
    ----------
    rig : plant.logs.rig.Rig
        The rig.
    trajectory : plant.Trajectory
        The reference (n joints).
    duration_s : float
        Length of the run (s).
    f : array_like, shape (r,)
        The robot's base parameters (a prior, or the truth in a benchmark):
        f1..f9, or the model's base parameters with ``model``.
    flexible : plant.FlexibleJoints, optional
        Emulate flexible joints (PUMA 560 links 2--3 only); the replay is
        then the same flexible plant (its joint constants known: the errors
        of f alone).
    base : plant.ExperimentLog, optional
        Template of the emulated log (default: a minimal one from ``rig``;
        PUMA 560 links 2--3 only).
    substeps : int, optional
        RK4 substeps of the replay (default the identification's).
    workers : int, optional
        Threads of the simulation.
    model : plant.RobotModel, optional
        The robot (default the PUMA 560 links 2--3 of :mod:`plant.robot.model`).
    friction_prior : array_like, shape (n, 3), optional
        Joint-side friction (viscous N m s/rad, Coulomb + and - N m) of the
        components the rig leaves unknown (``null``), at which the P
        experiment is emulated (default 0); those components are then
        estimated with the base parameters (nuisance parameters), as the
        identification does.  On the PUMA 560 links 2--3 (no ``model``)
        the prediction then runs through the instance's robot model
        (``RobotModel.puma560_links23``, the same prediction to 1e-3 at the
        same substeps); with ``flexible`` or ``base`` the unknown components
        are held at 0 and ``friction_prior`` is not used.

    Returns
    -------
    ndarray, shape (r,)
        Predicted standard errors of the base parameters.

    Raises
    ------
    ValueError
        A failed emulation, or ``flexible``/``base`` with a robot model.
    """
    if model is not None:
        if flexible is not None or base is not None:
            raise ValueError("flexible= and base= are for the PUMA 560 links 2-3 path; with a "
                             "robot model the design's emulation is its rigid arm")
        return _predicted_arm_std(_Robot(rig, model, friction_prior=friction_prior), trajectory,
                                  duration_s, f, substeps=substeps, workers=workers)
    if rig.unknown_friction and flexible is None and base is None:
        # the identification estimates the unknown friction with f: through the PUMA 560
        # links 2-3 instance's arm plant, whose prediction is this path's (to 1e-3 at the
        # same substeps, tests/test_excitation.py), its components are nuisance parameters
        from plant.logs.arm_log import links23_model

        return _predicted_arm_std(_Robot(rig, links23_model(rig), friction_prior=friction_prior),
                                  trajectory, duration_s, f, substeps=substeps, workers=workers)
    from .objective import IDENTIFICATION_SUBSTEPS
    from .refinement import FD_STEP, PredictionErrorProblem

    f = np.asarray(f, dtype=float).reshape(9)
    base = _template(rig) if base is None else base
    log = plant.emulate_log(base, f, rig=rig, trajectory=trajectory, duration_s=duration_s,
                            flexible=flexible, name="excitation_prediction")
    prob = PredictionErrorProblem(log, substeps=IDENTIFICATION_SUBSTEPS if substeps is None
                                  else substeps, workers=workers, plant=flexible)
    h = FD_STEP * 1e2 * (rig.bounds[:, 1] - rig.bounds[:, 0])
    return _gauss_newton_std(prob, f, h)


def _gauss_newton_std(prob, f, h):
    """``sqrt(diag(sigma^2 (J^T J)^-1))`` of a prediction-error problem at f (forward differences h)."""
    X = np.vstack([f, f + np.diag(h)])
    R = prob.residuals(X)
    J = (R[1:] - R[0]).T / h
    sigma2 = max(float(np.mean(R[0] ** 2)), QUANTISATION_VAR)
    try:
        cov = sigma2 * np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        return np.full(f.shape[0], np.inf)
    return np.sqrt(np.maximum(np.diag(cov), 0.0))


def _predicted_arm_std(robot, trajectory, duration_s, f, *, substeps=None, workers=None):
    """:func:`predicted_f_std` on a robot model's rigid arm (emulated P log, arm refinement).

    Unknown friction (``null`` in the sidecar) is emulated at the robot's
    friction prior and estimated with beta, as :func:`identification.arm.identify_arm`
    does: its components are nuisance parameters of the Jacobian.
    """
    from plant.simulation.arm import ARM_SUBSTEPS, arm_plant
    from plant.simulation.synthetic import emulate_arm_log

    from .arm import ARM_REFINE_SUBSTEPS, ArmPredictionErrorProblem
    from .refinement import FD_STEP

    f = np.asarray(f, dtype=float).reshape(robot.r)
    rig = robot.rig
    n_samples = int(round(float(duration_s) / rig.sample_time_s)) + 1
    pl, row, x = robot.plant, f, f
    if robot.unknown:  # the friction per lane: the prior's in the emulation, estimated in the fit
        pl = arm_plant(robot.plant.model, robot.plant.base, lane_friction=True)
        row = np.concatenate([f, robot.friction.reshape(-1)])
        x = np.concatenate([f, [robot.friction[j, w] for j, w in robot.unknown]])
    # an in-memory log, never written: its sidecar names the robot by text (a URDF or
    # named-basis model has no inline DH table)
    log = emulate_arm_log(pl, row, rig, trajectory, n_samples, name="excitation_prediction",
                          substeps=ARM_SUBSTEPS, robot=robot.plant.model.name)
    prob = ArmPredictionErrorProblem(log, pl, workers=workers,
                                     substeps=ARM_REFINE_SUBSTEPS if substeps is None
                                     else int(substeps))
    # the step of the PUMA path (1e-4 of the search range), the range twice the scale without
    # one; a friction component's range twice its value (at least 0.01 N m s/rad or N m)
    width = (robot.box[:, 1] - robot.box[:, 0]) if robot.box is not None else \
        2.0 * _scale(f, None)
    width = np.concatenate([width, 2.0 * np.maximum(np.abs(x[robot.r:]), 1e-2)])
    return _gauss_newton_std(prob, x, FD_STEP * 1e2 * width)[:robot.r]


#: Exponent of the smooth maximum (a p-norm) of the relative standard errors in the polish.
POLISH_P = 16
#: SLSQP iterations of the polish.
POLISH_ITER = 60


def _polish(robot, fam, t, x, s, scale, f_prior, lim, vmax, imax):
    """SLSQP from the GA's best on the regressor criterion, the limits as constraints.

    The repaired criterion is piecewise flat in x (the repair's bisection);
    here the limits are smooth inequality constraints on the grid instead
    (angles within ``lim``, rates within ``vmax``, the feed-forward current
    within ``CURRENT_MARGIN imax``) and the minimax is smoothed to the
    ``POLISH_P``-norm of the relative standard errors.  Returns the polished
    x (None when SLSQP fails) and the criterion evaluations it took.
    """
    from scipy.optimize import minimize

    x0 = fam.scaled(x, s)
    span = lim[:, 1] - lim[:, 0]

    def states(z):
        return fam.trajectory(z, 1.0).evaluate(t)

    def obj(z):
        q, qd, qdd = states(z)
        rse = _rse_from_states(robot, q, qd, qdd, scale)
        if not np.all(np.isfinite(rse)):
            return 1e6
        m = np.max(rse)
        return float(np.log(m) + np.log(np.sum((rse / m) ** POLISH_P)) / POLISH_P)

    def cons(z):
        q, qd, qdd = states(z)
        out = [((q - lim[:, 0]) / span).ravel(), ((lim[:, 1] - q) / span).ravel()]
        if vmax is not None:
            out += [(1.0 - np.abs(qd) / vmax).ravel()]
        if imax is not None:
            i = np.abs(_current(robot, q, qd, qdd, f_prior))
            out += [(1.0 - i / (CURRENT_MARGIN * imax)).ravel()]
        return np.concatenate(out)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            res = minimize(obj, x0, method="SLSQP", bounds=fam.bounds,
                           constraints=[dict(type="ineq", fun=cons)],
                           options=dict(maxiter=POLISH_ITER))
        except (ValueError, np.linalg.LinAlgError):
            return None, 0
    z = np.clip(res.x, fam.bounds[:, 0], fam.bounds[:, 1])
    return (z if np.all(np.isfinite(z)) else None), int(res.nfev)


def _bisect(ok):
    """The largest factor in [0, 1) with ``ok(factor)``, given ``ok(0)`` and not ``ok(1)`` (bisection)."""
    lo, hi = 0.0, 1.0
    for _ in range(REPAIR_STEPS):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if ok(mid) else (lo, mid)
    return lo


def _repair(fam, feasible, x):
    """The factors ``(s_offset, s_amplitude)`` that bring ``x`` within the limits.

    The largest amplitude factor in [0, 1] within them; when the start ramp
    to the offsets alone breaks them (a move across the range in a fraction
    of a second), the largest offset factor first (towards the start state
    0; at ``(0, 0)`` the reference holds it).  ``feasible(x, s)`` checks
    the limits, at most once per factor tried; ``x`` is within them at the
    factors returned unless the amplitude factor is 0.
    """
    if feasible(x, (1.0, 1.0)):
        return 1.0, 1.0
    if not fam.ramp or feasible(x, (1.0, 0.0)):
        return 1.0, _bisect(lambda a: feasible(x, (1.0, a)))
    so = _bisect(lambda o: feasible(x, (o, 0.0)))
    if feasible(x, (so, 1.0)):
        return so, 1.0
    return so, _bisect(lambda a: feasible(x, (so, a)))


def design_excitation(rig, duration_s, *, joint_limits_rad=None, max_velocity_rad_s=None,
                      max_current_A=None, n_harmonics=DEFAULT_HARMONICS, rng=None,
                      f_prior=None, t_ramp_s=None, generations=None, rerank=RERANK,
                      workers=None, full_output=False, model=None, grid_s=None,
                      friction_prior=None, polish=True):
    """Design an excitation trajectory that identifies a robot's base parameters.

    Parameters
    ----------
    rig : plant.logs.rig.Rig
        The rig (start state, gears, encoders, P gains, friction, search box,
        current full scale), e.g. ``plant.load_log(path).rig``, or an
        :class:`~plant.logs.arm_log.ArmLog`'s ``rig`` with its ``model``.
    duration_s : float
        Length of the experiment (s).
    joint_limits_rad : array_like, shape (n, 2), optional
        ``[[q_min, q_max], ...]`` per joint (rad); default the paper
        trajectory's range ``[[-pi/2, 0], [0, pi/2]]`` on the PUMA 560
        links 2--3, the start state +- pi/4 on any other robot.  Must
        contain the start state.
    max_velocity_rad_s : float or array_like (n,), optional
        Joint rate limit (rad/s); default none.
    max_current_A : float or array_like (n,), optional
        Drive current limit (A); default the rig's ``current_full_scale_A``.
        The rigid model's feed-forward current along the reference at
        ``f_prior`` stays below ``CURRENT_MARGIN`` times it.
    n_harmonics : int
        Harmonics of ``2 pi / duration_s`` per joint (>= 1).
    rng : numpy.random.Generator or int, optional
        Random source of the GA.
    f_prior : array_like, shape (r,), optional
        Prior base parameters (current check, scales of the relative errors,
        linearisation point); default the centre of the rig's search box, or
        (a robot model without one) the model's own base parameters.
    t_ramp_s : float, optional
        Start ramp (s) when the start state is q = 0 (default
        ``min(0.3, duration_s / 5)``).
    generations : int, optional
        GA generations (4 x 20 individuals); default 30 on the PUMA 560
        links 2--3 (14 searched numbers), ``max(30, 2 g)`` for a robot
        model searching g numbers (``n (1 + 2 n_harmonics)`` from rest at
        q = 0): the regressor criterion of a three-joint arm with 6
        harmonics still improves markedly from 30 to 100 generations (0.80,
        0.67, 0.56 on a development draw of ``benchmarks/independent_arm.py``).
    rerank : int
        Best distinct GA candidates re-ranked by the prediction-error
        criterion (0: keep the GA's best, no simulation).
    polish : bool
        Polish the GA's best on the regressor criterion by SLSQP with the
        limits as constraints (module docstring) before the re-ranking.
    workers : int, optional
        Threads of the simulations.
    full_output : bool
        Also return the design's figures (scipy's convention).
    model : plant.RobotModel, optional
        The robot (n joints; module docstring); default the PUMA 560 links
        2--3 of :mod:`plant.robot.model` (f1..f9).
    grid_s : float, optional
        Time step of the limit checks and the regressor criterion (s);
        default 2 ms, ``max(2 ms, duration_s / 500)`` with a robot model.
        The design returned is checked again at the rig's sample time
        (and scaled down to the limits there if a peak between grid points
        passed one); ``info['limits']`` is of that check.
    friction_prior : array_like, shape (n, 3), optional
        Joint-side friction (viscous N m s/rad, Coulomb + and - N m) for
        the components the rig leaves unknown (``null``): in the current
        check and, with a robot model, the emulated P experiment of the
        prediction-error criterion (default 0; a P loop that relies on its
        friction for damping may not run without it -- then the design
        keeps the regressor criterion's best and says so).  Either way the
        unknown components are nuisance parameters of both criteria, as
        the identification estimates them with the base parameters.

    Returns
    -------
    trajectory : plant.Trajectory
        The design (``to_parameters()`` is the sidecar's
        ``trajectory.parameters``).
    info : dict
        Only with ``full_output``: ``names`` (the r parameters), ``f_scale``
        (r,) (each parameter's scale of the relative errors),
        ``predicted_f_std`` (r,) (prediction-error criterion at ``f_prior``;
        None with ``rerank=0``; inf when no candidate's emulated P
        experiment ran), ``predicted_f_rse``, ``regressor_rse``
        (relative, up to one factor), ``limits``
        (:func:`trajectory_limits`), ``f_prior``, ``nfev`` (regressor
        criterion evaluations: the GA's and the polish's), ``generations``,
        ``polished`` (the polish improved the GA's best), ``message``.

    Warns
    -----
    RuntimeWarning
        When the prediction-error criterion failed on every candidate (the
        design is then the regressor criterion's best).

    Raises
    ------
    ValueError
        On a bad duration, limits that exclude the start state, an unknown
        start state, a model that does not match the rig, or when no
        candidate satisfies the limits.
    """
    from .ga import run_ga

    if not (isinstance(duration_s, (int, float)) and math.isfinite(duration_s)
            and duration_s > 0):
        raise ValueError(f"duration_s must be a positive number, got {duration_s!r}")
    if int(n_harmonics) != n_harmonics or n_harmonics < 1:
        raise ValueError(f"n_harmonics must be an integer >= 1, got {n_harmonics!r}")
    robot = _Robot(rig, model, friction_prior=friction_prior)
    n, r = robot.n, robot.r
    if rig.q0_rad is None:
        raise ValueError("the rig has no start state (start_state.q_rad); a designed "
                         "trajectory starts at rest there")
    q0 = np.asarray(rig.q0_rad, dtype=float)
    if q0.shape != (n,):
        raise ValueError(f"the rig's start state has {q0.size} angles, the robot {n} joints")
    lim = robot.default_limits(q0) if joint_limits_rad is None else \
        np.asarray(joint_limits_rad, float)
    if lim.shape != (n, 2) or not np.all(np.isfinite(lim)) or np.any(lim[:, 0] >= lim[:, 1]):
        raise ValueError(f"joint_limits_rad must be {n} rows [q_min, q_max] (one per joint) "
                         f"with min < max, got {joint_limits_rad!r}")
    if np.any(q0 < lim[:, 0] - 1e-12) or np.any(q0 > lim[:, 1] + 1e-12):
        raise ValueError(f"the start state q0 = {q0.tolist()} lies outside joint_limits_rad")
    vmax = _per_joint(max_velocity_rad_s, n)
    imax = _per_joint(rig.current_full_scale_A if max_current_A is None else max_current_A, n)
    for name, v in (("max_velocity_rad_s", vmax), ("max_current_A", imax)):
        if v is not None and not np.all(np.isfinite(v) & (v > 0)):
            raise ValueError(f"{name} must be positive, got {v.tolist()}")
    grid = robot.grid(duration_s) if grid_s is None else float(grid_s)
    if not (math.isfinite(grid) and 0 < grid < float(duration_s)):
        raise ValueError(f"grid_s must lie in (0, duration_s), got {grid_s!r}")
    bounds = robot.box
    f_prior = robot.default_prior() if f_prior is None else np.asarray(f_prior, float)
    if f_prior.shape != (r,) or not np.all(np.isfinite(f_prior)):
        raise ValueError(f"f_prior must be {r} finite numbers ({', '.join(robot.names)}), "
                         f"got shape {f_prior.shape}")
    scale = _scale(f_prior, bounds)
    fam = _Family(q0, duration_s, n_harmonics, lim, t_ramp_s)
    if generations is None:
        generations = 30 if model is None else max(30, 2 * fam.bounds.shape[0])
    t = np.arange(0.0, float(duration_s) + 1e-12, grid)
    nfev = [0]

    def states(x, s, at=t):
        return fam.trajectory(x, s).evaluate(at)

    def feasible(x, s, at=t):
        q, qd, qdd = states(x, s, at)
        return _limits(robot, q, qd, qdd, f_prior, lim, vmax, imax)["violation"] == 0.0

    def repair(x):
        return _repair(fam, feasible, x)

    def evaluate(X):
        out = np.empty(X.shape[0])
        for m, x in enumerate(X):
            s = repair(x)
            if s[1] <= 0.0:  # else within the limits at s (_repair)
                out[m] = np.inf
                continue
            q, qd, qdd = states(x, s)
            out[m] = float(np.log(np.max(_rse_from_states(robot, q, qd, qdd, scale))))
        nfev[0] += X.shape[0]
        return out

    ga = run_ga(evaluate, fam.bounds, n_gen=int(generations), rng=rng, gray=True,
                bits=16)
    x_best, polished = ga.x, False
    if polish and np.isfinite(ga.fun):
        xp, nfev_polish = _polish(robot, fam, t, ga.x, repair(ga.x), scale, f_prior, lim,
                                  vmax, imax)
        nfev[0] += nfev_polish
        if xp is not None and evaluate(xp[None, :])[0] < ga.fun:
            x_best, polished = xp, True
    order = np.argsort(ga.population_energies) if ga.population is not None else None
    cands = [x_best]
    if order is not None:
        for i in order:
            x = ga.population[i]
            if not np.isfinite(ga.population_energies[i]):
                break
            if all(np.max(np.abs(x - y) / np.ptp(fam.bounds, axis=1)) > 1e-3 for y in cands):
                cands.append(x)
            if len(cands) >= max(int(rerank), 1):
                break
    if not np.isfinite(evaluate(np.asarray(cands[:1]))[0]):
        raise ValueError("no trajectory within the limits was found; widen the limits, "
                         "lengthen the run or raise the generations")
    best, best_std = cands[0], None
    if rerank > 0:
        scores = []
        for x in cands:
            try:
                sd = predicted_f_std(rig, fam.trajectory(x, repair(x)), duration_s, f_prior,
                                     workers=workers, model=model, friction_prior=robot.friction)
            except ValueError:
                sd = np.full(r, np.inf)
            scores.append((float(np.max(sd / scale)), sd))
        k = int(np.argmin([s for s, _ in scores]))
        best, best_std = cands[k], scores[k][1]
        if not np.isfinite(scores[k][0]):
            message = ("the prediction-error criterion failed on every candidate (the emulated "
                       "P experiment did not run at the prior"
                       + ("; give friction_prior=" if robot.unknown else "")
                       + "): the design is the regressor criterion's best")
            warnings.warn(message, RuntimeWarning, stacklevel=2)
        else:
            message = "designed; ranked by the prediction-error criterion"
    else:
        message = "designed; the regressor criterion's best (rerank=0)"
    # the limits were checked on the design's grid; the reference runs at the rig's samples,
    # where a peak between grid points can pass a limit (a planar arm's design by 4.5e-5 rad
    # at 4 ms): the chosen candidate's factors are found again on the rig's sample grid
    t_fine = np.arange(0.0, float(duration_s) + 1e-12, min(grid, float(rig.sample_time_s)))
    factors = repair(best)
    if not feasible(best, factors, t_fine):
        factors = _repair(fam, lambda x, s: feasible(x, s, t_fine), best)
    traj = fam.trajectory(best, factors)
    q, qd, qdd = traj.evaluate(t)
    info = dict(
        names=robot.names, f_scale=scale,
        predicted_f_std=best_std,
        predicted_f_rse=None if best_std is None else best_std / scale,
        regressor_rse=_rse_from_states(robot, q, qd, qdd, scale),
        limits=_limits(robot, *traj.evaluate(t_fine), f_prior, lim, vmax, imax),
        f_prior=f_prior, nfev=nfev[0], generations=int(generations), candidates=len(cands),
        polished=polished, message=message)
    return (traj, info) if full_output else traj


# ------------------------------------------------------------------ command line
def _parser():
    import argparse

    ap = argparse.ArgumentParser(
        prog="python -m identification.excitation",
        description="Design an excitation trajectory for the rig of a sidecar (writes "
                    "{'trajectory': {'parameters', 'duration_s'}, 'predicted_f_std'}); a "
                    "sidecar with a 'robot' object designs for that robot model.")
    ap.add_argument("sidecar", help="the rig's JSON sidecar (STEM.json)")
    ap.add_argument("--duration-s", type=float, required=True, help="length of the run (s)")
    ap.add_argument("--seed", type=int, default=None, help="seed of the GA")
    ap.add_argument("--output", required=True, help="JSON file to write")
    ap.add_argument("--n-harmonics", type=int, default=DEFAULT_HARMONICS,
                    help=f"harmonics per joint (default {DEFAULT_HARMONICS})")
    ap.add_argument("--generations", type=int, default=None,
                    help="GA generations (default 30 on the PUMA 560 links 2-3, more for a robot "
                         "model with more searched numbers: design_excitation's rule)")
    ap.add_argument("--max-current", type=float, default=None,
                    help="current limit (A; default the sidecar's current_full_scale_A)")
    ap.add_argument("--max-velocity", type=float, default=None,
                    help="joint rate limit (rad/s; default none)")
    ap.add_argument("--joint-limits", type=float, nargs="+", default=None,
                    metavar="QMIN QMAX",
                    help="joint range, a min and a max per joint (rad; default the paper "
                         "trajectory's on the PUMA 560 links 2-3, else the start state +- pi/4)")
    ap.add_argument("--friction-prior", type=float, nargs="+", default=None,
                    metavar="V C+ C-",
                    help="joint-side friction guess for the components the sidecar leaves null: "
                         "viscous (N m s/rad), Coulomb + and - (N m) per joint, 3 numbers a joint "
                         "(default 0)")
    ap.add_argument("--workers", type=int, default=None, help="simulation threads")
    return ap


def _per_joint_rows(values, n, k, flag, what):
    """A flag's numbers as (n, k) rows, k per joint (None when not given); a wrong count: one line."""
    if values is None:
        return None
    if len(values) != k * n:
        raise ValueError(f"{flag} takes {what} per joint: {k * n} numbers for {n} joints, "
                         f"got {len(values)}")
    return np.reshape(values, (n, k))


def _finite_or_none(v):
    v = float(v)
    return v if math.isfinite(v) else None


def main(argv=None):
    """Command line: ``python -m identification.excitation SIDECAR.json --duration-s ...``.

    Parameters
    ----------
    argv : list of str, optional
        Arguments without the program name (default ``sys.argv[1:]``).

    Returns
    -------
    int
        Exit status: 0, or 1 after a one-line error (argparse usage errors
        exit with 2).
    """
    import json
    import sys

    from plant.logs.arm_log import arm_rig, is_arm_sidecar
    from plant.logs.fileio import write_text_atomic
    from plant.logs.sidecar import read_sidecar, rig_from_sidecar

    args = _parser().parse_args(argv)
    try:
        if not (math.isfinite(args.duration_s) and args.duration_s > 0):
            raise ValueError(f"--duration-s must be a positive number, got {args.duration_s}")
        path = Path(args.sidecar)
        sidecar = read_sidecar(path)
        model = None
        if is_arm_sidecar(sidecar):
            model, rig = arm_rig(sidecar, path)
        else:
            rig = rig_from_sidecar(sidecar, source=path)
        n = len(rig.gear_ratio)
        lim = _per_joint_rows(args.joint_limits, n, 2, "--joint-limits", "a min and a max")
        friction = _per_joint_rows(args.friction_prior, n, 3, "--friction-prior", "3 numbers")
        with warnings.catch_warnings():  # a failed prediction: its message is printed below
            warnings.simplefilter("ignore", RuntimeWarning)
            traj, info = design_excitation(
                rig, args.duration_s, joint_limits_rad=lim, max_velocity_rad_s=args.max_velocity,
                max_current_A=args.max_current, n_harmonics=args.n_harmonics, rng=args.seed,
                generations=args.generations, workers=args.workers, full_output=True,
                model=model, friction_prior=friction)
        lims = info["limits"]
        out = {
            "trajectory": {"parameters": traj.to_parameters(),
                           "duration_s": float(args.duration_s)},
            "parameter_names": list(info["names"]),
            # null where the prediction failed (no candidate's emulated run: the message says so)
            "predicted_f_std": [_finite_or_none(v) for v in info["predicted_f_std"]],
            "predicted_f_rse": [_finite_or_none(v) for v in info["predicted_f_rse"]],
            "message": info["message"],
            "f_prior": [float(v) for v in info["f_prior"]],
            "peak_feedforward_current_A": [float(v) for v in lims["i_max"]],
            "q_range_rad": [[float(a), float(b)] for a, b in zip(lims["q_min"], lims["q_max"])],
            "seed": args.seed,
        }
        write_text_atomic(args.output, json.dumps(out, indent=2) + "\n")
    except KeyboardInterrupt:
        print("error: interrupted (nothing written)", file=sys.stderr)
        return 130
    except (ValueError, OSError) as e:  # LogError and OutputFileError are ValueErrors
        msg = " ".join(str(e).split())
        print(f"error: {msg}", file=sys.stderr)
        return 1
    rse = 100 * np.asarray(info["predicted_f_rse"])
    if not np.all(np.isfinite(rse)):
        print(f"wrote {args.output}: {info['message']}")
        return 0
    print(f"wrote {args.output}: predicted max relative standard error {rse.max():.2f} % "
          f"({', '.join(f'{a} {v:.2f}' for a, v in zip(info['names'], rse))})")
    return 0


if __name__ == "__main__":
    import sys

    sys.exit(main())
