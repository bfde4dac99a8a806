"""The JSON schema of an identification result: writing, reading, checking.

:class:`identification.IdentificationResult` is the container; this module
holds what its JSON file is (:data:`REQUIRED_KEYS`, :func:`result_dict`,
:func:`read_result_file`), how it is written (:func:`write_json_atomic`,
the policy of :mod:`plant.logs.fileio`) and the texts the file and the plots
share (:func:`describe_setting`, :func:`format_output_error`).
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from plant.logs.fileio import read_json_object, write_text_atomic
from plant.logs.rig import F_NAMES, F_UNITS

__all__ = ["REQUIRED_KEYS", "ResultFileError", "write_json_atomic", "jsonable",
           "describe_setting", "format_output_error", "result_dict", "read_result_file"]

#: Keys written by :meth:`identification.IdentificationResult.to_dict` that
#: :meth:`identification.IdentificationResult.load_json` requires (an alternative older name
#: in parentheses): ``f``, ``fun`` (``objective_pulses2``), ``nfev``
#: (``evaluations``), ``method``.
REQUIRED_KEYS = (("f",), ("fun", "objective_pulses2"), ("nfev", "evaluations"), ("method",))


class ResultFileError(ValueError):
    """A result file that cannot be read back (one-line message naming the file)."""


def write_json_atomic(path, data, *, create_dirs=True):
    """Write ``data`` as JSON to ``path`` atomically (policy of :mod:`plant.logs.fileio`).

    The text is produced first (``allow_nan=False``), so a value JSON cannot
    hold raises before anything is written; no partial file is ever left.

    Parameters
    ----------
    path : str or os.PathLike
        Output file.  A symlink is written through; a directory, device,
        FIFO or socket is refused.
    data : object
        JSON-serialisable data (finite floats only).
    create_dirs : bool
        Create a missing parent directory (default, as this function always
        did); the created directories are listed in the returned
        ``created_dirs``.  False refuses a missing directory.

    Returns
    -------
    plant.logs.fileio.OutputTarget
        The file written (``target``) and the directories created
        (``created_dirs``).

    Raises
    ------
    TypeError, ValueError
        If ``data`` is not JSON-serialisable (nothing is written).
    plant.logs.fileio.OutputFileError
        If the target is refused by the output-file policy.
    OSError
        If writing fails.
    """
    text = json.dumps(data, indent=2, allow_nan=False) + "\n"
    return write_text_atomic(path, text, create_dirs=create_dirs)


def jsonable(x):
    """``x`` with numpy types as Python ones and non-finite floats as None (JSON-ready).

    Parameters
    ----------
    x : object
        Nested dicts, lists, tuples, ndarrays and numbers.
    """
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [jsonable(v) for v in x]
    if isinstance(x, np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, np.bool_):
        return bool(x)
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        x = float(x)
        return x if math.isfinite(x) else None
    return x


def describe_setting(substeps, lowpass_hz=None, *, identification_substeps=None):
    """Human-readable integration setting of an output error.

    Parameters
    ----------
    substeps : int
        RK4 steps per sample of the simulation.
    lowpass_hz : float, optional
        Cutoff (Hz) of the zero-phase low-pass applied to both error
        sequences, if any.
    identification_substeps : int, optional
        The identification's setting; when ``substeps`` equals it the text
        says "(identification)".

    Returns
    -------
    str
        E.g. ``"1 RK4 step/sample (identification)"`` or
        ``"exact reproduction, 48 RK4 steps/sample"``.
    """
    from plant import DEFAULT_SUBSTEPS

    n = int(substeps)
    steps = f"{n} RK4 step{'s' if n != 1 else ''}/sample"
    tags = []
    if identification_substeps is not None and n == int(identification_substeps):
        tags.append("identification")
    if n == DEFAULT_SUBSTEPS:
        tags.append("exact reproduction")
    if tags == ["exact reproduction"]:
        text = f"exact reproduction, {steps}"
    elif tags:
        text = f"{steps} ({', '.join(tags)})"
    else:
        text = steps
    if lowpass_hz is not None:
        text += f", low-passed at {float(lowpass_hz):.4g} Hz"
    return text


def format_output_error(y):
    """The one format of an output error (pulses^2) in text, titles and tables.

    Parameters
    ----------
    y : float or None
        Output error (pulses^2); None prints ``nan``.
    """
    return "nan" if y is None else f"{float(y):.6g}"



def result_dict(res) -> dict:
    """The JSON-ready dict of a result: the keys of the CLI's result file.

    Parameters
    ----------
    res : identification.IdentificationResult
        See :meth:`identification.IdentificationResult.to_dict` for the keys.

    Returns
    -------
    dict
    """
    f = np.asarray(res.f, dtype=float)
    fun = float(res.fun)
    nfev = res.get("nfev")
    nit = res.get("nit")
    x = res.get("x")
    d = {
        "f": [float(v) for v in f],
        "f_named": {n: float(v) for n, v in zip(F_NAMES, f)},
        "f_units": dict(zip(F_NAMES, F_UNITS)),
        "objective_pulses2": fun,
        "x": None if x is None else np.asarray(x, dtype=float).ravel(),
        "x_names": res.names_of_x(),
        "parameters": res.parameterisation_name(),
        "fun": fun,
        "nfev": None if nfev is None else int(nfev),
        "nit": None if nit is None else int(nit),
        "evaluations": None if nfev is None else int(nfev),
        "success": bool(res.get("success", not res.get("interrupted", False))),
        "message": res.get("message", ""),
        "method": res.get("method"),
        "seed": res.get("seed"),
        "log": res.get("log_name"),
        "interrupted": bool(res.get("interrupted", False)),
        "bounds": res.get("bounds"),
        "settings": res.settings_dict(),
        "setting": res.setting_text(),
        "history": res.get("history", {}),
        "refinement": res.get("refinement"),
        "wall_time_s": float(res.get("wall_time_s") or 0.0),
        "compile_time_s": res.get("compile_time_s"),
    }
    from .uncertainty import RESULT_KEYS  # standard errors (issue 15)
    d.update({k: res[k] for k in RESULT_KEYS if res.get(k) is not None})
    payload = res.get("payload")
    if payload:
        d["payload"] = payload
        for k, v in payload.items():
            d[f"payload_{k}"] = v
    from .models import MODEL_KEYS  # rigid/flexible model and friction (always written)

    d.update({key: res.get(key) for key in MODEL_KEYS})
    if d["model"] is None:
        d["model"] = "rigid"
    return jsonable(d)



def read_result_file(path) -> dict:
    """The fields of a result file, checked (:meth:`identification.IdentificationResult.load_json`).

    Parameters
    ----------
    path : str or os.PathLike
        A file written by ``save_json`` or the CLI's ``--output``.

    Returns
    -------
    dict
        Keyword arguments of :class:`identification.IdentificationResult`.

    Raises
    ------
    ResultFileError
        One line naming the file: missing, unreadable, not JSON, a required
        key missing or malformed.
    """
    p = Path(path)
    try:
        d = read_json_object(p, "result file")
    except ValueError as e:
        raise ResultFileError(str(e)) from None
    for alternatives in REQUIRED_KEYS:
        if not any(k in d for k in alternatives):
            raise ResultFileError(f"{p}: missing key {alternatives[0]!r} "
                                  "(not an identification result file?)")

    def num_array(key, value, shape=None):
        try:
            a = np.array([np.nan if v is None else v for v in value]
                         if isinstance(value, list) and np.ndim(value) == 1 else value,
                         dtype=float)
        except (TypeError, ValueError):
            raise ResultFileError(f"{p}: key {key!r} must hold numbers") from None
        if shape is not None and (a.ndim != len(shape) or any(
                s is not None and a.shape[i] != s for i, s in enumerate(shape))):
            raise ResultFileError(f"{p}: key {key!r} has shape {a.shape}, expected "
                                  f"{tuple('k' if s is None else s for s in shape)}")
        return a

    def number(key, value, kind=float):
        if value is None:
            return np.nan if kind is float else None
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ResultFileError(f"{p}: key {key!r} must be a number, got {value!r}")
        return kind(value)

    f = num_array("f", d["f"], (9,))
    fun = number("fun", d.get("fun", d.get("objective_pulses2")))
    nfev = number("nfev", d.get("nfev", d.get("evaluations")), int)
    x = num_array("x", d["x"], (None,)) if d.get("x") is not None else f.copy()
    bounds = d.get("bounds")
    if bounds is not None:
        bounds = num_array("bounds", bounds, (x.size, 2))
    hist = d.get("history") or {}
    if not isinstance(hist, dict):
        raise ResultFileError(f"{p}: key 'history' must be an object")
    history = {}
    for k, v in hist.items():
        a = num_array(f"history.{k}", v)
        if k in ("generation", "nfev") and np.all(np.isfinite(a)):
            a = a.astype(np.int64)
        history[k] = a
    refinement = d.get("refinement")
    if refinement is not None:
        if not isinstance(refinement, dict):
            raise ResultFileError(f"{p}: key 'refinement' must be an object or null")
        refinement = {k: (num_array(f"refinement.{k}", v) if isinstance(v, list) else v)
                      for k, v in refinement.items()}
    settings = d.get("settings") or {}
    if not isinstance(settings, dict):
        raise ResultFileError(f"{p}: key 'settings' must be an object")
    nit = d.get("nit")
    kw = dict(
        x=x, f=f, fun=fun, nfev=nfev, nit=None if nit is None else number("nit", nit, int),
        success=bool(d.get("success", not d.get("interrupted", False))),
        message=str(d.get("message", "")),
        population=None, population_energies=None,
        method=str(d["method"]), seed=d.get("seed"), history=history,
        refinement=refinement,
        wall_time_s=number("wall_time_s", d.get("wall_time_s")),
        compile_time_s=number("compile_time_s", d.get("compile_time_s")),
        interrupted=bool(d.get("interrupted", False)),
        log_name=d.get("log"), log=None, bounds=bounds,
        x_names=[str(n) for n in d["x_names"]] if d.get("x_names") else None,
        parameters=d.get("parameters"), settings=settings,
    )
    if d.get("payload") is not None:
        kw["payload"] = d["payload"]
    from .uncertainty import RESULT_KEYS  # standard errors (issue 15)
    for k in RESULT_KEYS:
        if d.get(k) is not None:
            kw[k] = d[k] if k in ("poorly_excited", "uncertainty") else num_array(k, d[k])
    from .models import MODEL_KEYS

    for key in MODEL_KEYS:
        if key in d:
            kw[key] = d[key]
    return kw

