"""Logs of any serial arm: CSV columns per named joint, the robot in the sidecar.

A robot model's log is the PUMA log's format (:mod:`plant.logs.log`) for n named
joints:

* CSV header ``t_s, q<j>_ref_rad..., e<j>_pulses..., i<j>_A...`` with ``<j>``
  the joint's name without its leading ``q`` (joint names ``q1, q2, q3``
  give ``q1_ref_rad, ..., e1_pulses, ..., i1_A, ...``; a joint named
  ``shoulder`` gives ``qshoulder_ref_rad``, ``eshoulder_pulses``,
  ``ishoulder_A``);
* the JSON sidecar has the rig keys of a PUMA sidecar with one entry per
  joint (``sample_time_s``, ``gear_ratio``, ``encoder_ppr``,
  ``p_gain_A_per_pulse``, ``torque_constant_Nm_per_A``,
  ``viscous_friction_Nms_per_rad``, ``coulomb_friction_Nm``,
  ``coulomb_ramp_speed_rad_per_s``, ``gravity_m_s2``, ``start_state``,
  ``trajectory.parameters``, optional ``current_full_scale_A``) and a
  ``robot`` **object** naming the robot and its joints:

  - a DH table inline: ``{"name", "convention": "standard" | "modified",
    "links": [{"a", "alpha", "d", "offset", "mass", "com", "inertia",
    "motor_inertia"}, ...], "active": [indices], "locked": {index: angle},
    "gravity": [gx, gy, gz], "joint_names": [...]}``;
  - or a URDF: ``{"urdf": "path relative to the sidecar", "joints": [names],
    "locked": {name: angle}, "motor_inertias": {name: Jm}, "gravity": [...]}``.

  The drive's gear ratios are the sidecar's ``gear_ratio`` (they set the
  model's reflected motor inertias ``Jm k^2`` too).

A sidecar whose ``robot`` is absent or a string (the development logs' free
text) is a PUMA 560 links 2-3 log (columns ``q2_ref_rad, q3_ref_rad,
e2_pulses, ...``, the rig keys of :func:`plant.load_log`, which reads it
unchanged for the paper's f1..f9 path).  :func:`load_arm_log` reads it too:
the arrays, rig and trajectory of :func:`plant.load_log`, and as the robot
:meth:`RobotModel.puma560_links23 <plant.robot.robot_model.RobotModel.puma560_links23>`
with the sidecar's gear ratios and g -- the paper's model as a robot-model
instance, its parameters f1..f9.
"""
from __future__ import annotations

import csv
import io
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from plant._errors import LogError
from plant.logs.fileio import write_text_atomic
from plant.logs.rig import Rig
from plant.logs.sidecar import read_sidecar, read_text, rig_from_sidecar, sidecar_error
from plant.logs.trajectory import Trajectory

__all__ = ["ArmLog", "load_arm_log", "robot_from_sidecar", "robot_section",
           "column_names", "is_arm_sidecar", "arm_rig", "links23_model"]


def __getattr__(name):
    """``plant.logs.arm_log.emulate_arm_log`` (the name issue 23 gives it) is
    :func:`plant.simulation.synthetic.emulate_arm_log`: the emulator is the
    simulator's, so it is imported on first use (logs never import the
    simulator at import time)."""
    if name == "emulate_arm_log":
        from plant.simulation.synthetic import emulate_arm_log

        return emulate_arm_log
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def column_names(joint_names) -> list:
    """CSV header of a robot model's log, ``t_s`` then per joint q_ref, e, i.

    Parameters
    ----------
    joint_names : sequence of str

    Returns
    -------
    list of str
    """
    sfx = [n[1:] if n.startswith("q") and len(n) > 1 else n for n in joint_names]
    return (["t_s"] + [f"q{s}_ref_rad" for s in sfx] + [f"e{s}_pulses" for s in sfx]
            + [f"i{s}_A" for s in sfx])


def is_arm_sidecar(sidecar) -> bool:
    """Whether a sidecar describes a robot model's log (its ``robot`` is an object).

    Parameters
    ----------
    sidecar : dict
        A parsed sidecar.

    Returns
    -------
    bool
    """
    return isinstance(sidecar, dict) and isinstance(sidecar.get("robot"), dict)


def robot_section(model) -> dict:
    """The sidecar's ``robot`` object of a DH model (inline table).

    Parameters
    ----------
    model : plant.robot.robot_model.RobotModel
        A DH model (``convention`` standard or modified).

    Returns
    -------
    dict

    Raises
    ------
    ValueError
        For a URDF model (write ``{"urdf": path, "joints": [...]}`` instead)
        or a :class:`~plant.robot.robot_model.BasisModel` (the PUMA 560
        links 2-3 instance: its sidecar has no ``robot`` section).
    """
    from plant.robot.robot_model import BasisModel

    if isinstance(model, BasisModel):
        raise ValueError(f"{model.name} has its parameters in a named basis ({model.basis.name}): "
                         "a DH table would lose it; its log is a sidecar without 'robot'")
    if model.convention not in ("standard", "modified"):
        raise ValueError("only a DH model is written inline; name a URDF model by its file")
    links = []
    for ln in model.links:
        links.append(dict(a=ln.a, alpha=ln.alpha, d=ln.d, offset=ln.offset, mass=ln.mass,
                          com=[float(v) for v in ln.com],
                          inertia=np.asarray(ln.inertia, dtype=float).tolist(),
                          motor_inertia=ln.motor_inertia))
        if ln.flip:  # written only when set: the sidecars of unflipped tables are unchanged
            links[-1]["flip"] = True
    locked = {str(i): float(model.locked_angles[i]) for i in range(len(model.links))
              if i not in model.active and model.locked_angles[i] != 0.0}
    return dict(name=model.name, convention=model.convention, links=links,
                active=list(model.active), locked=locked,
                gravity=[float(v) for v in model.gravity], joint_names=list(model.joint_names))


def robot_from_sidecar(section, gear_ratios, base_dir=".", source="sidecar"):
    """The :class:`~plant.robot.robot_model.RobotModel` of a sidecar's ``robot`` object.

    Parameters
    ----------
    section : dict
        The ``robot`` object (module docstring).
    gear_ratios : sequence of float
        The drive's gear ratios of the active joints (the sidecar's ``gear_ratio``).
    base_dir : path-like
        Directory a relative URDF path is relative to.
    source : str
        Name for error messages.

    Returns
    -------
    plant.robot.robot_model.RobotModel

    Raises
    ------
    LogError
        A malformed section (one line naming the key).
    """
    from plant.robot.robot_model import Link, RobotModel

    def err(msg):
        return sidecar_error(source, f"key 'robot' {msg}")

    if not isinstance(section, dict):
        raise err("must be an object")
    try:
        if "urdf" in section:
            path = Path(base_dir) / str(section["urdf"])
            joints = section.get("joints")
            gear = dict(zip(joints, gear_ratios)) if joints else None
            model = RobotModel.from_urdf(path, active=joints, locked=section.get("locked"),
                                         gear_ratios=gear,
                                         motor_inertias=section.get("motor_inertias"),
                                         gravity=section.get("gravity", (0.0, 0.0, -9.81)),
                                         name=section.get("name"))
        else:
            rows = section.get("links")
            if not isinstance(rows, list) or not rows:
                raise err("needs 'links' (a DH table) or 'urdf'")
            active = section.get("active")
            active = list(range(len(rows))) if active is None else [int(i) for i in active]
            locked = {int(k): float(v) for k, v in (section.get("locked") or {}).items()}
            if len(gear_ratios) != len(active):
                raise err(f"has {len(active)} active joints, gear_ratio {len(gear_ratios)} entries")
            links = []
            for i, row in enumerate(rows):
                if not isinstance(row, dict):
                    raise err(f"links[{i}] must be an object of DH and inertial values")
                row = dict(row)
                if i in active:
                    row["gear_ratio"] = float(gear_ratios[active.index(i)])
                links.append(Link(**row))
            model = RobotModel(links, convention=section.get("convention", "standard"),
                               active=active, locked=locked,
                               gravity=section.get("gravity", (0.0, 0.0, -9.81)),
                               name=section.get("name", "robot"),
                               joint_names=section.get("joint_names"))
    except LogError:
        raise
    except (TypeError, ValueError, KeyError, OSError) as exc:
        raise err(f"does not describe a robot: {str(exc).splitlines()[0] if str(exc) else exc!r}") from None
    if model.n_joints != len(gear_ratios):
        raise err(f"has {model.n_joints} active joints, gear_ratio {len(gear_ratios)} entries")
    return model


@dataclass(frozen=True, eq=False)
class ArmLog:
    """A logged P-control experiment of a robot model's arm (n joints).

    Attributes
    ----------
    path : Path or None
        The CSV file (None in memory).
    name : str
    model : plant.robot.robot_model.RobotModel
        The robot (from the sidecar's ``robot`` object).
    rig : plant.Rig
        Rig constants (per-joint tuples of n).
    trajectory : plant.Trajectory
        Reference of the n joints.
    t : ndarray, shape (n_samples,)
        Sample times (s).
    q_ref : ndarray, shape (n_samples, n)
        Reference angles (rad).
    e_pulses : ndarray, shape (n_samples, n), int64
        Logged errors ``trunc(q_ref k N / 2 pi) - trunc(q k N / 2 pi)``.
    i_A : ndarray, shape (n_samples, n)
        Currents applied over each sample (A).
    sidecar : dict
    """

    path: Path | None
    name: str
    model: object
    rig: Rig
    trajectory: Trajectory
    t: np.ndarray
    q_ref: np.ndarray
    e_pulses: np.ndarray
    i_A: np.ndarray
    sidecar: dict = field(default_factory=dict)

    @property
    def n_samples(self) -> int:
        """Logged samples."""
        return self.t.shape[0]

    @property
    def n_joints(self) -> int:
        """Joints n."""
        return self.e_pulses.shape[1]

    @property
    def joint_names(self) -> tuple:
        """The robot's joint names."""
        return self.model.joint_names

    def reference_counts(self) -> np.ndarray:
        """Unquantised reference counts ``q_ref(t_k) k N / 2 pi`` at ``t_k = k Ts``, (n_samples, n)
        (:func:`plant.simulation.arm.reference_counts`)."""
        from plant.simulation.arm import reference_counts

        return reference_counts(self.trajectory, self.rig, self.n_samples)

    def measured_counts(self) -> np.ndarray:
        """Encoder counts the log implies, ``trunc(ref) - e`` (n_samples, n)."""
        return np.trunc(self.reference_counts()) - self.e_pulses

    def save(self, path) -> Path:
        """Write ``STEM.csv`` and ``STEM.json`` (atomically: never half-written).

        Parameters
        ----------
        path : path-like
            The CSV path (``.csv`` appended when missing).

        Returns
        -------
        Path
            The CSV written.
        """
        path = Path(path)
        if path.suffix != ".csv":
            path = path.with_suffix(".csv")
        buf = io.StringIO()
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(column_names(self.joint_names))
        for k in range(self.n_samples):
            w.writerow([repr(float(self.t[k]))] + [repr(float(v)) for v in self.q_ref[k]]
                       + [str(int(v)) for v in self.e_pulses[k]]
                       + [repr(float(v)) for v in self.i_A[k]])
        write_text_atomic(path, buf.getvalue())
        write_text_atomic(path.with_suffix(".json"), json.dumps(self.sidecar, indent=2) + "\n")
        return path


def arm_rig(sidecar, side):
    """The robot model and the rig of a sidecar with a ``robot`` object (module docstring).

    Parameters
    ----------
    sidecar : dict
        The parsed sidecar (``plant.logs.sidecar.read_sidecar``).
    side : path-like
        Its file (error messages; a URDF path is relative to its folder).

    Returns
    -------
    model : plant.robot.robot_model.RobotModel
    rig : plant.Rig
        Per-joint tuples of the model's n joints.

    Raises
    ------
    LogError
        A missing or malformed ``robot``, ``gear_ratio`` or rig key (one line).
    """
    side = Path(side)
    robot = sidecar.get("robot")
    gear = sidecar.get("gear_ratio")
    if not isinstance(gear, list) or not gear:
        raise sidecar_error(side, "key 'gear_ratio' must be a list of numbers, one per joint")
    nj = len(gear)
    if not isinstance(robot, dict):
        raise sidecar_error(side, "key 'robot' must be an object (a DH table or a URDF) or, for a "
                            "PUMA 560 links 2-3 log, text or absent")
    rig = rig_from_sidecar(sidecar, side, n_joints=nj, robot_model=True)
    return robot_from_sidecar(robot, rig.gear_ratio, side.parent, side), rig


def load_arm_log(path) -> ArmLog:
    """Read a robot model's log (``STEM.csv`` and ``STEM.json``; module docstring).

    Parameters
    ----------
    path : path-like
        The CSV file (its sidecar is the same stem with ``.json``).

    Returns
    -------
    ArmLog
        For a sidecar without a ``robot`` object (or with a text one): a
        PUMA 560 links 2-3 log, read by :func:`plant.load_log` (every check
        of it; ``t``, ``q_ref``, ``e_pulses``, ``i_A``, ``rig`` and
        ``trajectory`` are its), the model
        :meth:`RobotModel.puma560_links23 <plant.robot.robot_model.RobotModel.puma560_links23>`
        with the sidecar's ``gear_ratio`` and ``gravity_m_s2``.

    Raises
    ------
    LogError
        A missing or malformed file, column or key (one line); a PUMA 560
        links 2-3 log that is a window of a run (``window_s`` not starting
        at 0: an ArmLog starts at t = 0; read it with :func:`plant.load_log`).
    """
    path = Path(path)
    side = path.with_suffix(".json")
    sidecar = read_sidecar(side)
    robot = sidecar.get("robot")
    if robot is None or isinstance(robot, str):
        return _links23_log(path)
    model, rig = arm_rig(sidecar, side)
    trajectory = Trajectory.from_sidecar(sidecar, str(side), n_joints=model.n_joints)
    text = read_text(path, "log")
    rows = list(csv.reader(io.StringIO(text)))
    if not rows:
        raise LogError(f"{path}: empty log")
    header = [h.strip() for h in rows[0]]
    names = column_names(model.joint_names)
    missing = [c for c in names if c not in header]
    if missing:
        raise LogError(f"{path}: column '{missing[0]}' is missing (header: {', '.join(header)})")
    cols = [header.index(c) for c in names]
    try:
        data = np.array([[float(r[c]) for c in cols] for r in rows[1:] if r], dtype=float)
    except (ValueError, IndexError):
        raise LogError(f"{path}: a row is short or not numeric") from None
    if data.shape[0] < 2:
        raise LogError(f"{path}: fewer than 2 samples")
    if not np.all(np.isfinite(data)):
        raise LogError(f"{path}: NaN or inf in the log")
    n = model.n_joints
    e = data[:, 1 + n:1 + 2 * n]
    if np.any(e != np.round(e)):
        raise LogError(f"{path}: the pulse errors must be integers")
    return ArmLog(path=path, name=path.stem, model=model, rig=rig, trajectory=trajectory,
                  t=data[:, 0], q_ref=data[:, 1:1 + n], e_pulses=e.astype(np.int64),
                  i_A=data[:, 1 + 2 * n:1 + 3 * n], sidecar=sidecar)


def links23_model(rig):
    """The robot model of a PUMA 560 links 2-3 rig (a sidecar without a ``robot`` object).

    :meth:`~plant.robot.robot_model.RobotModel.puma560_links23` with the
    rig's gear ratios and gravity: its base parameters are f1..f9.

    Parameters
    ----------
    rig : plant.logs.rig.Rig
        A two-joint rig of the PUMA 560 links 2-3.

    Returns
    -------
    plant.robot.robot_model.RobotModel
    """
    from plant.robot.robot_model import RobotModel

    return RobotModel.puma560_links23(gear_ratios=rig.gear_ratio, gravity_m_s2=rig.gravity_m_s2)


def _links23_log(path: Path) -> ArmLog:
    """A PUMA 560 links 2-3 log (sidecar without a ``robot`` object) as an ArmLog."""
    from plant.logs.log import load_log

    log = load_log(path)
    if log.start_index != 0:
        raise LogError(f"{log.path}: a window of a PUMA 560 links 2-3 run (t starts at "
                       f"{float(log.t[0])!r} s); an ArmLog starts at t = 0: read it with plant.load_log")
    return ArmLog(path=log.path, name=log.name, model=links23_model(log.rig), rig=log.rig,
                  trajectory=log.trajectory, t=log.t, q_ref=log.q_ref, e_pulses=log.e_pulses,
                  i_A=log.i_A, sidecar=log.sidecar)
