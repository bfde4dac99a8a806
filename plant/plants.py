"""Plants of the closed-loop core: the robot's right-hand side, rigid or flexible.

A plant is a right-hand side ``rhs(P, c, X, U, A, K, n)`` of the core
(:mod:`plant.core`, where the signature is described), registered under a
kind (a type tag) in :data:`RIGHT_HAND_SIDES`, together with its state
layout (:class:`Plant`): which rows the motor encoders read, how many
per-lane parameters it takes and how its start state follows from the rig's.  Two
plants are defined here:

* :data:`RIGID` -- the rigid model of :mod:`plant.model` (paper eq. 2),
  state ``(q2, q3, qd2, qd3)``, parameters f1..f9, the encoders read q;
* :class:`FlexibleJoints` -- Spong's two-mass flexible joints, state
  ``(q2, q3, qd2, qd3, th2, th3, thd2, thd3)`` (link, then motor angle / k),
  the encoders read th.

Both add the joint-side drive friction of the rig (motor side: viscous and
asymmetric Coulomb with a linear ramp; :func:`plant.model.friction_torque`)
and turn the held motor current into joint torque ``k Kt i``.  To add a
plant (another friction law, a third joint), write its right-hand side with
the same signature, register it under a new kind in
:data:`RIGHT_HAND_SIDES` and describe it by a :class:`Plant`; every driver
of the core then simulates it.  The drive friction is the rig's
(:class:`plant.rig.RigConstants`, shared by all lanes: per-lane friction
rows in P cost the lane loops their vectorisation, measured 0.30 -> 0.84 ms
per candidate); a plant that identifies friction would carry it in its own
P rows.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numba
import numpy as np

from .anchors import libm_sincos, near_anchors, stage_sincos
from .model import friction_torque, joint_acceleration_sc

__all__ = ["Plant", "RIGID", "FlexibleJoints", "rigid_rhs", "flexible_rhs", "RigidKind",
           "FlexibleKind", "RIGID_KIND", "FLEXIBLE_KIND", "RIGHT_HAND_SIDES"]


class RigidKind(NamedTuple):
    """Type tag of the rigid plant: its numba type selects the right-hand side.

    Attributes
    ----------
    code : int
        0 (informative only: the *type* is what the core dispatches on).
    """

    code: int = 0


class FlexibleKind(NamedTuple):
    """Type tag of the two-mass flexible plant (see :class:`RigidKind`).

    Attributes
    ----------
    code : int
        1.
    """

    code: int = 1


#: Plant kinds: values whose numba *type* chooses a right-hand side at
#: compile time (:func:`plant.core.plant_rhs`), so each kernel is compiled
#: once per plant, with only that plant's right-hand side, and loads from
#: numba's cache (a value would be a runtime branch over all plants; a
#: compiled function as an argument cannot be cached).
RIGID_KIND = RigidKind()
FLEXIBLE_KIND = FlexibleKind()

# Helpers compiled into the kernels that call them (whose cache holds their code):
# not cached on their own, which saves a cache file and its write per helper.
_jit = numba.njit(nogil=True, error_model="numpy")


@dataclass(frozen=True)
class Plant:
    """A right-hand side of the closed-loop core and its state layout.

    Attributes
    ----------
    name : str
        ``"rigid"`` or ``"flexible"``.
    kind : RigidKind or FlexibleKind
        :data:`RIGID_KIND` or :data:`FLEXIBLE_KIND`: how the core finds the
        right-hand side (:func:`plant.core.plant_rhs`).
    n_states : int
        Rows of the state array; rows 0, 1 are the link angles q2, q3 and
        rows 2, 3 their rates.
    encoder_row : int
        Row of the angle the joint-2 motor encoder reads (joint 3: the next
        row), joint side (motor angle / k).
    n_parameters : int
        Rows of the per-lane parameter array P.
    """

    name: str
    kind: tuple
    n_states: int
    encoder_row: int
    n_parameters: int

    def lane_parameters(self, F, rig) -> np.ndarray:
        """Per-lane parameter array of candidates ``F`` (m, 9) (rigid-equivalent f).

        Plants with parameters beyond f take them as keyword arrays (e.g.
        :meth:`FlexibleJoints.lane_parameters`).

        Parameters
        ----------
        F : ndarray, shape (m, 9)
            Base parameters f1..f9 per candidate.
        rig : plant.rig.Rig

        Returns
        -------
        ndarray, shape (n_parameters, m)
        """
        return np.ascontiguousarray(np.asarray(F, dtype=np.float64).T)

    def initial_state(self, c) -> np.ndarray:
        """Start state (n_states,) from the rig layout's ``q0``, ``qd0``.

        Parameters
        ----------
        c : plant.rig.RigConstants

        Returns
        -------
        ndarray, shape (n_states,)
        """
        return np.array([c.q0[0], c.q0[1], c.qd0[0], c.qd0[1]])


@_jit
def _rigid_lane(P, j, c, q2, q3, w2, w3, s2, c2, s3, c3, i2, i3):
    """Joint accelerations and PD margin of rigid lane ``j`` (scalars in and out)."""
    tau2 = c.torque_per_amp[0] * i2 + friction_torque(
        w2, c.viscous[0], c.coulomb_pos[0], c.coulomb_neg[0], c.ramp_speed[0])
    tau3 = c.torque_per_amp[1] * i3 + friction_torque(
        w3, c.viscous[1], c.coulomb_pos[1], c.coulomb_neg[1], c.ramp_speed[1])
    f = (P[0, j], P[1, j], P[2, j], P[3, j], P[4, j], P[5, j], P[6, j], P[7, j], P[8, j])
    a2, a3, det = joint_acceleration_sc(f, s2, c2, s3, c3, w2, w3, tau2, tau3, c.gravity)
    return a2, a3, det if P[0, j] > 0.0 else -1.0


@numba.njit(nogil=True, error_model="numpy", inline="always")  # IR-inlined (plant.core)
def rigid_rhs(P, c, X, U, A, K, n):
    """Right-hand side of the rigid robot (paper eq. 2) for lanes ``0..n-1``.

    State ``X`` rows (q2, q3, qd2, qd3); parameters ``P`` rows f1..f9;
    ``K`` rows (qd2, qd3, qdd2, qdd3, det D) (det D replaced by -1 where
    f1 <= 0).  See :mod:`plant.core` for the protocol.

    Parameters
    ----------
    P : ndarray, shape (n_par, lanes)
        Per-lane parameters.
    c : plant.rig.RigConstants
        Rig layout.
    X : ndarray, shape (n_x, lanes)
        Stage state.
    U : ndarray, shape (2, lanes)
        Held motor currents (A).
    A : ndarray, shape (6, lanes)
        Trigonometric anchors (:mod:`plant.core`).
    K : ndarray, shape (n_x + 1, lanes)
        Output: state derivative and PD margin.
    n : int
        Lanes to evaluate.
    """
    far = 0
    for j in range(n):
        s2, c2, s3, c3, near = stage_sincos(X, A, j)
        K[2, j], K[3, j], K[4, j] = _rigid_lane(P, j, c, X[0, j], X[1, j], X[2, j], X[3, j],
                                                s2, c2, s3, c3, U[0, j], U[1, j])
        K[0, j] = X[2, j]
        K[1, j] = X[3, j]
        far += not near
    if far:  # lanes that moved too far from the anchors: libm (rare)
        for j in range(n):
            if not near_anchors(X, A, j):
                s2, c2, s3, c3 = libm_sincos(X, j)
                K[2, j], K[3, j], K[4, j] = _rigid_lane(P, j, c, X[0, j], X[1, j], X[2, j],
                                                        X[3, j], s2, c2, s3, c3, U[0, j], U[1, j])


#: Registry of the core: plant kind class -> right-hand side (:func:`plant.core.plant_rhs`).
RIGHT_HAND_SIDES = {RigidKind: rigid_rhs}

#: The rigid robot of :mod:`plant.model`: state (q2, q3, qd2, qd3), the
#: encoders read q, parameters f1..f9.
RIGID = Plant(name="rigid", kind=RIGID_KIND, n_states=4, encoder_row=0, n_parameters=9)


# ----------------------------------------------------------------------------
# Two-mass flexible joints
# ----------------------------------------------------------------------------
# Rows of the flexible plant's per-lane parameters after the nine link f.
_FX_K, _FX_D, _FX_J = 9, 11, 13


@_jit
def _flexible_lane(P, j, c, q2, q3, w2, w3, th2, th3, v2, v3, s2, c2, s3, c3, i2, i3):
    """Link and motor accelerations and PD margin of flexible lane ``j``."""
    ts2 = P[_FX_K, j] * (th2 - q2) + P[_FX_D, j] * (v2 - w2)
    ts3 = P[_FX_K + 1, j] * (th3 - q3) + P[_FX_D + 1, j] * (v3 - w3)
    f = (P[0, j], P[1, j], P[2, j], P[3, j], P[4, j], P[5, j], P[6, j], P[7, j], P[8, j])
    a2, a3, det = joint_acceleration_sc(f, s2, c2, s3, c3, w2, w3, ts2, ts3, c.gravity)
    fr2 = friction_torque(v2, c.viscous[0], c.coulomb_pos[0], c.coulomb_neg[0], c.ramp_speed[0])
    fr3 = friction_torque(v3, c.viscous[1], c.coulomb_pos[1], c.coulomb_neg[1], c.ramp_speed[1])
    b2 = (c.torque_per_amp[0] * i2 + fr2 - ts2) / P[_FX_J, j]
    b3 = (c.torque_per_amp[1] * i3 + fr3 - ts3) / P[_FX_J + 1, j]
    return a2, a3, b2, b3, det if P[0, j] > 0.0 else -1.0


@_jit
def flexible_rhs(P, c, X, U, A, K, n):
    """Right-hand side of the two-mass flexible-joint robot for lanes ``0..n-1``.

    State rows (q2, q3, qd2, qd3, th2, th3, thd2, thd3); parameters rows
    link f1..f9, stiffness K (2), damping D (2), reflected motor inertia
    Jm k^2 (2); ``K`` rows: the derivative (8) and det D_link.

    Parameters
    ----------
    P : ndarray, shape (n_par, lanes)
        Per-lane parameters.
    c : plant.rig.RigConstants
        Rig layout.
    X : ndarray, shape (n_x, lanes)
        Stage state.
    U : ndarray, shape (2, lanes)
        Held motor currents (A).
    A : ndarray, shape (6, lanes)
        Trigonometric anchors (:mod:`plant.core`).
    K : ndarray, shape (n_x + 1, lanes)
        Output: state derivative and PD margin.
    n : int
        Lanes to evaluate.
    """
    far = 0
    for j in range(n):
        s2, c2, s3, c3, near = stage_sincos(X, A, j)
        K[2, j], K[3, j], K[6, j], K[7, j], K[8, j] = _flexible_lane(
            P, j, c, X[0, j], X[1, j], X[2, j], X[3, j], X[4, j], X[5, j], X[6, j], X[7, j],
            s2, c2, s3, c3, U[0, j], U[1, j])
        K[0, j] = X[2, j]
        K[1, j] = X[3, j]
        K[4, j] = X[6, j]
        K[5, j] = X[7, j]
        far += not near
    if far:
        for j in range(n):
            if not near_anchors(X, A, j):
                s2, c2, s3, c3 = libm_sincos(X, j)
                K[2, j], K[3, j], K[6, j], K[7, j], K[8, j] = _flexible_lane(
                    P, j, c, X[0, j], X[1, j], X[2, j], X[3, j], X[4, j], X[5, j], X[6, j],
                    X[7, j], s2, c2, s3, c3, U[0, j], U[1, j])


RIGHT_HAND_SIDES[FlexibleKind] = flexible_rhs


@dataclass(frozen=True)
class FlexibleJoints(Plant):
    """Spong two-mass joints: motor and link joined by a spring and damper.

    With ``th`` the motor angle divided by the gear ratio (joint-side motor
    angle, what the encoder reads) and ``q`` the link angle, per joint::

        Jm k^2 th'' = k Kt i + tau_friction(th') - tau_s
        D_link(q) q'' + h(q, q') + g(q) = tau_s
        tau_s = Ks (th - q) + Ds (th' - q')

    ``D_link`` is the rigid model of :mod:`plant.model` with the reflected
    motor inertias removed from f7 (joint 2) and f1 (joint 3) (f1 - Jm k3^2,
    f7 - Jm k2^2); friction acts on the motor side.  Source: M. W. Spong,
    "Modeling and control of elastic joint robots", J. Dyn. Syst. Meas.
    Control 109 (1987).  The robot starts with the springs relaxed (motor
    angles and rates equal to the link's).

    Parameters
    ----------
    stiffness_Nm_per_rad : float or tuple of 2 float
        Joint-side spring stiffness Ks (N m/rad), > 0.
    damping_Nms_per_rad : float or tuple of 2 float
        Joint-side spring damping Ds (N m s/rad), >= 0.
    motor_inertia_kgm2 : float or tuple of 2 float
        Motor rotor inertia Jm (kg m^2), motor side, > 0.

    Raises
    ------
    ValueError
        On a non-finite or out-of-range constant.
    """

    stiffness_Nm_per_rad: tuple = (1.0, 1.0)
    damping_Nms_per_rad: tuple = (0.0, 0.0)
    motor_inertia_kgm2: tuple = (1.0, 1.0)

    def __init__(self, stiffness_Nm_per_rad, damping_Nms_per_rad, motor_inertia_kgm2):
        pairs = []
        for name, v, positive in (("stiffness_Nm_per_rad", stiffness_Nm_per_rad, True),
                                  ("damping_Nms_per_rad", damping_Nms_per_rad, False),
                                  ("motor_inertia_kgm2", motor_inertia_kgm2, True)):
            a = np.broadcast_to(np.asarray(v, dtype=float), (2,))
            if not np.all(np.isfinite(a)) or np.any(a <= 0 if positive else a < 0):
                raise ValueError("FlexibleJoints: stiffness and motor inertia must be > 0, "
                                 f"damping >= 0 (got {name}={v!r})")
            pairs.append((float(a[0]), float(a[1])))
        Plant.__init__(self, name="flexible", kind=FLEXIBLE_KIND, n_states=8, encoder_row=4,
                       n_parameters=15)
        object.__setattr__(self, "stiffness_Nm_per_rad", pairs[0])
        object.__setattr__(self, "damping_Nms_per_rad", pairs[1])
        object.__setattr__(self, "motor_inertia_kgm2", pairs[2])

    def reflected_inertia(self, rig) -> np.ndarray:
        """Reflected motor inertias Jm k^2 of joints 2 and 3 (kg m^2), shape (2,).

        Parameters
        ----------
        rig : plant.rig.Rig
        """
        k = np.asarray(rig.gear_ratio, float)
        return np.asarray(self.motor_inertia_kgm2) * k * k

    def link_parameters(self, f, rig) -> np.ndarray:
        """Link-only f: the rigid-equivalent f minus the reflected motor inertias.

        Parameters
        ----------
        f : array_like, shape (9,) or (m, 9)
            Rigid-equivalent base parameters (link plus Jm k^2 in f1 and f7).
        rig : plant.rig.Rig

        Returns
        -------
        ndarray, same shape as ``f``
            ``f1 - Jm3 k3^2`` and ``f7 - Jm2 k2^2``, the rest unchanged.
        """
        jk2 = self.reflected_inertia(rig)
        fl = np.array(f, dtype=float)
        fl[..., 6] -= jk2[0]
        fl[..., 0] -= jk2[1]
        return fl

    def lane_parameters(self, F, rig, joints=None) -> np.ndarray:
        """Per-lane parameters (15, m): link f, Ks, Ds, Jm k^2 (see :func:`flexible_rhs`).

        Parameters
        ----------
        F : ndarray, shape (m, 9)
            Rigid-equivalent base parameters per candidate.
        rig : plant.rig.Rig
        joints : array_like, shape (m, 6), optional
            Per-candidate joints ``(K2, K3, D2, D3, Jm2 k2^2, Jm3 k3^2)``
            (N m/rad, N m s/rad, kg m^2; identification); default this
            plant's constants for every candidate.

        Returns
        -------
        ndarray, shape (15, m)
        """
        F = np.atleast_2d(np.asarray(F, dtype=float))
        m = F.shape[0]
        P = np.empty((15, m))
        if joints is not None:
            J = np.broadcast_to(np.atleast_2d(np.asarray(joints, dtype=float)), (m, 6))
            P[:9] = F.T
            P[6] -= J[:, 4]
            P[0] -= J[:, 5]
            P[_FX_K:] = J.T
            return P
        P[:9] = self.link_parameters(F, rig).T
        P[_FX_K:_FX_K + 2] = np.asarray(self.stiffness_Nm_per_rad)[:, None]
        P[_FX_D:_FX_D + 2] = np.asarray(self.damping_Nms_per_rad)[:, None]
        P[_FX_J:_FX_J + 2] = self.reflected_inertia(rig)[:, None]
        return P

    def initial_state(self, c) -> np.ndarray:
        """Start state (8,): link and motor at the rig's start, springs relaxed.

        Parameters
        ----------
        c : plant.rig.RigConstants

        Returns
        -------
        ndarray, shape (8,)
        """
        x = np.array([c.q0[0], c.q0[1], c.qd0[0], c.qd0[1]])
        return np.concatenate([x, x])
