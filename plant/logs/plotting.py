"""Plots of tracking errors (like the paper's figures 10-15)."""
from __future__ import annotations

import numpy as np

__all__ = ["plot_tracking_errors"]


def plot_tracking_errors(t, e_logged, e_model=None, *, labels=("logged", "model"), title=None,
                         fig=None, ax=None, residual=True):
    """Overlay logged and simulated tracking errors per joint, with their residual.

    Where the model reproduces the log the two curves coincide and the
    overlay alone shows nothing; the residual ``logged - model`` (pulses)
    is what the output error of paper eq. 4 sums, so it is drawn too: in a
    panel of its own under each joint's overlay when the function makes the
    figure, as a third curve when ``ax`` is given.  Pulse axes get integer
    ticks (the errors are whole pulses).

    Parameters
    ----------
    t : array_like, shape (n,)
        Sample times (s).
    e_logged : array_like, shape (n, 2)
        Logged tracking errors (pulses), joints 2 and 3.
    e_model : array_like, shape (n, 2), optional
        Simulated tracking errors (pulses) to overlay.
    labels : tuple of 2 str
        Legend labels of the two curves.
    title : str, optional
        Title: the figure's suptitle when drawing into a figure of its own
        (``fig`` or a new one), the first Axes' title when ``ax`` is given.
    fig : matplotlib.figure.Figure, optional
        Figure to draw into (new subplots; default: a new Figure).
    ax : matplotlib.axes.Axes or sequence of 2 Axes, optional
        Draw into these Axes instead: two Axes (joint 2, joint 3), or one
        Axes holding both joints (labels prefixed ``e2``/``e3``).
    residual : bool
        Draw the residual ``e_logged - e_model`` (with ``e_model``).

    Returns
    -------
    Axes, sequence of Axes or matplotlib.figure.Figure
        ``ax`` if given (the same object), else the figure drawn into.
        Never shown (no ``plt.show()``): save it or display it yourself.

    Raises
    ------
    ValueError
        If the array shapes disagree, ``ax`` is not one or two Axes, or
        both ``ax`` and ``fig`` are given and differ.
    """
    from matplotlib.ticker import MaxNLocator

    t = np.asarray(t, dtype=float)
    e_logged = np.asarray(e_logged)
    if e_logged.shape != (t.size, 2):
        raise ValueError(f"e_logged must have shape ({t.size}, 2), got {e_logged.shape}")
    if e_model is not None:
        e_model = np.asarray(e_model)
        if e_model.shape != e_logged.shape:
            raise ValueError(f"e_model must have shape {e_logged.shape}, got {e_model.shape}")
    show_res = bool(residual) and e_model is not None
    single = False
    res_axes = None
    if ax is not None:
        axes, single = _axes_pair(ax)
        if fig is not None and any(a.figure is not fig for a in axes):
            raise ValueError("ax belongs to another figure than fig")
        out = ax
    else:
        if fig is None:
            from matplotlib.figure import Figure

            fig = Figure(figsize=(9, 7.5 if show_res else 5.5), layout="constrained")
        if show_res:
            grid = fig.subplots(4, 1, sharex=True, gridspec_kw=dict(height_ratios=[3, 1.2, 3, 1.2]))
            axes, res_axes = [grid[0], grid[2]], [grid[1], grid[3]]
        else:
            axes = fig.subplots(2, 1, sharex=True)
        out = fig
    for j, a in enumerate(axes):
        pre = f"e{j + 2} " if single else ""
        a.step(t, e_logged[:, j], where="post", lw=0.9, label=pre + labels[0])
        if e_model is not None:
            a.step(t, e_model[:, j], where="post", lw=0.9, alpha=0.8, ls="--",
                   label=pre + labels[1])
        if show_res:
            r = e_logged[:, j] - e_model[:, j]
            target = res_axes[j] if res_axes is not None else a
            target.step(t, r, where="post", lw=0.8, color="tab:red",
                        label=pre + f"residual {labels[0]} - {labels[1]}")
            if res_axes is not None:
                target.set_ylabel(f"residual e{j + 2}\n(pulses)")
                target.grid(True, alpha=0.3)
                target.yaxis.set_major_locator(MaxNLocator(integer=True))
                target.axhline(0.0, color="0.5", lw=0.6)
        if not single:
            a.set_ylabel(f"e{j + 2} (pulses)")
        a.grid(True, alpha=0.3)
        a.yaxis.set_major_locator(MaxNLocator(integer=True))
        a.legend(loc="best", fontsize="small", framealpha=0.85)
    if single:
        axes[0].set_ylabel("tracking error (pulses)")
    (res_axes or axes)[-1].set_xlabel("t (s)")
    if title:
        if out is fig:
            fig.suptitle(title)
        else:
            axes[0].set_title(title, fontsize="medium")
    return out


def _axes_pair(ax):
    """(two Axes to draw joints 2 and 3 into, whether it is one Axes twice)."""
    from matplotlib.axes import Axes

    if isinstance(ax, Axes):
        return [ax, ax], True
    try:
        axes = list(np.ravel(np.asarray(ax, dtype=object)))
    except TypeError:
        axes = []
    if len(axes) != 2 or not all(isinstance(a, Axes) for a in axes):
        raise ValueError("ax must be one matplotlib Axes or a pair of Axes (joint 2, joint 3)")
    return axes, False
