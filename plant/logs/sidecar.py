"""The JSON sidecar of a rig log: rig constants, trajectory, start state, window.

:func:`rig_from_sidecar` reads a sidecar's rig constants into a
:class:`plant.logs.rig.Rig` (raising :class:`plant.LogError` with a one-line
message naming the key at fault); the inverse writes a rig back into a
sidecar dict (:meth:`plant.logs.log.ExperimentLog.save`).
"""
from __future__ import annotations

import json
import math
import re
from pathlib import Path
from typing import Any, Mapping

from plant._errors import LogError
from plant.logs.rig import F_NAMES, Rig

__all__ = ["rig_from_sidecar"]

#: Coulomb ramp speed used when every Coulomb value is zero (then it has no effect).
_UNUSED_RAMP_SPEED = 1.0

#: Coulomb ramp speed (motor side, rad/s) when the Coulomb friction is unknown
#: (null) and neither ``coulomb_ramp_speed_rad_per_s`` nor the note gives one:
#: 0.5 rad/s, well below the motor speeds of a moving joint (tens to hundreds
#: of rad/s), so the identified Coulomb levels hardly depend on it.
DEFAULT_UNKNOWN_RAMP_SPEED = 0.5

_RAMP_NOTE_RE = re.compile(r"below\s+([0-9.eE+-]+)\s*rad/s")


# --------------------------------------------------------------------------- helpers
def _one_line(msg: str) -> str:
    return msg.replace("\r", "\\r").replace("\n", "\\n")


def sidecar_error(source: Any, msg: str) -> LogError:
    return LogError(_one_line(f"{source}: {msg}"))


def short_text(value: Any, n: int = 60) -> str:
    r = repr(value)
    return r if len(r) <= n else r[: n - 3] + "..."


def _is_number(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


# ------------------------------------------------------------------- sidecar parsing
class SidecarKeys:
    """Typed access to sidecar keys with one-line LogErrors naming the key."""

    def __init__(self, data: Mapping[str, Any], source: Any):
        self.data = data
        self.source = source

    def err(self, key: str, msg: str) -> LogError:
        return sidecar_error(self.source, f"key '{key}' {msg}")

    def get(self, key: str, *, required: bool = True, default: Any = None) -> Any:
        node: Any = self.data
        parts = key.split(".")
        for i, part in enumerate(parts):
            if not isinstance(node, Mapping):
                raise self.err(".".join(parts[:i]), "must be an object")
            if part not in node:
                if required:
                    raise self.err(".".join(parts[: i + 1]), "is missing")
                return default
            node = node[part]
        return node

    def _check(self, key: str, x: Any, what: str, positive: bool, nonneg: bool,
               nonzero: bool, integer: bool) -> float | int:
        if not _is_number(x):
            raise self.err(key, f"must be {what}, got {short_text(x)}")
        if not math.isfinite(x):
            raise self.err(key, f"must be finite, got {short_text(x)}")
        if integer:
            if float(x) != math.floor(x):
                raise self.err(key, f"must be an integer, got {short_text(x)}")
            x = int(x)
        if positive and not x > 0:
            raise self.err(key, f"must be > 0, got {short_text(x)}")
        if nonneg and not x >= 0:
            raise self.err(key, f"must be >= 0, got {short_text(x)}")
        if nonzero and x == 0:
            raise self.err(key, "must be nonzero")
        return x if integer else float(x)

    def number(self, key: str, *, positive=False, nonneg=False, nonzero=False,
               integer=False, required=True, default=None):
        x = self.get(key, required=required, default=default)
        if x is None and not required:
            return default
        return self._check(key, x, "an integer" if integer else "a number",
                           positive, nonneg, nonzero, integer)

    def vector(self, key: str, n: int = 2, *, positive=False, nonneg=False,
               nonzero=False, integer=False, value: Any = None) -> tuple:
        x = self.get(key) if value is None else value
        what = f"a list of {n} {'integers' if integer else 'numbers'}"
        if not isinstance(x, (list, tuple)) or len(x) != n:
            raise self.err(key, f"must be {what}, got {short_text(x)}")
        return tuple(
            self._check(f"{key}[{i}]", v, "an integer" if integer else "a number",
                        positive, nonneg, nonzero, integer)
            for i, v in enumerate(x)
        )


def _ramp_speed_from_note(note: Any) -> float | None:
    if not isinstance(note, str):
        return None
    m = _RAMP_NOTE_RE.search(note)
    if not m:
        return None
    try:
        return float(m.group(1))
    except ValueError:
        return None


def rig_from_sidecar(sidecar: Mapping[str, Any], source: Any = "sidecar", n_joints: int = 2,
                     robot_model: bool = False) -> Rig:
    """Build the :class:`~plant.logs.rig.Rig` described by a log sidecar.

    Parameters
    ----------
    sidecar : mapping
        The parsed ``STEM.json``. Keys read: ``sample_time_s`` (s, > 0),
        ``gear_ratio`` (2, nonzero), ``encoder_ppr`` (2 positive integers),
        ``p_gain_A_per_pulse`` (2, > 0), ``torque_constant_Nm_per_A`` (2, > 0),
        ``viscous_friction_Nms_per_rad`` (2, >= 0; null or absent: unknown),
        ``coulomb_friction_Nm`` ([[pos, neg], [pos, neg]], >= 0; null or
        absent: unknown -- the rig's field is then None and
        :func:`identification.identify` estimates it with f),
        ``coulomb_ramp_speed_rad_per_s`` (> 0) or else the speed in
        ``coulomb_friction_note`` ("... below 0.5 rad/s ..."),
        ``gravity_m_s2``, ``a3_m``, ``start_state.q_rad`` (2),
        ``start_state.qd_rad_per_s`` (2) (both optional in a window log,
        ``window_s`` set: then the rig's ``q0_rad`` and ``qd0_rad_per_s`` are
        None, the start of the run being unknown), ``f_search_ranges`` (``f1``..``f9``
        -> [low, high], low < high), optional ``current_full_scale_A``
        (> 0 or null) and ``payload`` (null or ``{"mass_kg": number or null}``).
        When every Coulomb value is zero and no ramp speed is given, the ramp
        speed is set to 1.0 rad/s; it has no effect then.  When the Coulomb
        friction is unknown and no ramp speed is given, it is
        ``DEFAULT_UNKNOWN_RAMP_SPEED`` (0.5 rad/s).
    source : str or Path, optional
        File name used in error messages.
    n_joints : int, optional
        Length of the per-joint lists (2 for the PUMA links 2-3).
    robot_model : bool, optional
        The log of a robot model's arm (a ``robot`` object in the sidecar,
        :mod:`plant.logs.arm_log`): ``a3_m`` and ``f_search_ranges`` (PUMA links
        2-3 only) are not read.

    Returns
    -------
    Rig

    Raises
    ------
    LogError
        A key is missing, has the wrong shape, a non-finite or out-of-range
        value, or a search range is inverted (low > high) or empty
        (low == high).
    """
    k = SidecarKeys(sidecar, source)
    if not isinstance(sidecar, Mapping):
        raise sidecar_error(source, "sidecar must be a JSON object")
    nj = int(n_joints)
    ts = k.number("sample_time_s", positive=True)
    gear = k.vector("gear_ratio", nj, nonzero=True)
    ppr = k.vector("encoder_ppr", nj, integer=True, positive=True)
    p_gain = k.vector("p_gain_A_per_pulse", nj, positive=True)
    kt = k.vector("torque_constant_Nm_per_A", nj, positive=True)
    # null or absent friction: unknown (None), identified with f (plant.simulation.friction)
    visc = None
    if sidecar.get("viscous_friction_Nms_per_rad") is not None:
        visc = k.vector("viscous_friction_Nms_per_rad", nj, nonneg=True)
    coul_raw = sidecar.get("coulomb_friction_Nm")
    coul = None
    if coul_raw is not None:
        if not isinstance(coul_raw, (list, tuple)) or len(coul_raw) != nj:
            shape = ", ".join(["[pos, neg]"] * nj) if nj <= 3 else "[pos, neg], ..."
            raise k.err("coulomb_friction_Nm", f"must be [{shape}] ({nj} x 2 numbers) "
                        f"or null, got {short_text(coul_raw)}")
        coul = tuple(k.vector(f"coulomb_friction_Nm[{j}]", nonneg=True, value=coul_raw[j])
                     for j in range(nj))
    ramp = k.number("coulomb_ramp_speed_rad_per_s", positive=True, required=False)
    if ramp is None:
        note = sidecar.get("coulomb_friction_note")
        ramp = _ramp_speed_from_note(note)
        if ramp is not None and not (math.isfinite(ramp) and ramp > 0):
            raise k.err("coulomb_friction_note", f"gives a ramp speed that is not > 0: {ramp!r}")
        if ramp is None and coul is None:
            ramp = DEFAULT_UNKNOWN_RAMP_SPEED
        if ramp is None:
            if any(v != 0.0 for row in coul for v in row):
                raise k.err(
                    "coulomb_ramp_speed_rad_per_s",
                    "is missing and 'coulomb_friction_note' names no 'below X rad/s' "
                    "(needed for the Coulomb friction ramp)",
                )
            ramp = _UNUSED_RAMP_SPEED
    gravity = k.number("gravity_m_s2")
    a3 = 0.0 if robot_model else k.number("a3_m")
    start = sidecar.get("start_state")
    if (sidecar.get("window_s") is not None
            and not (isinstance(start, Mapping) and ("q_rad" in start or "qd_rad_per_s" in start))):
        q0 = qd0 = None  # a window of a run whose start is unknown
    else:
        q0 = k.vector("start_state.q_rad", nj)
        qd0 = k.vector("start_state.qd_rad_per_s", nj)

    full_scale = k.number("current_full_scale_A", positive=True, required=False)
    if robot_model:  # no PUMA-specific search ranges, no payload mass
        return Rig(sample_time_s=ts, gear_ratio=gear, encoder_ppr=ppr, p_gain_A_per_pulse=p_gain,
                   torque_constant_Nm_per_A=kt, viscous_friction_Nms_per_rad=visc,
                   coulomb_friction_Nm=coul, coulomb_ramp_speed_rad_per_s=float(ramp),
                   gravity_m_s2=gravity, a3_m=a3, q0_rad=q0, qd0_rad_per_s=qd0, f_bounds=(),
                   current_full_scale_A=full_scale)

    ranges = k.get("f_search_ranges")
    if not isinstance(ranges, Mapping):
        raise k.err("f_search_ranges", "must be an object with keys f1..f9")
    extra = [name for name in ranges if name not in F_NAMES]
    if extra:
        raise k.err(f"f_search_ranges.{extra[0]}", "is not one of f1..f9")
    bounds = []
    for name in F_NAMES:
        key = f"f_search_ranges.{name}"
        lo, hi = k.vector(key)
        if lo > hi:
            raise k.err(key, f"is inverted: low {lo!r} > high {hi!r}")
        if lo == hi:
            raise k.err(key, f"is empty: low == high == {lo!r}")
        bounds.append((lo, hi))

    payload = sidecar.get("payload")
    if payload is None:
        mass = None
    elif isinstance(payload, Mapping):
        mass = k.number("payload.mass_kg", nonneg=True, required=False)
    else:
        raise k.err("payload", f"must be null or an object, got {short_text(payload)}")

    return Rig(
        sample_time_s=ts,
        gear_ratio=gear,
        encoder_ppr=ppr,
        p_gain_A_per_pulse=p_gain,
        torque_constant_Nm_per_A=kt,
        viscous_friction_Nms_per_rad=visc,
        coulomb_friction_Nm=coul,
        coulomb_ramp_speed_rad_per_s=float(ramp),
        gravity_m_s2=gravity,
        a3_m=a3,
        q0_rad=q0,
        qd0_rad_per_s=qd0,
        f_bounds=tuple(bounds),
        current_full_scale_A=full_scale,
        payload_mass_kg=mass,
    )


def rig_into_sidecar(rig: Rig, d: dict) -> None:
    """Write the numeric values of ``rig`` into sidecar dict ``d`` (in place).

    ``a3_m`` and ``f_search_ranges`` describe the PUMA 560 links 2-3: they
    are written for a rig with search ranges (``rig.f_bounds``), not for a
    robot model's rig (:mod:`plant.logs.arm_log`).
    """
    d["sample_time_s"] = float(rig.sample_time_s)
    d["gear_ratio"] = [float(x) for x in rig.gear_ratio]
    d["encoder_ppr"] = [int(x) for x in rig.encoder_ppr]
    d["p_gain_A_per_pulse"] = [float(x) for x in rig.p_gain_A_per_pulse]
    d["torque_constant_Nm_per_A"] = [float(x) for x in rig.torque_constant_Nm_per_A]
    visc, coul = rig.viscous_friction_Nms_per_rad, rig.coulomb_friction_Nm
    d["viscous_friction_Nms_per_rad"] = None if visc is None else [float(x) for x in visc]
    d["coulomb_friction_Nm"] = None if coul is None else [[float(v) for v in r] for r in coul]
    ramp = float(rig.coulomb_ramp_speed_rad_per_s)
    # The numeric key wins over the note on loading: write it unless the note
    # already states exactly this speed.
    note_speed = _ramp_speed_from_note(d.get("coulomb_friction_note"))
    if "coulomb_ramp_speed_rad_per_s" in d or note_speed != ramp:
        d["coulomb_ramp_speed_rad_per_s"] = ramp
    d["gravity_m_s2"] = float(rig.gravity_m_s2)
    if rig.f_bounds:
        d["a3_m"] = float(rig.a3_m)
    start = d.get("start_state")
    start = dict(start) if isinstance(start, Mapping) else {}
    if rig.q0_rad is None or rig.qd0_rad_per_s is None:  # window without a start state
        start.pop("q_rad", None)
        start.pop("qd_rad_per_s", None)
    else:
        start["q_rad"] = [float(x) for x in rig.q0_rad]
        start["qd_rad_per_s"] = [float(x) for x in rig.qd0_rad_per_s]
    d["start_state"] = start
    if rig.f_bounds:
        ranges = d.get("f_search_ranges")
        ranges = dict(ranges) if isinstance(ranges, Mapping) else {}
        for name, (lo, hi) in zip(F_NAMES, rig.f_bounds):
            ranges[name] = [float(lo), float(hi)]
        d["f_search_ranges"] = ranges
    if rig.current_full_scale_A is None:
        d.pop("current_full_scale_A", None)
    else:
        d["current_full_scale_A"] = float(rig.current_full_scale_A)
    payload = d.get("payload")
    if rig.payload_mass_kg is None:
        if isinstance(payload, Mapping) and payload.get("mass_kg") is not None:
            payload = dict(payload)
            payload["mass_kg"] = None
            d["payload"] = payload
    else:
        payload = dict(payload) if isinstance(payload, Mapping) else {}
        payload["mass_kg"] = float(rig.payload_mass_kg)
        d["payload"] = payload


def parse_window(sidecar: Mapping[str, Any], source: Any) -> tuple[float, float] | None:
    w = sidecar.get("window_s")
    if w is None:
        return None
    k = SidecarKeys(sidecar, source)
    start, stop = k.vector("window_s")
    if start < 0:
        raise k.err("window_s", f"start must be >= 0, got {start!r}")
    if not start < stop:
        raise k.err("window_s", f"must be [start, stop] with start < stop, got {short_text(w)}")
    return (start, stop)


def read_text(path: Path, what: str) -> str:
    try:
        with open(path, "r", encoding="utf-8-sig", newline="") as fh:
            return fh.read()
    except FileNotFoundError:
        raise sidecar_error(path, f"{what} not found") from None
    except IsADirectoryError:
        raise sidecar_error(path, f"{what} is a directory") from None
    except UnicodeDecodeError as e:
        raise sidecar_error(path, f"{what} is not UTF-8 text (byte {e.start})") from None
    except OSError as e:
        raise sidecar_error(path, f"cannot read {what} ({e.strerror or e})") from None


def read_sidecar(path: Path) -> dict:
    text = read_text(path, "sidecar")
    if not text.strip():
        raise sidecar_error(path, "empty sidecar (no JSON)")
    try:
        data = json.loads(text)
    except json.JSONDecodeError as e:
        raise sidecar_error(path, f"invalid JSON at line {e.lineno} column {e.colno}: {e.msg}") from None
    except RecursionError:
        raise sidecar_error(path, "sidecar is nested too deeply to be read (JSON nesting beyond "
                         "Python's recursion limit)") from None
    if not isinstance(data, dict):
        raise sidecar_error(path, f"sidecar must be a JSON object, got {type(data).__name__}")
    return data
