"""Tests of plant.logs.log: loading the development logs, windows, saving, and every bad input."""
from __future__ import annotations

import dataclasses
import json
import math
import os
import time
from pathlib import Path

import numpy as np
import pytest

from plant._errors import LogError
from plant.logs.log import COLUMNS, ExperimentLog, example_log_path, load_example, load_log, rig_from_sidecar
from plant.logs.rig import Rig
from plant.logs.trajectory import Trajectory

PAPER_RIGID = "puma560_paper_rigid"
VALIDATION_RIGID = "puma560_validation_rigid"
DRILL_FLEX = "puma560_paper_drill_flex"
DEV_STEMS = (PAPER_RIGID, VALIDATION_RIGID, DRILL_FLEX)

TS = 0.0007


def expect_log_error(path, *fragments):
    """load_log(path) raises a one-line LogError naming the file and containing the fragments."""
    with pytest.raises(LogError) as exc:
        load_log(path)
    msg = str(exc.value)
    assert isinstance(exc.value, ValueError)
    assert "\n" not in msg, msg
    assert Path(path).stem.split(".")[0] in msg, msg
    for frag in fragments:
        assert frag in msg, f"{frag!r} not in {msg!r}"
    return msg


def set_key(side, key, value):
    node = side
    parts = key.split(".")
    for p in parts[:-1]:
        node = node[p]
    node[parts[-1]] = value
    return side


def del_key(side, key):
    node = side
    parts = key.split(".")
    for p in parts[:-1]:
        node = node[p]
    del node[parts[-1]]
    return side


def edit_cell(line_no, column, value):
    """csv_edit replacing one cell (line_no is the 1-based file line)."""

    def edit(lines):
        cells = lines[line_no - 1].split(",")
        cells[COLUMNS.index(column)] = value
        lines[line_no - 1] = ",".join(cells)
        return lines

    return edit


# ------------------------------------------------------------------ the dev logs
@pytest.mark.parametrize("stem", DEV_STEMS)
def test_dev_logs_load(dev_log_paths, stem):
    log = load_log(dev_log_paths[stem])
    side = json.loads(dev_log_paths[stem].with_suffix(".json").read_text())
    n = side["n_samples"]
    assert isinstance(log, ExperimentLog)
    assert log.name == stem and log.path == dev_log_paths[stem]
    assert log.n_samples == n == log.n_total
    assert log.t.shape == (n,) and log.q_ref.shape == (n, 2)
    assert log.e_pulses.shape == (n, 2) and log.e_pulses.dtype == np.int64
    assert log.i_A.shape == (n, 2) and log.i_A.dtype == np.float64
    assert log.start_index == 0 and log.window_s is None
    np.testing.assert_array_equal(log.sample_index, np.arange(n))
    np.testing.assert_allclose(log.t, np.arange(n) * TS, rtol=0, atol=1e-12)
    raw = np.loadtxt(dev_log_paths[stem], delimiter=",", skiprows=1)
    np.testing.assert_array_equal(log.t, raw[:, 0])
    np.testing.assert_array_equal(log.q_ref, raw[:, 1:3])
    np.testing.assert_array_equal(log.e_pulses, raw[:, 3:5])
    np.testing.assert_array_equal(log.i_A, raw[:, 5:7])
    assert isinstance(log.trajectory, Trajectory)
    assert np.abs(log.trajectory.position(log.t) - log.q_ref).max() <= 1e-12
    assert log.sidecar == side


@pytest.mark.parametrize("stem", DEV_STEMS)
def test_rig_values(dev_log_paths, stem):
    rig = load_log(dev_log_paths[stem]).rig
    assert isinstance(rig, Rig)
    assert rig.sample_time_s == TS
    assert rig.gear_ratio == (107.8, -53.7)
    assert rig.encoder_ppr == (800, 1000) and all(type(n) is int for n in rig.encoder_ppr)
    assert rig.p_gain_A_per_pulse == (0.15, 0.15)
    assert rig.torque_constant_Nm_per_A == (0.22, 0.22)
    assert rig.viscous_friction_Nms_per_rad == (0.006817, 0.00738)
    assert rig.coulomb_friction_Nm == ((0.071, 0.126), (0.105, 0.132))
    assert rig.coulomb_ramp_speed_rad_per_s == 0.5  # parsed from coulomb_friction_note
    assert rig.gravity_m_s2 == 9.81 and rig.a3_m == 0.4318
    assert rig.q0_rad == (0.0, 0.0) and rig.qd0_rad_per_s == (0.0, 0.0)
    assert rig.bounds.shape == (9, 2) and rig.f_bounds[0] == (0.28, 4.07) and rig.f_bounds[8] == (-2.7, 11.25)
    assert rig.current_full_scale_A == 15.0
    assert rig.payload_mass_kg == (1.5 if stem == DRILL_FLEX else None)
    hash(rig)  # frozen, hashable


def test_validation_log_trajectory_has_ramp(validation_rigid_path):
    log = load_log(validation_rigid_path)
    assert log.trajectory.t_ramp_s == 0.8 and log.n_samples == 7143


def test_path_forms(paper_rigid_path):
    ref = load_log(paper_rigid_path)
    stem = paper_rigid_path.with_suffix("")
    for p in (stem, str(stem), stem.with_suffix(".json"), str(paper_rigid_path)):
        log = load_log(p)
        assert log == ref and log.path == paper_rigid_path and log.name == PAPER_RIGID


def test_json_without_its_csv_is_refused(data_dir, tmp_path):
    """Any JSON that is not a sidecar beside its CSV (a truth file, a result) is
    refused in one line by the same path rule: STEM.json needs STEM.csv."""
    expect_log_error(data_dir / f"{PAPER_RIGID}.truth.json", "log file not found")
    other = tmp_path / "result.json"
    other.write_text("{}")
    expect_log_error(other, "log file not found")


def test_load_is_fast(validation_rigid_path):
    load_log(validation_rigid_path)
    best = min(_timed(load_log, validation_rigid_path) for _ in range(5))
    assert best < 0.1, f"loading 7143 rows took {best * 1e3:.1f} ms"


def _timed(f, *args):
    t0 = time.perf_counter()
    f(*args)
    return time.perf_counter() - t0


def test_arrays_are_read_only_and_log_frozen(paper_log):
    for a in (paper_log.t, paper_log.q_ref, paper_log.e_pulses, paper_log.i_A):
        with pytest.raises(ValueError):
            a[0] = 1
    with pytest.raises(dataclasses.FrozenInstanceError):
        paper_log.start_index = 3


def test_example_log(paper_rigid_path):
    p = example_log_path()
    assert p.is_file() and p.name == "puma560_paper_rigid.csv" and p.parent.name == "data"
    assert p.with_suffix(".json").is_file()
    ex = load_example()
    assert ex == load_log(paper_rigid_path)
    assert ex.path == p
    assert example_log_path("paper_rigid") == p and load_example("paper_rigid") == ex


def test_example_drill_flex(drill_flex_path):
    """The second bundled example is the drill/flex development log, without its truth."""
    p = example_log_path("drill_flex")
    assert p.is_file() and p.name == "puma560_paper_drill_flex.csv" and p.parent == example_log_path().parent
    assert p.with_suffix(".json").is_file()
    assert not p.with_name("puma560_paper_drill_flex.truth.json").exists()
    assert p.read_bytes() == drill_flex_path.read_bytes()
    ex = load_example("drill_flex")
    assert ex == load_log(drill_flex_path) and ex.path == p
    assert ex.rig.payload_mass_kg > 0


@pytest.mark.parametrize("name", ["", "drill", "PAPER_RIGID", None, 3])
def test_example_unknown_name(name):
    with pytest.raises(ValueError, match="paper_rigid.*drill_flex") as exc:
        example_log_path(name)
    assert "\n" not in str(exc.value)
    with pytest.raises(ValueError, match="unknown example"):
        load_example(name)


def test_no_truth_files_in_package():
    """The package data never ships a truth file (the library never reads one)."""
    assert not list(example_log_path().parent.glob("*truth*"))


def test_replace(paper_log):
    other = paper_log.replace(start_index=0)
    assert other == paper_log and other is not paper_log
    assert paper_log.replace(window_s=(0.0, 10.0)) != paper_log


# ----------------------------------------------------------------------- windows
def test_window_of_drill_log(drill_flex_path, tmp_path):
    log = load_log(drill_flex_path)
    win = log.window(1.0, 1.2)
    k0 = math.ceil(1.0 / TS)  # first k with k*Ts >= 1.0 (1428*Ts = 0.9996 s is before it)
    assert k0 == round(1.0 / TS) == 1429
    assert win.start_index == 1429
    assert win.window_s == (1.0, 1.2)
    assert np.all(win.t >= 1.0) and np.all(win.t < 1.2)
    k1 = math.ceil(1.2 / TS - 1e-9)
    assert win.n_samples == k1 - k0 and win.n_total == k1
    np.testing.assert_array_equal(win.sample_index, np.arange(k0, k1))
    np.testing.assert_array_equal(win.t, log.t[k0:k1])
    np.testing.assert_array_equal(win.e_pulses, log.e_pulses[k0:k1])
    np.testing.assert_array_equal(win.i_A, log.i_A[k0:k1])
    np.testing.assert_array_equal(win.q_ref, log.q_ref[k0:k1])
    assert win.rig == log.rig and win.trajectory == log.trajectory
    assert win.sidecar["n_samples"] == win.n_samples and win.sidecar["window_s"] == [1.0, 1.2]
    assert "window_s" not in log.sidecar  # the original is untouched

    saved = win.save(tmp_path / "drill_window")
    assert saved == tmp_path / "drill_window.csv"
    assert sorted(os.listdir(tmp_path)) == ["drill_window.csv", "drill_window.json"]  # no temp files left
    back = load_log(saved)
    assert back == win
    assert back.start_index == 1429 and back.window_s == (1.0, 1.2) and back.name == "drill_window"
    np.testing.assert_array_equal(back.t, win.t)
    np.testing.assert_array_equal(back.i_A, win.i_A)
    assert back.sidecar == win.sidecar


def test_window_boundaries_on_samples_and_nested(paper_log):
    win = paper_log.window(1000 * TS, 1100 * TS)  # boundaries exactly on samples
    assert win.start_index == 1000 and win.n_samples == 100
    inner = win.window(0.0, 1050 * TS)  # intersected with the outer window
    assert inner.start_index == 1000 and inner.n_samples == 50
    assert inner.window_s == (1000 * TS, 1050 * TS)
    tail = paper_log.window(3.6, 100.0)
    assert tail.n_total == paper_log.n_samples
    with pytest.raises(ValueError, match="holds no sample"):
        paper_log.window(10.0, 11.0)
    with pytest.raises(ValueError, match="t_start < t_stop"):
        paper_log.window(1.2, 1.0)
    with pytest.raises(ValueError, match="t_start < t_stop"):
        paper_log.window(0.0, float("inf"))


def test_save_full_log_round_trip_and_overwrite(paper_log, tmp_path):
    p = paper_log.save(tmp_path / "copy.json")
    back = load_log(p)
    assert back == paper_log
    assert json.loads(p.with_suffix(".json").read_text()) == paper_log.sidecar
    # overwriting an existing log
    win = paper_log.window(0.5, 0.6)
    win.save(tmp_path / "copy")
    assert load_log(tmp_path / "copy") == win
    assert sorted(os.listdir(tmp_path)) == ["copy.csv", "copy.json"]


def test_save_writes_replaced_rig_and_trajectory(paper_log, tmp_path):
    rig = dataclasses.replace(paper_log.rig, coulomb_ramp_speed_rad_per_s=0.25, payload_mass_kg=2.0)
    log = paper_log.replace(rig=rig)
    back = load_log(log.save(tmp_path / "r"))
    assert back.rig == rig
    assert back.sidecar["coulomb_ramp_speed_rad_per_s"] == 0.25


def test_hand_written_window_loads(tmp_log):
    """A window of a longer run: t does not start at 0, with and without window_s."""
    k0, k1 = 2000, 2300

    def cut(lines):
        return [lines[0]] + lines[1 + k0 : 1 + k1]

    def side(d, window=True):
        d["n_samples"] = k1 - k0
        if window:
            d["window_s"] = [k0 * TS, k1 * TS]
        return d

    log = load_log(tmp_log(csv_edit=cut, json_edit=side))
    assert log.start_index == k0 and log.n_total == k1 and log.window_s == (k0 * TS, k1 * TS)
    np.testing.assert_array_equal(log.sample_index, np.arange(k0, k1))
    log2 = load_log(tmp_log(csv_edit=cut, json_edit=lambda d: side(d, window=False)))
    assert log2.start_index == k0 and log2.window_s is None


# -------------------------------------------------------------------- variations that load
def test_column_order_crlf_bom_quotes_and_blank_tail(tmp_log, paper_log):
    order = [6, 0, 3, 1, 5, 2, 4]

    def permute(lines):
        return [",".join(line.split(",")[i] for i in order) for line in lines]

    assert load_log(tmp_log(csv_edit=permute)) == paper_log
    text = "\r\n".join((paper_log.path.read_text()).splitlines()) + "\r\n"
    assert load_log(tmp_log(csv_text=text)) == paper_log
    assert load_log(tmp_log(csv_text="\ufeff" + paper_log.path.read_text())) == paper_log
    quoted = [",".join(f'"{c}"' for c in line.split(",")) for line in paper_log.path.read_text().splitlines()]
    assert load_log(tmp_log(csv_text="\n".join(quoted) + "\n")) == paper_log
    assert load_log(tmp_log(csv_edit=lambda lines: lines + ["", ""])) == paper_log


def test_integral_float_pulse_and_tiny_time_jitter_accepted(tmp_log):
    log = load_log(tmp_log(csv_edit=edit_cell(10, "e2_pulses", "0.0")))
    assert log.e_pulses[8, 0] == 0
    log = load_log(tmp_log(csv_edit=edit_cell(10, "t_s", repr(8 * TS + 1e-12))))
    assert log.start_index == 0


def test_coulomb_ramp_speed_sources(tmp_log):
    def numeric_key(d):
        d["coulomb_ramp_speed_rad_per_s"] = 0.3
        d["coulomb_friction_note"] = "no speed here"

    assert load_log(tmp_log(json_edit=numeric_key)).rig.coulomb_ramp_speed_rad_per_s == 0.3

    def zero_coulomb(d):
        del d["coulomb_friction_note"]
        d["coulomb_friction_Nm"] = [[0.0, 0.0], [0.0, 0.0]]

    assert load_log(tmp_log(json_edit=zero_coulomb)).rig.coulomb_ramp_speed_rad_per_s == 1.0


def test_optional_keys(tmp_log):
    def edit(d):
        d["payload"] = {"mass_kg": None}
        d["current_full_scale_A"] = None

    rig = load_log(tmp_log(json_edit=edit)).rig
    assert rig.payload_mass_kg is None and rig.current_full_scale_A is None
    rig = load_log(tmp_log(json_edit=lambda d: d.pop("current_full_scale_A"))).rig
    assert rig.current_full_scale_A is None


# ------------------------------------------------------------------ bad inputs: files
def test_missing_csv(tmp_log):
    p = tmp_log(write_csv=False)
    expect_log_error(p, "log file not found", ".csv")


def test_missing_sidecar(tmp_log):
    p = tmp_log(write_json=False)
    expect_log_error(p, "sidecar not found", ".json")


def test_unreadable_csv_is_directory(tmp_log):
    p = tmp_log(write_csv=False)
    p.mkdir()
    expect_log_error(p, "log file is a directory")


def test_non_utf8_csv(tmp_log):
    p = tmp_log(write_csv=False)
    p.write_bytes(b"t_s,q2\xff\n")
    expect_log_error(p, "not UTF-8")


def test_invalid_json(tmp_log):
    expect_log_error(tmp_log(json_text='{"sample_time_s": 0.0007,'), "invalid JSON at line 1")


def test_empty_sidecar(tmp_log):
    expect_log_error(tmp_log(json_text=""), "empty sidecar")


def test_sidecar_not_object(tmp_log):
    expect_log_error(tmp_log(json_text="[1, 2]"), "sidecar must be a JSON object")


def test_empty_csv(tmp_log):
    expect_log_error(tmp_log(csv_text=""), "empty file (no header row)")
    expect_log_error(tmp_log(csv_text="\n\n"), "empty file (no header row)")


def test_header_only_csv(tmp_log):
    expect_log_error(tmp_log(csv_text=",".join(COLUMNS) + "\n"), "no data rows (header only)")


# -------------------------------------------------------------------- bad inputs: CSV
def _drop_column(name):
    i = COLUMNS.index(name)

    def edit(lines):
        return [",".join(c for j, c in enumerate(line.split(",")) if j != i) for line in lines]

    return edit


def test_missing_column(tmp_log):
    expect_log_error(tmp_log(csv_edit=_drop_column("i3_A")), "line 1", "missing column(s) 'i3_A'")


def test_extra_column(tmp_log):
    def edit(lines):
        return [lines[0] + ",temp_C"] + [line + ",20.0" for line in lines[1:]]

    expect_log_error(tmp_log(csv_edit=edit), "unexpected column(s) 'temp_C'")


def test_renamed_column(tmp_log):
    def edit(lines):
        lines[0] = lines[0].replace("e2_pulses", "e2_pulse")
        return lines

    expect_log_error(tmp_log(csv_edit=edit), "missing column(s) 'e2_pulses'", "unexpected column(s) 'e2_pulse'")


def test_duplicate_column(tmp_log):
    def edit(lines):
        lines[0] = lines[0].replace("i3_A", "i2_A")
        return lines

    expect_log_error(tmp_log(csv_edit=edit), "duplicate column 'i2_A'")


@pytest.mark.parametrize("quoted", [False, True])
def test_ragged_rows(tmp_log, quoted):
    def short(lines):
        lines[100] = lines[100].rsplit(",", 1)[0]
        return lines

    def long(lines):
        lines[200] = lines[200] + ",1.0"
        return lines

    def quote(lines):
        return [",".join(f'"{c}"' for c in line.split(",")) for line in lines] if quoted else lines

    expect_log_error(tmp_log(csv_edit=lambda ls: quote(short(ls))), "line 101", "ragged row with 6 fields, expected 7")
    expect_log_error(tmp_log(csv_edit=lambda ls: quote(long(ls))), "line 201", "ragged row with 8 fields, expected 7")


def test_blank_line_inside(tmp_log):
    def edit(lines):
        lines[50] = ""
        return lines

    expect_log_error(tmp_log(csv_edit=edit), "line 51", "empty row")


@pytest.mark.parametrize(
    "column, value, fragment",
    [
        ("q2_ref_rad", "abc", "non-numeric value 'abc'"),
        ("i3_A", "", "non-numeric value ''"),
        ("t_s", "1_0", "non-numeric value '1_0'"),
        ("i2_A", "nan", "non-finite value 'nan'"),
        ("i2_A", "NaN", "non-finite value 'NaN'"),
        ("q3_ref_rad", "inf", "non-finite value 'inf'"),
        ("i3_A", "-Infinity", "non-finite value '-Infinity'"),
        ("e3_pulses", "1e400", "non-finite value '1e400'"),
        ("e2_pulses", "3.5", "non-integer pulse value '3.5'"),
        ("e3_pulses", "-0.25", "non-integer pulse value '-0.25'"),
        ("e2_pulses", "nan", "non-finite value 'nan'"),
    ],
)
def test_bad_values(tmp_log, column, value, fragment):
    expect_log_error(tmp_log(csv_edit=edit_cell(42, column, value)), "line 42", f"column '{column}'", fragment)


def test_bad_value_in_quoted_csv(tmp_log):
    def edit(lines):
        lines = edit_cell(42, "i2_A", "x1")(lines)
        return [",".join(f'"{c}"' for c in line.split(",")) for line in lines]

    expect_log_error(tmp_log(csv_edit=edit), "line 42", "column 'i2_A'", "non-numeric value 'x1'")


def test_time_not_on_sample_grid(tmp_log):
    expect_log_error(
        tmp_log(csv_edit=edit_cell(30, "t_s", repr(28 * TS + 1e-6))), "line 30", "column 't_s'", "is not k*Ts", "expected 0.0196 "
    )


def test_time_gap(tmp_log):
    def edit(lines):
        del lines[500]  # a missing sample: t jumps by 2 Ts
        return lines

    def side(d):
        d["n_samples"] -= 1

    expect_log_error(tmp_log(csv_edit=edit, json_edit=side), "line 501", "is not k*Ts")


def test_first_time_off_grid_and_negative(tmp_log):
    expect_log_error(tmp_log(csv_edit=edit_cell(2, "t_s", "0.0003")), "line 2", "t = 0.0003 s is not k*Ts")
    expect_log_error(tmp_log(csv_edit=edit_cell(2, "t_s", "-0.0007")), "line 2", "negative time")


def test_trajectory_does_not_match_reference_columns(tmp_log):
    msg = expect_log_error(
        tmp_log(json_edit=lambda d: set_key(d, "trajectory.parameters.c", [-0.785, 0.7853981633974483])),
        "trajectory in sidecar does not match q*_ref_rad columns",
    )
    assert "column 'q2_ref_rad'" in msg
    expect_log_error(
        tmp_log(csv_edit=edit_cell(1000, "q3_ref_rad", "0.1")),
        "trajectory in sidecar does not match q*_ref_rad columns",
        "line 1000",
        "column 'q3_ref_rad'",
    )


def test_ramped_reference_without_ramp_in_sidecar(tmp_log):
    expect_log_error(
        tmp_log(VALIDATION_RIGID, json_edit=lambda d: set_key(d, "trajectory.parameters.t_ramp_s", 0.0)),
        "trajectory in sidecar does not match",
    )


# ---------------------------------------------------------------- bad inputs: sidecar
REQUIRED_KEYS = [
    "sample_time_s",
    "n_samples",
    "gear_ratio",
    "encoder_ppr",
    "p_gain_A_per_pulse",
    "torque_constant_Nm_per_A",
    # the friction keys may be absent or null: unknown (tests/test_unknown_friction.py)
    "gravity_m_s2",
    "a3_m",
    "start_state",
    "start_state.q_rad",
    "start_state.qd_rad_per_s",
    "f_search_ranges",
    "f_search_ranges.f1",
    "f_search_ranges.f9",
    "trajectory",
    "trajectory.parameters",
    "trajectory.parameters.c",
    "trajectory.parameters.terms_A_omega_phi",
]


@pytest.mark.parametrize("key", REQUIRED_KEYS)
def test_missing_sidecar_key(tmp_log, key):
    expect_log_error(tmp_log(json_edit=lambda d: del_key(d, key)), f"key '{key}' is missing")


def test_missing_coulomb_ramp_speed(tmp_log):
    expect_log_error(
        tmp_log(json_edit=lambda d: del_key(d, "coulomb_friction_note")),
        "key 'coulomb_ramp_speed_rad_per_s' is missing",
    )
    expect_log_error(
        tmp_log(json_edit=lambda d: set_key(d, "coulomb_friction_note", "ramps below some speed")),
        "key 'coulomb_ramp_speed_rad_per_s' is missing",
    )


@pytest.mark.parametrize(
    "key, value, fragment",
    [
        ("gear_ratio", [107.8, -53.7, 1.0], "key 'gear_ratio' must be a list of 2 numbers"),
        ("gear_ratio", 107.8, "key 'gear_ratio' must be a list of 2 numbers"),
        ("gear_ratio", [107.8, 0.0], "key 'gear_ratio[1]' must be nonzero"),
        ("encoder_ppr", [800], "key 'encoder_ppr' must be a list of 2 integers"),
        ("encoder_ppr", [800.5, 1000], "key 'encoder_ppr[0]' must be an integer"),
        ("encoder_ppr", [0, 1000], "key 'encoder_ppr[0]' must be > 0"),
        ("encoder_ppr", [800, -1000], "key 'encoder_ppr[1]' must be > 0"),
        ("sample_time_s", 0.0, "key 'sample_time_s' must be > 0"),
        ("sample_time_s", -0.0007, "key 'sample_time_s' must be > 0"),
        ("sample_time_s", "0.0007", "key 'sample_time_s' must be a number"),
        ("sample_time_s", True, "key 'sample_time_s' must be a number"),
        ("torque_constant_Nm_per_A", [0.22, 0.0], "key 'torque_constant_Nm_per_A[1]' must be > 0"),
        ("torque_constant_Nm_per_A", [-0.22, 0.22], "key 'torque_constant_Nm_per_A[0]' must be > 0"),
        ("p_gain_A_per_pulse", [0.15, 0.0], "key 'p_gain_A_per_pulse[1]' must be > 0"),
        ("viscous_friction_Nms_per_rad", [-0.1, 0.0], "key 'viscous_friction_Nms_per_rad[0]' must be >= 0"),
        ("coulomb_friction_Nm", [0.071, 0.126], "key 'coulomb_friction_Nm[0]' must be a list of 2 numbers"),
        ("coulomb_friction_Nm", [[0.1, 0.2, 0.3], [0.1, 0.2]], "key 'coulomb_friction_Nm[0]' must be a list of 2"),
        ("coulomb_friction_Nm", [[0.1, 0.2]], "key 'coulomb_friction_Nm' must be [[pos, neg], [pos, neg]]"),
        ("coulomb_friction_Nm", [[0.1, 0.2], [0.1, -0.2]], "key 'coulomb_friction_Nm[1][1]' must be >= 0"),
        ("coulomb_ramp_speed_rad_per_s", 0.0, "key 'coulomb_ramp_speed_rad_per_s' must be > 0"),
        ("gravity_m_s2", float("nan"), "key 'gravity_m_s2' must be finite"),
        ("a3_m", float("inf"), "key 'a3_m' must be finite"),
        ("start_state.q_rad", [0.0], "key 'start_state.q_rad' must be a list of 2 numbers"),
        ("start_state.qd_rad_per_s", [0.0, None], "key 'start_state.qd_rad_per_s[1]' must be a number"),
        ("start_state", [0.0, 0.0], "key 'start_state' must be an object"),
        ("f_search_ranges", [[0, 1]] * 9, "key 'f_search_ranges' must be an object"),
        ("f_search_ranges.f3", [0.2, -0.2], "key 'f_search_ranges.f3' is inverted"),
        ("f_search_ranges.f5", [0.4, 0.4], "key 'f_search_ranges.f5' is empty"),
        ("f_search_ranges.f7", [2.23], "key 'f_search_ranges.f7' must be a list of 2 numbers"),
        ("f_search_ranges.f8", [-1.75, float("nan")], "key 'f_search_ranges.f8[1]' must be finite"),
        ("f_search_ranges.f10", [0.0, 1.0], "key 'f_search_ranges.f10' is not one of f1..f9"),
        ("current_full_scale_A", 0.0, "key 'current_full_scale_A' must be > 0"),
        ("payload", 1.5, "key 'payload' must be null or an object"),
        ("payload", {"mass_kg": -1.0}, "key 'payload.mass_kg' must be >= 0"),
        ("n_samples", 5214, "key 'n_samples' is 5214 but"),
        ("n_samples", 5216, "has 5215 data rows"),
        ("n_samples", 5215.5, "key 'n_samples' must be an integer"),
        ("window_s", [1.0], "key 'window_s' must be a list of 2 numbers"),
        ("window_s", [1.0, 0.5], "key 'window_s' must be [start, stop] with start < stop"),
        ("window_s", [-1.0, 5.0], "key 'window_s' start must be >= 0"),
        ("window_s", [1.0, 5.0], "key 'window_s' [1.0, 5.0] does not contain the rows"),
        ("window_s", [0.0, 1.0], "does not contain the rows"),
        ("trajectory.parameters.t_ramp_s", -0.8, "key 'trajectory.parameters.t_ramp_s' must be finite and >= 0"),
        ("trajectory.parameters.c", [0.0], "key 'trajectory.parameters.c' must be a list of 2 numbers"),
    ],
)
def test_bad_sidecar_values(tmp_log, key, value, fragment):
    msg = expect_log_error(tmp_log(json_edit=lambda d: set_key(d, key, value)), fragment)
    assert ".json: " in msg


def test_rig_from_sidecar_directly(data_dir):
    side = json.loads((data_dir / f"{PAPER_RIGID}.json").read_text())
    rig = rig_from_sidecar(side)
    assert rig == load_log(data_dir / PAPER_RIGID).rig
    side["f_search_ranges"]["f2"] = [1.0, 0.0]
    with pytest.raises(LogError, match=r"^run\.json: key 'f_search_ranges\.f2' is inverted"):
        rig_from_sidecar(side, "run.json")
