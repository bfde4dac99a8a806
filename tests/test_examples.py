"""Every example script runs from the library alone (``--quick``) and writes what it says.

Each script runs in a subprocess, from a scratch working directory (so no
relative path to the development data can help it), with ``PUMA_DATA_DIR``
pointing to an empty directory, its output in a tmp dir and the clone's
source tree first on ``PYTHONPATH``.  A bad option or log ends with one line
``error: ...`` and exit status 1, never a traceback.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
EXAMPLES = REPO / "examples"

#: script -> (files it writes into --out, extra quick arguments)
OUTPUTS = {
    "identify_paper_log.py": ("result.json", "convergence.png", "tracking_errors.png"),
    "ctc_vs_p.py": ("results.json", "errors.png", "currents.png", "robustness.png", "flex.png"),
    "real_rigs.py": ("results.json", "spectrum.png", "prior.json", "payload_result.json",
                     "payload_window_errors.png", "drill_window_1000_1200ms.csv",
                     "drill_window_1000_1200ms.json"),
    "alteration_study.py": ("alteration.json",),
    "online_payload.py": ("errors.png", "results.json"),
    "your_robot.py": ("base_parameters.json",),
    "any_arm.py": ("planar2.csv", "planar2.json", "planar2_result.json", "planar2_tracking.png"),
}


def _run(script, args, cwd, timeout=300):
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO)] + [p for p in
                                         env.get("PYTHONPATH", "").split(os.pathsep) if p])
    env["MPLBACKEND"] = "Agg"
    env["PUMA_DATA_DIR"] = str(cwd / "no_data_here")  # nothing to find there
    return subprocess.run([sys.executable, str(EXAMPLES / script), *args], cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=timeout)


def test_every_example_is_covered():
    assert sorted(p.name for p in EXAMPLES.glob("*.py")) == sorted(OUTPUTS)


@pytest.mark.parametrize("script", sorted(OUTPUTS))
def test_example_quick_run(script, tmp_path):
    out = tmp_path / "out"
    proc = _run(script, ["--quick", "--out", str(out)], cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr
    for name in OUTPUTS[script]:
        f = out / name
        assert f.is_file() and f.stat().st_size > 0, f"{script} did not write {name}"
        if name.endswith(".png"):
            assert f.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        if name.endswith(".json"):
            json.loads(f.read_text())
    assert str(out) in proc.stdout  # it says where the results went


def test_identify_example_result(tmp_path):
    """The quick identification still lands near the truth of the bundled log (read by the test)."""
    import numpy as np

    truth = json.loads((REPO / "tests" / "data" / "puma560_paper_rigid.truth.json").read_text())
    out = tmp_path / "out"
    proc = _run("identify_paper_log.py",
                ["--quick", "--out", str(out),
                 "--validate", str(REPO / "tests" / "data" / "puma560_validation_rigid.csv")],
                cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert (out / "tracking_errors_validation.png").is_file()
    assert "cross-validation on puma560_validation_rigid" in proc.stdout
    f = np.asarray(json.loads((out / "result.json").read_text())["f"])
    f_true = np.asarray(truth["f_vector"])
    well_excited = [0, 1, 3, 5, 6, 8]  # f1 f2 f4 f6 f7 f9
    assert np.all(np.abs(f - f_true)[well_excited] / np.abs(f_true)[well_excited] < 0.01)


def test_ctc_example_with_truth(tmp_path):
    """With --truth the robot is the true one and the table gains the true-f row."""
    out = tmp_path / "out"
    proc = _run("ctc_vs_p.py", ["--quick", "--no-flex", "--out", str(out), "--truth",
                                str(REPO / "tests" / "data" / "puma560_paper_rigid.truth.json")],
                cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    res = json.loads((out / "results.json").read_text())
    assert res["f_true"] is not None and res["f_robot"] == res["f_true"]
    names = [r["name"] for r in res["rigid"]]
    assert "CTC, true f" in names and res["flexible"] is None
    p, ctc_id = res["rigid"][0], res["rigid"][1]
    # CTC with the identified model tracks far closer than the paper's P control
    assert max(ctc_id["max_abs_after_50ms"]) < max(p["max_abs_after_50ms"]) / 5


@pytest.mark.parametrize("script, args, needle", [
    ("identify_paper_log.py", ["--log", "missing.csv"], "missing.csv"),
    ("ctc_vs_p.py", ["--truth", "missing.truth.json"], "missing.truth.json"),
    ("ctc_vs_p.py", ["--f-identified", "1,2,3"], "--f-identified"),
    ("real_rigs.py", ["--log", "missing.csv"], "missing.csv"),
    ("real_rigs.py", ["--truth", "bad.truth.json"], "bad.truth.json"),
    ("alteration_study.py", ["--truth", "missing.truth.json"], "missing.truth.json"),
    ("any_arm.py", ["--duration", "0.2"], "--duration"),
    ("any_arm.py", ["--pick-up", "20"], "--pick-up"),
    ("any_arm.py", ["--pick-up", "2", "--flexible"], "--pick-up"),
])
def test_example_bad_input_one_line(script, args, needle, tmp_path):
    (tmp_path / "bad.truth.json").write_text("{not json")
    proc = _run(script, [*args, "--out", str(tmp_path / "out")], cwd=tmp_path, timeout=120)
    assert proc.returncode == 1
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and needle in lines[0], proc.stderr


def test_any_arm_pick_up_compares_the_static_and_the_adaptive_ctc(tmp_path):
    """examples/any_arm.py --pick-up: a tool picked up mid-run; the adaptive CTC's report
    tracks within +-1 pulse from 0.5 s after where the static one does not (the library's own
    plant: a tutorial's run)."""
    out = tmp_path / "out"
    proc = _run("any_arm.py", ["--quick", "--pick-up", "2", "--out", str(out)], cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-3000:]
    pick = json.loads((out / "planar2_result.json").read_text())["pick_up"]
    assert max(pick["adaptive"]["max_abs_error_after_change_0p5s"]) <= 1
    assert max(pick["static"]["max_abs_error_after_change_0p5s"]) > 1
    assert abs(pick["adaptive"]["payload_history"][-1][1] - 2.0) < 0.04
