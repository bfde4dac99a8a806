"""Every public function and class documents every parameter (numpydoc).

Like python-control's docstring test: walk the public API (each package's and
each module's ``__all__``, and the public methods of public classes) and
validate the docstrings with :func:`numpydoc.validate.validate`.  Checked:
a docstring exists (GL08), every parameter is documented (PR01) and no
documented parameter is unknown (PR02).
"""
from __future__ import annotations

import importlib
import inspect
import pkgutil

import pytest

numpydoc_validate = pytest.importorskip("numpydoc.validate")

PACKAGES = ("plant", "identification", "ctc")
CHECKED = {"GL08", "PR01", "PR02"}


def _modules():
    for name in PACKAGES:
        pkg = importlib.import_module(name)
        yield pkg
        for info in pkgutil.walk_packages(pkg.__path__, prefix=f"{name}."):
            if info.name.rsplit(".", 1)[-1].startswith("_"):
                continue
            yield importlib.import_module(info.name)


def _public_objects():
    seen = set()
    for mod in _modules():
        for attr in getattr(mod, "__all__", ()):
            obj = getattr(mod, attr, None)
            if obj is None or not (inspect.isclass(obj) or callable(obj)):
                continue
            home = getattr(obj, "__module__", "") or ""
            if not home.split(".")[0] in PACKAGES:
                continue
            qual = f"{home}.{getattr(obj, '__qualname__', attr)}"
            if qual in seen:
                continue
            seen.add(qual)
            yield qual, obj
            if inspect.isclass(obj):
                for mname, member in vars(obj).items():
                    if mname.startswith("_") or not (inspect.isfunction(member)
                                                     or isinstance(member, (classmethod,
                                                                            staticmethod))):
                        continue
                    yield f"{qual}.{mname}", getattr(obj, mname)


def _attributes(target):
    """Names listed in a class docstring's Attributes section."""
    doc = numpydoc_validate.get_doc_object(target)
    names = set()
    for item in doc["Attributes"]:
        for n in item.name.split(","):
            names.add(n.strip())
    return names


def _problems(qual, obj):
    target = getattr(obj, "py_func", obj)  # numba dispatchers: the Python function
    res = numpydoc_validate.validate(numpydoc_validate.get_doc_object(target))
    out = []
    for code, msg in res["errors"]:
        if code not in CHECKED:
            continue
        if code == "PR01" and inspect.isclass(target):
            # a data class documents its fields as Attributes (numpydoc's convention)
            sig = inspect.signature(target)
            missing = {p for p in sig.parameters if p not in ("args", "kwargs")}
            documented = _attributes(target)
            params = {i.name.split(":")[0].strip() for i in
                      numpydoc_validate.get_doc_object(target)["Parameters"]}
            if not (missing - documented - params - {"*args", "**kwargs"}):
                continue
        out.append(f"{qual}: {code} {msg}")
    return out


def test_every_public_callable_documents_its_parameters():
    problems = []
    for qual, obj in _public_objects():
        problems.extend(_problems(qual, obj))
    assert not problems, "\n".join(problems)
