"""The result object of an identification (scipy ``OptimizeResult`` style).

:class:`IdentificationResult` holds what :func:`identification.identify`
found, writes it as JSON (:meth:`~IdentificationResult.save_json`), reads it
back (:meth:`~IdentificationResult.load_json`) and plots it.

One number for one thing: ``fun`` is the output error of paper eq. 4 at
``f`` computed with the identification's own integration setting
(``settings["substeps"]`` RK4 steps per sample, and its low-pass filter if
any).  The CLI table, the JSON (``fun`` = ``objective_pulses2``), ``repr``
and the plot titles all report that same number and say which setting it is
at; :meth:`~IdentificationResult.plot_tracking_errors` simulates with that
setting by default, and says so when asked for another one (e.g. the exact
reproduction, :data:`plant.DEFAULT_SUBSTEPS` RK4 steps per sample).
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
from scipy.optimize import OptimizeResult

from plant.fileio import read_json_object, write_text_atomic
from plant.rig import F_NAMES, F_UNITS

__all__ = ["IdentificationResult", "ResultFileError", "write_json_atomic", "describe_setting"]

#: Keys written by :meth:`IdentificationResult.to_dict` that
#: :meth:`IdentificationResult.load_json` requires (an alternative older name
#: in parentheses): ``f``, ``fun`` (``objective_pulses2``), ``nfev``
#: (``evaluations``), ``method``.
_REQUIRED = (("f",), ("fun", "objective_pulses2"), ("nfev", "evaluations"), ("method",))


class ResultFileError(ValueError):
    """A result file that cannot be read back (one-line message naming the file)."""


def write_json_atomic(path, data, *, create_dirs=True):
    """Write ``data`` as JSON to ``path`` atomically (policy of :mod:`plant.fileio`).

    The text is produced first (``allow_nan=False``), so a value JSON cannot
    hold raises before anything is written; no partial file is ever left.

    Parameters
    ----------
    path : str or os.PathLike
        Output file.  A symlink is written through; a directory, device,
        FIFO or socket is refused.
    data : object
        JSON-serialisable data (finite floats only).
    create_dirs : bool
        Create a missing parent directory (default, as this function always
        did); the created directories are listed in the returned
        ``created_dirs``.  False refuses a missing directory.

    Returns
    -------
    plant.fileio.OutputTarget
        The file written (``target``) and the directories created
        (``created_dirs``).

    Raises
    ------
    TypeError, ValueError
        If ``data`` is not JSON-serialisable (nothing is written).
    plant.fileio.OutputFileError
        If the target is refused by the output-file policy.
    OSError
        If writing fails.
    """
    text = json.dumps(data, indent=2, allow_nan=False) + "\n"
    return write_text_atomic(path, text, create_dirs=create_dirs)


def _jsonable(x):
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, np.bool_):
        return bool(x)
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        x = float(x)
        return x if math.isfinite(x) else None
    return x


def describe_setting(substeps, lowpass_hz=None, *, identification_substeps=None):
    """Human-readable integration setting of an output error.

    Parameters
    ----------
    substeps : int
        RK4 steps per sample of the simulation.
    lowpass_hz : float, optional
        Cutoff (Hz) of the zero-phase low-pass applied to both error
        sequences, if any.
    identification_substeps : int, optional
        The identification's setting; when ``substeps`` equals it the text
        says "(identification)".

    Returns
    -------
    str
        E.g. ``"1 RK4 step/sample (identification)"`` or
        ``"exact reproduction, 48 RK4 steps/sample"``.
    """
    from plant import DEFAULT_SUBSTEPS

    n = int(substeps)
    steps = f"{n} RK4 step{'s' if n != 1 else ''}/sample"
    tags = []
    if identification_substeps is not None and n == int(identification_substeps):
        tags.append("identification")
    if n == DEFAULT_SUBSTEPS:
        tags.append("exact reproduction")
    if tags == ["exact reproduction"]:
        text = f"exact reproduction, {steps}"
    elif tags:
        text = f"{steps} ({', '.join(tags)})"
    else:
        text = steps
    if lowpass_hz is not None:
        text += f", low-passed at {float(lowpass_hz):.4g} Hz"
    return text


def _fmt_y(y):
    """The one format of an output error (pulses^2) in text, titles and tables."""
    return "nan" if y is None else f"{float(y):.6g}"


def _summary(a, n=9):
    """One-line summary of an array: values if short, else shape and range."""
    if a is None:
        return "None"
    a = np.asarray(a)
    if a.ndim == 1 and a.size <= n and a.dtype.kind in "fiu":
        return "[" + ", ".join(f"{v:.4g}" for v in a.tolist()) + "]"
    if a.size and a.dtype.kind in "fiu":
        return f"array{a.shape} in [{np.nanmin(a):.4g}, {np.nanmax(a):.4g}]"
    return f"array{a.shape}"


class IdentificationResult(OptimizeResult):
    """Outcome of :func:`identification.identify` (a ``scipy.optimize.OptimizeResult``).

    Attributes
    ----------
    x : ndarray, shape (k,)
        The searched vector (names in ``x_names``); equals ``f`` for the
        plain 9-parameter search (``parameters == "base"``).
    f : ndarray, shape (9,)
        Identified base parameters f1..f9 (SI units, :data:`plant.F_UNITS`).
    fun : float
        Output error of paper eq. 4 at ``f`` on the log (pulses^2), computed
        with the identification's integration setting
        (``settings["substeps"]`` RK4 steps per sample) and its low-pass
        filter (``settings["lowpass_hz"]``) if any.
    nfev : int
        Simulations run in total (GA + refinement + final evaluation).
    nit : int
        GA generations + refinement iterations.
    success : bool
        False when interrupted.
    message : str
        What the optimisers reported.
    population : ndarray, shape (n_individuals, k) or None
        Final GA population (None without a GA); not written to JSON.
    population_energies : ndarray, shape (n_individuals,) or None
        Output errors of ``population`` (pulses^2); not written to JSON.
    method : str
        ``'paper'`` (the paper's GA alone) or ``'ga+pem'`` (GA, then
        prediction-error refinement).
    seed : int or None
        The integer seed, if ``rng`` was one.
    history : dict of ndarray
        Per GA generation (index 0: initial population): ``'generation'``,
        ``'best'`` (best output error in the population, pulses^2, at the
        identification setting), ``'best_so_far'``, ``'mean'``, ``'nfev'``
        (cumulative simulations).
    refinement : dict or None
        ``'start_costs'``, ``'costs'`` (prediction-error cost per start,
        pulses^2), ``'fun'``, ``'nfev'``, ``'nit'``, ``'merged'`` (merged
        start pairs), ``'gain'``, ``'ga_f'`` (the GA's best f),
        ``'initial_state'`` (estimated state at the first sample, payload
        mode); None for ``method='paper'``.
    wall_time_s : float
        Wall-clock time of the identification (s), JIT compilation excluded.
    compile_time_s : float
        Time spent compiling (or loading) the numerical kernels (s).
    interrupted : bool
        True when stopped by Ctrl-C or by the callback (best so far returned).
    log_name : str
        Name (file stem) of the log.
    log : plant.ExperimentLog or None
        The log itself (not serialised; None after :meth:`load_json`).
    bounds : ndarray, shape (k, 2)
        Search ranges of ``x``.
    x_names : list of str, length k
        Names of the components of ``x``.
    parameters : str
        The parameterisation of ``x``: ``"base"`` (f1..f9), ``"consistent"``
        (eq.-3 structure, 7 parameters) or ``"payload"``.
    settings : dict
        At least ``substeps`` (RK4 steps per sample while identifying) and
        ``lowpass_hz`` (float or None), plus the GA and refinement settings.
    f_std, f_rse : ndarray, shape (9,), optional
        Standard errors of f and relative standard errors ``f_std / |f|``
        (after a refinement; :mod:`identification.uncertainty`).
    f_correlation, x_correlation : ndarray, optional
        Correlation matrices of f (9, 9) and of x (k, k).
    x_std : ndarray, shape (k,), optional
        Standard errors of x (e.g. the payload's ``[m, xp, yp, Jc]``).
    poorly_excited : list of str, optional
        Parameters of f whose relative standard error exceeds 10 %.
    uncertainty : dict, optional
        How the standard errors were computed (lag, HAC factor, scale).
    payload : dict, optional
        Identified payload (payload mode only): ``mass_kg``, ``com_m``,
        ``izz_kgm2``, ``vector``, ...
    """

    def __dir__(self):
        return list(self.keys())

    # -- derived --------------------------------------------------------------
    def _settings(self):
        s = self.get("settings") or {}
        return s if isinstance(s, dict) else {}

    @property
    def substeps(self):
        """RK4 steps per sample of the identification (``settings["substeps"]``), int."""
        from .objective import IDENTIFICATION_SUBSTEPS

        s = self._settings().get("substeps")
        return int(IDENTIFICATION_SUBSTEPS if s is None else s)

    @property
    def lowpass_hz(self):
        """Low-pass cutoff of the identification (Hz) or None (``settings["lowpass_hz"]``)."""
        v = self._settings().get("lowpass_hz")
        return None if v is None else float(v)

    def setting_text(self, substeps=None, lowpass_hz=None):
        """The integration setting of ``fun`` (default) or of ``substeps``, as text.

        Parameters
        ----------
        substeps : int, optional
            RK4 steps per sample (default: the identification's).
        lowpass_hz : float, optional
            Cutoff (Hz) when ``substeps`` is given; by default the
            identification's filter.

        Returns
        -------
        str
            See :func:`describe_setting`.
        """
        if substeps is None:
            substeps, lowpass_hz = self.substeps, self.lowpass_hz
        return describe_setting(substeps, lowpass_hz, identification_substeps=self.substeps)

    def _x_names(self):
        names = self.get("x_names")
        if names is not None:
            return [str(n) for n in names]
        k = np.size(self.get("x", self.get("f")))
        return list(F_NAMES) if k == 9 else [f"x{i + 1}" for i in range(k)]

    def _parameters(self):
        p = self.get("parameters")
        if p is not None:
            return str(p)
        if self.get("payload") or self._settings().get("payload"):
            return "payload"
        return "base"

    def __repr__(self):
        f = np.asarray(self.get("f"), dtype=float) if self.get("f") is not None else None
        lines = [
            f"IdentificationResult(method={self.get('method')!r}, "
            f"log={self.get('log_name')!r}, parameters={self._parameters()!r})",
            f"  f       = {_summary(f)}  (f1..f9)",
        ]
        x = self.get("x")
        if x is not None and (f is None or np.shape(x) != f.shape
                              or not np.array_equal(np.asarray(x, dtype=float), f)):
            lines.append(f"  x       = {_summary(x)}  ({', '.join(self._x_names())})")
        lines += [
            f"  fun     = {_fmt_y(self.get('fun'))} pulses^2  (output error eq. 4, "
            f"{self.setting_text()})",
            f"  nfev    = {self.get('nfev')}   nit = {self.get('nit')}   "
            f"wall_time_s = {float(self.get('wall_time_s') or 0.0):.3g}",
            f"  success = {self.get('success')}   interrupted = {self.get('interrupted')}",
            f"  message = {self.get('message')!r}",
        ]
        if self.get("payload"):
            p = self["payload"]
            lines.append(f"  payload = mass_kg {p.get('mass_kg')!r}, com_m {p.get('com_m')!r}")
        pop = self.get("population")
        if pop is not None:
            lines.append(f"  population = {_summary(pop)}, population_energies = "
                         f"{_summary(self.get('population_energies'))}")
        return "\n".join(lines)

    __str__ = __repr__

    # -- serialisation --------------------------------------------------
    def to_dict(self):
        """JSON-ready dict; the keys of the CLI's result file.

        Returns
        -------
        dict
            ``f`` (list of 9 floats, f1..f9), ``f_named``, ``f_units``,
            ``objective_pulses2`` (= ``fun``), ``x``, ``x_names``,
            ``parameters``, ``fun``, ``nfev``, ``nit``, ``evaluations``
            (= ``nfev``, for older readers), ``success``, ``message``,
            ``method``, ``seed``, ``log`` (the log's name), ``interrupted``,
            ``bounds``, ``settings`` (with ``substeps`` and ``lowpass_hz``),
            ``setting`` (``fun``'s integration setting as text),
            ``history``, ``refinement``, ``wall_time_s``,
            ``compile_time_s``, the standard errors when computed
            (``f_std``, ``f_rse``, ``f_correlation``, ``x_std``,
            ``x_correlation``, ``poorly_excited``, ``uncertainty``;
            :mod:`identification.uncertainty`), in payload mode ``payload`` and its
            flattened ``payload_<key>`` entries (``payload_mass_kg``, ...);
            always the model keys of :data:`identification.models.MODEL_KEYS`
            (``model``, joint stiffness/damping/reflected inertia, friction,
            ``friction_identified``, ``model_choice``).
            Non-finite floats become ``null``.  ``log``, ``population`` and
            ``population_energies`` are not written.
        """
        f = np.asarray(self.f, dtype=float)
        fun = float(self.fun)
        nfev = self.get("nfev")
        nit = self.get("nit")
        x = self.get("x")
        d = {
            "f": [float(v) for v in f],
            "f_named": {n: float(v) for n, v in zip(F_NAMES, f)},
            "f_units": dict(zip(F_NAMES, F_UNITS)),
            "objective_pulses2": fun,
            "x": None if x is None else np.asarray(x, dtype=float).ravel(),
            "x_names": self._x_names(),
            "parameters": self._parameters(),
            "fun": fun,
            "nfev": None if nfev is None else int(nfev),
            "nit": None if nit is None else int(nit),
            "evaluations": None if nfev is None else int(nfev),
            "success": bool(self.get("success", not self.get("interrupted", False))),
            "message": self.get("message", ""),
            "method": self.get("method"),
            "seed": self.get("seed"),
            "log": self.get("log_name"),
            "interrupted": bool(self.get("interrupted", False)),
            "bounds": self.get("bounds"),
            "settings": self._settings(),
            "setting": self.setting_text(),
            "history": self.get("history", {}),
            "refinement": self.get("refinement"),
            "wall_time_s": float(self.get("wall_time_s") or 0.0),
            "compile_time_s": self.get("compile_time_s"),
        }
        from .uncertainty import RESULT_KEYS  # standard errors (issue 15)
        d.update({k: self[k] for k in RESULT_KEYS if self.get(k) is not None})
        payload = self.get("payload")
        if payload:
            d["payload"] = payload
            for k, v in payload.items():
                d[f"payload_{k}"] = v
        from .models import MODEL_KEYS  # rigid/flexible model and friction (always written)

        d.update({key: self.get(key) for key in MODEL_KEYS})
        if d["model"] is None:
            d["model"] = "rigid"
        return _jsonable(d)

    def save_json(self, path, *, create_dirs=True):
        """Write :meth:`to_dict` as JSON to ``path`` atomically.

        Parameters
        ----------
        path : str or os.PathLike
            Output file; written with the policy of :mod:`plant.fileio`
            (a symlink is written through, a special file is refused, an
            existing file keeps its permission bits; no partial file on
            error).
        create_dirs : bool
            Create a missing parent directory (default, as before; listed
            in the returned ``created_dirs``); False refuses it.

        Returns
        -------
        plant.fileio.OutputTarget
            The file written (``target``, a symlink's target) and the
            directories created (``created_dirs``).

        Raises
        ------
        plant.fileio.OutputFileError
            If the target is refused.
        OSError
            If writing fails.
        """
        return write_json_atomic(path, self.to_dict(), create_dirs=create_dirs)

    @classmethod
    def load_json(cls, path):
        """Read a result file written by :meth:`save_json` (or the CLI's ``--output``).

        Parameters
        ----------
        path : str or os.PathLike
            The JSON file.

        Returns
        -------
        IdentificationResult
            With ``f`` (9,), ``x`` (k,), ``bounds`` (k, 2), the ``history``
            and numeric ``refinement`` entries as ndarrays; ``log``,
            ``population`` and ``population_energies`` are None (not
            serialised); ``null`` numbers come back as NaN.

        Raises
        ------
        ResultFileError
            (a ValueError) with one line naming the file, if it is missing,
            unreadable, not JSON, or lacks a required key (``f``, ``fun`` or
            ``objective_pulses2``, ``nfev`` or ``evaluations``, ``method``)
            or has a malformed one.
        """
        p = Path(path)
        try:
            d = read_json_object(p, "result file")
        except ValueError as e:
            raise ResultFileError(str(e)) from None
        for alternatives in _REQUIRED:
            if not any(k in d for k in alternatives):
                raise ResultFileError(f"{p}: missing key {alternatives[0]!r} "
                                      "(not an identification result file?)")

        def num_array(key, value, shape=None):
            try:
                a = np.array([np.nan if v is None else v for v in value]
                             if isinstance(value, list) and np.ndim(value) == 1 else value,
                             dtype=float)
            except (TypeError, ValueError):
                raise ResultFileError(f"{p}: key {key!r} must hold numbers") from None
            if shape is not None and (a.ndim != len(shape) or any(
                    s is not None and a.shape[i] != s for i, s in enumerate(shape))):
                raise ResultFileError(f"{p}: key {key!r} has shape {a.shape}, expected "
                                      f"{tuple('k' if s is None else s for s in shape)}")
            return a

        def number(key, value, kind=float):
            if value is None:
                return np.nan if kind is float else None
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise ResultFileError(f"{p}: key {key!r} must be a number, got {value!r}")
            return kind(value)

        f = num_array("f", d["f"], (9,))
        fun = number("fun", d.get("fun", d.get("objective_pulses2")))
        nfev = number("nfev", d.get("nfev", d.get("evaluations")), int)
        x = num_array("x", d["x"], (None,)) if d.get("x") is not None else f.copy()
        bounds = d.get("bounds")
        if bounds is not None:
            bounds = num_array("bounds", bounds, (x.size, 2))
        hist = d.get("history") or {}
        if not isinstance(hist, dict):
            raise ResultFileError(f"{p}: key 'history' must be an object")
        history = {}
        for k, v in hist.items():
            a = num_array(f"history.{k}", v)
            if k in ("generation", "nfev") and np.all(np.isfinite(a)):
                a = a.astype(np.int64)
            history[k] = a
        refinement = d.get("refinement")
        if refinement is not None:
            if not isinstance(refinement, dict):
                raise ResultFileError(f"{p}: key 'refinement' must be an object or null")
            refinement = {k: (num_array(f"refinement.{k}", v) if isinstance(v, list) else v)
                          for k, v in refinement.items()}
        settings = d.get("settings") or {}
        if not isinstance(settings, dict):
            raise ResultFileError(f"{p}: key 'settings' must be an object")
        nit = d.get("nit")
        res = cls(
            x=x, f=f, fun=fun, nfev=nfev, nit=None if nit is None else number("nit", nit, int),
            success=bool(d.get("success", not d.get("interrupted", False))),
            message=str(d.get("message", "")),
            population=None, population_energies=None,
            method=str(d["method"]), seed=d.get("seed"), history=history,
            refinement=refinement,
            wall_time_s=number("wall_time_s", d.get("wall_time_s")),
            compile_time_s=number("compile_time_s", d.get("compile_time_s")),
            interrupted=bool(d.get("interrupted", False)),
            log_name=d.get("log"), log=None, bounds=bounds,
            x_names=[str(n) for n in d["x_names"]] if d.get("x_names") else None,
            parameters=d.get("parameters"), settings=settings,
        )
        if res["x_names"] is None:
            res["x_names"] = res._x_names()
        if res["parameters"] is None:
            res["parameters"] = res._parameters()
        if d.get("payload") is not None:
            res["payload"] = d["payload"]
        from .uncertainty import RESULT_KEYS  # standard errors (issue 15)
        for k in RESULT_KEYS:
            if d.get(k) is not None:
                res[k] = d[k] if k in ("poorly_excited", "uncertainty") else num_array(k, d[k])
        from .models import MODEL_KEYS

        for key in MODEL_KEYS:
            if key in d:
                res[key] = d[key]
        return res

    # -- plots --------------------------------------------------------------
    def plot(self, ax=None, *, fig=None):
        """Convergence plot: best and mean output error per GA generation.

        The output errors are at the identification's setting (the title
        says which) and ``fun`` is marked after a refinement.

        Parameters
        ----------
        ax : matplotlib.axes.Axes, optional
            Axes to draw into.
        fig : matplotlib.figure.Figure, optional
            Figure to draw into (one new subplot) when ``ax`` is not given.

        Returns
        -------
        matplotlib.axes.Axes or matplotlib.figure.Figure
            ``ax`` if given, else the figure drawn into (``fig`` or a new
            Figure, never shown: save it with ``savefig``).
        """
        target_ax, out = _one_axes(ax, fig, figsize=(7, 4.2))
        h = self.get("history") or {}
        evals = np.asarray(h.get("nfev", []), dtype=float)
        target_ax.semilogy(evals, np.asarray(h.get("best", []), dtype=float), "-",
                           label="GA best")
        if h.get("median") is not None and len(h.get("median")) == len(evals):
            # the population's median: its mean is dominated by a few penalised candidates
            target_ax.semilogy(evals, np.asarray(h["median"], dtype=float), "-", alpha=0.6,
                               label="GA population median")
        else:
            target_ax.semilogy(evals, np.asarray(h.get("mean", []), dtype=float), "-", alpha=0.6,
                               label="GA population mean")
        if self.get("refinement"):
            target_ax.semilogy([self.nfev], [self.fun], "o", label="after refinement")
        target_ax.set_xlabel("simulations")
        target_ax.set_ylabel("output error Y (pulses$^2$, eq. 4)")
        target_ax.set_title(f"{self.get('log_name') or ''}: convergence of {self.get('method')}, "
                            f"final Y = {_fmt_y(self.fun)} pulses$^2$\n"
                            f"model simulated with {self.setting_text()}", fontsize="medium")
        target_ax.grid(True, which="both", alpha=0.3)
        target_ax.legend()
        return out

    def tracking_output_error(self, log=None, *, substeps=None, lowpass_hz="identification"):
        """Simulated tracking errors of ``f`` and their output error (eq. 4).

        Parameters
        ----------
        log : plant.ExperimentLog, optional
            Default: the identified log (``self.log``).
        substeps : int, optional
            RK4 steps per sample; default the identification's
            (``settings["substeps"]``), so that the output error equals
            ``fun`` on the identified log.
        lowpass_hz : float, None or "identification"
            Zero-phase low-pass (Hz) applied to both error sequences before
            the sum of squares; default the identification's filter when
            ``substeps`` is the identification's, otherwise none.

        Returns
        -------
        e_model : ndarray, shape (n_samples, 2)
            Simulated tracking errors (int64 pulses).
        y : float
            Output error (pulses^2).
        setting : str
            The integration setting (see :func:`describe_setting`).

        Raises
        ------
        ValueError
            If no log is attached and none is given.
        """
        import plant

        log = log if log is not None else self.get("log")
        if log is None:
            raise ValueError("no log attached to this result (e.g. after load_json): pass one")
        ident = substeps is None or int(substeps) == self.substeps
        n = self.substeps if substeps is None else int(substeps)
        if isinstance(lowpass_hz, str):
            if lowpass_hz != "identification":
                raise ValueError(f"lowpass_hz must be a frequency, None or 'identification', "
                                 f"got {lowpass_hz!r}")
            lowpass_hz = self.lowpass_hz if ident else None
        x0 = None
        if log.rig.q0_rad is None:  # a window without a start state: the refined one
            x0 = (self.get("refinement") or {}).get("initial_state")
            if x0 is None:
                from .window import estimate_initial_state

                x0 = estimate_initial_state(log)[0]
        e = plant.simulate_experiment(log, np.asarray(self.f, dtype=float), substeps=n,
                                      initial_state=x0)
        if lowpass_hz is None:
            d = log.e_pulses - e
            y = float(np.sum(d * d))
        else:
            from .filtering import apply_lowpass, lowpass_sos

            sos = lowpass_sos(lowpass_hz, log.rig.sample_time_s)
            d = apply_lowpass(e, sos) - apply_lowpass(log.e_pulses, sos)
            y = float(np.einsum("nj,nj->", d, d))
        return e, y, describe_setting(n, lowpass_hz, identification_substeps=self.substeps)

    def plot_tracking_errors(self, log=None, *, substeps=None, lowpass_hz="identification",
                             ax=None, fig=None):
        """Logged vs simulated tracking errors of the identified model.

        By default the model is simulated with the identification's setting
        (``settings["substeps"]`` RK4 steps per sample, its low-pass filter
        for the number), so the output error in the title equals ``fun`` on
        the identified log; the title names the setting.  Pass
        ``substeps=plant.DEFAULT_SUBSTEPS`` for the exact reproduction.

        Parameters
        ----------
        log : plant.ExperimentLog, optional
            The log to compare with (default: the identified one).  A
            different log (e.g. a validation run) cross-validates ``f``.
        substeps : int, optional
            RK4 steps per sample (default: the identification's).
        lowpass_hz : float, None or "identification"
            See :meth:`tracking_output_error` (the curves are never
            filtered; only the number in the title is).
        ax : matplotlib.axes.Axes or pair of Axes, optional
            Two Axes (joint 2, joint 3), or one Axes for both joints.  The
            title goes on the first Axes.
        fig : matplotlib.figure.Figure, optional
            Figure to draw into (two new subplots) when ``ax`` is not given.

        Returns
        -------
        Axes, pair of Axes or matplotlib.figure.Figure
            ``ax`` if given, else the figure (``fig`` or a new Figure,
            never shown).

        Raises
        ------
        ValueError
            If no log is attached and none is given, or ``ax`` is malformed.
        """
        import plant

        log = log if log is not None else self.get("log")
        e, y, setting = self.tracking_output_error(log, substeps=substeps,
                                                   lowpass_hz=lowpass_hz)
        return plant.plot_tracking_errors(
            log.t, log.e_pulses, e, labels=("logged", "identified model"),
            title=(f"{log.name}: logged and identified-model tracking errors\n"
                   f"output error Y (eq. 4) = {_fmt_y(y)} pulses$^2$, model simulated with "
                   f"{setting}"),
            fig=fig, ax=ax,
        )


def _one_axes(ax, fig, figsize):
    """(axes to draw into, object to return) for a single-panel plot."""
    if ax is not None:
        if fig is not None and ax.figure is not fig:
            raise ValueError("ax belongs to another figure than fig")
        return ax, ax
    if fig is None:
        from matplotlib.figure import Figure

        fig = Figure(figsize=figsize, layout="constrained")
    return fig.add_subplot(), fig
