"""Flexible joints identified from position-only logs, and the rigid/flexible choice.

The two-mass plant (:class:`plant.plants.FlexibleJoints`, Spong's model: motor
``Jm k^2 th'' = k Kt i + tau_f(th') - tau_s``, link ``D_link(q) q'' + h + g =
tau_s``, ``tau_s = K (th - q) + D (th' - q')``, the encoder reads th) is
identified through :class:`FlexibleParameters`:
``x = [f1..f9, log10 K2, log10 K3, D2, D3, r2, r3]`` -- the rigid-equivalent
f exactly as the rigid model defines it (link plus ``Jm k^2`` in f7 and f1,
so every consumer of f keeps working), the joint stiffnesses on a log scale
(they span decades), the joint dampings, and the reflected motor inertias as
fractions of the f they sit in (``Jm2 k2^2 = r2 f7``, ``Jm3 k3^2 = r3 f1``,
``0 < r < 1`` keeps the link inertia positive).

Procedure (:func:`identify_flexible`, called by ``identify(model=...)``):

1. the rigid identification as always (its f is the start, and the rigid
   result is kept bit for bit when the rigid model is chosen);
2. a grid over (K2, K3) (:data:`STIFFNESS_GRID`, log-spaced) at the rigid f,
   light damping and r = 1/2, evaluated as one batch of logged-input
   prediction errors (:func:`plant.prediction_errors`);
3. the batched Levenberg-Marquardt refinement of :mod:`identification.refinement`
   over all 15 components from the grid's best points.

Substeps: RK4 is accurate when ``h w << 1`` for the fastest mode w; the
stiffest mode of a candidate is at most ``w_max = sqrt(K_max / J_min)``
(motor inertia against the spring, link locked) over the search box, and
:func:`flexible_substeps` takes ``ceil(w_max Ts / H_OMEGA)`` steps per sample
with :data:`H_OMEGA` = 0.5 (the prediction errors then change by less than
0.01 pulse when the substeps are doubled; tested).

Model choice (``model="auto"``, the default of the CLI): both models are fit
on the log with every fourth block of 0.1 s *held back* (its residuals are
not fitted; the replay still runs through it), and the flexible model is
chosen when its held-back prediction-error cost is below
:data:`CHOICE_RATIO` times the rigid model's.  Rationale, not a tuned
threshold: on a log the rigid model describes, both models sit at the
quantisation floor of the prediction errors (ratio ~1; a spring adds
nothing the held-back samples can confirm), while an unmodelled compliance
leaves structured residuals many times the floor.  Before that, a log that the
rigid fit already predicts to the quantisation floor (prediction-error cost
at most :data:`FLOOR_FACTOR` times ``n_residuals / 12`` pulse^2, the variance
of a count known to a unit cell; measured 0.99 and 1.01 on the two rigid
development logs) keeps the rigid result without a flexible fit, so rigid
logs cost no more than before.  ``auto`` considers the flexible model only
for the default search (default budgets, base parameters, known friction,
no low-pass).  The error spectrum's
lightly damped mode (:func:`identification.diagnostics.error_spectrum`) and
both costs are reported in ``model_choice``.

Accuracy on held-out logs (``benchmarks/bench_flexible.py``: six emulated
flexible logs, K 5e3..5e4 N m/rad, D 0.1..15 N m s/rad, payload 0..4 kg,
encoders 250..4096 ppr, P gains 0.1..0.2 A/pulse; default ``identify(log)``),
worst case of the relative error over the six logs:

=====  =====  =====  =====  =====  =====  =====  =====  =========  =========
f1     f2     f4     f6     f7     f9     K2     K3     Jm2 k2^2   Jm3 k3^2
=====  =====  =====  =====  =====  =====  =====  =====  =========  =========
0.01%  0.13%  0.15%  0.01%  0.23%  0.07%  0.5%   3.8%   0.24%      2.0%
=====  =====  =====  =====  =====  =====  =====  =====  =========  =========

``puma560_paper_drill_flex`` with no options: flexible chosen (held-back
ratio 0.018), f1 f2 f4 f6 f7 f9 within 0.11 %, K within 0.1 % of the
emulator's (3.0e4 / 6.0e3), about 30 s.
"""
from __future__ import annotations

import math

import numpy as np

from plant.plants import FlexibleJoints

from .parameters import BaseParameters, Parameterisation, check_bounds
from .refinement import DEFAULT_GAIN, PredictionErrorProblem, refine

__all__ = ["FlexibleParameters", "flexible_substeps", "identify_flexible", "choose_model",
           "apply_model", "held_back_cost",
           "DEFAULT_JOINT_BOUNDS", "STIFFNESS_GRID", "H_OMEGA", "CHOICE_RATIO", "FLOOR_FACTOR",
           "MODELS"]

#: Values of ``identify(model=...)`` and of the CLI's ``--model``.
MODELS = ("rigid", "flexible", "auto")

#: Box of ``[log10 K2, log10 K3, D2, D3, r2, r3]``: stiffness 1e3 .. 2e5 N m/rad
#: (gearboxes of industrial arms), damping 0 .. 50 N m s/rad, reflected motor
#: inertia 10 % .. 95 % of f7 (joint 2) / f1 (joint 3).
DEFAULT_JOINT_BOUNDS = np.array([[3.0, 5.3], [3.0, 5.3], [0.0, 50.0], [0.0, 50.0],
                                 [0.1, 0.95], [0.1, 0.95]])

#: log10 K of the start grid (per joint; all pairs are tried).
STIFFNESS_GRID = np.linspace(3.2, 5.2, 6)

#: RK4 step times the fastest mode's angular frequency (see the module docstring).
H_OMEGA = 0.5

#: The flexible model is chosen when its held-back cost is below this times the rigid's.
CHOICE_RATIO = 0.5

#: ``auto`` keeps the rigid result without fitting the flexible model when the
#: rigid prediction-error cost is at most this many times the quantisation floor
#: (``1/12`` pulse^2 per residual: a count known to a unit cell).
FLOOR_FACTOR = 2.0

#: Held-back blocks: every ``HOLD_EVERY``-th block of ``HOLD_BLOCK_S`` seconds.
HOLD_BLOCK_S = 0.1
HOLD_EVERY = 4

_PLANT = FlexibleJoints(1.0, 0.0, 1.0)  # constants unused: every lane carries its joints


class FlexibleParameters(Parameterisation):
    """Rigid-equivalent f plus the flexible joints (see the module docstring).

    Parameters
    ----------
    bounds : array_like, shape (9, 2), optional
        Ranges of f1..f9 (default the sidecar's).
    joint_bounds : array_like, shape (6, 2), optional
        Box of ``[log10 K2, log10 K3, D2, D3, r2, r3]`` (default
        :data:`DEFAULT_JOINT_BOUNDS`).

    Raises
    ------
    ValueError
        On malformed bounds.
    """

    name = "flexible"

    def __init__(self, bounds=None, joint_bounds=None):
        self.base = BaseParameters(bounds)
        self.joint_bounds = check_bounds(
            DEFAULT_JOINT_BOUNDS if joint_bounds is None else joint_bounds, 6)

    def names(self, log) -> list:
        """f1..f9, ``log10_K2``, ``log10_K3``, ``D2``, ``D3``, ``r2``, ``r3``.

        Parameters
        ----------
        log : plant.ExperimentLog
        """
        return self.base.names(log) + ["log10_K2", "log10_K3", "D2", "D3", "r2", "r3"]

    def bounds(self, log) -> np.ndarray:
        """The f box and the joint box, shape (15, 2).

        Parameters
        ----------
        log : plant.ExperimentLog
        """
        return np.vstack([self.base.bounds(log), self.joint_bounds])

    def to_f(self, x, log) -> np.ndarray:
        """The rigid-equivalent f (the first nine components).

        Parameters
        ----------
        x : ndarray, shape (15,) or (m, 15)
        log : plant.ExperimentLog
        """
        return np.asarray(x, dtype=float)[..., :9]

    @staticmethod
    def joints(x) -> np.ndarray:
        """``(K2, K3, D2, D3, Jm2 k2^2, Jm3 k3^2)`` of x.

        Parameters
        ----------
        x : ndarray, shape (15,) or (m, 15)

        Returns
        -------
        ndarray, shape (6,) or (m, 6)
        """
        x = np.asarray(x, dtype=float)
        return np.stack([10.0 ** x[..., 9], 10.0 ** x[..., 10], x[..., 11], x[..., 12],
                         x[..., 13] * x[..., 6], x[..., 14] * x[..., 0]], axis=-1)

    def plant(self, log):
        """A :class:`plant.plants.FlexibleJoints` (its lanes carry each candidate's joints).

        Parameters
        ----------
        log : plant.ExperimentLog
        """
        return _PLANT

    def plant_parameters(self, x, log):
        """``{"joints": (m, 6)}``.

        Parameters
        ----------
        x : ndarray, shape (m, 15)
        log : plant.ExperimentLog
        """
        return {"joints": np.atleast_2d(self.joints(x))}

    def extras(self, x, log) -> dict:
        """``model`` and the identified joints (the JSON keys of the module docstring).

        Parameters
        ----------
        x : ndarray, shape (15,)
        log : plant.ExperimentLog
        """
        j = self.joints(x)
        return dict(model="flexible", joint_stiffness_Nm_per_rad=[float(j[0]), float(j[1])],
                    joint_damping_Nms_per_rad=[float(j[2]), float(j[3])],
                    motor_inertia_reflected_kgm2=[float(j[4]), float(j[5])])

    def __repr__(self) -> str:
        return "FlexibleParameters()"


def flexible_substeps(log, joint_bounds=DEFAULT_JOINT_BOUNDS, bounds=None) -> int:
    """RK4 substeps per sample for the flexible plant (rule of the module docstring).

    Parameters
    ----------
    log : plant.ExperimentLog
    joint_bounds : array_like, shape (6, 2)
        The joint box (stiffest spring, lightest reflected inertia).
    bounds : array_like, shape (9, 2), optional
        Box of f (default the sidecar's).

    Returns
    -------
    int
        ``ceil(sqrt(K_max / J_min) Ts / H_OMEGA)``, at least 1.
    """
    jb = np.asarray(joint_bounds, dtype=float)
    fb = log.rig.bounds if bounds is None else np.asarray(bounds, dtype=float)
    k_max = 10.0 ** jb[:2, 1].max()
    j_min = min(jb[4, 0] * max(fb[6, 0], 1e-3), jb[5, 0] * max(fb[0, 0], 1e-3))
    w = math.sqrt(k_max / j_min)
    return max(1, int(math.ceil(w * log.rig.sample_time_s / H_OMEGA)))


def _hold_mask(log):
    """Residual mask (2 n,) of the fitted samples: every HOLD_EVERY-th block held back."""
    n = log.n_samples
    block = max(1, int(round(HOLD_BLOCK_S / log.rig.sample_time_s)))
    held = (np.arange(n) // block) % HOLD_EVERY == HOLD_EVERY - 1
    return np.repeat(~held, 2), np.repeat(held, 2)


class _Masked:
    """A prediction-error problem restricted to some residuals (the fitted samples)."""

    def __init__(self, problem, mask):
        self.problem = problem
        self.mask = mask

    @property
    def nfev(self):
        return self.problem.nfev

    def residuals(self, X):
        R = self.problem.residuals(X)
        return R[..., self.mask]


def _problem(log, space, substeps, workers, gain):
    return PredictionErrorProblem(
        log, to_f=lambda X: space.to_f(X, log), gain=gain, substeps=substeps, workers=workers,
        plant=space.plant(log), to_plant_parameters=lambda X: space.plant_parameters(X, log))


def identify_flexible(log, rigid, *, substeps=None, workers=None, gain=DEFAULT_GAIN,
                      n_starts=4, max_iter=40, hold_back=False, space=None):
    """Fit the flexible model from the rigid result's f (grid over K, then refinement).

    Parameters
    ----------
    log : plant.ExperimentLog
    rigid : IdentificationResult
        The rigid identification of the same log (its f starts the fit).
    substeps : int, optional
        RK4 substeps per sample (default :func:`flexible_substeps`).
    workers : int, optional
        Threads.
    gain : float
        Output-injection gain of the replay.
    n_starts : int
        Refinement starts (the grid's best points).
    max_iter : int
        Refinement batches at most.
    hold_back : bool
        Fit without the held-back blocks (model choice).
    space : FlexibleParameters, optional
        Default ``FlexibleParameters()``.

    Returns
    -------
    dict
        ``x`` (15,), ``f`` (9,), ``cost`` (fitted prediction-error cost),
        ``refine`` (:class:`~identification.refinement.RefineResult`),
        ``substeps``, ``space``.
    """
    space = FlexibleParameters() if space is None else space
    substeps = flexible_substeps(log, space.joint_bounds) if substeps is None else int(substeps)
    xb = space.bounds(log)
    problem = _problem(log, space, substeps, workers, gain)
    fit = problem
    if hold_back:
        fit = _Masked(problem, _hold_mask(log)[0])
    f0 = np.clip(np.asarray(rigid["f"], dtype=float), xb[:9, 0], xb[:9, 1])
    grid = np.array([(a, b) for a in STIFFNESS_GRID for b in STIFFNESS_GRID])
    X = np.empty((len(grid), 15))
    X[:, :9] = f0
    X[:, 9:11] = grid
    r = 0.5
    jk = np.array([r * f0[6], r * f0[0]])
    X[:, 11:13] = 0.02 * np.sqrt(10.0 ** grid * jk)  # light damping
    X[:, 13:15] = r
    X = np.clip(X, xb[:, 0], xb[:, 1])
    R = fit.residuals(X)
    costs = np.einsum("ij,ij->i", R, R)
    starts = X[np.argsort(costs, kind="stable")[:max(1, n_starts)]]
    ref = refine(fit, starts, xb, max_iter=max_iter)
    return dict(x=ref.x, f=space.to_f(ref.x, log), cost=ref.fun, refine=ref,
                substeps=substeps, space=space, grid_costs=costs)


def held_back_cost(log, x, space, substeps, workers=None, gain=DEFAULT_GAIN):
    """Prediction-error cost (pulses^2) of x on the held-back blocks only.

    Parameters
    ----------
    log : plant.ExperimentLog
    x : ndarray, shape (k,)
    space : Parameterisation
    substeps : int
    workers : int, optional
    gain : float

    Returns
    -------
    float
    """
    r = _problem(log, space, substeps, workers, gain).residuals(np.atleast_2d(x))[0]
    held = _hold_mask(log)[1]
    return float(r[held] @ r[held])


def choose_model(log, rigid, *, workers=None, gain=DEFAULT_GAIN):
    """Rigid or flexible: compare both fits on held-back samples (module docstring).

    Parameters
    ----------
    log : plant.ExperimentLog
    rigid : IdentificationResult
        The rigid identification of the log.
    workers : int, optional
    gain : float

    Returns
    -------
    (str, dict)
        The chosen model and ``model_choice``: ``rule``,
        ``held_back_cost_rigid_pulses2``, ``held_back_cost_flexible_pulses2``,
        ``ratio``, ``mode_hz`` and ``mode_prominence_dec`` of the error
        spectrum, ``reason``.
    """
    from .diagnostics import error_spectrum

    base = BaseParameters()
    # rigid, refit without the held-back blocks (from the full fit's f)
    rp = PredictionErrorProblem(log, gain=gain, substeps=rigid.substeps, workers=workers)
    mask_fit, held = _hold_mask(log)
    ref_r = refine(_Masked(rp, mask_fit), np.atleast_2d(rigid["f"]), base.bounds(log),
                   max_iter=20)
    r_rigid = rp.residuals(ref_r.x)
    c_rigid = float(r_rigid[held] @ r_rigid[held])
    flex = identify_flexible(log, rigid, workers=workers, gain=gain, hold_back=True)
    c_flex = held_back_cost(log, flex["x"], flex["space"], flex["substeps"], workers, gain)
    ratio = c_flex / c_rigid if c_rigid > 0 else 1.0
    try:
        spec = error_spectrum(log)
        mode = [None if not np.isfinite(v) else float(v) for v in spec.mode_hz]
        prom = [None if not np.isfinite(v) else float(v) for v in spec.mode_prominence_dec]
    except ValueError:
        mode, prom = [None, None], [None, None]
    chosen = "flexible" if ratio < CHOICE_RATIO else "rigid"
    reason = (f"held-back prediction-error cost flexible/rigid = {ratio:.3g} "
              f"({c_flex:.4g} / {c_rigid:.4g} pulses^2) "
              f"{'<' if chosen == 'flexible' else '>='} {CHOICE_RATIO}; error spectrum mode "
              + ", ".join(f"e{j + 2} {'none' if m is None else f'{m:.1f} Hz'}"
                          for j, m in enumerate(mode)))
    return chosen, dict(rule=f"flexible if held-back cost ratio < {CHOICE_RATIO}",
                        held_back_cost_rigid_pulses2=c_rigid,
                        held_back_cost_flexible_pulses2=c_flex, ratio=ratio, mode_hz=mode,
                        mode_prominence_dec=prom, reason=reason, model=chosen)


def _flexible_result(rigid, log, fit, model_choice, workers):
    """The IdentificationResult of a flexible fit (the rigid result's bookkeeping kept)."""
    from .objective import OutputError
    from .result import IdentificationResult

    space, x = fit["space"], fit["x"]
    objective = OutputError(log, substeps=fit["substeps"], workers=workers, plant=space.plant(log))
    fun = float(objective(fit["f"][None],
                          plant_parameters=space.plant_parameters(np.atleast_2d(x), log))[0])
    ref = fit["refine"]
    res = IdentificationResult(dict(rigid))
    settings = dict(rigid.get("settings") or {})
    settings.update(substeps=int(fit["substeps"]), parameters=repr(space), model="flexible")
    res.update(
        x=np.asarray(x, dtype=float), f=np.asarray(fit["f"], dtype=float), fun=fun,
        nfev=int(rigid["nfev"]) + int(ref.nfev) + 1, nit=int(rigid["nit"]) + int(ref.nit),
        message=f"{rigid['message']}; flexible: {ref.message}", bounds=space.bounds(log),
        x_names=space.names(log), parameters=space.name, settings=settings,
        rigid_f=np.asarray(rigid["f"], dtype=float), rigid_fun=float(rigid["fun"]),
        refinement=dict(start_costs=ref.start_costs, costs=ref.costs, fun=ref.fun,
                        nfev=ref.nfev, nit=ref.nit, merged=ref.merged,
                        ga_f=np.asarray(rigid["f"], dtype=float)),
        population=None, population_energies=None)
    res.update(space.extras(x, log))
    # standard errors of the flexible fit (issue 15), replacing the rigid fit's
    from .uncertainty import RESULT_KEYS, uncertainty_entries

    for key in RESULT_KEYS:
        res.pop(key, None)
    xs = np.asarray(x, dtype=float)
    res.update(uncertainty_entries(ref.jac, ref.residuals, ref.x, lambda X: space.to_f(X, log),
                                   k=xs.size, names=space.names(log), a3=log.rig.a3_m,
                                   warn=False))
    res["model_choice"] = model_choice
    return res


def apply_model(rigid, log, model, *, workers=None, eligible=True):
    """The result for ``identify(model=...)`` from the rigid identification of the log.

    Parameters
    ----------
    rigid : IdentificationResult
        The rigid identification (default parameterisation).
    log : plant.ExperimentLog
    model : {'rigid', 'flexible', 'auto'}
        ``'auto'``: :func:`choose_model` unless the rigid model already
        predicts the log to its quantisation floor (module docstring).
    workers : int, optional
    eligible : bool
        False when the identification's options rule the flexible model out
        (a low-pass filter, another parameterisation, the paper's method,
        unknown friction): ``'auto'`` then keeps the rigid result and says
        why, ``'flexible'`` raises.

    Returns
    -------
    IdentificationResult

    Raises
    ------
    ValueError
        On an unknown model, or ``'flexible'`` with options that rule it out.
    """
    if model not in MODELS:
        raise ValueError(f"unknown model {model!r}; choose one of {', '.join(MODELS)}")
    if model == "rigid":
        return rigid
    if not eligible:
        if model == "flexible":
            raise ValueError("model='flexible' identifies the default parameterisation with the "
                             "default method, known friction and no low-pass filter")
        rigid["model_choice"] = dict(model="rigid", reason="options other than the default "
                                     "search (low-pass, parameterisation, method or unknown "
                                     "friction): rigid model")
        return rigid
    if model == "auto":
        ref = rigid.get("refinement") or {}
        floor = 2 * log.n_samples / 12.0
        level = float(ref.get("fun", np.inf)) / floor
        if level <= FLOOR_FACTOR:
            rigid["model_choice"] = dict(
                model="rigid", floor_ratio=level,
                reason=f"the rigid model predicts the log to the quantisation floor "
                       f"(prediction-error cost {level:.3g} x n/12 <= {FLOOR_FACTOR})")
            return rigid
        chosen, choice = choose_model(log, rigid, workers=workers)
        if chosen == "rigid":
            rigid["model_choice"] = choice
            return rigid
    else:
        choice = dict(model="flexible", reason="model='flexible' requested")
    fit = identify_flexible(log, rigid, workers=workers)
    return _flexible_result(rigid, log, fit, choice, workers)
