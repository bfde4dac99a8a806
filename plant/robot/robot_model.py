"""A serial robot as one object: DH table or URDF -> symbolic dynamics -> regressor -> base parameters.

:class:`RobotModel` describes a chain of revolute joints by its
Denavit--Hartenberg table (standard or modified) or a URDF file
(:meth:`RobotModel.from_urdf`, read by Robotics Toolbox's reader), the links' inertial
parameters and the drives (gear ratio, motor inertia), with a chosen subset
of the joints *active* (the others locked at given angles, e.g. the PUMA 560
joints 2 and 3 of the paper with joint 1 and the wrist locked).  casadi
derives, once per model:

* the inverse dynamics ``tau = D(q) qdd + c(q, qd) + g(q)`` of the active
  joints, with the inertia matrix D, the Coriolis/centrifugal vector c and
  the gravity vector g as casadi functions;
* the regressor ``Y(q, qd, qdd)``, shape ``(n, 10 L + n)``, linear in the
  **standard inertial parameters** (Khalil & Dombre, *Modeling,
  Identification and Control of Robots*, 2002, sec. 9.3): per link, in the
  link's own DH frame, ``XX XY XZ YY YZ ZZ`` (inertia about the frame
  origin), ``MX MY MZ`` (first moments, mass x centre of mass) and ``M``;
  per active joint the reflected motor inertia ``Ia = Jm k^2``;
* the **base parameters** by the numerical QR method (M. Gautier, "Numerical
  calculation of the base inertial parameters of robots", *ICRA* 1990; the
  regressor stacked at random states, QR with column pivoting, the rank from
  the diagonal of R): the identifiable linear combinations of the standard
  parameters, each with its expression (:class:`BaseParameterSet`);
* their search ranges from physical ranges by interval arithmetic (the
  paper's section 3.6; :meth:`RobotModel.parameter_ranges`).

Derivation (Newton--Euler in the world frame, every quantity symbolic):
the forward kinematics give each link frame's origin ``o_i(q)`` and rotation
``R_i(q)``; velocities and accelerations are their time derivatives by the
chain rule (``d/dt x(q, qd) = dx/dq qd + dx/dqd qdd``, casadi ``jtimes``);
the angular velocity is ``vee(dR/dt R^T)``.  Link i exerts, about its frame
origin, the force ``f_i = M a_i + alpha_i x m_i + w_i x (w_i x m_i)`` and the
moment ``n_i = I_i alpha_i + w_i x (I_i w_i) + m_i x a_i`` (``m_i = R_i
[MX, MY, MZ]``, ``I_i = R_i I_o R_i^T``, ``a_i`` the origin's acceleration
minus gravity); the torque of joint j is the moment of every link distal to
it about its axis, ``tau_j = z_j . sum_i (n_i + (o_i - p_j) x f_i)``, plus
``Ia_j qdd_j`` (the rotors' gyroscopic coupling neglected, as in the standard
PUMA model and Robotics Toolbox's ``rne``).  A flipped joint (``Link.flip``,
Robotics Toolbox's ``flip``) turns the other way: ``theta = offset - q``
and its torque is about ``-z_j``.  The tests check the result
against Robotics Toolbox for Python (``DHRobot.rne``) when it is installed,
and the PUMA 560 links 2--3 base parameters against the paper's eq. 3.

A model may also take a named basis as its parameter vector
(:class:`BasisModel`: the torques ``B(q, qd, qdd) theta``, ``theta = K p``
of the chain's standard parameters).  The paper's PUMA 560 links 2--3 are
such an instance, :meth:`RobotModel.puma560_links23`: the paper's joint
convention, the parameters f1..f9 of eq. 3 (nine, kept free although the
chain's geometry ties two of them), its dynamics
:mod:`plant.robot.model`'s closed forms.

Any model runs through the closed loop, the identification and the
controllers of :mod:`plant.simulation.arm`, :mod:`identification.arm` and
:mod:`ctc.arm`; the paper's own path (:func:`identification.identify`, the
on-line payload, the adaptive CTC) still runs on the PUMA 560 links 2--3
model of :mod:`plant.robot.model` (issue 23 carries it to n joints).
"""
from __future__ import annotations

import dataclasses
import functools
import math
from dataclasses import dataclass, field
from functools import cached_property

import casadi as ca
import numpy as np

__all__ = [
    "Link",
    "RobotModel",
    "BasisModel",
    "BaseParameterSet",
    "ParameterBasis",
    "STANDARD_NAMES",
    "PUMA560_DH",
    "PUMA560_LINKS23_BASIS",
]

#: Link-frame conventions: standard DH, modified DH (Craig), URDF (origin + axis).
CONVENTIONS = ("standard", "modified", "urdf")

#: Standard inertial parameters of one link, in this order (Khalil & Dombre).
STANDARD_NAMES = ("XX", "XY", "XZ", "YY", "YZ", "ZZ", "MX", "MY", "MZ", "M")


@dataclass(frozen=True)
class Link:
    """One revolute joint with its link: DH row, inertia and drive.

    Parameters
    ----------
    a, alpha, d : float
        DH link length (m), twist (rad) and offset (m).  Standard DH
        (``T = Rz(theta) Tz(d) Tx(a) Rx(alpha)``, frame i at the far end of
        link i) or modified DH (Craig: ``T = Rx(alpha) Tx(a) Rz(theta)
        Tz(d)``, frame i on joint i's axis), as the model's ``convention``.
    offset : float
        Joint angle offset (rad): ``theta = q + offset``.
    mass : float
        Link mass (kg), >= 0.
    com : array_like, shape (3,)
        Centre of mass in the link frame (m).
    inertia : array_like, shape (3, 3) or (6,)
        Inertia about the centre of mass in the link frame (kg m^2): a
        symmetric matrix or ``(Ixx, Iyy, Izz, Ixy, Iyz, Ixz)`` (Robotics
        Toolbox's order).
    gear_ratio : float
        Motor angle / joint angle (k), nonzero.
    motor_inertia : float
        Rotor inertia Jm on the motor side (kg m^2), >= 0; the joint sees
        ``Jm k^2``.
    origin : array_like, shape (4, 4), optional
        ``convention="urdf"`` only: the constant transform from the parent
        link's frame to the joint frame (URDF ``<origin>``); default identity.
    axis : array_like, shape (3,)
        ``convention="urdf"`` only: the joint axis in the joint frame (URDF
        ``<axis>``), normalised; default z.
    name : str
        The joint's name (URDF); optional.
    flip : bool
        The joint variable turns the other way: ``theta = offset - q`` and
        the joint's torque is about the negated axis (Robotics Toolbox's
        ``flip``); the link frame, hence the inertial parameters, is the
        same.  Default False.

    Raises
    ------
    ValueError
        On a non-finite value, a negative mass or motor inertia, a zero gear
        ratio, an inertia of the wrong shape, an origin that is not a rigid
        transform or a zero axis.
    """

    a: float = 0.0
    alpha: float = 0.0
    d: float = 0.0
    offset: float = 0.0
    mass: float = 0.0
    com: tuple = (0.0, 0.0, 0.0)
    inertia: tuple = field(default=(0.0,) * 6)
    gear_ratio: float = 1.0
    motor_inertia: float = 0.0
    origin: tuple | None = None
    axis: tuple = (0.0, 0.0, 1.0)
    name: str = ""
    flip: bool = False

    def __post_init__(self):
        for name in ("a", "alpha", "d", "offset", "mass", "gear_ratio", "motor_inertia"):
            v = float(getattr(self, name))
            if not math.isfinite(v):
                raise ValueError(f"Link.{name} must be finite, got {getattr(self, name)!r}")
            object.__setattr__(self, name, v)
        if self.mass < 0 or self.motor_inertia < 0:
            raise ValueError("Link.mass and Link.motor_inertia must be >= 0")
        if self.gear_ratio == 0:
            raise ValueError("Link.gear_ratio must be nonzero")
        com = np.asarray(self.com, dtype=float).reshape(-1)
        if com.shape != (3,) or not np.all(np.isfinite(com)):
            raise ValueError(f"Link.com must be 3 finite numbers, got {self.com!r}")
        object.__setattr__(self, "com", tuple(com.tolist()))
        inertia = np.asarray(self.inertia, dtype=float)
        if inertia.shape == (6,):
            ixx, iyy, izz, ixy, iyz, ixz = inertia
            inertia = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
        if inertia.shape != (3, 3) or not np.all(np.isfinite(inertia)) or not np.allclose(
                inertia, inertia.T):
            raise ValueError("Link.inertia must be a finite symmetric (3, 3) matrix or 6 numbers "
                             "(Ixx, Iyy, Izz, Ixy, Iyz, Ixz)")
        object.__setattr__(self, "inertia", tuple(map(tuple, inertia.tolist())))
        if self.origin is not None:
            T = np.asarray(self.origin, dtype=float)
            if (T.shape != (4, 4) or not np.all(np.isfinite(T))
                    or not np.allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-9)
                    or not np.allclose(T[3], [0, 0, 0, 1])):
                raise ValueError("Link.origin must be a (4, 4) rigid transform")
            object.__setattr__(self, "origin", tuple(map(tuple, T.tolist())))
        ax = np.asarray(self.axis, dtype=float).reshape(-1)
        if ax.shape != (3,) or not np.all(np.isfinite(ax)) or np.linalg.norm(ax) == 0:
            raise ValueError(f"Link.axis must be 3 finite numbers, not all zero, got {self.axis!r}")
        object.__setattr__(self, "axis", tuple((ax / np.linalg.norm(ax)).tolist()))
        object.__setattr__(self, "flip", bool(self.flip))

    def standard_parameters(self) -> np.ndarray:
        """``XX XY XZ YY YZ ZZ MX MY MZ M`` of this link (about the frame origin), shape (10,).

        The inertia about the frame origin is the inertia about the centre
        of mass plus ``M (|c|^2 1 - c c^T)`` (parallel axes, Steiner).
        """
        return _body_parameters(self.mass, np.asarray(self.com), np.asarray(self.inertia))


def _body_parameters(mass, c, inertia) -> np.ndarray:
    """``XX XY XZ YY YZ ZZ MX MY MZ M`` (10,) of a body of ``mass`` with centre of mass ``c``
    (3,) and inertia (3, 3) about it, about the frame origin (Steiner)."""
    i_o = inertia + mass * (c @ c * np.eye(3) - np.outer(c, c))
    return np.array([i_o[0, 0], i_o[0, 1], i_o[0, 2], i_o[1, 1], i_o[1, 2], i_o[2, 2],
                     *(mass * c), mass])


@dataclass(frozen=True)
class ParameterBasis:
    """A named parameter basis of a model's torques: ``tau = B(q, qd, qdd) theta``.

    Attributes
    ----------
    name : str
    names : tuple of str
        Parameter names, in order.
    regressor : callable
        ``B(q, qd, qdd)`` -> ndarray (n, k), in the model's joint convention.
    torque : callable, optional
        ``torque(s, c, qd, qdd, theta)`` -> casadi SX (n,): the torques ``B
        theta`` (N m) written in ``s = sin q`` and ``c = cos q`` (casadi SX
        columns (n,), like ``qd``, ``qdd``; ``theta`` (k,)).  Needed to make
        the basis a model's parameter vector (:class:`BasisModel`); None
        when the basis only names combinations (:meth:`RobotModel.express`).
    """

    name: str
    names: tuple
    regressor: object
    torque: object = None


@dataclass(frozen=True)
class BaseParameterSet:
    """The base parameters of a robot model (numerical QR, Gautier 1990).

    ``beta = K p`` with ``p`` the standard parameters; the regressor of the
    base parameters is ``Y[:, independent]`` (``Y p = Y_b beta`` for every
    p and every state).

    Attributes
    ----------
    names : tuple of str
        One name per base parameter: the independent standard parameter it
        is built on, with ``R`` appended when others are regrouped into it
        (Khalil's convention, e.g. ``ZZ2R``).
    independent : ndarray of int, shape (r,)
        Columns of the standard regressor that carry the base parameters.
    K : ndarray, shape (r, n_std)
        The regrouping: ``beta = K p`` (entries below 1e-10 of the largest
        set to zero).
    expressions : tuple of str
        ``beta_i`` written in the standard parameters.
    rank : int
        Number of base parameters r (for a named basis, the rank of K: fewer
        than ``len(names)`` when the basis is not minimal).
    singular_values : ndarray
        Absolute diagonal of R of the QR (decreasing), or the singular
        values of K for a named basis: the rank's evidence.
    relations : tuple of str
        For a named basis that is not minimal: the linear relations the
        geometry imposes on its parameters (``"f3 - 0.4318 f5 = 0"``), one
        per missing rank; empty for the QR's base parameters.

    A named basis (:meth:`RobotModel.express`) has ``independent = None``.
    """

    names: tuple
    independent: np.ndarray | None
    K: np.ndarray
    expressions: tuple
    rank: int
    singular_values: np.ndarray
    relations: tuple = ()

    def __call__(self, p) -> np.ndarray:
        """The parameters of standard parameters ``p`` (n_std,), shape (len(names),)."""
        return self.K @ np.asarray(p, dtype=float)


def _rref(N, tol=1e-9):
    """Reduced row echelon form of the rows of N (partial pivoting), shape kept."""
    N = np.array(N, dtype=float)
    row = 0
    for col in range(N.shape[1]):
        if row >= N.shape[0]:
            break
        piv = row + int(np.argmax(np.abs(N[row:, col])))
        if abs(N[piv, col]) <= tol:
            continue
        N[[row, piv]] = N[[piv, row]]
        N[row] /= N[row, col]
        for i in range(N.shape[0]):
            if i != row:
                N[i] -= N[i, col] * N[row]
        row += 1
    N[np.abs(N) <= tol] = 0.0
    return N[:row]


def _vee(S):
    return ca.vertcat(S[2, 1], S[0, 2], S[1, 0])


def _transform(R=None, p=None):
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = R
    if p is not None:
        T[:3, 3] = p
    return T


def _rot_x(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _pieces(link: Link, convention):
    """``(A, axis, B)`` with the link transform ``T = A Rot(axis, theta) B`` (A, B constant 4x4).

    Standard DH: ``A = 1``, ``B = Tz(d) Tx(a) Rx(alpha)``; modified DH:
    ``A = Rx(alpha) Tx(a)``, ``B = Tz(d)``; URDF: ``A = origin``, ``B = 1``.
    """
    z = np.array([0.0, 0.0, 1.0])
    if convention == "standard":
        return np.eye(4), z, _transform(_rot_x(link.alpha), [link.a, 0.0, link.d])
    if convention == "modified":
        return _transform(_rot_x(link.alpha), [link.a, 0.0, 0.0]), z, _transform(p=[0, 0, link.d])
    A = np.eye(4) if link.origin is None else np.asarray(link.origin, dtype=float)
    return A, np.asarray(link.axis, dtype=float), np.eye(4)


def _lumped(link: Link, T, m, com, inertia) -> Link:
    """``link`` with a rigidly attached body (mass m, centre of mass ``com`` and inertia
    about it in the body frame; ``T`` body frame -> link frame) added."""
    R, p = T[:3, :3], T[:3, 3]
    m0, c0, I0 = link.mass, np.asarray(link.com), np.asarray(link.inertia)
    c1, I1 = R @ np.asarray(com) + p, R @ np.asarray(inertia) @ R.T
    mt = m0 + m
    if mt <= 0:
        return link
    c = (m0 * c0 + m * c1) / mt
    Ic = np.zeros((3, 3))
    for mi, ci, Ii in ((m0, c0, I0), (m, c1, I1)):
        d = ci - c
        Ic += Ii + mi * (d @ d * np.eye(3) - np.outer(d, d))
    return dataclasses.replace(link, mass=mt, com=tuple(c), inertia=tuple(map(tuple, Ic)))


def _interval(v, what):
    a = np.asarray(v, dtype=float).reshape(-1)
    if a.size == 1:
        a = np.array([a[0], a[0]])
    if a.shape != (2,) or not np.all(np.isfinite(a)) or a[0] > a[1]:
        raise ValueError(f"a {what} range must be a number or (lo, hi) with lo <= hi, got {v!r}")
    return float(a[0]), float(a[1])


def _imul(a, b):
    p = (a[0] * b[0], a[0] * b[1], a[1] * b[0], a[1] * b[1])
    return min(p), max(p)


def _iadd(a, b):
    return a[0] + b[0], a[1] + b[1]


def _ineg(a):
    return -a[1], -a[0]


def _isq(a):
    lo2, hi2 = a[0] * a[0], a[1] * a[1]
    return (0.0 if a[0] <= 0.0 <= a[1] else min(lo2, hi2)), max(lo2, hi2)


def _interval_map(K, lo, hi):
    """``(lo, hi)`` of ``K x`` for x in the box ``[lo, hi]`` (term by term, exact per row)."""
    Kp, Kn = np.clip(K, 0, None), np.clip(K, None, 0)
    return Kp @ lo + Kn @ hi, Kp @ hi + Kn @ lo


def _axis_rotation(axis, sin_theta, cos_theta):
    """Rodrigues' rotation about a unit axis (numeric) by theta, from sin and cos of theta."""
    K = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    return ca.DM.eye(3) + sin_theta * ca.DM(K) + (1 - cos_theta) * ca.DM(K @ K)


class RobotModel:
    """A serial arm of revolute joints (DH table), some active, the rest locked.

    Parameters
    ----------
    links : sequence of Link
        The chain from the base, one per joint.
    convention : {"standard", "modified", "urdf"}
        How a link's frame follows its parent's: DH table (standard or
        modified) or URDF joint (``Link.origin``, then a turn about
        ``Link.axis``; :meth:`from_urdf`).
    active : sequence of int, optional
        Indices (0-based) of the joints that move (default all), in chain
        order.  The model's joint vector q holds these, in this order.
    locked : dict or sequence of float, optional
        Angles (rad, the joint variable q, before ``offset``) of the joints
        that do not move: a dict ``{index: angle}`` or one angle per joint
        (the active ones' entries ignored); default 0.
    gravity : array_like, shape (3,)
        Gravity vector in the base frame (m/s^2); default ``(0, 0, -9.81)``.
    name : str
        A label.
    joint_names : sequence of str, optional
        Names of the active joints (default ``q1``, ``q2``, ... by the chain
        index + 1).

    Raises
    ------
    ValueError
        An empty chain, an unknown convention, active indices out of range
        or repeated, or a malformed gravity vector.

    Examples
    --------
    >>> from plant.robot.robot_model import Link, RobotModel
    >>> arm = RobotModel([Link(a=1.0, mass=1.0, com=(-0.5, 0, 0)),
    ...                   Link(a=1.0, mass=1.0, com=(-0.5, 0, 0))],
    ...                  gravity=(0, -9.81, 0), name="planar 2-link")
    >>> arm.base_parameters().names
    ('ZZ1R', 'MX1R', 'MY1', 'ZZ2R', 'MX2R', 'MY2', 'Ia2')
    """

    def __init__(self, links, *, convention="standard", active=None, locked=None,
                 gravity=(0.0, 0.0, -9.81), name="robot", joint_names=None):
        links = tuple(links)
        if not links or not all(isinstance(l, Link) for l in links):
            raise ValueError("links must be a non-empty sequence of plant.robot.robot_model.Link")
        if convention not in CONVENTIONS:
            raise ValueError(f"convention must be one of {CONVENTIONS}, got {convention!r}")
        n_all = len(links)
        active = tuple(range(n_all)) if active is None else tuple(int(i) for i in active)
        if (not active or len(set(active)) != len(active) or min(active) < 0
                or max(active) >= n_all or list(active) != sorted(active)):
            raise ValueError(f"active must be increasing distinct joint indices in 0..{n_all - 1}, "
                             f"got {active!r}")
        angles = np.zeros(n_all)
        if isinstance(locked, dict):
            for i, v in locked.items():
                if not 0 <= int(i) < n_all:
                    raise ValueError(f"locked joint index {i!r} out of range 0..{n_all - 1}")
                angles[int(i)] = float(v)
        elif locked is not None:
            a = np.asarray(locked, dtype=float).reshape(-1)
            if a.shape != (n_all,):
                raise ValueError(f"locked needs one angle per joint ({n_all}), got {a.size}")
            angles[:] = a
        if not np.all(np.isfinite(angles)):
            raise ValueError("locked angles must be finite")
        g = np.asarray(gravity, dtype=float).reshape(-1)
        if g.shape != (3,) or not np.all(np.isfinite(g)):
            raise ValueError(f"gravity must be 3 finite numbers, got {gravity!r}")
        self.links = links
        self.convention = convention
        self.active = active
        self.locked_angles = angles
        self.gravity = g
        self.name = str(name)
        self.joint_names = (tuple(f"q{i + 1}" for i in active) if joint_names is None
                            else tuple(str(s) for s in joint_names))
        if len(self.joint_names) != len(active):
            raise ValueError("joint_names needs one name per active joint")

    # ------------------------------------------------------------------ sizes
    @property
    def n_joints(self) -> int:
        """Number of active joints n."""
        return len(self.active)

    @property
    def gear_ratios(self) -> np.ndarray:
        """Gear ratios k of the active joints, shape (n,)."""
        return np.array([self.links[i].gear_ratio for i in self.active])

    @cached_property
    def _moving(self) -> tuple:
        """Links that move (distal to the first active joint)."""
        return tuple(range(self.active[0], len(self.links)))

    @property
    def standard_parameter_names(self) -> tuple:
        """Names of the standard parameters: 10 per moving link (1-based), then ``Ia<j>``."""
        names = [f"{s}{i + 1}" for i in self._moving for s in STANDARD_NAMES]
        return tuple(names + [f"Ia{i + 1}" for i in self.active])

    def standard_parameters(self) -> np.ndarray:
        """The model's standard parameters from its links, shape (n_std,)."""
        p = [self.links[i].standard_parameters() for i in self._moving]
        ia = [self.links[i].motor_inertia * self.links[i].gear_ratio ** 2 for i in self.active]
        return np.concatenate(p + [np.array(ia)])

    def motor_inertia_columns(self) -> np.ndarray:
        """How each reflected motor inertia ``Ia_j = Jm_j k_j^2`` enters the parameters, shape (n_std, n).

        Column j is the derivative of the model's parameter vector
        (:meth:`standard_parameters`) with respect to ``Ia_j`` of active
        joint j: here the unit vector of ``Ia<j>``.  A two-mass (flexible)
        joint's link model is the rigid one without these columns
        (:attr:`plant.simulation.arm.ArmPlant.motor_inertia_columns`).

        Returns
        -------
        ndarray, shape (n_std, n)
        """
        names = list(self.standard_parameter_names)
        cols = np.zeros((len(names), self.n_joints))
        for j, i in enumerate(self.active):
            cols[names.index(f"Ia{i + 1}"), j] = 1.0
        return cols

    def payload_parameters(self, mass_kg, com_m=(0.0, 0.0, 0.0), inertia_kgm2=None) -> np.ndarray:
        """Standard parameters (n_std,) of a rigid payload fixed to the chain's last link.

        The payload adds its own ``XX .. ZZ, MX, MY, MZ, M`` (about the last
        link's frame origin: inertia about its centre of mass plus the
        parallel-axis term, :meth:`Link.standard_parameters`) to the last
        link's, which moves with the last active joint (a locked wrist
        included); every other entry is zero.  The robot with the payload has
        standard parameters ``p + payload_parameters(...)``: the dynamics are
        linear in them (Khalil & Dombre, *Modeling, Identification and
        Control of Robots*, sec. 9.3; the payload on the last link is the
        paper's on-line identification, sec. 5, for any arm).

        Parameters
        ----------
        mass_kg : float
            Payload mass (kg), >= 0.
        com_m : array_like, shape (3,)
            Its centre of mass in the last link's frame (m) -- Robotics
            Toolbox's ``payload(m, p)`` frame for a DH table.
        inertia_kgm2 : array_like, shape (3, 3) or (6,), optional
            Its inertia about its centre of mass, in the last link's frame
            (default a point mass).

        Returns
        -------
        ndarray, shape (n_std,)
            In the order of :attr:`standard_parameter_names`.

        Raises
        ------
        ValueError
            As :class:`Link` (a negative or non-finite mass, a malformed
            centre of mass or inertia).
        """
        if inertia_kgm2 is None:  # a point mass (the on-line search's, once per candidate)
            m = float(mass_kg)
            c = np.asarray(com_m, dtype=float).reshape(-1)
            if not math.isfinite(m) or m < 0:
                raise ValueError(f"the payload's mass must be finite and >= 0, got {mass_kg!r}")
            if c.shape != (3,) or not np.all(np.isfinite(c)):
                raise ValueError(f"the payload's centre of mass must be 3 finite numbers, "
                                 f"got {com_m!r}")
            body = _body_parameters(m, c, np.zeros((3, 3)))
        else:
            body = Link(mass=mass_kg, com=com_m, inertia=inertia_kgm2).standard_parameters()
        dp = np.zeros(len(self.standard_parameter_names))
        k = self._moving.index(len(self.links) - 1)
        dp[10 * k:10 * k + 10] = body
        return dp

    def payload_delta(self, mass_kg, com_m=(0.0, 0.0, 0.0), inertia_kgm2=None, *,
                      base=None) -> np.ndarray:
        """Change of the base parameters when the arm carries a payload, shape (r,).

        ``base(p + dp) - base(p) = K dp`` with ``dp`` from
        :meth:`payload_parameters`: the base parameters are linear in the
        standard ones (Gautier 1990), so a payload shifts them by a vector
        that does not depend on the robot's own inertias.

        Parameters
        ----------
        mass_kg, com_m, inertia_kgm2
            See :meth:`payload_parameters`.
        base : BaseParameterSet, optional
            The parameters to change (default :meth:`base_parameters`; a named
            basis from :meth:`express`, e.g. the paper's f1..f9).

        Returns
        -------
        ndarray, shape (len(base.names),)

        Raises
        ------
        ValueError
            As :meth:`payload_parameters`.
        """
        base = self.base_parameters() if base is None else base
        return base.K @ self.payload_parameters(mass_kg, com_m, inertia_kgm2)

    # ------------------------------------------------------------- derivation
    @cached_property
    def _symbols(self):
        n = self.n_joints
        q, qd, qdd = ca.SX.sym("q", n), ca.SX.sym("qd", n), ca.SX.sym("qdd", n)
        p = ca.SX.sym("p", len(self.standard_parameter_names))
        return q, qd, qdd, p

    @cached_property
    def _trig_symbols(self):
        """SX symbols ``(s, c)``, shape (n,) each: sin and cos of the active joints' q."""
        n = self.n_joints
        return ca.SX.sym("s", n), ca.SX.sym("c", n)

    @cached_property
    def _tau_sc(self):
        """tau(s, c, qd, qdd, p) as a casadi SX, with ``s = sin q``, ``c = cos q`` of the
        active joints (Newton--Euler in the world frame; module docstring).

        The joint angles enter only through their sine and cosine, so the
        kinematics are written in them and time derivatives take the chain
        rule ``ds/dt = c qd``, ``dc/dt = -s qd``.  This form is the one the
        compiled plant evaluates (:mod:`plant.simulation.arm`: sine and cosine come from
        the core's anchors); :attr:`_tau_sx` substitutes ``sin q, cos q``.
        """
        _, qd, qdd, p = self._symbols
        s, c = self._trig_symbols
        col = {j: k for k, j in enumerate(self.active)}
        R = ca.SX.eye(3)
        o = ca.SX.zeros(3)
        axes, points, frames = [], [], []
        for i, link in enumerate(self.links):
            # theta = offset + q, or offset - q for a flipped joint
            if i in col:  # sin and cos of theta by angle addition
                k, co, so = col[i], math.cos(link.offset), math.sin(link.offset)
                sq = -s[k] if link.flip else s[k]
                st, ct = sq * co + c[k] * so, c[k] * co - sq * so
            else:
                q_lock = self.locked_angles[i]
                theta = (-q_lock if link.flip else q_lock) + link.offset
                st, ct = math.sin(theta), math.cos(theta)
            A, axis, B = _pieces(link, self.convention)
            # the joint frame: its axis (the way q turns) and a point on it, in the base frame
            Rj = ca.mtimes(R, ca.DM(A[:3, :3]))
            oj = o + ca.mtimes(R, ca.DM(A[:3, 3]))
            z = ca.mtimes(Rj, ca.DM(axis))
            axes.append(-z if link.flip else z)
            points.append(oj)
            Rq = ca.mtimes(Rj, _axis_rotation(axis, st, ct))
            o = oj + ca.mtimes(Rq, ca.DM(B[:3, 3]))
            R = ca.mtimes(Rq, ca.DM(B[:3, :3]))
            frames.append((R, o))

        def velocity(x):  # d/dt of x(s, c): dx/ds c qd - dx/dc s qd
            return ca.jtimes(x, s, c * qd) - ca.jtimes(x, c, s * qd)

        def ddt(x):  # d/dt of x(s, c, qd)
            return velocity(x) + ca.jtimes(x, qd, qdd)

        g = ca.DM(self.gravity)
        wrench = {}
        for k, i in enumerate(self._moving):
            R, o = frames[i]
            pl = p[10 * k:10 * k + 10]
            I_o = ca.vertcat(ca.horzcat(pl[0], pl[1], pl[2]), ca.horzcat(pl[1], pl[3], pl[4]),
                             ca.horzcat(pl[2], pl[4], pl[5]))
            ms, m = pl[6:9], pl[9]
            Rd = ca.reshape(velocity(ca.vec(R)), 3, 3)
            w = _vee(ca.mtimes(Rd, R.T))
            alpha = ddt(w)
            a = ddt(velocity(o)) - g
            msw = ca.mtimes(R, ms)
            Iw = ca.mtimes(ca.mtimes(R, I_o), R.T)
            f = m * a + ca.cross(alpha, msw) + ca.cross(w, ca.cross(w, msw))
            nmom = ca.mtimes(Iw, alpha) + ca.cross(w, ca.mtimes(Iw, w)) + ca.cross(msw, a)
            wrench[i] = (f, nmom, o)
        n_link = 10 * len(self._moving)
        tau = []
        for k, j in enumerate(self.active):
            z, pj = axes[j], points[j]
            t = 0
            for i in self._moving:
                if i < j:
                    continue
                f, nmom, o = wrench[i]
                t = t + ca.dot(z, nmom + ca.cross(o - pj, f))
            tau.append(t + p[n_link + k] * qdd[k])
        return ca.vertcat(*tau)

    @cached_property
    def _tau_sx(self):
        """tau(q, qd, qdd, p) as a casadi SX (:attr:`_tau_sc` at ``s = sin q``, ``c = cos q``)."""
        q = self._symbols[0]
        s, c = self._trig_symbols
        return ca.substitute(self._tau_sc, ca.vertcat(s, c), ca.vertcat(ca.sin(q), ca.cos(q)))

    @cached_property
    def inverse_dynamics_function(self) -> ca.Function:
        """casadi ``tau = ID(q, qd, qdd, p)``: (n,), (n,), (n,), (n_std,) -> (n,) (N m)."""
        q, qd, qdd, p = self._symbols
        return ca.Function("inverse_dynamics", [q, qd, qdd, p], [self._tau_sx],
                           ["q", "qd", "qdd", "p"], ["tau"])

    @cached_property
    def regressor_function(self) -> ca.Function:
        """casadi ``Y(q, qd, qdd)`` (n, n_std): ``tau = Y p`` (tau is linear in p)."""
        q, qd, qdd, p = self._symbols
        Y = ca.jacobian(self._tau_sx, p)
        return ca.Function("regressor", [q, qd, qdd], [ca.substitute(Y, p, ca.SX.zeros(p.shape))],
                           ["q", "qd", "qdd"], ["Y"])

    @cached_property
    def _terms(self):
        q, qd, qdd, p = self._symbols
        tau = self._tau_sx
        D = ca.jacobian(tau, qdd)
        zero = ca.SX.zeros(self.n_joints)
        gvec = ca.substitute(tau, ca.vertcat(qd, qdd), ca.vertcat(zero, zero))
        c = ca.substitute(tau, qdd, zero) - gvec
        return (ca.Function("inertia", [q, p], [D], ["q", "p"], ["D"]),
                ca.Function("coriolis", [q, qd, p], [c], ["q", "qd", "p"], ["c"]),
                ca.Function("gravity", [q, p], [gvec], ["q", "p"], ["g"]))

    def _p(self, p):
        p = self.standard_parameters() if p is None else np.asarray(p, dtype=float).reshape(-1)
        if p.shape != (len(self.standard_parameter_names),):
            raise ValueError(f"p must have {len(self.standard_parameter_names)} standard "
                             f"parameters, got {p.size}")
        return p

    def _q(self, q, name="q"):
        q = np.asarray(q, dtype=float).reshape(-1)
        if q.shape != (self.n_joints,):
            raise ValueError(f"{name} must have {self.n_joints} values, got {q.size}")
        return q

    def inverse_dynamics(self, q, qd, qdd, p=None) -> np.ndarray:
        """Joint torques ``D qdd + c + g`` plus ``Ia qdd`` (N m), shape (n,).

        Parameters
        ----------
        q, qd, qdd : array_like, shape (n,)
            Active joints' angles (rad), rates (rad/s), accelerations (rad/s^2).
        p : array_like, shape (n_std,), optional
            Standard parameters (default :meth:`standard_parameters`).

        Raises
        ------
        ValueError
            On wrong sizes.
        """
        out = self.inverse_dynamics_function(self._q(q), self._q(qd, "qd"), self._q(qdd, "qdd"),
                                             self._p(p))
        return np.asarray(out).reshape(-1)

    def regressor(self, q, qd, qdd) -> np.ndarray:
        """Standard regressor ``Y`` with ``tau = Y p``, shape (n, n_std).

        Parameters
        ----------
        q, qd, qdd : array_like, shape (n,)
            Joint angles (rad), rates (rad/s) and accelerations (rad/s^2).

        Raises
        ------
        ValueError
            On wrong sizes.
        """
        return np.asarray(self.regressor_function(self._q(q), self._q(qd, "qd"),
                                                  self._q(qdd, "qdd")))

    def inertia_matrix(self, q, p=None) -> np.ndarray:
        """Inertia matrix ``D(q)`` including ``Ia`` on the diagonal (kg m^2), shape (n, n).

        Parameters
        ----------
        q : array_like, shape (n,)
            Joint angles (rad).
        p : array_like, shape (n_std,), optional
            Standard parameters (default :meth:`standard_parameters`).
        """
        return np.asarray(self._terms[0](self._q(q), self._p(p)))

    def coriolis_centrifugal(self, q, qd, p=None) -> np.ndarray:
        """Coriolis/centrifugal torques ``c(q, qd)`` (N m), shape (n,).

        Parameters
        ----------
        q, qd : array_like, shape (n,)
            Joint angles (rad) and rates (rad/s).
        p : array_like, shape (n_std,), optional
            Standard parameters (default :meth:`standard_parameters`).
        """
        return np.asarray(self._terms[1](self._q(q), self._q(qd, "qd"), self._p(p))).reshape(-1)

    def gravity_vector(self, q, p=None) -> np.ndarray:
        """Gravity torques ``g(q)`` (N m), shape (n,).

        Parameters
        ----------
        q : array_like, shape (n,)
            Joint angles (rad).
        p : array_like, shape (n_std,), optional
            Standard parameters (default :meth:`standard_parameters`).
        """
        return np.asarray(self._terms[2](self._q(q), self._p(p))).reshape(-1)

    # -------------------------------------------------------- base parameters
    def random_states(self, n_states, rng=None):
        """Random ``(q, qd, qdd)``, each shape (n_states, n): angles in [-pi, pi], rates and
        accelerations standard normal (rad/s, rad/s^2).

        Parameters
        ----------
        n_states : int
        rng : numpy.random.Generator or int, optional
        """
        rng = np.random.default_rng(rng)
        n = self.n_joints
        return (rng.uniform(-math.pi, math.pi, (n_states, n)), rng.standard_normal((n_states, n)),
                rng.standard_normal((n_states, n)))

    def stacked_regressor(self, q, qd, qdd) -> np.ndarray:
        """Regressors at many states, stacked state by state: shape (m n, n_std).

        Parameters
        ----------
        q, qd, qdd : array_like, shape (m, n)
            m states (time-first), rad, rad/s, rad/s^2.
        """
        f = self.regressor_function.map(np.shape(q)[0])
        Y = np.asarray(f(np.asarray(q, float).T, np.asarray(qd, float).T, np.asarray(qdd, float).T))
        n, m = self.n_joints, np.shape(q)[0]
        # map() concatenates the (n, n_std) blocks side by side: [Y(s0) | Y(s1) | ...]
        return Y.reshape(n, m, -1).transpose(1, 0, 2).reshape(m * n, -1)

    def base_parameters(self, *, n_states=None, rng=0, rtol=1e-8) -> BaseParameterSet:
        """The base parameters by the numerical QR method (Gautier 1990).

        The regressor is stacked at ``n_states`` random states
        (:meth:`random_states`) into ``W``; ``W P = Q R`` with column
        pivoting; the rank r is the number of ``|R_kk| > rtol |R_00|``;
        the first r pivoted columns are independent and
        ``beta = p_1 + R_11^-1 R_12 p_2``.

        Parameters
        ----------
        n_states : int, optional
            Random states (default ``max(50, 5 n_std / n)``).
        rng : numpy.random.Generator or int
            Seed of the states (the result does not depend on it beyond
            rounding when the states are enough).
        rtol : float
            Relative rank tolerance.

        Returns
        -------
        BaseParameterSet
        """
        from scipy.linalg import qr, solve_triangular

        names = self.standard_parameter_names
        n_std = len(names)
        m = n_states or max(50, 5 * n_std // self.n_joints)
        W = self.stacked_regressor(*self.random_states(m, rng))
        # columns scaled to unit norm (parameters of very different sizes); a column
        # at rounding level (cos(pi/2) = 6e-17 in a DH rotation) is a parameter
        # that does not act at all: zeroed, never promoted by the scaling
        scale = np.linalg.norm(W, axis=0)
        dead = scale <= rtol * scale.max()
        scale[dead] = 1.0
        Ws = W / scale
        Ws[:, dead] = 0.0
        # Gautier's order: a column that the columns before it already span is
        # dependent (QR without pivoting, in the order of standard_parameter_names:
        # links from the base, XX..ZZ, MX..MZ, M, then the motor inertias), so the
        # dependent parameters regroup onto the proximal links' (Khalil's ZZ1R ...)
        _, R0 = qr(Ws, mode="economic")
        d = np.abs(np.diag(R0))
        top = d.max() if d.size else 0.0
        ind = np.flatnonzero(d > rtol * top) if top > 0 else np.zeros(0, dtype=int)
        dep = np.setdiff1d(np.arange(n_std), ind)
        r = ind.size
        # back in unscaled parameters: W[:, dep] = W[:, ind] B  ->  beta = p_ind + B p_dep
        R = qr(Ws[:, np.concatenate([ind, dep])], mode="r")[0]
        B = solve_triangular(R[:r, :r], R[:r, r:]) * (scale[dep][None, :] / scale[ind][:, None])
        K = np.zeros((r, n_std))
        K[np.arange(r), ind] = 1.0
        K[:, dep] = B
        K[np.abs(K) < 1e-10 * max(1.0, np.abs(K).max())] = 0.0
        bnames, exprs = [], []
        for k in range(r):
            others = [j for j in np.flatnonzero(K[k]) if j != ind[k]]
            bnames.append(names[ind[k]] + ("R" if others else ""))
            terms = [names[ind[k]]] + [f"{'+' if K[k, j] > 0 else '-'} {abs(K[k, j]):.6g} {names[j]}"
                                       for j in others]
            exprs.append(" ".join(terms))
        return BaseParameterSet(names=tuple(bnames), independent=ind, K=K,
                                expressions=tuple(exprs), rank=r, singular_values=d)

    def express(self, basis, *, n_states=None, rng=0, rtol=1e-8) -> BaseParameterSet:
        """The model's torques in a named parameter basis (e.g. the paper's f1..f9).

        Finds K with ``Y(q, qd, qdd) = B(q, qd, qdd) K`` at random states
        (least squares on the stacked regressors), i.e. the basis'
        parameters ``theta = K p`` in the standard parameters, and checks
        that the fit is exact: every torque of the model is ``B theta``.

        Parameters
        ----------
        basis : ParameterBasis
            Names and regressor ``B`` (n, k) of the basis, in this model's
            joint convention.
        n_states : int, optional
            Random states (default as :meth:`base_parameters`).
        rng : numpy.random.Generator or int
        rtol : float
            Relative tolerance of the exactness check and of K's rank.

        Returns
        -------
        BaseParameterSet
            ``independent`` None; ``relations`` lists the linear relations
            among the basis' parameters when it is not minimal.

        Raises
        ------
        ValueError
            When the basis does not describe the model (residual above
            ``rtol`` of the regressor's size) or has a wrong shape.
        """
        names = self.standard_parameter_names
        m = n_states or max(50, 5 * len(names) // self.n_joints)
        q, qd, qdd = self.random_states(m, rng)
        W = self.stacked_regressor(q, qd, qdd)
        Bs = np.vstack([np.atleast_2d(basis.regressor(q[i], qd[i], qdd[i])) for i in range(m)])
        if Bs.shape != (W.shape[0], len(basis.names)):
            raise ValueError(f"the basis regressor must be ({self.n_joints}, {len(basis.names)}) "
                             f"per state, got {Bs.shape[0] // m} x {Bs.shape[1]}")
        K = np.linalg.lstsq(Bs, W, rcond=None)[0]
        resid = np.abs(Bs @ K - W).max()
        if resid > rtol * max(1.0, np.abs(W).max()):
            raise ValueError(f"the basis {basis.name!r} does not describe {self.name}: torque "
                             f"residual {resid:.3g} (its regressor misses a term of the model)")
        K[np.abs(K) < 1e-10 * max(1.0, np.abs(K).max())] = 0.0
        u, sv, _ = np.linalg.svd(K)
        r = int(np.sum(sv > rtol * sv[0])) if sv.size and sv[0] > 0 else 0
        relations = []
        for v in _rref(u[:, r:].T):  # solved for the first parameters they tie
            k = int(np.flatnonzero(np.abs(v) > 1e-9)[0])
            terms = [basis.names[k]] + [f"{'+' if v[j] > 0 else '-'} {abs(v[j]):.6g} {basis.names[j]}"
                                        for j in np.flatnonzero(np.abs(v) > 1e-9) if j != k]
            relations.append(" ".join(terms) + " = 0")
        exprs = tuple(" ".join(f"{'+' if K[i, j] > 0 else '-'} {abs(K[i, j]):.6g} {names[j]}"
                               for j in np.flatnonzero(K[i])).lstrip("+ ") or "0"
                      for i in range(K.shape[0]))
        return BaseParameterSet(names=tuple(basis.names), independent=None, K=K,
                                expressions=exprs, rank=r, singular_values=sv,
                                relations=tuple(relations))

    def parameter_ranges(self, ranges=None, basis=None) -> np.ndarray:
        """Search ranges of the base (or a basis') parameters from physical ranges.

        The paper's section 3.6: ranges of link masses, centres of mass,
        inertias and motor inertias give the ranges of the base parameters
        by interval arithmetic on their expressions (its ``f9min = m2max
        x2min + m3min a3min``, in general).  The standard parameters'
        intervals come from ``M = m``, ``MX = m cx``, ``XX = Ixx + m (cy^2 +
        cz^2)``, ``XY = Ixy - m cx cy``, ..., ``Ia = Jm k^2`` (each product
        and square by interval rules), then ``beta = K p`` term by term.
        Intervals ignore that the same mass appears in several terms, so the
        ranges are safe (they contain every consistent value), not tight.

        Parameters
        ----------
        ranges : dict, optional
            ``{chain index (0-based): {key: range}}`` with keys ``mass``
            ``(lo, hi)`` (kg), ``com`` ``((lo, hi),) * 3`` (m, link frame),
            ``inertia`` ``((lo, hi),) * 6`` about the centre of mass in
            Robotics Toolbox's order ``Ixx Iyy Izz Ixy Iyz Ixz`` (kg m^2),
            ``motor_inertia`` ``(lo, hi)`` (kg m^2); anything not given is
            the link's own value.
        basis : ParameterBasis, optional
            Ranges of that basis' parameters (e.g.
            :data:`PUMA560_LINKS23_BASIS`) instead of the QR's base parameters.

        Returns
        -------
        ndarray, shape (r, 2)
            ``[lo, hi]`` per parameter, in the order of
            :meth:`base_parameters` ``.names`` (or the basis').

        Raises
        ------
        ValueError
            On an unknown link index or key, or a range with lo > hi.
        """
        K = (self.base_parameters() if basis is None else self.express(basis)).K
        return np.column_stack(_interval_map(K, *self._standard_ranges(ranges)))

    def _standard_ranges(self, ranges):
        """``(lo, hi)``, each (n_std,): the standard parameters' intervals (:meth:`parameter_ranges`)."""
        ranges = dict(ranges or {})
        unknown = set(ranges) - set(self._moving)
        if unknown:
            raise ValueError(f"ranges for links {sorted(unknown)}: only moving links "
                             f"{list(self._moving)} have parameters")
        lo, hi = [], []
        for i in self._moving:
            link, r = self.links[i], dict(ranges.get(i, {}))
            bad = set(r) - {"mass", "com", "inertia", "motor_inertia"}
            if bad:
                raise ValueError(f"unknown range keys {sorted(bad)} for link {i}")
            Ic = np.asarray(link.inertia)
            m = _interval(r.get("mass", link.mass), "mass")
            c = [_interval(v, "com") for v in r.get("com", link.com)]
            nominal6 = (Ic[0, 0], Ic[1, 1], Ic[2, 2], Ic[0, 1], Ic[1, 2], Ic[0, 2])
            I6 = [_interval(v, "inertia") for v in r.get("inertia", nominal6)]
            if len(c) != 3 or len(I6) != 6:
                raise ValueError(f"link {i}: com needs 3 ranges and inertia 6")
            sq = [_isq(x) for x in c]
            xx = _iadd(I6[0], _imul(m, _iadd(sq[1], sq[2])))
            yy = _iadd(I6[1], _imul(m, _iadd(sq[0], sq[2])))
            zz = _iadd(I6[2], _imul(m, _iadd(sq[0], sq[1])))
            xy = _iadd(I6[3], _ineg(_imul(m, _imul(c[0], c[1]))))
            yz = _iadd(I6[4], _ineg(_imul(m, _imul(c[1], c[2]))))
            xz = _iadd(I6[5], _ineg(_imul(m, _imul(c[0], c[2]))))
            for a in (xx, xy, xz, yy, yz, zz, _imul(m, c[0]), _imul(m, c[1]), _imul(m, c[2]), m):
                lo.append(a[0])
                hi.append(a[1])
        for i in self.active:
            link = self.links[i]
            jm = _interval(dict(ranges.get(i, {})).get("motor_inertia", link.motor_inertia),
                           "motor_inertia")
            lo.append(jm[0] * link.gear_ratio ** 2)
            hi.append(jm[1] * link.gear_ratio ** 2)
        return np.array(lo), np.array(hi)

    # --------------------------------------------------------------- builders
    @classmethod
    def from_dh(cls, table, *, convention="standard", **options):
        """A model from a DH table: one row (dict or sequence) per joint.

        Parameters
        ----------
        table : sequence
            Rows as dicts of :class:`Link` fields, or sequences
            ``(a, alpha, d, offset)``.
        convention : {"standard", "modified"}
        **options
            Keyword arguments of :class:`RobotModel` (``active``, ``locked``,
            ``gravity``, ``name``, ``joint_names``).

        Raises
        ------
        ValueError
            On a malformed row or as :class:`RobotModel`.
        """
        links = []
        for k, row in enumerate(table):
            try:
                if not isinstance(row, dict) and len(row) != 4:
                    raise ValueError(f"a tuple row is (a, alpha, d, offset), got {len(row)} values")
                links.append(Link(**row) if isinstance(row, dict) else Link(*row))
            except (TypeError, ValueError) as exc:
                raise ValueError(f"DH row {k}: {exc}") from None
        return cls(links, convention=convention, **options)

    @classmethod
    def from_urdf(cls, path, *, active=None, locked=None, gear_ratios=None, motor_inertias=None,
                  gravity=(0.0, 0.0, -9.81), name=None):
        """A model from a URDF file (a serial chain of revolute joints).

        The file is read by Robotics Toolbox for Python's URDF reader (the
        ``urdf`` extra: ``pip install puma-ga-ctc[urdf]``); each revolute
        joint becomes a :class:`Link` (``origin``, ``axis``, the child link's
        inertial), fixed joints fold into their neighbours: before the
        first revolute joint into the next joint's origin, after it into the
        moving link (their mass, centre of mass and inertia lumped).

        Parameters
        ----------
        path : str or path-like
            The URDF file.
        active : sequence of str or int, optional
            Joints that move, by name or 0-based index among the revolute
            joints (default all).
        locked : dict, optional
            ``{joint name or index: angle (rad)}`` for the others (default 0).
        gear_ratios, motor_inertias : dict, optional
            ``{joint name: k}`` and ``{joint name: Jm (kg m^2)}`` (URDF has
            neither; default 1 and 0).
        gravity : array_like, shape (3,)
            Gravity in the URDF's base frame (m/s^2).
        name : str, optional
            Default: the URDF's robot name.

        Raises
        ------
        ValueError
            Robotics Toolbox missing, an unreadable file, a branched tree, a
            prismatic or continuous-without-axis joint, unknown joint names.
        """
        try:
            from roboticstoolbox.models.URDF.URDFRobot import URDF_file
        except ImportError:
            raise ValueError("RobotModel.from_urdf needs Robotics Toolbox for Python: "
                             "pip install 'puma-ga-ctc[urdf]'") from None
        import os
        import warnings

        if not os.path.isfile(path):
            raise ValueError(f"no URDF file at {os.fspath(path)!r}")
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                elinks, robot_name, _ = URDF_file(os.path.abspath(os.fspath(path)))
        except Exception as exc:  # noqa: BLE001 -- any parser failure is one line
            raise ValueError(f"cannot read the URDF {os.fspath(path)!r}: "
                             f"{type(exc).__name__}: {exc}") from None
        links, pending = [], np.eye(4)
        prev = None
        for el in elinks:
            if prev is not None and el.parent is not prev:
                raise ValueError(f"the URDF is not a serial chain: link {el.name!r} hangs on "
                                 f"{getattr(el.parent, 'name', None)!r}, not on {prev.name!r}")
            prev = el
            A, axis, after = pending.copy(), None, np.eye(4)
            for et in el.ets:
                if et.isjoint:
                    kind = getattr(et, "kind", None) or et.axis
                    if kind not in ("Rx", "Ry", "Rz"):
                        raise ValueError(f"joint of link {el.name!r} is {kind}: only revolute "
                                         "joints are supported")
                    axis = np.eye(3)["xyz".index(kind[1])] * (-1.0 if et.isflip else 1.0)
                elif axis is None:
                    A = A @ np.asarray(et.A(), dtype=float)
                else:
                    after = after @ np.asarray(et.A(), dtype=float)
            m = float(el.m or 0.0)
            com = np.asarray(el.r if el.r is not None else np.zeros(3), dtype=float).reshape(3)
            inertia = np.asarray(el.I if el.I is not None else np.zeros((3, 3)), dtype=float)
            if inertia.shape == (6,):
                inertia = Link(inertia=inertia).inertia
            if axis is None:  # a fixed joint
                if not links:
                    pending = A  # the base side: kinematics only, it never moves
                    continue
                pending = A  # the moving link's frame -> this body's (all fixed joints since)
                links[-1] = _lumped(links[-1], pending, m, com, inertia)
                continue
            if not np.allclose(after, np.eye(4)):
                raise ValueError(f"link {el.name!r}: a constant transform after its joint")
            jname = getattr(el, "_joint_name", None) or el.name
            k = (gear_ratios or {}).get(jname, 1.0)
            jm = (motor_inertias or {}).get(jname, 0.0)
            links.append(Link(origin=A, axis=axis, mass=m, com=com, inertia=inertia,
                              gear_ratio=k, motor_inertia=jm, name=jname))
            pending = np.eye(4)
        if not links:
            raise ValueError(f"the URDF {os.fspath(path)!r} has no revolute joint")
        names = [l.name for l in links]
        unknown = set(gear_ratios or {}) | set(motor_inertias or {})
        unknown -= set(names)
        if unknown:
            raise ValueError(f"unknown joint names {sorted(unknown)}; the URDF's are {names}")

        def index(j):
            if isinstance(j, str):
                if j not in names:
                    raise ValueError(f"unknown joint {j!r}; the URDF's are {names}")
                return names.index(j)
            return int(j)

        act = None if active is None else tuple(index(j) for j in active)
        lock = None if locked is None else {index(j): v for j, v in locked.items()}
        act_names = names if act is None else [names[i] for i in act]
        return cls(links, convention="urdf", active=act, locked=lock, gravity=gravity,
                   name=name or robot_name, joint_names=act_names)

    @classmethod
    def puma560(cls, active=(1, 2), **options):
        """The PUMA 560 of Corke's Robotics Toolbox (standard DH, :data:`PUMA560_DH`).

        Parameters
        ----------
        active : sequence of int
            Active joints, 0-based (default ``(1, 2)``: the paper's joints 2
            and 3, with joint 1 and the wrist locked at 0).
        **options
            Keyword arguments of :class:`RobotModel`.

        Notes
        -----
        The joint angles are Robotics Toolbox's.  The paper's joints 2 and 3
        turn the other way (``q_paper = -q``, ``tau_paper = -tau``, the same
        zero); :data:`PUMA560_LINKS23_BASIS` is the paper's f1..f9 in this
        model's convention, so ``RobotModel.puma560().express(
        PUMA560_LINKS23_BASIS)`` gives eq. 3 in the standard parameters.
        """
        options.setdefault("name", "PUMA 560")
        if tuple(active) == (1, 2):
            options.setdefault("joint_names", ("q2", "q3"))
        return cls([Link(**row) for row in PUMA560_DH], active=active, **options)

    @staticmethod
    def puma560_links23(*, gear_ratios=None, locked=None, gravity_m_s2=9.81,
                        name="PUMA 560 links 2-3", joint_names=("q2", "q3")):
        """PUMA 560 links 2--3 in the paper's joint convention, its parameters the paper's f1..f9.

        The paper's model (:mod:`plant.robot.model`: eq. 2, corrected, in
        the base parameters f1..f9 of eq. 3) as an instance of the robot
        model: a :class:`BasisModel` whose chain is Corke's PUMA 560
        (:data:`PUMA560_DH`) with joints 2 and 3 active, turned the paper's
        way (``Link.flip``: ``q = -q_RTB``, ``tau = -tau_RTB``, the same
        zero -- the DH zero configuration, upper arm horizontal), and whose
        parameter vector is ``f = (f1, ..., f9)``: ``regressor(q, qd, qdd) @
        f`` and ``inverse_dynamics(q, qd, qdd, f)`` are ``D(q) qdd + h(q, qd)
        + g(q)`` of :func:`plant.robot.model.inverse_dynamics`, q = (q2, q3)
        the development logs' angles.

        Parameters
        ----------
        gear_ratios : sequence of 2 float, optional
            k2, k3 (motor angle / joint angle, a log's ``gear_ratio``);
            default Corke's (107.815, -53.7063).  They set the reflected
            rotor inertias ``Jm k^2`` in f1 and f7 of
            :meth:`~BasisModel.standard_parameters`.
        locked : dict, optional
            ``{0-based chain index: angle (rad)}`` of joint 1 and the wrist
            (indices 0, 3, 4, 5; Robotics Toolbox's convention); default 0.
        gravity_m_s2 : float
            g (m/s^2, > 0), along the base's -z.
        name : str
            The model's name.
        joint_names : sequence of 2 str
            Default ``("q2", "q3")``: the development logs' columns
            ``q2_ref_rad``, ``e2_pulses``, ``i2_A``, ...

        Returns
        -------
        BasisModel
            ``standard_parameter_names`` f1..f9;
            :meth:`~RobotModel.base_parameters` f1..f9 (rank 9, K the
            identity); :attr:`~BasisModel.definition` eq. 3 in the chain's
            standard parameters (rank 7, two relations).

        Raises
        ------
        ValueError
            Gear ratios that are not two nonzero numbers, g not finite and
            > 0, or a malformed ``locked`` (as :class:`RobotModel`).

        Notes
        -----
        Nine parameters, two relations.  In the chain's standard parameters
        the geometry ties ``f3 = a3 f5`` and ``f4 = a3 f6`` (a3 = 0.4318 m):
        the numerical QR on the DH chain finds 7 base parameters
        (``model.chain.base_parameters()``), and ``model.definition.relations``
        lists the two ties.  The instance keeps the paper's nine as free
        parameters, as the paper's identification and the library's GA do:
        as functions of the state the nine regressor columns are independent
        (the QR on the instance's own regressor keeps all nine); a rigid
        arm's true f satisfies the relations anyway, and effects outside the
        rigid DH model (motor-side and flexible-joint dynamics, eq. 2 fitted
        to a real rig) may move the best fit off them.
        The paper's path imposes the two relations when asked
        (:class:`identification.parameters.ConsistentBaseParameters`, seven
        parameters searched).

        Examples
        --------
        >>> from plant.robot.robot_model import RobotModel
        >>> puma = RobotModel.puma560_links23()
        >>> puma.standard_parameter_names
        ('f1', 'f2', 'f3', 'f4', 'f5', 'f6', 'f7', 'f8', 'f9')
        >>> puma.definition.relations
        ('f3 - 0.4318 f5 = 0', 'f4 - 0.4318 f6 = 0')
        """
        g = float(gravity_m_s2)
        if not (math.isfinite(g) and g > 0):
            raise ValueError(f"gravity_m_s2 must be finite and > 0, got {gravity_m_s2!r}")
        rows = [dict(row) for row in PUMA560_DH]
        if gear_ratios is not None:
            k = np.asarray(gear_ratios, dtype=float).reshape(-1)
            if k.shape != (2,):
                raise ValueError(f"gear_ratios must be (k2, k3), got {gear_ratios!r}")
            rows[1]["gear_ratio"], rows[2]["gear_ratio"] = k
        for j in (1, 2):  # the paper's joints 2 and 3 turn the other way
            rows[j]["flip"] = True
        chain = RobotModel([Link(**row) for row in rows], active=(1, 2), locked=locked,
                           gravity=(0.0, 0.0, -g), name=f"{name} (DH chain)",
                           joint_names=joint_names)
        basis = ParameterBasis(name="PUMA 560 links 2-3, eq. 3", names=PUMA560_LINKS23_BASIS.names,
                               regressor=functools.partial(_eq2_regressor, g=g),
                               torque=functools.partial(_eq2_torque, g=g))
        return BasisModel(chain, basis, name=name)

    def __repr__(self) -> str:
        kind = "URDF" if self.convention == "urdf" else f"{self.convention} DH"
        return (f"RobotModel({self.name!r}, {len(self.links)} links, {kind}, "
                f"active joints {list(self.joint_names)})")


class BasisModel(RobotModel):
    """A robot model whose parameter vector is a named basis' parameters (e.g. the paper's f1..f9).

    The arm is ``chain``'s (links, active and locked joints, gravity, joint
    convention); the parameters are not its standard parameters p but a
    basis' ``theta`` with ``tau = B(q, qd, qdd) theta`` (``basis.torque``),
    related to them by ``theta = K p`` (:attr:`definition`).  Every
    :class:`RobotModel` method reads "standard parameters" as theta:
    :attr:`standard_parameter_names` are the basis' names,
    :meth:`~RobotModel.regressor` is B (n, k),
    :meth:`~RobotModel.inverse_dynamics` and the D, c, g methods take
    theta, :meth:`standard_parameters` is ``K p`` of the chain's links;
    :meth:`~RobotModel.base_parameters` is the QR on B -- for a basis whose
    columns are independent functions of the state (f1..f9) K is the
    identity and the names are the basis' own, so the closed loop
    (:func:`plant.simulation.arm.arm_plant`) and the identification search
    all k of them; payloads (:meth:`payload_parameters`) and search ranges
    (:meth:`~RobotModel.parameter_ranges`) go through K from the chain's.
    :meth:`RobotModel.puma560_links23` is the instance of the paper.

    Parameters
    ----------
    chain : RobotModel
        The arm (a plain :class:`RobotModel`).
    basis : ParameterBasis
        With its ``torque``, in the chain's joint convention; its
        ``regressor`` must describe every torque of the chain
        (:meth:`RobotModel.express`).
    name : str, optional
        Default the chain's.
    joint_names : sequence of str, optional
        Default the chain's.

    Attributes
    ----------
    chain : RobotModel
        The arm in its standard parameters (its own QR:
        ``chain.base_parameters()``).
    basis : ParameterBasis
        The parameter vector's names, regressor and torque.

    Raises
    ------
    ValueError
        If ``chain`` is not a plain RobotModel or ``basis`` has no ``torque``.
    """

    def __init__(self, chain, basis, *, name=None, joint_names=None):
        if not isinstance(chain, RobotModel) or isinstance(chain, BasisModel):
            raise ValueError("BasisModel needs a plant.RobotModel as its chain")
        if not isinstance(basis, ParameterBasis) or basis.torque is None:
            raise ValueError("BasisModel needs a ParameterBasis with its torque(s, c, qd, qdd, theta)")
        super().__init__(chain.links, convention=chain.convention, active=chain.active,
                         locked=chain.locked_angles, gravity=chain.gravity,
                         name=chain.name if name is None else name,
                         joint_names=chain.joint_names if joint_names is None else joint_names)
        self.chain = chain
        self.basis = basis

    @property
    def standard_parameter_names(self) -> tuple:
        """The basis' names: the parameter vector theta that :meth:`~RobotModel.regressor` multiplies."""
        return tuple(self.basis.names)

    @cached_property
    def definition(self) -> BaseParameterSet:
        """``chain.express(basis)``: theta = K p of the chain's standard parameters p.

        Its ``expressions`` write each theta in the chain's standard
        parameters (eq. 3 for the paper's f), ``rank`` is K's and
        ``relations`` the ties among the thetas that the chain's geometry
        imposes.  Computed on first use (about a second for the PUMA 560).
        """
        return self.chain.express(self.basis)

    @cached_property
    def _tau_sc(self):
        """tau(s, c, qd, qdd, theta): the basis' torque (:attr:`ParameterBasis.torque`)."""
        _, qd, qdd, p = self._symbols
        s, c = self._trig_symbols
        return ca.vertcat(self.basis.torque(s, c, qd, qdd, p))

    def standard_parameters(self) -> np.ndarray:
        """The basis' parameters of the chain's links, ``K p`` (:attr:`definition`), shape (k,)."""
        return self.definition(self.chain.standard_parameters())

    def payload_parameters(self, mass_kg, com_m=(0.0, 0.0, 0.0), inertia_kgm2=None) -> np.ndarray:
        """Shift of the basis' parameters by a rigid payload on the chain's last link, shape (k,).

        ``K dp`` with ``dp`` the chain's :meth:`RobotModel.payload_parameters`.

        Parameters
        ----------
        mass_kg : float
            Payload mass (kg), >= 0.
        com_m : array_like, shape (3,)
            Its centre of mass in the chain's last link frame (m).
        inertia_kgm2 : array_like, shape (3, 3) or (6,), optional
            Its inertia about its centre of mass (default a point mass).

        Returns
        -------
        ndarray, shape (k,)

        Raises
        ------
        ValueError
            As :meth:`RobotModel.payload_parameters`.
        """
        return self.definition.K @ self.chain.payload_parameters(mass_kg, com_m, inertia_kgm2)

    def motor_inertia_columns(self) -> np.ndarray:
        """How each reflected motor inertia ``Ia_j`` enters the basis' parameters, shape (k, n).

        ``K`` of :attr:`definition` times the chain's
        :meth:`RobotModel.motor_inertia_columns`: the columns of theta that
        hold ``Jm k^2`` (for the paper's f: ``Jm3 k3^2`` in f1, ``Jm2 k2^2``
        in f7).

        Returns
        -------
        ndarray, shape (k, n)
        """
        return self.definition.K @ self.chain.motor_inertia_columns()

    def _standard_ranges(self, ranges):
        return _interval_map(self.definition.K, *self.chain._standard_ranges(ranges))

    def __repr__(self) -> str:
        return (f"BasisModel({self.name!r}, parameters {', '.join(self.standard_parameter_names)} "
                f"({self.basis.name}), active joints {list(self.joint_names)})")


#: The PUMA 560 of P. Corke's Robotics Toolbox (``Puma560``; B. Armstrong,
#: O. Khatib and J. Burdick, "The explicit dynamic model and inertial
#: parameters of the PUMA 560 arm", ICRA 1986): standard DH, SI units.
PUMA560_DH = (
    dict(a=0.0, alpha=math.pi / 2, d=0.67183, mass=0.0, com=(0, 0, 0),
         inertia=(0, 0.35, 0, 0, 0, 0), gear_ratio=-62.6111, motor_inertia=200e-6),
    dict(a=0.4318, alpha=0.0, d=0.0, mass=17.4, com=(-0.3638, 0.006, 0.2275),
         inertia=(0.13, 0.524, 0.539, 0, 0, 0), gear_ratio=107.815, motor_inertia=200e-6),
    dict(a=0.0203, alpha=-math.pi / 2, d=0.15005, mass=4.8, com=(-0.0203, -0.0141, 0.070),
         inertia=(0.066, 0.086, 0.0125, 0, 0, 0), gear_ratio=-53.7063, motor_inertia=200e-6),
    dict(a=0.0, alpha=math.pi / 2, d=0.4318, mass=0.82, com=(0, 0.019, 0),
         inertia=(1.8e-3, 1.3e-3, 1.8e-3, 0, 0, 0), gear_ratio=76.0364, motor_inertia=33e-6),
    dict(a=0.0, alpha=-math.pi / 2, d=0.0, mass=0.34, com=(0, 0, 0),
         inertia=(0.3e-3, 0.4e-3, 0.3e-3, 0, 0, 0), gear_ratio=71.923, motor_inertia=33e-6),
    dict(a=0.0, alpha=0.0, d=0.0, mass=0.09, com=(0, 0, 0.032),
         inertia=(0.15e-3, 0.15e-3, 0.04e-3, 0, 0, 0), gear_ratio=76.686, motor_inertia=33e-6),
)


def _eq2_regressor(q, qd, qdd, g=9.81):
    """The paper's f1..f9 regressor in its own joint convention, (2, 9) (:func:`plant.robot.model.regressor`)."""
    from plant.robot.model import regressor

    return regressor(q, qd, qdd, g)


def _eq2_torque(s, c, qd, qdd, f, g=9.81):
    """The paper's eq. 2 (corrected) as casadi SX in s = sin q, c = cos q of (q2, q3).

    Built by :mod:`plant.robot.model`'s own kernels (``mass_terms``,
    ``coriolis_terms``, ``gravity_terms``, their Python functions called on
    SX), so the instance's expressions are the library's one copy of eq. 2.
    """
    from plant.robot.model import coriolis_terms, gravity_terms, mass_terms

    s23, c23 = s[0] * c[1] + c[0] * s[1], c[0] * c[1] - s[0] * s[1]
    d11, d12, d22 = mass_terms.py_func(f, c[1], s[1])
    h1, h2 = coriolis_terms.py_func(f, c[1], s[1], qd[0], qd[1])
    g1, g2 = gravity_terms.py_func(f, c[0], s[0], c23, s23, g)
    return ca.vertcat(d11 * qdd[0] + d12 * qdd[1] + h1 + g1, d12 * qdd[0] + d22 * qdd[1] + h2 + g2)


def _paper_regressor(q, qd, qdd, g=9.81):
    """The paper's f1..f9 regressor in Robotics Toolbox's joint convention (q_paper = -q)."""
    return -_eq2_regressor(-np.asarray(q, float), -np.asarray(qd, float), -np.asarray(qdd, float), g)


#: The paper's base parameters f1..f9 (eq. 3; :mod:`plant.robot.model`) as a named
#: basis of ``RobotModel.puma560()`` (joints 2 and 3 in Robotics Toolbox's
#: convention).  Not minimal: the geometry ties ``f3 = a3 f5`` and ``f4 = a3 f6``
#: (a3 = 0.4318 m), which the paper leaves free.
PUMA560_LINKS23_BASIS = ParameterBasis(
    name="PUMA 560 links 2-3, eq. 3",
    names=tuple(f"f{i}" for i in range(1, 10)),
    regressor=_paper_regressor,
)
