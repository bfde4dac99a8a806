"""``identify``: from a rig log to the base parameters f1..f9 (the main job)."""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np
from scipy.optimize import OptimizeResult

import plant
from plant.simulate import warm_up

from .ga import run_ga
from .objective import IDENTIFICATION_SUBSTEPS, OutputError
from .refine import DEFAULT_GAIN, PredictionErrorProblem, refine
from .result import IdentificationResult

__all__ = ["identify", "METHODS", "DEFAULT_METHOD"]

#: Identification methods: the paper's GA alone, and GA + prediction-error
#: refinement (the default).
METHODS = ("ga+pem", "paper")
DEFAULT_METHOD = "ga+pem"

#: The paper's GA settings (section 4): 4 subpopulations of 20, 40
#: generations, SP 2.0, single-point crossover 0.6, generation gap 0.94,
#: complete-net migration at rate 0.3.
PAPER_GA = dict(n_subpops=4, n_ind=20, n_gen=40, sp=2.0, p_xover=0.6, ggap=0.94,
                migration_rate=0.3, migration_interval=5, bits=20)


def _as_log(log):
    if isinstance(log, plant.ExperimentLog):
        return log
    if isinstance(log, (str, Path)):
        return plant.load_log(log)
    raise TypeError(f"log must be a plant.ExperimentLog or a path, got {type(log).__name__}")


def _check_bounds(bounds, log, n=9):
    b = log.rig.bounds if bounds is None else np.asarray(bounds, dtype=float)
    if b.shape != (n, 2):
        raise ValueError(f"bounds must have shape ({n}, 2), got {b.shape}")
    if not np.all(np.isfinite(b)):
        raise ValueError("bounds contain NaN or inf")
    bad = np.flatnonzero(b[:, 0] >= b[:, 1])
    if bad.size:
        i = int(bad[0])
        raise ValueError(f"bounds of parameter {i + 1} are inverted or empty: "
                         f"[{b[i, 0]}, {b[i, 1]}]")
    return b


#: Search box of the payload in its physically consistent coordinates
#: ``[m (kg), xp (m), yp (m), Jc (kg m^2)]``: mass up to 5 kg (twice the PUMA
#: 560's rated payload), centre of mass in link 3's frame within 1 m of its
#: origin (the flange is ~0.43 m from it along the forearm), and inertia about
#: the payload's own centre of mass of a compact tool (Jc <= 0.05 kg m^2, e.g.
#: a 1.5 kg rod 0.6 m long).
DEFAULT_PAYLOAD_BOUNDS = np.array([[0.0, 5.0], [-1.0, 1.0], [-1.0, 1.0], [0.0, 0.05]])


def _prior_f(prior):
    if prior is None:
        raise ValueError("payload identification needs prior= (the unloaded robot's f)")
    f = prior.get("f") if isinstance(prior, dict) else getattr(prior, "f", prior)
    try:
        f = np.asarray(f, dtype=float)
    except (TypeError, ValueError):
        raise ValueError("prior must hold 9 numbers f1..f9") from None
    if f.shape != (9,) or not np.all(np.isfinite(f)):
        raise ValueError(f"prior must hold 9 finite numbers f1..f9, got shape {f.shape}")
    return f


def _seed_of(rng):
    if rng is None or isinstance(rng, (int, np.integer)):
        return None if rng is None else int(rng)
    return None


def identify(
    log,
    *,
    method=DEFAULT_METHOD,
    bounds=None,
    rng=None,
    callback=None,
    workers=None,
    progress=True,
    lowpass_hz=None,
    substeps=IDENTIFICATION_SUBSTEPS,
    ga_options=None,
    refine_options=None,
    payload=False,
    prior=None,
    payload_bounds=None,
    consistent=False,
):
    """Identify the base parameters f1..f9 from a P-control log.

    The paper's procedure: a multi-population GA (:func:`identification.ga.run_ga`)
    searches the box ``bounds`` for the f whose simulated closed loop
    reproduces the logged integer tracking errors, minimising the output
    error of eq. 4 (:class:`~identification.objective.OutputError`).  The
    default method then refines the GA's best individuals by Gauss-Newton on
    logged-input prediction errors (:mod:`identification.refine`).

    Parameters
    ----------
    log : plant.ExperimentLog or path
        The experiment (CSV + JSON sidecar); rig, trajectory and start state
        come from it.
    method : {'ga+pem', 'paper'}
        ``'paper'`` runs the paper's GA alone (binary chromosome, its
        settings); ``'ga+pem'`` (default) runs the same GA on Gray-coded
        chromosomes and then the refinement.
    bounds : array_like, shape (9, 2), optional
        Search ranges (low, high) of f1..f9; default: the sidecar's.
    rng : numpy.random.Generator or int, optional
        Random source (SPEC 7); the same seed gives the same result bit for
        bit (for a fixed number of ``workers``-independent kernels: the
        simulation is deterministic per candidate).
    callback : callable, optional
        ``callback(intermediate_result) -> bool``, called after each GA
        generation and each refined start with an ``OptimizeResult`` holding
        ``x``, ``fun``, ``stage`` ('ga' or 'refine'), ``evaluations``; True
        stops the search and returns the best so far (``interrupted``).
    workers : int, optional
        Threads of the parallel simulation (default: all cores).
    progress : bool
        Show a tqdm progress bar per GA generation.
    lowpass_hz : float, optional
        Low-pass both logged and simulated errors with the same zero-phase
        filter before comparing them (logs with flexible-joint oscillations).
    substeps : int
        RK4 substeps per sample while identifying.
    ga_options : dict, optional
        Overrides of the GA settings (:func:`~identification.ga.run_ga`).
        The default method runs the GA Gray-coded and with
        ``early_stop=1.0`` (offspring stop being simulated once their running
        output error passes the worst individual of the population: same
        result on the paper log, 2 % fewer simulated samples); ``'paper'``
        runs the paper's binary GA without early termination.
    refine_options : dict, optional
        ``gain`` (replay output injection, default 0.02), ``n_starts``
        (default 4), ``max_nfev`` (per start, default 40).
    payload : bool
        On-line payload identification: keep the robot's f from ``prior``
        and search only the payload vector ``p = [m, m xp, m yp, J]``
        (:mod:`plant.payload`; f is linear in p), typically on a short log
        or a window of a longer run.  The default method solves it by the
        prediction-error Gauss-Newton directly (it is smooth and has 4
        unknowns); ``'paper'`` runs the GA on the output error over p.
    prior : IdentificationResult, dict with ``'f'``, or array_like (9,)
        The unloaded robot's f (required with ``payload``).
    payload_bounds : array_like, shape (4, 2), optional
        Search box of the payload's physically consistent coordinates
        ``[m, xp, yp, Jc]`` (default :data:`DEFAULT_PAYLOAD_BOUNDS`).  The
        search runs in these coordinates, ``p = [m, m xp, m yp, Jc + m (xp^2 +
        yp^2)]`` (parallel-axis theorem), so that every candidate is a rigid
        body with ``Jc >= 0`` (physical consistency; Wensing, Kim and Slotine,
        IEEE RA-L 3(1), 2018).  In the linear coordinates p a short window
        fits the unmodelled oscillations of a flexible robot with bodies of
        any inertia (measured: 2.74 kg for the 1.5 kg drill on [1.0, 1.2) s);
        bounded Jc removes that freedom.

    consistent : bool
        Enforce the structure of eq. 3, ``f3 = a3 f5`` and ``f4 = a3 f6``
        (both are m3 x3 a3 and m3 y3 a3), with ``a3`` from the sidecar: the
        search runs over f1, f2, f5, f6, f7, f8, f9 (bounds: those rows of
        ``bounds``).  The paper searches the nine independently (default
        False).  On a flexible robot it keeps the unmodelled compliance from
        pulling f4 away from a3 f6 (drill/flex log: f4 error -6.4 % -> the
        f6 error, -0.5 %).

    Returns
    -------
    IdentificationResult

    Raises
    ------
    ValueError
        On an unknown method, bad bounds or options, or ``payload`` without
        a valid ``prior``.
    plant.LogError
        If ``log`` is a path to a malformed log.
    """
    if method == "default":
        method = DEFAULT_METHOD
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
    log = _as_log(log)
    bounds = _check_bounds(bounds, log)
    seed = _seed_of(rng)
    rng = np.random.default_rng(rng)
    if workers is not None and int(workers) < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    ga_settings = dict(PAPER_GA, gray=(method != "paper"),
                       early_stop=None if method == "paper" else 1.0)
    ga_settings.update(ga_options or {})
    ropts = dict(gain=DEFAULT_GAIN, n_starts=4, max_nfev=40)
    unknown = set(refine_options or {}) - set(ropts)
    if unknown:
        raise ValueError(f"unknown refine option(s): {', '.join(sorted(unknown))}")
    ropts.update(refine_options or {})

    if payload:
        space = _payload_space(log, _prior_f(prior), payload_bounds)
    elif consistent:
        space = _consistent_space(log, bounds)
    else:
        space = _Space(bounds)
    return _search(log, space, method, rng, seed, ga_settings, ropts, callback, workers,
                   progress, lowpass_hz, substeps)


class _Space:
    """The searched vector x and its map to the base parameters.

    ``f = offset + matrix @ x[:k]`` (identity for f1..f9 themselves); for a
    window log in payload mode ``x[k:]`` is the state at the first sample,
    estimated as a nuisance parameter by the refinement.
    """

    def __init__(self, bounds, offset=None, matrix=None, state=None, refine_starts=None,
                 extras=None):
        self.bounds = bounds  # (k, 2)
        self.k = bounds.shape[0]
        self.offset = offset
        self.matrix = matrix
        self.state = state  # None or (x0 (4,), bounds (4, 2))
        # refinement starts without a GA (payload mode); None: from the GA
        self.refine_starts = refine_starts
        self.extras = extras or (lambda x: {})

    def to_f(self, x):
        x = np.asarray(x, dtype=float)[..., : self.k]
        if self.matrix is None:
            return x
        return self.offset + self.to_linear(x) @ self.matrix.T

    def to_linear(self, x):
        """The linear coordinates (f's coefficients) of a searched vector."""
        return x


class _PayloadSpace(_Space):
    """Payload mode: x = [m, xp, yp, Jc] -> p = [m, m xp, m yp, Jc + m (xp^2 + yp^2)]."""

    def to_linear(self, x):
        m, xp, yp, jc = (x[..., i] for i in range(4))
        return np.stack([m, m * xp, m * yp, jc + m * (xp * xp + yp * yp)], axis=-1)


#: The searched f of ``consistent=True`` (0-based indices of f1, f2, f5, f6, f7, f8, f9).
CONSISTENT_F = (0, 1, 4, 5, 6, 7, 8)


def _consistent_space(log, bounds):
    """f = M x with x = (f1, f2, f5, f6, f7, f8, f9), f3 = a3 f5, f4 = a3 f6 (eq. 3)."""
    M = np.zeros((9, len(CONSISTENT_F)))
    for j, i in enumerate(CONSISTENT_F):
        M[i, j] = 1.0
    M[2, CONSISTENT_F.index(4)] = M[3, CONSISTENT_F.index(5)] = log.rig.a3_m
    return _Space(bounds[list(CONSISTENT_F)], offset=np.zeros(9), matrix=M)


def _payload_space(log, f_prior, payload_bounds):
    """Payload mode: x = [m, xp, yp, Jc] (+ the window's initial state)."""
    from plant.payload import payload_delta_matrix, payload_from_vector
    from plant.simulate import measured_counts

    pb = _check_bounds(DEFAULT_PAYLOAD_BOUNDS if payload_bounds is None else payload_bounds,
                       log, n=4)
    # Initial-state guess: the centre of the first count interval and the
    # reference velocity (no quantised simulation before a window, which would
    # not be smooth in p; no differentiated encoder counts).
    scale = log.rig.pulses_per_rad
    _, qd_ref, _ = log.trajectory.evaluate(log.t[:1])
    x_state = np.concatenate([measured_counts(log)[0] / scale, qd_ref[0]])
    half = np.r_[2.0 / np.abs(scale), 0.2 * np.abs(qd_ref[0]) + 0.05]
    lo, hi = pb[:, 0], pb[:, 1]
    # light and heavy payloads, COM near the axis and along link 3, compact and not
    starts = lo + (hi - lo) * np.array([[0.1, 0.5, 0.35, 0.2], [0.4, 0.5, 0.35, 0.2],
                                        [0.2, 0.6, 0.2, 0.5], [0.6, 0.4, 0.65, 0.5]])

    def extras(x):
        p = space.to_linear(np.asarray(x, dtype=float))
        pl = payload_from_vector(p, clip_negative_inertia=True)
        return dict(payload=dict(mass_kg=pl.mass_kg, com_m=list(pl.com_m),
                                 izz_kgm2=pl.izz_kgm2,
                                 vector=[float(v) for v in p],
                                 vector_names=["m_kg", "m_xp_kgm", "m_yp_kgm", "J_kgm2"]),
                    prior_f=f_prior)

    space = _PayloadSpace(pb, offset=f_prior, matrix=payload_delta_matrix(log.rig.a3_m),
                          state=(x_state, np.column_stack([x_state - half, x_state + half])),
                          refine_starts=starts, extras=extras)
    return space


def _stage_callback(callback, stage, evaluations):
    """Wrap the user's callback for one stage: ``fn(x, fun, **info) -> bool``."""
    def fn(x, fun, **info):
        if callback is None:
            return False
        return bool(callback(OptimizeResult(x=x, fun=fun, stage=stage,
                                            evaluations=evaluations(), **info)))
    return fn


def _search(log, space, method, rng, seed, ga_settings, ropts, callback, workers, progress,
            lowpass_hz, substeps):
    """GA on the output error and/or prediction-error refinement over ``space``."""
    compile_s = warm_up()
    t0 = time.perf_counter()
    objective = OutputError(log, substeps=substeps, lowpass_hz=lowpass_hz, workers=workers)
    f_objective = (objective if space.matrix is None
                   else (lambda X, cap=None: objective(space.to_f(X), cap=cap)))
    refining = method == "ga+pem"
    problem = None
    if refining:
        to_state = None if space.state is None else (lambda x: x[space.k:])
        problem = PredictionErrorProblem(log, to_f=space.to_f, to_state=to_state,
                                         gain=ropts["gain"], substeps=substeps,
                                         lowpass_hz=lowpass_hz, workers=workers)

    def evaluations():
        return objective.evaluations + (problem.evaluations if problem else 0)

    ga = None
    interrupted, messages = False, []
    if space.refine_starts is None or not refining:  # the global search
        ga_cb = _stage_callback(callback, "ga", evaluations)
        ga = run_ga(f_objective, space.bounds, rng=rng, progress=progress,
                    callback=lambda st: ga_cb(st.best_x, st.best_objective,
                                              generation=st.generation),
                    **ga_settings)
        x = np.asarray(ga.x_best, dtype=float)
        interrupted = ga.interrupted
        messages.append(ga.message)

    refinement = None
    if refining and not interrupted:
        if ga is None:
            starts = list(space.refine_starts[: max(1, int(ropts["n_starts"]))])
        else:  # the GA's best and the best distinct individuals of its final population
            starts = [x]
            for i in np.argsort(ga.population_objective, kind="stable"):
                if len(starts) >= int(ropts["n_starts"]):
                    break
                xi = ga.population[i]
                if not any(np.array_equal(xi, s) for s in starts):
                    starts.append(xi)
        starts, xb = np.array(starts), space.bounds
        if space.state is not None:
            starts = np.hstack([starts, np.tile(space.state[0], (len(starts), 1))])
            xb = np.vstack([xb, space.state[1]])
        ref_cb = _stage_callback(callback, "refine", evaluations)
        ref = refine(problem, starts, xb, max_nfev=int(ropts["max_nfev"]), callback=ref_cb)
        x = ref.x
        interrupted = ref.interrupted
        messages.append(ref.message)
        refinement = dict(start_costs=ref.start_costs, costs=ref.costs, cost=ref.cost,
                          evaluations=ref.evaluations, gain=ropts["gain"])
        if ga is not None:
            refinement["ga_f"] = space.to_f(ga.x_best)
        if space.state is not None:
            refinement["initial_state"] = ref.x[space.k:]

    f = space.to_f(x)
    # the GA's best was evaluated already; a refined point is evaluated once here
    y = float(ga.objective_best) if refinement is None else float(objective(f[None])[0])
    wall = time.perf_counter() - t0
    if ga is not None:
        hist = {k: np.asarray(v) for k, v in ga.history.items()}
        hist["generation"] = np.arange(len(hist["best"]))
    else:
        hist = {"generation": np.arange(1), "best": np.array([y]), "mean": np.array([y]),
                "evaluations": np.array([evaluations()])}
    return IdentificationResult(
        f=f, x=f, objective=y, fun=y, method=method, seed=seed, history=hist,
        refinement=refinement,
        population=None if ga is None else ga.population,
        population_objective=None if ga is None else ga.population_objective,
        evaluations=int(evaluations()), wall_time_s=wall, compile_time_s=compile_s,
        interrupted=bool(interrupted), success=not interrupted, message="; ".join(messages),
        log_name=log.name, log=log, bounds=space.bounds,
        settings=dict(ga=ga_settings if ga is not None else None,
                      refine=ropts if refining else None, substeps=int(substeps),
                      lowpass_hz=lowpass_hz, payload=space.matrix is not None),
        **space.extras(x[: space.k]),
    )
