"""Rig constants of a PUMA 560 links 2-3 test set-up, read from a log's sidecar."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

#: Names of the nine base parameters, in order (paper eq. 3).
F_NAMES = ("f1", "f2", "f3", "f4", "f5", "f6", "f7", "f8", "f9")

#: SI units of f1..f9 (inertias kg m^2, first moments kg m).
F_UNITS = ("kg m^2", "kg m^2", "kg m^2", "kg m^2", "kg m", "kg m", "kg m^2", "kg m", "kg m")


@dataclass(frozen=True)
class Rig:
    """Constants of the drive, encoders and P controller of one experiment.

    All values come from the log's JSON sidecar; nothing is hard-coded.
    Per-joint values are tuples of n_joints entries in the log's joint order
    (for the PUMA 560 links 2-3: joint 2, joint 3).  ``a3_m`` and
    ``f_bounds`` describe the PUMA links 2-3 instance (for another robot
    model: 0 and empty).

    Attributes
    ----------
    sample_time_s : float
        Controller sample time Ts (s).
    gear_ratio : tuple of n_joints float
        k, defined by motor angle = k * joint angle (k3 < 0 on the PUMA).
    encoder_ppr : tuple of n_joints int
        Motor-encoder pulses per motor revolution N.
    p_gain_A_per_pulse : tuple of n_joints float
        P gain (A per pulse of error).
    torque_constant_Nm_per_A : tuple of n_joints float
        Motor torque constant Kt.
    viscous_friction_Nms_per_rad : tuple of n_joints float or None
        Motor-side viscous friction B (joint side: k^2 B); None when the
        sidecar says it is unknown (``null``; see :attr:`unknown_friction`).
    coulomb_friction_Nm : tuple of n_joints (float, float) or None
        Motor-side Coulomb friction per joint, (magnitude for positive joint
        velocity, magnitude for negative joint velocity); joint side:
        abs(k) Tc; None when unknown.
    coulomb_ramp_speed_rad_per_s : float
        Motor speed below which the Coulomb friction ramps linearly to zero.
    gravity_m_s2 : float
        Gravitational acceleration g.
    a3_m : float
        Link length a3 (m).
    q0_rad, qd0_rad_per_s : tuple of n_joints float or None
        Start state of the run (at t = 0); None for a window log whose
        sidecar gives no ``start_state.q_rad`` / ``qd_rad_per_s`` (a robot
        that has run for hours: the run's t = 0 is not known).  A simulation
        of such a log starts at the window's first sample from a state given
        to it (``initial_state=``, e.g. estimated from the window by
        :func:`identification.window.estimate_initial_state`).
    f_bounds : tuple of 9 (float, float)
        Search ranges (low, high) of f1..f9.
    current_full_scale_A : float or None
        Current saturation of the amplifiers, if the sidecar gives one.
    payload_mass_kg : float or None
        Payload mass if the sidecar states it, else None.
    """

    sample_time_s: float
    gear_ratio: tuple
    encoder_ppr: tuple
    p_gain_A_per_pulse: tuple
    torque_constant_Nm_per_A: tuple
    viscous_friction_Nms_per_rad: tuple
    coulomb_friction_Nm: tuple
    coulomb_ramp_speed_rad_per_s: float
    gravity_m_s2: float
    a3_m: float
    q0_rad: tuple = (0.0, 0.0)
    qd0_rad_per_s: tuple = (0.0, 0.0)
    f_bounds: tuple = ()
    current_full_scale_A: float | None = None
    payload_mass_kg: float | None = None

    @property
    def pulses_per_rad(self) -> np.ndarray:
        """Encoder pulses per joint radian, k N / (2 pi), shape (n_joints,); negative for k < 0."""
        return np.array(
            [k * n / (2.0 * math.pi) for k, n in zip(self.gear_ratio, self.encoder_ppr)]
        )

    @property
    def unknown_friction(self) -> tuple:
        """Names of the friction fields the sidecar leaves unknown (``null``), possibly empty.

        A subset of ``("viscous_friction_Nms_per_rad", "coulomb_friction_Nm")``;
        :func:`rig_constants` takes zeros for them and
        :func:`identification.identify` estimates them with f.
        """
        return tuple(name for name in ("viscous_friction_Nms_per_rad", "coulomb_friction_Nm")
                     if getattr(self, name) is None)

    @property
    def bounds(self) -> np.ndarray:
        """Search ranges of f1..f9 as an array of shape (9, 2): columns (low, high)."""
        return np.array(self.f_bounds, dtype=float).reshape(9, 2)


class RigConstants(NamedTuple):
    """The rig layout of the compiled closed-loop core: joint-side drive constants.

    The one layout every simulation and controller kernel reads (by field
    name, never by position).  Built from a :class:`Rig` by
    :func:`rig_constants`; a ``NamedTuple`` of floats and pairs of floats, so
    numba types it as a value (no arrays, no reference counting).  Per-joint
    fields are tuples of n_joints floats, in the rig's joint order (for the
    PUMA 560 links 2-3 pairs, ordered joint 2, joint 3).

    Attributes
    ----------
    sample_time_s : float
        Controller sample time Ts (s).
    pulses_per_rad : tuple of n_joints float
        Encoder pulses per joint radian, k N / (2 pi) (negative for k < 0).
    torque_per_amp : tuple of n_joints float
        Joint torque per motor current, k Kt (N m / A).
    p_gain : tuple of n_joints float
        P gain of the logged experiment (A / pulse).
    viscous : tuple of n_joints float
        Joint-side viscous friction k^2 B (N m s / rad).
    coulomb_pos, coulomb_neg : tuple of n_joints float
        Joint-side Coulomb friction abs(k) Tc for positive / negative joint
        velocity (N m).
    ramp_speed : tuple of n_joints float
        Joint-side speed below which the Coulomb friction ramps linearly to
        zero, v_ramp / abs(k) (rad/s).
    gravity : float
        Gravitational acceleration g (m/s^2).
    q0, qd0 : tuple of n_joints float
        Start angles (rad) and rates (rad/s) of the run (NaN when the rig's
        start state is unknown and none was given).
    current_limit : float
        The drive's current full scale ``current_full_scale_A`` (A): every
        commanded current is saturated to ``[-current_limit, current_limit]``
        (inf when the sidecar gives none).
    """

    sample_time_s: float
    pulses_per_rad: tuple
    torque_per_amp: tuple
    p_gain: tuple
    viscous: tuple
    coulomb_pos: tuple
    coulomb_neg: tuple
    ramp_speed: tuple
    gravity: float
    q0: tuple
    qd0: tuple
    current_limit: float = math.inf


def _per_joint(values, n) -> tuple:
    a = np.broadcast_to(np.asarray(values, dtype=float), (n,))
    return tuple(float(v) for v in a)


def rig_constants(rig: Rig, *, q0=None, qd0=None) -> RigConstants:
    """The joint-side constants of a rig in the core's layout.

    Parameters
    ----------
    rig : Rig
        Sidecar constants (motor side where the sidecar gives them so).
    q0, qd0 : array_like, shape (n_joints,), optional
        Start angles (rad) and rates (rad/s); default the rig's start state
        (NaN if the rig has none: a window log without a start state).

    Returns
    -------
    RigConstants
        Per-joint fields are tuples of ``n_joints = len(rig.gear_ratio)``
        floats (2 for the PUMA 560 links 2-3).
        Joint side: viscous ``k^2 B``, Coulomb ``abs(k) Tc`` (zero where the
        rig's friction is unknown, None), ramp speed
        ``v / abs(k)``, torque per amp ``k Kt``, pulses per rad ``k N / 2 pi``.

    Raises
    ------
    ValueError
        If ``q0`` or ``qd0`` is not ``n_joints`` finite numbers.
    """
    k = np.asarray(rig.gear_ratio, dtype=float).reshape(-1)
    nj = k.size
    n = np.asarray(rig.encoder_ppr, dtype=float)
    # unknown friction (None) is zero here: a plant that identifies it carries it per lane
    tc = np.zeros((nj, 2)) if rig.coulomb_friction_Nm is None else np.asarray(
        rig.coulomb_friction_Nm, dtype=float).reshape(nj, 2)
    visc = np.zeros(nj) if rig.viscous_friction_Nms_per_rad is None else np.asarray(
        rig.viscous_friction_Nms_per_rad, dtype=float)
    start = []
    for name, given, default in (("q0", q0, rig.q0_rad), ("qd0", qd0, rig.qd0_rad_per_s)):
        if given is None and default is None:  # a window without a start state
            start.append((math.nan,) * nj)
            continue
        v = np.asarray(default if given is None else given, dtype=float)
        if v.shape != (nj,) or not np.all(np.isfinite(v)):
            raise ValueError(f"{name} must be {nj} finite numbers, got {given!r}")
        start.append(_per_joint(v, nj))
    return RigConstants(
        sample_time_s=float(rig.sample_time_s),
        pulses_per_rad=_per_joint(k * n / (2.0 * math.pi), nj),
        torque_per_amp=_per_joint(k * np.asarray(rig.torque_constant_Nm_per_A, dtype=float), nj),
        p_gain=_per_joint(rig.p_gain_A_per_pulse, nj),
        viscous=_per_joint(k * k * visc, nj),
        coulomb_pos=_per_joint(np.abs(k) * tc[:, 0], nj),
        coulomb_neg=_per_joint(np.abs(k) * tc[:, 1], nj),
        ramp_speed=_per_joint(rig.coulomb_ramp_speed_rad_per_s / np.abs(k), nj),
        gravity=float(rig.gravity_m_s2),
        q0=start[0],
        qd0=start[1],
        current_limit=(math.inf if rig.current_full_scale_A is None
                       else float(rig.current_full_scale_A)),
    )


def p_law_current(rig, e_pulses) -> np.ndarray:
    """The rig's P law ``i = clip(P e, -I_fs, I_fs)`` (A), the current the drive applies.

    Parameters
    ----------
    rig : Rig
        Its ``p_gain_A_per_pulse`` and ``current_full_scale_A`` (None: no limit).
    e_pulses : array_like, shape (n_samples, n_joints) or (n_joints,)
        Integer pulse errors ``ref - act``.

    Returns
    -------
    ndarray, the shape of ``e_pulses``
    """
    lim = math.inf if rig.current_full_scale_A is None else float(rig.current_full_scale_A)
    return np.clip(np.asarray(e_pulses, dtype=float) * np.asarray(rig.p_gain_A_per_pulse, dtype=float),
                   -lim, lim)


# ----------------------------------------------------------------------------
# Drive friction as vectors (motor side, sidecar order) and per-lane rows (joint side)
# ----------------------------------------------------------------------------
def friction_vector(rig) -> np.ndarray:
    """The rig's friction as a vector (6,) in :data:`plant.simulation.friction.FRICTION_NAMES` order; unknown -> 0.

    Parameters
    ----------
    rig : plant.logs.rig.Rig

    Returns
    -------
    ndarray, shape (6,)
    """
    v = np.zeros(6)
    if rig.viscous_friction_Nms_per_rad is not None:
        v[:2] = rig.viscous_friction_Nms_per_rad
    if rig.coulomb_friction_Nm is not None:
        v[2:] = np.asarray(rig.coulomb_friction_Nm, dtype=float).ravel()
    return v


def joint_side_friction(V, rig) -> np.ndarray:
    """Joint-side friction rows (6, m) of motor-side friction vectors V (m, 6).

    Parameters
    ----------
    V : array_like, shape (m, 6) or (6,)
        Motor-side friction (:data:`plant.simulation.friction.FRICTION_NAMES`).
    rig : plant.logs.rig.Rig
        For the gear ratios k.

    Returns
    -------
    ndarray, shape (6, m)
        Rows ``k^2 B`` (2), ``abs(k) Tc+`` (2), ``abs(k) Tc-`` (2).
    """
    V = np.atleast_2d(np.asarray(V, dtype=float))
    if V.shape[1] != 6 or not np.all(np.isfinite(V)):
        raise ValueError(f"friction must be finite with shape (m, 6), got {V.shape}")
    k = np.abs(np.asarray(rig.gear_ratio, dtype=float))
    out = np.empty((6, V.shape[0]))
    out[0:2] = (k * k)[:, None] * V[:, 0:2].T
    out[2] = k[0] * V[:, 2]
    out[3] = k[1] * V[:, 4]
    out[4] = k[0] * V[:, 3]
    out[5] = k[1] * V[:, 5]
    return out
