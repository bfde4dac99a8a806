"""Plants of the closed-loop core: the robot's right-hand side, rigid or flexible.

A plant is a right-hand side of one lane, ``rhs(p, c, x, u, sc) -> (xdot,
margin)``, of the core (:mod:`plant.simulation.core`, where the
signature is described), registered under a kind (a type tag) by
:func:`register_plant` in :data:`RIGHT_HAND_SIDES`, together with its state
layout (:class:`Plant`): which rows the motor encoders read, how many
per-lane parameters it takes and how its start state follows from the
rig's.  Two plants are defined here:

* :data:`RIGID` -- the rigid model of :mod:`plant.robot.model` (paper eq. 2),
  state ``(q2, q3, qd2, qd3)``, parameters f1..f9, the encoders read q;
* :class:`FlexibleJoints` -- Spong's two-mass flexible joints, state
  ``(q2, q3, qd2, qd3, th2, th3, thd2, thd3)`` (link, then motor angle / k),
  the encoders read th.

A robot model's rigid n-joint arm (:class:`plant.simulation.arm.ArmPlant`) registers
its own kind, generated from the model.

Both add the joint-side drive friction of the rig (motor side: viscous and
asymmetric Coulomb with a linear ramp; :func:`plant.robot.model.friction_torque`)
and turn the held motor current into joint torque ``k Kt i``.  To add a
plant (another friction law, a third joint), write its right-hand side with
the same signature, register it under a new kind with :func:`register_plant`
and describe it by a :class:`Plant`; every driver of the core then
simulates it.  The drive friction is the rig's
(:class:`plant.logs.rig.RigConstants`, shared by all lanes); a plant that
identifies friction carries it in its own per-lane parameters
(:data:`plant.simulation.friction.RIGID_FRICTION`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, NamedTuple

import numba
import numpy as np

from plant.robot.model import friction_torque, joint_acceleration_sc
from plant.logs.rig import friction_vector, joint_side_friction

__all__ = ["Plant", "RIGID", "FlexibleJoints", "rigid_rhs", "rigid_derivative", "flexible_rhs", "RigidKind",
           "FlexibleKind", "RIGID_KIND", "FLEXIBLE_KIND", "RightHandSide", "RIGHT_HAND_SIDES",
           "register_plant", "dead_zone", "FLEXIBLE_N_PARAMETERS", "link_f"]


def link_f(f, reflected_inertia) -> np.ndarray:
    """Link-only f of a two-mass robot: the rigid-equivalent f minus ``Jm k^2``.

    Parameters
    ----------
    f : array_like, shape (9,) or (m, 9)
        Rigid-equivalent base parameters (link plus Jm k^2 in f7 and f1, eq. 3).
    reflected_inertia : array_like, shape (2,)
        ``(Jm2 k2^2, Jm3 k3^2)`` (kg m^2).

    Returns
    -------
    ndarray, same shape as ``f``
        ``f7 - Jm2 k2^2`` and ``f1 - Jm3 k3^2``, the rest unchanged (a copy).
    """
    jk2 = np.asarray(reflected_inertia, dtype=float)
    fl = np.array(f, dtype=float)
    fl[..., 6] -= jk2[0]
    fl[..., 0] -= jk2[1]
    return fl


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
#: compile time (:func:`plant.simulation.core.plant_rhs`), so each kernel is compiled
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
        right-hand side (:func:`plant.simulation.core.plant_rhs`), registered with its
        sizes by :func:`register_plant`.
    encoder_row : int
        Row of the angle the joint-2 motor encoder reads (joint 3: the next
        row), joint side (motor angle / k).
    n_states : int
        Rows of the state array (from the registry); rows 0, 1 are the link
        angles q2, q3 and rows 2, 3 their rates.
    n_parameters : int
        Rows of the per-lane parameter array P (from the registry).
    """

    name: str
    kind: tuple
    encoder_row: int

    def _registered(self):
        entry = RIGHT_HAND_SIDES.get(type(self.kind))
        if entry is None:
            raise ValueError(f"unknown plant kind {type(self.kind).__name__}: register its "
                             "right-hand side with plant.simulation.plants.register_plant")
        return entry

    @property
    def n_states(self) -> int:
        """Rows of the state array: the registered right-hand side's state size."""
        return self._registered().n_states

    @property
    def n_parameters(self) -> int:
        """Rows of the per-lane parameter array: the registered right-hand side's."""
        return self._registered().n_parameters

    def lane_parameters(self, F, rig) -> np.ndarray:
        """Per-lane parameter array of candidates ``F`` (m, 9) (rigid-equivalent f).

        Plants with parameters beyond f take them as keyword arrays (e.g.
        :meth:`FlexibleJoints.lane_parameters`).

        Parameters
        ----------
        F : ndarray, shape (m, 9)
            Base parameters f1..f9 per candidate.
        rig : plant.logs.rig.Rig

        Returns
        -------
        ndarray, shape (n_parameters, m)
        """
        return np.ascontiguousarray(np.asarray(F, dtype=np.float64).T)

    def initial_state(self, c) -> np.ndarray:
        """Start state (n_states,) from the rig layout's ``q0``, ``qd0``.

        A plant whose state repeats the joints' ``(q, qd)`` -- two-mass
        joints, the motor's ``(th, thd)`` after the link's -- starts with
        every copy at the rig's start (springs relaxed, motor where the
        link is).

        Parameters
        ----------
        c : plant.logs.rig.RigConstants

        Returns
        -------
        ndarray, shape (n_states,)

        Raises
        ------
        ValueError
            If the state is not a whole number of ``(q, qd)`` copies.
        """
        x = np.array(list(c.q0) + list(c.qd0), dtype=float)
        copies, rest = divmod(self.n_states, x.size) if x.size else (0, 1)
        if rest or copies < 1:
            raise ValueError(f"{self.name}: {self.n_states} states are not copies of (q, qd) "
                             f"({x.size} values)")
        return np.tile(x, copies)


@_jit
def rigid_rhs(p, c, x, u, sc):
    """Right-hand side of the rigid robot (paper eq. 2) for one lane.

    State ``x = (q2, q3, qd2, qd3)``; parameters ``p = (f1, ..., f9)``.  See
    :mod:`plant.simulation.core` for the protocol.

    Parameters
    ----------
    p : tuple of 9 float
        The lane's base parameters f1..f9.
    c : plant.logs.rig.RigConstants
        Rig layout.
    x : tuple of 4 float
        Stage state (rad, rad/s).
    u : tuple of 2 float
        Held motor currents (A) of joints 2 and 3.
    sc : tuple of 4 float
        sin q2, cos q2, sin q3, cos q3 of the stage.

    Returns
    -------
    xdot : tuple of 4 float
        (qd2, qd3, qdd2, qdd3).
    margin : float
        det D(q), or -1 where f1 <= 0.
    """
    return rigid_derivative(p, c, x, u, sc, c.viscous, c.coulomb_pos, c.coulomb_neg)


@_jit
def rigid_derivative(p, c, x, u, sc, viscous, coulomb_pos, coulomb_neg):
    """The rigid robot's state derivative with the given joint-side friction.

    The one copy of the rigid right-hand side: :func:`rigid_rhs` passes the
    rig's friction, :func:`plant.simulation.friction.rigid_friction_rhs` the lane's.

    Parameters
    ----------
    p, c, x, u, sc
        As :func:`rigid_rhs` (only ``p[0:9]`` is read).
    viscous, coulomb_pos, coulomb_neg : tuple of 2 float
        Joint-side viscous coefficients (N m s/rad) and Coulomb levels for
        positive / non-positive rate (N m), joints 2 and 3; the ramp speed is
        the rig's.

    Returns
    -------
    xdot : tuple of 4 float
        (qd2, qd3, qdd2, qdd3).
    margin : float
        det D(q), or -1 where f1 <= 0.
    """
    u2, u3 = u
    s2, c2, s3, c3 = sc
    w2 = x[2]
    w3 = x[3]
    tau2 = c.torque_per_amp[0] * u2 + friction_torque(
        w2, viscous[0], coulomb_pos[0], coulomb_neg[0], c.ramp_speed[0])
    tau3 = c.torque_per_amp[1] * u3 + friction_torque(
        w3, viscous[1], coulomb_pos[1], coulomb_neg[1], c.ramp_speed[1])
    a2, a3, det = joint_acceleration_sc(p[0:9], s2, c2, s3, c3, w2, w3, tau2, tau3, c.gravity)
    return (w2, w3, a2, a3), (det if p[0] > 0.0 else -1.0)


class RightHandSide(NamedTuple):
    """A registered right-hand side of the core and its state size.

    Attributes
    ----------
    function : callable
        The compiled right-hand side (protocol of :mod:`plant.simulation.core`).
    n_states : int
        Length of the state tuple it takes and returns.
    n_parameters : int
        Length of the per-lane parameter tuple it takes.
    n_inputs : int
        Held motor currents it takes (one per driven joint).
    n_angles : int
        Leading state components whose sine and cosine it takes.
    """

    function: Callable
    n_states: int
    n_parameters: int
    n_inputs: int = 2
    n_angles: int = 2


#: Registry of the core: plant kind class -> :class:`RightHandSide`
#: (:func:`plant.simulation.core.plant_rhs`).
RIGHT_HAND_SIDES: dict = {}


def register_plant(kind_class, rhs, n_states: int, n_parameters: int, n_inputs: int = 2,
                   n_angles: int = 2) -> None:
    """Register a right-hand side under a plant kind class (see the module docstring).

    Parameters
    ----------
    kind_class : type
        A ``NamedTuple`` class whose instances are the plant's kind.
    rhs : numba dispatcher
        The compiled right-hand side ``rhs(p, c, x, u, sc) -> (xdot,
        margin)`` with ``x`` and ``xdot`` tuples of ``n_states`` floats,
        ``p`` a tuple of ``n_parameters`` floats, ``u`` of ``n_inputs``
        currents and ``sc`` the sine and cosine of the first ``n_angles``
        states (:mod:`plant.simulation.core`).
    n_states : int
        State components; rows ``0..n_angles-1`` are the angles.
    n_parameters : int
        Per-lane parameters (rows of the plant's P).
    n_inputs : int
        Motor currents (rows of the plant's U); 2 for the PUMA links 2-3.
    n_angles : int
        Angles whose sine and cosine the right-hand side takes.

    Raises
    ------
    ValueError
        If ``n_parameters < 1``, ``n_inputs < 1`` or ``n_angles`` is not in
        ``1..n_states``.
    """
    if not (1 <= int(n_angles) <= int(n_states)) or int(n_parameters) < 1 or int(n_inputs) < 1:
        raise ValueError("a plant has at least one angle among its states, one parameter and one "
                         f"input, got n_states={n_states}, n_parameters={n_parameters}, "
                         f"n_inputs={n_inputs}, n_angles={n_angles}")
    RIGHT_HAND_SIDES[kind_class] = RightHandSide(rhs, int(n_states), int(n_parameters),
                                                 int(n_inputs), int(n_angles))


register_plant(RigidKind, rigid_rhs, 4, 9)

#: The rigid robot of :mod:`plant.robot.model`: state (q2, q3, qd2, qd3), the
#: encoders read q, parameters f1..f9.
RIGID = Plant(name="rigid", kind=RIGID_KIND, encoder_row=0)


# ----------------------------------------------------------------------------
# Two-mass flexible joints
# ----------------------------------------------------------------------------
# Rows of the flexible plant's per-lane parameters after the nine link f:
# stiffness (2), damping (2), reflected motor inertia (2), joint-side friction
# (viscous 2, Coulomb for positive rate 2, for negative rate 2), backlash width (2).
_FX_K, _FX_D, _FX_J, _FX_FV, _FX_FP, _FX_FN, _FX_B = 9, 11, 13, 15, 17, 19, 21
#: Per-lane parameters of the flexible plant.
FLEXIBLE_N_PARAMETERS = 23


@_jit
def dead_zone(delta, width):
    """Spring deflection through a gearbox dead zone (backlash) of total width ``width``.

    ``delta - clip(delta, -width / 2, width / 2)``: zero inside the play, the
    deflection beyond it outside (the classical dead-zone backlash model of
    a gear pair: M. Nordin and P.-O. Gutman, "Controlling mechanical systems
    with backlash -- a survey", Automatica 38 (2002), sec. 2.2).  With
    ``width = 0`` it is ``delta`` bit for bit.

    Parameters
    ----------
    delta : float
        Deflection th - q (rad, joint side).
    width : float
        Backlash width b >= 0 (rad, joint side).

    Returns
    -------
    float
        The deflection the spring sees (rad).
    """
    hb = 0.5 * width
    return delta - min(max(delta, -hb), hb)


@_jit
def flexible_rhs(p, c, x, u, sc):
    """Right-hand side of the two-mass flexible-joint robot for one lane.

    State ``x = (q2, q3, qd2, qd3, th2, th3, thd2, thd3)``; parameters ``p``:
    link f1..f9, stiffness K (2), damping D (2), reflected motor inertia
    Jm k^2 (2), joint-side drive friction (viscous 2, Coulomb for positive
    rate 2, for negative rate 2) and backlash width b (2).  The spring
    torque is ``K dead_zone(th - q, b) + D (th' - q')`` (:func:`dead_zone`).
    See :mod:`plant.simulation.core` for the protocol.

    Parameters
    ----------
    p : tuple of 23 float
        The lane's parameters.
    c : plant.logs.rig.RigConstants
        Rig layout (the Coulomb ramp speed).
    x : tuple of 8 float
        Stage state (rad, rad/s).
    u : tuple of 2 float
        Held motor currents (A) of joints 2 and 3.
    sc : tuple of 4 float
        sin q2, cos q2, sin q3, cos q3 of the stage's link angles.

    Returns
    -------
    xdot : tuple of 8 float
        The state derivative.
    margin : float
        det D_link(q), or -1 where the link f1 <= 0.
    """
    q2, q3, w2, w3, th2, th3, v2, v3 = x
    u2, u3 = u
    s2, c2, s3, c3 = sc
    ts2 = p[_FX_K] * dead_zone(th2 - q2, p[_FX_B]) + p[_FX_D] * (v2 - w2)
    ts3 = p[_FX_K + 1] * dead_zone(th3 - q3, p[_FX_B + 1]) + p[_FX_D + 1] * (v3 - w3)
    a2, a3, det = joint_acceleration_sc(p[0:9], s2, c2, s3, c3, w2, w3, ts2, ts3, c.gravity)
    fr2 = friction_torque(v2, p[_FX_FV], p[_FX_FP], p[_FX_FN], c.ramp_speed[0])
    fr3 = friction_torque(v3, p[_FX_FV + 1], p[_FX_FP + 1], p[_FX_FN + 1], c.ramp_speed[1])
    b2 = (c.torque_per_amp[0] * u2 + fr2 - ts2) / p[_FX_J]
    b3 = (c.torque_per_amp[1] * u3 + fr3 - ts3) / p[_FX_J + 1]
    return (w2, w3, a2, a3, v2, v3, b2, b3), (det if p[0] > 0.0 else -1.0)


register_plant(FlexibleKind, flexible_rhs, 8, FLEXIBLE_N_PARAMETERS)


@dataclass(frozen=True)
class FlexibleJoints(Plant):
    """Spong two-mass joints: motor and link joined by a spring and damper, optional backlash.

    With ``th`` the motor angle divided by the gear ratio (joint-side motor
    angle, what the encoder reads) and ``q`` the link angle, per joint::

        Jm k^2 th'' = k Kt i + tau_friction(th') - tau_s
        D_link(q) q'' + h(q, q') + g(q) = tau_s
        tau_s = Ks (delta - clip(delta, -b/2, b/2)) + Ds (th' - q'),  delta = th - q

    ``D_link`` is the rigid model of :mod:`plant.robot.model` with the reflected
    motor inertias removed from f7 (joint 2) and f1 (joint 3) (f1 - Jm k3^2,
    f7 - Jm k2^2); friction acts on the motor side; ``b`` is the gearbox
    backlash (a dead zone of total width b on the deflection,
    :func:`dead_zone`; 0 by default).  Source: M. W. Spong, "Modeling and
    control of elastic joint robots", J. Dyn. Syst. Meas. Control 109
    (1987); backlash: M. Nordin and P.-O. Gutman, Automatica 38 (2002).
    The robot starts with the springs relaxed (motor angles and rates equal
    to the link's).

    Parameters
    ----------
    stiffness_Nm_per_rad : float or tuple of 2 float
        Joint-side spring stiffness Ks (N m/rad), > 0.
    damping_Nms_per_rad : float or tuple of 2 float
        Joint-side spring damping Ds (N m s/rad), >= 0.
    motor_inertia_kgm2 : float or tuple of 2 float
        Motor rotor inertia Jm (kg m^2), motor side, > 0.
    backlash_rad : float or tuple of 2 float
        Backlash width b (rad, joint side), >= 0 (default 0: none).

    Raises
    ------
    ValueError
        On a non-finite or out-of-range constant.
    """

    stiffness_Nm_per_rad: tuple = (1.0, 1.0)
    damping_Nms_per_rad: tuple = (0.0, 0.0)
    motor_inertia_kgm2: tuple = (1.0, 1.0)
    backlash_rad: tuple = (0.0, 0.0)

    def __init__(self, stiffness_Nm_per_rad, damping_Nms_per_rad, motor_inertia_kgm2,
                 backlash_rad=0.0):
        pairs = []
        for name, v, positive in (("stiffness_Nm_per_rad", stiffness_Nm_per_rad, True),
                                  ("damping_Nms_per_rad", damping_Nms_per_rad, False),
                                  ("motor_inertia_kgm2", motor_inertia_kgm2, True),
                                  ("backlash_rad", backlash_rad, False)):
            a = np.broadcast_to(np.asarray(v, dtype=float), (2,))
            if not np.all(np.isfinite(a)) or np.any(a <= 0 if positive else a < 0):
                raise ValueError("FlexibleJoints: stiffness and motor inertia must be > 0, "
                                 f"damping and backlash >= 0 (got {name}={v!r})")
            pairs.append((float(a[0]), float(a[1])))
        Plant.__init__(self, name="flexible", kind=FLEXIBLE_KIND, encoder_row=4)
        object.__setattr__(self, "stiffness_Nm_per_rad", pairs[0])
        object.__setattr__(self, "damping_Nms_per_rad", pairs[1])
        object.__setattr__(self, "motor_inertia_kgm2", pairs[2])
        object.__setattr__(self, "backlash_rad", pairs[3])

    def reflected_inertia(self, rig) -> np.ndarray:
        """Reflected motor inertias Jm k^2 of joints 2 and 3 (kg m^2), shape (2,).

        Parameters
        ----------
        rig : plant.logs.rig.Rig
        """
        k = np.asarray(rig.gear_ratio, float)
        return np.asarray(self.motor_inertia_kgm2) * k * k

    def link_parameters(self, f, rig) -> np.ndarray:
        """Link-only f: the rigid-equivalent f minus the reflected motor inertias.

        Parameters
        ----------
        f : array_like, shape (9,) or (m, 9)
            Rigid-equivalent base parameters (link plus Jm k^2 in f1 and f7).
        rig : plant.logs.rig.Rig

        Returns
        -------
        ndarray, same shape as ``f``
            ``f1 - Jm3 k3^2`` and ``f7 - Jm2 k2^2``, the rest unchanged.
        """
        return link_f(f, self.reflected_inertia(rig))

    def lane_parameters(self, F, rig, joints=None, friction=None, backlash=None) -> np.ndarray:
        """Per-lane parameters (23, m): link f, Ks, Ds, Jm k^2, friction, b (see :func:`flexible_rhs`).

        Parameters
        ----------
        F : ndarray, shape (m, 9)
            Rigid-equivalent base parameters per candidate.
        rig : plant.logs.rig.Rig
        joints : array_like, shape (m, 6), optional
            Per-candidate joints ``(K2, K3, D2, D3, Jm2 k2^2, Jm3 k3^2)``
            (N m/rad, N m s/rad, kg m^2; identification); default this
            plant's constants for every candidate.
        friction : array_like, shape (m, 6) or (6,), optional
            Motor-side drive friction per candidate in the order of
            :data:`plant.simulation.friction.FRICTION_NAMES`; default the rig's
            (unknown values 0).
        backlash : array_like, shape (m, 2) or (2,), optional
            Backlash widths b (rad, joint side) per candidate; default this
            plant's :attr:`backlash_rad`.

        Returns
        -------
        ndarray, shape (23, m)

        Raises
        ------
        ValueError
            On a friction of the wrong shape or not finite.
        """
        F = np.atleast_2d(np.asarray(F, dtype=float))
        m = F.shape[0]
        P = np.empty((FLEXIBLE_N_PARAMETERS, m))
        if joints is not None:
            J = np.broadcast_to(np.atleast_2d(np.asarray(joints, dtype=float)), (m, 6))
            P[:9] = F.T
            P[6] -= J[:, 4]
            P[0] -= J[:, 5]
            P[_FX_K:_FX_FV] = J.T
        else:
            P[:9] = self.link_parameters(F, rig).T
            P[_FX_K:_FX_K + 2] = np.asarray(self.stiffness_Nm_per_rad)[:, None]
            P[_FX_D:_FX_D + 2] = np.asarray(self.damping_Nms_per_rad)[:, None]
            P[_FX_J:_FX_J + 2] = self.reflected_inertia(rig)[:, None]
        V = friction_vector(rig) if friction is None else friction
        V = np.broadcast_to(np.atleast_2d(np.asarray(V, dtype=float)), (m, 6))
        P[_FX_FV:_FX_B] = joint_side_friction(V, rig)
        b = self.backlash_rad if backlash is None else backlash
        P[_FX_B:] = np.broadcast_to(np.atleast_2d(np.asarray(b, dtype=float)), (m, 2)).T
        return P

