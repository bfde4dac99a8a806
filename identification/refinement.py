"""Refinement after the GA: Gauss-Newton on logged-input prediction errors.

Why not polish the output error of eq. 4 directly?  The simulated closed loop
quantises its own feedback, so a change of f of one part in 10^7 already
flips whole pulses here and there: the integer output error has a floor of
~1000 pulses^2 (paper log) around the true f, as rough as a random function
below ~1 % of f.  No local method can descend it, and the paper's GA alone
therefore stops at a few per cent (its "alteration").

The P controller's current is known exactly from the logged integer error
(``i = P e``).  Driving the model with that current (plus a weak output
injection, :func:`plant.prediction_errors`) removes the quantised feedback
from the simulation: the model's continuous encoder count then depends
smoothly on f, and the prediction errors against the log's count intervals
are a smooth least-squares problem.

The solver is a bounded Levenberg-Marquardt (Marquardt's diagonal scaling;
J. J. More, "The Levenberg-Marquardt algorithm: implementation and theory",
1978) run on all starts *at once*: every iteration evaluates, for every
active start, its trial point and the k forward-difference columns of the
Jacobian there, as one batch of ``n_starts (k + 1)`` candidates in the SIMD
lanes of the simulation core.  A trial point that lowers the cost is
accepted together with its Jacobian (no re-evaluation); a rejected one
raises the damping.  Starts that converge to the same point are merged (the
costlier is dropped), so the usual case -- the GA's best individuals all in
one basin -- costs little more than one start.  With ``lazy_jacobian`` the
trial points are simulated first and only the accepted ones' columns after
them (the same iterates): the fits of compliant arms, with many parameters
and starts far from their optimum, reject a third to a half of their steps
(:func:`identification.arm_flexible.fit_flexible_arm` uses it).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

import plant
from plant import STATUS_OK

from .filtering import apply_lowpass, lowpass_sos

__all__ = ["PredictionErrorProblem", "RefineResult", "refine", "refine_through_gains", "DEFAULT_GAIN", "MaskedProblem",
           "held_back_mask", "HOLD_BLOCK_S", "HOLD_EVERY", "widen_guessed_box", "BOX_WIDENINGS",
           "BOX_EDGE"]

#: Length (s) of the held-back blocks of the model choice (:func:`held_back_mask`).
HOLD_BLOCK_S = 0.1

#: Every ``HOLD_EVERY``-th block of :data:`HOLD_BLOCK_S` seconds is held back (not
#: fitted, only predicted).
HOLD_EVERY = 4


def held_back_mask(n_samples, n_joints, sample_time_s):
    """Residual masks of the fitted and of the held-back samples (model choice).

    Every :data:`HOLD_EVERY`-th block of :data:`HOLD_BLOCK_S` seconds is held
    back: its residuals are not fitted (the replay still runs through it),
    and the cost on them judges a model by samples it did not fit.

    Parameters
    ----------
    n_samples, n_joints : int
        Residuals are sample-major, ``n_samples * n_joints`` of them.
    sample_time_s : float

    Returns
    -------
    fitted, held : ndarray of bool, shape (n_samples * n_joints,)
    """
    block = max(1, int(round(HOLD_BLOCK_S / float(sample_time_s))))
    held = (np.arange(int(n_samples)) // block) % HOLD_EVERY == HOLD_EVERY - 1
    return np.repeat(~held, int(n_joints)), np.repeat(held, int(n_joints))


class MaskedProblem:
    """A prediction-error problem restricted to some residuals (e.g. the fitted samples).

    Parameters
    ----------
    problem : object
        Has ``residuals(X) -> (m, n_residuals)`` and ``nfev``.
    mask : ndarray of bool, shape (n_residuals,)
        The residuals kept.
    """

    def __init__(self, problem, mask):
        self.problem = problem
        self.mask = mask

    @property
    def nfev(self):
        """Candidates simulated by the underlying problem."""
        return self.problem.nfev

    def residuals(self, X):
        """The kept residuals of a batch.

        Parameters
        ----------
        X : array_like, shape (m, k)

        Returns
        -------
        ndarray, shape (m, mask.sum())
        """
        R = self.problem.residuals(X)
        return R[..., self.mask]

#: Output-injection gain of the replay, as a fraction of the P gain.
DEFAULT_GAIN = 0.02

#: Relative forward-difference step of the Jacobian (of the box width).
FD_STEP = 1e-6
#: Two starts closer than this (per parameter, relative to the box width) are merged.
MERGE_TOL = 1e-5


class PredictionErrorProblem:
    """Least-squares residuals r(x) = prediction errors of the replay, in batches.

    Parameters
    ----------
    log : plant.ExperimentLog
        The logged experiment.
    to_f : callable, optional
        Maps searched vectors x (m, k) to f (m, 9) (identity by default).
    to_state : callable, optional
        Maps x (m, k + 4) to the state (q2, q3, qd2, qd3) (m, 4) at the log's
        first sample when the initial state is estimated with the parameters
        (window logs).
    gain : float
        Output-injection gain (:func:`plant.prediction_errors`).
    substeps : int
        RK4 steps per sample.
    lowpass_hz : float, optional
        Low-pass both sides (as :class:`identification.objective.OutputError`).
    workers : int, optional
        Threads of the simulation.
    controller : object, optional
        The controller that ran (:func:`plant.prediction_errors`: a non-P
        controller is replayed by its logged currents).
    plant : plant.simulation.plants.Plant, optional
        The simulated plant (default rigid).
    to_plant_parameters : callable, optional
        Maps x (m, k) to the plant parameters beyond f (a dict of arrays,
        :func:`plant.prediction_errors`).

    Attributes
    ----------
    nfev : int
        Simulations run so far by this problem (a counter, nothing else is
        kept between calls).
    """

    def __init__(self, log, *, to_f=None, to_state=None, gain=DEFAULT_GAIN, substeps=1,
                 lowpass_hz=None, workers=None, controller=None, plant=None,
                 to_plant_parameters=None):
        self.log = log
        self.controller = controller
        self.plant = plant
        self.to_plant_parameters = to_plant_parameters
        self.to_state = to_state
        self.to_f = to_f if to_f is not None else (lambda X: np.asarray(X, dtype=float))
        self.gain = float(gain)
        self.substeps = int(substeps)
        self.workers = workers
        self.nfev = 0
        self._sos = None if lowpass_hz is None else lowpass_sos(lowpass_hz, log.rig.sample_time_s)

    def residuals(self, X) -> np.ndarray:
        """Residual vectors of a batch of points.

        Parameters
        ----------
        X : array_like, shape (m, k) or (k,)

        Returns
        -------
        ndarray, shape (m, 2 n_samples) or (2 n_samples,)
            Prediction errors (pulses), failed candidates filled with the
            divergence bound.
        """
        X = np.asarray(X, dtype=float)
        single = X.ndim == 1
        X = np.atleast_2d(X)
        F = np.asarray(self.to_f(X), dtype=float).reshape(X.shape[0], 9)
        X0 = None if self.to_state is None else np.asarray(self.to_state(X), dtype=float)
        eps, status = plant.prediction_errors(
            self.log, F, gain=self.gain, substeps=self.substeps, workers=self.workers,
            initial_state=X0, controller=self.controller, plant=self.plant,
            plant_parameters=None if self.to_plant_parameters is None
            else self.to_plant_parameters(X))
        self.nfev += F.shape[0]
        if self._sos is not None:
            ok = status == STATUS_OK
            if np.any(ok):
                eps[ok] = apply_lowpass(eps[ok], self._sos)
        R = eps.reshape(F.shape[0], -1)
        return R[0] if single else R


@dataclass
class RefineResult:
    """Outcome of :func:`refine` (scipy ``OptimizeResult`` vocabulary).

    Attributes
    ----------
    x : ndarray, shape (k,)
        Refined parameters (the best start's).
    fun : float
        Sum of squared prediction errors at x (pulses^2).
    nfev : int
        Simulations run (residuals and Jacobian columns).
    nit : int
        Iterations run (each a batch of simulations; with ``lazy_jacobian``
        the accepted steps' columns are batches of their own).
    success : bool
        False when interrupted.
    message : str
    start_costs, costs : ndarray, shape (n_starts,)
        Cost at each start point and at its end (a merged start ends at the
        cost of the start it merged into).
    merged : list of (int, int)
        ``(dropped, kept)`` start indices (0-based) of merged starts.
    interrupted : bool
    jac : ndarray, shape (n_residuals, k) or None
        Forward-difference Jacobian of the residuals at x (the one the last
        accepted step was taken with); None if no point was evaluated.
    residuals : ndarray, shape (n_residuals,) or None
        Residual vector at x (prediction errors, pulses; for the standard
        errors, :mod:`identification.uncertainty`).
    """

    x: np.ndarray
    fun: float
    nfev: int = 0
    nit: int = 0
    success: bool = True
    message: str = ""
    start_costs: np.ndarray = field(default_factory=lambda: np.empty(0))
    costs: np.ndarray = field(default_factory=lambda: np.empty(0))
    merged: list = field(default_factory=list)
    interrupted: bool = False
    jac: np.ndarray | None = None
    residuals: np.ndarray | None = None


def _fd_points(x, lo, hi):
    """x and the k forward-difference points (inward at the upper bound); steps h (k,)."""
    h = FD_STEP * (hi - lo)
    h = np.where(x + h > hi, -h, h)
    return np.vstack([x, x + np.diag(h)]), h


def _lm_step(J, r, lam, x, lo, hi):
    """Bounded Levenberg-Marquardt step with Marquardt scaling; free variables only."""
    g = J.T @ r
    A = J.T @ J
    d = np.maximum(np.diag(A), 1e-30)
    # variables at a bound whose descent direction points out of the box stay fixed
    free = ~(((x <= lo) & (g > 0)) | ((x >= hi) & (g < 0)))
    step = np.zeros_like(x)
    if np.any(free):
        Af = A[np.ix_(free, free)] + lam * np.diag(d[free])
        try:
            step[free] = np.linalg.solve(Af, -g[free])
        except np.linalg.LinAlgError:
            step[free] = -g[free] / (d[free] * (1.0 + lam))
    return np.clip(x + step, lo, hi)


def refine_through_gains(problem_at, starts, bounds, gains, *, max_iter=40, ftol=1e-10,
                         stage_ftol=1e-4, callback=None, lazy_jacobian=False, poll=None,
                         leader_stop=False):
    """:func:`refine` through a continuation in the predictor's output-injection gain.

    Each gain's refinement starts at the previous one's optimum (a homotopy:
    strongly corrected replays first, few local minima; L. Ljung, *System
    Identification*, 2nd ed., sec. 7.3); the last gain's result is returned.

    Parameters
    ----------
    problem_at : callable
        ``problem_at(gain)`` -> the prediction-error problem at that gain.
    starts : array_like, shape (n_starts, k)
        Start points of the first gain.
    bounds : array_like, shape (k, 2)
    gains : sequence of float
        Gains in order; the last is the final fit's.
    max_iter : int
    ftol : float
        Tolerance of the last gain's refinement.
    stage_ftol : float
        Tolerance of the intermediate ones.
    callback : callable, optional
        :func:`refine`'s, at every gain; True stops the continuation (the
        stopped refinement's best point, ``interrupted=True``).
    lazy_jacobian, poll
        :func:`refine`'s, at every gain.
    leader_stop : bool
        :func:`refine`'s, at the first gain (the only one with several
        starts).

    Returns
    -------
    RefineResult
        The last refinement's, ``nfev`` summed over the gains.
    """
    x = np.atleast_2d(np.asarray(starts, dtype=float))
    nfev = 0
    ref = None
    for i, g in enumerate(gains):
        last = i == len(gains) - 1
        ref = refine(problem_at(g), x, bounds, max_iter=max_iter, ftol=ftol if last else stage_ftol,
                     callback=callback, lazy_jacobian=lazy_jacobian, poll=poll,
                     leader_stop=leader_stop and i == 0)
        nfev += int(ref.nfev)
        x = np.asarray(ref.x, dtype=float)[None]
        if ref.interrupted:
            break
    ref.nfev = nfev
    return ref


def refine(problem, starts, bounds, *, max_iter=40, ftol=1e-10, xtol=1e-10, callback=None,
           lazy_jacobian=False, poll=None, leader_stop=False):
    """Refine all starts together by bounded Levenberg-Marquardt; return the best.

    Parameters
    ----------
    problem : PredictionErrorProblem
        The residuals.
    starts : array_like, shape (n_starts, k)
        Start points (e.g. the GA's best individuals), clipped into ``bounds``.
    bounds : array_like, shape (k, 2)
        Box of x.
    max_iter : int
        Iterations at most: batches of one trial point and its k
        forward-difference Jacobian columns per active start.
    ftol : float
        A start converges when an accepted step lowers its cost by less than
        ``ftol`` relative.
    xtol : float
        ... or moves it by less than ``xtol`` of the box width.
    callback : callable, optional
        ``callback(start, n_starts, x, cost) -> bool`` once per start when it
        converges, is merged, is stopped by ``leader_stop`` or runs out of
        iterations (``start`` 1-based); True stops the refinement.
    lazy_jacobian : bool
        Simulate an iteration's trial points alone, as one batch, and then
        the Jacobian columns of the trials whose step is accepted, as a
        second: a rejected step's columns are never simulated (with the
        default, they are, together with its trial point, and thrown away).
        The same iterates, costs and Jacobians to the bit, fewer
        simulations where many steps are rejected, at the price of a second
        batch of simulations per accepted step (the first iteration takes
        each start point with its columns in one batch; a start that stops
        simulates the columns at its end only if it is the best).
    poll : callable, optional
        ``poll() -> bool`` after every iteration; True stops the refinement
        as the callback's True does (a Ctrl-C then takes effect within an
        iteration, not when a start ends).
    leader_stop : bool
        End the refinement as soon as the start of lowest cost has
        converged: the starts still iterating lie above it, and Levenberg--
        Marquardt only lowers a start's cost, so they could change the
        result only by descending past a converged local minimum.  Measured
        on the flexible fits of compliant arms
        (:func:`identification.arm_flexible.fit_flexible_arm`): the starts
        that go on after the leader converges are mostly creeping along one
        flat valley toward the leader's own point, for most of the
        iterations.  (Successive halving -- dropping the worse half of the
        starts at fixed iterations -- was tried there first and dropped the
        start of the right basin on one arm: early costs rank the starts
        poorly.)  Default False: every start runs until it converges.

    Returns
    -------
    RefineResult
        A KeyboardInterrupt stops the refinement and returns the best point
        evaluated so far with ``interrupted=True``.

    Raises
    ------
    ValueError
        On malformed starts or bounds.
    """
    bounds = np.asarray(bounds, dtype=float)
    lo, hi = bounds[:, 0], bounds[:, 1]
    starts = np.clip(np.atleast_2d(np.asarray(starts, dtype=float)), lo, hi)
    if starts.shape[1] != bounds.shape[0]:
        raise ValueError(f"starts have {starts.shape[1]} parameters, bounds {bounds.shape[0]}")
    ns, k = starts.shape
    nfev0 = problem.nfev
    width = hi - lo
    x = starts.copy()
    cost = np.full(ns, np.inf)
    start_costs = np.full(ns, np.inf)
    lam = np.full(ns, 1e-3)
    J = [None] * ns
    r = [None] * ns
    active = list(range(ns))
    done_reason = {}
    merged = []
    interrupted = False
    nit = 0
    message = ""
    reported = set()

    def report(s):
        if callback is None or s in reported:
            return False
        reported.add(s)
        return bool(callback(s + 1, ns, x[s].copy(), float(cost[s])))

    trial = x.copy()
    stale = set()  # converged starts whose Jacobian columns at x were not simulated (yet)

    def columns(S):
        """Simulate the Jacobian columns of the starts S at their x (one batch)."""
        pts, hs = zip(*(_fd_points(x[s], lo, hi) for s in S))
        R = problem.residuals(np.vstack([p[1:] for p in pts]))
        for a, s in enumerate(S):
            J[s] = ((R[a * k:(a + 1) * k] - r[s]) / hs[a][:, None]).T

    try:
        while active and nit < max_iter + 1:
            # the trial points: a start point with its k columns (it is always taken), a later
            # trial alone (its columns follow if its step is accepted)
            pts, hs = zip(*(_fd_points(trial[s], lo, hi) if not lazy_jacobian or J[s] is None
                            else (trial[s][None], None) for s in active))
            R = problem.residuals(np.vstack(pts))
            nit += 1
            stop = False
            accepted = []
            o = 0
            for a, s in enumerate(active):
                Rs = R[o:o + pts[a].shape[0]]
                o += pts[a].shape[0]
                c_t = float(Rs[0] @ Rs[0])
                if not np.isfinite(cost[s]):  # the start point itself
                    start_costs[s] = c_t
                if c_t < cost[s]:
                    dc = cost[s] - c_t
                    dx = np.max(np.abs(trial[s] - x[s]) / width) if np.isfinite(cost[s]) else np.inf
                    x[s], cost[s], r[s] = trial[s].copy(), c_t, Rs[0]
                    if hs[a] is not None:  # the columns came with the trial
                        J[s] = ((Rs[1:] - Rs[0]) / hs[a][:, None]).T
                    else:
                        accepted.append(s)
                    lam[s] = max(lam[s] / 3.0, 1e-12)
                    if dc <= ftol * c_t or dx <= xtol:
                        done_reason[s] = "converged"
                else:
                    lam[s] *= 4.0
                    if lam[s] > 1e12:
                        done_reason[s] = "converged (no further decrease)"
            # merge starts that reached the same point
            for a_i, s in enumerate(active):
                if s in done_reason:
                    continue
                for t in active[:a_i]:
                    if t not in done_reason or done_reason[t].startswith("converged"):
                        if np.all(np.abs(x[s] - x[t]) <= MERGE_TOL * width):
                            keep, drop = (t, s) if cost[t] <= cost[s] else (s, t)
                            done_reason[drop] = f"merged into start {keep + 1}"
                            merged.append((drop, keep))
                            break
            if nit >= max_iter + 1:
                for s in active:
                    done_reason.setdefault(s, "iteration limit")
            lead = int(np.argmin(cost)) if leader_stop else -1
            if leader_stop and done_reason.get(lead, "").startswith("converged"):
                for s in active:
                    done_reason.setdefault(s, f"stopped: start {lead + 1} converged below it")
            # lazy_jacobian: the accepted steps' columns, now for the starts that go on, at the
            # end for the best of those that stop (the Jacobian of the standard errors)
            stale.update(s for s in accepted if s in done_reason)
            going = [s for s in accepted if s not in done_reason]
            if going:
                columns(going)
            for s in active:
                if s in done_reason and report(s):
                    stop = True
                    break
            stop = stop or (poll is not None and bool(poll()))
            if stop:
                interrupted = True
                message = "stopped by callback during refinement"
                break
            active = [s for s in active if s not in done_reason]
            for s in active:
                trial[s] = _lm_step(J[s], r[s], lam[s], x[s], lo, hi)
        best = int(np.argmin(cost))
        if best in stale and np.isfinite(cost[best]):
            columns([best])
            stale.discard(best)
    except KeyboardInterrupt:
        interrupted = True
        message = "interrupted (KeyboardInterrupt) during refinement"
    costs = cost.copy()
    for drop, keep in merged:
        costs[drop] = cost[keep]
    best = int(np.argmin(cost))
    if not np.isfinite(cost[best]):
        best_x, best_cost, best_jac, best_r = starts[0], np.inf, None, None
    else:  # no Jacobian when an interrupt came before its columns at x were simulated
        best_x, best_cost, best_r = x[best], float(cost[best]), r[best]
        best_jac = None if best in stale else J[best]
    if not message:
        message = (f"refined {ns} start(s) together by Levenberg-Marquardt in {nit} iterations"
                   + (f" ({len(merged)} merged)" if merged else ""))
    return RefineResult(x=np.asarray(best_x, dtype=float), fun=best_cost,
                        nfev=problem.nfev - nfev0, nit=nit, success=not interrupted,
                        message=message, start_costs=start_costs, costs=costs, merged=merged,
                        interrupted=interrupted, jac=best_jac, residuals=best_r)


#: Times the box around the IDIM estimate is widened when the refinement ends on one of
#: its bounds (each time that bound moves out by the box's whole width, so the width at
#: least doubles a round; then the fit is refined again from its point; a widening that
#: lowers no cost is undone).  That box, the estimate +- (50 % + 10 standard errors), is a
#: guess, not the robot's: IDIM-LS is biased on a compliant arm (the springs bend the
#: motor-side accelerations it differentiates), and on the random compliant chain 20262916
#: of ``benchmarks/bench_arms.py`` a true base parameter (MY1R) lay outside it; the rigid
#: fit ended on the bound and the two-mass fit, in the same box of beta, could not reach
#: the robot.  The search restart (:data:`identification.arm.ARM_MAX_RESTARTS`) runs in the
#: widened box, as the caller's.
BOX_WIDENINGS = 3

#: A component within this fraction of its box's width from a bound is on that bound.
BOX_EDGE = 1e-6


def widen_guessed_box(problem, ref, bounds, *, guessed=None, nonnegative=None, max_iter, ftol,
                      callback=None):
    """Widen a guessed box where the refinement ended on a bound; refine again from there.

    A box that is a guess (:func:`identification.arm.identify_arm`'s around the IDIM
    estimate; the unknown friction's box that :func:`identification.identify` takes
    from the log, :func:`identification.friction.default_friction_bounds`)
    is no constraint of the robot's: a fit that ends on one of its bounds
    says the data want the parameter beyond it.  Each round moves every
    such bound of a guessed row out by the box's whole width in that
    parameter (a non-negative row stays so) and refines again from the
    fit's point, up to :data:`BOX_WIDENINGS` rounds; a round that does not
    lower the cost is undone and ends the widening.  The same treatment as a
    trust region's; a caller's box, the sidecar's or physical ranges are
    not guesses and are kept as they are.

    Parameters
    ----------
    problem : object
        The refinement's problem (``residuals``; its bounds do not enter it).
    ref : scipy.optimize.OptimizeResult
        The refinement's result (``x``, ``fun``, ``nfev``, ``nit``).
    bounds : ndarray, shape (k, 2)
        The box of x.
    guessed : array_like of bool, shape (k,), optional
        The rows whose box is a guess (default every row).
    nonnegative : array_like of bool, shape (k,), optional
        The rows whose lower bound 0 is physical (a friction constant).
    max_iter, ftol : int, float
        The refinement's.
    callback : callable or None
        The refinement's callback.

    Returns
    -------
    ref : OptimizeResult
        The last refinement (its ``nfev`` and ``nit`` summed over the rounds).
    bounds : ndarray, shape (k, 2)
        The box it ran in.
    widened : list of int
        Indices of x whose box was widened (in the kept rounds).
    """
    bounds = np.asarray(bounds, dtype=float)
    k = bounds.shape[0]
    guessed = np.ones(k, bool) if guessed is None else np.asarray(guessed, bool)
    nonnegative = np.zeros(k, bool) if nonnegative is None else np.asarray(nonnegative, bool)
    widened = []
    for _ in range(BOX_WIDENINGS):
        x = np.asarray(ref.x, dtype=float)
        width = bounds[:, 1] - bounds[:, 0]
        low = guessed & (x <= bounds[:, 0] + BOX_EDGE * width)
        high = guessed & (x >= bounds[:, 1] - BOX_EDGE * width)
        box = bounds.copy()
        box[low, 0] -= width[low]
        box[high, 1] += width[high]
        box[nonnegative, 0] = np.maximum(box[nonnegative, 0], 0.0)
        moved = np.flatnonzero(np.any(box != bounds, axis=1))
        if moved.size == 0:
            break
        new = refine(problem, x[None], box, max_iter=max_iter, ftol=ftol, callback=callback)
        new.nfev = int(new.nfev) + int(ref.nfev)
        new.nit = int(new.nit) + int(ref.nit)
        if not new.fun < ref.fun:
            ref.nfev, ref.nit = new.nfev, new.nit
            if getattr(new, "interrupted", False):
                ref.interrupted, ref.message = True, new.message
            break
        ref, bounds = new, box
        widened += [int(i) for i in moved if int(i) not in widened]
        if getattr(new, "interrupted", False):
            break
    return ref, bounds, widened
