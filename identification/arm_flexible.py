"""Flexible joints and backlash of any serial arm, identified from position-only logs.

The n-joint form of :mod:`identification.flexible` (issue 23: the compliant
rigs' features carried to any arm).  The plant is the robot model's two-mass
arm (:func:`plant.simulation.arm.arm_plant` with ``flexible=True``: per joint a motor of
reflected inertia ``Ia = Jm k^2`` and the link joined by a spring K and a
damper D through a gearbox dead zone of width b; the encoders read the
motors).  The searched vector is, with r base parameters and n joints::

    x = [beta (r), log10 K (n), D (n), Ia (n), (b (n)), unknown friction (u)]

``beta`` is the **rigid-equivalent** base parameters (link plus the
reflected motor inertias, exactly as the rigid model defines them, so every
consumer of beta -- the computed-torque controller first -- keeps working);
the link's own beta is ``beta - Ia @ columns``
(:attr:`plant.simulation.arm.ArmPlant.motor_inertia_columns`).  The stiffnesses are
searched on a log scale (they span decades); the drive friction the sidecar
does not know acts on the motor.

The box (:class:`ArmFlexibleSpace`) comes from the rigid fit, not from
constants: with ``M_jj`` the rigid-equivalent diagonal inertia over the
log's configurations, ``Ia_j`` lies in ``[0.02, 0.95] min M_jj``, the link
mode ``sqrt(K_j / M_jj) / 2 pi`` in ``[2, MAX_MODE_HZ]`` Hz, and ``D_j`` below
``sqrt(K_max M_jj) / 2`` (damping ratios far above any gearbox's).  The RK4
substeps per sample follow from the box's fastest motor-side eigenvalue
(:func:`identification.flexible.flexible_substeps`' rule, ``H_OMEGA``).

Procedure (:func:`fit_flexible_arm`): a start pool of link modes crossed
with reflected motor inertias (equal on all joints, then drawn per joint
from a fixed seed) at the rigid beta and light damping, evaluated as one
batch (in the backlash space, at each width of :data:`ARM_BACKLASH_GRID`);
the best :data:`N_STARTS` refined by the batched Levenberg--Marquardt of
:mod:`identification.refinement` through the predictor-gain continuation of
:data:`identification.flexible.CONTINUATION_GAINS` (a strongly corrected
replay first: few local minima), then at the default gain.  The first
gain's refinement ends when its start of lowest cost has converged
(``refine(..., leader_stop=True)``): the starts still iterating then mostly
creep along one flat valley toward the same point.  The model choice
(:func:`identification.arm.identify_arm`, ``model='auto'``) compares the
rigid and the flexible fits on held-back blocks
(:func:`identification.refinement.held_back_mask`) by the tests of
:class:`identification.model_choice.ModelImprovement` (the cost ratio,
:data:`identification.model_choice.CHOICE_RATIO`, a paired t test over the
blocks, :data:`identification.model_choice.CHOICE_T`, the quantisation floor,
:data:`identification.model_choice.ARM_FLOOR_FACTOR`, and the excess over it),
adds the backlash when the model chosen so far leaves more than that floor,
says which model and why,
and flags a chosen model above ``INADEQUATE_FACTOR`` floors.

Source: M. W. Spong, "Modeling and control of elastic joint robots", J. Dyn.
Syst. Meas. Control 109 (1987); backlash as a dead zone: M. Nordin and P.-O.
Gutman, Automatica 38 (2002); the prediction-error method with held-back
data: L. Ljung, *System Identification*, 2nd ed. (1999), sec. 7.3 and 16.4.
"""
from __future__ import annotations

import math

import numpy as np

from plant.simulation.arm import arm_plant, link_mode_bound, symmetric_from_lower

from .flexible import CONTINUATION_FTOL, CONTINUATION_GAINS, H_OMEGA, scan_joints
from .friction import FRICTION_COMPONENTS, friction_layout
from .refinement import BOX_EDGE, DEFAULT_GAIN, MaskedProblem, refine_through_gains

__all__ = ["ArmFlexibleSpace", "fit_flexible_arm", "MAX_MODE_HZ", "N_STARTS", "ARM_BACKLASH_GRID",
           "IA_FRACTION_BOUNDS", "IA_FRACTION_MAX", "H_REAL",
           "inertia_matrices", "diagonal_inertias", "arm_joint_intervals"]

#: Highest link mode ``sqrt(K / M_jj) / 2 pi`` (Hz) of the search box: industrial
#: gearboxes give 10-40 Hz (the paper's PUMA: 27-32 Hz); 60 Hz keeps a margin and
#: the RK4 substeps few.
MAX_MODE_HZ = 60.0

#: Starts refined from the pool (measured: 4 missed a joint's stiffness basin on a heavily
#: damped two-joint draw that 12 found).  Tried and not kept: 16 starts from 64 random
#: link modes (``bench_arms.py --compliant``, seed 20261122): the first planar draw's
#: worst well-excited error went from 4.6 % to 0.23 % and its K errors from 58 / 683 % to
#: 16 / 9 %, but the second's (2.99 mrad of backlash, fitted without) from 0.38 % to 1.3 %
#: and its joint-2 K error from 4.5 % to 4400 % -- a lower cost further from the truth.
N_STARTS = 8

#: Box of the reflected motor inertia ``Ia_j = Jm_j k_j^2`` as fractions of the
#: smallest rigid-equivalent diagonal inertia ``min M_jj`` over the log.  Light motors
#: behind low ratios reflect little: the independent simulator's arms reach 3.4 % (a
#: planar draw at 6.4 %, outside an earlier 10 % bound, was fitted with K 58 / 683 % off
#: and a well-excited base parameter 4.6 % off; 3.8 / 2.9 % and 0.06 % inside this one).
#: The lower bound sets the fastest motor mode and so the RK4 substeps.  A fit that ends
#: on the upper bound is refitted with it at :data:`IA_FRACTION_MAX`.
IA_FRACTION_BOUNDS = (0.02, 0.95)

#: The upper bound of ``Ia`` (fraction of the smallest diagonal inertia) when a fit ends on
#: :data:`IA_FRACTION_BOUNDS`' (:meth:`ArmFlexibleSpace.at_motor_inertia_bound`).  Heavy
#: motors behind high ratios reflect nearly all of a joint's inertia (a wrist's motor, or
#: joint 3 of the random chain 20262916 of ``benchmarks/bench_arms.py``); the bound
#: stops short of 1, where the link model's inertia vanishes, and
#: :meth:`ArmFlexibleSpace.feasible` rejects every candidate whose link model is not
#: positive definite or too fast for the fit's RK4 steps.  Not the first box: the fits'
#: Levenberg-Marquardt steps scale with it, and on the committed near-floor compliant log of
#: ``tests/test_arm_flexible.py`` the wider first box left the springs' fit above the
#: rigid model's held-back cost.
IA_FRACTION_MAX = 0.999

#: ``|lambda| h`` of RK4 on the fast real pole of a heavily damped light motor (a decaying
#: transient: RK4's amplification 0.375 against the exact 0.368 at 1; stable to 2.78).
H_REAL = 1.0

#: Backlash widths (rad) tried from the spring fit's point and with the start pool.
ARM_BACKLASH_GRID = (0.5e-3, 1.5e-3, 3e-3)

# the start pool: link modes (Hz) equal on all joints, then this many drawn per joint
_POOL_MODES_HZ = (4.0, 8.0, 16.0, 32.0)
_POOL_FRACTIONS = (0.2, 0.5, 0.85)
_POOL_RANDOM = 32
_POOL_SEED = 20261122
_START_ZETA = 0.05


class ArmFlexibleSpace:
    """The searched vector of a flexible arm, its box and its map to the plant's lanes.

    Parameters
    ----------
    log : plant.logs.arm_log.ArmLog
    rigid_plant : plant.simulation.arm.ArmPlant
        The log's rigid arm (its model and base parameters).
    beta : array_like, shape (r,)
        The rigid fit's base parameters (the diagonal inertias of the box).
    friction_bounds : array_like, shape (u, 2)
        Box of the unknown joint-side friction components
        (:func:`identification.friction.friction_layout`'s order).
    backlash : bool
        Search a backlash width per joint.

    Raises
    ------
    ValueError
        When the rigid beta gives no positive diagonal inertia on the log.
    """

    def __init__(self, log, rigid_plant, beta, friction_bounds, *, backlash=False):
        self.log = log
        self.rigid = rigid_plant
        self.known, self.unknown = friction_layout(log.rig)
        self.plant = arm_plant(rigid_plant.model, rigid_plant.base,
                               lane_friction=bool(self.unknown), flexible=True)
        self.backlash = bool(backlash)
        self.r = rigid_plant.base.rank
        self.n = rigid_plant.n_joints
        self.friction_bounds = np.asarray(friction_bounds, dtype=float).reshape(-1, 2)
        self.configurations = _configurations(log)
        M = diagonal_inertias(rigid_plant, beta, self.configurations)
        if not np.all(M > 0):
            raise ValueError("the rigid fit's inertia matrix is not positive on the log: "
                             "no flexible joints to fit")
        self.m_min, self.m_max = M.min(axis=0), M.max(axis=0)

    @property
    def k(self) -> int:
        """Length of x."""
        return self.r + (4 if self.backlash else 3) * self.n + len(self.unknown)

    def names(self) -> list:
        """Names of x's components (base parameters, joints, friction)."""
        j = self.rigid.model.joint_names
        out = list(self.rigid.base.names)
        out += [f"log10_K_{a}" for a in j] + [f"D_{a}" for a in j] + [f"Ia_{a}" for a in j]
        if self.backlash:
            out += [f"b_{a}" for a in j]
        out += [f"{FRICTION_COMPONENTS[w]}_{j[i]}" for i, w in self.unknown]
        return out

    def bounds(self, beta_bounds, ia_max=None) -> np.ndarray:
        """The box of x, shape (k, 2) (module docstring).

        Parameters
        ----------
        beta_bounds : array_like, shape (r, 2)
            The rigid fit's box of beta.
        ia_max : float, optional
            Upper bound of ``Ia`` as a fraction of the smallest diagonal
            inertia; default the upper end of :data:`IA_FRACTION_BOUNDS`
            (:data:`IA_FRACTION_MAX` after a fit on that bound).
        """
        w_hi = 2 * math.pi * MAX_MODE_HZ
        ia_lo, ia_hi = IA_FRACTION_BOUNDS
        if ia_max is not None:
            ia_hi = float(ia_max)
        k_lo = np.log10(ia_lo * self.m_min * (2 * math.pi * 2.0) ** 2)
        k_hi = np.log10(self.m_max * w_hi ** 2)
        d_hi = 0.5 * np.sqrt(10.0 ** k_hi * self.m_max)
        rows = [np.asarray(beta_bounds, dtype=float)[:self.r],
                np.column_stack([k_lo, k_hi]), np.column_stack([np.zeros(self.n), d_hi]),
                np.column_stack([ia_lo * self.m_min, ia_hi * self.m_min])]
        if self.backlash:
            rows.append(np.tile([0.0, 0.01], (self.n, 1)))
        rows.append(self.friction_bounds)
        return np.vstack(rows)

    def at_motor_inertia_bound(self, box, x, edge=None) -> bool:
        """Whether x's motor inertia ``Ia`` of some joint sits on the box's upper bound.

        Parameters
        ----------
        box : ndarray, shape (k, 2)
            The box of x (:meth:`bounds`).
        x : array_like, shape (k,)
            A point of the two-mass fit (beta, K, D, Ia, ...).
        edge : float or None
            "On the bound": within this fraction of the bound's width; None:
            :data:`identification.refinement.BOX_EDGE`, the rule the guessed box's
            widening uses.

        Returns
        -------
        bool
        """
        if edge is None:
            edge = BOX_EDGE
        cols = slice(self.r + 2 * self.n, self.r + 3 * self.n)
        hi = np.asarray(box, dtype=float)[cols, 1]
        width = hi - np.asarray(box, dtype=float)[cols, 0]
        return bool(np.any(np.asarray(x, dtype=float)[cols] >= hi - edge * width))

    def substeps(self, box) -> int:
        """RK4 substeps per sample for every candidate of the box (fastest motor mode).

        The motor of a candidate, ``Ia th'' + D th' + K th = ...``, has
        either a complex pair of modulus ``sqrt(K / Ia)``, which RK4 follows
        accurately at ``|lambda| h <= H_OMEGA``
        (:data:`identification.flexible.H_OMEGA`), or -- heavily damped
        against a light motor -- two real poles, the fast one within
        ``2 a``, ``a = D / (2 Ia)``, a decaying transient that RK4 follows
        to a few per cent per step at ``|lambda| h <=`` :data:`H_REAL`.
        Over the box: ``h = Ts / substeps`` with ``sqrt(K_max / Ia_min) h <=
        H_OMEGA`` and ``2 a_max h <= H_REAL``, ``a_max = D_max / (2 Ia_min)``.
        (One bound ``(a + sqrt(K / Ia + a^2)) h <= H_OMEGA`` for both took
        twice the steps at the light-motor corner of the box for no change
        of the prediction errors beyond 0.004 pulse: tested.)

        Parameters
        ----------
        box : ndarray, shape (k, 2)
            The box of x (:meth:`bounds`).

        Returns
        -------
        int
            At least 2.
        """
        r, n = self.r, self.n
        k_max = 10.0 ** box[r:r + n, 1]
        d_max = box[r + n:r + 2 * n, 1]
        ia_min = box[r + 2 * n:r + 3 * n, 0]
        ts = self.log.rig.sample_time_s
        oscillating = float(np.max(np.sqrt(k_max / ia_min))) * ts / H_OMEGA
        real = float(np.max(d_max / ia_min)) * ts / H_REAL
        return max(2, int(math.ceil(max(oscillating, real))))

    def to_lanes(self, X) -> np.ndarray:
        """The plant's rows ``[beta, K, D, Ia, b, (friction 3 n)]`` of vectors X.

        Parameters
        ----------
        X : array_like, shape (m, k)

        Returns
        -------
        ndarray, shape (m, plant.n_parameters)
        """
        X = np.atleast_2d(np.asarray(X, dtype=float))
        r, n = self.r, self.n
        o = r + 3 * n
        b = X[:, o:o + n] if self.backlash else np.zeros((X.shape[0], n))
        o += n if self.backlash else 0
        cols = [X[:, :r], 10.0 ** X[:, r:r + n], X[:, r + n:r + 3 * n], b]
        if self.unknown:
            F = np.tile(self.known.reshape(-1), (X.shape[0], 1))
            for i, (j, w) in enumerate(self.unknown):
                F[:, 3 * j + w] = X[:, o + i]
            cols.append(F)
        return np.hstack(cols)

    def joints(self, x) -> dict:
        """The joints of x in the result's keys (lists of n floats; backlash None without it).

        Parameters
        ----------
        x : array_like, shape (k,)

        Returns
        -------
        dict
        """
        x = np.asarray(x, dtype=float)
        r, n = self.r, self.n
        return dict(joint_stiffness_Nm_per_rad=(10.0 ** x[r:r + n]).tolist(),
                    joint_damping_Nms_per_rad=x[r + n:r + 2 * n].tolist(),
                    motor_inertia_reflected_kgm2=x[r + 2 * n:r + 3 * n].tolist(),
                    joint_backlash_rad=(x[r + 3 * n:r + 4 * n].tolist() if self.backlash else None))

    def with_backlash(self, x, widths) -> np.ndarray:
        """Points of the backlash space from a point of this one (no backlash), one per width.

        Parameters
        ----------
        x : array_like, shape (k,)
            A point of this space (without backlash).
        widths : sequence of float
            Backlash widths (rad), the same on every joint.

        Returns
        -------
        ndarray, shape (len(widths), k + n)
        """
        x = np.asarray(x, dtype=float)
        o = self.r + 3 * self.n
        return np.array([np.concatenate([x[:o], np.full(self.n, w), x[o:]]) for w in widths])

    def pool(self, beta, friction, widths=(0.0,)) -> np.ndarray:
        """The start pool (module docstring).

        Parameters
        ----------
        beta : array_like, shape (r,)
            The rigid fit's base parameters.
        friction : array_like, shape (u,)
            The rigid fit's unknown friction components.
        widths : sequence of float
            Backlash widths (rad, the same on every joint) crossed with the
            link modes in a backlash space (ignored without backlash).

        Returns
        -------
        ndarray, shape (p, k)
            ``p`` link modes, times ``len(widths)`` in a backlash space.
        """
        n = self.n
        rng = np.random.default_rng(_POOL_SEED)
        lo, hi = IA_FRACTION_BOUNDS
        # (link modes, motor-inertia fractions of min M_jj): equal on all joints, then drawn
        # per joint (the two-mass dynamics hinge on both: a start at the right mode with the
        # wrong motor inertia predicts the log no better than a wrong mode)
        points = [(np.full(n, f), np.full(n, a)) for a in _POOL_FRACTIONS for f in _POOL_MODES_HZ]
        for _ in range(_POOL_RANDOM):
            f = np.exp(rng.uniform(np.log(3.0), np.log(50.0), n))
            a = np.exp(rng.uniform(np.log(lo), np.log(hi), n))
            points.append((f, a))
        mbar = np.sqrt(self.m_min * self.m_max)
        X = []
        for w in (widths if self.backlash else (None,)):
            for f, a in points:
                ia = np.clip(a, lo, hi) * self.m_min
                link = np.maximum(mbar - ia, 1e-3 * mbar)
                mu = ia * link / (ia + link)
                K = link * (2 * math.pi * f) ** 2
                D = 2 * _START_ZETA * np.sqrt(K * mu)
                parts = [beta, np.log10(K), D, ia]
                if self.backlash:
                    parts.append(np.full(n, float(w)))
                parts.append(friction)
                X.append(np.concatenate(parts))
        return np.array(X)


    def link_check(self, x, substeps, *, margin_rad=0.2, n_points=256):
        """Whether the link model of x is a robot near the log's configurations, and why not.

        A flexible fit can predict a log with a link model that is no robot
        outside the configurations the log visited, or one so nearly
        singular that its fastest mode escapes the integration that fitted
        it; its controller would then fail (:func:`identification.arm.identify_arm`
        rejects it).  Checked at the log's reference samples and
        ``n_points`` drawn uniformly (fixed seed) in the box of its ranges
        widened by ``margin_rad``: the link inertia matrix ``D_link(q)``
        (``beta - Ia @ columns``) is positive definite, and the fastest link
        mode (the largest ``w`` of ``det(diag(K) - w^2 D_link(q)) = 0``)
        satisfies ``w Ts / substeps <= 2 H_OMEGA`` (the RK4 steps of the fit
        resolve it; :data:`identification.flexible.H_OMEGA`).

        Parameters
        ----------
        x : array_like, shape (k,)
        substeps : int
            RK4 steps per sample of the fit.
        margin_rad : float
        n_points : int

        Returns
        -------
        (bool, str)
            The verdict and, when False, the reason.
        """
        x = np.asarray(x, dtype=float)
        qs = self.check_points(margin_rad, n_points)
        r, n = self.r, self.n
        ia = x[r + 2 * n:r + 3 * n]
        link = x[:r] - ia @ self.plant.motor_inertia_columns
        D = inertia_matrices(self.rigid, link, qs)
        eig = np.linalg.eigvalsh(D)
        if not np.all(eig[:, 0] > 0):
            return False, ("its link model (beta minus the motor inertias) has an inertia matrix "
                           "that is not positive definite near the log's configurations")
        w = link_mode_bound(x[r:r + n], D)
        w_max = 2 * H_OMEGA * int(substeps) / self.log.rig.sample_time_s
        if w > w_max:
            return False, (f"its link model has a mode at {w / (2 * math.pi):.0f} Hz near the "
                           f"log's configurations (a nearly singular link inertia matrix), beyond "
                           f"the {w_max / (2 * math.pi):.0f} Hz that the fit's {int(substeps)} RK4 "
                           "steps per sample resolve")
        return True, ""

    def check_points(self, margin_rad=0.2, n_points=256) -> np.ndarray:
        """Configurations of :meth:`link_check` and :meth:`feasible`, shape (p + n_points, n).

        The log's reference configurations (p = min(64, samples) along it) and
        ``n_points`` drawn uniformly (fixed seed) in the box of its ranges
        widened by ``margin_rad``.

        Parameters
        ----------
        margin_rad : float
            Widening of the box of the log's ranges (rad).
        n_points : int
            Configurations drawn in it.
        """
        key = (float(margin_rad), int(n_points))
        cache = self.__dict__.setdefault("_check_points", {})
        if key not in cache:
            q = np.asarray(self.log.q_ref, dtype=float)
            lo, hi = q.min(axis=0) - margin_rad, q.max(axis=0) + margin_rad
            rng = np.random.default_rng(_POOL_SEED)
            cache[key] = np.vstack([self.configurations, rng.uniform(lo, hi, (n_points, self.n))])
        return cache[key]

    def check_inertias(self, beta) -> np.ndarray:
        """Inertia matrices ``D(q; beta)`` at :meth:`check_points`, shape (m, p, n, n).

        ``D`` is affine in the base parameters (linear in the inertial
        parameters), so it is ``D(q; 0) + sum_k beta_k (D(q; e_k) - D(q; 0))``
        with the r + 1 matrices per configuration evaluated once
        (:func:`inertia_matrices`); a batch costs a tensor contraction
        instead of m p casadi calls (the same matrices to rounding).

        Parameters
        ----------
        beta : array_like, shape (m, r)
        """
        if "_check_basis" not in self.__dict__:
            E = np.vstack([np.zeros(self.r), np.eye(self.r)])
            M = inertia_matrices(self.rigid, E, self.check_points())  # (r + 1, p, n, n)
            self._check_basis = (M[0], M[1:] - M[0])
        d0, basis = self._check_basis
        B = np.atleast_2d(np.asarray(beta, dtype=float))[:, :self.r]
        return d0 + np.einsum("mk,kpij->mpij", B, basis, optimize=True)

    def feasible(self, X, substeps) -> np.ndarray:
        """Which candidates' link models are robots the fit's integration resolves, shape (m,).

        The screen of :meth:`link_check`, at its configurations
        (:meth:`check_points`), for every candidate of a batch: the fit
        never simulates a link model that is not positive definite near the
        log's configurations or whose fastest mode its RK4 steps cannot
        follow there, so that it cannot end on a link model that
        :meth:`link_check` rejects (but for one within rounding of a
        limit: the batch's matrices come from :meth:`check_inertias`).  It
        screened 16 of the log's own configurations: on the random compliant
        draw 20262912 of ``benchmarks/bench_arms.py``, a two-mass fit that
        predicted the held-back samples to the floor was then rejected by
        :meth:`link_check` for its link model, and the rigid model was kept.

        Parameters
        ----------
        X : array_like, shape (m, k)
        substeps : int
            RK4 steps per sample of the fit.
        """
        X = np.atleast_2d(np.asarray(X, dtype=float))
        r, n = self.r, self.n
        w_max = 2 * H_OMEGA * int(substeps) / self.log.rig.sample_time_s
        links = X[:, :r] - X[:, r + 2 * n:r + 3 * n] @ self.plant.motor_inertia_columns
        D = self.check_inertias(links)  # (m, p, n, n)
        out = np.all(np.linalg.eigvalsh(D)[:, :, 0] > 0, axis=1)
        if out.any():  # link_mode_bound of every positive definite candidate in one batch
            k = np.sqrt(10.0 ** X[out, r:r + n])[:, None]  # (m', 1, n)
            A = k[..., :, None] * np.linalg.inv(D[out]) * k[..., None, :]
            out[out] = np.sqrt(np.linalg.eigvalsh(A)[..., -1].max(axis=1)) <= w_max
        return out


def _configurations(log, n_points=64) -> np.ndarray:
    """Configurations evenly along the log's reference, shape (p, n)."""
    q = np.asarray(log.q_ref, dtype=float)
    idx = np.linspace(0, q.shape[0] - 1, min(n_points, q.shape[0])).astype(int)
    return q[idx]


def inertia_matrices(plant, beta, q, eig=False) -> np.ndarray:
    """Inertia matrices ``D(q; beta)`` of an arm at configurations q, shape (p, n, n).

    One call of the plant's casadi dynamics function mapped over the
    configurations (casadi's ``Function.map``; the same expressions, so
    the same numbers as one call per configuration).

    Parameters
    ----------
    plant : plant.simulation.arm.ArmPlant
    beta : array_like, shape (r,) or (m, r)
        Base parameters; a batch of m gives shape (m, p, n, n) (or (m, p)).
    q : array_like, shape (p, n)
    eig : bool
        Return the smallest eigenvalue per configuration instead, shape (p,).
    """
    fn = plant.dynamics_function
    n = plant.n_joints
    q = np.atleast_2d(np.asarray(q, dtype=float))
    beta = np.asarray(beta, dtype=float)
    batch = beta.ndim == 2
    B = np.atleast_2d(beta)[:, :plant.base.rank]
    m, p = B.shape[0], q.shape[0]
    sc = np.stack([np.sin(q), np.cos(q)], axis=2).reshape(p, 2 * n).T  # (2n, p)
    lower = np.asarray(_mapped(fn, m * p)(np.tile(sc, (1, m)), np.zeros((n, 1)),
                                          np.repeat(B.T, p, axis=1))[0])  # (n(n+1)/2, m p)
    out = symmetric_from_lower(lower.T, n)  # (m p, n, n)
    out = out.reshape(m, p, n, n) if batch else out
    return np.linalg.eigvalsh(out)[..., 0] if eig else out


_MAPPED = {}


def _mapped(fn, count):
    """``fn.map(count)``, kept per function and count."""
    key = (id(fn), int(count))
    f = _MAPPED.get(key)
    if f is None or f[0] is not fn:
        if len(_MAPPED) > 64:
            _MAPPED.clear()
        f = _MAPPED[key] = (fn, fn.map(int(count)))
    return f[1]


def diagonal_inertias(plant, beta, q) -> np.ndarray:
    """Diagonal of the inertia matrix ``D(q; beta)`` at configurations q, shape (p, n).

    Parameters
    ----------
    plant : plant.simulation.arm.ArmPlant
    beta : array_like, shape (r,)
    q : array_like, shape (p, n)
    """
    return np.diagonal(inertia_matrices(plant, beta, q), axis1=1, axis2=2).copy()


def fit_flexible_arm(space, problem_at, box, *, starts=None, pool=None, mask=None,
                     max_iter=40, ftol=1e-6, continuation=CONTINUATION_GAINS, n_starts=N_STARTS,
                     callback=None, poll=None, leader_stop=True):
    """Fit a flexible arm: start pool, gain continuation, final refinement (module docstring).

    Parameters
    ----------
    space : ArmFlexibleSpace
    problem_at : callable
        ``problem_at(gain)`` -> the prediction-error problem at that
        output-injection gain (residuals of x batches).
    box : ndarray, shape (k, 2)
    starts : array_like, shape (s, k), optional
        Starts refined anyway (e.g. the held-back fit's point).
    pool : array_like, shape (p, k), optional
        Candidates evaluated at the first gain; their best ``n_starts`` are refined.
    mask : ndarray of bool, optional
        Fit only these residuals (the model choice's fitted samples).
    max_iter : int
    ftol : float
        Tolerance of the final refinement.
    continuation : sequence of float
        Gains refined at first, in order (none: the default gain only).
    n_starts : int
    callback : callable, optional
        :func:`~identification.refinement.refine`'s ``callback(start,
        n_starts, x, cost) -> bool`` at every gain; True stops the fit
        (``refine.interrupted``).
    poll : callable, optional
        ``poll() -> bool`` after every refinement iteration; True stops the
        fit the same way.
    leader_stop : bool
        End the first gain's refinement when its start of lowest cost has
        converged (:func:`~identification.refinement.refine`'s
        ``leader_stop``); False runs every start until it converges.

    Returns
    -------
    dict
        ``x`` (k,), ``cost`` (the final fit's cost), ``refine``
        (:class:`~identification.refinement.RefineResult` of the final stage),
        ``nfev``.
    """
    def problem(g):
        p = problem_at(g)
        return p if mask is None else MaskedProblem(p, mask)

    gains = list(continuation) + [DEFAULT_GAIN]
    S = np.empty((0, box.shape[0])) if starts is None else np.atleast_2d(starts)
    nfev = 0
    if pool is not None and len(pool):
        pr = problem(gains[0])
        P = np.clip(np.atleast_2d(pool), box[:, 0], box[:, 1])
        R = pr.residuals(P)
        nfev += P.shape[0]
        c = np.einsum("ij,ij->i", R, R)
        S = np.vstack([S, P[np.argsort(c, kind="stable")[:max(1, n_starts)]]])
    # lazy Jacobians: a rejected step's columns are not simulated -- a third to a half of
    # the steps of these fits are rejected (many parameters, starts far from their optimum)
    ref = refine_through_gains(problem, S, box, gains, max_iter=max_iter, ftol=ftol,
                               stage_ftol=CONTINUATION_FTOL, callback=callback, lazy_jacobian=True,
                               poll=poll, leader_stop=leader_stop)
    x = np.asarray(ref.x, dtype=float)
    return dict(x=x, cost=float(ref.fun), refine=ref, nfev=nfev + int(ref.nfev))


def arm_joint_intervals(log, x, space, box, residuals, *, allowance=None):
    """Ranges of each joint's K, D and ``Ia`` that predict an arm's log as well as its fit.

    The n-joint form of :func:`identification.flexible.joint_intervals` (its
    rationale and source): each joint's stiffness, damping and reflected motor
    inertia is scanned by :func:`identification.flexible.floor_ranges` with
    the others held (beta is rigid-equivalent, so a heavier motor is a
    lighter link), and the values whose prediction-error cost stays within
    ``allowance`` of the fit's -- by default the model choice's
    ``(ARM_FLOOR_FACTOR - 1)`` quantisation floors -- are the range; the
    combinations of an open joint's range ends that the log allows are its
    ``corners``.  The result names the springs and motors the log leaves
    open in its ``warnings``; the arm's flexible CTC checks its design at
    the corners (:func:`ctc.arm.check_scenarios`), as the PUMA 560 path's
    does (:func:`ctc.flexible.log_range_scenarios`).

    Parameters
    ----------
    log : plant.logs.arm.ArmLog
        The identified log.
    x : array_like, shape (k,)
        The flexible fit (``[beta, log10 K, D, Ia, (b), friction]``).
    space : ArmFlexibleSpace
        Its space.
    box : ndarray, shape (k, 2)
        Its box.
    residuals : callable
        ``residuals(X) -> (m, n_res)`` of the fit's prediction-error problem
        (whole log, the final gain).
    allowance : float, optional
        Cost allowance (pulses^2).

    Returns
    -------
    dict
        As :func:`identification.flexible.joint_intervals`
        (:func:`identification.flexible.range_record` with ``corners``):
        ``names`` ``K_<joint>_Nm_per_rad``, ``D_<joint>_Nms_per_rad``,
        ``Ia_<joint>_kgm2`` (3 n values each, K, then D, then Ia).
    """
    x = np.asarray(x, dtype=float)
    r, n = space.r, space.n

    def physical(X):  # (m, k) -> (m, 3 n): K, D, Ia
        X = np.atleast_2d(X)
        return np.concatenate([10.0 ** X[:, r:r + n], X[:, r + n:r + 3 * n]], axis=1)

    names = ([f"K_{j}_Nm_per_rad" for j in log.joint_names]
             + [f"D_{j}_Nms_per_rad" for j in log.joint_names]
             + [f"Ia_{j}_kgm2" for j in log.joint_names])
    return scan_joints(residuals, x, list(range(r, r + 3 * n)), n, box, physical, names,
                       n * log.n_samples,
                       "each joint's K, D and Ia scanned one at a time, the others held "
                       "(identification.arm_flexible.arm_joint_intervals)",
                       allowance=allowance)
