"""Acceptance of the exact closed-loop simulator (issue 3) and its failure handling."""
import dataclasses
import subprocess
import sys
from typing import NamedTuple

import numba
import numpy as np
import pytest

import plant
from plant.simulation.controllers import LoggedController, register_control_law
from plant.simulation.core import STATUS_DIVERGED, STATUS_NOT_PD, STATUS_OK, STATUS_STOPPED
from plant.simulation.replay import prediction_errors
from plant.simulation.simulate import DEFAULT_SUBSTEPS, default_bound, simulate_batch


def _true_f(truth, log):
    return np.array(truth(log.name)["f_vector"])


@pytest.fixture(scope="module")
def rigid_logs(paper_log, validation_log):
    return [paper_log, validation_log]


def test_true_f_reproduces_rigid_logs(rigid_logs, truth):
    """100 % of samples within +-1 pulse, >= 75 % identical (issue 3 acceptance)."""
    for log in rigid_logs:
        e = plant.simulate_experiment(log, _true_f(truth, log))
        d = e - log.e_pulses
        assert e.shape == (log.n_samples, 2) and e.dtype == np.int64
        assert np.abs(d).max() <= 1, log.name
        identical = np.mean(np.all(d == 0, axis=1))
        assert identical >= 0.75, (log.name, identical)


def test_default_substeps_converged(rigid_logs, truth):
    """Doubling the substeps of the default changes no pulse (convergence test)."""
    for log in rigid_logs:
        f = _true_f(truth, log)
        a = plant.simulate_experiment(log, f, substeps=DEFAULT_SUBSTEPS)
        b = plant.simulate_experiment(log, f, substeps=2 * DEFAULT_SUBSTEPS)
        np.testing.assert_array_equal(a, b)


def test_coarse_substeps_stay_within_one_pulse(paper_log, truth):
    """The identification's coarse integration is off by single-pulse flips only."""
    e = plant.simulate_experiment(paper_log, _true_f(truth, paper_log), substeps=2)
    assert np.abs(e - paper_log.e_pulses).max() <= 1


def test_output_error_true_far_below_centre(rigid_logs, truth):
    for log in rigid_logs:
        lo, hi = log.rig.bounds.T
        y_true = plant.output_error(log, _true_f(truth, log))
        y_centre = plant.output_error(log, 0.5 * (lo + hi))
        assert y_true < 0.01 * y_centre, (log.name, y_true, y_centre)


def test_batch_matches_single_and_objective(paper_log, truth):
    f = _true_f(truth, paper_log)
    F = np.vstack([f, f * 1.01, f * 0.98])
    sim = simulate_batch(paper_log, F, substeps=2)
    for i in range(3):
        e = plant.simulate_experiment(paper_log, F[i], substeps=2)
        np.testing.assert_array_equal(sim.e_pulses[i], e)
        assert sim.objective[i] == np.sum((paper_log.e_pulses - e) ** 2)
    only = simulate_batch(paper_log, F, substeps=2, errors=False)
    assert only.e_pulses is None
    np.testing.assert_array_equal(only.objective, sim.objective)


def test_same_result_with_one_or_two_threads(paper_log, truth):
    f = _true_f(truth, paper_log)
    F = f * (1 + 0.05 * np.random.default_rng(0).standard_normal((6, 9)))
    a = simulate_batch(paper_log, F, substeps=2, errors=False, workers=1).objective
    b = simulate_batch(paper_log, F, substeps=2, errors=False, workers=2).objective
    np.testing.assert_array_equal(a, b)


def test_window_log_simulates_from_t0(paper_log, truth):
    f = _true_f(truth, paper_log)
    full = plant.simulate_experiment(paper_log, f, substeps=4)
    w = paper_log.window(1.0, 1.2)
    assert w.start_index == 1429
    part = plant.simulate_experiment(w, f, substeps=4)
    np.testing.assert_array_equal(part, full[w.start_index : w.start_index + w.n_samples])


def test_not_positive_definite_candidate_gets_penalty(paper_log, truth):
    f = _true_f(truth, paper_log)
    bad = f.copy()
    bad[1] = 2.3  # f2 >> f1: det D < 0 at every q3
    assert not plant.is_positive_definite(bad)
    sim = simulate_batch(paper_log, np.vstack([f, bad]), substeps=2, errors=False)
    assert sim.status[0] == STATUS_OK and sim.status[1] == STATUS_NOT_PD
    bound = default_bound(paper_log.e_pulses)
    # fails right after the first sample (e = 0 at t = 0): the rest is charged the penalty
    assert sim.n_compared[1] == 1
    assert sim.objective[1] == pytest.approx(2 * bound**2 * (paper_log.n_samples - 1), rel=1e-12)
    assert np.isfinite(sim.objective[1]) and sim.objective[1] > sim.objective[0]
    with pytest.raises(plant.SimulationError, match="not positive definite"):
        plant.simulate_experiment(paper_log, bad)


def test_diverging_candidate_stops_early_and_penalty_orders_failures(paper_log, truth):
    f = _true_f(truth, paper_log)
    # a far too small joint-3 inertia makes the sampled P loop unstable
    light, lighter = f.copy(), f.copy()
    light[0], lighter[0] = 0.05, 0.04
    sim = simulate_batch(paper_log, np.vstack([light, lighter]), substeps=2, errors=False,
                         bound=200.0)
    assert np.all(sim.status == STATUS_DIVERGED)
    assert np.all(sim.n_compared < paper_log.n_samples)
    # the later failure has the smaller penalty
    assert sim.n_compared[0] > sim.n_compared[1]
    assert sim.objective[0] < sim.objective[1]
    with pytest.raises(plant.SimulationError, match="left the bound"):
        plant.simulate_experiment(paper_log, light, substeps=2, bound=200.0)
    # a window whose run from t = 0 fails before the window: said so, not the window's start
    t_fail = sim.n_compared[0] * paper_log.rig.sample_time_s
    window = paper_log.window(t_fail + 0.5, t_fail + 1.0)
    with pytest.raises(plant.SimulationError, match="failed before the log's window"):
        plant.simulate_experiment(window, light, substeps=2, bound=200.0)


@pytest.mark.parametrize(
    "F, match",
    [
        (np.ones(8), "shape"),
        (np.full(9, np.nan), "NaN"),
    ],
)
def test_bad_candidates_raise(paper_log, F, match):
    with pytest.raises(ValueError, match=match):
        plant.output_error(paper_log, np.atleast_2d(F) if F.size == 9 else F)


def test_bad_substeps_raise(paper_log):
    with pytest.raises(ValueError, match="substeps"):
        plant.output_error(paper_log, np.ones(9), substeps=0)


def test_pure_replay_of_true_f_stays_in_count_intervals(paper_log, truth):
    """Driven by the logged current, the true model's count lies in every logged interval."""
    from plant.simulation.simulate import reference_counts

    eps, status = prediction_errors(paper_log, _true_f(truth, paper_log), gain=0.0,
                                    substeps=DEFAULT_SUBSTEPS)
    assert status == STATUS_OK
    a = np.trunc(reference_counts(paper_log)) - paper_log.e_pulses
    centre = np.where(a > 0, a + 0.5, np.where(a < 0, a - 0.5, 0.0))
    np.testing.assert_array_equal(np.trunc(centre - eps), a)


def test_prediction_errors_smooth_in_f(paper_log, truth):
    """Unlike the integer output error, the replay cost changes smoothly with f."""
    f = _true_f(truth, paper_log)
    steps = np.linspace(-1e-3, 1e-3, 9)
    F = f[None] * (1 + steps[:, None] * np.eye(9)[6])  # vary f7
    eps, status = prediction_errors(paper_log, F, substeps=2)
    assert np.all(status == STATUS_OK)
    cost = np.einsum("mnj,mnj->m", eps, eps)
    # a parabola fits the cost to 1e-3 relative: no flips, no jumps
    c = np.polyfit(steps, cost, 2)
    assert np.max(np.abs(np.polyval(c, steps) - cost)) < 1e-3 * cost.min()
    assert c[0] > 0


@pytest.mark.parametrize("substeps", [1, 2])
def test_lanes_and_single_lane_drivers_give_the_same_pulses(paper_log, validation_log, truth,
                                                             substeps):
    """One core: a batch in SIMD lanes on 2 threads == each candidate alone (one lane)."""
    for log in (paper_log, validation_log):
        f = _true_f(truth, log)
        rng = np.random.default_rng(3)
        lo, hi = log.rig.bounds.T
        F = np.vstack([f, f * (1 + 0.02 * rng.standard_normal((9, 9))),
                       lo + (hi - lo) * rng.random((8, 9))])
        a = simulate_batch(log, F, substeps=substeps, workers=2)
        for i in (0, 1, 5, 12, 17):
            b = simulate_batch(log, F[i:i + 1], substeps=substeps, workers=1)
            np.testing.assert_array_equal(a.e_pulses[i], b.e_pulses[0])
            assert a.status[i] == b.status[0] and a.objective[i] == b.objective[0]


def test_casadi_twin_gives_the_same_pulses(paper_log, validation_log, truth):
    """The casadi twin of the core (plant.simulation.twin) reproduces the numba pulses sample for sample."""
    from plant.simulation.twin import simulate_experiment_twin

    for log in (paper_log, validation_log):
        f = _true_f(truth, log)
        e_numba = plant.simulate_experiment(log, f)
        e_twin = simulate_experiment_twin(log, f, substeps=DEFAULT_SUBSTEPS)
        np.testing.assert_array_equal(e_twin, e_numba)


def test_replay_driver_uses_the_same_core(paper_log, truth):
    """Replaying a simulated run's own currents (gain 0) retraces its counts exactly."""
    f = _true_f(truth, paper_log)
    log = paper_log.window(0.0, 1.0)
    sim = simulate_batch(log, f[None], substeps=2, continuous_output=True)  # ref - c, float
    e_int = np.trunc(plant.simulation_inputs(log).ref_counts) - np.trunc(
        plant.simulation_inputs(log).ref_counts - sim.e_pulses[0])
    own = log.replace(e_pulses=e_int.astype(np.int64))
    eps, status = prediction_errors(own, f, gain=0.0, substeps=2)
    assert status == STATUS_OK
    c_replay = plant.measured_counts(own) - eps
    c_sim = plant.simulation_inputs(log).ref_counts - sim.e_pulses[0]
    np.testing.assert_allclose(c_replay, c_sim, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(np.trunc(c_replay), np.trunc(c_sim))


def test_lockstep_lane_does_not_depend_on_its_neighbours(paper_log, truth):
    """A candidate simulated alone or among failing and diverging neighbours: same result."""
    f = _true_f(truth, paper_log)
    rng = np.random.default_rng(5)
    lo, hi = paper_log.rig.bounds.T
    bad = f.copy()
    bad[1] = 2.3  # not positive definite
    light = f.copy()
    light[0] = 0.05  # diverges
    F = np.vstack([lo + (hi - lo) * rng.random((20, 9)), bad, light,
                   f * (1 + 0.01 * rng.standard_normal((15, 9)))])
    batch = simulate_batch(paper_log, F, substeps=1, workers=2, bound=200.0)
    # other neighbours and lanes: reversed order, and a chunk of 8 copies with others
    rev = simulate_batch(paper_log, F[::-1], substeps=1, workers=1, bound=200.0)
    np.testing.assert_array_equal(rev.e_pulses[::-1], batch.e_pulses)
    np.testing.assert_array_equal(rev.objective[::-1], batch.objective)
    np.testing.assert_array_equal(rev.status[::-1], batch.status)
    for i in (0, 20, 21, 36):
        few = simulate_batch(paper_log, np.vstack([F[i], F[30:37]]), substeps=1, workers=1,
                             bound=200.0)
        np.testing.assert_array_equal(few.e_pulses[0], batch.e_pulses[i])
        assert few.objective[0] == batch.objective[i]
        assert few.status[0] == batch.status[i]
    assert {STATUS_NOT_PD, STATUS_DIVERGED} <= set(batch.status.tolist())


def test_window_log_lanes_match_single_lane(paper_log, truth):
    w = paper_log.window(1.0, 1.2)
    f = _true_f(truth, paper_log)
    F = f * (1 + 0.05 * np.random.default_rng(1).standard_normal((20, 9)))
    a = simulate_batch(w, F, substeps=2)
    for i in (0, 7, 19):
        b = simulate_batch(w, F[i:i + 1], substeps=2)
        np.testing.assert_array_equal(a.e_pulses[i], b.e_pulses[0])
        assert a.objective[i] == b.objective[0]


@pytest.mark.parametrize("workers", [1, 2])
def test_cap_stops_only_candidates_above_it(paper_log, truth, workers):
    """Early termination: below the cap nothing changes; above, the sum is extrapolated."""
    f = _true_f(truth, paper_log)
    F = f * (1 + 0.05 * np.random.default_rng(2).standard_normal((20, 9)))
    full = simulate_batch(paper_log, F, substeps=1, errors=False, workers=workers)
    assert np.all(full.status == STATUS_OK)
    cap = float(np.median(full.objective))
    capped = simulate_batch(paper_log, F, substeps=1, errors=False, cap=cap, workers=workers)
    below = full.objective <= cap
    np.testing.assert_array_equal(capped.objective[below], full.objective[below])
    assert np.all(capped.status[below] == STATUS_OK)
    assert np.all(capped.status[~below] == STATUS_STOPPED)
    assert np.all(capped.objective[~below] > cap)
    assert np.all(capped.n_compared[~below] < paper_log.n_samples)
    n = paper_log.n_samples
    # the running sum at the stop (> cap) extrapolated to the whole log
    running = capped.objective[~below] * capped.n_compared[~below] / n
    assert np.all(running > cap) and np.all(running <= full.objective[~below] + 1e-9)
    with pytest.raises(ValueError, match="cap"):
        simulate_batch(paper_log, F, cap=float("nan"))


@pytest.mark.parametrize("window", [False, True])
def test_replay_lanes_match_single_lane(paper_log, truth, window):
    log = paper_log.window(1.0, 1.2) if window else paper_log
    f = _true_f(truth, paper_log)
    rng = np.random.default_rng(6)
    bad = f.copy()
    bad[1] = 2.3
    F = np.vstack([f * (1 + 0.02 * rng.standard_normal((19, 9))), bad])
    a, sa = prediction_errors(log, F, substeps=1, workers=2)
    assert sa[-1] == STATUS_NOT_PD and np.all(sa[:-1] == STATUS_OK)
    for i in (0, 11, 19):
        b, sb = prediction_errors(log, F[i], substeps=1)
        assert sb == sa[i]
        np.testing.assert_array_equal(a[i], b)
    if window:
        x0 = np.tile([-0.1, 0.05, -0.2, 0.3], (len(F), 1))
        a, _ = prediction_errors(log, F, substeps=1, initial_state=x0)
        b, _ = prediction_errors(log, F[3], substeps=1, initial_state=x0[3])
        np.testing.assert_array_equal(a[3], b)


def test_ctrl_c_inside_the_kernel_is_a_keyboard_interrupt(paper_log, truth):
    """numba's SystemError wrapping of SIGINT is translated back to KeyboardInterrupt."""
    import os
    import signal
    import threading

    f = _true_f(truth, paper_log)
    simulate_batch(paper_log, f[None], substeps=1, errors=False)  # compiled
    timer = threading.Timer(0.2, lambda: os.kill(os.getpid(), signal.SIGINT))
    timer.start()
    try:
        with pytest.raises(KeyboardInterrupt):
            for _ in range(50):  # long enough for the timer on any machine
                simulate_batch(paper_log, np.tile(f, (200, 1)), substeps=8, errors=False)
    finally:
        timer.cancel()


class _ScaledPKind(NamedTuple):
    """Type tag of a law registered from outside ``plant`` (the test's own)."""

    code: int = 90


@numba.njit(nogil=True, inline="always")
def _scaled_p_law(lp, c, k, Y, E, CS, U, j):
    # any number of joints: lane j's currents from every joint's pulse error
    for m in range(U.shape[0]):
        U[m, j] = lp * c.p_gain[m] * E[m, j]


register_control_law(_ScaledPKind, _scaled_p_law)


def test_a_registered_joint_generic_law_runs_in_the_logged_driver(paper_log, truth):
    """A law of the array signature ``law(lp, c, k, Y, E, CS, U, j)``, called per lane with
    every joint's angle and error, gives the fused P law's pulses bit for bit at scale 1, and
    at scale 2 the pulses of a rig whose gains are doubled (the law sees the errors)."""
    f = np.asarray(truth("puma560_paper_rigid")["f_vector"])
    F = f * (1.0 + 0.02 * np.random.default_rng(3).standard_normal((5, 9)))
    p = plant.simulate_batch(paper_log, F, substeps=2)
    gains = tuple(2.0 * np.asarray(paper_log.rig.p_gain_A_per_pulse))
    doubled = paper_log.replace(rig=dataclasses.replace(paper_log.rig, p_gain_A_per_pulse=gains))
    for scale, log in ((1.0, paper_log), (2.0, doubled)):
        law = LoggedController(kind=_ScaledPKind(), parameters=scale, state=np.zeros(1),
                               name="scaled P")
        sim = plant.simulate_batch(paper_log, F, substeps=2, controller=law)
        ref = p if scale == 1.0 else plant.simulate_batch(log, F, substeps=2)
        assert (scale == 1.0) == np.array_equal(ref.e_pulses, p.e_pulses)
        np.testing.assert_array_equal(sim.e_pulses, ref.e_pulses)
        np.testing.assert_array_equal(sim.status, ref.status)


def test_a_law_from_outside_the_library_never_enters_the_on_disk_cache(paper_log, truth):
    """numba pickles a cached kernel's signatures into its index: a kind class from a test or
    a user's script there would make every later process fail to load the driver.  Such a
    law runs in the driver's in-memory twin, and a fresh process still loads the cached one."""
    from plant.simulation.controllers import P_LAW
    from plant.simulation.plants import RIGID
    from plant.simulation.simulate import for_kinds, log_chunk

    assert for_kinds(log_chunk, RIGID.kind, P_LAW.kind, P_LAW.parameters) is log_chunk
    # a library law whose parameters hold a class of the test's is the test's too
    assert for_kinds(log_chunk, RIGID.kind, P_LAW.kind, (1.0, _ScaledPKind())) is not log_chunk
    twin = for_kinds(log_chunk, RIGID.kind, _ScaledPKind())
    assert twin is not log_chunk and twin is for_kinds(log_chunk, RIGID.kind, _ScaledPKind())
    f = np.asarray(truth("puma560_paper_rigid")["f_vector"])
    law = LoggedController(kind=_ScaledPKind(), parameters=1.0, state=np.zeros(1))
    plant.simulate_batch(paper_log, f[None], substeps=1, controller=law)
    plant.simulate_batch(paper_log, f[None], substeps=1)  # the cached kernel, index written
    code = ("import numpy as np, plant; log = plant.load_example(); "
            f"print(plant.output_error(log, np.array({f.tolist()}), substeps=1))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert float(proc.stdout) == plant.output_error(paper_log, f, substeps=1)
