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


# A robot model's arm (plant.simulation.arm): builds the planar arm of tests/test_arm.py,
# emulates 0.3 s of its P loop, and prints whether the driver loaded from numba's cache,
# where its generated module is, and the output error of a perturbed candidate.
_ARM_RUN = """
import sys
sys.path.insert(0, {root!r})
sys.path.insert(0, {tests!r})
import numpy as np
from test_arm import TRAJ, planar_arm, planar_rig
from plant.simulation.arm import arm_plant, kernels_cached, simulate_arm
before = kernels_cached(planar_arm())  # what the command line announces
arm = arm_plant(planar_arm())
beta = arm.beta()
log = simulate_arm(arm, beta, planar_rig(), TRAJ, 300)
sim = simulate_arm(arm, beta * 1.01, planar_rig(), TRAJ, 300, e_log=log.errors[0], errors=False)
stats = arm.kernels.logged_run.stats
print(sum(stats.cache_hits.values()) > 0, sum(stats.cache_misses.values()) > 0,
      arm.kernels.__file__, repr(float(sim.objective[0])), before, kernels_cached(planar_arm()))
"""


def _arm_spawn(env):
    return subprocess.Popen([sys.executable, "-c", _ARM_RUN.format(root=str(ROOT),
                                                                    tests=str(ROOT / "tests"))],
                            env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _arm_result(proc):
    out, err = proc.communicate(timeout=600)
    assert proc.returncode == 0, err[-2000:]
    hit, miss, path, y, before, after = out.split()
    # kernels_cached says beforehand whether the run compiles, and True once it has
    assert before == hit and after == "True"
    return hit == "True", miss == "True", Path(path), float(y)


def _arm_process(env):
    return _arm_result(_arm_spawn(env))


@pytest.mark.slow
def test_a_robots_generated_kernels_load_from_the_cache_in_the_next_process(tmp_path):
    """The arm's driver compiles once; a second process loads it and gives the same numbers."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    env.pop("PUMA_GA_CTC_KERNELS", None)
    hit0, miss0, path0, y0 = _arm_process(env)
    hit1, miss1, path1, y1 = _arm_process(env)
    assert (hit0, miss0) == (False, True) and (hit1, miss1) == (True, False)
    assert path0 == path1 and path0.parent == tmp_path / "cache" / "generated"
    assert y1 == y0 > 0
    # an unwritable directory (here a file where the directory should be): a private
    # temporary directory, compiled again, the same numbers
    blocked = tmp_path / "blocked"
    blocked.write_text("")
    env["PUMA_GA_CTC_KERNELS"] = str(blocked / "kernels")
    hit2, miss2, path2, y2 = _arm_process(env)
    assert (hit2, miss2) == (False, True) and not path2.is_relative_to(blocked) and y2 == y0


def test_generated_modules_are_written_once_and_a_missing_one_imports_as_a_placeholder(
        tmp_path, monkeypatch):
    import importlib

    from plant.simulation import generated

    monkeypatch.setattr(generated, "_DIRECTORY", [tmp_path])
    text = "VALUE = 41 + 1\n"
    mod = generated.load("probe", text)
    assert mod.VALUE == 42 and generated.load("probe", text) is mod
    assert Path(mod.__file__).parent == tmp_path and mod.__name__.startswith(
        "plant.simulation.generated.probe_")
    # a file of that name with other text (say, cut short) is written again
    name = mod.__name__
    Path(mod.__file__).write_text("VALUE = ")
    del sys.modules[name]
    assert generated.load("probe", text).VALUE == 42
    # a generated module that is gone (cleared, or beyond KEEP) imports as a placeholder, so
    # that numba's index of a kernel naming its kind still loads; load() writes it again
    assert generated.clear() >= 1 and not Path(mod.__file__).exists()
    del sys.modules[name]
    ghost = importlib.import_module(name)
    assert ghost.__placeholder__ and ghost.ArmKind._fields == ("code",)
    assert ghost.ArmKind.__module__ == name
    assert generated.load("probe", text).VALUE == 42
    # tools that walk the library's packages never import a generated module (one that
    # another version of the library left in the directory may no longer import)
    import pkgutil

    assert not list(pkgutil.iter_modules(generated.__path__))
    with pytest.raises(ValueError, match="identifier"):
        generated.load("no good", text)


def test_only_plain_module_level_functions_are_copied_into_generated_modules():
    from plant.simulation import generated
    from plant.simulation.core import encoder_read
    from plant.simulation.simulate import logged_run

    defined = {"np"}
    imports, src = generated.function_copy(logged_run, "_kernel", defined)
    assert src.startswith("@_kernel\ndef logged_run(")
    assert imports.startswith("from plant.simulation.simulate import (") and "advance_sample" in imports
    assert " np" not in imports and "advance_sample" in defined
    with pytest.raises(ValueError, match="plain module-level"):
        generated.function_copy(encoder_read, "_kernel", set())  # a numba dispatcher


@pytest.mark.slow
def test_two_processes_generating_the_same_robot_at_once_share_one_module(tmp_path):
    """Both write the robot's module (whole, by rename) and compile; a third loads their cache."""
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    env.pop("PUMA_GA_CTC_KERNELS", None)
    a, b = _arm_spawn(env), _arm_spawn(env)
    (_, _, pa, ya), (_, _, pb, yb) = _arm_result(a), _arm_result(b)
    assert pa == pb and ya == yb
    assert [p.name for p in pa.parent.iterdir() if p.suffix in (".py", ".tmp")] == [pa.name]
    hit, miss, pc, yc = _arm_process(env)
    assert hit and not miss and pc == pa and yc == ya


def test_generated_modules_beyond_keep_are_deleted_least_recently_used_first(tmp_path,
                                                                              monkeypatch):
    import time

    from plant.simulation import generated

    monkeypatch.setattr(generated, "_DIRECTORY", [tmp_path])
    monkeypatch.setattr(generated, "KEEP", 2)
    a = generated.load("keep", "A = 1\n")
    time.sleep(0.05)
    b = generated.load("keep", "B = 1\n")
    time.sleep(0.05)
    del sys.modules[a.__name__]
    generated.load("keep", "A = 1\n")  # a used again: b is now the least recently used
    time.sleep(0.05)
    c = generated.load("keep", "C = 1\n")  # the third module: one must go
    left = sorted(p.name for p in tmp_path.glob("*.py"))
    assert left == sorted(Path(m.__file__).name for m in (a, c))
    assert not (tmp_path / f".{Path(b.__file__).stem}.used").exists()
