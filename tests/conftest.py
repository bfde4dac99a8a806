"""Shared pytest fixtures: the development logs and a factory for corrupted copies.

The development logs (CSV, JSON sidecar and truth file of each) are part of
the repository, in ``tests/data`` next to this file, so the suite runs on a
fresh clone with nothing beside it. Set the environment variable
``PUMA_DATA_DIR`` to use another directory; it takes precedence over the
default. A data directory without the logs is a test *failure*, never a skip.

Only tests may read the ``*.truth.json`` files (fixture ``truth``); library
code never does.
"""
from __future__ import annotations

import json
import os
import signal
import threading
from pathlib import Path
from typing import Callable

import pytest


def pytest_configure(config):
    """Run the Ctrl-C tests as from a terminal.

    A suite started in the background by a non-interactive shell (``cmd &``
    without job control) inherits SIGINT ignored, and so do its child
    processes; the library then leaves Ctrl-C alone
    (:func:`identification.sigint.install` replaces only Python's default
    handler), and no test could deliver one.  Python's default handler is put
    back in each test process (the main suite's and every pytest-xdist
    worker's, which runs its tests in its main thread from pytest-xdist 3.6);
    a process started from it gets SIGINT's default action at exec.  The
    suite then stops on a Ctrl-C meant for the shell's foreground job, as it
    would in the foreground.
    """
    if (threading.current_thread() is threading.main_thread()
            and signal.getsignal(signal.SIGINT) is signal.SIG_IGN):
        signal.signal(signal.SIGINT, signal.default_int_handler)


#: Stems of the development logs.
PAPER_RIGID = "puma560_paper_rigid"
VALIDATION_RIGID = "puma560_validation_rigid"
DRILL_FLEX = "puma560_paper_drill_flex"
DEV_STEMS = (PAPER_RIGID, VALIDATION_RIGID, DRILL_FLEX)

_DEFAULT_DATA_DIR = Path(__file__).resolve().parent / "data"


def _data_dir() -> Path:
    env = os.environ.get("PUMA_DATA_DIR")
    return Path(env) if env else _DEFAULT_DATA_DIR


@pytest.fixture(scope="session")
def data_dir() -> Path:
    """Directory of the development logs (``PUMA_DATA_DIR`` or ``tests/data``)."""
    d = _data_dir()
    missing = [f"{stem}{ext}" for stem in DEV_STEMS
               for ext in (".csv", ".json", ".truth.json") if not (d / f"{stem}{ext}").is_file()]
    if missing:
        pytest.fail(f"development logs missing in {d}: {', '.join(missing)}"
                    f" (they ship in tests/data; PUMA_DATA_DIR overrides)", pytrace=False)
    return d


@pytest.fixture(scope="session")
def dev_log_paths(data_dir: Path) -> dict:
    """Stem -> Path of the CSV of each development log."""
    return {stem: data_dir / f"{stem}.csv" for stem in DEV_STEMS}


@pytest.fixture(scope="session")
def paper_rigid_path(dev_log_paths) -> Path:
    """CSV of ``puma560_paper_rigid`` (paper trajectory, rigid, no payload)."""
    return dev_log_paths[PAPER_RIGID]


@pytest.fixture(scope="session")
def validation_rigid_path(dev_log_paths) -> Path:
    """CSV of ``puma560_validation_rigid`` (ramped validation trajectory, rigid)."""
    return dev_log_paths[VALIDATION_RIGID]


@pytest.fixture(scope="session")
def drill_flex_path(dev_log_paths) -> Path:
    """CSV of ``puma560_paper_drill_flex`` (drill payload, flexible joints, noisy currents)."""
    return dev_log_paths[DRILL_FLEX]


@pytest.fixture(scope="session")
def paper_log(paper_rigid_path):
    """Loaded ``puma560_paper_rigid`` (an ``ExperimentLog``; immutable, shared)."""
    from plant.logs.log import load_log

    return load_log(paper_rigid_path)


@pytest.fixture(scope="session")
def validation_log(validation_rigid_path):
    """Loaded ``puma560_validation_rigid``."""
    from plant.logs.log import load_log

    return load_log(validation_rigid_path)


@pytest.fixture(scope="session")
def drill_log(drill_flex_path):
    """Loaded ``puma560_paper_drill_flex``."""
    from plant.logs.log import load_log

    return load_log(drill_flex_path)


@pytest.fixture(scope="session")
def truth(data_dir) -> Callable[[str], dict]:
    """``truth(stem)`` -> the parsed ``STEM.truth.json`` (tests only; true f is ``["f_vector"]``)."""

    def _load(stem: str) -> dict:
        return json.loads((data_dir / f"{stem}.truth.json").read_text())

    return _load


@pytest.fixture
def tmp_log(tmp_path: Path, data_dir: Path):
    """Factory writing a (modified) copy of a development log into ``tmp_path``.

    ``tmp_log(stem=PAPER_RIGID, *, name=None, csv_text=None, csv_edit=None,
    json_text=None, json_edit=None, write_csv=True, write_json=True)``
    returns the Path of the copy's CSV (its sidecar is next to it).

    - ``csv_edit(lines) -> lines``: edit the CSV as a list of lines (without
      newlines; ``lines[0]`` is the header); ``csv_text`` replaces it entirely.
    - ``json_edit(dict)``: edit the parsed sidecar in place, or return a new
      dict (any other return value is ignored); ``json_text`` replaces it.
    - ``write_csv`` / ``write_json`` False: leave that file out.
    - ``name``: stem of the copy (default ``"<stem>_<counter>"``).
    """
    counter = {"n": 0}

    def make(
        stem: str = PAPER_RIGID,
        *,
        name: str | None = None,
        csv_text: str | None = None,
        csv_edit: Callable[[list], list] | None = None,
        json_text: str | None = None,
        json_edit: Callable[[dict], dict | None] | None = None,
        write_csv: bool = True,
        write_json: bool = True,
    ) -> Path:
        counter["n"] += 1
        out_stem = name or f"{stem}_{counter['n']}"
        csv_out = tmp_path / f"{out_stem}.csv"
        json_out = tmp_path / f"{out_stem}.json"
        if write_csv:
            if csv_text is None:
                lines = (data_dir / f"{stem}.csv").read_text().splitlines()
                if csv_edit is not None:
                    lines = csv_edit(lines)
                csv_text = "\n".join(lines) + ("\n" if lines else "")
            csv_out.write_text(csv_text)
        if write_json:
            if json_text is None:
                side = json.loads((data_dir / f"{stem}.json").read_text())
                if json_edit is not None:
                    edited = json_edit(side)
                    side = edited if isinstance(edited, dict) else side
                json_text = json.dumps(side, indent=2)
            json_out.write_text(json_text)
        return csv_out

    return make


@pytest.fixture
def ctrl_c_at_objective_call(monkeypatch):
    """``ctrl_c_at_objective_call(n)``: the n-th population evaluation of the
    output error raises KeyboardInterrupt (a Ctrl-C during the GA)."""
    from identification.objective import OutputError

    real_call = OutputError.__call__

    def arm(n):
        calls = {"n": 0}

        def interrupted(self, F, cap=None, **kwargs):
            calls["n"] += 1
            if calls["n"] == n:
                raise KeyboardInterrupt
            return real_call(self, F, cap=cap, **kwargs)

        monkeypatch.setattr(OutputError, "__call__", interrupted)

    return arm
