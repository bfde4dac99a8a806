"""Zero-phase low-pass filtering of tracking errors (issue 7).

The paper low-pass filtered its logs before identifying, because the real
robot's joint flexibility and backlash produced 27-32 Hz oscillations that the
rigid nine-parameter model cannot describe.  Filtering only the logged side
would bias the fit; here the *same* zero-phase Butterworth filter
(``scipy.signal.butter`` + ``sosfiltfilt``) is applied to the logged and to the
simulated errors before the output error is formed, so the unmodelled mode is
removed from both sides alike.
"""
from __future__ import annotations

import numpy as np

__all__ = ["lowpass_sos", "apply_lowpass"]

#: Butterworth order used by :func:`lowpass_sos` (applied forward and backward,
#: so the magnitude response is squared: an effective order of 8).
FILTER_ORDER = 4


def lowpass_sos(cutoff_hz, sample_time_s, order=FILTER_ORDER):
    """Second-order sections of a digital Butterworth low-pass.

    Parameters
    ----------
    cutoff_hz : float
        -3 dB frequency of the single pass (Hz); must lie in (0, Nyquist).
    sample_time_s : float
        Sample time of the log (s).
    order : int
        Filter order (default 4).

    Returns
    -------
    ndarray, shape (n_sections, 6)

    Raises
    ------
    ValueError
        If the cutoff is not positive or not below the Nyquist frequency.
    """
    fs = 1.0 / float(sample_time_s)
    if not (0.0 < float(cutoff_hz) < 0.5 * fs):
        raise ValueError(
            f"low-pass cutoff must lie in (0, {0.5 * fs:g}) Hz (Nyquist), got {cutoff_hz}"
        )
    from scipy import signal  # imported on use: scipy.signal takes ~0.5 s to import

    return signal.butter(int(order), float(cutoff_hz), btype="low", fs=fs, output="sos")


def apply_lowpass(x, sos, axis=-2):
    """Zero-phase filtering of error sequences along the time axis.

    Parameters
    ----------
    x : array_like, shape (..., n_samples, 2)
        Tracking errors (pulses), time-first per sequence.
    sos : ndarray
        From :func:`lowpass_sos`.
    axis : int
        Time axis (default: second to last).

    Returns
    -------
    ndarray of float, same shape as ``x``.
    """
    x = np.asarray(x, dtype=float)
    padlen = min(3 * (2 * len(sos) + 1), x.shape[axis] - 1)
    from scipy import signal

    return signal.sosfiltfilt(sos, x, axis=axis, padlen=padlen)
