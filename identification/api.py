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


#: Default search box of the payload vector [m (kg), m xp (kg m), m yp (kg m),
#: J = Izz + m (xp^2 + yp^2) (kg m^2)]: up to 5 kg (twice the PUMA 560's rated
#: payload) with its centre of mass within 0.6 m of the link-3 frame origin
#: (the flange of a PUMA 560 is ~0.43 m from it along the forearm).
DEFAULT_PAYLOAD_BOUNDS = np.array([[0.0, 5.0], [-3.0, 3.0], [-3.0, 3.0], [0.0, 2.0]])


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
        Search box of p (default :data:`DEFAULT_PAYLOAD_BOUNDS`).

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
    ga_settings = dict(PAPER_GA, gray=(method != "paper"))
    ga_settings.update(ga_options or {})
    ropts = dict(gain=DEFAULT_GAIN, n_starts=4, max_nfev=40)
    unknown = set(refine_options or {}) - set(ropts)
    if unknown:
        raise ValueError(f"unknown refine option(s): {', '.join(sorted(unknown))}")
    ropts.update(refine_options or {})

    if payload:
        return _identify_payload(log, method, _prior_f(prior), payload_bounds, rng, seed,
                                 ga_settings, ropts, callback, workers, progress, lowpass_hz,
                                 substeps)

    compile_s = warm_up()
    t0 = time.perf_counter()
    objective = OutputError(log, substeps=substeps, lowpass_hz=lowpass_hz, workers=workers)

    stopped = [False]

    def ga_callback(state):
        if callback is None:
            return False
        r = OptimizeResult(x=state.best_x, fun=state.best_objective, stage="ga",
                           generation=state.generation, evaluations=objective.evaluations)
        stopped[0] = bool(callback(r))
        return stopped[0]

    ga = run_ga(objective, bounds, rng=rng, callback=ga_callback, progress=progress,
                **ga_settings)
    f = np.asarray(ga.x_best, dtype=float)
    interrupted, message = ga.interrupted, ga.message
    refinement = None

    if method == "ga+pem" and not interrupted:
        problem = PredictionErrorProblem(log, gain=ropts["gain"], substeps=substeps,
                                         lowpass_hz=lowpass_hz, workers=workers)
        order = np.argsort(ga.population_objective, kind="stable")
        starts = [f]
        for i in order:  # the best distinct individuals of the final population
            x = ga.population[i]
            if len(starts) >= int(ropts["n_starts"]):
                break
            if not any(np.array_equal(x, s) for s in starts):
                starts.append(x)

        def refine_callback(x, cost):
            if callback is None:
                return False
            r = OptimizeResult(x=x, fun=cost, stage="refine",
                               evaluations=objective.evaluations + problem.evaluations)
            stopped[0] = bool(callback(r))
            return stopped[0]

        ref = refine(problem, np.array(starts), bounds, max_nfev=int(ropts["max_nfev"]),
                     callback=refine_callback)
        f = ref.x
        interrupted = ref.interrupted
        message = f"{ga.message}; {ref.message}"
        refinement = dict(start_costs=ref.start_costs, costs=ref.costs, cost=ref.cost,
                          evaluations=ref.evaluations, ga_f=ga.x_best, gain=ropts["gain"])
        evaluations_refine = ref.evaluations
    else:
        evaluations_refine = 0

    y = float(objective(f[None])[0])
    wall = time.perf_counter() - t0
    hist = {k: np.asarray(v) for k, v in ga.history.items()}
    hist["generation"] = np.arange(len(hist["best"]))
    return IdentificationResult(
        f=f, x=f, objective=y, fun=y, method=method, seed=seed,
        history=hist, refinement=refinement,
        population=ga.population, population_objective=ga.population_objective,
        evaluations=int(objective.evaluations + evaluations_refine),
        wall_time_s=wall, compile_time_s=compile_s,
        interrupted=bool(interrupted), success=not interrupted, message=message,
        log_name=log.name, log=log, bounds=bounds,
        settings=dict(ga=ga_settings, refine=ropts if method == "ga+pem" else None,
                      substeps=int(substeps), lowpass_hz=lowpass_hz),
    )


def _identify_payload(log, method, f_prior, payload_bounds, rng, seed, ga_settings, ropts,
                      callback, workers, progress, lowpass_hz, substeps):
    """Payload mode of :func:`identify`: search p = [m, m xp, m yp, J] only."""
    from plant.payload import payload_delta_matrix, payload_from_vector

    pb = DEFAULT_PAYLOAD_BOUNDS if payload_bounds is None else payload_bounds
    pb = _check_bounds(pb, log, n=4)
    M = payload_delta_matrix(log.rig.a3_m)  # (9, 4): f = f_prior + M p

    def to_f(p):
        return f_prior + M @ np.asarray(p, dtype=float)

    compile_s = warm_up()
    t0 = time.perf_counter()
    objective = OutputError(log, substeps=substeps, lowpass_hz=lowpass_hz, workers=workers)

    def objective_p(P):
        return objective(np.atleast_2d(P) @ M.T + f_prior)

    ga = None
    refinement = None
    evaluations_refine = 0
    if method == "paper":
        def ga_callback(state):
            if callback is None:
                return False
            return bool(callback(OptimizeResult(x=state.best_x, fun=state.best_objective,
                                                stage="ga", generation=state.generation,
                                                evaluations=objective.evaluations)))

        ga = run_ga(objective_p, pb, rng=rng, callback=ga_callback, progress=progress,
                    **ga_settings)
        p, interrupted, message = np.asarray(ga.x_best), ga.interrupted, ga.message
    else:
        # Gauss-Newton on the prediction errors over x = [p (4), state at the first
        # sample (4)]: the state is a nuisance parameter (no quantised simulation
        # before a window, which would not be smooth in p).  Its initial guess: the
        # centre of the first count interval and the reference velocity.
        from plant.simulate import measured_counts

        scale = log.rig.pulses_per_rad
        q_first = measured_counts(log)[0] / scale
        t_first = log.t[:1]
        _, qd_ref, _ = log.trajectory.evaluate(t_first)
        x_state = np.concatenate([q_first, qd_ref[0]])
        dq = 2.0 / np.abs(scale)
        dqd = 0.2 * np.abs(qd_ref[0]) + 0.05
        state_bounds = np.column_stack([x_state - np.r_[dq, dqd], x_state + np.r_[dq, dqd]])
        xb = np.vstack([pb, state_bounds])
        problem = PredictionErrorProblem(log, to_f=lambda x: to_f(x[:4]),
                                         to_state=lambda x: x[4:], gain=ropts["gain"],
                                         substeps=substeps, lowpass_hz=lowpass_hz,
                                         workers=workers)
        lo, hi = pb[:, 0], pb[:, 1]
        # start at a light payload near the frame origin and at mid-range mass
        starts = np.array([lo + (hi - lo) * np.array([0.2, 0.5, 0.5, 0.1]),
                           lo + (hi - lo) * np.array([0.6, 0.5, 0.5, 0.3])])
        starts = starts[: max(1, int(ropts["n_starts"]))]
        starts = np.hstack([starts, np.tile(x_state, (len(starts), 1))])

        def refine_callback(x, cost):
            if callback is None:
                return False
            return bool(callback(OptimizeResult(x=x, fun=cost, stage="refine",
                                                evaluations=problem.evaluations)))

        ref = refine(problem, starts, xb, max_nfev=int(ropts["max_nfev"]),
                     callback=refine_callback)
        p, interrupted = ref.x[:4], ref.interrupted
        message = "payload: " + ref.message
        refinement = dict(start_costs=ref.start_costs, costs=ref.costs, cost=ref.cost,
                          evaluations=ref.evaluations, gain=ropts["gain"],
                          initial_state=ref.x[4:])
        evaluations_refine = ref.evaluations

    f = to_f(p)
    y = float(objective(f[None])[0])
    wall = time.perf_counter() - t0
    pl = payload_from_vector(p, clip_negative_inertia=True)
    payload_info = dict(mass_kg=pl.mass_kg, com_m=list(pl.com_m), izz_kgm2=pl.izz_kgm2,
                        vector=list(map(float, p)),
                        vector_names=["m_kg", "m_xp_kgm", "m_yp_kgm", "J_kgm2"])
    if ga is not None:
        hist = {k: np.asarray(v) for k, v in ga.history.items()}
        hist["generation"] = np.arange(len(hist["best"]))
    else:
        hist = {"generation": np.arange(1), "best": np.array([y]), "mean": np.array([y]),
                "evaluations": np.array([objective.evaluations + evaluations_refine])}
    return IdentificationResult(
        f=f, x=f, objective=y, fun=y, method=method, seed=seed, history=hist,
        refinement=refinement, population=None if ga is None else ga.population,
        population_objective=None if ga is None else ga.population_objective,
        evaluations=int(objective.evaluations + evaluations_refine), wall_time_s=wall,
        compile_time_s=compile_s, interrupted=bool(interrupted), success=not interrupted,
        message=message, log_name=log.name, log=log, bounds=pb, payload=payload_info,
        prior_f=f_prior,
        settings=dict(payload=True, substeps=int(substeps), lowpass_hz=lowpass_hz,
                      ga=ga_settings if method == "paper" else None,
                      refine=ropts if method != "paper" else None),
    )
