"""Windows without a start state (issue 14, item 1).

A window log whose sidecar gives no ``start_state.q_rad`` loads (the rig's
start state is None); its model starts at the window's first sample from a
state estimated from the window (:func:`identification.window.estimate_initial_state`)
and refined as nuisance parameters.  Held-out logs are emulated here with
:func:`plant.emulate_log` (other payloads, encoders, gains), never the
development logs' answers.
"""
from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import identification
import plant
from identification.window import estimate_initial_state

REPO = Path(__file__).resolve().parents[1]
WELL_EXCITED = [0, 1, 3, 5, 6, 8]  # f1 f2 f4 f6 f7 f9


@pytest.fixture(scope="module")
def unloaded_f(truth):
    # the unloaded robot's f is the prior (the off-line identification's answer)
    return np.asarray(truth("puma560_paper_rigid")["f_vector"], dtype=float)


@pytest.fixture(scope="module")
def loaded(paper_log, unloaded_f):
    """A held-out run: 2 kg tool, other COM/inertia, 2000 ppr encoders, other P gain."""
    rig = dataclasses.replace(paper_log.rig, encoder_ppr=(2000, 2000),
                              p_gain_A_per_pulse=(0.04, 0.04))
    payload = plant.Payload(2.0, (0.1, 0.02), 0.01)
    f = plant.add_payload(unloaded_f, payload, rig.a3_m)
    return plant.emulate_log(paper_log, f, rig=rig, name="held_out_loaded"), f, payload


def _without_start(w):
    return w.replace(rig=dataclasses.replace(w.rig, q0_rad=None, qd0_rad_per_s=None,
                                             payload_mass_kg=None))


def test_window_without_start_state_loads_and_round_trips(loaded, tmp_path):
    log, _, _ = loaded
    w = _without_start(log.window(1.5, 1.7))
    path = w.save(tmp_path / "win")
    side = json.loads(path.with_suffix(".json").read_text())
    assert "q_rad" not in side["start_state"] and "qd_rad_per_s" not in side["start_state"]
    back = plant.load_log(path)
    assert back == w
    assert back.rig.q0_rad is None and back.rig.qd0_rad_per_s is None
    assert np.all(np.isnan(plant.rig_constants(back.rig).q0))
    # a full run (no window_s) still needs its start state
    side.pop("window_s")
    side["n_samples"] = back.n_samples
    path.with_suffix(".json").write_text(json.dumps(side))
    with pytest.raises(plant.LogError, match="start_state.q_rad"):
        plant.load_log(path)


def test_simulation_of_a_window_needs_and_uses_the_given_state(loaded, paper_log):
    log, f, _ = loaded
    w = _without_start(log.window(1.5, 1.7))
    for fn in (lambda: plant.simulate_experiment(w, f),
               lambda: plant.prediction_errors(w, f)):
        with pytest.raises(ValueError, match="initial_state"):
            fn()
    # the true state at the window's first sample reproduces the logged errors
    resp = plant.simulate_closed_loop(log.rig, f, __import__("ctc").PController.from_log(log),
                                      trajectory=log.trajectory, n_samples=w.n_total,
                                      substeps=64)
    k0 = w.start_index
    x_true = np.r_[resp.q[k0], resp.qd[k0]]
    e = plant.simulate_experiment(w, f, substeps=64, initial_state=x_true)
    assert np.max(np.abs(e - w.e_pulses)) <= 1
    assert np.mean(e == w.e_pulses) > 0.95
    with pytest.raises(ValueError, match="initial_state"):
        plant.simulate_experiment(w, f, initial_state=x_true[:3])


def test_estimated_start_state_is_within_its_box_and_close(loaded):
    log, f, _ = loaded
    resp = plant.simulate_closed_loop(log.rig, f, __import__("ctc").PController.from_log(log),
                                      trajectory=log.trajectory, n_samples=log.n_total,
                                      substeps=64)
    scale = np.abs(log.rig.pulses_per_rad)
    for t0 in (0.4, 1.5, 2.5):
        w = _without_start(log.window(t0, t0 + 0.2))
        guess, box = estimate_initial_state(w)
        k0 = w.start_index
        assert np.all(box[:, 0] < guess) and np.all(guess < box[:, 1])
        assert np.all(np.abs(guess[:2] - resp.q[k0]) * scale <= 1.0)  # within a pulse
        _, qd_ref, _ = w.trajectory.evaluate(w.t[:1])
        # the error trend improves on the reference rate alone
        assert np.all(np.abs(guess[2:] - resp.qd[k0]) <= np.abs(qd_ref[0] - resp.qd[k0]) + 1e-3)
        assert np.all((box[2:, 0] <= resp.qd[k0]) & (resp.qd[k0] <= box[2:, 1]))


def test_identify_payload_on_windows_without_start_state(loaded, unloaded_f):
    log, f, payload = loaded
    for t0 in (0.4, 2.5):
        w = _without_start(log.window(t0, t0 + 0.2))
        res = identification.identify(w, payload=True, prior=unloaded_f, rng=0, progress=False)
        assert res.payload["mass_kg"] == pytest.approx(payload.mass_kg, rel=0.05)
        x0 = res.refinement["initial_state"]
        assert x0.shape == (4,)
        # fun is the output error from the refined state at the window's start
        e, y, _ = res.tracking_output_error()
        assert y == res.fun and e.shape == w.e_pulses.shape


def test_cli_payload_on_a_window_without_start_state(loaded, unloaded_f, tmp_path):
    """The issue's acceptance: ``python -m identification WINDOW.csv --payload --prior PRIOR.json``."""
    log, f, payload = loaded
    w = log.window(2.5, 2.7)
    path = w.save(tmp_path / "window")
    side = json.loads(path.with_suffix(".json").read_text())
    side["start_state"] = {"description": "mid-experiment: the run's start is unknown"}
    path.with_suffix(".json").write_text(json.dumps(side))
    prior = tmp_path / "prior.json"
    prior.write_text(json.dumps({"f": list(map(float, unloaded_f))}))
    out = tmp_path / "result.json"

    def run():
        proc = subprocess.run([sys.executable, "-m", "identification", str(path), "--payload",
                               "--prior", str(prior), "--output", str(out), "--quiet"],
                              cwd=REPO, capture_output=True, text=True, timeout=300)
        assert proc.returncode == 0, proc.stderr
        return json.loads(out.read_text())

    d = run()
    assert d["payload_mass_kg"] == pytest.approx(payload.mass_kg, rel=0.05)
    err = np.abs(np.asarray(d["f"]) - f) / np.abs(f)
    assert np.all(err[WELL_EXCITED] <= 0.03), err
    # kernels compiled; the machine is shared, so one re-run when another job slowed it
    wall = d["wall_time_s"] if d["wall_time_s"] <= 0.2 else min(d["wall_time_s"],
                                                                run()["wall_time_s"])
    assert wall <= 0.2


def test_compiled_ctc_in_the_logged_driver_equals_the_python_loop(paper_log, unloaded_f):
    """Item 2: the CTC's compiled law in the logged-run driver = simulate_closed_loop, bit for bit."""
    import ctc

    n = 700
    f_robot = plant.add_payload(unloaded_f, plant.Payload(3.0, (0.05, -0.03), 0.02),
                                paper_log.rig.a3_m)
    c = ctc.ComputedTorqueController.from_log(unloaded_f, paper_log)
    resp = plant.simulate_closed_loop(paper_log, f_robot, c, n_samples=n, substeps=4)
    log = plant.emulate_log(paper_log, f_robot, duration_s=(n - 1) * paper_log.rig.sample_time_s)
    log = log.replace(e_pulses=resp.e_pulses, i_A=resp.i_A)
    sim = plant.simulate_batch(log, np.vstack([f_robot, unloaded_f]), substeps=4, controller=c)
    np.testing.assert_array_equal(sim.e_pulses[0], resp.e_pulses)
    assert sim.objective[0] == 0.0 and sim.objective[1] > 0.0
    # the P law stays the default; a controller without a compiled law is refused
    with pytest.raises(ValueError, match="compiled law"):
        plant.simulate_batch(log, f_robot[None], controller=object())
