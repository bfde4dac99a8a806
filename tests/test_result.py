"""Tests of :class:`identification.IdentificationResult` (issue 11, parts 5 and 6).

JSON round trip (``save_json`` -> ``load_json``), clear errors for bad files,
a short ``repr``, plot helpers that accept ``ax=``/``fig=`` and return what
they drew into, and one output error for one f: the plot title's number is
``fun`` at the identification's setting, and says which setting it is.
"""
from __future__ import annotations

import json
import re

import numpy as np
import pytest
from matplotlib.figure import Figure

import plant
from identification import IdentificationResult
from identification.objective import OutputError
from identification.result import ResultFileError

WINDOW = (1.0, 1.15)  # a short window of the paper log keeps every simulation fast
TITLE_Y = re.compile(r"output error Y \(eq\. 4\) = ([0-9.eE+-]+) pulses")


@pytest.fixture(scope="module")
def small_log(paper_log):
    return paper_log.window(*WINDOW)


@pytest.fixture(scope="module")
def f_true(truth):
    return np.array(truth("puma560_paper_rigid")["f_vector"], dtype=float)


def make_result(log, f, *, substeps=1, lowpass_hz=None, payload=None, rng_seed=0, **extra):
    """A result with the new vocabulary, fun computed like identify() does."""
    rng = np.random.default_rng(rng_seed)
    pop = f * (1 + 0.05 * rng.standard_normal((12, 9)))
    objective = OutputError(log, substeps=substeps, lowpass_hz=lowpass_hz, workers=1)
    energies = objective(pop)
    fun = float(objective(f[None])[0])
    bounds = np.column_stack([f - np.abs(f), f + np.abs(f) + 0.1])
    keys = dict(
        x=f.copy(), f=f.copy(), fun=fun, nfev=int(objective.nfev), nit=3,
        success=True, message="test result", population=pop, population_energies=energies,
        method="paper", seed=7,
        history={"generation": np.arange(4), "best": np.array([9e4, 5e3, 2e3, fun]),
                 "mean": np.array([2e5, 8e4, 6e4, 5e4]), "nfev": np.array([12, 24, 36, 48])},
        refinement=None, wall_time_s=1.25, compile_time_s=0.5, interrupted=False,
        log_name=log.name, log=log, bounds=bounds, x_names=list(plant.F_NAMES),
        parameters="base",
        settings={"substeps": substeps, "lowpass_hz": lowpass_hz, "ga": {"n_gen": 3}},
    )
    if payload is not None:
        keys["payload"] = payload
    keys.update(extra)
    return IdentificationResult(**keys)


def title_y(text):
    m = TITLE_Y.search(text)
    assert m, text
    return float(m.group(1))


# --------------------------------------------------------------------- JSON round trip
def assert_same_result(a, b):
    np.testing.assert_array_equal(a.f, b.f)
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.bounds, b.bounds)
    for key in ("fun", "nfev", "nit", "success", "message", "method", "seed", "interrupted",
                "log_name", "x_names", "parameters", "wall_time_s", "compile_time_s",
                "settings"):
        assert a[key] == b[key], key
    assert set(a.history) == set(b.history)
    for k in a.history:
        np.testing.assert_array_equal(a.history[k], b.history[k])
        assert isinstance(b.history[k], np.ndarray)


def test_json_round_trip(small_log, f_true, tmp_path):
    res = make_result(small_log, f_true * 1.01)
    path = tmp_path / "res.json"
    res.save_json(path)
    back = IdentificationResult.load_json(path)
    assert isinstance(back, IdentificationResult)
    assert_same_result(res, back)
    assert isinstance(back.f, np.ndarray) and back.f.shape == (9,)
    assert isinstance(back.bounds, np.ndarray) and back.bounds.shape == (9, 2)
    assert back.log is None and back.population is None and back.population_energies is None
    # a second save of the loaded result writes the same file
    back.save_json(tmp_path / "again.json")
    assert (tmp_path / "again.json").read_text() == path.read_text()


def test_json_contract_keys(small_log, f_true, tmp_path):
    res = make_result(small_log, f_true)
    d = json.loads(res.save_json(tmp_path / "r.json").target.read_text())
    assert d["f"] == [float(v) for v in f_true]
    assert d["objective_pulses2"] == d["fun"] == res.fun
    assert d["evaluations"] == d["nfev"] == res.nfev
    assert d["settings"]["substeps"] == 1 and "lowpass_hz" in d["settings"]
    assert "1 RK4 step/sample (identification)" in d["setting"]
    assert list(d["f_named"]) == list(plant.F_NAMES) and list(d["f_units"].values()) == list(
        plant.F_UNITS)
    for gone in ("population", "population_energies", "population_objective", "objective"):
        assert gone not in d


def test_round_trip_payload_refinement_and_nonfinite(small_log, f_true, tmp_path):
    payload = {"mass_kg": 1.5, "com_m": [0.1, -0.02], "izz_kgm2": 0.01,
               "vector": [1.5, 0.15, -0.03, 0.0266], "vector_names": ["m", "mx", "my", "J"]}
    refinement = {"start_costs": np.array([900.0, np.inf]), "costs": np.array([860.0, 870.0]),
                  "fun": 860.0, "nfev": 33, "ga_f": f_true}
    res = make_result(small_log, f_true, payload=payload, refinement=refinement,
                      parameters="payload", x=np.array([1.5, 0.1, -0.02, 0.01]),
                      x_names=["m", "xp", "yp", "Jc"], bounds=np.array([[0, 5], [-1, 1],
                                                                         [-1, 1], [0, 0.05]]))
    path = tmp_path / "p.json"
    res.save_json(path)
    d = json.loads(path.read_text())
    assert d["payload_mass_kg"] == 1.5 and d["refinement"]["start_costs"][1] is None
    back = IdentificationResult.load_json(path)
    assert_same_result(res, back)
    assert back.payload == payload
    np.testing.assert_array_equal(back.refinement["costs"], refinement["costs"])
    assert np.isnan(back.refinement["start_costs"][1])  # inf was written as null
    np.testing.assert_array_equal(back.refinement["ga_f"], f_true)
    assert back.refinement["nfev"] == 33


def test_older_result_file_loads(tmp_path):
    """A file of the previous contract (no fun/nfev/x keys) is still readable."""
    f = list(np.linspace(0.1, 0.9, 9))
    old = {"f": f, "objective_pulses2": 1175.0, "evaluations": 321, "method": "paper",
           "seed": 0, "log": "x", "interrupted": False, "message": "m", "wall_time_s": 2.0,
           "bounds": [[0, 1]] * 9, "settings": {"substeps": 1, "lowpass_hz": None},
           "history": {"best": [3.0, None]}, "refinement": None}
    p = tmp_path / "old.json"
    p.write_text(json.dumps(old))
    back = IdentificationResult.load_json(p)
    assert back.fun == 1175.0 and back.nfev == 321 and back.f.tolist() == f
    assert back.x.tolist() == f and back.x_names == list(plant.F_NAMES)
    assert np.isnan(back.history["best"][1])


@pytest.mark.parametrize("case, content, word", [
    ("missing", None, "not found"),
    ("directory", "DIR", "directory"),
    ("invalid", "{not json", "invalid JSON at line 1"),
    ("list", "[1, 2]", "JSON object"),
    ("no f", json.dumps({"fun": 1.0, "nfev": 1, "method": "paper"}), "'f'"),
    ("no fun", json.dumps({"f": [1.0] * 9, "nfev": 1, "method": "paper"}), "'fun'"),
    ("no method", json.dumps({"f": [1.0] * 9, "fun": 1.0, "nfev": 1}), "'method'"),
    ("short f", json.dumps({"f": [1.0] * 8, "fun": 1.0, "nfev": 1, "method": "p"}), "shape"),
    ("text f", json.dumps({"f": ["a"] * 9, "fun": 1.0, "nfev": 1, "method": "p"}), "numbers"),
    ("bad fun", json.dumps({"f": [1.0] * 9, "fun": "x", "nfev": 1, "method": "p"}), "'fun'"),
])
def test_load_json_errors_are_one_line(case, content, word, tmp_path):
    p = tmp_path / "r.json"
    if content == "DIR":
        p.mkdir()
    elif content is not None:
        p.write_text(content)
    with pytest.raises(ResultFileError) as exc:
        IdentificationResult.load_json(p)
    msg = str(exc.value)
    assert "\n" not in msg and str(p) in msg and word in msg, msg
    assert isinstance(exc.value, ValueError)


# ---------------------------------------------------------------------------- repr
def test_repr_is_short_and_summarises_arrays(small_log, f_true):
    res = make_result(small_log, f_true, population=np.tile(f_true, (80, 1)),
                      population_energies=np.arange(80.0))
    text = repr(res)
    lines = text.splitlines()
    assert 4 <= len(lines) <= 15, text
    assert all(len(ln) < 200 for ln in lines), text
    assert "array(80, 9)" in text  # the population is summarised, not printed
    assert f"{res.fun:.6g}" in text and "1 RK4 step/sample (identification)" in text
    assert "nfev" in text and "nit" in text and "paper" in text and "test result" in text
    assert str(res) == text


def test_one_name_per_quantity(small_log, f_true):
    """scipy's vocabulary only: no duplicated keys for the same quantity."""
    res = make_result(small_log, f_true)
    for old in ("objective", "evaluations", "population_objective", "x_best"):
        assert old not in res and not hasattr(res, old)


# ---------------------------------------------------------------------------- plots
def test_plot_accepts_ax_and_fig(small_log, f_true):
    res = make_result(small_log, f_true)
    fig = Figure()
    ax = fig.subplots()
    assert res.plot(ax=ax) is ax
    assert len(ax.get_lines()) == 2 and f"{res.fun:.6g}" in ax.get_title()
    fig2 = Figure()
    assert res.plot(fig=fig2) is fig2 and len(fig2.axes) == 1
    assert isinstance(res.plot(), Figure)


def test_tracking_errors_title_equals_fun_at_identification_setting(small_log, f_true):
    f = f_true * 1.02  # not the truth: a nonzero output error
    res = make_result(small_log, f, substeps=1)
    fig = res.plot_tracking_errors()
    title = fig._suptitle.get_text()
    assert title_y(title) == pytest.approx(res.fun, rel=1e-6) and res.fun > 0
    assert "1 RK4 step/sample (identification)" in title
    # pair of axes: returned as given, the title goes on the first one
    axes = Figure().subplots(2, 1)
    assert res.plot_tracking_errors(ax=axes) is axes
    assert title_y(axes[0].get_title()) == pytest.approx(res.fun, rel=1e-6)
    # logged, model and their residual per joint
    assert len(axes[0].get_lines()) == len(axes[1].get_lines()) == 3
    one = Figure().subplots()
    assert res.plot_tracking_errors(ax=one) is one and len(one.get_lines()) == 6
    # its own figure: an overlay and a residual panel per joint, integer pulse ticks
    assert len(fig.axes) == 4
    ticks = fig.axes[1].get_yticks()
    assert np.allclose(ticks, np.round(ticks))


def test_exact_reproduction_title_says_so(small_log, f_true):
    f = f_true * 1.02
    res = make_result(small_log, f, substeps=1)
    ax = Figure().subplots()
    res.plot_tracking_errors(substeps=plant.DEFAULT_SUBSTEPS, ax=ax)
    title = ax.get_title()
    exact = OutputError(small_log, substeps=plant.DEFAULT_SUBSTEPS, workers=1)(f[None])[0]
    assert title_y(title) == pytest.approx(exact, rel=1e-6)
    assert f"exact reproduction, {plant.DEFAULT_SUBSTEPS} RK4 steps/sample" in title
    assert "identification" not in title


def test_lowpass_title_equals_fun(small_log, f_true):
    f = f_true * 1.02
    res = make_result(small_log, f, substeps=2, lowpass_hz=40.0)
    ax = Figure().subplots()
    res.plot_tracking_errors(ax=ax)
    title = ax.get_title()
    assert title_y(title) == pytest.approx(res.fun, rel=1e-6)
    assert "2 RK4 steps/sample (identification), low-passed at 40 Hz" in title


def test_validation_log_and_missing_log(small_log, paper_log, f_true, tmp_path):
    res = make_result(small_log, f_true * 1.01)
    other = paper_log.window(2.0, 2.1)
    fig = res.plot_tracking_errors(other)
    y = OutputError(other, substeps=1, workers=1)(res.f[None])[0]
    assert title_y(fig._suptitle.get_text()) == pytest.approx(y, rel=1e-6)
    res.save_json(tmp_path / "r.json")
    back = IdentificationResult.load_json(tmp_path / "r.json")
    with pytest.raises(ValueError, match="pass one"):
        back.plot_tracking_errors()
    ax = Figure().subplots()
    back.plot_tracking_errors(small_log, ax=ax)  # a loaded result plots with a given log
    assert title_y(ax.get_title()) == pytest.approx(res.fun, rel=1e-6)


def test_identify_fun_equals_plot_title(small_log):
    """End to end: identify()'s fun is the number in the tracking-error title."""
    from identification import identify

    res = identify(small_log, method="paper", rng=1, progress=False, workers=1,
                   ga_options={"n_gen": 1, "n_ind": 10})
    ax = Figure().subplots()
    res.plot_tracking_errors(ax=ax)
    assert title_y(ax.get_title()) == pytest.approx(res.fun, rel=1e-9)
    assert f"{res.fun:.6g}" in repr(res)


def test_save_json_missing_directory_created_and_reported(small_log, f_true, tmp_path):
    from plant.logs.fileio import OutputFileError

    res = make_result(small_log, f_true)
    path = tmp_path / "a" / "b" / "r.json"
    with pytest.raises(OutputFileError, match="does not exist"):
        res.save_json(path, create_dirs=False)
    assert list(tmp_path.iterdir()) == []
    info = res.save_json(path)
    assert info.created_dirs == (tmp_path / "a", tmp_path / "a" / "b")
    assert IdentificationResult.load_json(path).fun == res.fun
