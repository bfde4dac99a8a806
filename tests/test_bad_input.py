"""Issue 22: the first hour of a new user -- every bad input named in the issue, exactly.

Each case asserts the one-line message (or ``success=False``), in the library
and on the command line, and never a traceback or a written result.
"""
from __future__ import annotations

import errno
import json

import numpy as np
import pytest

import identification
import plant
from identification.cli import main
from identification.uncertainty import PoorExcitationWarning
from plant.logs.sanity import check_experiment


def _cli(argv, capsys):
    status = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return status, out, err


def _one_error_line(status, err):
    assert status == 1, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    assert "Traceback" not in err
    return lines[0]


def _rewrite(paper_log, tmp_path, name, **changes):
    """The paper log with some arrays changed, saved as tmp_path/name.csv."""
    return paper_log.replace(**changes).save(tmp_path / name)


def test_a_two_sample_log_is_refused(paper_log, tmp_path, capsys):
    log = paper_log.replace(t=paper_log.t[:2], q_ref=paper_log.q_ref[:2],
                            e_pulses=paper_log.e_pulses[:2], i_A=paper_log.i_A[:2])
    with pytest.raises(plant.LogError, match="2 samples are too few to identify 9 parameters"):
        identification.identify(log, rng=0, progress=False)
    path = log.save(tmp_path / "two")
    line = _one_error_line(*_cli([path, "--seed", "0", "-o", tmp_path / "o.json"], capsys)[::2])
    assert "too few" in line and not (tmp_path / "o.json").exists()


def test_swapped_error_column_labels_are_refused(paper_log, tmp_path, capsys):
    path = paper_log.save(tmp_path / "swapped")
    text = path.read_text().splitlines()
    assert text[0] == "t_s,q2_ref_rad,q3_ref_rad,e2_pulses,e3_pulses,i2_A,i3_A"
    text[0] = "t_s,q2_ref_rad,q3_ref_rad,e3_pulses,e2_pulses,i2_A,i3_A"  # labels only
    path.write_text("\n".join(text) + "\n")
    log = plant.load_log(path)
    with pytest.raises(plant.LogError, match="disagrees with the rig's P law"):
        identification.identify(log, rng=0, progress=False)
    line = _one_error_line(*_cli([path, "--seed", "0"], capsys)[::2])
    assert "swapped" in line


def test_an_impossible_pulse_count_is_refused(paper_log, tmp_path, capsys):
    e = np.array(paper_log.e_pulses)
    e[1000, 0] = 123456789012
    path = _rewrite(paper_log, tmp_path, "huge", e_pulses=e)
    with pytest.raises(plant.LogError, match="e2_pulses = 123456789012 pulses at sample 1000"):
        identification.identify(plant.load_log(path), rng=0, progress=False)
    _one_error_line(*_cli([path, "--seed", "0"], capsys)[::2])


def test_a_single_spike_is_refused(paper_log):
    e = np.array(paper_log.e_pulses)
    e[2000, 1] += 5000  # within a joint turn, but no encoder moves that far in 0.7 ms
    with pytest.raises(plant.LogError, match="e3_pulses jumps by 5000 pulses at sample 2000"):
        check_experiment(paper_log.replace(e_pulses=e), n_parameters=9)


def test_all_zero_signals_are_refused(paper_log, tmp_path, capsys):
    z = np.zeros_like(paper_log.i_A)
    path = _rewrite(paper_log, tmp_path, "still", e_pulses=z.astype(np.int64), i_A=z)
    with pytest.raises(plant.LogError, match="every tracking error and current is zero"):
        identification.identify(plant.load_log(path), rng=0, progress=False)
    _one_error_line(*_cli([path, "--seed", "0"], capsys)[::2])


def test_an_absurd_current_is_refused(paper_log, tmp_path, capsys):
    i = np.array(paper_log.i_A)
    i[10, 1] = 1e300
    path = _rewrite(paper_log, tmp_path, "amps", i_A=i)
    with pytest.raises(plant.LogError, match=r"i3_A = 1e\+300 A at sample 10 is beyond"):
        identification.identify(plant.load_log(path), rng=0, progress=False)
    _one_error_line(*_cli([path, "--seed", "0"], capsys)[::2])


def test_sanity_accepts_every_bundled_and_committed_log():
    from pathlib import Path

    data = Path(__file__).resolve().parent / "data"
    paths = sorted(data.glob("*.csv")) + sorted((data / "independent").glob("*.csv"))
    assert len(paths) >= 8
    for p in paths:
        try:
            log = plant.load_log(p)
        except plant.LogError:
            continue  # the malformed fixtures of test_log
        check_experiment(log, n_parameters=23)


def test_deeply_nested_json_is_one_line(paper_log, tmp_path, capsys):
    deep = '{"a": ' * 100000 + "1" + "}" * 100000
    nested = tmp_path / "nested.json"
    nested.write_text(deep)
    with pytest.raises(ValueError, match="nested too deeply"):
        identification.IdentificationResult.load_json(nested)
    with pytest.raises(ValueError, match="nested too deeply"):
        plant.logs.fileio.read_json_object(nested, "prior result file")
    stem = paper_log.save(tmp_path / "deep").with_suffix("")
    stem.with_suffix(".json").write_text(deep)
    with pytest.raises(plant.LogError, match="nested too deeply"):
        plant.load_log(stem.with_suffix(".csv"))
    _one_error_line(*_cli([stem.with_suffix(".csv"), "--seed", "0"], capsys)[::2])
    ok = paper_log.save(tmp_path / "ok")
    line = _one_error_line(*_cli([ok, "--payload", "--prior", nested], capsys)[::2])
    assert "nested too deeply" in line


def test_a_full_disk_names_the_file_and_what_was_written(paper_log, tmp_path, capsys, monkeypatch):
    """A failing write names its target; a failure after the JSON says it was written."""
    import identification.cli as cli

    small = paper_log.window(1.0, 1.2).save(tmp_path / "small")
    out = tmp_path / "o.json"

    def full(*a, **k):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(cli, "_save_plots", lambda *a, **k: full())
    status, _, err = _cli([small, "--method", "paper", "--generations", "2", "-o", out,
                           "--plot", tmp_path / "plots", "--quiet"], capsys)
    line = _one_error_line(status, err)
    assert "No space left on device" in line and f"written before the failure: {out}" in line
    # the atomic writer names the target itself
    from plant.logs.fileio import OutputFileError, write_text_atomic

    monkeypatch.setattr(plant.logs.fileio.os, "replace", full)
    with pytest.raises(OutputFileError, match=f"cannot write {tmp_path / 'x.txt'}: No space left"):
        write_text_atomic(tmp_path / "x.txt", "data")
    assert not (tmp_path / "x.txt").exists()


def test_an_unwritable_output_fails_before_the_work(paper_log, tmp_path, capsys):
    import time

    path = paper_log.save(tmp_path / "log")
    t0 = time.perf_counter()
    line = _one_error_line(*_cli([path, "--seed", "0", "-o", "/proc/nope/x.json"], capsys)[::2])
    assert "/proc/nope" in line
    assert time.perf_counter() - t0 < 5.0  # refused before identifying (about 1 s of work)


def test_a_fit_at_the_search_bound_is_flagged(paper_log, tmp_path, capsys):
    """f7's upper bound just below its value: the fit ends there, and says so."""
    bounds = np.array(paper_log.rig.f_bounds, dtype=float)
    bounds[6] = (3.0, 4.0)  # the paper log's f7 is 4.44
    with pytest.warns(identification.SearchBoundWarning, match=r"f7 \(upper\)"):
        res = identification.identify(paper_log, bounds=bounds, rng=0, progress=False)
    assert res["at_bounds"] == ["f7 (upper)"]
    assert json.loads(json.dumps(res.to_dict()))["at_bounds"] == ["f7 (upper)"]
    path = paper_log.save(tmp_path / "b")
    d = json.loads(path.with_suffix(".json").read_text())
    d["f_search_ranges"]["f7"] = [3.0, 4.0]
    path.with_suffix(".json").write_text(json.dumps(d))
    status, out, err = _cli([path, "--seed", "0", "--quiet"], capsys)
    assert status == 0 and "fit at the search bound: f7 (upper)" in err


def test_payload_mode_names_the_payload_parameters(paper_log, truth):
    """Issue 22: in payload mode the poor-excitation warning names m, xp, yp, Jc, not f."""
    import dataclasses
    import warnings

    prior = np.asarray(truth("puma560_paper_rigid")["f_vector"], dtype=float)
    f = plant.add_payload(prior, plant.Payload(0.3, (0.1, 0.02), 0.01), paper_log.rig.a3_m)
    run = plant.emulate_log(paper_log, f)
    w = run.window(0.2, 0.3)
    w = w.replace(rig=dataclasses.replace(w.rig, q0_rad=None, qd0_rad_per_s=None))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        res = identification.identify(w, payload=True, prior=prior, rng=0, progress=False)
    texts = [str(c.message) for c in caught
             if isinstance(c.message, PoorExcitationWarning)]
    names = set(res.get("x_names"))
    assert set(res["poorly_excited"]) <= names
    for t in texts:
        assert not any(f"f{i} (" in t for i in range(1, 10)), t
