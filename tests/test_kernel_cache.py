"""numba's on-disk cache of the kernels: concurrent first compiles, read-only installs.

Each test runs fresh Python processes with their own empty cache directory,
so it measures what a user's first and second runs do.
"""
from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

# Simulates the paper log for one f and prints whether the kernels were in the
# cache before, and the output error (the same in every process).
_RUN = """
import sys
sys.path.insert(0, {root!r})
{prelude}
import numpy as np
import plant
cached = plant.kernels_cached()
log = plant.load_example()
f = np.array([0.9, 0.35, 0.01, -0.4, 0.03, -0.9, 4.5, -0.1, 3.8])
print(cached, plant.output_error(log, f, substeps=1))
"""


def _spawn(env, prelude=""):
    return subprocess.Popen([sys.executable, "-c", _RUN.format(root=str(ROOT), prelude=prelude)],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _result(proc):
    out, err = proc.communicate(timeout=600)
    assert proc.returncode == 0, err[-2000:]
    cached, y = out.split()
    return cached == "True", float(y)


@pytest.mark.slow
def test_two_processes_compiling_at_once_do_not_corrupt_the_cache(tmp_path):
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    a, b = _spawn(env), _spawn(env)
    (ca, ya), (cb, yb) = _result(a), _result(b)
    assert not ca and not cb  # both started with an empty cache
    assert ya == yb
    cached, y = _result(_spawn(env))  # a third process loads what they wrote
    assert cached and y == ya


@pytest.mark.slow
def test_read_only_package_directory_falls_back_to_the_user_cache(tmp_path):
    """A package directory numba may not write to: the per-user cache is used.

    The tests run as root, for whom file modes do not stop writes, so the
    read-only package directory is simulated where numba checks it: its
    in-tree locators (the ones that write ``__pycache__`` next to the
    sources) fail their writability probe with a PermissionError, as they do
    in a read-only site-packages.  numba then falls back to its per-user
    cache under ``$HOME/.cache`` (``NUMBA_CACHE_DIR`` unset), which must work.
    """
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    env["HOME"] = str(tmp_path / "home")
    env["XDG_CACHE_HOME"] = str(tmp_path / "home" / ".cache")
    prelude = ("from numba.core import caching\n"
               "def _read_only(self):\n"
               "    raise PermissionError('read-only package directory')\n"
               "for _cls in (caching.InTreeCacheLocator, caching.InTreeCacheLocatorFsAgnostic):\n"
               "    _cls.ensure_cache_path = _read_only\n")
    cold, y0 = _result(_spawn(env, prelude))
    warm, y1 = _result(_spawn(env, prelude))
    assert not cold and warm and y0 == y1
    user_cache = tmp_path / "home" / ".cache"
    assert any(p.suffix == ".nbi" for p in user_cache.rglob("*"))
