"""A payload on any arm's last link from a window of pulses, fed to the arm's CTC (issue 23)."""
from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

import plant
from identification.arm_payload import (DEFAULT_ARM_PAYLOAD_BOUNDS, ArmPayloadResult,
                                         identify_arm_payload)
from plant.logs.arm_log import load_arm_log
from plant.simulation.arm import arm_plant
from plant.simulation.synthetic import emulate_arm_log
from test_arm import TRAJ, planar_arm, planar_rig

DATA = Path(__file__).parent / "data" / "independent_arm"
STEM = "indep_arm_planar2_payload"
TOOL = dict(mass_kg=2.0, com_m=(0.08, 0.03, 0.0))


@pytest.fixture(scope="module")
def arm():
    return arm_plant(planar_arm())


@pytest.fixture(scope="module")
def loaded_log(arm):
    """A P-control log of the library's planar arm carrying TOOL (plumbing; acceptance:
    the independent log below and benchmarks/bench_arm_payload.py)."""
    beta = arm.beta() + arm.model.payload_delta(TOOL["mass_kg"], TOOL["com_m"], base=arm.base)
    return emulate_arm_log(arm, beta, planar_rig(), TRAJ, 3000), beta


def test_independent_robot_payload_from_a_window():
    """The committed log of benchmarks/independent_arm.py (Robotics Toolbox rne, DOP853): a
    3.49 kg point mass on a random planar arm's last link.  From the unloaded arm's base
    parameters, each 0.2 s window gives the mass within 2 % and the centre of mass in the
    arm's plane within a centimetre; the offset along the joint axes changes no torque of a
    planar arm and is reported as not identifiable."""
    log = load_arm_log(DATA / f"{STEM}.csv")
    truth = json.loads((DATA / f"{STEM}.truth.json").read_text())
    tool = truth["settings"]["payload"]
    for t0 in (0.6, 1.4, 2.5):
        res = identify_arm_payload(log, truth["beta"], window_s=(t0, t0 + 0.2))
        assert isinstance(res, ArmPayloadResult) and res.success
        assert res.mass_kg == pytest.approx(tool["mass_kg"], rel=0.02)
        assert np.all(np.abs(res.com_m[:2] - tool["com_m"][:2]) < 0.01)
        assert res.com_identifiable.tolist() == [True, True, False]
        assert np.all(np.isfinite(res.x_std[:3])) and np.isnan(res.x_std[3])
        # the loaded arm's base parameters: the prior shifted by the payload alone, within
        # 2 % of the largest shift
        shift = np.asarray(truth["beta_loaded"]) - np.asarray(truth["beta"])
        assert np.abs(res.beta - np.asarray(truth["beta_loaded"])).max() <= 0.02 * np.abs(shift).max()
        np.testing.assert_array_equal(res.beta_prior, truth["beta"])
        assert res.window_s[0] == pytest.approx(t0, abs=log.rig.sample_time_s)


def test_a_search_stopped_at_its_iteration_limit_goes_on_in_first_moments(arm, loaded_log,
                                                                         monkeypatch):
    """When the (m, c) search stops at its iteration limit, identify_arm_payload searches
    again from its best in first moments (m, m c) and keeps the lower cost (never higher,
    every simulation counted); a search that converges within the limit is untouched."""
    import identification.arm_payload as ap

    log, _ = loaded_log
    prior = arm.beta()
    window = (0.8, 1.0)
    monkeypatch.setattr(ap, "WIDE_SEARCH_Z", np.inf)  # this stage alone (the wide one below)
    short = identify_arm_payload(log, prior, window_s=window, max_iter=3)
    ample = identify_arm_payload(log, prior, window_s=window)
    monkeypatch.setattr(ap, "_first_moment_stage", lambda problem, ref, box, max_iter: ref)
    short_off = identify_arm_payload(log, prior, window_s=window, max_iter=3)
    ample_off = identify_arm_payload(log, prior, window_s=window)
    assert short.fun < short_off.fun and short.nfev > short_off.nfev
    assert abs(short.mass_kg - TOOL["mass_kg"]) < abs(short_off.mass_kg - TOOL["mass_kg"])
    assert ample.nit < 40  # converged within the limit: the stage does not run
    np.testing.assert_array_equal(ample.x, ample_off.x)
    assert ample.nfev == ample_off.nfev
    # the first-moment box holds every (m, c) of the (m, c) box, and the maps invert
    box = np.array(ap.DEFAULT_ARM_PAYLOAD_BOUNDS)
    rng = np.random.default_rng(3)
    X = np.column_stack([rng.uniform(*box[0], 50)] + [rng.uniform(*b, 50) for b in box[1:]])
    H = ap._FirstMoments.to_moments(X)
    mbox = ap._FirstMoments.box(box)
    assert np.all((H >= mbox[:, 0]) & (H <= mbox[:, 1]))
    np.testing.assert_allclose(ap._FirstMoments.to_com(H), X, rtol=1e-12)


def test_quantisation_z_is_standard_under_pure_quantisation_noise():
    """quantisation_z of n uniform unit-cell errors has mean 0 and standard deviation 1
    (the statistic's definition: mean n/12, variance n/180), whatever n."""
    from identification.flexible import quantisation_z

    rng = np.random.default_rng(20261127)
    for n in (40, 400, 4000):
        z = np.array([quantisation_z(np.sum(rng.uniform(-0.5, 0.5, n) ** 2), n)
                      for _ in range(4000)])
        assert abs(z.mean()) < 0.06 and abs(z.std() - 1.0) < 0.06
    assert quantisation_z(12.0, 0) == 0.0


def test_the_wide_search_runs_only_above_quantisation_and_never_costs_more(arm, loaded_log,
                                                                          monkeypatch):
    """A window the loaded model explains sits near the quantisation floor: no wide search,
    quantisation_z small.  Forced to run (threshold -inf), the wide search from the centre-
    of-mass box's corners keeps the lower cost -- never a higher one -- and counts its
    simulations."""
    import identification.arm_payload as ap

    log, _ = loaded_log
    prior = arm.beta()
    window = (0.8, 1.0)
    base = identify_arm_payload(log, prior, window_s=window)
    assert not base.wide_search and base.quantisation_z < ap.WIDE_SEARCH_Z
    monkeypatch.setattr(ap, "WIDE_SEARCH_Z", -np.inf)
    wide = identify_arm_payload(log, prior, window_s=window)
    assert wide.wide_search and wide.fun <= base.fun and wide.nfev > base.nfev
    assert wide.mass_kg == pytest.approx(TOOL["mass_kg"], rel=0.02)
    assert wide.to_dict()["wide_search"] is True
    box = np.array(ap.DEFAULT_ARM_PAYLOAD_BOUNDS)
    starts = ap._starts(box, np.arange(4.0, 8.0), ap._WIDE_CORNER_FRACTION)
    assert starts.shape == (24, 8) and np.all(np.abs(starts[:, 1:4]) == 0.2)
    np.testing.assert_array_equal(starts[:, 4:], np.tile(np.arange(4.0, 8.0), (24, 1)))
    centre = ap._starts(box, np.arange(4.0, 8.0))  # the default search: the box's centre
    assert centre.shape == (3, 8) and np.all(centre[:, 1:4] == 0.0)
    np.testing.assert_array_equal(np.unique(starts[:, 0]), centre[:, 0])


def test_cli_payload_on_a_robot_model_log(arm, loaded_log, tmp_path, capsys):
    """``python -m identification LOADED.csv --payload --prior UNLOADED.json`` on a robot
    model's log: the unloaded arm's result file (the CLI's own --output) is the prior, the
    payload is identified over the whole log, printed and written as JSON; a prior of another
    robot, a malformed one and identification options are one-line errors with no output."""
    from identification.cli import main

    log, _ = loaded_log
    unloaded = emulate_arm_log(arm, arm.beta(), planar_rig(), TRAJ, 2000, name="unloaded")
    prior = tmp_path / "prior.json"
    assert main([str(unloaded.save(tmp_path / "unloaded.csv")), "-o", str(prior), "--quiet"]) == 0
    loaded = log.save(tmp_path / "loaded.csv")
    capsys.readouterr()
    out, plots = tmp_path / "payload.json", tmp_path / "plots"
    assert main([str(loaded), "--payload", "--prior", str(prior), "-o", str(out),
                 "--plot", str(plots), "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "payload on the last link" in printed and "quantisation noise" in printed
    data = json.loads(out.read_text())
    assert data["success"] is True and data["mass_kg"] == pytest.approx(TOOL["mass_kg"], rel=0.02)
    assert (plots / "payload_residuals.png").stat().st_size > 0
    other = tmp_path / "other.json"
    other.write_text(json.dumps(dict(json.loads(prior.read_text()), names=["a", "b", "c"])))
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    for args, needle in ((["--prior", str(other)], "another robot"),
                         (["--prior", str(bad)], "invalid JSON"),
                         (["--prior", str(prior), "--method", "idim-ls"], "does not apply")):
        target = tmp_path / "never.json"
        assert main([str(loaded), "--payload", *args, "-o", str(target), "--quiet"]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("error: ") and needle in err[0]
        assert not target.exists()


def test_a_mass_at_the_box_bound_is_reported(arm, loaded_log):
    """A box too small for the tool (1 kg at most for 2 kg): the mass ends on the box's top,
    and the result says so (at_bounds, the table, the JSON); the right box flags nothing."""
    log, _ = loaded_log
    box = np.array(DEFAULT_ARM_PAYLOAD_BOUNDS, dtype=float)
    box[0] = (0.0, 1.0)
    small = identify_arm_payload(log, arm.beta(), window_s=(0.8, 1.0), bounds=box)
    assert small.mass_kg == pytest.approx(1.0) and small.at_bounds == ("m (upper)",)
    assert "at the box's bound: m (upper)" in small.table()
    assert small.to_dict()["at_bounds"] == ["m (upper)"]
    assert identify_arm_payload(log, arm.beta(), window_s=(0.8, 1.0)).at_bounds == ()


def test_the_payload_makes_the_arm_ctc_track(arm, loaded_log):
    """The CTC built from the prior plus a window's payload tracks the loaded arm within +-1
    pulse after 0.1 s; the prior alone does not."""
    from ctc.arm import ArmComputedTorque

    log, beta_true = loaded_log
    res = identify_arm_payload(log, arm.beta(), window_s=(1.0, 1.2))
    assert res.mass_kg == pytest.approx(TOOL["mass_kg"], rel=0.01)
    rig = planar_rig(limit=40.0)
    out = {}
    for name, beta in (("prior", arm.beta()), ("payload", res.beta)):
        ctrl = ArmComputedTorque(arm, beta, rig, TRAJ)
        r = plant.simulate_closed_loop(rig, beta_true, ctrl, trajectory=TRAJ, n_samples=2000,
                                       plant=arm)
        assert r.success
        out[name] = r.max_abs_error(0.1)
    assert np.all(out["payload"] <= 1) and np.any(out["prior"] > 1)


def test_online_from_a_window_of_the_ctcs_own_run(arm, loaded_log):
    """The paper's on-line proposal: the prior's CTC runs the loaded arm; a 0.2 s window of
    its own run, its commanded currents replayed (``currents='logged'``), gives the payload,
    and the CTC with it tracks within +-1 pulse."""
    import dataclasses

    from ctc.arm import ArmComputedTorque

    log, beta_true = loaded_log
    rig = planar_rig(limit=40.0)
    run = plant.simulate_closed_loop(rig, beta_true, ArmComputedTorque(arm, arm.beta(), rig, TRAJ),
                                     trajectory=TRAJ, n_samples=2000, plant=arm)
    assert run.success and np.any(run.max_abs_error(0.1) > 1)
    n = run.e_pulses.shape[0]
    ctc_log = dataclasses.replace(log, rig=rig, t=log.t[:n], q_ref=log.q_ref[:n],
                                  e_pulses=np.asarray(run.e_pulses), i_A=np.asarray(run.i_A))
    res = identify_arm_payload(ctc_log, arm.beta(), window_s=(1.0, 1.2), currents="logged")
    assert res.mass_kg == pytest.approx(TOOL["mass_kg"], rel=0.01)
    r = plant.simulate_closed_loop(rig, beta_true, ArmComputedTorque(arm, res.beta, rig, TRAJ),
                                   trajectory=TRAJ, n_samples=2000, plant=arm)
    assert np.all(r.max_abs_error(0.1) <= 1)


def test_logged_currents_of_a_p_log_are_the_p_law(arm, loaded_log):
    """``currents='logged'`` reads the log's i_A; on a P-control log they are the P law's, so
    the result is the default's."""
    log, _ = loaded_log
    a = identify_arm_payload(log, arm.beta(), window_s=(2.0, 2.15))
    b = identify_arm_payload(log, arm.beta(), window_s=(2.0, 2.15), currents="logged")
    np.testing.assert_allclose(a.x, b.x, rtol=1e-9, atol=1e-12)
    assert a.fun == pytest.approx(b.fun, rel=1e-9)


def test_result_speaks_scipy_and_json(arm, loaded_log, tmp_path):
    import matplotlib

    matplotlib.use("Agg")
    log, _ = loaded_log
    res = identify_arm_payload(log, arm.beta(), window_s=(0.5, 0.7))
    for key in ("x", "fun", "nfev", "nit", "success", "message"):
        assert key in res
    assert res.nfev > 0 and res.nit > 0
    d = res.to_dict()
    text = json.dumps(d)
    assert json.loads(text)["x_std"][3] is None  # NaN -> null
    assert "not identifiable" in res.table()
    assert f"{res.quantisation_z:+.1f} standard deviations from quantisation noise" in res.table()
    ax = res.plot()
    assert len(ax.lines) == 2
    assert res.residuals_pulses.shape == (int(round(0.2 / log.rig.sample_time_s)) + 1, 2)


@pytest.mark.parametrize("kwargs, match", [
    (dict(window_s=(1.0, 1.005)), "at least 20"),
    (dict(window_s=(2.5, 9.0)), "outside the log"),
    (dict(currents="measured"), "currents must be"),
    (dict(currents=np.zeros((5, 2))), "currents must be"),
    (dict(bounds=[[0, 1], [0, 1], [0, 1]]), "bounds"),
])
def test_bad_inputs_give_one_line_errors(arm, loaded_log, kwargs, match):
    log, _ = loaded_log
    with pytest.raises(ValueError, match=match) as exc:
        identify_arm_payload(log, arm.beta(), **kwargs)
    assert "\n" not in str(exc.value)


def test_a_bare_prior_needs_known_friction(arm, loaded_log):
    import dataclasses

    log, _ = loaded_log
    rig = dataclasses.replace(log.rig, viscous_friction_Nms_per_rad=None, coulomb_friction_Nm=None)
    unknown = dataclasses.replace(log, rig=rig)
    with pytest.raises(ValueError, match="friction is unknown"):
        identify_arm_payload(unknown, arm.beta(), window_s=(1.0, 1.2))
    with pytest.raises(ValueError, match="base parameters"):
        identify_arm_payload(log, arm.beta()[:-1], window_s=(1.0, 1.2))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        identify_arm_payload(log, arm.beta(), window_s=(1.0, 1.2))


def test_a_friction_change_is_fitted_as_the_payloads_rival(arm):
    """A window of a P log whose drive friction is 1.5 times the rig's: the friction-change
    hypothesis finds the factors (within 5 %) and explains the window better than any
    payload."""
    import dataclasses

    from identification.arm_payload import identify_arm_friction_change

    rig = planar_rig()
    warm = dataclasses.replace(
        rig, viscous_friction_Nms_per_rad=tuple(1.5 * v for v in rig.viscous_friction_Nms_per_rad),
        coulomb_friction_Nm=tuple((1.5 * a, 1.5 * b) for a, b in rig.coulomb_friction_Nm))
    log = emulate_arm_log(arm, arm.beta(), warm, TRAJ, 2000)
    log = dataclasses.replace(log, rig=rig)  # the model's rig: the friction it knows
    window = (1.0, 1.2)
    fr = identify_arm_friction_change(log, arm.beta(), window_s=window, currents=None)
    assert fr.success
    assert np.allclose(fr.viscous_factor, 1.5, rtol=0.05)
    assert fr.residuals_pulses.shape == (201, 2)
    pl = identify_arm_payload(log, arm.beta(), window_s=window)
    assert fr.fun < pl.fun
    with pytest.raises(ValueError, match="finite base parameters"):
        identify_arm_friction_change(log, arm.beta(), beta=np.zeros(3), window_s=window)
