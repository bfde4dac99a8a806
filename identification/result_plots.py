"""Plots of an identification result: convergence, logged vs simulated tracking errors.

The functions take an :class:`identification.IdentificationResult` first;
its methods ``plot``, ``tracking_output_error`` and ``plot_tracking_errors``
call them.
"""
from __future__ import annotations

import numpy as np

from .result_schema import describe_setting, format_output_error

__all__ = ["plot_convergence", "tracking_output_error", "plot_tracking_errors", "one_axes"]


def plot_convergence(res, ax=None, *, fig=None):
    """Convergence plot: best and mean output error per GA generation.

    The output errors are at the identification's setting (the title
    says which) and ``fun`` is marked after a refinement.

    Parameters
    ----------
    res : identification.IdentificationResult
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
    target_ax, out = one_axes(ax, fig, figsize=(7, 4.2))
    h = res.get("history") or {}
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
    if res.get("refinement"):
        target_ax.semilogy([res.nfev], [res.fun], "o", label="after refinement")
    target_ax.set_xlabel("simulations")
    target_ax.set_ylabel("output error Y (pulses$^2$, eq. 4)")
    target_ax.set_title(f"{res.get('log_name') or ''}: convergence of {res.get('method')}, "
                        f"final Y = {format_output_error(res.fun)} pulses$^2$\n"
                        f"model simulated with {res.setting_text()}", fontsize="medium")
    target_ax.grid(True, which="both", alpha=0.3)
    target_ax.legend()
    return out

def tracking_output_error(res, log=None, *, substeps=None, lowpass_hz="identification"):
    """Simulated tracking errors of ``f`` and their output error (eq. 4).

    Parameters
    ----------
    res : identification.IdentificationResult
    log : plant.ExperimentLog, optional
        Default: the identified log (``res.log``).
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

    log = log if log is not None else res.get("log")
    if log is None:
        raise ValueError("no log attached to this result (e.g. after load_json): pass one")
    ident = substeps is None or int(substeps) == res.substeps
    n = res.substeps if substeps is None else int(substeps)
    if isinstance(lowpass_hz, str):
        if lowpass_hz != "identification":
            raise ValueError(f"lowpass_hz must be a frequency, None or 'identification', "
                             f"got {lowpass_hz!r}")
        lowpass_hz = res.lowpass_hz if ident else None
    x0 = None
    if log.rig.q0_rad is None:  # a window without a start state: the refined one
        x0 = (res.get("refinement") or {}).get("initial_state")
        if x0 is None:
            from .window import estimate_initial_state

            x0 = estimate_initial_state(log)[0]
    e = plant.simulate_experiment(log, np.asarray(res.f, dtype=float), substeps=n,
                                  initial_state=x0)
    if lowpass_hz is None:
        d = log.e_pulses - e
        y = float(np.sum(d * d))
    else:
        from .filtering import apply_lowpass, lowpass_sos

        sos = lowpass_sos(lowpass_hz, log.rig.sample_time_s)
        d = apply_lowpass(e, sos) - apply_lowpass(log.e_pulses, sos)
        y = float(np.einsum("nj,nj->", d, d))
    return e, y, describe_setting(n, lowpass_hz, identification_substeps=res.substeps)

def plot_tracking_errors(res, log=None, *, substeps=None, lowpass_hz="identification",
                         ax=None, fig=None):
    """Logged vs simulated tracking errors of the identified model.

    By default the model is simulated with the identification's setting
    (``settings["substeps"]`` RK4 steps per sample, its low-pass filter
    for the number), so the output error in the title equals ``fun`` on
    the identified log; the title names the setting.  Pass
    ``substeps=plant.DEFAULT_SUBSTEPS`` for the exact reproduction.

    Parameters
    ----------
    res : identification.IdentificationResult
    log : plant.ExperimentLog, optional
        The log to compare with (default: the identified one).  A
        different log (e.g. a validation run) cross-validates ``f``.
    substeps : int, optional
        RK4 steps per sample (default: the identification's).
    lowpass_hz : float, None or "identification"
        See :func:`tracking_output_error` (the curves are never
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

    log = log if log is not None else res.get("log")
    e, y, setting = tracking_output_error(res, log, substeps=substeps,
                                               lowpass_hz=lowpass_hz)
    return plant.plot_tracking_errors(
        log.t, log.e_pulses, e, labels=("logged", "identified model"),
        title=(f"{log.name}: logged and identified-model tracking errors\n"
               f"output error Y (eq. 4) = {format_output_error(y)} pulses$^2$, model simulated with "
               f"{setting}"),
        fig=fig, ax=ax,
    )


def one_axes(ax, fig, figsize):
    """(axes to draw into, object to return) for a single-panel plot.

    Parameters
    ----------
    ax : matplotlib.axes.Axes or None
    fig : matplotlib.figure.Figure or None
    figsize : tuple of float
        Size of a new figure (inches).
    """
    if ax is not None:
        if fig is not None and ax.figure is not fig:
            raise ValueError("ax belongs to another figure than fig")
        return ax, ax
    if fig is None:
        from matplotlib.figure import Figure

        fig = Figure(figsize=figsize, layout="constrained")
    return fig.add_subplot(), fig
