"""Error-spectrum diagnostic: where is the unmodelled mode, and where to cut (issue 7).

A log of a robot with compliant gearboxes (or backlash) carries a lightly
damped closed-loop mode near 30 Hz in its tracking errors, which the rigid
nine-parameter model cannot describe (the paper saw 27-32 Hz on its rig).
:func:`error_spectrum` estimates the power spectral density of the logged
errors (Welch), looks for that mode and proposes the cut-off of the
zero-phase low-pass (:mod:`identification.filtering`) that the identification
should apply to the logged and the simulated errors alike
(``identify(..., lowpass_hz=...)``).  :func:`suggest_lowpass` returns the
cut-off alone (``None`` when the log shows no mode: then do not filter).

Detection rule
--------------
On the base-10 logarithm of the PSD of each joint's error, a peak counts as
the unmodelled mode if

* its frequency lies in ``[min_mode_hz, 0.4 fs]`` (default ``min_mode_hz`` =
  25 Hz).  Below that the rigid P loops of the rig have their own closed-loop
  resonances (15-22 Hz on the development logs, whose tracking errors are
  rigid: ``puma560_paper_rigid`` and ``puma560_validation_rigid``); those are
  described by the model and carry information about f;
* it stands out of its surroundings by at least ``min_prominence_dec`` =
  0.25 decades (``scipy.signal.find_peaks`` prominence, a factor 1.8 in
  power);
* it lies at least ``min_height_dec`` = 1 decade above the noise floor (the
  median log-PSD above 0.25 fs, where the quantisation noise of the integer
  errors is white).

The most prominent such peak of each joint is reported (``mode_hz``, NaN for
a joint without one).  Measured margins (default segment of 1024 samples):
the drill/flex log's 30.7 Hz mode has prominences 0.54 / 0.65 decades and
heights 1.8 / 2.0 decades (e2 / e3); on the two rigid logs no peak above
25 Hz is higher than 0.55 decades above the floor.

Cut-off rule
------------
Only a log that shows the unmodelled mode is filtered (``cutoff_hz`` is None
otherwise: identify a rigid log unfiltered).  Then

``cutoff_hz = CUTOFF_FRACTION * resonance``, ``CUTOFF_FRACTION = 0.5``,

``resonance`` being the lowest closed-loop resonance of the errors: the
lowest peak of the log-PSD (prominence >= ``min_prominence_dec``, at least
``min_height_dec`` above the floor) between ``min_resonance_hz`` and the mode
(default ``min_resonance_hz``: the larger of 2 Hz and four times the highest
frequency of the reference trajectory), over both joints; the mode itself if
there is no such peak.

Why not half the mode frequency?  With a compliant gearbox under motor-side
P control, the flexible mode is not the only change: *all* closed-loop modes
move (``puma560_paper_drill_flex``: 9.6, 16, 31 and 33 Hz at q = 0, against
15-22 Hz for the rigid robot), so the rigid model is wrong from the lowest
loop resonance up, not only near 30 Hz.  Measured with the default method
(seed 0) on ``puma560_paper_drill_flex`` (spectrum: resonance 8.4 Hz, mode
30.7 Hz), relative error of f7 / f9 against the rigid-equivalent truth:
unfiltered +7.4 / -2.3 %, 25 Hz +7.4 / -2.3 %, 15 Hz (half the mode) +6.2 /
-2.0 %, 10 Hz +4.9 / -1.7 %, 7 Hz +2.7 / -1.1 %, 5 Hz +1.6 / -0.8 %,
4.2 Hz (this rule) +1.1 / -0.65 %, 3 Hz +0.7 / -0.5 %.  Below the loop resonances the tracking error is essentially
the inverse-dynamics torque divided by the loop gain, which is what the
identification needs, so cutting at half the lowest resonance (4.2 Hz there;
the filter's -3 dB point, about -48 dB of the two-pass filter at the
resonance) keeps the information and removes what the rigid model cannot
describe.  f2 and f4 (the coupling inertia) stay about 5 and 6.5 % low
whatever the cut-off: that bias is in the data, not in the filter (the true
f fits the filtered log worse than the identified one).  For windows shorter
than about ``1 / cutoff_hz`` the cut-off removes most of what the window
holds: do not filter them (measured on 200 ms windows, see the tutorial).
Figures:
``benchmarks/bench_payload.py`` and ``docs/tutorial_real_rigs.rst``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import signal

import plant

__all__ = [
    "ErrorSpectrum",
    "error_spectrum",
    "suggest_lowpass",
    "MIN_MODE_HZ",
    "MIN_PROMINENCE_DEC",
    "MIN_HEIGHT_DEC",
    "CUTOFF_FRACTION",
    "MIN_RESONANCE_HZ",
]

#: Lowest frequency (Hz) searched for the unmodelled mode (above the rigid
#: P loops' own resonances, 15-22 Hz on the development rig).
MIN_MODE_HZ = 25.0

#: Smallest prominence of a peak in the log10-PSD (decades).
MIN_PROMINENCE_DEC = 0.25

#: Smallest height of a peak above the high-frequency noise floor (decades).
MIN_HEIGHT_DEC = 1.0

#: The suggested cut-off is this fraction of the lowest closed-loop resonance.
CUTOFF_FRACTION = 0.5

#: Lower limit (Hz) of the resonance search, unless the trajectory asks for more.
MIN_RESONANCE_HZ = 2.0

#: Target frequency resolution of the default Welch segment (Hz).
_TARGET_RESOLUTION_HZ = 1.5

#: Fewest Welch segments (50 % overlap) the default segment length allows.
_MIN_SEGMENTS = 4


@dataclass(frozen=True)
class ErrorSpectrum:
    """Welch spectrum of a log's tracking errors, with the detected mode and cut-off.

    Attributes
    ----------
    f_hz : ndarray, shape (n_freq,)
        Frequencies (Hz), 0 .. fs/2.
    psd : ndarray, shape (n_freq, 2)
        One-sided power spectral density of e2 and e3 (pulses^2 / Hz).
    mode_hz : ndarray, shape (2,)
        Frequency of the unmodelled (flexible) mode per joint (Hz); NaN where
        none was found.
    mode_prominence_dec : ndarray, shape (2,)
        Prominence of that peak in the log10-PSD (decades); NaN where none.
    resonance_hz : ndarray, shape (2,)
        Lowest closed-loop resonance below the mode per joint (Hz); NaN where
        there is no mode or no such peak.
    floor_dec : ndarray, shape (2,)
        log10 of the high-frequency noise floor (median above 0.25 fs).
    cutoff_hz : float or None
        Suggested low-pass cut-off (Hz), see the module docstring; None if no
        mode was found.
    search_band_hz : tuple of 2 float
        Band searched for the mode (Hz).
    min_resonance_hz : float
        Lower end of the resonance search (Hz).
    nperseg : int
        Welch segment length (samples).
    n_segments : int
        Number of averaged Welch segments (few segments: a noisy estimate).
    sample_time_s : float
        Sample time of the log (s).
    log_name : str
        Name of the analysed log.
    """

    f_hz: np.ndarray
    psd: np.ndarray
    mode_hz: np.ndarray
    mode_prominence_dec: np.ndarray
    resonance_hz: np.ndarray
    floor_dec: np.ndarray
    cutoff_hz: float | None
    search_band_hz: tuple
    min_resonance_hz: float
    nperseg: int
    n_segments: int
    sample_time_s: float
    log_name: str = ""

    @property
    def mode_found(self) -> bool:
        """True if an unmodelled mode was found in at least one joint."""
        return bool(np.any(np.isfinite(self.mode_hz)))

    @property
    def mode_frequency_hz(self) -> float | None:
        """Lowest detected mode frequency over the joints (Hz), or None."""
        found = self.mode_hz[np.isfinite(self.mode_hz)]
        return float(found.min()) if found.size else None

    def summary(self) -> str:
        """One line: the mode and lowest resonance per joint, and the suggested cut-off."""
        def fmt(values):
            return ", ".join(f"e{j + 2} {v:.1f} Hz" if np.isfinite(v) else f"e{j + 2} none"
                             for j, v in enumerate(values))

        cut = "no filtering" if self.cutoff_hz is None else f"low-pass {self.cutoff_hz:.1f} Hz"
        name = f"{self.log_name}: " if self.log_name else ""
        res = f"; lowest resonance {fmt(self.resonance_hz)}" if self.mode_found else ""
        return f"{name}mode {fmt(self.mode_hz)}{res}; suggested: {cut}"

    def plot(self, fig=None, *, max_hz=None):
        """Plot the PSD of both joints, marking the mode, the resonance and the cut-off.

        Parameters
        ----------
        fig : matplotlib.figure.Figure, optional
            Figure to draw into (default: a new one).
        max_hz : float, optional
            Upper end of the frequency axis (default: twice the mode frequency,
            or 80 Hz without a mode, at most fs/2).

        Returns
        -------
        matplotlib.figure.Figure
            Never shown (no ``plt.show()``): save it or display it yourself.
        """
        from matplotlib.figure import Figure

        if fig is None:
            fig = Figure(figsize=(8, 5), layout="constrained")
        ax = fig.subplots()
        if max_hz is None:
            mode = self.mode_frequency_hz
            max_hz = 2.0 * mode if mode else 80.0
        max_hz = min(float(max_hz), float(self.f_hz[-1]))
        sel = (self.f_hz > 0) & (self.f_hz <= max_hz)
        ax.axvspan(self.search_band_hz[0], min(self.search_band_hz[1], max_hz),
                   color="0.92", zorder=0, label="mode search band")
        for j in range(2):
            line, = ax.semilogy(self.f_hz[sel], self.psd[sel, j], lw=1.0, label=f"e{j + 2}")
            c = line.get_color()
            for freq, marker, what in ((self.mode_hz[j], "v", "mode"),
                                       (self.resonance_hz[j], "o", "resonance")):
                if np.isfinite(freq):
                    k = int(np.argmin(np.abs(self.f_hz - freq)))
                    ax.plot(self.f_hz[k], self.psd[k, j], marker, color=c, ms=8, mfc="none",
                            label=f"{what} e{j + 2}: {freq:.1f} Hz")
            ax.axhline(10.0 ** self.floor_dec[j], color=c, ls=":", lw=0.8)
        if self.cutoff_hz is not None:
            ax.axvline(self.cutoff_hz, color="k", ls="--", lw=1.0,
                       label=f"suggested cut-off {self.cutoff_hz:.1f} Hz")
        ax.set_xlabel("frequency (Hz)")
        ax.set_ylabel("PSD of the logged error (pulses$^2$/Hz)")
        ax.set_xlim(0, max_hz)
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(loc="upper right", fontsize="small")
        title = "Tracking-error spectrum (Welch)"
        ax.set_title(f"{title}: {self.log_name}" if self.log_name else title)
        return fig


def _default_nperseg(n, fs):
    """Power of two near 1.5 Hz resolution, leaving at least 4 segments."""
    target = int(2 ** np.ceil(np.log2(fs / _TARGET_RESOLUTION_HZ)))
    most = 2 * n // (_MIN_SEGMENTS + 1)  # n_segments = 2 n / nperseg - 1 at 50 % overlap
    most = int(2 ** np.floor(np.log2(max(most, 16))))
    return int(max(16, min(target, most, n)))


def _peaks(logp, floor, min_prominence_dec, min_height_dec):
    """Peaks of one joint's log-PSD passing both thresholds: (indices, prominences)."""
    idx, props = signal.find_peaks(logp, prominence=float(min_prominence_dec))
    ok = logp[idx] - floor >= float(min_height_dec)
    return idx[ok], props["prominences"][ok]


def _reference_max_hz(log):
    """Highest frequency of the reference trajectory (Hz), 0 if unknown."""
    omega = getattr(getattr(log, "trajectory", None), "omega", None)
    if omega is None:
        return 0.0
    omega = np.abs(np.asarray(omega, dtype=float))
    return float(omega.max()) / (2 * np.pi) if omega.size else 0.0


def error_spectrum(log, *, nperseg=None, min_mode_hz=MIN_MODE_HZ,
                   min_prominence_dec=MIN_PROMINENCE_DEC, min_height_dec=MIN_HEIGHT_DEC,
                   min_resonance_hz=None, cutoff_fraction=CUTOFF_FRACTION):
    """Welch spectrum of the logged tracking errors, the unmodelled mode and a cut-off.

    Use a log of several seconds: a 200 ms window has too few samples to
    resolve a 30 Hz mode (read the spectrum on the whole run and apply its
    cut-off to windows cut from it).

    Parameters
    ----------
    log : plant.ExperimentLog or path
        The log (CSV + sidecar); ``e_pulses``, the sample time and the
        trajectory's frequencies are used.
    nperseg : int, optional
        Welch segment length in samples (Hann window, 50 % overlap, linear
        detrend per segment).  Default: the power of two giving about 1.5 Hz
        resolution (1024 at Ts = 0.7 ms), reduced so that at least 4
        segments are averaged.
    min_mode_hz : float
        Lower end of the band searched for the mode (Hz); the upper end is
        0.4 fs.  See the module docstring for the default.
    min_prominence_dec, min_height_dec : float
        Detection thresholds of a peak, in decades of the PSD (prominence,
        height above the high-frequency floor).
    min_resonance_hz : float, optional
        Lower end of the resonance search (Hz); default the larger of 2 Hz
        and four times the highest reference frequency.
    cutoff_fraction : float
        The suggested cut-off is this fraction of the lowest resonance.

    Returns
    -------
    ErrorSpectrum

    Raises
    ------
    ValueError
        If the log has fewer than 16 samples, ``nperseg`` is out of
        ``[16, n_samples]`` or ``cutoff_fraction`` is not in (0, 1).

    Examples
    --------
    >>> spec = error_spectrum(plant.load_log("puma560_paper_drill_flex.csv"))  # doctest: +SKIP
    >>> spec.summary()                                                         # doctest: +SKIP
    'puma560_paper_drill_flex: mode e2 30.7 Hz, e3 30.7 Hz; lowest resonance
    e2 8.4 Hz, e3 8.4 Hz; suggested: low-pass 4.2 Hz'
    """
    log = plant.as_log(log)
    e = np.asarray(log.e_pulses, dtype=float)
    n = e.shape[0]
    if n < 16:
        raise ValueError(f"error_spectrum needs at least 16 samples, got {n}")
    if not 0.0 < float(cutoff_fraction) < 1.0:
        raise ValueError(f"cutoff_fraction must lie in (0, 1), got {cutoff_fraction}")
    ts = float(log.rig.sample_time_s)
    fs = 1.0 / ts
    if nperseg is None:
        nperseg = _default_nperseg(n, fs)
    nperseg = int(nperseg)
    if not 16 <= nperseg <= n:
        raise ValueError(f"nperseg must lie in [16, {n}] (the log length), got {nperseg}")
    f_hz, psd = signal.welch(e, fs=fs, nperseg=nperseg, detrend="linear", axis=0)
    n_segments = max(1, (n - nperseg) // (nperseg // 2) + 1)
    logp = np.log10(np.maximum(psd, np.finfo(float).tiny))
    if min_resonance_hz is None:
        min_resonance_hz = max(MIN_RESONANCE_HZ, 4.0 * _reference_max_hz(log))
    min_resonance_hz = float(min_resonance_hz)

    band = (float(min_mode_hz), 0.4 * fs)
    floor = np.median(logp[f_hz >= 0.25 * fs], axis=0)
    mode = np.full(2, np.nan)
    prom = np.full(2, np.nan)
    resonance = np.full(2, np.nan)
    for j in range(2):
        idx, prominence = _peaks(logp[:, j], floor[j], min_prominence_dec, min_height_dec)
        in_band = (f_hz[idx] >= band[0]) & (f_hz[idx] <= band[1])
        if not np.any(in_band):
            continue
        best = int(np.argmax(np.where(in_band, prominence, -np.inf)))
        mode[j], prom[j] = f_hz[idx[best]], prominence[best]
        below = (f_hz[idx] >= min_resonance_hz) & (f_hz[idx] < mode[j])
        resonance[j] = f_hz[idx[below][0]] if np.any(below) else mode[j]
    found = resonance[np.isfinite(resonance)]
    cutoff = float(cutoff_fraction * found.min()) if found.size else None
    return ErrorSpectrum(
        f_hz=f_hz, psd=psd, mode_hz=mode, mode_prominence_dec=prom, resonance_hz=resonance,
        floor_dec=floor, cutoff_hz=cutoff, search_band_hz=band,
        min_resonance_hz=min_resonance_hz, nperseg=nperseg, n_segments=int(n_segments),
        sample_time_s=ts, log_name=str(getattr(log, "name", "")),
    )


def suggest_lowpass(log, **kwargs):
    """Suggested low-pass cut-off (Hz) for identifying a log, or None.

    ``error_spectrum(log, **kwargs).cutoff_hz``: half the lowest closed-loop
    resonance of a log that shows an unmodelled (flexible) mode, None for a
    log that shows none (a rigid log: identify it unfiltered).

    Parameters
    ----------
    log : plant.ExperimentLog or path
    **kwargs
        Passed to :func:`error_spectrum`.

    Returns
    -------
    float or None
    """
    return error_spectrum(log, **kwargs).cutoff_hz
