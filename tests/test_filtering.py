"""Zero-phase low-pass of the tracking errors and the error-spectrum diagnostic (issue 7).

The filter must act identically on the logged and the simulated side of the
output error, reject impossible cut-offs with a one-line ValueError, and the
diagnostic must find the ~30 Hz mode of the flexible log and none in the
rigid logs.
"""
from __future__ import annotations

import numpy as np
import pytest

import plant
from identification import IDENTIFICATION_SUBSTEPS, OutputError, PredictionErrorProblem
from identification.diagnostics import ErrorSpectrum, error_spectrum, suggest_lowpass
from identification.filtering import apply_lowpass, lowpass_sos

PAPER_RIGID = "puma560_paper_rigid"
DRILL = "puma560_paper_drill_flex"


@pytest.fixture(scope="module")
def f_rigid(truth):
    return np.asarray(truth(PAPER_RIGID)["f_vector"], dtype=float)


@pytest.fixture(scope="module")
def short_log(paper_log):
    """The first 0.7 s of the paper log (a window from t = 0: fast to simulate)."""
    return paper_log.window(0.0, 0.7)


# ------------------------------------------------------------------ lowpass_sos
@pytest.mark.parametrize("cutoff", [0.0, -5.0, 714.2857142857143, 800.0, float("nan")])
def test_lowpass_sos_rejects_cutoff_outside_open_nyquist_band(cutoff):
    with pytest.raises(ValueError) as info:
        lowpass_sos(cutoff, 0.0007)
    msg = str(info.value)
    assert "\n" not in msg and "Nyquist" in msg


def test_lowpass_sos_accepts_cutoff_just_below_nyquist():
    sos = lowpass_sos(700.0, 0.0007)
    assert sos.ndim == 2 and sos.shape[1] == 6


def test_output_error_with_bad_cutoff_raises(short_log):
    with pytest.raises(ValueError, match="Nyquist"):
        OutputError(short_log, lowpass_hz=1000.0)


def test_apply_lowpass_is_zero_phase_and_linear():
    ts = 0.0007
    t = np.arange(2000) * ts
    slow = np.column_stack([np.sin(2 * np.pi * 1.0 * t), np.cos(2 * np.pi * 0.5 * t)])
    fast = 0.5 * np.sin(2 * np.pi * 30.0 * t)[:, None] * np.ones((1, 2))
    sos = lowpass_sos(10.0, ts)
    y = apply_lowpass(slow + fast, sos)
    inner = slice(300, -300)  # away from the edge transients
    assert np.max(np.abs(y[inner] - slow[inner])) < 1e-2  # no delay, 30 Hz removed
    a, b = np.random.default_rng(0).normal(size=(2, 500, 2))
    np.testing.assert_allclose(apply_lowpass(2 * a - b, sos),
                               2 * apply_lowpass(a, sos) - apply_lowpass(b, sos), atol=1e-12)


# --------------------------------------------------- same filter on both sides
def test_filtered_output_error_equals_manual_filtering_of_both_sides(short_log, f_rigid):
    cutoff = 12.0
    F = np.vstack([f_rigid, f_rigid * 1.03])
    y = OutputError(short_log, lowpass_hz=cutoff)(F)
    sos = lowpass_sos(cutoff, short_log.rig.sample_time_s)
    sim = plant.simulate_batch(short_log, F, substeps=IDENTIFICATION_SUBSTEPS)
    d = apply_lowpass(sim.e_pulses, sos) - apply_lowpass(short_log.e_pulses, sos)[None]
    np.testing.assert_allclose(y, np.sum(d ** 2, axis=(1, 2)), rtol=1e-12)
    # and it differs from the unfiltered output error (the filter does act)
    y_raw = OutputError(short_log)(F)
    assert not np.allclose(y, y_raw)


def test_self_simulated_log_gives_zero_with_and_without_filter(short_log, f_rigid):
    e = plant.simulate_experiment(short_log, f_rigid, substeps=IDENTIFICATION_SUBSTEPS)
    own = short_log.replace(e_pulses=e, i_A=e * np.asarray(short_log.rig.p_gain_A_per_pulse))
    for lp in (None, 5.0, 30.0):
        assert OutputError(own, lowpass_hz=lp)(f_rigid[None])[0] == 0.0


def test_prediction_errors_are_filtered_like_the_manual_filter(short_log, f_rigid):
    raw = PredictionErrorProblem(short_log).residuals(f_rigid).reshape(-1, 2)
    filt = PredictionErrorProblem(short_log, lowpass_hz=8.0).residuals(f_rigid).reshape(-1, 2)
    sos = lowpass_sos(8.0, short_log.rig.sample_time_s)
    np.testing.assert_allclose(filt, apply_lowpass(raw, sos), atol=1e-9)


# ------------------------------------------------------------- error spectrum
def test_error_spectrum_finds_the_30_hz_mode_of_the_drill_log(drill_log):
    spec = error_spectrum(drill_log)
    assert isinstance(spec, ErrorSpectrum)
    assert spec.psd.shape == (spec.f_hz.size, 2) and np.all(spec.psd >= 0)
    assert spec.mode_found
    assert np.all((spec.mode_hz > 27.0) & (spec.mode_hz < 34.0)), spec.mode_hz
    # the lowest loop resonance (~8-10 Hz) sets the cut-off: half of it
    assert np.all((spec.resonance_hz > 6.0) & (spec.resonance_hz < 12.0)), spec.resonance_hz
    assert spec.cutoff_hz == pytest.approx(0.5 * np.nanmin(spec.resonance_hz))
    assert suggest_lowpass(drill_log) == spec.cutoff_hz
    assert "30.7 Hz" in spec.summary()


@pytest.mark.parametrize("nperseg", [512, 2048])
def test_mode_detection_is_robust_to_the_segment_length(drill_log, paper_log, nperseg):
    assert 27.0 < error_spectrum(drill_log, nperseg=nperseg).mode_frequency_hz < 34.0
    assert not error_spectrum(paper_log, nperseg=nperseg).mode_found


def test_error_spectrum_finds_no_mode_in_rigid_logs(paper_log, validation_log):
    for log in (paper_log, validation_log):
        spec = error_spectrum(log)
        assert not spec.mode_found
        assert np.all(np.isnan(spec.mode_hz))
        assert spec.cutoff_hz is None and spec.mode_frequency_hz is None
        assert suggest_lowpass(log) is None


def test_error_spectrum_accepts_a_path(drill_flex_path):
    assert suggest_lowpass(drill_flex_path) == pytest.approx(4.185, abs=0.5)


def test_error_spectrum_plot_returns_a_figure(drill_log, paper_log):
    from matplotlib.figure import Figure

    for log in (drill_log, paper_log):
        fig = error_spectrum(log).plot()
        assert isinstance(fig, Figure)
        ax = fig.axes[0]
        labels = [t.get_text() for t in ax.get_legend().get_texts()]
        if log is drill_log:
            assert any("mode" in s and "30.7" in s for s in labels)
            assert any("cut-off" in s for s in labels)
        else:
            assert not any("cut-off" in s for s in labels)


def test_short_window_default_segment_and_bad_arguments(drill_log):
    w = drill_log.window(1.0, 1.2)
    spec = error_spectrum(w)
    assert spec.n_segments >= 4 and spec.nperseg <= w.n_samples
    with pytest.raises(ValueError, match="nperseg"):
        error_spectrum(w, nperseg=w.n_samples + 1)
    with pytest.raises(ValueError, match="cutoff_fraction"):
        error_spectrum(w, cutoff_fraction=1.5)
    with pytest.raises(ValueError, match="16 samples"):
        error_spectrum(drill_log.window(1.0, 1.005))
