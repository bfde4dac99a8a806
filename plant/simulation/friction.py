"""A rigid plant whose drive friction is a per-lane parameter (friction unknown).

The plants of :mod:`plant.simulation.plants` take the drive friction from the rig
(:class:`plant.logs.rig.RigConstants`, shared by all lanes).  When the sidecar does not know the friction
(``"viscous_friction_Nms_per_rad": null`` and/or ``"coulomb_friction_Nm":
null``; :attr:`plant.logs.rig.Rig.unknown_friction`) it has to be identified with
f, so every candidate carries its own: :data:`RIGID_FRICTION` is the rigid
robot of :data:`plant.simulation.plants.RIGID` with six more rows in its per-lane
parameters P, the joint-side viscous coefficients and asymmetric Coulomb
levels.  Its right-hand side :func:`rigid_friction_rhs` is registered in
:data:`plant.simulation.plants.RIGHT_HAND_SIDES` under :class:`RigidFrictionKind`
(:func:`plant.simulation.plants.register_plant`), so every
driver of the core (:func:`plant.simulate_batch`, :func:`plant.prediction_errors`)
simulates it with ``plant=RIGID_FRICTION, plant_parameters={"friction": ...}``.
With the core's per-lane parameter tuples it costs about as much per
candidate as the rigid plant; the default rigid plant still takes the
friction from the rig, where the sidecar knows it.

Friction vectors are given motor side, in the sidecar's units and order
(:data:`FRICTION_NAMES`): ``B2, B3`` (N m s/rad) and ``Tc2+, Tc2-, Tc3+,
Tc3-`` (N m, magnitudes for positive / negative joint velocity); the lanes
hold them joint side (``k^2 B``, ``abs(k) Tc``).  The Coulomb ramp speed stays
the rig's (:attr:`plant.logs.rig.Rig.coulomb_ramp_speed_rad_per_s`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numba
import numpy as np

from plant.simulation.plants import Plant, register_plant, rigid_derivative
from plant.logs.rig import friction_vector, joint_side_friction  # noqa: F401 (their home is plant.logs.rig)

__all__ = ["RigidFrictionKind", "RIGID_FRICTION_KIND", "RigidWithFriction", "RIGID_FRICTION",
           "rigid_friction_rhs", "FRICTION_NAMES", "friction_vector", "friction_fields",
           "joint_side_friction"]

#: Names of the components of a friction vector (motor side, the sidecar's units).
FRICTION_NAMES = ("B2_Nms_per_rad", "B3_Nms_per_rad", "Tc2_pos_Nm", "Tc2_neg_Nm",
                  "Tc3_pos_Nm", "Tc3_neg_Nm")

# Rows of the per-lane parameters after the nine f: viscous (2), Coulomb + (2), Coulomb - (2).
_FR_V, _FR_P, _FR_N = 9, 11, 13

_jit = numba.njit(nogil=True, error_model="numpy")


class RigidFrictionKind(NamedTuple):
    """Type tag of :data:`RIGID_FRICTION` (see :class:`plant.simulation.plants.RigidKind`).

    Attributes
    ----------
    code : int
        2.
    """

    code: int = 2


#: The kind value of :data:`RIGID_FRICTION`.
RIGID_FRICTION_KIND = RigidFrictionKind()


def friction_fields(v) -> dict:
    """A friction vector (6,) as the sidecar's fields.

    Parameters
    ----------
    v : array_like, shape (6,)
        Motor-side friction in :data:`FRICTION_NAMES` order.

    Returns
    -------
    dict
        ``viscous_friction_Nms_per_rad`` (list of 2) and
        ``coulomb_friction_Nm`` (2 x 2 nested list, ``[[pos, neg], [pos, neg]]``).
    """
    v = np.asarray(v, dtype=float).reshape(6)
    return dict(viscous_friction_Nms_per_rad=[float(v[0]), float(v[1])],
                coulomb_friction_Nm=[[float(v[2]), float(v[3])], [float(v[4]), float(v[5])]])


@_jit
def rigid_friction_rhs(p, c, x, u, sc):
    """Right-hand side of the rigid robot with per-lane drive friction.

    As :func:`plant.simulation.plants.rigid_rhs`, with the lane's joint-side friction
    in ``p[9:15]`` (viscous 2, Coulomb for positive rate 2, for negative
    rate 2) instead of the rig's; the ramp speed is the rig's.

    Parameters
    ----------
    p : tuple of 15 float
        The lane's f1..f9 and friction.
    c : plant.logs.rig.RigConstants
        Rig layout.
    x : tuple of 4 float
        Stage state (q2, q3, qd2, qd3).
    u : tuple of 2 float
        Held motor currents (A).
    sc : tuple of 4 float
        sin q2, cos q2, sin q3, cos q3 of the stage.

    Returns
    -------
    xdot : tuple of 4 float
        (qd2, qd3, qdd2, qdd3).
    margin : float
        det D(q), or -1 where f1 <= 0.
    """
    return rigid_derivative(p, c, x, u, sc, (p[_FR_V], p[_FR_V + 1]),
                            (p[_FR_P], p[_FR_P + 1]), (p[_FR_N], p[_FR_N + 1]))


register_plant(RigidFrictionKind, rigid_friction_rhs, 4, 15)


@dataclass(frozen=True)
class RigidWithFriction(Plant):
    """The rigid robot with per-candidate drive friction (see the module docstring).

    State ``(q2, q3, qd2, qd3)``, the encoders read q; per-lane parameters
    f1..f9 and the joint-side friction (6 rows).  Use the instance
    :data:`RIGID_FRICTION`.

    Parameters
    ----------
    name : str
        ``"rigid+friction"``.
    kind : RigidFrictionKind
        :data:`RIGID_FRICTION_KIND` (registered with 4 states and 15
        parameters per lane).
    encoder_row : int
        0.
    """

    def lane_parameters(self, F, rig, friction=None) -> np.ndarray:
        """Per-lane parameters (15, m): f and the joint-side friction.

        Parameters
        ----------
        F : ndarray, shape (m, 9)
            Base parameters f1..f9 per candidate.
        rig : plant.logs.rig.Rig
            Gear ratios (and the friction when ``friction`` is None).
        friction : array_like, shape (m, 6) or (6,), optional
            Motor-side friction per candidate (:data:`FRICTION_NAMES`);
            default the rig's (:func:`friction_vector`, unknown values 0).

        Returns
        -------
        ndarray, shape (15, m)

        Raises
        ------
        ValueError
            On a friction of the wrong shape or not finite.
        """
        F = np.atleast_2d(np.asarray(F, dtype=float))
        m = F.shape[0]
        V = friction_vector(rig) if friction is None else friction
        V = np.broadcast_to(np.atleast_2d(np.asarray(V, dtype=float)), (m, 6))
        P = np.empty((15, m))
        P[:9] = F.T
        P[9:] = joint_side_friction(V, rig)
        return P


#: The rigid robot with per-lane friction rows (15 parameters).
RIGID_FRICTION = RigidWithFriction(name="rigid+friction", kind=RIGID_FRICTION_KIND, encoder_row=0)
