"""The library's layout: plant's three subpackages, the 0.1 flat paths, and no import circles."""
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


def _import_graph(packages=("plant", "identification", "ctc")) -> dict:
    """The library's module import graph ``{module: {modules it imports}}``, read from the
    source: every ``import`` and ``from ... import`` at any depth (a function-level import
    is a dependency too), but not those of a module's PEP 562 ``__getattr__`` (a lazy
    alias under an old name, not a dependency of the module's code)."""
    import ast
    from pathlib import Path

    repo = Path(plant.__file__).resolve().parents[1]
    files = {}
    for pkg in packages:
        for path in (repo / pkg).rglob("*.py"):
            parts = path.relative_to(repo).with_suffix("").parts
            files[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path

    def targets(name, node):
        if isinstance(node, ast.Import):
            return [a.name for a in node.names if a.name in files]
        if node.level:
            base = name.split(".")
            if files[name].name != "__init__.py":
                base = base[:-1]
            base = base[:len(base) - node.level + 1]
            mod = ".".join(base + ([node.module] if node.module else []))
        else:
            mod = node.module
        found = []
        for a in node.names:
            if f"{mod}.{a.name}" in files:
                found.append(f"{mod}.{a.name}")
            elif mod in files and files[mod].name == "__init__.py":
                # a package's name: the module that defines it (a package may re-export it
                # lazily, through its own __getattr__)
                obj = getattr(importlib.import_module(mod), a.name, None)
                where = getattr(obj, "__module__", None)
                found.append(where if where in files else mod)
            elif mod in files:
                found.append(mod)
        return found

    graph = {}
    for name, path in files.items():
        tree = ast.parse(path.read_text())
        skip = {id(n) for f in tree.body if isinstance(f, ast.FunctionDef)
                and f.name == "__getattr__" for n in ast.walk(f)}
        graph[name] = {t for node in ast.walk(tree) if isinstance(node, (ast.Import, ast.ImportFrom))
                       and id(node) not in skip for t in targets(name, node) if t != name}
    return graph


def test_no_module_of_the_library_imports_itself_through_others():
    """No import circle among the library's modules, function-level imports included
    (issue 23: the circles of identification's api/arm/flexible and of the closed loop's
    sample step are gone): the modules form layers.  A name imported from a package
    counts as an import of the module that defines it (packages re-export their modules'
    names, some lazily); a package's own imports are its ``__init__``'s."""
    edges = _import_graph()
    # Tarjan's strongly connected components
    index, low, stack, on, circles = {}, {}, [], set(), []

    def visit(v):
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in edges[v]:
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                circles.append(sorted(comp))

    for v in list(edges):
        if v not in index:
            visit(v)
    assert circles == []
    # the checker sees function-level imports (identify_arm's of the two-mass fit)
    assert "identification.arm_flexible" in edges["identification.arm"]


def test_names_that_moved_below_identification_arm_still_import_from_it():
    """The model choice's statistic and the guessed box's constants moved below
    identification.arm (no import circles): the old names import, with a warning."""
    import identification.arm as arm
    import identification.model_choice as mc
    import identification.refinement as rf

    with pytest.warns(DeprecationWarning, match="identification.model_choice.held_back_paired_t"):
        assert arm.held_back_paired_t is mc.held_back_paired_t
    with pytest.warns(DeprecationWarning, match="identification.refinement.BOX_EDGE"):
        assert arm.BOX_EDGE == rf.BOX_EDGE
    assert arm.ModelImprovement is mc.ModelImprovement  # used by identify_arm itself
    with pytest.raises(AttributeError, match="no_such_name"):
        arm.no_such_name
