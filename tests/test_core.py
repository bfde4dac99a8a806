"""The one closed-loop core: every driver advances the plant through the same step.

Issue 12: the P experiment in SIMD lanes, one candidate alone, the loop with
a Python controller, and the logged-input replay all run
``plant.simulation.core.advance_sample`` with the same rig layout, so they give the same
pulses bit for bit on every development log.
"""
import dataclasses
import json
import math

import numba
import numpy as np
import pytest

import plant
from ctc import PController
from plant.simulation.core import STATUS_OK
from plant.logs.rig import RigConstants, rig_constants

SUBSTEPS = 8


@pytest.fixture(scope="module", params=["puma560_paper_rigid", "puma560_validation_rigid",
                                        "puma560_paper_drill_flex"])
def log_and_f(request, data_dir):
    log = plant.load_log(data_dir / f"{request.param}.csv")
    f = np.array(json.loads((data_dir / f"{request.param}.truth.json").read_text())["f_vector"])
    return log, f


def test_lane_single_and_controller_drivers_give_identical_pulses(log_and_f, monkeypatch):
    log, f = log_and_f
    monkeypatch.setattr(plant.simulation.parallel, "MIN_LANES_PER_CHUNK", 1)  # 2 threads even for 16
    rng = np.random.default_rng(0)
    F = np.vstack([f, f * (1 + 0.01 * rng.standard_normal((15, 9)))])
    lanes = plant.simulate_batch(log, F, substeps=SUBSTEPS, workers=2)  # 2 chunks of 8 lanes
    assert np.all(lanes.status == STATUS_OK)
    single = plant.simulate_batch(log, f[None], substeps=SUBSTEPS, workers=1)
    np.testing.assert_array_equal(lanes.e_pulses[0], single.e_pulses[0])
    resp = plant.simulate_closed_loop(log, f, PController.from_log(log), substeps=SUBSTEPS)
    np.testing.assert_array_equal(resp.e_pulses[log.start_index:], single.e_pulses[0])
    np.testing.assert_array_equal(resp.i_A, np.asarray(log.rig.p_gain_A_per_pulse) * resp.e_pulses)


def test_replay_of_a_runs_own_currents_retraces_its_counts(log_and_f):
    """Replay driver (gain 0) fed with a simulated run's errors == that run, count for count."""
    log, f = log_and_f
    w = log.window(0.0, 0.6)
    sim = plant.simulate_batch(w, f[None], substeps=SUBSTEPS, continuous_output=True)
    ref = plant.simulation_inputs(w).ref_counts
    c_sim = ref - sim.e_pulses[0]  # continuous counts of the simulated run
    own = w.replace(e_pulses=(np.trunc(ref) - np.trunc(c_sim)).astype(np.int64))
    eps, status = plant.prediction_errors(own, f, gain=0.0, substeps=SUBSTEPS)
    assert status == STATUS_OK
    c_replay = plant.measured_counts(own) - eps
    np.testing.assert_array_equal(np.trunc(c_replay), np.trunc(c_sim))
    np.testing.assert_allclose(c_replay, c_sim, rtol=0, atol=1e-9)


def test_rig_layout_is_named_and_joint_side(paper_log):
    rig = paper_log.rig
    c = rig_constants(rig)
    assert isinstance(c, RigConstants) and c._fields[0] == "sample_time_s"
    k = np.asarray(rig.gear_ratio)
    np.testing.assert_allclose(c.pulses_per_rad, rig.pulses_per_rad)
    np.testing.assert_allclose(c.viscous, k**2 * np.asarray(rig.viscous_friction_Nms_per_rad))
    np.testing.assert_allclose(c.coulomb_neg, np.abs(k) * np.asarray(rig.coulomb_friction_Nm)[:, 1])
    moved = rig_constants(rig, q0=(0.1, -0.2))
    assert moved.q0 == (0.1, -0.2) and moved.qd0 == c.qd0
    with pytest.raises(ValueError, match="q0"):
        rig_constants(rig, q0=(np.nan, 0.0))


def test_chunks_have_enough_lanes():
    from plant.simulation.parallel import MIN_LANES_PER_CHUNK, chunk_ranges

    small = 2 * MIN_LANES_PER_CHUNK - 1
    assert chunk_ranges(small, 2) == [(0, small)]  # one thread: splitting would cost more
    assert chunk_ranges(76, 2) == [(0, 38), (38, 76)]  # a paper GA generation: two threads
    big = chunk_ranges(4 * MIN_LANES_PER_CHUNK, 2)
    assert big == [(0, 2 * MIN_LANES_PER_CHUNK), (2 * MIN_LANES_PER_CHUNK, 4 * MIN_LANES_PER_CHUNK)]
    assert chunk_ranges(5, 8) == [(0, 5)]
    # kernels whose lanes cost per lane (a robot model's arm): split beyond one SIMD block
    assert chunk_ranges(8, 2, block=8) == [(0, 8)]
    assert chunk_ranges(9, 2, block=8) == [(0, 5), (5, 9)]
    assert chunk_ranges(16, 4, block=8) == [(0, 8), (8, 16)]
    assert chunk_ranges(76, 2, block=8) == [(0, 38), (38, 76)]


def test_simulation_leaves_no_state_behind(paper_log):
    """No write onto the frozen log, numba's thread count untouched by workers=."""
    threads = numba.get_num_threads()
    f = np.array([0.9, 0.35, 0.01, -0.4, 0.03, -0.9, 4.5, -0.1, 3.8])
    plant.simulate_batch(paper_log, np.tile(f, (4, 1)), substeps=1, workers=1, errors=False)
    assert numba.get_num_threads() == threads
    assert not hasattr(paper_log, "_sim_cache") and "_sim_cache" not in vars(paper_log)
    assert plant.simulation_inputs(paper_log) is plant.simulation_inputs(paper_log)  # cached


def test_a_new_plant_kind_must_be_registered(paper_log):
    """The core dispatches on the plant's kind type; an unregistered kind is refused at compile time."""
    from typing import NamedTuple

    class UnknownKind(NamedTuple):
        code: int = 7

    bogus = dataclasses.replace(plant.RIGID, kind=UnknownKind())
    f = np.array([0.9, 0.35, 0.01, -0.4, 0.03, -0.9, 4.5, -0.1, 3.8])
    with pytest.raises(Exception, match="unknown plant kind"):
        plant.simulate_batch(paper_log.window(0.0, 0.01), f[None], plant=bogus)


def test_core_helpers_python_reference_matches_compiled(paper_log):
    """The helpers' Python bodies (the overloads' reference) give the compiled RK4 step bit for bit."""
    from plant.simulation.core import (_all_finite, lane_parameters, lane_state, plant_rhs, rk4_lane,
                            store_lane_state)
    from plant.simulation.friction import RIGID_FRICTION
    from plant.simulation.plants import RIGID, FlexibleJoints

    c = rig_constants(paper_log.rig)
    f = np.array([0.94, 0.36, 0.011, -0.39, 0.025, -0.89, 4.43, -0.10, 3.80])
    flex = FlexibleJoints((6e4, 1.5e4), (6.0, 1.0), 2e-4)
    for pl, P in ((RIGID, RIGID.lane_parameters(f[None], paper_log.rig)),
                  (RIGID_FRICTION, RIGID_FRICTION.lane_parameters(f[None], paper_log.rig)),
                  (flex, flex.lane_parameters(f[None], paper_log.rig))):
        X = np.tile(pl.initial_state(c)[:, None], (1, 1)) + 0.01
        x = lane_state(pl.kind, X, 0)
        p = lane_parameters(pl.kind, P, 0)
        assert len(x) == pl.n_states and len(p) == pl.n_parameters
        a = (0.3, math.sin(0.3), math.cos(0.3), -0.2, math.sin(-0.2), math.cos(-0.2))
        args = (pl.kind, p, c, x, (1.5, -0.7), a, 0.5e-3, 1e-3, 1e-3 / 6)
        for exact in (False, True):
            compiled = rk4_lane(*args, exact)
            python = rk4_lane.py_func(*args, exact)
            assert compiled == python
        xd, m = plant_rhs(pl.kind, p, c, x, (1.5, -0.7), (*a[1:3], *a[4:6]))
        assert len(xd) == pl.n_states and m > 0 and _all_finite(xd)
        store_lane_state(X, 0, compiled[0])
        assert lane_state(pl.kind, X, 0) == compiled[0]
