"""Windows of a long run: the state at a window's first sample, from the window itself.

A robot that has worked for hours has no t = 0: a window log of its
controller (sidecar ``window_s``) may come without a start state
(:attr:`plant.logs.rig.Rig.q0_rad` is None).  Its model then starts at the
window's first sample, from a state estimated from the window and refined
with the searched parameters as nuisance parameters
(``Parameterisation.initial_state``,
:func:`identification.identify`).

:func:`estimate_initial_state` gives the guess and the box of that state:

* the position from the encoder counts: the continuous tracking error
  ``d_k = ref_k - m_k`` (``m_k`` the centre of the count cell the log
  allows, :func:`plant.measured_counts`) fitted by a straight line over the
  first samples, taken at the first sample -- better than one cell centre
  (+-0.5 pulse) because the error is slow;
* the velocity from the reference and the error trend: ``qd = qd_ref -
  (dd/dt) / (pulses per rad)`` with the slope of the same fit (no
  differentiated encoder counts, which are mostly quantisation noise).
"""
from __future__ import annotations

import numpy as np

__all__ = ["estimate_initial_state", "TREND_SAMPLES"]

#: Samples of the line fitted to the tracking error at a window's start.
TREND_SAMPLES = 20


def estimate_initial_state(log, *, trend_samples=TREND_SAMPLES):
    """Guess and box of the rigid state (q2, q3, qd2, qd3) at a log's first sample.

    Parameters
    ----------
    log : plant.ExperimentLog
        The window (or any log).
    trend_samples : int
        Samples of the straight-line fit of the continuous tracking error
        (at most the log's length, at least 2).

    Returns
    -------
    guess : ndarray, shape (4,)
        q2, q3 (rad), qd2, qd3 (rad/s) at ``log.t[0]``.
    box : ndarray, shape (4, 2)
        (low, high) per component: +-2 pulses and +-(20 % of the reference
        rate + 0.05 rad/s).

    Raises
    ------
    ValueError
        If ``trend_samples < 2`` or the log has fewer than 2 samples.
    """
    import plant

    n = min(int(trend_samples), log.n_samples)
    if int(trend_samples) < 2 or n < 2:
        raise ValueError(f"need at least 2 samples for the error trend, got {n}")
    rig = log.rig
    scale = np.asarray(rig.pulses_per_rad, dtype=float)
    q_ref, qd_ref, _ = log.trajectory.evaluate(log.t[:n])
    d = q_ref * scale - plant.measured_counts(log)[:n]  # continuous error (pulses)
    tau = log.t[:n] - log.t[0]
    slope, intercept = np.polyfit(tau, d, 1)  # per joint, (2,) each
    q0 = (q_ref[0] * scale - intercept) / scale
    qd0 = qd_ref[0] - slope / scale
    guess = np.concatenate([q0, qd0])
    half = np.r_[2.0 / np.abs(scale), 0.2 * np.abs(qd_ref[0]) + 0.05]
    return guess, np.column_stack([guess - half, guess + half])
