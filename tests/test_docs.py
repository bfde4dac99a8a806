"""The documentation: every Python code block of every page runs, and Sphinx builds cleanly.

Code blocks: every ``.. code-block:: python`` (also ``.. code::`` /
``.. sourcecode::`` with language python) of every ``docs/*.rst`` page is
extracted and executed in page order, in one namespace per page, with a
scratch working directory (pages write figures and logs).  Nothing is skipped.
To keep the suite fast the test runs the identifications of the pages with
small settings: ``identification.identify`` and
``identification.distributed.seed_jobs`` get ``ga_options={"n_gen": 2}``
and ``refine_options={"n_starts": 1}`` unless a block passes its own
(``QUICK_OPTIONS``).  Everything else runs as printed.

Build: ``python -m sphinx -n -W -b html docs OUT`` (nitpicky, warnings are
errors) into a tmp dir must succeed with no warning.
"""
from __future__ import annotations

import functools
import re
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
DOCS = REPO / "docs"

#: Small settings for the identifications run by the pages' code blocks.
QUICK_OPTIONS = {"ga_options": {"n_gen": 2}, "refine_options": {"n_starts": 1}}

_DIRECTIVE = re.compile(r"^(?P<indent>[ \t]*)\.\. (?:code-block|code|sourcecode)::[ \t]*(?P<lang>\S*)[ \t]*$")


def python_blocks(text: str) -> list[tuple[int, str]]:
    """The Python code blocks of an rst text: ``[(line number, code), ...]`` in order.

    A block is the indented content after a ``code-block`` directive whose
    language is ``python`` (or ``py``, ``python3``, ``pycon`` is not run);
    the directive's options (``:linenos:`` ...) are dropped.
    """
    lines = text.splitlines()
    blocks = []
    i = 0
    while i < len(lines):
        m = _DIRECTIVE.match(lines[i])
        if not m or m.group("lang").lower() not in ("python", "py", "python3"):
            i += 1
            continue
        base = len(m.group("indent").expandtabs())
        start = i + 1
        j = start
        body = []
        while j < len(lines):
            ln = lines[j]
            if ln.strip() and len(ln) - len(ln.lstrip()) <= base:
                break
            body.append(ln)
            j += 1
        # drop the directive's options (first indented lines starting with ':')
        k = 0
        while k < len(body) and (body[k].strip().startswith(":") or not body[k].strip()):
            if not body[k].strip() and any(b.strip() and not b.strip().startswith(":")
                                           for b in body[k:]):
                k += 1
                break
            k += 1
        code_lines = body[k:]
        indent = min((len(b) - len(b.lstrip()) for b in code_lines if b.strip()), default=0)
        code = "\n".join(b[indent:] for b in code_lines).strip("\n")
        blocks.append((start + 1 + k, code))
        i = j
    return blocks


def _pages_with_python():
    return sorted(p for p in DOCS.glob("*.rst") if python_blocks(p.read_text(encoding="utf-8")))


def test_block_extraction():
    text = ("Title\n=====\n\n.. code-block:: python\n   :linenos:\n\n   a = 1\n\n   b = a + 1\n"
            "\ntext\n\n.. code-block:: bash\n\n   echo no\n\n.. code-block:: python\n\n"
            "   for i in range(2):\n       b += i\n")
    blocks = python_blocks(text)
    assert [code for _, code in blocks] == ["a = 1\n\nb = a + 1", "for i in range(2):\n    b += i"]
    ns = {}
    for _, code in blocks:
        exec(compile(code, "<test>", "exec"), ns)
    assert ns["b"] == 3


def test_tutorials_have_python_blocks():
    pages = {p.name for p in _pages_with_python()}
    assert {"tutorial_ctc.rst", "tutorial_real_rigs.rst", "model.rst", "payload.rst"} <= pages


def _quick(fn):
    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        for key, value in QUICK_OPTIONS.items():
            kwargs.setdefault(key, value)
        return fn(*args, **kwargs)

    return wrapper


@pytest.mark.parametrize("page", _pages_with_python(), ids=lambda p: p.name)
def test_page_code_blocks_run(page, tmp_path, monkeypatch):
    import matplotlib

    matplotlib.use("Agg")
    import identification
    import identification.api
    import identification.distributed

    quick_identify = _quick(identification.api.identify)
    monkeypatch.setattr(identification, "identify", quick_identify)
    monkeypatch.setattr(identification.api, "identify", quick_identify)
    quick_jobs = _quick(identification.distributed.seed_jobs)
    monkeypatch.setattr(identification.distributed, "seed_jobs", quick_jobs)
    monkeypatch.setattr(identification, "seed_jobs", quick_jobs)
    monkeypatch.chdir(tmp_path)

    from matplotlib import pyplot as plt

    ns = {"__name__": f"docs_{page.stem}"}
    blocks = python_blocks(page.read_text(encoding="utf-8"))
    assert blocks
    try:
        for line, code in blocks:
            # line numbers in tracebacks point into the .rst file
            exec(compile("\n" * (line - 1) + code, str(page), "exec"), ns)
    finally:
        plt.close("all")


def test_sphinx_nitpicky_build_has_no_warnings(tmp_path):
    out = tmp_path / "html"
    proc = subprocess.run(
        [sys.executable, "-m", "sphinx", "-n", "-W", "--keep-going", "-q", "-E",
         "-d", str(tmp_path / "doctrees"), "-b", "html", str(DOCS), str(out)],
        cwd=REPO, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-5000:]
    assert "WARNING" not in proc.stderr, proc.stderr[-5000:]
    assert (out / "index.html").is_file() and (out / "api.html").is_file()


def test_make_figures_script_is_idempotent(tmp_path):
    """docs/make_figures.py (the source of the quoted figures) runs and can be rerun."""
    import json

    env = dict(__import__("os").environ, PYTHONPATH=str(REPO), MPLBACKEND="Agg")
    cmd = [sys.executable, str(DOCS / "make_figures.py"), "--quick", "--sections", "simulator",
           "--out", str(tmp_path)]
    for _ in range(2):
        proc = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True,
                              timeout=300)
        assert proc.returncode == 0, proc.stderr[-3000:]
    data = json.loads((tmp_path / "figures.json").read_text())
    assert data["run"]["sections"] == ["simulator"] and data["run"]["quick"] is True
    sim = data["simulator"]["puma560_paper_rigid"]
    assert 0 <= sim["identical_pct"] <= sim["within_1_pulse_pct"] <= 100
    bad = subprocess.run([sys.executable, str(DOCS / "make_figures.py"), "--sections", "nope"],
                         cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120)
    assert bad.returncode == 2 and "unknown section" in bad.stderr
