"""A payload on any arm's last link, identified from a window of encoder pulses.

The paper's on-line proposal (sec. 5: identify a carried load from a
100-200 ms window and feed it to the computed-torque controller) for a
robot model of n joints (:class:`plant.robot.robot_model.RobotModel`): the
arm's base parameters are known (``prior``, e.g. an
:func:`identification.arm.identify_arm` result of the unloaded arm), and a
rigid payload fixed to the chain's last link shifts them by a vector linear
in its standard parameters (``beta = prior + K dp``,
:meth:`~plant.robot.robot_model.RobotModel.payload_delta`; Khalil &
Dombre, *Modeling, Identification and Control of Robots*, 2002, sec. 9.3).
The search is over the payload as a point mass, ``x = [m, cx, cy, cz]``
(kg, and its centre of mass in the last link's frame, m -- Robotics
Toolbox's ``payload(m, p)`` frame for a DH table): a window of a tenth of
a second determines the mass and first moment, not a payload's own
inertia about its centre of mass, which is left out (an extended tool's
inertia is absorbed by its centre of mass estimate).

The residuals are the arm's logged-input predictor's
(:func:`plant.simulation.arm.replay_arm`, as :func:`identification.arm.identify_arm`'s
refinement): the arm driven by the current the drive applied over the
window plus a weak output injection must keep its continuous encoder count
in the count cells the logged errors allow (pulses).  The window's start
state is refined with the payload as nuisance parameters: per joint the
rate (its guess the reference's rate minus the logged error's slope) and
the angle within the count cell of the first logged error (+-0.5 pulse
about its centre; on the independent planar arm of the tests, fixing it
at the centre left 0.2 s windows up to 10 % off in mass, refining it
brings them within 2 %).  The applied current is
the rig's P law on the logged errors (a P-control log, exact) or the
controller's own logged commands (``currents="logged"``: a
computed-torque run, where the controller knows what it commanded).

A **flexible prior** (an :func:`identification.arm.identify_arm` result with
``model == "flexible"``) is searched through its two-mass arm
(:func:`plant.simulation.arm.arm_plant` with ``flexible=True``; its springs,
dampers, reflected motor inertias and backlash held at the identified
values): the payload loads the link, whose base parameters move by the same
``K dp``.  The encoders read the motors, so the refined start angles and
rates are the motors'; the links start where the springs carry the loaded
link's inverse dynamics along the reference at the window's start
(``tau_s = D_link(q) qdd_ref + n_link(q, qd)``, the deflection ``tau_s / K``
plus half the backlash gap in its direction, the link rates the motors'):
a payload bends the springs, and a start state that ignored that would
start each window with a spring transient of the payload's size (M. W.
Spong, J. Dyn. Syst. Meas. Control 109, 1987: the link is driven by the
spring torque alone).  The springs' ringing about that deflection is
refined too: per joint a link angle offset (within +-100 pulses: a
change's transient of tens of pulses leaves the springs ringing; a box of
20 pulses left the windows after a put-down on the independent simulator
unexplained) and a link rate offset (within that ringing's rate at the
joint's two-mass frequency, :meth:`ArmPayloadProblem.start_box`).  The box
is a numerical aid, not a prior: where a fit sits at its edge, the springs
rang beyond it (a heavy tool picked up or put down by soft gearboxes rings
by hundreds of pulses), and that joint's box is widened x4 and the window
refined again, at most twice (``_ringing_stage``; on the rivals' fits
too).  A
window at the log's first sample starts as the plant's simulation of a log
does, springs relaxed (the links where the motors are).

Bounded Levenberg--Marquardt (:func:`identification.refinement.refine`)
from several masses.  A short window may determine some first moments
``h = m c`` well and the mass poorly: in ``(m, c)`` that is a curved
valley along which the search crawls.  When it stops at its iteration
limit, it goes on from its best in first moments ``(m, h)``, where the
valley is nearly straight (the base parameters are linear in ``m`` and
``h``; only the point mass's own inertia ``(|h|^2 I - h h^T) / m`` is not),
and that point is refined in ``(m, c)`` again; the lower cost is kept (on
a random URDF chain of the independent simulator, three 0.2 s windows gave
64.7, 54.5 and 58.2 % mass errors at the limit, and 2.3, 15.6 and 0.8 %
with the stage: ``benchmarks/bench_arm_payload.py``,
``docs/figures/bench_arm_payload_random_20262751*.txt``).

A window can also hold a true local minimum in the centre of mass, which
every start from the box's centre reaches.  Its cost says so: ``n``
residuals that only quantisation disturbs cost ``n / 12`` pulses^2 with a
standard deviation of ``sqrt(n / 180)``
(:func:`identification.flexible.quantisation_z`).  When the
best of the default starts lies more than :data:`WIDE_SEARCH_Z` (3)
standard deviations above that, the search runs again from 24 starts --
the three masses times the corners of the centre-of-mass box at 40 % of its
half-widths -- and the lower cost wins (``wide_search``).  A window the
model explains costs nothing more.  On the independent simulator's random
chains, windows with 9.14, 5.14 and 5.67 kg for payloads of 4.17, 4.17 and
4.02 kg sat 85, 12 and 21 standard deviations above quantisation; the wide
search found 4.18, 4.16 and 4.02 kg at 0.7, -1.0 and -2.1
(``benchmarks/bench_arm_payload.py``, the random and URDF draws of seed
20262771).  The result's ``quantisation_z`` reports where the final cost
lies.  Standard errors
from the Gauss--Newton sandwich (:func:`identification.uncertainty.sandwich_covariance`).  A centre-of-mass
component the arm's dynamics do not depend on (``cz`` of a planar arm: the
payload's offset along parallel joint axes changes no torque) has a zero
Jacobian column: it is reported as not identifiable (``com_identifiable``,
its standard error NaN) and does not change ``beta``.
"""
from __future__ import annotations

import dataclasses
import math
import time

import numpy as np
from scipy.optimize import OptimizeResult

from plant.logs.rig import p_law_current, rig_constants
from plant.simulation.arm import ArmPlant, arm_plant, replay_arm, symmetric_from_lower
from plant.simulation.core import cell_centre

from .api import at_bounds
from .arm import ARM_REFINE_SUBSTEPS, rig_with_friction
from .flexible import DRIVE_CHANGE_BOUNDS, quantisation_z
from .friction import friction_layout
from .refinement import DEFAULT_GAIN, refine
from .result_schema import jsonable
from .uncertainty import sandwich_covariance

__all__ = ["identify_arm_payload", "ArmPayloadResult", "ArmPayloadProblem",
           "DEFAULT_ARM_PAYLOAD_BOUNDS", "PAYLOAD_NAMES", "WIDE_SEARCH_Z",
           "identify_arm_friction_change", "ArmFrictionChangeProblem", "FRICTION_CHANGE_LOG_BOX",
           "identify_arm_drive_change", "ArmDriveChangeProblem",
           "prior_from_file", "replay_arm_state"]

#: Names of the searched payload parameters (kg, m).
PAYLOAD_NAMES = ("m", "cx", "cy", "cz")

#: Default box of ``[m, cx, cy, cz]``: up to 10 kg, centre of mass within
#: 0.5 m of the last link's frame origin.
DEFAULT_ARM_PAYLOAD_BOUNDS = ((0.0, 10.0), (-0.5, 0.5), (-0.5, 0.5), (-0.5, 0.5))

#: Half-width of the start-rate box around its guess (rad/s), per joint, plus
#: 20 % of the guess.
_RATE_BOX = 0.2

#: Samples each side of the window's start for the start-rate guess.
_RATE_SAMPLES = 5

#: Smallest mass (kg) by which the first-moment stage divides ``m c`` back into ``c``.
_FIRST_MOMENT_MASS_FLOOR = 1e-3

#: The searches' start masses, as fractions of the mass box (the default search: one start
#: each, the centre of mass at the box's centre; the wide search: each with every corner).
_START_MASS_FRACTIONS = (0.1, 0.35, 0.65)

#: The wide search runs when the window's cost lies more than this many standard
#: deviations above the cost of pure quantisation noise
#: (:func:`identification.flexible.quantisation_z`).
WIDE_SEARCH_Z = 3.0

#: Centre-of-mass starts of the wide search: the corners of the box at this
#: fraction of its half-widths about its centre.
_WIDE_CORNER_FRACTION = 0.4

#: Half-width (pulses) of a two-mass arm's link-angle offsets from the springs'
#: quasi-static start (:meth:`ArmPayloadProblem.start_box`): the springs' ringing, which a
#: change's transient of tens of pulses leaves behind (a box of 20 pulses left the windows
#: after a put-down unexplained: ``benchmarks/bench_arm_adaptive.py --compliant``, seed
#: 20262101, planar draw 20262103, whose windows' decisions on either box are
#: ``docs/figures/bench_arm_adaptive_compliant_payload_20262103_at_b895508.json`` and
#: ``..._20262101_return_to_prior.json``).
_LINK_BOX_PULSES = 100.0

#: Factor by which :func:`_ringing_stage` widens a joint's link start box where a fit sits at
#: its edge, and how many times at most: the +-100 pulses grow to +-1600 at most (a cap that
#: holds too for fits started from another's box, ``link_box_pulses``).
_LINK_BOX_WIDEN = 4.0
_LINK_BOX_WIDENINGS = 2


class ArmPayloadProblem:
    """Residuals of the logged-input predictor over a window, one payload per row of X.

    ``X = [m, cx, cy, cz, qd0_1 .. qd0_n, dq0_1 .. dq0_n]``: the payload
    (point mass on the last link), the window's start rates (rad/s) and its
    start angles' offsets from the centres of their count cells (pulses;
    zero offsets start at the centres).  A two-mass arm's rows go on with
    its links' start angle offsets (pulses) and rate offsets (rad/s) from
    the springs' quasi-static start (module docstring; :meth:`start_box`).

    Parameters
    ----------
    log : plant.logs.arm_log.ArmLog
    plant : plant.simulation.arm.ArmPlant
        The arm (rigid, or two-mass with ``joints``; the rig's friction).
    prior : array_like, shape (r,)
        The unloaded arm's base parameters (rigid-equivalent for a two-mass arm).
    k0, k1 : int
        The window: samples ``k0 .. k1 - 1``.
    currents : ndarray, shape (n_samples, n)
        The current the drive applied over each sample (A).
    gain : float
        Output-injection gain (fraction of the P gain).
    substeps : int
        RK4 steps per sample.
    workers : int, optional
        Threads of the simulations.
    joints : array_like, shape (4 n,), optional
        A two-mass arm's ``[K (n), D (n), Ia (n), b (n)]`` (N m/rad, N m s/rad,
        kg m^2, rad; :meth:`plant.simulation.arm.ArmPlant.lane_parameters`),
        required with a flexible ``plant``.

    Attributes
    ----------
    nfev : int
        Candidates simulated so far.

    Raises
    ------
    ValueError
        A flexible plant without its joints (or joints for a rigid one).
    """

    def __init__(self, log, plant, prior, k0, k1, currents, *, gain=DEFAULT_GAIN,
                 substeps=ARM_REFINE_SUBSTEPS, workers=None, joints=None):
        self.log, self.plant = log, plant
        self.model = plant.model
        self.prior = np.asarray(prior, dtype=float)
        self.k0, self.k1 = int(k0), int(k1)
        self.n = log.n_joints
        self.ref = log.reference_counts()[self.k0:self.k1]
        self.e = np.asarray(log.e_pulses, dtype=float)[self.k0:self.k1]
        self.i = np.asarray(currents, dtype=float)[self.k0:self.k1]
        zeros = np.zeros(self.n)
        self.spr = np.asarray(rig_constants(log.rig, q0=zeros, qd0=zeros).pulses_per_rad, float)
        # the start angles: the centre of the count cell the first logged error allows
        counts = np.trunc(self.ref[0]) - self.e[0]
        self.q0 = np.array([cell_centre(c) for c in counts]) / self.spr
        self.gain, self.substeps, self.workers = float(gain), int(substeps), workers
        self.nfev = 0
        self.bound = 1e6
        self.sim_plant = plant
        self.joints = None
        if plant.flexible != (joints is not None):
            raise ValueError("a two-mass plant needs its joints [K, D, Ia, b] (and a rigid one none)")
        if joints is not None:
            self.joints = np.asarray(joints, dtype=float).reshape(-1)
            if self.joints.shape != (4 * self.n,) or not np.all(np.isfinite(self.joints)):
                raise ValueError(f"joints must be 4 n = {4 * self.n} finite numbers [K, D, Ia, b]")
            # the reference's acceleration at the window's start: the springs carry the
            # link's inverse dynamics along it (the links' start state, _link_start)
            t0 = np.array([self.k0 * log.rig.sample_time_s])
            self.qdd0 = np.asarray(log.trajectory.evaluate(t0)[2], dtype=float).reshape(self.n)
            self._dyn = plant.dynamics_kernel

    #: Values of the hypothesis in front of the start state in a row of X (the payload's 4).
    n_model = 4

    @property
    def n_nuisance(self) -> int:
        """Start-state values after the hypothesis in a row of X: the motors' (encoders')
        rates and count offsets (2 n), and a two-mass arm's link angle offsets (pulses)
        and rate offsets (rad/s) from the springs' quasi-static start (2 n more)."""
        return (4 if self.joints is not None else 2) * self.n

    def start_box(self, k0, link_pulses=None):
        """The start-state nuisances' guess ``(n_nuisance,)`` and box ``(n_nuisance, 2)``.

        The rates: the reference's minus the logged error's slope, +- 0.2 rad/s
        + 20 %; the count offsets within +-0.5 pulse of the cell's centre; a
        two-mass arm's link offsets within +-100 pulses (``_LINK_BOX_PULSES``;
        widened where a fit sits at the edge, ``_ringing_stage``)
        and its link rate offsets within that ringing's rate, ``omega A``
        (at least the rates' half-width): the springs ring about their
        quasi-static deflection at the two-mass joint's frequency ``omega =
        sqrt(K / D_link,jj + K / Ia)`` (the other joints locked, the prior's
        link inertia at the window's start angles).

        Parameters
        ----------
        k0 : int
            The window's first sample.
        link_pulses : array_like, shape (n,), optional
            A two-mass arm's link offset half-widths (pulses; default
            ``_LINK_BOX_PULSES`` each; ``_ringing_stage`` widens them).

        Returns
        -------
        (ndarray, ndarray)
            Shapes ``(n_nuisance,)`` and ``(n_nuisance, 2)``.
        """
        n = self.n
        qd_guess, rate_box = _start_box(self.log, self, k0)
        guess = [qd_guess, np.zeros(n)]
        box = [rate_box, np.tile([-0.5, 0.5], (n, 1))]
        if self.joints is not None:
            a = np.broadcast_to(np.asarray(_LINK_BOX_PULSES if link_pulses is None
                                           else link_pulses, dtype=float), (n,))
            half = np.maximum(0.5 * (rate_box[:, 1] - rate_box[:, 0]),
                              self._ringing_rate(a / self.spr))
            guess += [np.zeros(n), np.zeros(n)]
            box += [np.column_stack([-a, a]), np.column_stack([-half, half])]
        return np.concatenate(guess), np.vstack(box)

    def _ringing_rate(self, amplitude) -> np.ndarray:
        """Rate amplitude (rad/s, (n,)) of the springs ringing at ``amplitude`` (rad, (n,))
        about the window's start: per joint the two-mass frequency ``sqrt(K / D_jj + K /
        Ia)``, the link inertia ``D_jj`` the prior's at the start angles (the others
        locked)."""
        n = self.n
        K, Ia = self.joints[:n], self.joints[2 * n:3 * n]
        link_beta = self.prior - Ia @ self.plant.motor_inertia_columns
        sc = np.empty(2 * n)
        sc[0::2], sc[1::2] = np.sin(self.q0), np.cos(self.q0)
        lower, _ = self._dyn(sc, np.zeros(n), link_beta)
        d = np.abs(np.diag(symmetric_from_lower(lower, n)))
        with np.errstate(divide="ignore"):
            omega2 = np.where(d > 0, K / d, 0.0) + np.where(Ia > 0, K / Ia, 0.0)
        return np.sqrt(omega2) * np.abs(amplitude)

    def row(self, beta, *extra) -> np.ndarray:
        """The plant's lane row of base parameters ``beta``: ``[beta, joints, *extra]``.

        Parameters
        ----------
        beta : array_like, shape (r,)
            Base parameters (rigid-equivalent for a two-mass arm).
        *extra : array_like
            Further lane parameters after the joints (the friction of a rival).

        Returns
        -------
        ndarray
            ``(r,)``, plus ``4 n`` for a two-mass arm, plus the extras.
        """
        parts = [np.asarray(beta, dtype=float).reshape(-1)]
        if self.joints is not None:
            parts.append(self.joints)
        return np.concatenate(parts + [np.asarray(e, dtype=float).reshape(-1) for e in extra])

    def _link_start(self, beta, th, thd, joints=None) -> np.ndarray:
        """A two-mass arm's start state ``(q, qd, th, thd)`` (4 n,) for motors at ``th, thd``:
        the links where the springs carry the link's inverse dynamics along the reference
        (module docstring), two fixed-point passes for the link angle in ``D_link(q)``; a
        window at the log's first sample starts as the plant does (springs relaxed, the links
        where the motors are: :meth:`plant.simulation.plants.Plant.initial_state`).
        ``joints`` (4 n,) are the lane's ``[K, D, Ia, b]`` (default the problem's)."""
        n = self.n
        if self.k0 == 0:
            return np.concatenate([th, thd, th, thd])
        joints = self.joints if joints is None else joints
        K, Ia, b = joints[:n], joints[2 * n:3 * n], joints[3 * n:]
        link_beta = np.asarray(beta, dtype=float) - Ia @ self.plant.motor_inertia_columns
        q = np.array(th, dtype=float)
        sc = np.empty(2 * n)
        for _ in range(2):
            sc[0::2], sc[1::2] = np.sin(q), np.cos(q)
            lower, nvec = self._dyn(sc, np.asarray(thd, dtype=float), link_beta)
            tau = symmetric_from_lower(lower, n) @ self.qdd0 + nvec
            q = th - (tau / K + 0.5 * b * np.sign(tau))
        return np.concatenate([q, thd, th, thd])

    def lane(self, x) -> np.ndarray:
        """Lane parameters of the row ``x`` for the replay: the loaded arm's beta.

        Parameters
        ----------
        x : array_like, shape (4 + n_nuisance,) or (4,)
            A row of X.

        Returns
        -------
        ndarray, shape (1, r) or (1, r + 4 n)
            A two-mass arm's row holds its joints after beta.
        """
        return self.row(self.beta(x))[None]

    def beta(self, x) -> np.ndarray:
        """Base parameters (r,) of the arm carrying the payload ``x[:4]``.

        Parameters
        ----------
        x : array_like, shape (4,) or longer
            ``[m, cx, cy, cz, ...]`` (kg, m); a negative mass counts as zero.

        Returns
        -------
        ndarray, shape (r,)
        """
        m, c = float(x[0]), np.asarray(x[1:4], dtype=float)
        return self.prior + self.model.payload_delta(max(m, 0.0), c, base=self.plant.base)

    def start_states(self, X) -> np.ndarray:
        """The plant's state at the window's first sample for rows of X.

        Parameters
        ----------
        X : array_like, shape (m, 4 + n_nuisance) or (4 + n_nuisance,)

        Returns
        -------
        ndarray, shape (m, n_states) or (n_states,)
            ``(q, qd)``, then a two-mass arm's motors ``(th, thd)`` (rad, rad/s,
            joint side): the motors at the refined cell offsets and rates, the
            links at the springs' quasi-static deflection plus the refined
            ringing (module docstring).

        Raises
        ------
        ValueError
            Rows of another length than ``n_model + n_nuisance``.
        """
        single, X, _, starts = self._batch(X)
        return starts[0] if single else starts

    def _batch(self, X):
        """``(single, X (m, width), lanes (m, row), starts (m, n_states))`` of rows ``X``."""
        X = np.asarray(X, dtype=float)
        single = X.ndim == 1
        X = np.atleast_2d(X)
        n, p = self.n, self.n_model
        width = p + self.n_nuisance
        if X.shape[1] != width:
            raise ValueError(f"a row of X holds {width} values, got {X.shape[1]}")
        # each row has its own start state: one batch, a lane per row
        lanes = np.vstack([self.lane(x) for x in X])
        starts = np.hstack([self.q0 + X[:, p + n:p + 2 * n] / self.spr, X[:, p:p + n]])
        if self.joints is not None:  # the encoders read the motors; the links at the springs'
            r = self.prior.size
            starts = np.vstack([self._link_start(row[:r], s[:n], s[n:], row[r:r + 4 * n])
                                for row, s in zip(lanes, starts)])
            # the springs' ringing at the window's start: the links' offsets from there
            starts[:, :n] += X[:, p + 2 * n:p + 3 * n] / self.spr
            starts[:, n:2 * n] += X[:, p + 3 * n:p + 4 * n]
        return single, X, lanes, starts

    def residuals(self, X) -> np.ndarray:
        """Prediction errors (pulses) of a batch of payloads and start rates.

        Parameters
        ----------
        X : array_like, shape (m, 4 + n_nuisance) or (4 + n_nuisance,)

        Returns
        -------
        ndarray, shape (m, (k1 - k0) n) or ((k1 - k0) n,)
            ``bound`` throughout a row whose simulation failed.

        Raises
        ------
        ValueError
            Rows of another length than ``n_model + n_nuisance``.
        """
        single, X, lanes, starts = self._batch(X)
        sim = replay_arm(self.sim_plant, lanes, self.log.rig,
                         self.ref, self.e, self.i, gain=self.gain, substeps=self.substeps,
                         initial_state=starts, bound=self.bound, workers=self.workers)
        R = sim.errors.reshape(X.shape[0], -1).copy()
        bad = (sim.status != 0) | ~np.all(np.isfinite(R), axis=1)
        R[bad] = self.bound
        self.nfev += X.shape[0]
        return R[0] if single else R


class _FirstMoments:
    """An :class:`ArmPayloadProblem` searched in ``[m, m cx, m cy, m cz, start...]``.

    A short window determines some first moments ``h = m c`` of the payload
    well and its mass poorly; in ``(m, c)`` the well-determined ``h`` is a
    curved valley (``m c = const``) along which Levenberg--Marquardt crawls,
    in ``(m, h)`` a nearly straight one (the first moments enter the base
    parameters linearly; only the point mass's own inertia ``(|h|^2 I - h
    h^T) / m`` does not).  Rows map back with ``c = h / max(m, floor)``.
    """

    def __init__(self, problem):
        self.problem = problem

    @property
    def nfev(self) -> int:
        return self.problem.nfev

    @staticmethod
    def to_com(X) -> np.ndarray:
        """Rows ``[m, h, ...]`` as ``[m, c, ...]``."""
        X = np.array(X, dtype=float, copy=True)
        Y = np.atleast_2d(X)
        Y[:, 1:4] /= np.maximum(Y[:, 0], _FIRST_MOMENT_MASS_FLOOR)[:, None]
        return X

    @staticmethod
    def to_moments(X) -> np.ndarray:
        """Rows ``[m, c, ...]`` as ``[m, h, ...]``."""
        X = np.array(X, dtype=float, copy=True)
        Y = np.atleast_2d(X)
        Y[:, 1:4] *= np.maximum(Y[:, 0], _FIRST_MOMENT_MASS_FLOOR)[:, None]
        return X

    @staticmethod
    def box(box) -> np.ndarray:
        """The ``(m, h)`` box holding every ``(m, c)`` of ``box`` (rows as :meth:`to_com`)."""
        box = np.array(box, dtype=float, copy=True)
        m = np.maximum(box[0], _FIRST_MOMENT_MASS_FLOOR)
        corners = np.stack([box[1:4, 0][:, None] * m, box[1:4, 1][:, None] * m], axis=1)
        box[1:4, 0], box[1:4, 1] = corners.min(axis=(1, 2)), corners.max(axis=(1, 2))
        return box

    def residuals(self, X) -> np.ndarray:
        """The problem's residuals at the rows ``X`` in first moments."""
        return self.problem.residuals(self.to_com(X))


def _starts(box, rest, corner_fraction=None) -> np.ndarray:
    """Starts of the payload search: each start mass (:data:`_START_MASS_FRACTIONS` of the
    mass box) with the centre of the centre-of-mass box (the default search) or with each
    corner of that box at ``corner_fraction`` of its half-widths (the wide search); ``rest``
    (the start state) appended to every row."""
    mid, half = 0.5 * (box[1:4, 0] + box[1:4, 1]), 0.5 * (box[1:4, 1] - box[1:4, 0])
    if corner_fraction is None:
        coms = mid[None]
    else:
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)],
                         float)
        coms = mid + corner_fraction * signs * half
    rest = np.asarray(rest, dtype=float).reshape(-1)
    return np.array([[box[0, 0] + f * (box[0, 1] - box[0, 0]), *c, *rest]
                     for f in _START_MASS_FRACTIONS for c in coms])


def _wide_stage(problem, ref, box, max_iter, n_residuals):
    """When the best of the default starts leaves the window's cost more than
    :data:`WIDE_SEARCH_Z` standard deviations above quantisation noise
    (:func:`~identification.flexible.quantisation_z`): refine again from :func:`_starts` at the
    corners (with the
    first-moment stage); the lower cost wins.  Returns the result and whether
    the wide search ran."""
    if not (np.isfinite(ref.fun) and quantisation_z(ref.fun, n_residuals) > WIDE_SEARCH_Z):
        return ref, False
    wide = refine(problem, _starts(box, np.asarray(ref.x)[4:], _WIDE_CORNER_FRACTION), box,
                  max_iter=max_iter, ftol=1e-8)
    wide = _first_moment_stage(problem, wide, box, max_iter)
    out = wide if wide.fun < ref.fun else ref
    return dataclasses.replace(out, nfev=ref.nfev + wide.nfev, nit=ref.nit + wide.nit), True


def _ringing_stage(problem, ref, box, first, max_iter, k0, link_pulses):
    """A two-mass arm's link start box is a numerical aid, not a prior.

    Where the fit's link angle offset or link rate offset of a joint sits at
    the edge of its box (within 1 % of its half-width), the springs rang
    beyond it (a change's transient, a heavy tool's sag): that joint's link
    offset half-width is widened by :data:`_LINK_BOX_WIDEN` (its rate box
    with it, :meth:`ArmPayloadProblem.start_box`) and the window refined
    again from the fit, at most :data:`_LINK_BOX_WIDENINGS` times; the lower
    cost wins, and a widening that lowers nothing ends the stage (the
    project's rule for a bound: an estimate at it is the optimiser's edge,
    not the robot's).  ``first`` is the index of the start-state nuisances
    in a row of X (:attr:`ArmPayloadProblem.n_model`, or a rival's factor
    count), ``k0`` the window's first sample and ``link_pulses`` (n,) the
    half-widths ``box`` was built with.  Returns the result and the
    half-widths (pulses, (n,)) of the box it was refined in."""
    a = np.array(link_pulses, dtype=float)
    if problem.joints is None or not np.isfinite(ref.fun):
        return ref, a
    n = problem.n
    off, rate = first + 2 * n + np.arange(n), first + 3 * n + np.arange(n)
    for _ in range(_LINK_BOX_WIDENINGS):
        x = np.asarray(ref.x, dtype=float)
        edge = (np.abs(x[off]) >= 0.99 * box[off, 1]) | (np.abs(x[rate]) >= 0.99 * box[rate, 1])
        if not edge.any():
            break
        cap = _LINK_BOX_PULSES * _LINK_BOX_WIDEN ** _LINK_BOX_WIDENINGS
        wider = np.where(edge, np.maximum(a, np.minimum(_LINK_BOX_WIDEN * a, cap)), a)
        if np.array_equal(wider, a):
            break  # at the cap: the box a chain of fits may reach (+-1600 pulses)
        box_w = np.array(box, dtype=float)
        box_w[first:] = problem.start_box(k0, wider)[1]
        again = refine(problem, np.clip(x, box_w[:, 0], box_w[:, 1])[None], box_w,
                       max_iter=max_iter, ftol=1e-8)
        better = bool(again.fun < ref.fun)
        ref = dataclasses.replace(again if better else ref, nfev=ref.nfev + again.nfev,
                                  nit=ref.nit + again.nit)
        if not better:
            break
        a, box = wider, box_w
    return ref, a


def _first_moment_stage(problem, ref, box, max_iter):
    """When the search in ``(m, c)`` stopped at its iteration limit: search again from its
    best in first moments (:class:`_FirstMoments`), then refine that point in ``(m, c)``
    (the standard errors' parameters); the lower cost wins.  A search that converged
    within the limit is returned as it is."""
    if not (np.isfinite(ref.fun) and ref.nit >= max_iter + 1):
        return ref
    fm = _FirstMoments(problem)
    mbox = fm.box(box)
    start = np.clip(fm.to_moments(ref.x), mbox[:, 0], mbox[:, 1])
    moved = refine(fm, start[None], mbox, max_iter=max_iter, ftol=1e-8)
    x = np.clip(fm.to_com(moved.x), box[:, 0], box[:, 1])
    back = refine(problem, x[None], box, max_iter=max_iter, ftol=1e-8)
    out = back if back.fun < ref.fun else ref
    return dataclasses.replace(out, nfev=ref.nfev + moved.nfev + back.nfev,
                               nit=ref.nit + moved.nit + back.nit)


class ArmFrictionChangeProblem(ArmPayloadProblem):
    """:class:`ArmPayloadProblem` for a change of the drive friction instead of a payload.

    ``X = [ln f_v,1 .. ln f_v,n, ln f_c,1 .. ln f_c,n, qd0 (n), dq0 (n)]``: per
    joint the factors on the rig's viscous and Coulomb friction (both signs),
    the arm's base parameters held at ``beta`` (the model in use), then the
    start state as the payload problem's.

    Parameters
    ----------
    log, plant, k0, k1, currents, gain, substeps, workers, joints
        As :class:`ArmPayloadProblem`.
    beta : array_like, shape (r,)
        The base parameters held (the model in use).
    """

    def __init__(self, log, plant, beta, k0, k1, currents, *, gain=DEFAULT_GAIN,
                 substeps=ARM_REFINE_SUBSTEPS, workers=None, joints=None):
        super().__init__(log, plant, beta, k0, k1, currents, gain=gain, substeps=substeps,
                         workers=workers, joints=joints)
        self.sim_plant = arm_plant(plant.model, plant.base, lane_friction=True,
                                   flexible=plant.flexible)
        self.friction = friction_layout(log.rig)[0]  # (n, 3) joint side
        self.n_model = 2 * self.n

    def lane(self, x) -> np.ndarray:
        """Lane parameters for the replay: beta held, the rig's friction times the factors.

        Parameters
        ----------
        x : array_like, shape (4 n,) or (2 n,)
            A row of X (the log factors first).

        Returns
        -------
        ndarray, shape (1, r + 3 n) or (1, r + 7 n)
            A two-mass arm's row holds its joints between beta and the friction
            (which acts on its motors).
        """
        n = self.n
        fv, fc = np.exp(np.asarray(x[:n], dtype=float)), np.exp(np.asarray(x[n:2 * n], dtype=float))
        F = self.friction * np.column_stack([fv, fc, fc])
        return self.row(self.prior, F)[None]


def _start_box(log, problem, k0):
    """The start rates' guess (n,) and box (n, 2) of a window starting at sample ``k0``: the
    reference's rate minus the logged error's slope (least squares over a few samples each
    side), +- :data:`_RATE_BOX` + 20 %."""
    n, ts = log.n_joints, log.rig.sample_time_s
    lo, hi = max(k0 - _RATE_SAMPLES, 0), min(k0 + _RATE_SAMPLES + 1, log.n_samples)
    tt = np.arange(lo, hi) * ts
    counts = np.trunc(log.reference_counts()[lo:hi]) - np.asarray(log.e_pulses[lo:hi], float)
    slope = np.polyfit(tt, counts, 1)[0] if hi - lo > 1 else np.zeros(n)
    qd_guess = np.asarray(slope, dtype=float).reshape(n) / problem.spr
    half = _RATE_BOX + 0.2 * np.abs(qd_guess)
    return qd_guess, np.column_stack([qd_guess - half, qd_guess + half])


#: Box of the friction factors' logarithms of :func:`identify_arm_friction_change`
#: (factors x0.25 .. x4).
FRICTION_CHANGE_LOG_BOX = math.log(4.0)


class ArmDriveChangeProblem(ArmPayloadProblem):
    """:class:`ArmPayloadProblem` for a change of a two-mass arm's springs instead of a payload.

    ``X = [ln fK_1 .. ln fK_n, ln fD_1 .. ln fD_n, start state]``: per joint the
    factors on the spring's stiffness K and damping D (the gearbox wearing,
    softening or stiffening; issue 21's stiffness x0.7 and damping x2), the
    arm's base parameters held at ``beta`` (the model in use), the reflected
    motor inertias, backlash and friction the prior's, then the start state as
    the payload problem's (the links' quasi-static start under the changed
    springs).  A joint whose damping is zero keeps it.

    Parameters
    ----------
    log, plant, k0, k1, currents, gain, substeps, workers
        As :class:`ArmPayloadProblem` (``plant`` two-mass).
    beta : array_like, shape (r,)
        The base parameters held (the model in use, rigid-equivalent).
    joints : array_like, shape (4 n,)
        The prior's ``[K, D, Ia, b]``, the factors' reference.

    Raises
    ------
    ValueError
        A rigid plant, or joints missing or of the wrong size.
    """

    def __init__(self, log, plant, beta, k0, k1, currents, *, joints=None, gain=DEFAULT_GAIN,
                 substeps=ARM_REFINE_SUBSTEPS, workers=None):
        if not plant.flexible:
            raise ValueError("a change of the springs needs a two-mass arm (a flexible prior)")
        super().__init__(log, plant, beta, k0, k1, currents, gain=gain, substeps=substeps,
                         workers=workers, joints=joints)
        self.n_model = 2 * self.n

    def lane(self, x) -> np.ndarray:
        """Lane parameters for the replay: beta held, the springs' K and D times the factors.

        Parameters
        ----------
        x : array_like, shape (6 n,) or (2 n,)
            A row of X (the log factors first).

        Returns
        -------
        ndarray, shape (1, r + 4 n)
        """
        n = self.n
        joints = self.joints.copy()
        joints[:2 * n] *= np.exp(np.asarray(x[:2 * n], dtype=float))
        return np.concatenate([self.prior, joints])[None]


def identify_arm_friction_change(log, prior, *, beta=None, window_s, currents="logged",
                                 gain=DEFAULT_GAIN, substeps=None, max_iter=40,
                                 workers=None) -> OptimizeResult:
    """Fit a change of the drive friction on a window of an arm's log (the payload's rival).

    The hypothesis a window's payload estimate is tested against
    (:class:`ctc.arm_adaptive.ArmAdaptiveComputedTorque`): the arm is the
    model in use (``beta``), and its drive friction changed -- per joint a
    factor on the viscous and one on the Coulomb friction, in x0.25 .. x4
    (a drive warming up; :class:`ArmFrictionChangeProblem`).  The residuals,
    the start-state nuisances and the optimiser are
    :func:`identify_arm_payload`'s.

    Parameters
    ----------
    log : plant.logs.arm_log.ArmLog
    prior : identification.arm.ArmIdentificationResult or array_like, shape (r,)
        As :func:`identify_arm_payload` (its plant and rig, with the identified
        friction when the sidecar had none).
    beta : array_like, shape (r,), optional
        The base parameters held (default the prior's).
    window_s : (float, float)
        Start and end time of the window (s), at least 20 samples.
    currents : {"logged", None} or array_like, shape (n_samples, n)
        As :func:`identify_arm_payload` (default the log's own commands).
    gain, substeps, max_iter, workers
        As :func:`identify_arm_payload`.

    Returns
    -------
    scipy.optimize.OptimizeResult
        ``x`` (the 2 n log factors), ``fun`` (pulses^2), ``nfev``, ``nit``,
        ``success``, ``message``, ``viscous_factor`` and ``coulomb_factor``
        (n each), ``residuals_pulses`` (window samples, n).

    Raises
    ------
    ValueError
        As :func:`identify_arm_payload`.
    """
    n = log.n_joints
    box = np.tile([-FRICTION_CHANGE_LOG_BOX, FRICTION_CHANGE_LOG_BOX], (2 * n, 1))
    res = _fit_held_change(ArmFrictionChangeProblem, log, prior, beta, window_s, currents, box,
                           gain=gain, substeps=substeps, max_iter=max_iter, workers=workers)
    res.update(viscous_factor=np.exp(res.x[:n]), coulomb_factor=np.exp(res.x[n:]))
    return res


def _fit_held_change(problem_class, log, prior, beta, window_s, currents, factor_box, *, gain,
                     substeps, max_iter, workers, needs_joints=False) -> OptimizeResult:
    """A rival change of a window (:func:`identify_arm_friction_change`,
    :func:`identify_arm_drive_change`): ``problem_class``'s log factors in ``factor_box``
    (p, 2) from no change, the start state as a payload's, the base parameters held at
    ``beta`` (default the prior's).  Returns ``x`` (p,), ``fun``, ``nfev``, ``nit``,
    ``success``, ``message`` and ``residuals_pulses`` (window samples, n)."""
    plant, rig, beta_prior, joints = _prior_of(prior, log, None)
    if needs_joints and joints is None:
        raise ValueError("a change of the springs needs a flexible prior (an identify_arm result "
                         "with model 'flexible')")
    substeps = _substeps_of(prior, joints, substeps)
    if rig is not log.rig:
        log = dataclasses.replace(log, rig=rig)
    held = beta_prior if beta is None else np.asarray(beta, dtype=float).reshape(-1)
    if held.shape != beta_prior.shape or not np.all(np.isfinite(held)):
        raise ValueError(f"beta must be {beta_prior.size} finite base parameters")
    k0, k1 = _window_samples(log, window_s)
    problem = problem_class(log, plant, held, k0, k1, _currents_of(log, currents), gain=gain,
                            substeps=substeps, workers=workers, joints=joints)
    link = np.full(log.n_joints, _LINK_BOX_PULSES)
    guess, nuisance_box = problem.start_box(k0, link)
    p = len(factor_box)
    box = np.vstack([factor_box, nuisance_box])
    ref = refine(problem, np.concatenate([np.zeros(p), guess])[None], box, max_iter=max_iter,
                 ftol=1e-8)
    ref, _ = _ringing_stage(problem, ref, box, p, max_iter, k0, link)
    x_all = np.asarray(ref.x, dtype=float)
    ok = bool(np.isfinite(ref.fun) and ref.fun < problem.bound ** 2)
    return OptimizeResult(
        x=x_all[:p], fun=float(ref.fun), nfev=int(ref.nfev), nit=int(ref.nit), success=ok,
        message=(ref.message or "ok") if ok else "the predictor failed: the window does not fit",
        residuals_pulses=problem.residuals(x_all).reshape(k1 - k0, log.n_joints))


def identify_arm_drive_change(log, prior, *, beta=None, window_s, currents="logged",
                              gain=DEFAULT_GAIN, substeps=None, max_iter=40,
                              workers=None) -> OptimizeResult:
    """Fit a change of a two-mass arm's springs on a window of its log (the payload's rival).

    The hypothesis a window's payload estimate is tested against on a
    flexible prior (:class:`ctc.arm_adaptive.ArmAdaptiveComputedTorque`),
    the arm path's counterpart of the PUMA path's
    :class:`identification.flexible.DriveChangeParameters`: the arm is the
    model in use (``beta``), and its joints' springs changed -- per joint a
    factor on the stiffness K in x0.5 .. x2 and one on the damping D in
    x0.25 .. x4 (:data:`identification.flexible.DRIVE_CHANGE_BOUNDS`, wider
    than the flexible design's model-error set, so that a change inside that
    set is never at the box's edge; :class:`ArmDriveChangeProblem`).  The
    residuals, the start-state nuisances and the optimiser are
    :func:`identify_arm_payload`'s.

    Parameters
    ----------
    log, beta, window_s, currents, gain, substeps, max_iter, workers
        As :func:`identify_arm_friction_change`.
    prior : identification.arm.ArmIdentificationResult
        A flexible result of :func:`identification.arm.identify_arm` (its
        two-mass arm, joints and -- when the sidecar had none -- identified
        friction).

    Returns
    -------
    scipy.optimize.OptimizeResult
        ``x`` (the 2 n log factors), ``fun`` (pulses^2), ``nfev``, ``nit``,
        ``success``, ``message``, ``stiffness_factor`` and ``damping_factor``
        (n each), ``residuals_pulses`` (window samples, n).

    Raises
    ------
    ValueError
        A rigid prior, or as :func:`identify_arm_payload`.
    """
    n = log.n_joints
    bounds = np.log(np.asarray(DRIVE_CHANGE_BOUNDS, dtype=float))  # K, K, D, D of two joints
    box = np.vstack([np.tile(bounds[0], (n, 1)), np.tile(bounds[2], (n, 1))])
    res = _fit_held_change(ArmDriveChangeProblem, log, prior, beta, window_s, currents, box,
                           gain=gain, substeps=substeps, max_iter=max_iter, workers=workers,
                           needs_joints=True)
    res.update(stiffness_factor=np.exp(res.x[:n]), damping_factor=np.exp(res.x[n:]))
    return res


def _window_samples(log, window_s, minimum=20):
    """Samples ``(k0, k1)`` of a window (s) of a log (None: the whole log), at least
    ``minimum`` of them (a fit's 20; a replay's 1)."""
    ts = log.rig.sample_time_s
    if window_s is None:
        k0, k1 = 0, log.n_samples
    else:
        t0, t1 = (float(v) for v in window_s)
        k0, k1 = int(np.ceil(t0 / ts - 1e-9)), int(np.floor(t1 / ts + 1e-9)) + 1
        if not (0 <= k0 and k1 <= log.n_samples):
            raise ValueError(f"window_s {window_s} is outside the log (0 to {log.t[-1]:.4g} s)")
    if k1 - k0 < minimum:
        raise ValueError(f"the window has {k1 - k0} samples; at least {minimum} are needed")
    return k0, k1


def _currents_of(log, currents):
    """The applied currents (n_samples, n) A: None (the P law), "logged" or an array."""
    if currents is None:
        i = p_law_current(log.rig, log.e_pulses)
    elif isinstance(currents, str):
        if currents != "logged":
            raise ValueError(f"currents must be None, 'logged' or an array, got {currents!r}")
        i = np.asarray(log.i_A, dtype=float)
    else:
        i = np.asarray(currents, dtype=float)
    if i.shape != (log.n_samples, log.n_joints) or not np.all(np.isfinite(i)):
        raise ValueError(f"currents must be finite, shape ({log.n_samples}, {log.n_joints})")
    return i


class ArmPayloadResult(OptimizeResult):
    """A payload identified on a window of an arm's log (scipy ``OptimizeResult``).

    Attributes
    ----------
    x : ndarray, shape (4,)
        ``[m, cx, cy, cz]`` (kg, m; centre of mass in the last link's frame).
    fun : float
        Sum of squared prediction errors over the window (pulses^2).
    nfev, nit : int
        Candidates simulated, refinement iterations.
    success : bool
    message : str
    mass_kg : float
    com_m : ndarray, shape (3,)
    x_std : ndarray, shape (4,)
        Standard errors (NaN for a parameter the window does not determine).
    com_identifiable : ndarray of bool, shape (3,)
        Whether the arm's dynamics depend on that centre-of-mass component.
    beta : ndarray, shape (r,)
        The loaded arm's base parameters, ``prior + K dp`` -- what a
        computed-torque controller takes (:class:`ctc.arm.ArmComputedTorque`).
    beta_prior : ndarray, shape (r,)
    names : tuple of str
        The base parameters' names.
    window_s : tuple of float
        First and last sample time of the window (s).
    start_rates_rad_s : ndarray, shape (n,)
        The window's refined start rates (nuisance parameters).
    start_offsets_pulses : ndarray, shape (n,)
        The window's refined start angles, from the centres of their count
        cells (pulses, within +-0.5; nuisance parameters).
    start_state : ndarray, shape (n_states,)
        The plant's state at the window's first sample at the estimate
        (:meth:`ArmPayloadProblem.start_states`: ``(q, qd)``, then a two-mass
        arm's motors ``(th, thd)``; rad, rad/s) -- with
        :func:`replay_arm_state`, the loaded arm's state at a later sample.
    residuals_pulses : ndarray, shape (n_window, n)
        Prediction errors at the estimate (time-first).
    joint_names : tuple of str
    quantisation_z : float
        How many standard deviations the window's cost lies above pure
        quantisation noise (:func:`identification.flexible.quantisation_z`; NaN when
        ``success`` is False).  Near 0 when the loaded model explains the
        window to the encoders' resolution; well above 3 when it does not (a
        change no payload describes, a local minimum the wide search did not
        leave, a poor prior).
    wide_search : bool
        Whether the wide search ran (module docstring).
    link_box_pulses : ndarray, shape (n,), or None
        A two-mass arm's link start box the fit ended in: half-widths of the
        links' start offsets (pulses; wider than asked where the fit sat at
        the edge, module docstring); None for a rigid arm.
    at_bounds : tuple of str
        The payload parameters that ended on a bound of their box
        (:func:`identification.api.at_bounds`, e.g. ``'m (upper)'``): a mass at
        the box's top is a window that does not determine it (its standard
        error says how little) or a box too small for the tool.
    elapsed_s : float
    """

    def table(self) -> str:
        """The payload and its standard errors as a text table."""
        units = ("kg", "m", "m", "m")
        rows = [f"{'':>4} {'estimate':>10} {'std':>9}"]
        for name, v, s, u in zip(PAYLOAD_NAMES, self.x, self.x_std, units):
            note = "" if np.isfinite(s) else "  (not identifiable on this arm)"
            rows.append(f"{name:>4} {v:10.4f} {s:9.4f} {u}{note}")
        z = self.get("quantisation_z", float("nan"))
        if np.isfinite(z):
            wide = ", after the wide search" if self.get("wide_search") else ""
            rows.append(f"cost {self.fun:.4g} pulses^2: {z:+.1f} standard deviations from "
                        f"quantisation noise{wide}")
        if self.get("at_bounds"):
            rows.append(f"at the box's bound: {', '.join(self.at_bounds)} (the window may not "
                        "determine it, or the box is too small: bounds=)")
        return "\n".join(rows)

    def to_dict(self) -> dict:
        """JSON-ready dict of the result (arrays as lists, NaN as None)."""
        keys = ("x", "fun", "nfev", "nit", "success", "message", "mass_kg", "com_m", "x_std",
                "com_identifiable", "beta", "beta_prior", "names", "window_s",
                "start_rates_rad_s", "start_offsets_pulses", "start_state", "joint_names",
                "quantisation_z", "wide_search", "link_box_pulses", "at_bounds", "elapsed_s")
        return {k: jsonable(self[k]) for k in keys}

    def plot(self, ax=None):
        """The window's prediction errors at the estimate, per joint (pulses).

        Parameters
        ----------
        ax : matplotlib.axes.Axes, optional
            Drawn into (default: a new figure).

        Returns
        -------
        matplotlib.axes.Axes
        """
        import matplotlib.pyplot as plt

        if ax is None:
            _, ax = plt.subplots()
        r = np.asarray(self.residuals_pulses)
        t = np.linspace(self.window_s[0], self.window_s[1], r.shape[0])
        for j, name in enumerate(self.joint_names):
            ax.plot(t, r[:, j], label=name)
        ax.set_xlabel("t (s)")
        ax.set_ylabel("prediction error (pulses)")
        ax.set_title(f"payload {self.mass_kg:.3g} kg on the last link")
        ax.legend()
        return ax


def prior_from_file(path, log) -> dict:
    """The unloaded arm of an :func:`identification.arm.identify_arm` result file, as a prior.

    Reads the JSON that :meth:`identification.arm.ArmIdentificationResult.save_json`
    (the CLI's ``--output``) wrote for the unloaded arm and rebuilds what
    :func:`identify_arm_payload` takes from a result: the base parameters,
    the arm plant of ``log``'s robot, the rig with the identified friction
    (when the file's identification identified it) and, for a flexible
    result, its joints and RK4 substeps.

    Parameters
    ----------
    path : path-like
        The result file (JSON).
    log : plant.logs.arm_log.ArmLog
        The loaded arm's log: its robot must be the file's (the same base
        parameters by name).

    Returns
    -------
    dict
        ``beta`` (r,), ``plant`` (:class:`plant.simulation.arm.ArmPlant`),
        ``rig``, ``model``, ``plant_row`` (a flexible result's ``[beta, K,
        D, Ia, b]``, else None), ``flexible_substeps`` -- a prior for
        :func:`identify_arm_payload`.

    Raises
    ------
    ValueError
        An unreadable or malformed file (one line), base parameters other
        than the log's robot's, a non-finite value, a flexible result without
        its joints or substeps.
    """
    from pathlib import Path

    from plant.logs.fileio import read_json_object

    p = Path(path)
    data = read_json_object(p, "prior result file")
    if not isinstance(data.get("beta"), list) or not isinstance(data.get("names"), list):
        raise ValueError(f"{p} is not a result file of identify_arm (no 'beta' and 'names' lists)")
    plant = arm_plant(log.model)
    names, r = tuple(plant.base.names), plant.base.rank
    if tuple(data["names"][:r]) != names or len(data["beta"]) != r:
        raise ValueError(f"the prior {p} holds the base parameters of another robot "
                         f"({', '.join(map(str, data['names'][:r]))}), not {log.model.name}'s "
                         f"({', '.join(names)})")
    try:
        beta = np.array(data["beta"], dtype=float)
    except (TypeError, ValueError):
        beta = np.full(r, np.nan)
    if not np.all(np.isfinite(beta)):
        raise ValueError(f"the prior {p} has non-finite base parameters")
    rig = log.rig
    if friction_layout(rig)[1] and data.get("friction_identified"):
        try:
            rig = rig_with_friction(rig, data["friction"])
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"the prior {p} has no usable identified friction ({exc})") from None
    model = str(data.get("model") or "rigid")
    row, substeps = None, None
    if model != "rigid":
        n = log.n_joints
        keys = ("joint_stiffness_Nm_per_rad", "joint_damping_Nms_per_rad",
                "motor_inertia_reflected_kgm2")
        try:
            parts = [np.array(data[k], dtype=float).reshape(n) for k in keys]
            b = data.get("joint_backlash_rad")
            parts.append(np.zeros(n) if b is None else np.array(b, dtype=float).reshape(n))
            substeps = int(data["flexible_substeps"])
        except (KeyError, TypeError, ValueError):
            raise ValueError(f"the prior {p} is a {model} result without its joints or "
                             "flexible_substeps (write it again with this version)") from None
        row = np.concatenate([beta, *parts])
        if not np.all(np.isfinite(row)) or substeps < 1:
            raise ValueError(f"the prior {p} has non-finite joints or substeps")
    return dict(beta=beta, plant=plant, rig=rig, model=model, plant_row=row,
                flexible_substeps=substeps)


def _at_bounds(x, box, identifiable) -> tuple:
    """:func:`identification.api.at_bounds` of the payload, its identifiable components only
    (a component the arm does not depend on goes where the search leaves it)."""
    keep = np.concatenate([[True], identifiable])
    names = [n for n, k in zip(PAYLOAD_NAMES, keep) if k]
    return tuple(at_bounds(dict(x=x[keep], bounds=box[keep], x_names=names)))


def _substeps_of(prior, joints, substeps) -> int:
    """RK4 steps per sample: the caller's, else the refinement's, at least a flexible fit's."""
    if substeps is not None:
        return int(substeps)
    fit = prior.get("flexible_substeps") if joints is not None and hasattr(prior, "get") else None
    return max(ARM_REFINE_SUBSTEPS, int(fit or 0))


def _prior_of(prior, log, plant):
    """(plant, rig, beta, joints) of a prior: an identification result or a vector.

    A flexible result gives its two-mass arm with the rig's friction and its joints
    ``[K, D, Ia, b]`` (4 n,); a rigid prior ``joints`` None."""
    rig = log.rig
    joints = None
    if hasattr(prior, "get") and prior.get("beta") is not None and prior.get("plant") is not None:
        rig = prior.get("rig") or rig  # the identified friction, when the sidecar had none
        beta = np.asarray(prior["beta"], dtype=float)
        if prior.get("model", "rigid") != "rigid":
            row = prior.get("plant_row")
            row = np.zeros(0) if row is None else np.asarray(row, dtype=float).reshape(-1)
            n, r = prior["plant"].n_joints, prior["plant"].base.rank
            if row.size < r + 4 * n:
                raise ValueError("a flexible prior needs its two-mass arm's joints (plant_row of "
                                 "an identification.arm.identify_arm result)")
            joints = row[r:r + 4 * n].copy()
            if plant is None:  # the two-mass arm with the rig's (identified) friction
                plant = arm_plant(prior["plant"].model, prior["plant"].base, flexible=True)
        plant = prior["plant"] if plant is None else plant
    else:
        beta = np.asarray(prior, dtype=float).reshape(-1)
    if plant is None:
        plant = arm_plant(log.model)
    if not isinstance(plant, ArmPlant) or plant.lane_friction:
        raise ValueError("plant must be a plant.simulation.arm.ArmPlant with the rig's friction")
    if plant.flexible and joints is None:
        raise ValueError("a two-mass plant needs a flexible prior (an identify_arm result with "
                         "model 'flexible', which carries the joints)")
    if not plant.flexible and joints is not None:
        raise ValueError("a flexible prior needs its two-mass plant (flexible=True), not a rigid one")
    if beta.shape != (plant.base.rank,) or not np.all(np.isfinite(beta)):
        raise ValueError(f"prior must be {plant.base.rank} finite base parameters "
                         f"({', '.join(plant.base.names)}), got shape {beta.shape}")
    if friction_layout(rig)[1]:
        raise ValueError("the rig's friction is unknown: give the prior's identification result "
                         "(identification.arm.identify_arm), which carries the identified friction")
    return plant, rig, beta, joints


def identify_arm_payload(log, prior, *, window_s=None, plant=None, currents=None, bounds=None,
                         gain=DEFAULT_GAIN, substeps=None, max_iter=40,
                         workers=None, link_box_pulses=None) -> ArmPayloadResult:
    """Identify a payload on an arm's last link from a window of its log (module docstring).

    Parameters
    ----------
    log : plant.logs.arm_log.ArmLog
        The logged run of the loaded arm.
    prior : identification.arm.ArmIdentificationResult or array_like, shape (r,)
        The unloaded arm: an identification result (its base parameters,
        plant and -- when the sidecar had none -- identified friction; a
        flexible result also its joints, and the payload is searched through
        its two-mass arm, module docstring), or its base parameters (a rigid
        arm; the rig's friction must then be known).
    window_s : (float, float), optional
        Start and end time of the window (s); default the whole log.  At
        least 20 samples.
    plant : plant.simulation.arm.ArmPlant, optional
        The arm with the rig's friction (default the prior's -- a flexible
        prior's two-mass arm -- else :func:`plant.simulation.arm.arm_plant`
        of the log's robot).
    currents : {None, "logged"} or array_like, shape (n_samples, n)
        The current the drive applied: None (default), the rig's P law on
        the logged errors (a P-control log); ``"logged"``, the log's
        ``i_A`` (a run of another controller, which logged its commands); or
        the currents themselves (A).
    bounds : array_like, shape (4, 2), optional
        Box of ``[m, cx, cy, cz]`` (default :data:`DEFAULT_ARM_PAYLOAD_BOUNDS`).
    gain : float
        Output-injection gain of the predictor (fraction of the P gain).
    substeps : int, optional
        RK4 steps per sample (default :data:`identification.arm.ARM_REFINE_SUBSTEPS`;
        a flexible prior's at least its fit's, ``flexible_substeps``: the springs'
        modes need them).
    max_iter : int
        Refinement iterations at most.
    workers : int, optional
        Threads of the simulations (default: the CPUs this process may use).
    link_box_pulses : array_like, shape (n,), optional
        A two-mass arm's link start box: half-widths of the links' start
        offsets (pulses; default +-100 each), widened where the fit sits at
        the edge (module docstring).  Two fits compared on one window (a free
        payload against a pinned one) start from the same box: pass one's
        ``link_box_pulses`` to the other.

    Returns
    -------
    ArmPayloadResult
        ``success`` False with a message when the predictor fails for
        every start (the window does not fit the robot model).

    Raises
    ------
    ValueError
        A prior of the wrong size, a flexible prior without its joints or
        with a rigid plant, unknown friction with a bare vector, a window outside the log or shorter than 20 samples,
        malformed currents or bounds, ``link_box_pulses`` not n positive finite numbers.
    """
    t_start = time.perf_counter()
    plant, rig, beta_prior, joints = _prior_of(prior, log, plant)
    link = np.full(log.n_joints, _LINK_BOX_PULSES)
    if link_box_pulses is not None:
        link = np.asarray(link_box_pulses, dtype=float).reshape(-1)
        if link.shape != (log.n_joints,) or not np.all(np.isfinite(link)) or np.any(link <= 0):
            raise ValueError(f"link_box_pulses must be {log.n_joints} positive finite numbers "
                             "(pulses)")
    substeps = _substeps_of(prior, joints, substeps)
    if rig is not log.rig:
        import dataclasses

        log = dataclasses.replace(log, rig=rig)
    n, ts = log.n_joints, rig.sample_time_s
    k0, k1 = _window_samples(log, window_s)
    i = _currents_of(log, currents)
    box = np.asarray(DEFAULT_ARM_PAYLOAD_BOUNDS if bounds is None else bounds, dtype=float)
    if box.shape != (4, 2) or not np.all(np.isfinite(box)) or np.any(box[:, 0] >= box[:, 1]) \
            or box[0, 0] < 0:
        raise ValueError("bounds must be 4 finite (low, high) pairs with low < high and a mass >= 0")
    problem = ArmPayloadProblem(log, plant, beta_prior, k0, k1, i, gain=gain, substeps=substeps,
                                workers=workers, joints=joints)
    # the start rates: the reference's minus the logged error's slope, refined as nuisances
    guess, nuisance_box = problem.start_box(k0, link)
    full_box = np.vstack([box, nuisance_box])
    starts = _starts(box, guess)
    if box[0, 1] - box[0, 0] < 1e-6:  # a pinned mass (a model's own fit): one start
        starts = starts[:1]
    ref = refine(problem, starts, full_box, max_iter=max_iter, ftol=1e-8)
    n_residuals = (k1 - k0) * n
    wide = False
    if starts.shape[0] > 1:
        ref = _first_moment_stage(problem, ref, full_box, max_iter)
        ref, wide = _wide_stage(problem, ref, full_box, max_iter, n_residuals)
    ref, link = _ringing_stage(problem, ref, full_box, problem.n_model, max_iter, k0, link)
    x_all = np.asarray(ref.x, dtype=float)
    ok = bool(np.isfinite(ref.fun) and ref.fun < problem.bound ** 2)
    x_std = np.full(4, np.nan)
    identifiable = np.ones(3, dtype=bool)
    if ok and ref.jac is not None:
        J = np.asarray(ref.jac, dtype=float)
        norms = np.linalg.norm(J, axis=0)
        keep = norms > 1e-9 * max(float(norms.max()), 1e-300)
        identifiable = keep[1:4].copy()
        cov, _ = sandwich_covariance(J[:, keep], ref.residuals, n_channels=n)
        std = np.full(J.shape[1], np.nan)
        std[keep] = np.sqrt(np.maximum(np.diag(cov), 0.0))
        x_std = std[:4]
    x = x_all[:4]
    residuals = problem.residuals(x_all).reshape(k1 - k0, n)
    return ArmPayloadResult(
        x=x, fun=float(ref.fun), nfev=int(ref.nfev), nit=int(ref.nit), success=ok,
        message=(ref.message or "ok") if ok else
        "the predictor failed from every start: the window does not fit the robot model",
        mass_kg=float(x[0]), com_m=x[1:4].copy(), x_std=x_std, com_identifiable=identifiable,
        beta=problem.beta(x), beta_prior=beta_prior, names=tuple(plant.base.names),
        window_s=(float(k0 * ts), float((k1 - 1) * ts)), start_rates_rad_s=x_all[4:4 + n].copy(),
        start_offsets_pulses=x_all[4 + n:4 + 2 * n].copy(),
        start_state=problem.start_states(x_all), residuals_pulses=residuals,
        joint_names=tuple(log.joint_names),
        quantisation_z=quantisation_z(ref.fun, n_residuals) if ok else float("nan"),
        wide_search=wide, link_box_pulses=link if joints is not None else None,
        at_bounds=_at_bounds(x, box, identifiable) if ok else (),
        elapsed_s=time.perf_counter() - t_start)


def replay_arm_state(log, prior, beta, start_state, window_s, *, plant=None, currents="logged",
                     gain=DEFAULT_GAIN, substeps=None) -> np.ndarray:
    """The arm's state at a window's last sample, replayed from its state at the first.

    The logged-input predictor of the payload's fit
    (:func:`plant.simulation.arm.replay_arm`: the current the drive applied
    plus the output injection that keeps the simulated encoders in the
    count cells the log allows) run as a state estimator: from
    ``start_state`` at the window's first sample (an
    :class:`ArmPayloadResult`'s ``start_state``), the arm of the base
    parameters ``beta`` is driven over the window's samples, and its state
    at the last one -- the instant that sample's encoders are read, before
    its current acts -- is returned.  A two-mass arm's link state is what
    the encoders do not see: a flexible-joint controller whose model changes
    takes the new model's link estimate from here
    (:meth:`ctc.arm.ArmFlexibleComputedTorque.set_link_estimate`) instead of
    its old model's (a bumpless transfer from a state estimate: L. Zaccarian
    and A. R. Teel, "The L2 (l2) bumpless transfer problem for linear
    plants", Automatica 41, 2005).

    Parameters
    ----------
    log : plant.logs.arm_log.ArmLog
        The run (its errors and, with ``currents="logged"``, its commanded
        currents; the last sample's current is not used).
    prior : identification.arm.ArmIdentificationResult or array_like, shape (r,)
        As :func:`identify_arm_payload` (its plant, rig and a flexible
        result's joints).
    beta : array_like, shape (r,)
        The arm's base parameters (rigid-equivalent for a two-mass arm),
        e.g. the estimate's ``beta``.
    start_state : array_like, shape (n_states,)
        The state at the window's first sample (the plant's layout).
    window_s : (float, float)
        First and last sample time (s); one sample or more.
    currents : None, "logged" or array_like, shape (n_samples, n)
        The current the drive applied (A): the rig's P law on the logged
        errors (None), the log's ``i_A`` (``"logged"``, the default: a
        controller's own commands) or given.
    plant, gain, substeps
        As :func:`identify_arm_payload`.

    Returns
    -------
    ndarray, shape (n_states,)
        ``(q, qd)``, then a two-mass arm's motors ``(th, thd)`` (rad, rad/s,
        joint side); NaN throughout when the replay failed (a singular
        inertia matrix, a non-finite state, a count more than 10^6 pulses
        from the reference).

    Raises
    ------
    ValueError
        As :func:`identify_arm_payload`; ``beta`` or ``start_state`` of the
        wrong size or not finite; a window outside the log.
    """
    plant, rig, _, joints = _prior_of(prior, log, plant)
    substeps = _substeps_of(prior, joints, substeps)
    if rig is not log.rig:
        log = dataclasses.replace(log, rig=rig)
    k0, k1 = _window_samples(log, window_s, minimum=1)
    beta = np.asarray(beta, dtype=float).reshape(-1)
    if beta.shape != (plant.base.rank,) or not np.all(np.isfinite(beta)):
        raise ValueError(f"beta must be {plant.base.rank} finite base parameters, got shape "
                         f"{beta.shape}")
    row = beta if joints is None else np.concatenate([beta, joints])
    i = _currents_of(log, currents)
    sim = replay_arm(plant, row[None], rig, log.reference_counts()[k0:k1],
                     np.asarray(log.e_pulses, dtype=float)[k0:k1], i[k0:k1], gain=gain,
                     substeps=substeps, errors=False, bound=1e6, workers=1,
                     initial_state=np.asarray(start_state, dtype=float), final_state=True)
    return sim.final_state[0]
