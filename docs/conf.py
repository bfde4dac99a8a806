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
    from importlib.metadata import PackageNotFoundError, version

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

html_theme = "alabaster"
html_static_path: list[str] = []
html_title = "puma-ga-ctc"
