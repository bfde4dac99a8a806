"""The plant package's layout: three subpackages, and the 0.1 flat paths still import."""
from __future__ import annotations

import importlib
import sys

import pytest

import plant

MOVED = {
    "logs": ("log", "arm_log", "rig", "sidecar", "fileio", "sanity", "trajectory", "plotting"),
    "robot": ("robot_model", "model", "symbolic", "codegen", "payload"),
    "simulation": ("core", "anchors", "plants", "friction", "arm", "lanes", "parallel",
                   "simulate", "replay", "closed_loop", "controllers", "twin", "response",
                   "synthetic", "warmup"),
}


@pytest.mark.parametrize("group, name", [(g, m) for g, ms in MOVED.items() for m in ms])
def test_flat_path_is_the_new_module(group, name):
    new = importlib.import_module(f"plant.{group}.{name}")
    sys.modules.pop(f"plant.{name}", None)
    with pytest.warns(DeprecationWarning, match=f"plant.{group}.{name}"):
        old = importlib.import_module(f"plant.{name}")
    assert old is new


def test_emulate_arm_log_keeps_its_issue_name():
    """Issue 23 names ``plant.arm_log.emulate_arm_log``: it is the simulator's emulator."""
    from plant.logs.arm_log import emulate_arm_log
    from plant.simulation.synthetic import emulate_arm_log as emulator

    assert emulate_arm_log is emulator
    with pytest.raises(AttributeError, match="no_such_name"):
        plant.logs.arm_log.no_such_name


def test_subpackages_do_not_import_upwards():
    """logs never imports the simulator, and nothing in plant imports identification or ctc."""
    import ast
    from pathlib import Path

    root = Path(plant.__file__).parent
    for path in root.rglob("*.py"):
        tree = ast.parse(path.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module and node.col_offset == 0:
                mod = node.module
                assert not mod.startswith(("identification", "ctc")), (path, mod)
                if path.parent.name == "logs":
                    assert not mod.startswith("plant.simulation"), (path, mod)
