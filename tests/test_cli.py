"""Tests of the command line ``python -m identification`` (contract of issue 4).

Each case runs both as a subprocess (``[sys.executable, '-m',
'identification', ...]`` from the repository root, as a user would) and
in-process through ``identification.cli.main``.  Successful runs use
``--method paper --generations 2``: the plumbing is the point here, the
accuracy is tested in ``test_identify.py``.
"""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

import plant
from identification.cli import main

REPO = Path(__file__).resolve().parents[1]
QUICK = ["--method", "paper", "--generations", "2"]
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def run_cli(args, timeout=120):
    """Run ``python -m identification ARGS`` from the repository root."""
    return subprocess.run(
        [sys.executable, "-m", "identification", *map(str, args)],
        cwd=REPO, capture_output=True, text=True, timeout=timeout,
    )


def run_main(args, capsys):
    """Run ``main(ARGS)`` in-process; return (status, stdout, stderr)."""
    status = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return status, out, err


def assert_one_error_line(status, stderr, stdout=""):
    assert status != 0
    lines = stderr.strip().splitlines()
    assert len(lines) == 1, stderr
    assert lines[0].startswith("error: "), stderr
    assert "Traceback" not in stderr
    assert stdout == ""


def check_result_file(path, method="paper", seed=0):
    d = json.loads(Path(path).read_text())
    for key in ("f", "objective_pulses2", "evaluations", "wall_time_s", "method", "seed"):
        assert key in d, key
    assert len(d["f"]) == 9 and all(isinstance(v, float) for v in d["f"])
    assert np.isfinite(d["objective_pulses2"]) and d["objective_pulses2"] > 0
    assert isinstance(d["evaluations"], int) and d["evaluations"] > 0
    assert d["wall_time_s"] > 0
    assert d["method"] == method and d["seed"] == seed
    return d


def check_table(stdout):
    for name, unit in zip(plant.F_NAMES, plant.F_UNITS):
        assert any(line.split()[:1] == [name] and line.rstrip().endswith(unit)
                   for line in stdout.splitlines()), (name, stdout)
    assert "output error" in stdout and "pulses^2" in stdout


# ------------------------------------------------------------------------- success
def test_subprocess_run_writes_result_and_plots(tmp_path):
    out, plots = tmp_path / "res" / "out.json", tmp_path / "plots"
    r = run_cli([plant.example_log_path(), "--seed", "3", "--output", out, "--plot", plots,
                 "--quiet", *QUICK])
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    check_table(r.stdout)
    d = check_result_file(out, seed=3)
    assert d["interrupted"] is False
    assert len(d["history"]["best"]) == 3  # --generations 2
    for name in ("convergence.png", "tracking_errors.png"):
        data = (plots / name).read_bytes()
        assert data.startswith(PNG_MAGIC) and len(data) > 10_000
    # the printed f is the written f
    printed = {ln.split()[0]: float(ln.split()[1]) for ln in r.stdout.splitlines()
               if ln.split()[:1] and ln.split()[0] in plant.F_NAMES}
    assert np.allclose([printed[n] for n in plant.F_NAMES], d["f"], rtol=1e-5)


def test_in_process_example_is_reproducible(tmp_path, capsys):
    a, b = tmp_path / "a.json", tmp_path / "b.json"
    s1, out1, err1 = run_main(["--example", "--output", a, *QUICK], capsys)
    s2, out2, _ = run_main(["--example", "--output", b, "--quiet", *QUICK], capsys)
    assert s1 == s2 == 0
    check_table(out1)
    assert "GA" in err1  # the tqdm progress bar (absent with --quiet)
    da, db = check_result_file(a), check_result_file(b)
    assert da["f"] == db["f"] and da["objective_pulses2"] == db["objective_pulses2"]
    assert da["history"] == db["history"]
    assert out1 == out2.replace(f"wall time: {db['wall_time_s']:.2f}",
                                f"wall time: {da['wall_time_s']:.2f}")


class _Stop(Exception):
    """Raised by the spies below instead of running an identification."""


def test_options_are_passed_to_identify(monkeypatch, capsys):
    import identification.api

    seen = {}

    def spy(log, **kw):
        seen.update(kw, log=log)
        raise _Stop

    monkeypatch.setattr(identification.api, "identify", spy)
    with pytest.raises(_Stop):
        main(["--example", "--seed", "5", "--method", "paper", "--generations", "7",
              "--workers", "1", "--lowpass", "45", "--quiet"])
    assert seen["log"].name == "puma560_paper_rigid"
    assert seen["rng"] == 5 and seen["method"] == "paper"
    assert seen["ga_options"] == {"n_gen": 7}
    assert seen["workers"] == 1 and seen["lowpass_hz"] == 45.0
    assert seen["progress"] is False
    assert "payload" not in seen and "prior" not in seen
    seen.clear()
    with pytest.raises(_Stop):
        main(["--example"])
    assert seen["method"] == "ga+pem" and seen["rng"] == 0 and seen["progress"] is True
    assert seen["lowpass_hz"] is None and "ga_options" not in seen


def test_payload_and_prior_are_wired(monkeypatch, tmp_path, capsys):
    """--payload --prior P.json passes payload=True and prior=P's f (spy identify)."""
    import identification.api

    f = [0.9, 0.35, 0.01, -0.4, 0.03, -0.9, 4.5, -0.1, 3.8]
    prior = tmp_path / "prior.json"
    prior.write_text(json.dumps({"f": f, "method": "ga+pem"}))
    seen = {}

    def spy(log, *, payload=False, prior=None, **kw):
        seen.update(payload=payload, prior=prior)
        raise _Stop

    monkeypatch.setattr(identification.api, "identify", spy)
    with pytest.raises(_Stop):
        main(["--example", "--payload", "--prior", str(prior), "--quiet"])
    assert seen["payload"] is True
    assert isinstance(seen["prior"], np.ndarray) and seen["prior"].tolist() == f


def test_payload_end_to_end(tmp_path, capsys, paper_log, truth):
    """--payload --prior on a window of a loaded run writes payload_mass_kg (within 5 %)."""
    import dataclasses

    import plant

    f0 = np.array(truth("puma560_paper_rigid")["f_vector"])
    f_loaded = np.array(truth("puma560_paper_drill_flex")["f_vector"])  # rigid-equivalent
    e = plant.simulate_experiment(paper_log, f_loaded)
    p_gain = np.array(paper_log.rig.p_gain_A_per_pulse)
    loaded = paper_log.replace(e_pulses=e, i_A=e * p_gain,
                               rig=dataclasses.replace(paper_log.rig, payload_mass_kg=None))
    window = loaded.window(1.0, 1.2).save(tmp_path / "loaded_window")
    prior = tmp_path / "prior.json"
    prior.write_text(json.dumps({"f": f0.tolist()}))
    out = tmp_path / "payload.json"
    status, stdout, err = run_main([str(window), "--payload", "--prior", str(prior),
                                    "-o", str(out), "--quiet"], capsys)
    assert status == 0, err
    res = json.loads(out.read_text())
    assert abs(res["payload_mass_kg"] - 1.5) < 0.05 * 1.5
    assert len(res["f"]) == 9 and "payload" in stdout


# ---------------------------------------------------------------------- Ctrl-C
def test_keyboard_interrupt_still_writes_the_result(ctrl_c_at_objective_call, tmp_path, capsys):
    ctrl_c_at_objective_call(3)  # initial population, generation 1, then Ctrl-C
    out = tmp_path / "out.json"
    status, stdout, _ = run_main(["--example", "-o", out, "--quiet", "--generations", "20"],
                                 capsys)
    assert status == 130
    assert "INTERRUPTED" in stdout
    d = check_result_file(out, method="ga+pem")
    assert d["interrupted"] is True and "KeyboardInterrupt" in d["message"]
    assert len(d["history"]["best"]) == 2


def test_keyboard_interrupt_before_any_result(monkeypatch, tmp_path, capsys):
    import identification.api

    def interrupted(log, **kw):
        raise KeyboardInterrupt

    monkeypatch.setattr(identification.api, "identify", interrupted)
    out = tmp_path / "out.json"
    status, _, err = run_main(["--example", "-o", out, "--quiet"], capsys)
    assert status == 130
    assert_one_error_line(status, err)
    assert not out.exists()


@pytest.mark.skipif(os.name != "posix", reason="SIGINT delivery to a child (POSIX)")
def test_sigint_to_the_subprocess_writes_the_interrupted_result(tmp_path):
    out = tmp_path / "out.json"
    proc = subprocess.Popen(
        [sys.executable, "-m", "identification", "--example", "--method", "paper",
         "--generations", "1000", "-o", str(out)],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    err_chunks, started = [], threading.Event()

    def read_stderr():
        for chunk in iter(lambda: proc.stderr.read(1), ""):
            err_chunks.append(chunk)
            if "gen/s" in "".join(err_chunks[-200:]):  # tqdm: the GA is iterating
                started.set()

    reader = threading.Thread(target=read_stderr, daemon=True)
    reader.start()
    try:
        assert started.wait(60), "".join(err_chunks)
        time.sleep(0.3)
        proc.send_signal(signal.SIGINT)
        stdout = proc.stdout.read()
        status = proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    reader.join(5)
    stderr = "".join(err_chunks)
    assert status == 130, stderr
    assert "Traceback" not in stderr
    assert "INTERRUPTED" in stdout
    assert "Ctrl-C" in stderr
    d = check_result_file(out)
    assert d["interrupted"] is True and "Ctrl-C" in d["message"]
    assert 1 <= len(d["history"]["best"]) - 1 < 1000


# -------------------------------------------------------------------- bad input
def _drop_column(lines, name="i3_A"):
    ci = lines[0].split(",").index(name)
    return [",".join(c for j, c in enumerate(ln.split(",")) if j != ci) for ln in lines]


def _set_cell(lines, row, name, value):
    ci = lines[0].split(",").index(name)
    cells = lines[row].split(",")
    cells[ci] = value
    lines[row] = ",".join(cells)
    return lines


def _invert_range(side):
    side["f_search_ranges"]["f3"] = side["f_search_ranges"]["f3"][::-1]


BAD_LOGS = {
    "nan": dict(csv_edit=lambda ls: _set_cell(ls, 100, "e2_pulses", "nan")),
    "missing column": dict(csv_edit=_drop_column),
    "ragged row": dict(csv_edit=lambda ls: ls[:50] + [ls[50].rsplit(",", 1)[0]] + ls[51:]),
    "fractional pulses": dict(csv_edit=lambda ls: _set_cell(ls, 200, "e3_pulses", "2.5")),
    "missing sidecar": dict(write_json=False),
    "empty file": dict(csv_text=""),
    "inverted search range": dict(json_edit=_invert_range),
    "wrong sample time": dict(json_edit=lambda side: side.update(sample_time_s=0.001)),
}
BAD_WORDS = {  # a word the one-line message must contain
    "nan": "non-finite", "missing column": "missing column", "ragged row": "ragged",
    "fractional pulses": "non-integer", "missing sidecar": "not found",
    "empty file": "empty", "inverted search range": "f3", "wrong sample time": "k*Ts",
    "missing file": "not found",
}


@pytest.fixture(params=[*BAD_LOGS, "missing file"])
def bad_log(request, tmp_log, tmp_path):
    """(case, path of a broken log)."""
    case = request.param
    if case == "missing file":
        return case, tmp_path / "no_such_log.csv"
    return case, tmp_log(**BAD_LOGS[case])


def test_bad_log_subprocess(bad_log, tmp_path):
    case, path = bad_log
    out, plots = tmp_path / "out.json", tmp_path / "plots"
    r = run_cli([path, "--output", out, "--plot", plots, *QUICK])
    assert_one_error_line(r.returncode, r.stderr, r.stdout)
    assert r.returncode == 1
    assert BAD_WORDS[case] in r.stderr, r.stderr
    assert not out.exists() and not plots.exists()
    assert not list(tmp_path.glob("*.tmp")) and not list(tmp_path.glob(".out.json*"))


def test_bad_log_in_process(bad_log, tmp_path, capsys):
    case, path = bad_log
    out = tmp_path / "out.json"
    status, stdout, err = run_main([path, "--output", out, *QUICK], capsys)
    assert_one_error_line(status, err, stdout)
    assert BAD_WORDS[case] in err, err
    assert not out.exists()


@pytest.mark.parametrize("args, word", [
    (["--lowpass", "-5"], "--lowpass"),
    (["--lowpass", "5000"], "Nyquist"),
    (["--workers", "0"], "--workers"),
    (["--generations", "0"], "--generations"),
    (["--seed", "-1"], "--seed"),
    (["--payload"], "--prior"),
    (["--prior", "PRIOR"], "--payload"),
    (["--payload", "--prior", "MISSING"], "not found"),
    (["--payload", "--prior", "BADPRIOR"], "'f'"),
    (["LOG"], "either"),
    ([], "no log"),
])
def test_bad_options(args, word, tmp_path, capsys):
    out = tmp_path / "out.json"
    prior = tmp_path / "prior.json"
    prior.write_text(json.dumps({"f": [1.0] * 9}))
    bad_prior = tmp_path / "bad_prior.json"
    bad_prior.write_text(json.dumps({"f": [1.0] * 8}))
    subst = {"PRIOR": prior, "MISSING": tmp_path / "missing.json", "BADPRIOR": bad_prior,
             "LOG": plant.example_log_path()}
    args = [subst.get(a, a) for a in args]
    base = [] if args == [] else ["--example"]  # ["LOG"]: both a log and --example
    status, stdout, err = run_main([*base, *args, "--output", out], capsys)
    assert_one_error_line(status, err, stdout)
    assert word in err, err
    assert not out.exists()


@pytest.mark.parametrize("target", ["output", "plot"])
def test_unwritable_targets_fail_before_running(target, tmp_path, capsys):
    a_file = tmp_path / "file.txt"
    a_file.write_text("x")
    if target == "output":
        args = ["--output", tmp_path]  # a directory
    else:
        args = ["--output", tmp_path / "out.json", "--plot", a_file]
    status, stdout, err = run_main(["--example", *args], capsys)
    assert_one_error_line(status, err, stdout)
    assert not (tmp_path / "out.json").exists()


def test_bad_option_subprocess(tmp_path):
    out = tmp_path / "out.json"
    r = run_cli(["--example", "--lowpass", "0", "--output", out])
    assert_one_error_line(r.returncode, r.stderr, r.stdout)
    assert not out.exists()


def test_usage_errors_are_argparse_exit_2(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--example", "--method", "cma"])
    assert exc.value.code == 2
    with pytest.raises(SystemExit) as exc:
        main(["--example", "--seed", "zero"])
    assert exc.value.code == 2
    assert "Traceback" not in capsys.readouterr().err
