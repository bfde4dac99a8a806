"""``identify``: from a rig log to the base parameters f1..f9 (the main job)."""
from __future__ import annotations

import time
import warnings

import numpy as np
from scipy.optimize import OptimizeResult

import plant
from plant.logs.sanity import check_experiment

from .ga import PAPER_GA, run_ga
from .objective import IDENTIFICATION_SUBSTEPS, OutputError
from .parameters import (
    DEFAULT_PAYLOAD_BOUNDS,
    BaseParameters,
    ConsistentBaseParameters,
    Parameterisation,
    PayloadParameters,
)
from .flexible import MODELS, apply_model, open_joints_text
from .friction import FrictionParameters, default_friction_bounds, unknown_friction_indices
from .models import result_entries
from .refinement import DEFAULT_GAIN, PredictionErrorProblem, refine, widen_guessed_box
from .result import IdentificationResult
from .uncertainty import PoorExcitationWarning, uncertainty_entries, warning_text
from .window import estimate_initial_state

__all__ = ["identify", "METHODS", "DEFAULT_METHOD", "DEFAULT_PAYLOAD_BOUNDS",
           "ModelInadequacyWarning", "SearchBoundWarning", "GA_OPTION_KEYS", "at_bounds",
           "bounds_text", "excitation_text"]

#: Identification methods: the paper's GA alone, and GA + prediction-error
#: refinement (the default).
METHODS = ("ga+pem", "paper", "idim-ls", "idim-iv")
DEFAULT_METHOD = "ga+pem"

def _check_rng(rng):
    """``rng`` must be None, a seed >= 0 or a numpy Generator (one-line error otherwise)."""
    ok = (rng is None or isinstance(rng, np.random.Generator)
          or (isinstance(rng, (int, np.integer)) and not isinstance(rng, bool) and rng >= 0))
    if not ok:
        raise ValueError(f"rng must be None, an integer seed >= 0 or a numpy.random.Generator, "
                         f"got {rng!r}")


#: Keys of ``ga_options`` (the settings of :func:`identification.ga.run_ga`).
GA_OPTION_KEYS = ("n_subpops", "n_ind", "n_gen", "bits", "sp", "p_xover", "p_mut", "ggap",
                  "migration_rate", "migration_interval", "initial", "gray", "topology",
                  "immigrants", "early_stop")


def _checked_ga_options(ga_options) -> dict:
    """``ga_options`` validated against :data:`GA_OPTION_KEYS` (one-line errors)."""
    if ga_options is None:
        return {}
    if not isinstance(ga_options, dict):
        raise ValueError(f"ga_options must be a dict, got {type(ga_options).__name__}")
    unknown = sorted(set(ga_options) - set(GA_OPTION_KEYS))
    if unknown:
        raise ValueError(f"unknown ga_options key(s) {', '.join(map(repr, unknown))}; valid keys: "
                         + ", ".join(GA_OPTION_KEYS))
    for key in ("n_subpops", "n_ind", "n_gen", "migration_interval"):
        v = ga_options.get(key)
        if v is not None and (isinstance(v, bool) or not isinstance(v, (int, np.integer))
                              or v < 1):
            raise ValueError(f"ga_options[{key!r}] must be an integer >= 1, got {v!r}")
    return dict(ga_options)


def _seed_of(rng):
    if rng is None or isinstance(rng, (int, np.integer)):
        return None if rng is None else int(rng)
    return None


def _parameterisation(parameters, bounds, payload, prior, payload_bounds, consistent):
    """The parameterisation object from ``parameters=`` or the documented shorthands."""
    shorthand = bool(payload) or bool(consistent)
    if parameters is not None:
        if shorthand or prior is not None or payload_bounds is not None or bounds is not None:
            raise ValueError("give either parameters= or the shorthands (bounds, payload, prior, "
                             "payload_bounds, consistent), not both")
        if not isinstance(parameters, Parameterisation):
            raise ValueError("parameters must be an identification.Parameterisation (e.g. "
                             f"BaseParameters()), got {type(parameters).__name__}")
        return parameters
    if payload:
        if consistent:
            raise ValueError("payload and consistent cannot be combined")
        return PayloadParameters(prior, payload_bounds)
    if prior is not None or payload_bounds is not None:
        raise ValueError("prior and payload_bounds are only used with payload=True")
    if consistent:
        return ConsistentBaseParameters(bounds)
    return BaseParameters(bounds)


def _with_friction(space, log):
    """Wrap ``space`` in FrictionParameters when the log's friction is unknown."""
    if log.rig.unknown_friction and not isinstance(space, FrictionParameters):
        return FrictionParameters(space)
    return space


def identify(
    log,
    *,
    method=DEFAULT_METHOD,
    parameters=None,
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
    controller=None,
    model="auto",
):
    """Identify the base parameters f1..f9 from a P-control log.

    The paper's procedure: a multi-population GA (:func:`identification.ga.run_ga`)
    searches a box for the parameters whose simulated closed loop reproduces
    the logged integer tracking errors, minimising the output error of eq. 4
    (:class:`~identification.objective.OutputError`).  The default method
    then refines the GA's best individuals together by Levenberg-Marquardt on
    logged-input prediction errors (:mod:`identification.refinement`).

    Parameters
    ----------
    log : plant.ExperimentLog or path
        The experiment (CSV + JSON sidecar); rig, trajectory and start state
        come from it.
    method : {'ga+pem', 'paper', 'idim-ls', 'idim-iv'}
        ``'paper'`` runs the paper's GA alone (binary chromosome, its
        settings); ``'ga+pem'`` (default) runs the same GA on Gray-coded
        chromosomes and then the refinement (from the GA's best distinct
        individuals; when they all end more than
        :data:`~identification.flexible.FLOOR_FACTOR` quantisation floors up
        and the IDIM-LS estimate starts lower, from it too:
        ``refinement['idim_start']``); ``'idim-ls'`` the classical
        inverse dynamic model by least squares on the logged currents
        (:mod:`identification.idim`; the base parameters only), ``'idim-iv'``
        the same with the simulated closed loop's regressor as instruments.
    parameters : Parameterisation, optional
        What is searched (:mod:`identification.parameters`):
        :class:`~identification.parameters.BaseParameters` (default),
        :class:`~identification.parameters.ConsistentBaseParameters`,
        :class:`~identification.parameters.PayloadParameters`, or your own.
    bounds : array_like, shape (9, 2), optional
        Shorthand: search ranges of f1..f9 (default: the sidecar's), i.e.
        ``parameters=BaseParameters(bounds)``.
    rng : numpy.random.Generator or int >= 0, optional
        Random source (SPEC 7); the same seed gives the same result bit for
        bit, whatever the number of ``workers``.
    callback : callable, optional
        ``callback(intermediate_result) -> bool`` with an ``OptimizeResult``:
        after each GA generation ``stage='ga'``, ``generation``, ``x``,
        ``fun`` (output error, pulses^2), ``nfev``; after each refinement
        start has converged (or merged) ``stage='refine'``, ``start``
        (1-based), ``n_starts``, ``x``, ``fun`` (prediction-error cost,
        pulses^2), ``nfev``; during the model choice and the flexible fit
        ``stage='model'`` (the rigid result's ``x``, ``fun``), polled between
        refinement steps.  True stops the search and returns the best so far
        (``interrupted``; a stop in the model choice keeps the rigid result).
    workers : int, optional
        Threads of the parallel simulation (default: all available CPUs).
    progress : bool
        Show a tqdm progress bar per GA generation (only on a terminal).
    lowpass_hz : float, optional
        Low-pass both logged and simulated errors with the same zero-phase
        filter before comparing them (logs with flexible-joint oscillations).
    substeps : int
        RK4 substeps per sample while identifying.
    ga_options : dict, optional
        Overrides of the GA settings (:func:`~identification.ga.run_ga`; keys
        :data:`identification.api.GA_OPTION_KEYS`, an unknown key is refused).
        The default method runs the GA Gray-coded and with
        ``early_stop=1.0`` (offspring stop being simulated once their running
        output error passes the worst individual of the population);
        ``'paper'`` runs the paper's binary GA without early termination.
    refine_options : dict, optional
        ``gain`` (replay output injection, default 0.02), ``n_starts``
        (default 4), ``max_iter`` (batches, default 40), ``ftol`` (relative
        decrease of the cost below which a start has converged, default
        1e-10, or the parameterisation's ``refine_ftol``: 1e-6 for the
        payload).
    payload : bool
        Shorthand for ``parameters=PayloadParameters(prior, payload_bounds)``:
        on-line payload identification on top of the unloaded robot's f
        (typically on a short log or a window); the default method refines
        from four spread payloads directly (no GA), ``'paper'`` runs the GA.
    prior : IdentificationResult, dict with ``'f'``, or array_like (9,)
        The unloaded robot's f (with ``payload``).
    payload_bounds : array_like, shape (4, 2), optional
        Box of ``[m, xp, yp, Jc]`` (with ``payload``).
    consistent : bool
        Shorthand for ``parameters=ConsistentBaseParameters(bounds)``: eq. 3's
        ``f3 = a3 f5``, ``f4 = a3 f6``, seven free parameters.
    controller : object, optional
        The controller that ran the log, if not the rig's P law (e.g. a
        :class:`ctc.ComputedTorqueController`, or its
        :class:`plant.simulation.controllers.LoggedController` with the estimator state
        at the window's start): the output error simulates it in the loop,
        the refinement replays its logged currents (:mod:`plant.simulation.controllers`).

    model : {'auto', 'rigid', 'flexible'}
        The robot model (:mod:`identification.flexible`): ``'auto'``
        (default) keeps the rigid model when its prediction errors sit at
        the encoder's quantisation floor; otherwise it fits the two-mass
        flexible-joint model (friction included when the sidecar does not
        know it) with every fourth 0.1 s block held back, chooses it when it
        predicts the held-back samples better by the tests of every robot's
        model choice (:class:`identification.model_choice.ModelImprovement`:
        half the rigid model's held-back cost, a paired t per block, the
        quantisation floor reached, or half the excess over it), and adds
        gearbox backlash when the model chosen so far stays above the
        quantisation floor and the backlash predicts the held-back samples
        better by the same tests (``model_choice`` says which and why).
        A chosen model still far above the floor raises a
        :class:`ModelInadequacyWarning`; one that leaves more than
        :data:`~identification.flexible.RESTART_FRACTION` of the held-back
        error energy unexplained (a failed search) is searched again, up to
        :data:`~identification.flexible.MAX_RESTARTS` times
        (``model_choice['restarts']``).  Only with the default search (no
        low-pass, base parameters, ``'ga+pem'``, default budgets), otherwise
        rigid.

    Returns
    -------
    IdentificationResult
        ``x`` (the searched vector), ``f`` (f1..f9), ``fun`` (output error
        of eq. 4 at f, pulses^2, at ``settings['substeps']`` RK4 steps per
        sample), ``nfev``, ``nit``, ``success`` (False when interrupted or
        when the simulated closed loop at the result diverges), ``message``,
        ``population``, ``population_energies``, ``wall_time_s`` (the whole
        call) with ``stage_times_s``, and the domain keys.

    Raises
    ------
    ValueError
        On an unknown method, bad bounds or options, or ``payload`` without
        a valid ``prior``.
    plant.LogError
        If ``log`` is a path to a malformed log, or its signals cannot carry
        an identification (:func:`plant.logs.sanity.check_experiment`: too few
        samples for the parameters, all zero, impossible encoder counts or
        currents, currents that disagree with the rig's ``i = P e``).
    """
    if method == "default":
        method = DEFAULT_METHOD
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
    log = plant.as_log(log)
    if method in ("idim-ls", "idim-iv"):  # the classical inverse-dynamic model (issue 15)
        from .idim import identify_idim

        check_experiment(log, n_parameters=9 + len(log.rig.unknown_friction), p_control=True)

        return identify_idim(log, substeps=substeps, workers=workers, lowpass_hz=lowpass_hz,
                             seed=_seed_of(rng), method=method)
    _check_rng(rng)
    space = _with_friction(
        _parameterisation(parameters, bounds, payload, prior, payload_bounds, consistent), log)
    # a log that cannot carry an identification is refused in one line (issue 22)
    check_experiment(log, n_parameters=int(np.asarray(space.bounds(log)).shape[0]),
                     p_control=controller is None)
    seed = _seed_of(rng)
    rng = np.random.default_rng(rng)
    if workers is not None and int(workers) < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    ga_settings = dict(PAPER_GA, gray=(method != "paper"),
                       early_stop=None if method == "paper" else 1.0)
    ga_settings.update(_checked_ga_options(ga_options))
    ropts = dict(gain=DEFAULT_GAIN, n_starts=4, max_iter=40,
                 ftol=getattr(space, "refine_ftol", 1e-10))
    unknown = set(refine_options or {}) - set(ropts)
    if unknown:
        raise ValueError(f"unknown refine option(s): {', '.join(sorted(unknown))}")
    ropts.update(refine_options or {})
    if model not in MODELS:
        raise ValueError(f"unknown model {model!r}; choose one of {', '.join(MODELS)}")
    t_start = time.perf_counter()
    res = _search(log, space, method=method, rng=rng, seed=seed, ga_settings=ga_settings,
                  ropts=ropts, callback=callback, workers=workers, progress=progress,
                  lowpass_hz=lowpass_hz, substeps=substeps, controller=controller)
    t_search = time.perf_counter()
    wide = (res.get("refinement") or {}).get("friction_box_widened")
    if wide is not None:  # the model choice refits in the widened friction box
        space = FrictionParameters(space.base, friction_bounds=wide["friction_bounds"])
    eligible = (_default_space(space) and lowpass_hz is None and method == "ga+pem"
                and controller is None and log.rig.q0_rad is not None
                and not res.interrupted and (model == "flexible" or (
                    ga_options is None and refine_options is None)))
    stop = None
    if callback is not None:  # the caller's callback may stop the model choice too (Ctrl-C)
        stop = lambda: bool(callback(OptimizeResult(  # noqa: E731
            x=res.get("x"), fun=res.get("fun"), stage="model", nfev=res.get("nfev"))))
    res = apply_model(res, log, model, workers=workers, eligible=eligible, space=space, stop=stop,
                      rng=rng)
    search_s = float(res["wall_time_s"])
    t_model = time.perf_counter()
    if eligible and model == "auto":
        res = _restart_failed_search(res, log, space, model, dict(
            method=method, rng=rng, seed=seed, ga_settings=ga_settings, ropts=ropts,
            callback=callback, workers=workers, progress=progress, lowpass_hz=lowpass_hz,
            substeps=substeps), stop)
    t_end = time.perf_counter()
    # the whole call: compilation, search, model choice and every fit (issue 20)
    res["stage_times_s"] = dict(compile=float(res.get("compile_time_s") or 0.0),
                                search=search_s,
                                model_choice_and_flexible_fit=t_model - t_search,
                                restarts=t_end - t_model)
    res["wall_time_s"] = t_end - t_start
    res["at_bounds"] = at_bounds(res)
    if res["at_bounds"]:
        warnings.warn(bounds_text(res["at_bounds"]), SearchBoundWarning, stacklevel=2)
    for text in res.get("warnings") or []:
        warnings.warn(text, ModelInadequacyWarning, stacklevel=2)
    if res.get("poorly_excited"):
        warnings.warn(excitation_text(res), PoorExcitationWarning, stacklevel=2)
    joints_open = open_joints_text(res.get("joint_intervals"))
    if joints_open:  # a flexible result's springs or motors the log leaves open
        warnings.warn(joints_open, PoorExcitationWarning, stacklevel=2)
    return res


def _restart_failed_search(res, log, space, model, search_options, stop):
    """Restart a search whose chosen model predicts the held-back samples worse than 90 %.

    See step 6 of :mod:`identification.flexible`: up to
    :data:`~identification.flexible.MAX_RESTARTS` further searches and model
    choices (the random stream continued), the attempt with the smallest
    unexplained fraction kept (an attempt whose rigid model predicts the whole log
    to the quantisation floor counts as 0, :func:`~identification.flexible.unexplained_fraction`);
    every attempt is listed in ``model_choice['restarts']``.
    """
    from .flexible import MAX_RESTARTS, RESTART_FRACTION, unexplained_fraction

    frac = unexplained_fraction(res, log)
    if frac is None or frac <= RESTART_FRACTION:
        return res
    attempts = [dict(attempt=0, model=res["model_choice"].get("model"), unexplained_fraction=frac,
                     nfev=int(res.get("nfev") or 0))]
    best, best_frac = res, frac
    for i in range(1, MAX_RESTARTS + 1):
        nxt = _search(log, space, **search_options)
        if nxt.interrupted:
            break
        nxt = apply_model(nxt, log, model, workers=search_options["workers"], eligible=True,
                          space=space, stop=stop, rng=search_options["rng"])
        f_i = unexplained_fraction(nxt, log)
        attempts.append(dict(attempt=i, model=(nxt.get("model_choice") or {}).get("model"),
                             unexplained_fraction=f_i, nfev=int(nxt.get("nfev") or 0)))
        if f_i is not None and f_i < best_frac:
            best, best_frac = nxt, f_i
        if best_frac <= RESTART_FRACTION:
            break
    best["model_choice"] = dict(best["model_choice"], restarts=attempts)
    best["nfev"] = int(sum(a["nfev"] for a in attempts))
    kept = next(a["attempt"] for a in attempts if a["unexplained_fraction"] == best_frac)
    best["message"] = (f"search restarted {len(attempts) - 1} time(s): attempt 0 left "
                       f"{frac:.3g} of the held-back error energy unexplained (> {RESTART_FRACTION}); "
                       f"attempt {kept} kept ({best_frac:.3g}); " + str(best.get("message", "")))
    return best


class SearchBoundWarning(UserWarning):
    """The identified point lies on the search box (issue 22): the optimum may lie outside it.

    The names are in the result's ``at_bounds``.
    """


#: A parameter within this fraction of its range of a bound is "at the bound".
AT_BOUND_FRACTION = 1e-6


def at_bounds(res) -> list:
    """Names of the searched parameters that ended on their search bound.

    Parameters
    ----------
    res : IdentificationResult or dict
        With ``x`` (k,), ``bounds`` (k, 2) and ``x_names`` (k).

    Returns
    -------
    list of str
        ``'f3 (upper)'``-style entries: within ``AT_BOUND_FRACTION`` (1e-6) of
        the range of a bound.  A fixed parameter (empty range) and a bound
        at exactly 0 (a physical limit: a mass, an inertia or a friction
        constant cannot be negative) are not flagged.
    """
    x = res.get("x")
    xb = res.get("bounds")
    names = res.get("x_names")
    if x is None or xb is None or names is None:
        return []
    x = np.asarray(x, dtype=float).ravel()
    xb = np.asarray(xb, dtype=float).reshape(-1, 2)
    if not (len(x) == len(xb) == len(names)):
        return []
    out = []
    for name, xi, (lo, hi) in zip(names, x, xb):
        span = hi - lo
        if not span > 0:
            continue
        if xi <= lo + AT_BOUND_FRACTION * span and lo != 0.0:
            out.append(f"{name} (lower)")
        elif xi >= hi - AT_BOUND_FRACTION * span and hi != 0.0:
            out.append(f"{name} (upper)")
    return out


def bounds_text(names) -> str:
    """The one-line warning for parameters at their search bound.

    Parameters
    ----------
    names : list of str
        Entries of :func:`at_bounds`.

    Returns
    -------
    str
    """
    return (f"fit at the search bound: {', '.join(names)} -- the optimum may lie outside "
            "the search ranges (widen f_search_ranges in the sidecar, or check the log)")


class ModelInadequacyWarning(UserWarning):
    """The chosen model does not describe the log to its quantisation floor (issue 20).

    Raised by :func:`identify` with the held-back prediction-error cost and
    the floor in the text (:func:`identification.flexible.apply_model`); the
    result's ``model_choice['adequate']`` is False and its ``f_std``
    includes the model-form error.
    """


def excitation_text(res) -> str:
    """The poor-excitation warning of a result, naming the parameters it was judged on.

    Parameters
    ----------
    res : IdentificationResult or dict

    Returns
    -------
    str
    """
    unc = res.get("uncertainty") or {}
    names = unc.get("rse_names")
    rse = res.get("poorly_excited_rse")
    if names is not None and rse is not None:
        return warning_text(res["poorly_excited"], rse, all_names=names)
    return warning_text(res["poorly_excited"], res["f_rse"])


def _user_callback(callback, stage, nfev):
    """Wrap the user's callback for one stage: ``fn(x, fun, **info) -> bool``."""
    def fn(x, fun, **info):
        if callback is None:
            return False
        return bool(callback(OptimizeResult(x=x, fun=fun, stage=stage, nfev=nfev(), **info)))
    return fn


def _default_space(space) -> bool:
    """The base parameters f1..f9, with the friction the sidecar leaves unknown or not."""
    return type(space) is BaseParameters or (
        type(space) is FrictionParameters and type(space.base) is BaseParameters)


def _widen_friction_box(problem, ref, bounds, space, log, ropts):
    """Widen the guessed friction box where the refined fit ends on it.

    The unknown friction's box comes from the log
    (:func:`identification.friction.default_friction_bounds`: ``B <= T / w``,
    ``Tc <= T``), a guess: gravity and inertia supply torque too, so a
    robot whose weight drives a joint can dissipate more than the drive
    applied (a rigid arm carrying 3.4 kg with unknown friction,
    ``tests/data/independent/indep_20261327_0054``: its true B2 above the
    box, the fit on that bound far above the quantisation floor;
    ``tests/test_independent_logs.py``).  Its rows are widened as
    :func:`identification.arm.identify_arm` widens its guessed box
    (:func:`identification.refinement.widen_guessed_box`); the f box (the
    sidecar's or a caller's) is kept.

    Parameters
    ----------
    problem : PredictionErrorProblem
        The refinement's problem (its bounds do not enter it).
    ref : RefineResult
        The refinement's result.
    bounds : ndarray, shape (k_r, 2)
        Its box (the parameterisation's rows first, then any start state's).
    space : FrictionParameters
        The parameterisation (its friction rows last of its k).
    log : plant.ExperimentLog
    ropts : dict
        The refinement's options (``max_iter``, ``ftol``).

    Returns
    -------
    (RefineResult, ndarray, dict or None)
        The refinement kept, its box, and what was widened (``names``, the
        whole widened friction box ``friction_bounds`` (6, 2) for the model
        choice, ``message``; None when nothing was on the box).
    """
    names = space.names(log)
    k = len(names)
    rows = np.arange(k - len(unknown_friction_indices(log.rig)), k)
    friction = np.isin(np.arange(len(bounds)), rows)
    ref, box, on = widen_guessed_box(problem, ref, bounds, guessed=friction,
                                     nonnegative=friction, max_iter=int(ropts["max_iter"]),
                                     ftol=float(ropts["ftol"]))
    if not on:
        return ref, np.asarray(bounds, dtype=float), None
    listed = [names[i] for i in sorted(on)]
    fb = default_friction_bounds(log)
    fb[unknown_friction_indices(log.rig)] = box[rows]
    return ref, box, dict(
        names=listed, friction_bounds=fb.tolist(),
        message=(f"the friction box (the log's guess) widened where the fit ended on it: "
                 f"{', '.join(listed)}"))


def _idim_restart(log, problem, ref, bounds, state, ropts, callback=None):
    """A further refinement from the IDIM-LS estimate when the GA's starts end far off.

    The GA's best individuals may all lie in a wrong basin of the output error
    (a log with heavy unknown Coulomb friction: the refined prediction-error
    cost hundreds of quantisation floors above a point the classical inverse
    dynamic model, :func:`identification.idim.idim_ls`, finds in a fraction of
    a second).  When the refined cost exceeds
    :data:`~identification.flexible.FLOOR_FACTOR` floors (``n_samples * 2 / 12``
    pulses^2: each count known to a unit cell) and the IDIM-LS estimate's
    prediction-error cost is already lower, it is refined too and the lower of
    the two is kept.  (Gautier's IDIM as the initial guess of an output-error
    refinement: M. Gautier, W. Khalil, P. P. Restrepo, "Identification of the
    dynamic parameters of a closed loop robot", ICRA 1995; on logs the GA's
    starts fit, nothing changes: their cost is at the floor, or below the
    estimate's.)

    ``callback`` is :func:`~identification.refinement.refine`'s (a stop it
    asks for during the further refinement keeps the first one, marked
    interrupted).

    Returns
    -------
    ref : RefineResult
        The refinement kept.
    record : dict or None
        ``start_cost``, ``fun`` and ``used`` of the IDIM-LS start (None when it
        was not tried).
    """
    from .flexible import FLOOR_FACTOR, quantisation_floor
    from .idim import idim_ls

    floor = quantisation_floor(np.asarray(log.e_pulses).size)
    if not np.isfinite(ref.fun) or ref.fun <= FLOOR_FACTOR * floor:
        return ref, None
    try:
        x_idim = np.asarray(idim_ls(log)["x"], dtype=float)
    except (ValueError, np.linalg.LinAlgError):
        return ref, None
    k = x_idim.size
    if k + (0 if state is None else len(state[0])) != bounds.shape[0]:
        return ref, None
    start = x_idim if state is None else np.concatenate([x_idim, state[0]])
    start = np.clip(start, bounds[:, 0], bounds[:, 1])
    r0 = problem.residuals(start[None])[0]
    c0 = float(r0 @ r0)
    record = dict(start_cost=c0, fun=None, used=False)
    if not (np.isfinite(c0) and c0 < ref.fun):
        return ref, record
    alt = refine(problem, start[None], bounds, max_iter=int(ropts["max_iter"]),
                 ftol=float(ropts["ftol"]), callback=callback)
    record["fun"] = float(alt.fun)
    if alt.interrupted:
        ref.interrupted, ref.message = True, f"{ref.message}; {alt.message}"
        return ref, record
    if not alt.fun < ref.fun:
        return ref, record
    record["used"] = True
    alt.message = (f"{ref.message}; then from the IDIM-LS estimate (the GA's starts ended at "
                   f"{ref.fun:.4g} pulses^2, {ref.fun / floor:.3g} quantisation floors): {alt.message}")
    alt.nfev += ref.nfev
    alt.nit += ref.nit
    return alt, record


def _refine_starts(space, log, ga, n_starts):
    """The GA's best and the best distinct individuals of its final population."""
    if ga is None:
        return np.asarray(space.refine_starts(log), dtype=float)[: max(1, n_starts)]
    starts = [ga.x]
    for i in np.argsort(ga.population_energies, kind="stable"):
        if len(starts) >= n_starts:
            break
        xi = ga.population[i]
        if not any(np.array_equal(xi, s) for s in starts):
            starts.append(xi)
    return np.array(starts)


def _search(log, space, *, method, rng, seed, ga_settings, ropts, callback, workers, progress,
            lowpass_hz, substeps, controller=None):
    """GA on the output error and/or prediction-error refinement over a parameterisation."""
    compile_s = plant.warm_up(closed_loop=False)
    t0 = time.perf_counter()
    xb = space.bounds(log)
    k = xb.shape[0]
    refining = method == "ga+pem"
    state = space.initial_state(log) if refining else None
    unknown_start = log.rig.q0_rad is None  # a window without a start state
    if unknown_start and state is None:
        state = estimate_initial_state(log)
    sim_plant = space.plant(log)
    objective = OutputError(log, substeps=substeps, lowpass_hz=lowpass_hz, workers=workers,
                            initial_state=state[0] if unknown_start else None,
                            controller=controller, plant=sim_plant)
    if controller is not None or (sim_plant is not None
                                  and type(sim_plant.kind) is not type(plant.RIGID.kind)):
        # compile (or load) the kernel of this plant and control law before the
        # clock starts, as plant.warm_up does for the rigid plant and the P law
        t_c = time.perf_counter()
        x_mid = xb.mean(axis=1)
        extra = space.plant_parameters(x_mid[None], log)
        if extra is None:
            objective(space.to_f(x_mid[None], log))
        else:
            objective(space.to_f(x_mid[None], log), plant_parameters=extra)
        objective.nfev = 0
        compile_s += time.perf_counter() - t_c
        t0 = time.perf_counter()

    def f_objective(X, cap=None):
        extra = space.plant_parameters(np.atleast_2d(X), log)
        if extra is None:  # the rigid plant's call
            return objective(space.to_f(X, log), cap=cap)
        return objective(space.to_f(X, log), cap=cap, plant_parameters=extra)

    problem = None
    if refining:
        to_state = None if state is None else (lambda X: X[:, k:])
        problem = PredictionErrorProblem(log, to_f=lambda X: space.to_f(X[:, :k], log),
                                         to_state=to_state, gain=ropts["gain"],
                                         substeps=substeps, lowpass_hz=lowpass_hz,
                                         workers=workers, controller=controller,
                                         plant=sim_plant,
                                         to_plant_parameters=lambda X: space.plant_parameters(
                                             X[:, :k], log))

    def nfev():
        return objective.nfev + (problem.nfev if problem else 0)

    ga = None
    interrupted, messages, nit = False, [], 0
    use_ga = not refining or space.refine_starts(log) is None
    if use_ga:
        ga_cb = _user_callback(callback, "ga", nfev)
        ga = run_ga(f_objective, xb, rng=rng, progress=progress,
                    callback=lambda st: ga_cb(st.x, st.fun, generation=st.generation),
                    **ga_settings)
        x = np.asarray(ga.x, dtype=float)
        interrupted = ga.interrupted
        messages.append(ga.message)
        nit += ga.nit

    refinement, unc = None, {}
    if refining and not interrupted:
        starts = _refine_starts(space, log, ga, int(ropts["n_starts"]))
        rb = xb
        if state is not None:
            starts = np.hstack([starts, np.tile(state[0], (len(starts), 1))])
            rb = np.vstack([xb, state[1]])
        ref_cb = _user_callback(callback, "refine", nfev)
        ref = refine(problem, starts, rb, max_iter=int(ropts["max_iter"]), ftol=float(ropts["ftol"]),
                     callback=lambda i, n, xs, c: ref_cb(xs[:k], c, start=i, n_starts=n))
        idim_start = None
        if (ga is not None and not ref.interrupted and controller is None and lowpass_hz is None
                and _default_space(space)):
            ref, idim_start = _idim_restart(
                log, problem, ref, rb, state, ropts,
                callback=lambda i, n, xs, c: ref_cb(xs[:k], c, start=i, n_starts=n))
        widened = None
        if not ref.interrupted and isinstance(space, FrictionParameters) and space.guessed(log):
            # the friction box is the log's guess: widened where the fit ends on it
            ref, rb, widened = _widen_friction_box(problem, ref, rb, space, log, ropts)
            xb = rb[:k]
        x = ref.x[:k]
        interrupted = ref.interrupted
        messages.append(ref.message)
        nit += ref.nit
        refinement = dict(start_costs=ref.start_costs, costs=ref.costs, fun=ref.fun,
                          nfev=ref.nfev, nit=ref.nit, merged=ref.merged, gain=ropts["gain"])
        if idim_start is not None:
            refinement["idim_start"] = idim_start
        if widened is not None:
            refinement["friction_box_widened"] = widened
            messages.append(widened["message"])
        if ga is not None:
            refinement["ga_f"] = space.to_f(ga.x, log)
        if state is not None:
            refinement["initial_state"] = ref.x[k:]
        # warned about once, for the final result (identify(), after the model choice)
        unc = uncertainty_entries(ref.jac, ref.residuals, ref.x, lambda X: space.to_f(X, log),
                                  k=k, names=space.names(log), a3=log.rig.a3_m, warn=False,
                                  judge_x=getattr(space, "name", None) == "payload")

    f = space.to_f(x, log)
    # the GA's best was evaluated already; a refined point is evaluated once here
    x0 = refinement.get("initial_state") if (refinement and unknown_start) else None
    fun = float(ga.fun) if refinement is None else float(objective(
        f[None], initial_state=x0,
        plant_parameters=space.plant_parameters(np.atleast_2d(x), log))[0])
    diverged = refinement is not None and (
        not np.isfinite(fun) or int(objective.last_status[0]) != plant.STATUS_OK)
    if diverged and ga is not None:
        # never a diverged result (issue 20): a refined point whose simulated closed
        # loop fails is dropped for the GA's best.  (A finite output error above the
        # GA's is kept: the integer output error is rough, the prediction error the
        # refinement minimises is the better estimator, docs/alteration.rst.)
        messages.append("refined point rejected (its simulated closed loop diverges): "
                        "the GA's best is returned")
        refinement.update(rejected=True, x=np.asarray(x, dtype=float))
        x, f, fun = np.asarray(ga.x, dtype=float), space.to_f(ga.x, log), float(ga.fun)
        diverged = False
    elif diverged:
        messages.append("the simulated closed loop at the result diverges: no valid result")
    wall = time.perf_counter() - t0
    if ga is not None:
        hist = {name: np.asarray(v) for name, v in ga.history.items()}
        hist["generation"] = np.arange(len(hist["best"]))
    else:
        hist = {"generation": np.arange(1), "best": np.array([fun]), "mean": np.array([fun]),
                "nfev": np.array([nfev()])}
    return IdentificationResult(
        x=np.asarray(x, dtype=float), f=np.asarray(f, dtype=float), fun=fun, nfev=int(nfev()),
        nit=int(nit), success=not (interrupted or diverged), message="; ".join(messages),
        population=None if ga is None else ga.population,
        population_energies=None if ga is None else ga.population_energies,
        method=method, seed=seed, history=hist, refinement=refinement,
        wall_time_s=wall, compile_time_s=compile_s, interrupted=bool(interrupted),
        log_name=log.name, log=log, bounds=xb, x_names=list(space.names(log)),
        parameters=space.name,
        settings=dict(ga=ga_settings if ga is not None else None,
                      refine=ropts if refining else None, substeps=int(substeps),
                      lowpass_hz=lowpass_hz, parameters=repr(space)),
        **result_entries(space, x, log), **unc,
    )
