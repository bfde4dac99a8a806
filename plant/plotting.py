"""Plots of tracking errors (like the paper's figures 10-15)."""
from __future__ import annotations

import numpy as np

__all__ = ["plot_tracking_errors"]


def plot_tracking_errors(t, e_logged, e_model=None, *, labels=("logged", "model"), title=None,
                         fig=None):
    """Overlay logged and simulated tracking errors, one panel per joint.

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
        Figure title.
    fig : matplotlib.figure.Figure, optional
        Figure to draw into (default: a new one).

    Returns
    -------
    matplotlib.figure.Figure
        Never shown (no ``plt.show()``): save it or display it yourself.

    Raises
    ------
    ValueError
        If the array shapes disagree.
    """
    from matplotlib.figure import Figure

    t = np.asarray(t, dtype=float)
    e_logged = np.asarray(e_logged)
    if e_logged.shape != (t.size, 2):
        raise ValueError(f"e_logged must have shape ({t.size}, 2), got {e_logged.shape}")
    if e_model is not None:
        e_model = np.asarray(e_model)
        if e_model.shape != e_logged.shape:
            raise ValueError(f"e_model must have shape {e_logged.shape}, got {e_model.shape}")
    if fig is None:
        fig = Figure(figsize=(9, 5.5), layout="constrained")
    axes = fig.subplots(2, 1, sharex=True)
    for j, ax in enumerate(axes):
        ax.step(t, e_logged[:, j], where="post", lw=0.9, label=labels[0])
        if e_model is not None:
            ax.step(t, e_model[:, j], where="post", lw=0.9, alpha=0.8, label=labels[1])
        ax.set_ylabel(f"e{j + 2} (pulses)")
        ax.grid(True, alpha=0.3)
        ax.legend(loc="upper right", fontsize="small")
    axes[-1].set_xlabel("t (s)")
    if title:
        fig.suptitle(title)
    return fig
