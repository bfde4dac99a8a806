"""Excitation design: a reference trajectory that identifies all nine f.

:func:`design_excitation` returns a :class:`plant.Trajectory` in the
sidecar's form (``c``, ``terms_A_omega_phi``, ``t_ramp_s``) that starts at
rest at the rig's start state, stays within joint, rate and current limits
and minimises the predicted relative standard error of the *worst*
determined parameter (a minimax, "E-like" criterion on relative errors: the
quantity the acceptance of a design is judged on, and the one a user reads
in the result's ``f_rse``).

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

Limits (checked on a 2 ms grid of the reference): the joint range (default:
the paper trajectory's, ``q2 in [-pi/2, 0]``, ``q3 in [0, pi/2]``), the rate
(default none) and the current the rigid model needs along the reference,
``(Y(q, qd, qdd) f - tau_friction(qd)) / (k Kt)``, at ``f_prior`` (default
the centre of the rig's search box) kept below ``CURRENT_MARGIN`` times the
drive's full scale (the P loop's tracking transients come on top of the
feed-forward current).

Criterion and why
-----------------
The predicted standard errors of the default identification are those of
its refinement: the Gauss-Newton covariance ``sigma^2 (J^T J)^-1`` of the
logged-input prediction errors (:mod:`identification.refinement`), ``J`` their
sensitivity to f, ``sigma^2 = 1/12`` pulse^2 (encoder quantisation).  That
needs an emulated log and 10 replays per candidate (~0.5 s); the search
instead minimises the same criterion computed from the information matrix of
the *regressor* along the reference, ``Y^T Y`` (:func:`plant.robot.model.regressor`;
equation error of constant variance), ~0.3 ms per candidate, and the
``RERANK`` best distinct candidates of the GA's final population are then
ranked by the prediction-error criterion (:func:`predicted_f_std`), which
also gives ``predicted_f_std``.  Measured (``benchmarks/bench_excitation.py
--agreement``) over random feasible trajectories on the drill/flex rig: the
two criteria's Spearman rank correlation is 0.95 over 12 random feasible
trajectories (``docs/optimisers.rst``).  Relative errors are taken relative to
``max(|f_prior|, 5 % of the search range)`` (a parameter near zero in the
prior still gets a finite scale).

The search is the project's GA (:func:`identification.ga.run_ga`, Gray-coded,
4 x 20 individuals).  A candidate outside the limits is repaired, not
penalised: its amplitudes are scaled by the largest factor in (0, 1] that
keeps it within them (bisection; at factor 0 the reference is the start
state held, or the ramp to the offsets), so every individual is feasible.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

import plant
from plant.robot.model import friction_torques, regressor
from plant.logs.rig import rig_constants

__all__ = ["design_excitation", "predicted_f_std", "trajectory_limits", "regressor_rse",
           "DEFAULT_HARMONICS", "CURRENT_MARGIN"]

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
    return np.maximum(np.abs(f_prior), SCALE_FLOOR * (bounds[:, 1] - bounds[:, 0]))


class _Family:
    """The trajectory family: x (searched, in a box) -> Trajectory."""

    def __init__(self, q0, duration, n_harmonics, limits, t_ramp_s):
        self.q0 = np.asarray(q0, dtype=float)
        self.L = int(n_harmonics)
        self.duration = float(duration)
        self.omega = 2 * math.pi * np.arange(1, self.L + 1) / self.duration
        self.ramp = bool(np.all(self.q0 == 0.0))
        self.t_ramp = (min(0.3, self.duration / 5) if t_ramp_s is None else float(t_ramp_s)) \
            if self.ramp else 0.0
        half = 0.5 * (limits[:, 1] - limits[:, 0])
        rows = []
        for j in range(2):
            # amplitudes fall off with the harmonic (same peak acceleration share)
            amax = half[j] / np.arange(1, self.L + 1)
            if self.ramp:
                rows += [[limits[j, 0], limits[j, 1]]]
                rows += [[0.0, a] for a in amax] + [[-math.pi, math.pi]] * self.L
            else:
                rows += [[-a, a] for a in amax]
        self.bounds = np.array(rows)

    def trajectory(self, x, s=1.0):
        x = np.asarray(x, dtype=float)
        c, terms, k = [], [], 0
        for j in range(2):
            if self.ramp:
                cj = x[k]
                amp = s * x[k + 1:k + 1 + self.L]
                ph = x[k + 1 + self.L:k + 1 + 2 * self.L]
                k += 1 + 2 * self.L
            else:
                amp = s * x[k:k + self.L]
                ph = np.zeros(self.L)
                cj = self.q0[j] - amp.sum()
                k += self.L
            c.append(float(cj))
            terms.append([(float(a), float(w), float(p)) for a, w, p in zip(amp, self.omega, ph)])
        return plant.Trajectory.from_terms(c, terms, self.t_ramp)


def trajectory_limits(trajectory, duration_s, rig, f, *, joint_limits_rad=None,
                      max_velocity_rad_s=None, max_current_A=None, grid_s=GRID_S):
    """Peak excursions of a reference and its normalised limit violation.

    Parameters
    ----------
    trajectory : plant.Trajectory
        The reference.
    duration_s : float
        Length of the run (s).
    rig : plant.logs.rig.Rig
        Gear, torque constants, friction and gravity of the current check.
    f : array_like, shape (9,)
        Base parameters of the rigid model's inverse dynamics.
    joint_limits_rad : array_like, shape (2, 2), optional
        ``[[q2_min, q2_max], [q3_min, q3_max]]`` (default: the paper
        trajectory's range).
    max_velocity_rad_s : float or array_like (2,), optional
        Rate limit per joint (default none).
    max_current_A : float or array_like (2,), optional
        Current limit (default the rig's ``current_full_scale_A``; none if
        the rig gives none).
    grid_s : float
        Time step of the check (s).

    Returns
    -------
    dict
        ``q_min``, ``q_max``, ``qd_max``, ``i_max`` (feed-forward current,
        A), each (2,), and ``violation`` (>= 0; 0 when every limit holds,
        the current against ``CURRENT_MARGIN`` times its limit).
    """
    lim = _paper_range() if joint_limits_rad is None else np.asarray(joint_limits_rad, float)
    t = np.arange(0.0, float(duration_s) + 1e-12, grid_s)
    q, qd, qdd = trajectory.evaluate(t)
    return _limits(q, qd, qdd, rig, np.asarray(f, float), lim,
                   _pair_or_none(max_velocity_rad_s),
                   _pair_or_none(rig.current_full_scale_A if max_current_A is None
                                 else max_current_A))


def _pair_or_none(v):
    return None if v is None else np.broadcast_to(np.asarray(v, dtype=float), (2,))


def _limits(q, qd, qdd, rig, f, lim, vmax, imax):
    c = rig_constants(rig)
    tau = regressor(q, qd, qdd, c.gravity) @ f - friction_torques(
        qd, c.viscous, c.coulomb_pos, c.coulomb_neg, c.ramp_speed)
    i = np.abs(tau / np.asarray(c.torque_per_amp))
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


def regressor_rse(trajectory, duration_s, f_scale, *, g=9.81, grid_s=GRID_S):
    """Relative standard errors from the regressor's information matrix (up to one factor).

    ``sqrt(diag((Y^T Y)^-1)) / f_scale`` with Y the regressor stacked along
    the reference on a ``grid_s`` grid: the errors of least squares on the
    inverse dynamic model with an equation error of unit variance.  Only
    ratios between trajectories mean something.

    Parameters
    ----------
    trajectory : plant.Trajectory
    duration_s : float
        Length of the run (s).
    f_scale : array_like, shape (9,)
        Scale of each parameter (its prior magnitude).
    g : float
        Gravity (m/s^2).
    grid_s : float
        Time step (s).

    Returns
    -------
    ndarray, shape (9,)
    """
    t = np.arange(0.0, float(duration_s) + 1e-12, grid_s)
    q, qd, qdd = trajectory.evaluate(t)
    return _rse_from_states(q, qd, qdd, np.asarray(f_scale, float), g)


def _rse_from_states(q, qd, qdd, scale, g):
    Y = regressor(q, qd, qdd, g).reshape(-1, 9) * scale
    try:
        M = np.linalg.inv(Y.T @ Y)
    except np.linalg.LinAlgError:
        return np.full(9, np.inf)
    d = np.diag(M)
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
                    substeps=None, workers=None):
    """Predicted standard errors of the default identification on a trajectory.

    Emulates the P experiment (:func:`plant.emulate_log`, optionally on
    flexible joints) at ``f``, then forms the forward-difference Jacobian of
    the refinement's prediction errors (:class:`~identification.refinement.PredictionErrorProblem`,
    the identification's substeps) at ``f`` and returns
    ``sqrt(diag(sigma^2 (J^T J)^-1))`` with ``sigma^2`` the mean square
    prediction error at ``f`` (quantisation: ~1/12 pulse^2 on a rigid plant).

    Parameters
    ----------
    rig : plant.logs.rig.Rig
        The rig.
    trajectory : plant.Trajectory
        The reference.
    duration_s : float
        Length of the run (s).
    f : array_like, shape (9,)
        The robot's base parameters (a prior, or the truth in a benchmark).
    flexible : plant.FlexibleJoints, optional
        Emulate flexible joints; the replay is then the same flexible plant
        (its joint constants known: the errors of f alone).
    base : plant.ExperimentLog, optional
        Template of the emulated log (default: a minimal one from ``rig``).
    substeps : int, optional
        RK4 substeps of the replay (default the identification's).
    workers : int, optional
        Threads of the simulation.

    Returns
    -------
    ndarray, shape (9,)
        Predicted standard errors of f1..f9.
    """
    from .objective import IDENTIFICATION_SUBSTEPS
    from .refinement import FD_STEP, PredictionErrorProblem

    f = np.asarray(f, dtype=float).reshape(9)
    base = _template(rig) if base is None else base
    log = plant.emulate_log(base, f, rig=rig, trajectory=trajectory, duration_s=duration_s,
                            flexible=flexible, name="excitation_prediction")
    prob = PredictionErrorProblem(log, substeps=IDENTIFICATION_SUBSTEPS if substeps is None
                                  else substeps, workers=workers, plant=flexible)
    h = FD_STEP * 1e2 * (rig.bounds[:, 1] - rig.bounds[:, 0])
    X = np.vstack([f, f + np.diag(h)])
    R = prob.residuals(X)
    J = (R[1:] - R[0]).T / h
    sigma2 = max(float(np.mean(R[0] ** 2)), QUANTISATION_VAR)
    try:
        cov = sigma2 * np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        return np.full(9, np.inf)
    return np.sqrt(np.maximum(np.diag(cov), 0.0))


def design_excitation(rig, duration_s, *, joint_limits_rad=None, max_velocity_rad_s=None,
                      max_current_A=None, n_harmonics=DEFAULT_HARMONICS, rng=None,
                      f_prior=None, t_ramp_s=None, generations=30, rerank=RERANK,
                      workers=None, full_output=False):
    """Design an excitation trajectory that identifies all nine f.

    Parameters
    ----------
    rig : plant.logs.rig.Rig
        The rig (start state, gears, encoders, P gains, friction, search box,
        current full scale), e.g. ``plant.load_log(path).rig``.
    duration_s : float
        Length of the experiment (s).
    joint_limits_rad : array_like, shape (2, 2), optional
        ``[[q2_min, q2_max], [q3_min, q3_max]]`` (rad); default the paper
        trajectory's range ``[[-pi/2, 0], [0, pi/2]]``.  Must contain the
        start state.
    max_velocity_rad_s : float or array_like (2,), optional
        Joint rate limit (rad/s); default none.
    max_current_A : float or array_like (2,), optional
        Drive current limit (A); default the rig's ``current_full_scale_A``.
        The rigid model's feed-forward current along the reference at
        ``f_prior`` stays below ``CURRENT_MARGIN`` times it.
    n_harmonics : int
        Harmonics of ``2 pi / duration_s`` per joint (>= 1).
    rng : numpy.random.Generator or int, optional
        Random source of the GA.
    f_prior : array_like, shape (9,), optional
        Prior base parameters (current check, scales of the relative errors,
        linearisation point); default the centre of the rig's search box.
    t_ramp_s : float, optional
        Start ramp (s) when the start state is q = 0 (default
        ``min(0.3, duration_s / 5)``).
    generations : int
        GA generations (4 x 20 individuals).
    rerank : int
        Best distinct GA candidates re-ranked by the prediction-error
        criterion (0: keep the GA's best, no simulation).
    workers : int, optional
        Threads of the simulations.
    full_output : bool
        Also return the design's figures (scipy's convention).

    Returns
    -------
    trajectory : plant.Trajectory
        The design (``to_parameters()`` is the sidecar's
        ``trajectory.parameters``).
    info : dict
        Only with ``full_output``: ``predicted_f_std`` (9,) (prediction-error criterion at ``f_prior``;
        None with ``rerank=0``), ``predicted_f_rse``, ``regressor_rse``
        (relative, up to one factor), ``limits``
        (:func:`trajectory_limits`), ``f_prior``, ``nfev``.

    Raises
    ------
    ValueError
        On a bad duration, limits that exclude the start state, an unknown
        start state, or when no candidate satisfies the limits.
    """
    from .ga import run_ga

    if not (isinstance(duration_s, (int, float)) and math.isfinite(duration_s)
            and duration_s > 0):
        raise ValueError(f"duration_s must be a positive number, got {duration_s!r}")
    if int(n_harmonics) != n_harmonics or n_harmonics < 1:
        raise ValueError(f"n_harmonics must be an integer >= 1, got {n_harmonics!r}")
    if rig.q0_rad is None:
        raise ValueError("the rig has no start state (start_state.q_rad); a designed "
                         "trajectory starts at rest there")
    q0 = np.asarray(rig.q0_rad, dtype=float)
    lim = _paper_range() if joint_limits_rad is None else np.asarray(joint_limits_rad, float)
    if lim.shape != (2, 2) or not np.all(np.isfinite(lim)) or np.any(lim[:, 0] >= lim[:, 1]):
        raise ValueError("joint_limits_rad must be [[q2_min, q2_max], [q3_min, q3_max]] "
                         f"with min < max, got {joint_limits_rad!r}")
    if np.any(q0 < lim[:, 0] - 1e-12) or np.any(q0 > lim[:, 1] + 1e-12):
        raise ValueError(f"the start state q0 = {q0.tolist()} lies outside joint_limits_rad")
    vmax = _pair_or_none(max_velocity_rad_s)
    imax = _pair_or_none(rig.current_full_scale_A if max_current_A is None else max_current_A)
    for name, v in (("max_velocity_rad_s", vmax), ("max_current_A", imax)):
        if v is not None and not np.all(np.isfinite(v) & (v > 0)):
            raise ValueError(f"{name} must be positive, got {v.tolist()}")
    bounds = rig.bounds
    f_prior = bounds.mean(axis=1) if f_prior is None else np.asarray(f_prior, float).reshape(9)
    scale = _scale(f_prior, bounds)
    c = rig_constants(rig)
    fam = _Family(q0, duration_s, n_harmonics, lim, t_ramp_s)
    t = np.arange(0.0, float(duration_s) + 1e-12, GRID_S)
    nfev = [0]

    def states(x, s):
        return fam.trajectory(x, s).evaluate(t)

    def feasible(x, s):
        q, qd, qdd = states(x, s)
        return _limits(q, qd, qdd, rig, f_prior, lim, vmax, imax)["violation"] == 0.0

    def repair(x):
        # the largest amplitude factor s in (0, 1] within the limits (bisection;
        # s -> 0 is the start state held, or the ramp to the offsets)
        if feasible(x, 1.0):
            return 1.0
        lo, hi = 0.0, 1.0
        for _ in range(REPAIR_STEPS):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if feasible(x, mid) else (lo, mid)
        return lo

    def evaluate(X):
        out = np.empty(X.shape[0])
        for m, x in enumerate(X):
            s = repair(x)
            if s <= 0.0 or not feasible(x, s):
                out[m] = np.inf
                continue
            q, qd, qdd = states(x, s)
            out[m] = float(np.log(np.max(_rse_from_states(q, qd, qdd, scale, c.gravity))))
        nfev[0] += X.shape[0]
        return out

    ga = run_ga(evaluate, fam.bounds, n_gen=int(generations), rng=rng, gray=True,
                bits=16)
    order = np.argsort(ga.population_energies) if ga.population is not None else None
    cands = [ga.x]
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
                                     workers=workers)
            except ValueError:
                sd = np.full(9, np.inf)
            scores.append((float(np.max(sd / scale)), sd))
        k = int(np.argmin([s for s, _ in scores]))
        best, best_std = cands[k], scores[k][1]
    traj = fam.trajectory(best, repair(best))
    info = dict(
        predicted_f_std=best_std,
        predicted_f_rse=None if best_std is None else best_std / scale,
        regressor_rse=regressor_rse(traj, duration_s, scale, g=c.gravity),
        limits=trajectory_limits(traj, duration_s, rig, f_prior, joint_limits_rad=lim,
                                 max_velocity_rad_s=vmax, max_current_A=imax),
        f_prior=f_prior, nfev=nfev[0], candidates=len(cands))
    return (traj, info) if full_output else traj


# ------------------------------------------------------------------ command line
def _parser():
    import argparse

    ap = argparse.ArgumentParser(
        prog="python -m identification.excitation",
        description="Design an excitation trajectory for the rig of a sidecar (writes "
                    "{'trajectory': {'parameters', 'duration_s'}, 'predicted_f_std'}).")
    ap.add_argument("sidecar", help="the rig's JSON sidecar (STEM.json)")
    ap.add_argument("--duration-s", type=float, required=True, help="length of the run (s)")
    ap.add_argument("--seed", type=int, default=None, help="seed of the GA")
    ap.add_argument("--output", required=True, help="JSON file to write")
    ap.add_argument("--n-harmonics", type=int, default=DEFAULT_HARMONICS,
                    help=f"harmonics per joint (default {DEFAULT_HARMONICS})")
    ap.add_argument("--generations", type=int, default=30, help="GA generations (default 30)")
    ap.add_argument("--max-current", type=float, default=None,
                    help="current limit (A; default the sidecar's current_full_scale_A)")
    ap.add_argument("--max-velocity", type=float, default=None,
                    help="joint rate limit (rad/s; default none)")
    ap.add_argument("--joint-limits", type=float, nargs=4, default=None,
                    metavar=("Q2MIN", "Q2MAX", "Q3MIN", "Q3MAX"),
                    help="joint range (rad; default the paper trajectory's)")
    ap.add_argument("--workers", type=int, default=None, help="simulation threads")
    return ap


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

    from plant.logs.fileio import write_text_atomic
    from plant.logs.sidecar import read_sidecar, rig_from_sidecar

    args = _parser().parse_args(argv)
    try:
        if not (math.isfinite(args.duration_s) and args.duration_s > 0):
            raise ValueError(f"--duration-s must be a positive number, got {args.duration_s}")
        path = Path(args.sidecar)
        rig = rig_from_sidecar(read_sidecar(path), source=path)
        lim = None if args.joint_limits is None else np.reshape(args.joint_limits, (2, 2))
        traj, info = design_excitation(
            rig, args.duration_s, joint_limits_rad=lim, max_velocity_rad_s=args.max_velocity,
            max_current_A=args.max_current, n_harmonics=args.n_harmonics, rng=args.seed,
            generations=args.generations, workers=args.workers, full_output=True)
        lims = info["limits"]
        out = {
            "trajectory": {"parameters": traj.to_parameters(),
                           "duration_s": float(args.duration_s)},
            "predicted_f_std": [float(v) for v in info["predicted_f_std"]],
            "predicted_f_rse": [float(v) for v in info["predicted_f_rse"]],
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
    print(f"wrote {args.output}: predicted max relative standard error {rse.max():.2f} % "
          f"({', '.join(f'f{i + 1} {v:.2f}' for i, v in enumerate(rse))})")
    return 0


if __name__ == "__main__":
    import sys

    sys.exit(main())
