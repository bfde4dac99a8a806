"""The result -> controller contract: what a computed-torque controller takes from an identification.

An identification result -- :class:`identification.IdentificationResult`
(PUMA 560 links 2-3), :class:`identification.arm.ArmIdentificationResult`
(any serial arm), their dicts, or a result JSON file -- is read here, once,
into an :class:`IdentifiedModel`: the base parameters, the model the
identification chose (rigid or two-mass flexible joints with their
stiffness, damping, reflected motor inertia and backlash), the drive
friction it identified, and whether it found its model adequate.  The
controllers (:mod:`ctc.computed_torque`, :mod:`ctc.flexible`,
:mod:`ctc.adaptive`, :mod:`ctc.arm`) take this object and read none of
these keys themselves (an arm result's simulation objects -- its generated
plant and its rig -- are no part of the contract: :mod:`ctc.arm` takes
them from the result where it runs them).

The keys read are the result schema's (:mod:`identification.result_schema`;
``docs/api.rst``): ``f`` (or ``beta`` for an arm), ``model``,
``joint_stiffness_Nm_per_rad``, ``joint_damping_Nms_per_rad``,
``motor_inertia_reflected_kgm2``, ``joint_backlash_rad``,
``friction_identified`` with ``viscous_friction_Nms_per_rad`` and
``coulomb_friction_Nm`` (at the top level, or in an arm result's
``friction``), ``model_choice['adequate']`` and ``joint_intervals``.
"""
from __future__ import annotations

import dataclasses
import os
from typing import Optional

import numpy as np

__all__ = ["IdentifiedModel", "JOINT_KEYS", "LOG_RANGE", "log_range_warning"]

#: The joints of a flexible result: result key -> :class:`IdentifiedModel` field.
JOINT_KEYS = (
    ("joint_stiffness_Nm_per_rad", "stiffness_Nm_per_rad"),
    ("joint_damping_Nms_per_rad", "damping_Nms_per_rad"),
    ("motor_inertia_reflected_kgm2", "motor_inertia_reflected_kgm2"),
)


@dataclasses.dataclass(frozen=True)
class IdentifiedModel:
    """The model a controller is built on, read from an identification result.

    Parameters
    ----------
    f : ndarray, shape (p,)
        Base parameters: the paper's f1..f9 (eq. 3) for PUMA 560 links 2-3,
        an arm's beta otherwise; rigid-equivalent (link plus reflected motor
        inertia) for a flexible model.
    model : {'rigid', 'flexible'}
        The model the identification chose.
    stiffness_Nm_per_rad, damping_Nms_per_rad : ndarray, shape (n,) or None
        Joint springs K (N m/rad) and their damping D (N m s/rad); flexible only.
    motor_inertia_reflected_kgm2 : ndarray, shape (n,) or None
        Reflected motor inertia ``Jm k^2`` (kg m^2); flexible only.
    backlash_rad : ndarray, shape (n,) or None
        Gearbox backlash width b (rad, joint side); None when not identified.
    viscous_friction_Nms_per_rad : ndarray, shape (n,) or None
        Identified motor-side viscous friction; None when the sidecar's is used.
    coulomb_friction_Nm : ndarray, shape (n, 2) or None
        Identified motor-side Coulomb friction ``[positive, negative]`` per joint.
    adequate : bool or None
        ``model_choice['adequate']``: False when the identification found
        that its model does not describe the log.
    joint_corners : tuple of tuple
        A flexible result's robots that its log allows beside the fit
        (``joint_intervals['corners']``,
        :func:`identification.flexible.joint_intervals`): per corner
        ``(joint index, stiffness factor, damping factor, motor inertia
        factor)``, one joint changed, its spring or motor not determined by
        the log; empty when the log determines them (or the result is older).

    Notes
    -----
    Build it with :meth:`from_result`; :meth:`joints` gives the keywords of
    the flexible-joint controllers, :meth:`rig` the rig with the identified
    friction.
    """

    f: np.ndarray
    model: str = "rigid"
    stiffness_Nm_per_rad: Optional[np.ndarray] = None
    damping_Nms_per_rad: Optional[np.ndarray] = None
    motor_inertia_reflected_kgm2: Optional[np.ndarray] = None
    backlash_rad: Optional[np.ndarray] = None
    viscous_friction_Nms_per_rad: Optional[np.ndarray] = None
    coulomb_friction_Nm: Optional[np.ndarray] = None
    adequate: Optional[bool] = None
    joint_corners: tuple = ()

    def corner_scenarios(self, joint_names):
        """The robots the log allows beside the fit as per-joint factors, one joint changed.

        Parameters
        ----------
        joint_names : sequence of str
            The joints' names for the labels (n).

        Returns
        -------
        list of (str, ndarray, ndarray, ndarray)
            Per corner of :attr:`joint_corners` its label (e.g. ``"joint 3 K
            x0.5, Jm k^2 x4 (log range)"``, ending in :data:`LOG_RANGE`) and
            the factors of the stiffness, the damping and the reflected motor
            inertia, shape (n,) each; empty without corners.
        """
        n = len(joint_names)
        out = []
        for j, *f in self.joint_corners:
            vec = [np.ones(n) for _ in f]
            for a, v in zip(vec, f):
                a[j] = v
            what = ", ".join(f"{w} x{v:.3g}" for w, v in zip(("K", "D", "Jm k^2"), f)
                             if abs(v - 1.0) > 1e-9)
            out.append((f"{joint_names[j]} {what}{LOG_RANGE}", *vec))
        return out

    @property
    def flexible(self) -> bool:
        """True for two-mass flexible joints."""
        return self.model == "flexible"

    @property
    def friction_identified(self) -> bool:
        """True when the result carries identified friction."""
        return self.viscous_friction_Nms_per_rad is not None

    def joints(self, *, backlash=True) -> dict:
        """The flexible joints as keywords of the flexible-joint controllers.

        Parameters
        ----------
        backlash : bool
            Include ``backlash_rad`` when the result has it.

        Returns
        -------
        dict
            ``stiffness_Nm_per_rad``, ``damping_Nms_per_rad``,
            ``motor_inertia_reflected_kgm2`` (each (n,)) and, when
            identified, ``backlash_rad`` (n,); empty for a rigid model.
        """
        if not self.flexible:
            return {}
        out = {name: getattr(self, name) for _, name in JOINT_KEYS}
        if backlash and self.backlash_rad is not None:
            out["backlash_rad"] = self.backlash_rad
        return out

    def rig(self, rig):
        """``rig`` with the identified friction (``rig`` itself when none was identified).

        Parameters
        ----------
        rig : plant.Rig

        Returns
        -------
        plant.Rig
        """
        if not self.friction_identified:
            return rig
        v = self.viscous_friction_Nms_per_rad
        c = self.coulomb_friction_Nm
        return dataclasses.replace(
            rig, viscous_friction_Nms_per_rad=tuple(float(x) for x in v),
            coulomb_friction_Nm=tuple((float(p), float(m)) for p, m in c))

    @classmethod
    def from_result(cls, result, *, n_joints=2, what="result"):
        """Read an identification result.

        Parameters
        ----------
        result : IdentifiedModel, identification.IdentificationResult, ArmIdentificationResult, dict or path
            The result, its dict (``to_dict``), or a JSON file written by
            ``save_json`` / the CLI's ``--output`` (read with
            :meth:`identification.IdentificationResult.load_json`).
        n_joints : int
            Joints of the robot (2 for PUMA 560 links 2-3).
        what : str
            What the result is to the caller, for the messages (``'result'``,
            ``'prior'``).

        Returns
        -------
        IdentifiedModel

        Raises
        ------
        ValueError
            One line: not a result (``"result must be ..."``), a file that
            cannot be read, no ``f``, an unknown model, a flexible result
            without its joints (never reduced to its rigid-equivalent f), or
            identified friction that is malformed or not finite.
        """
        if isinstance(result, cls):
            return result
        if isinstance(result, (str, os.PathLike)):
            from identification.result import IdentificationResult

            result = IdentificationResult.load_json(result)
        if not isinstance(result, dict):
            raise ValueError(f"{what} must be an IdentificationResult, its dict or a result JSON "
                             f"path, got {type(result).__name__}")
        d = result
        key = "beta" if d.get("beta") is not None else "f"
        if d.get(key) is None:
            raise ValueError(f"the {what} has no 'f' (not an identification result?)")
        f = np.asarray(d[key], dtype=float).reshape(-1)
        model = d.get("model") or "rigid"
        if model not in ("rigid", "flexible"):
            raise ValueError(f"unknown model {model!r} in the {what} (a rigid or flexible "
                             f"{what} is expected)")
        n = int(n_joints)
        fields = {}
        if model == "flexible":
            try:
                for k, name in JOINT_KEYS:
                    fields[name] = np.asarray(d[k], dtype=float).reshape(n)
            except (KeyError, TypeError, ValueError):
                raise ValueError(f"a flexible {what} needs "
                                 f"{', '.join(k for k, _ in JOINT_KEYS[:-1])} and "
                                 f"{JOINT_KEYS[-1][0]} ({n} values each); this one cannot be used "
                                 "(it is never reduced to its rigid f)") from None
            b = d.get("joint_backlash_rad")
            if b is not None:
                try:
                    fields["backlash_rad"] = np.asarray(b, dtype=float).reshape(n)
                except (TypeError, ValueError):
                    raise ValueError(f"the {what}'s joint_backlash_rad must be {n} values") from None
        if d.get("friction_identified"):
            src = d if d.get("viscous_friction_Nms_per_rad") is not None else (d.get("friction") or {})
            try:
                fields["viscous_friction_Nms_per_rad"] = np.asarray(
                    src["viscous_friction_Nms_per_rad"], dtype=float).reshape(n)
                fields["coulomb_friction_Nm"] = np.asarray(
                    src["coulomb_friction_Nm"], dtype=float).reshape(n, 2)
            except (KeyError, TypeError, ValueError):
                raise ValueError(f"a {what} with friction_identified needs "
                                 f"viscous_friction_Nms_per_rad ({n}) and coulomb_friction_Nm "
                                 f"({n} x 2)") from None
            if not (np.all(np.isfinite(fields["viscous_friction_Nms_per_rad"]))
                    and np.all(np.isfinite(fields["coulomb_friction_Nm"]))):
                raise ValueError(f"the {what}'s identified friction is not finite")
        choice = d.get("model_choice") or {}
        adequate = choice.get("adequate") if hasattr(choice, "get") else None
        if model == "flexible":
            fields["joint_corners"] = _joint_corners(d.get("joint_intervals"), n)
        return cls(f=f, model=model, adequate=None if adequate is None else bool(adequate),
                   **fields)


#: The end of a robustness scenario's name that is a robot the log allows beside the fit
#: (:meth:`IdentifiedModel.corner_scenarios`).
LOG_RANGE = " (log range)"


def log_range_warning(worst, lost, n_checked, where) -> str:
    """The warning of a controller built on a result whose log leaves joints open.

    Parameters
    ----------
    worst : list or float or None
        The controller's largest tracking error (pulses) over the corners it ran
        (None: it ran none to the end).
    lost : list of str
        The corners on which it lost the arm.
    n_checked : int
        Corners checked.
    where : str
        The controller's attribute holding the report (``".robustness"``).

    Returns
    -------
    str
    """
    said = f"tracks within {worst} pulses at worst" if worst is not None else ""
    if lost:
        said += ("; " if said else "") + f"loses the arm with {', '.join(lost)}"
    return ("the log does not determine every joint parameter this controller uses (the "
            f"result's joint_intervals: {n_checked} robots the log allows beside the fit "
            f"checked): over them this controller {said or 'was not run'} (see {where}); a "
            "richer experiment determines them")


def _joint_corners(intervals, n) -> tuple:
    """``joint_intervals['corners']`` as ``(joint, stiffness, damping, motor inertia)`` factors.

    A malformed corner (a joint outside ``0..n-1``, a factor not finite and
    positive) is left out: it names no robot.
    """
    corners = intervals.get("corners") if isinstance(intervals, dict) else None
    out = []
    for c in corners if isinstance(corners, (list, tuple)) else ():
        try:
            j = int(c["joint"])
            f = tuple(float(c[k]) for k in ("stiffness", "damping", "motor_inertia"))
        except (KeyError, TypeError, ValueError):
            continue
        if 0 <= j < n and all(np.isfinite(v) and v > 0 for v in f):
            out.append((j,) + f)
    return tuple(out)
