"""The result object of an identification (scipy ``OptimizeResult`` style).

:class:`IdentificationResult` holds what :func:`identification.identify`
found; its JSON file (:meth:`~IdentificationResult.save_json`,
:meth:`~IdentificationResult.load_json`) is defined in
:mod:`identification.result_schema`, its plots in
:mod:`identification.result_plots` (the methods call them).

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

import numpy as np
from scipy.optimize import OptimizeResult

from plant.logs.rig import F_NAMES

from . import result_plots
from .result_schema import (  # noqa: F401 (ResultFileError, write_json_atomic re-exported)
    ResultFileError,
    describe_setting,
    format_output_error,
    read_result_file,
    result_dict,
    write_json_atomic,
)

__all__ = ["IdentificationResult", "ResultFileError", "write_json_atomic", "describe_setting"]

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
    def settings_dict(self):
        """``settings`` as a dict (empty when missing or malformed)."""
        s = self.get("settings") or {}
        return s if isinstance(s, dict) else {}

    @property
    def substeps(self):
        """RK4 steps per sample of the identification (``settings["substeps"]``), int."""
        from .objective import IDENTIFICATION_SUBSTEPS

        s = self.settings_dict().get("substeps")
        return int(IDENTIFICATION_SUBSTEPS if s is None else s)

    @property
    def lowpass_hz(self):
        """Low-pass cutoff of the identification (Hz) or None (``settings["lowpass_hz"]``)."""
        v = self.settings_dict().get("lowpass_hz")
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

    def names_of_x(self):
        """Names of the components of ``x`` (``x_names``, or f1..f9 / x1..xk)."""
        names = self.get("x_names")
        if names is not None:
            return [str(n) for n in names]
        k = np.size(self.get("x", self.get("f")))
        return list(F_NAMES) if k == 9 else [f"x{i + 1}" for i in range(k)]

    def parameterisation_name(self):
        """``parameters``, or what the result implies: ``"payload"`` or ``"base"``."""
        p = self.get("parameters")
        if p is not None:
            return str(p)
        if self.get("payload") or self.settings_dict().get("payload"):
            return "payload"
        return "base"

    def __repr__(self):
        f = np.asarray(self.get("f"), dtype=float) if self.get("f") is not None else None
        lines = [
            f"IdentificationResult(method={self.get('method')!r}, "
            f"log={self.get('log_name')!r}, parameters={self.parameterisation_name()!r})",
            f"  f       = {_summary(f)}  (f1..f9)",
        ]
        x = self.get("x")
        if x is not None and (f is None or np.shape(x) != f.shape
                              or not np.array_equal(np.asarray(x, dtype=float), f)):
            lines.append(f"  x       = {_summary(x)}  ({', '.join(self.names_of_x())})")
        lines += [
            f"  fun     = {format_output_error(self.get('fun'))} pulses^2  (output error eq. 4, "
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
        return result_dict(self)

    def save_json(self, path, *, create_dirs=True):
        """Write :meth:`to_dict` as JSON to ``path`` atomically.

        Parameters
        ----------
        path : str or os.PathLike
            Output file; written with the policy of :mod:`plant.logs.fileio`
            (a symlink is written through, a special file is refused, an
            existing file keeps its permission bits; no partial file on
            error).
        create_dirs : bool
            Create a missing parent directory (default, as before; listed
            in the returned ``created_dirs``); False refuses it.

        Returns
        -------
        plant.logs.fileio.OutputTarget
            The file written (``target``, a symlink's target) and the
            directories created (``created_dirs``).

        Raises
        ------
        plant.logs.fileio.OutputFileError
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
        res = cls(**read_result_file(path))
        if res["x_names"] is None:
            res["x_names"] = res.names_of_x()
        if res["parameters"] is None:
            res["parameters"] = res.parameterisation_name()
        return res

    # -- plots (identification.result_plots) -------------------------------
    def plot(self, ax=None, *, fig=None):
        """Convergence plot: best and median output error per GA generation.

        See :func:`identification.result_plots.plot_convergence`.

        Parameters
        ----------
        ax : matplotlib.axes.Axes, optional
        fig : matplotlib.figure.Figure, optional

        Returns
        -------
        matplotlib.axes.Axes or matplotlib.figure.Figure
        """
        return result_plots.plot_convergence(self, ax, fig=fig)

    def tracking_output_error(self, log=None, *, substeps=None, lowpass_hz="identification"):
        """Simulated tracking errors of ``f`` and their output error (eq. 4).

        See :func:`identification.result_plots.tracking_output_error`.

        Parameters
        ----------
        log : plant.ExperimentLog, optional
        substeps : int, optional
        lowpass_hz : float, None or "identification"

        Returns
        -------
        tuple
            ``(e_model (n_samples, 2), y, setting)``.
        """
        return result_plots.tracking_output_error(self, log, substeps=substeps,
                                                  lowpass_hz=lowpass_hz)

    def plot_tracking_errors(self, log=None, *, substeps=None, lowpass_hz="identification",
                             ax=None, fig=None):
        """Logged vs simulated tracking errors of the identified model.

        See :func:`identification.result_plots.plot_tracking_errors`.

        Parameters
        ----------
        log : plant.ExperimentLog, optional
        substeps : int, optional
        lowpass_hz : float, None or "identification"
        ax : matplotlib.axes.Axes or pair of Axes, optional
        fig : matplotlib.figure.Figure, optional

        Returns
        -------
        Axes, pair of Axes or matplotlib.figure.Figure
        """
        return result_plots.plot_tracking_errors(self, log, substeps=substeps,
                                                 lowpass_hz=lowpass_hz, ax=ax, fig=fig)
