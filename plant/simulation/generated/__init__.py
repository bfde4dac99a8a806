"""Modules of code generated per robot, written to a cache directory so numba can cache them on disk.

A robot model's kernels (:mod:`plant.simulation.arm`: its right-hand side,
the logged-run driver and the closed-loop step compiled for it;
:mod:`ctc.arm`: the flexible CTC's link model) are Python source generated
from the robot's symbolic model.  Compiled from a string they would compile
again in every process (numba caches only functions of importable modules,
and the robot's plant kind -- a class -- must be importable for a cached
kernel's signature to load).  So :func:`load` writes each generated text as
a module ``plant.simulation.generated.<stem>_<hash>`` into
:func:`kernel_directory` (found there by this package's import hook, not
on its ``__path__``) and imports it; its kernels carry numba's
``cache=True``, and a second process that builds the same robot loads them
from numba's cache instead of compiling them (``docs/speed.rst``, compile
time).

The file's name is a hash of its text, and the text carries a fingerprint
of the library modules whose compiled helpers the kernels contain
(:data:`DEPENDENCIES`), so a changed generator, robot or library gives a
new module and never loads a stale kernel from numba's cache (whose own
check covers only the file the kernel's source is in).

The directory is, in order: ``$PUMA_GA_CTC_KERNELS``; ``generated`` under
``$NUMBA_CACHE_DIR`` when that is set; ``puma-ga-ctc/kernels`` under
``$XDG_CACHE_HOME`` (default ``~/.cache``).  When it cannot be created or
written, a temporary directory of the process is used (the kernels then
compile in every process, as without a cache).  At most :data:`KEEP`
generated modules are kept: writing a new one deletes the least recently
used beyond that, with their numba cache files.  :func:`clear` empties it.
"""
from __future__ import annotations

import ast
import atexit
import hashlib
import importlib
import importlib.abc
import importlib.machinery
import importlib.util
import inspect
import os
import shutil
import sys
import tempfile
import textwrap
from pathlib import Path
from typing import NamedTuple

__all__ = ["kernel_directory", "load", "clear", "compiled", "module_text", "function_copy",
           "DEPENDENCIES", "KEEP"]

#: Library modules (relative to the repository's package root) whose compiled helpers
#: the generated kernels contain; their text is part of every generated module's hash.
DEPENDENCIES = ("plant/simulation/core.py", "plant/simulation/lanes.py",
                "plant/simulation/anchors.py", "plant/simulation/plants.py", "plant/simulation/arm.py",
                "plant/simulation/closed_loop.py", "plant/simulation/simulate.py",
                "plant/simulation/controllers.py", "plant/robot/model.py", "ctc/arm.py",
                "ctc/computed_torque.py", "ctc/flexible.py")

#: Generated modules kept in the directory (the least recently used beyond are deleted).
KEEP = 64

_ROOT = Path(__file__).resolve().parents[3]
_DIRECTORY: list = []   # the resolved directory, once


def _writable(path: Path) -> bool:
    try:
        path.mkdir(parents=True, exist_ok=True)
        fd, probe = tempfile.mkstemp(dir=path, prefix=".probe-")
        os.close(fd)
        os.unlink(probe)
        return True
    except OSError:
        return False


def kernel_directory() -> Path:
    """The directory the generated modules are written to (created if needed).

    Returns
    -------
    pathlib.Path
        ``$PUMA_GA_CTC_KERNELS``, else ``$NUMBA_CACHE_DIR/generated``, else
        ``$XDG_CACHE_HOME/puma-ga-ctc/kernels`` (``~/.cache`` by default);
        a temporary directory of this process when that one is not writable.
    """
    if _DIRECTORY:
        return _DIRECTORY[0]
    env = os.environ
    if env.get("PUMA_GA_CTC_KERNELS"):
        path = Path(env["PUMA_GA_CTC_KERNELS"])
    elif env.get("NUMBA_CACHE_DIR"):
        path = Path(env["NUMBA_CACHE_DIR"]) / "generated"
    else:
        path = Path(env.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "puma-ga-ctc" / "kernels"
    path = path.expanduser()
    if not _writable(path):
        tmp = tempfile.mkdtemp(prefix="puma-ga-ctc-kernels-")
        atexit.register(shutil.rmtree, tmp, True)
        path = Path(tmp)
    _DIRECTORY.append(path)
    return path


def _fingerprint() -> str:
    h = hashlib.sha256()
    for rel in DEPENDENCIES:
        try:
            h.update((_ROOT / rel).read_bytes())
        except OSError:  # an installation without that source: the version stands for it
            h.update(rel.encode())
    import numba

    h.update(numba.__version__.encode())
    return h.hexdigest()[:16]


_FINGERPRINT: list = []


def load(stem: str, text: str):
    """Write a generated module (unless it is there) and import it.

    Parameters
    ----------
    stem : str
        Start of the module's name (a Python identifier, e.g. ``"arm"``).
    text : str
        The module's source.  A header with the library's fingerprint is put
        in front of it; the module is ``plant.simulation.generated.<stem>_<hash>``
        with the hash of the whole text.

    Returns
    -------
    module
        The imported module (the same object on later calls in this process).

    Raises
    ------
    ValueError
        If ``stem`` is not an identifier.
    """
    if not stem.isidentifier():
        raise ValueError(f"a generated module's stem must be an identifier, got {stem!r}")
    if not _FINGERPRINT:
        _FINGERPRINT.append(_fingerprint())
    text = (f"# Generated by puma-ga-ctc (library fingerprint {_FINGERPRINT[0]}); do not edit:\n"
            f"# the file's name is the hash of its text.\n" + text)
    name = f"{stem}_{hashlib.sha256(text.encode()).hexdigest()[:20]}"
    full = f"{__name__}.{name}"
    module = sys.modules.get(full)
    if module is not None and not getattr(module, "__placeholder__", False):
        return module
    sys.modules.pop(full, None)
    directory = kernel_directory()
    path = directory / f"{name}.py"
    try:
        fresh = path.read_text(encoding="utf-8") != text
    except (OSError, UnicodeDecodeError):
        fresh = True
    if fresh:  # written whole or not at all: a temporary file renamed over the name
        fd, tmp = tempfile.mkstemp(dir=directory, prefix=f".{name}-", suffix=".tmp")
        try:
            with os.fdopen(fd, "w", encoding="utf-8") as fh:
                fh.write(text)
            os.replace(tmp, path)
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
        _prune(directory, keep=path)
    try:  # most recently used: a mark of its own (older numba dates its cache by the module's)
        (directory / f".{name}.used").touch()
    except OSError:
        pass
    return importlib.import_module(full)


def _global_names(code) -> set:
    names = set(code.co_names)
    for const in code.co_consts:
        if hasattr(const, "co_names"):
            names |= _global_names(const)
    return names


def function_copy(fn, decorator: str, defined: set) -> tuple:
    """A plain Python function's source for a generated module, and the import it needs.

    The kernels of :mod:`plant.simulation.arm` and :mod:`ctc.arm` are written
    once, as plain functions of their modules; a robot's generated module
    holds a copy of each, compiled there for that robot (so numba caches it
    with the robot's module).

    Parameters
    ----------
    fn : function
        A module-level function without decorators.
    decorator : str
        The name of the decorator the copy gets in the generated module.
    defined : set of str
        Names the generated module defines or imports already; the names
        imported for ``fn`` are added to it.

    Returns
    -------
    imports : str
        ``from <fn's module> import (...)`` of every global name ``fn``
        uses that its module has and ``defined`` does not ("" if none).
    source : str
        ``@decorator`` and ``fn``'s source.

    Raises
    ------
    ValueError
        If ``fn`` is decorated or not at module level.
    """
    source = textwrap.dedent(inspect.getsource(fn))
    if not source.startswith("def ") or fn.__qualname__ != fn.__name__:
        raise ValueError(f"{fn.__qualname__} must be a plain module-level function to be copied")
    space = vars(sys.modules[fn.__module__])
    names = sorted(n for n in _global_names(fn.__code__) if n in space and n not in defined)
    defined.update(names)
    imports = f"from {fn.__module__} import ({', '.join(names)})" if names else ""
    return imports, f"@{decorator}\n{source}"


def _files_of(directory: Path, module: Path) -> list:
    """A generated module's file, its use mark and its caches (Python's and numba's)."""
    files = [module, directory / f".{module.stem}.used",
             *(directory / "__pycache__").glob(f"{module.stem}.*")]
    numba_dir = os.environ.get("NUMBA_CACHE_DIR")
    if numba_dir:  # numba's cache of the module, in a directory of its own
        files += Path(numba_dir).glob(f"*/{module.stem}.*")
    return files


def _unlink(paths) -> int:
    n = 0
    for p in paths:
        try:
            p.unlink()
            n += 1
        except OSError:
            pass
    return n


#: What every generated module starts with: its imports, and its three decorators
#: (``_kernel``: compiled and cached on disk; ``_inline``: compiled into its callers,
#: where LLVM inlines it if it finds it small; ``_inline_always``: inlined by numba at
#: every call, whatever its size -- for the right-hand side of a small robot, which must
#: be inlined for the lane loop to vectorise).
_PRELUDE = ("import math", "from typing import NamedTuple", "", "import numba", "import numpy as np")
_DECORATORS = ("_kernel = numba.njit(cache=True, nogil=True, error_model=\"numpy\")",
               "_inline = numba.njit(nogil=True, error_model=\"numpy\")",
               "_inline_always = numba.njit(nogil=True, error_model=\"numpy\", inline=\"always\")")


def _bound_names(text: str) -> set:
    """Names a module's top level binds (imports, definitions, assignments)."""
    names = set()
    for node in ast.parse(text).body:
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            names |= {(a.asname or a.name).split(".")[0] for a in node.names}
        elif isinstance(node, (ast.FunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, ast.Assign):
            names |= {t.id for t in node.targets if isinstance(t, ast.Name)}
    return names


def module_text(doc: str, *, imports=(), body=(), copies=(), tail=()) -> str:
    """The text of a generated module, for :func:`load`.

    Parameters
    ----------
    doc : str
        Its docstring.
    imports : sequence of str
        Import lines, after ``math``, ``NamedTuple``, ``numba`` and ``numpy as np``.
    body : sequence of str
        Source after the decorators ``_kernel`` (``numba.njit`` with
        ``cache=True``), ``_inline`` (without: compiled into its callers) and
        ``_inline_always`` (inlined by numba at every call site).
    copies : sequence of (function, str)
        Plain module-level functions copied after ``body``, each under the
        named decorator (:func:`function_copy`), with the imports their
        global names need (from their own modules; none the module binds itself).
    tail : sequence of str
        Source after the copies (e.g. the registration of a copied law).

    Returns
    -------
    str
    """
    head = [repr(doc), "", *_PRELUDE, *imports]
    rest = ["", "", *_DECORATORS, "", "", *body]
    defined = _bound_names("\n".join(head + rest)) | {fn.__name__ for fn, _ in copies}
    sources = []
    for fn, decorator in copies:
        line, src = function_copy(fn, decorator, defined)
        head += [line] if line else []
        sources.append(src)
    return "\n".join(head + rest + ["", ""] + [src + "\n" for src in sources]
                     + ([*tail, ""] if tail else []))


def _prune(directory: Path, keep: Path) -> None:
    """Delete the least recently used generated modules beyond :data:`KEEP` (with their caches)."""
    def used(p):
        try:
            return (directory / f".{p.stem}.used").stat().st_mtime
        except OSError:
            return p.stat().st_mtime

    try:
        files = sorted((p for p in directory.glob("*_*.py") if p != keep), key=used, reverse=True)
    except OSError:
        return
    _unlink(p for old in files[KEEP - 1:] for p in _files_of(directory, old))


def compiled(module) -> bool:
    """Whether numba's on-disk cache holds compiled kernels of a generated module.

    Parameters
    ----------
    module : module
        A module :func:`load` returned.

    Returns
    -------
    bool
        True when the index of numba's cache holds compiled code for one of
        its kernels, made from this very file (numba's own check: the
        index's stamp of the source file, and numba's version): they load
        without compiling (unless their argument types are new).  False
        for a module first generated in this directory, whose first call
        compiles; any trouble reading the cache counts as not compiled.
    """
    for obj in vars(module).values():
        index = getattr(getattr(obj, "_cache", None), "_cache_file", None)
        if index is None or getattr(getattr(obj, "py_func", None), "__module__", None) != \
                module.__name__:  # the library's kernels it imports are not its own
            continue
        try:
            if index._load_index():  # {} when absent, stale or of another numba
                return True
        except Exception:  # noqa: BLE001 - an unreadable cache is no cache
            continue
    return False


def clear() -> int:
    """Delete every generated module of :func:`kernel_directory` and its numba cache files.

    Returns
    -------
    int
        Files deleted.  Modules already imported stay usable in this process.
    """
    directory = kernel_directory()
    n = _unlink([p for m in directory.glob("*_*.py") for p in _files_of(directory, m)])
    return n + _unlink(directory.glob(".*.used")) + _unlink((directory / "__pycache__").glob("*"))


class _Finder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Finds ``plant.simulation.generated.<name>`` in :func:`kernel_directory`.

    The directory is not on this package's ``__path__``, so tools that walk
    the library's packages (``pkgutil.walk_packages``, documentation
    builders) never import a generated module -- in particular none left
    there by another version of the library.  A name whose file is gone
    imports as an empty placeholder: numba's cache index of a kernel lists
    the signatures it holds, and unpickling it imports the classes they name
    (a generated module's plant kind); when that module was deleted
    (:func:`clear`, or :data:`KEEP` exceeded) the placeholder's classes are
    new and match no kernel, so the index still loads and the kernel
    compiles, instead of an ``ImportError`` inside numba.
    """

    def find_spec(self, fullname, path=None, target=None):
        prefix = __name__ + "."
        if not fullname.startswith(prefix) or "." in fullname[len(prefix):]:
            return None
        file = kernel_directory() / f"{fullname[len(prefix):]}.py"
        if file.is_file():
            return importlib.util.spec_from_file_location(fullname, file)
        return importlib.machinery.ModuleSpec(fullname, self)

    def create_module(self, spec):
        return None

    def exec_module(self, module):
        classes = {}

        def __getattr__(attr):
            if attr.startswith("__"):
                raise AttributeError(attr)
            if attr not in classes:
                classes[attr] = NamedTuple(attr, [("code", int)])
                classes[attr].__module__ = module.__name__
            return classes[attr]

        module.__placeholder__ = True
        module.__getattr__ = __getattr__


sys.meta_path.append(_Finder())
