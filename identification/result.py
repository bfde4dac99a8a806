"""The result object of an identification (scipy ``OptimizeResult`` style)."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
from scipy.optimize import OptimizeResult

from plant.rig import F_NAMES, F_UNITS

__all__ = ["IdentificationResult", "write_json_atomic"]


def write_json_atomic(path, data):
    """Write ``data`` as JSON to ``path`` atomically (temp file + ``os.replace``).

    A failure (e.g. a value JSON cannot hold) leaves no partial file behind.
    """
    from plant.log import _atomic_write

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    _atomic_write(path, json.dumps(data, indent=2, allow_nan=False) + "\n")


def _jsonable(x):
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        x = float(x)
        return x if math.isfinite(x) else None
    return x


class IdentificationResult(OptimizeResult):
    """Outcome of :func:`identification.identify`.

    Attributes
    ----------
    f, x : ndarray, shape (9,)
        Identified base parameters f1..f9 (SI units, :data:`plant.F_UNITS`).
    objective, fun : float
        Output error of paper eq. 4 at ``f`` on the log (pulses^2), computed
        with the identification's simulation settings (and low-pass filter,
        if one was used).
    method : str
        ``'paper'`` (the paper's GA alone) or ``'ga+pem'`` (GA, then
        prediction-error refinement).
    seed : int or None
        The integer seed, if ``rng`` was one.
    history : dict of ndarray
        Per GA generation (index 0: initial population): ``'generation'``,
        ``'best'`` (best objective in the population), ``'mean'``,
        ``'evaluations'`` (cumulative simulations).
    refinement : dict or None
        ``'start_costs'``, ``'costs'`` (prediction-error cost per start,
        pulses^2), ``'cost'``, ``'evaluations'``, ``'ga_f'`` (the GA's best f).
    population : ndarray, shape (n_individuals, 9)
        Final GA population; ``population_objective`` (n_individuals,).
    evaluations : int
        Simulations run in total (GA + refinement + final evaluation).
    wall_time_s : float
        Wall-clock time of the identification (s), JIT compilation excluded.
    interrupted : bool
        True when stopped by Ctrl-C or by the callback (best so far returned).
    success : bool
    message : str
    log_name : str
    bounds : ndarray, shape (9, 2)
        Search ranges used.
    payload : dict or None
        Identified payload (payload mode only).
    """

    def __dir__(self):
        return list(self.keys())

    # -- serialisation --------------------------------------------------
    def to_dict(self):
        """JSON-ready dict; the keys of the CLI's result file.

        Keys: ``f`` (list of 9 floats, f1..f9), ``f_named``, ``f_units``,
        ``objective_pulses2``, ``evaluations``, ``wall_time_s``, ``method``,
        ``seed``, ``log``, ``interrupted``, ``message``, ``bounds``,
        ``history``, ``refinement``, settings, and the payload keys in payload
        mode (``payload_mass_kg`` ...).
        """
        f = np.asarray(self.f, dtype=float)
        d = {
            "f": [float(v) for v in f],
            "f_named": {n: float(v) for n, v in zip(F_NAMES, f)},
            "f_units": dict(zip(F_NAMES, F_UNITS)),
            "objective_pulses2": float(self.objective),
            "evaluations": int(self.evaluations),
            "wall_time_s": float(self.wall_time_s),
            "method": self.method,
            "seed": self.get("seed"),
            "log": self.get("log_name"),
            "interrupted": bool(self.interrupted),
            "message": self.message,
            "bounds": self.get("bounds"),
            "settings": self.get("settings", {}),
            "history": self.get("history", {}),
            "refinement": self.get("refinement"),
        }
        payload = self.get("payload")
        if payload:
            d["payload"] = payload
            for k, v in payload.items():
                d[f"payload_{k}"] = v
        return _jsonable(d)

    def save_json(self, path):
        """Write :meth:`to_dict` to ``path`` atomically (no partial file on error)."""
        write_json_atomic(path, self.to_dict())

    # -- plots --------------------------------------------------------------
    def plot(self, fig=None):
        """Convergence plot: best and mean output error per GA generation.

        Returns
        -------
        matplotlib.figure.Figure
            Never shown; the refined objective is marked when there is one.
        """
        from matplotlib.figure import Figure

        if fig is None:
            fig = Figure(figsize=(7, 4.2), layout="constrained")
        ax = fig.subplots()
        h = self.history
        ax.semilogy(h["evaluations"], h["best"], "-", label="GA best")
        mean = np.asarray(h["mean"], dtype=float)
        ax.semilogy(h["evaluations"], mean, "-", alpha=0.6, label="GA mean")
        if self.get("refinement"):
            ax.semilogy([self.evaluations], [self.objective], "o", label="after refinement")
        ax.set_xlabel("simulations")
        ax.set_ylabel("output error Y (pulses$^2$, eq. 4)")
        ax.set_title(f"{self.get('log_name', '')}: method {self.method}")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
        return fig

    def plot_tracking_errors(self, log=None, *, substeps=None, fig=None):
        """Logged vs simulated tracking errors of the identified model.

        Parameters
        ----------
        log : plant.ExperimentLog, optional
            The log to compare with (default: the identified one).  A
            different log (e.g. a validation run) cross-validates ``f``.
        substeps : int, optional
            RK4 substeps (default :data:`plant.DEFAULT_SUBSTEPS`).
        fig : matplotlib.figure.Figure, optional

        Returns
        -------
        matplotlib.figure.Figure
        """
        import plant

        log = log if log is not None else self.get("log")
        if log is None:
            raise ValueError("no log attached to this result: pass one")
        e = plant.simulate_experiment(
            log, self.f, substeps=substeps or plant.DEFAULT_SUBSTEPS
        )
        y = float(np.sum((log.e_pulses - e) ** 2))
        return plant.plot_tracking_errors(
            log.t, log.e_pulses, e, labels=("logged", "identified model"),
            title=f"{log.name}: output error {y:.0f} pulses$^2$", fig=fig,
        )
