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

    Returns
    -------
    IdentificationResult

    Raises
    ------
    ValueError
        On an unknown method, bad bounds or options.
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
