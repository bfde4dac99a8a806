"""Window logs and on-line payload identification (issue 7).

Window logs (sidecar ``window_s``) load and are simulated from t = 0, compared
on their own rows only; ``identify(..., payload=True, prior=...)`` recovers a
payload from a 200 ms window of a synthetic rigid loaded run.
"""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

import identification
import plant
from plant.robot.payload import payload_delta_matrix

PAPER_RIGID = "puma560_paper_rigid"
DRILL = "puma560_paper_drill_flex"
DRILL_MASS_KG = 1.5


@pytest.fixture(scope="module")
def f_unloaded(truth):
    return np.asarray(truth(PAPER_RIGID)["f_vector"], dtype=float)


@pytest.fixture(scope="module")
def f_loaded(truth):
    """The drill robot's rigid-equivalent f (unloaded robot + 1.5 kg drill)."""
    return np.asarray(truth(DRILL)["f_vector"], dtype=float)


@pytest.fixture(scope="module")
def loaded_log(paper_log, f_loaded):
    """Synthetic rigid loaded run: the paper log re-simulated with the drill's f."""
    e = plant.simulate_experiment(paper_log, f_loaded)
    return paper_log.replace(e_pulses=e, i_A=e * np.asarray(paper_log.rig.p_gain_A_per_pulse))


# ----------------------------------------------------------------- window logs
def test_window_log_saves_loads_and_simulates_from_t0(paper_log, f_unloaded, tmp_path):
    full = plant.simulate_experiment(paper_log, f_unloaded)
    w = paper_log.window(1.0, 1.2)
    path = w.save(tmp_path / "paper_window")
    side = json.loads(path.with_suffix(".json").read_text())
    assert side["window_s"] == [1.0, 1.2] and side["n_samples"] == w.n_samples
    back = plant.load_log(path)
    assert back == w
    ts = back.rig.sample_time_s
    assert back.start_index == int(np.ceil(1.0 / ts - 1e-9))  # first sample at t >= 1.0
    assert 1.0 <= back.t[0] < 1.0 + ts and back.t[-1] < 1.2
    np.testing.assert_allclose(back.t, back.sample_index * ts, rtol=0, atol=1e-12)
    # the window is simulated from t = 0 (start state of the run): its rows are
    # the full simulation's rows
    e_w = plant.simulate_experiment(back, f_unloaded)
    np.testing.assert_array_equal(e_w, full[back.start_index:back.n_total])
    # and its output error compares the window only
    y_w = plant.output_error(back, f_unloaded)
    d = paper_log.e_pulses[back.start_index:back.n_total] - e_w
    assert y_w == float(np.sum(d ** 2))


def test_window_with_unknown_payload_in_sidecar(drill_log, tmp_path):
    w = drill_log.window(1.0, 1.2)
    w = w.replace(rig=dataclasses.replace(w.rig, payload_mass_kg=None))
    path = w.save(tmp_path / "drill_window")
    side = json.loads(path.with_suffix(".json").read_text())
    assert side["payload"]["mass_kg"] is None
    back = plant.load_log(path)
    assert back.rig.payload_mass_kg is None and back.window_s == (1.0, 1.2)


# --------------------------------------------------------- payload identification
@pytest.mark.parametrize("t0", [0.5, 2.0])
def test_payload_from_synthetic_rigid_window_within_5_percent(loaded_log, f_unloaded, t0):
    w = loaded_log.window(t0, t0 + 0.2)
    res = identification.identify(w, payload=True, prior=f_unloaded, rng=0, progress=False)
    d = res.to_dict()
    assert d["payload_mass_kg"] == pytest.approx(DRILL_MASS_KG, rel=0.05)
    assert res.payload["mass_kg"] == d["payload_mass_kg"]
    # the result's f is the loaded robot: prior + M p, f8 untouched
    M = payload_delta_matrix(w.rig.a3_m)
    np.testing.assert_allclose(res.f, f_unloaded + M @ np.asarray(res.payload["vector"]),
                               rtol=1e-12, atol=1e-12)
    assert res.f[7] == f_unloaded[7]
    assert res.f[8] - f_unloaded[8] == pytest.approx(d["payload_mass_kg"] * w.rig.a3_m)


def test_payload_from_window_file_with_result_prior(loaded_log, f_unloaded, tmp_path):
    """A saved window whose sidecar does not know the payload, prior as a result dict."""
    w = loaded_log.window(0.5, 0.7)
    w = w.replace(rig=dataclasses.replace(w.rig, payload_mass_kg=None))
    path = w.save(tmp_path / "loaded_window")
    res = identification.identify(path, payload=True, prior={"f": list(f_unloaded)},
                                  rng=0, progress=False)
    d = res.to_dict()
    for key in ("payload_mass_kg", "payload_com_m", "payload_izz_kgm2", "f"):
        assert key in d
    assert d["payload_mass_kg"] == pytest.approx(DRILL_MASS_KG, rel=0.05)
    assert res.wall_time_s > 0


def test_payload_mode_needs_a_valid_prior(loaded_log, f_unloaded):
    w = loaded_log.window(0.5, 0.7)
    with pytest.raises(ValueError, match="prior"):
        identification.identify(w, payload=True, progress=False)
    with pytest.raises(ValueError, match="prior"):
        identification.identify(w, payload=True, prior=f_unloaded[:8], progress=False)
    with pytest.raises(ValueError, match="prior"):
        identification.identify(w, payload=True, prior=np.full(9, np.nan), progress=False)


# ------------------------------------------------ the flexible-robot cases
@pytest.fixture(scope="module")
def rigid_prior(paper_log):
    """The unloaded robot identified on puma560_paper_rigid (the issue's prior)."""
    return identification.identify(paper_log, rng=0, progress=False)


def test_payload_from_the_drill_flex_window_within_5_percent(drill_log, rigid_prior):
    """[1.0, 1.2) s of the flexible drill run, prior from the rigid log: mass within 5 %."""
    w = drill_log.window(1.0, 1.2)
    w = w.replace(rig=dataclasses.replace(w.rig, payload_mass_kg=None))
    res = identification.identify(w, payload=True, prior=rigid_prior, rng=0, progress=False)
    d = res.to_dict()
    assert d["payload_mass_kg"] == pytest.approx(DRILL_MASS_KG, rel=0.05)
    # a physically consistent rigid body: inertia about its own COM within the box
    jc = res.payload["izz_kgm2"]  # about the payload's own centre of mass
    assert 0.0 <= jc <= identification.api.DEFAULT_PAYLOAD_BOUNDS[3, 1] + 1e-12
    p = res.payload["vector"]
    assert p[3] == pytest.approx(jc + (p[1] ** 2 + p[2] ** 2) / p[0], rel=1e-9)


def test_drill_flex_consistent_and_filtered_within_5_percent(drill_log, truth):
    """Rigid-equivalent f of the flexible robot: eq.-3 structure + same-filter low-pass."""
    from identification.diagnostics import suggest_lowpass

    res = identification.identify(drill_log, rng=0, progress=False, consistent=True,
                                  lowpass_hz=suggest_lowpass(drill_log))
    f_true = np.array(truth(drill_log.name)["f_vector"])
    err = np.abs(res.f - f_true) / np.abs(f_true)
    assert np.all(err[[0, 1, 3, 5, 6, 8]] < 0.05), err
