"""Sphinx configuration for puma-ga-ctc."""
from __future__ import annotations

import os
import sys

# Make the packages importable from the source tree (no install needed).
ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))
sys.path.insert(0, ROOT)

# Headless builds: never open a window when a page or docstring plots.
os.environ.setdefault("MPLBACKEND", "Agg")

project = "puma-ga-ctc"
author = "puma-ga-ctc contributors"
copyright = "puma-ga-ctc contributors"

try:  # the version of the installed distribution, if any
    from importlib.metadata import version

    release = version("puma-ga-ctc")
except Exception:  # PackageNotFoundError or no metadata
    release = "0.1.0"
version = release

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "numpydoc",
]

# numpydoc
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False

# autodoc
autodoc_default_options = {
    "members": True,
    "undoc-members": False,
    "show-inheritance": True,
}
autodoc_member_order = "bysource"
autodoc_typehints = "none"  # numpydoc's Parameters sections carry the types

templates_path: list[str] = []
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store"]
source_suffix = {".rst": "restructuredtext"}
master_doc = "index"
root_doc = "index"

# ----------------------------------------------------------------------------- nitpicky
# The docs are built with ``python -m sphinx -n -W`` (tests/test_docs.py): every
# cross-reference must resolve.  Without network there is no intersphinx, so the
# targets in the standard library and in third-party packages that the docstrings
# name are listed here; they are not part of this project and cannot be documented
# in it.  Project-internal targets must resolve (see ``_resolve_short_names``).
nitpicky = True
_EXTERNAL = {
    "py:class": [
        "abc.ABC",
        "casadi.Function",
        "concurrent.futures.Executor",
        "concurrent.futures.ProcessPoolExecutor",
        "control.TimeResponseData",
        "matplotlib.axes.Axes",
        "matplotlib.figure.Figure",
        "numpy.ndarray",
        "numpy.random.Generator",
        "pathlib.Path",
        "scipy.optimize.OptimizeResult",
        "scipy.optimize._optimize.OptimizeResult",
    ],
    "py:func": [
        "dataclasses.replace",
        "open",
        "os.access",
        "os.path.realpath",
        "functools.lru_cache",
        "numpy.random.default_rng",
        "os.replace",
        "scipy.optimize.differential_evolution",
        "scipy.optimize.least_squares",
    ],
}
nitpick_ignore = [(role, target) for role, targets in _EXTERNAL.items() for target in targets]


def _resolve_short_names(app, env, node, contnode):
    """Resolve a short project-internal reference that the default lookup missed.

    Docstrings name objects of their own package by short names
    (``:func:`integrate_sample```, ``:data:`STATUS_OK```), and the packages
    re-export their members (``plant.simulate_batch`` is
    ``plant.simulation.simulate.simulate_batch``), so a docstring rendered in the
    package's context (``automodule:: plant``) looks the name up in the
    wrong module.  This retries the lookup like a reference written with a
    leading dot (Sphinx's "search in all modules" mode) and accepts the
    result only if it is unambiguous: one match, or several whose last two
    components agree and of which one is in the reference's own module tree.
    """
    if node.get("refdomain") != "py":
        return None
    target = node.get("reftarget", "")
    if not target or target.startswith((".", "~")):
        return None
    domain = env.get_domain("py")
    modname = node.get("py:module")
    clsname = node.get("py:class")
    typ = node.get("reftype")
    matches = domain.find_obj(env, modname, clsname, target, typ, 1)
    if not matches:
        return None
    if len(matches) > 1:
        top = (modname or "").split(".")[0]
        same_tree = [m for m in matches if m[0].split(".")[0] == top] or matches
        # prefer the defining submodule (longest name) over a package re-export
        same_tree.sort(key=lambda m: -m[0].count("."))
        matches = same_tree[:1]
    name, obj = matches[0]
    from sphinx.util.nodes import make_refnode

    return make_refnode(app.builder, node["refdoc"], obj.docname, obj.node_id, contnode, name)


def setup(app):
    app.connect("missing-reference", _resolve_short_names)


html_theme = "alabaster"
html_static_path: list[str] = []
html_title = "puma-ga-ctc"
