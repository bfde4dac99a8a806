"""Symbolic derivation of the PUMA 560 links 2-3 model by Lagrange's equations (casadi).

This module is the *reference* for the numeric model in :mod:`plant.robot.model`:
it derives the rigid-body dynamics

.. math::  D(q)\\,\\ddot q + h(q, \\dot q) + g(q) = \\tau

from the physical parameters of the two links and their drive motors with
casadi ``SX`` expressions, shows that they depend on those parameters only
through the nine base parameters f1..f9 of the paper's eq. 3, and builds the
base-parameter model of eq. 2 (with its two printing errors corrected, see
``docs/model.rst``) together with its regressor :math:`Y = \\partial\\tau/\\partial f`.
The tests compare :mod:`plant.robot.model` with these functions.

Kinematics (planar, everything in the plane of joints 2 and 3)
---------------------------------------------------------------
* The plane frame is the frame of link 2 at q2 = 0 (modified-DH/Craig zero
  configuration, upper arm horizontal along +x).  Joint angles are positive
  from +x towards +y.
* Link 2 rotates by q2; its COM is at ``R(q2) [x2, y2]``.
* The link-3 frame origin lies at distance a3 along link 2's x axis,
  ``a3 R(q2) e_x``; link 3 rotates by q2 + q3 and its COM is at
  ``a3 R(q2) e_x + R(q2 + q3) [x3, y3]``.
* **Gravity** acts along **+y** of the plane frame (:data:`GRAVITY_DIRECTION`):
  the plane's y axis points vertically *down* (for the PUMA the link-2 frame
  is the base frame turned by alpha = -90 deg about x, so y2 = -z0).  This is
  the only in-plane direction that reproduces the signs of the paper's g1, g2.
* Kinetic energy: links (translation of the COM + rotation about it, Izz
  about the COM) plus the motor rotors ``1/2 Jm2 (k2 qd2)^2 + 1/2 Jm3 (k3 qd3)^2``
  (the gyroscopic coupling of the rotors is neglected, as in the standard
  PUMA model).  Potential energy ``V = -sum_i m_i g GRAVITY_DIRECTION . p_i``.

All public functions return casadi :class:`casadi.Function` objects and are
cached (:func:`functools.lru_cache`): the derivation runs once per process.
Joint order is (joint 2, joint 3) everywhere, units are SI.
"""
from __future__ import annotations

from functools import lru_cache
from typing import NamedTuple

import casadi as ca

__all__ = [
    "PHYSICAL_PARAMETER_NAMES",
    "BASE_PARAMETER_NAMES",
    "GRAVITY_DIRECTION",
    "MODEL_VARIANTS",
    "PhysicalModel",
    "BaseModel",
    "derive_physical_model",
    "base_parameters_expr",
    "derive_base_model",
    "derive_coriolis_matrix",
]

#: Names (and order) of the physical parameter vector ``p`` (14,):
#: link 2 mass (kg), COM x, y in the link-2 frame (m), inertia about the COM
#: (kg m^2), motor-2 rotor inertia (kg m^2), gear ratio k2 (motor angle = k
#: joint angle); the same for link 3; link length a3 (m); gravity g (m/s^2).
PHYSICAL_PARAMETER_NAMES = (
    "m2", "x2", "y2", "Izz2", "Jm2", "k2",
    "m3", "x3", "y3", "Izz3", "Jm3", "k3",
    "a3", "g",
)

#: Names of the nine base parameters (paper eq. 3), in order.
BASE_PARAMETER_NAMES = ("f1", "f2", "f3", "f4", "f5", "f6", "f7", "f8", "f9")

#: Unit vector of the gravitational acceleration in the plane frame (x, y):
#: +y, i.e. the plane's y axis points down.
GRAVITY_DIRECTION = (0.0, 1.0)

#: Variants accepted by :func:`derive_base_model`: the corrected eq. 2 and the
#: equation as printed in the paper (both errors, or each one alone).
MODEL_VARIANTS = ("corrected", "printed", "printed_D11", "printed_h2")


class PhysicalModel(NamedTuple):
    """casadi Functions of the Lagrange model in the physical parameters.

    Every Function has the inputs ``(q, qd, qdd, p)``: q (2,) rad, qd (2,)
    rad/s, qdd (2,) rad/s^2, p (14,) ordered as
    :data:`PHYSICAL_PARAMETER_NAMES` (inputs a Function does not need are
    accepted and ignored).

    Attributes
    ----------
    D, h, g, tau : casadi.Function
        Inertia matrix (2, 2), Coriolis/centrifugal vector (2,), gravity
        vector (2,) and joint torque (2,).
    """

    D: ca.Function
    """Inertia matrix (2, 2), kg m^2 (Hessian of T w.r.t. qd)."""
    h: ca.Function
    """Coriolis/centrifugal vector (2,), N m (tau - D qdd - g)."""
    g: ca.Function
    """Gravity vector (2,), N m (gradient of V w.r.t. q)."""
    tau: ca.Function
    """Joint torques (2,), N m: d/dt(dL/dqd) - dL/dq."""


class BaseModel(NamedTuple):
    """casadi Functions of the base-parameter model (paper eq. 2).

    ``D, h, g, tau, Y`` have the inputs ``(f, q, qd, qdd, g)``: f (9,) the
    base parameters f1..f9, q, qd, qdd (2,) and the scalar gravitational
    acceleration g (m/s^2) (inputs a Function does not need are accepted and
    ignored).  ``forward`` has the inputs ``(f, q, qd, tau, g)``.

    Attributes
    ----------
    D, h, g, tau, Y, forward : casadi.Function
        Inertia matrix (2, 2), Coriolis/centrifugal vector (2,), gravity
        vector (2,), joint torque (2,), regressor (2, 9) and forward dynamics
        qdd (2,).
    """

    D: ca.Function
    """Inertia matrix (2, 2), kg m^2."""
    h: ca.Function
    """Coriolis/centrifugal vector (2,), N m."""
    g: ca.Function
    """Gravity vector (2,), N m."""
    tau: ca.Function
    """Joint torques D qdd + h + g (2,), N m."""
    Y: ca.Function
    """Regressor (2, 9) = jacobian(tau, f); it does not depend on f."""
    forward: ca.Function
    """Forward dynamics qdd = D^-1 (tau - h - g) (2,), rad/s^2."""


def _rot(theta):
    c, s = ca.cos(theta), ca.sin(theta)
    return ca.vertcat(ca.horzcat(c, -s), ca.horzcat(s, c))


@lru_cache(maxsize=None)
def derive_physical_model() -> PhysicalModel:
    """Derive D, h, g and tau from the physical parameters by Lagrange's equations.

    Builds the kinetic energy T (links + motor rotors) and the potential
    energy V of links 2 and 3 (see the module docstring for the kinematics
    and :data:`GRAVITY_DIRECTION`), L = T - V, and

    .. math::

       \\tau = \\frac{d}{dt}\\frac{\\partial L}{\\partial \\dot q}
               - \\frac{\\partial L}{\\partial q},
       \\qquad
       \\frac{d}{dt}\\frac{\\partial L}{\\partial \\dot q}
         = \\frac{\\partial^2 L}{\\partial \\dot q\\,\\partial q}\\dot q
         + \\frac{\\partial^2 L}{\\partial \\dot q^2}\\ddot q,

    then ``D = hessian(T, qd)``, ``g = gradient(V, q)`` and
    ``h = tau - D qdd - g`` (independent of qdd; evaluated at qdd = 0).

    Returns
    -------
    PhysicalModel
        casadi Functions ``D``, ``h``, ``g``, ``tau`` of ``(q, qd, qdd, p)``
        with q, qd, qdd of shape (2,) (rad, rad/s, rad/s^2) and p of shape
        (14,) ordered as :data:`PHYSICAL_PARAMETER_NAMES` (SI units).
        Outputs: D (2, 2) kg m^2; h, g, tau (2,) N m.

    Notes
    -----
    Source: Lagrange's equations for the planar two-link arm; the result
    depends on ``p`` only through the base parameters of the paper's eq. 3
    (:func:`base_parameters_expr`), which the tests check against
    :func:`derive_base_model`.
    """
    q = ca.SX.sym("q", 2)
    qd = ca.SX.sym("qd", 2)
    qdd = ca.SX.sym("qdd", 2)
    p = ca.SX.sym("p", len(PHYSICAL_PARAMETER_NAMES))
    m2, x2, y2, izz2, jm2, k2, m3, x3, y3, izz3, jm3, k3, a3, grav = ca.vertsplit(p)

    # COM positions in the plane frame
    p2 = _rot(q[0]) @ ca.vertcat(x2, y2)
    p3 = a3 * (_rot(q[0]) @ ca.vertcat(1, 0)) + _rot(q[0] + q[1]) @ ca.vertcat(x3, y3)
    v2 = ca.jtimes(p2, q, qd)  # jacobian(p2, q) @ qd
    v3 = ca.jtimes(p3, q, qd)
    w2 = qd[0]
    w3 = qd[0] + qd[1]

    T = (
        0.5 * m2 * ca.dot(v2, v2) + 0.5 * izz2 * w2**2
        + 0.5 * m3 * ca.dot(v3, v3) + 0.5 * izz3 * w3**2
        + 0.5 * jm2 * (k2 * qd[0]) ** 2 + 0.5 * jm3 * (k3 * qd[1]) ** 2
    )
    gdir = ca.vertcat(*GRAVITY_DIRECTION)
    V = -grav * (m2 * ca.dot(gdir, p2) + m3 * ca.dot(gdir, p3))
    L = T - V

    dL_dqd = ca.gradient(L, qd)
    ddt_dL_dqd = ca.jacobian(dL_dqd, q) @ qd + ca.jacobian(dL_dqd, qd) @ qdd
    tau = ca.simplify(ddt_dL_dqd - ca.gradient(L, q))

    D = ca.simplify(ca.hessian(T, qd)[0])
    g = ca.simplify(ca.gradient(V, q))
    # tau is affine in qdd with the coefficient d2L/dqd2 = hessian(T, qd) = D
    # (V does not depend on qd), so tau - D qdd - g does not depend on qdd;
    # the expression graph still holds qdd structurally (the two Hessians are
    # built separately), so evaluate it at qdd = 0 to make that explicit.
    # The tests check tau = D qdd + h + g at random qdd.
    h = ca.simplify(ca.substitute(tau - D @ qdd - g, qdd, ca.DM.zeros(2)))

    ins = [q, qd, qdd, p]
    names = ["q", "qd", "qdd", "p"]
    return PhysicalModel(
        D=ca.Function("D_phys", ins, [D], names, ["D"]),
        h=ca.Function("h_phys", ins, [h], names, ["h"]),
        g=ca.Function("g_phys", ins, [g], names, ["gq"]),
        tau=ca.Function("tau_phys", ins, [tau], names, ["tau"]),
    )


@lru_cache(maxsize=None)
def base_parameters_expr() -> ca.Function:
    """The base parameters f1..f9 (paper eq. 3) as a casadi Function of ``p``.

    Returns
    -------
    casadi.Function
        ``f = F(p)``: p (14,) physical parameters ordered as
        :data:`PHYSICAL_PARAMETER_NAMES` (g is ignored), f (9,) in kg m^2
        (f1, f2, f3, f4, f7) and kg m (f5, f6, f8, f9)::

            f1 = Jm3 k3^2 + Izz3 + m3 (x3^2 + y3^2)
            f2 = Izz3 + m3 (x3^2 + y3^2)
            f3 = m3 x3 a3          f4 = m3 y3 a3
            f5 = m3 x3             f6 = m3 y3
            f7 = Jm2 k2^2 + Izz2 + m2 (x2^2 + y2^2) + m3 a3^2 + Izz3 + m3 (x3^2 + y3^2)
            f8 = m2 y2             f9 = m2 x2 + m3 a3

    Notes
    -----
    Source: paper eq. 3.  Physically consistent f satisfy f3 = a3 f5,
    f4 = a3 f6 and f1 - f2 = Jm3 k3^2 > 0; the identification does not
    impose these.
    """
    p = ca.SX.sym("p", len(PHYSICAL_PARAMETER_NAMES))
    m2, x2, y2, izz2, jm2, k2, m3, x3, y3, izz3, jm3, k3, a3, _ = ca.vertsplit(p)
    link3 = izz3 + m3 * (x3**2 + y3**2)
    f = ca.vertcat(
        jm3 * k3**2 + link3,
        link3,
        m3 * x3 * a3,
        m3 * y3 * a3,
        m3 * x3,
        m3 * y3,
        jm2 * k2**2 + izz2 + m2 * (x2**2 + y2**2) + m3 * a3**2 + link3,
        m2 * y2,
        m2 * x2 + m3 * a3,
    )
    return ca.Function("base_parameters", [p], [f], ["p"], ["f"])


def _base_expressions(variant: str):
    """SX symbols and expressions of eq. 2 in f for one variant."""
    if variant not in MODEL_VARIANTS:
        raise ValueError(f"variant must be one of {MODEL_VARIANTS}, got {variant!r}")
    f = ca.SX.sym("f", 9)
    q = ca.SX.sym("q", 2)
    qd = ca.SX.sym("qd", 2)
    qdd = ca.SX.sym("qdd", 2)
    grav = ca.SX.sym("g")
    f1, f2, f3, f4, f5, f6, f7, f8, f9 = ca.vertsplit(f)
    q2, q3 = q[0], q[1]
    s3, c3 = ca.sin(q3), ca.cos(q3)

    d11_const = f1 if variant in ("printed", "printed_D11") else f7  # printed: f1
    d11 = d11_const + 2 * f3 * c3 - 2 * f4 * s3
    d12 = f2 + f3 * c3 - f4 * s3
    D = ca.vertcat(ca.horzcat(d11, d12), ca.horzcat(d12, f1))

    a = f3 * s3 + f4 * c3
    a_h2 = f3 * s3 + f4 * s3 if variant in ("printed", "printed_h2") else a  # printed: sin
    h = ca.vertcat(-a * (2 * qd[0] * qd[1] + qd[1] ** 2), a_h2 * qd[0] ** 2)

    g23 = -f5 * grav * ca.cos(q2 + q3) + f6 * grav * ca.sin(q2 + q3)
    g = ca.vertcat(g23 + f8 * grav * ca.sin(q2) - f9 * grav * ca.cos(q2), g23)

    tau = D @ qdd + h + g
    return f, q, qd, qdd, grav, D, h, g, tau


def derive_base_model(variant: str = "corrected") -> BaseModel:
    """The base-parameter model of the paper's eq. 2 and its regressor.

    Parameters
    ----------
    variant : {"corrected", "printed", "printed_D11", "printed_h2"}
        ``"corrected"`` (default) is the model used throughout the library::

            D11 = f7 + 2 f3 cos q3 - 2 f4 sin q3
            D12 = D21 = f2 + f3 cos q3 - f4 sin q3,   D22 = f1
            h1  = -(f3 sin q3 + f4 cos q3)(2 qd2 qd3 + qd3^2)
            h2  =  (f3 sin q3 + f4 cos q3) qd2^2
            g1  = -f5 g cos(q2+q3) + f6 g sin(q2+q3) + f8 g sin q2 - f9 g cos q2
            g2  = -f5 g cos(q2+q3) + f6 g sin(q2+q3)

        ``"printed"`` is eq. 2 as printed in the paper (f1 instead of f7 in
        D11 and sin q3 instead of cos q3 in the f4 term of h2);
        ``"printed_D11"`` / ``"printed_h2"`` contain one of the two errors
        only.  The printed variants exist to show that they disagree with
        :func:`derive_physical_model`.

    Returns
    -------
    BaseModel
        casadi Functions ``D`` (2, 2) kg m^2, ``h``, ``g``, ``tau`` (2,) N m
        and ``Y`` (2, 9) of the inputs ``(f, q, qd, qdd, g)`` -- f (9,),
        q, qd, qdd (2,) in rad, rad/s, rad/s^2, g scalar m/s^2 -- and
        ``forward`` (2,) rad/s^2 of ``(f, q, qd, tau, g)``.
        ``Y = jacobian(tau, f)`` does not depend on f, which proves
        tau = Y(q, qd, qdd) f.

    Raises
    ------
    ValueError
        If ``variant`` is unknown.

    Notes
    -----
    Source: paper eq. 2 (corrected, see ``docs/model.rst``) in the base
    parameters of eq. 3; equal to :func:`derive_physical_model` with
    ``f = base_parameters_expr()(p)``.
    """
    return _derive_base_model(variant)


@lru_cache(maxsize=None)
def _derive_base_model(variant: str) -> BaseModel:
    f, q, qd, qdd, grav, D, h, g, tau = _base_expressions(variant)
    Y = ca.jacobian(tau, f)
    tau_in = ca.SX.sym("tau", 2)
    qdd_fd = ca.solve(D, tau_in - h - g)

    ins = [f, q, qd, qdd, grav]
    names = ["f", "q", "qd", "qdd", "g"]
    tag = "" if variant == "corrected" else "_" + variant
    return BaseModel(
        D=ca.Function("D" + tag, ins, [D], names, ["D"]),
        h=ca.Function("h" + tag, ins, [h], names, ["h"]),
        g=ca.Function("g" + tag, ins, [g], names, ["gq"]),
        tau=ca.Function("tau" + tag, ins, [tau], names, ["tau"]),
        Y=ca.Function("Y" + tag, ins, [Y], names, ["Y"]),
        forward=ca.Function(
            "forward" + tag, [f, q, qd, tau_in, grav], [qdd_fd],
            ["f", "q", "qd", "tau", "g"], ["qdd"],
        ),
    )


def derive_coriolis_matrix(variant: str = "corrected") -> ca.Function:
    """Coriolis matrix C(q, qd) of the base model from the Christoffel symbols of D.

    .. math::

       C_{kj} = \\sum_i c_{ijk}\\,\\dot q_i,\\qquad
       c_{ijk} = \\tfrac12\\left(\\frac{\\partial D_{kj}}{\\partial q_i}
               + \\frac{\\partial D_{ki}}{\\partial q_j}
               - \\frac{\\partial D_{ij}}{\\partial q_k}\\right).

    For a Lagrangian system ``C qd = h`` and ``dD/dt - 2 C`` is
    skew-symmetric; the tests use both to check h against D.

    Parameters
    ----------
    variant : str
        As in :func:`derive_base_model` (D is taken from that variant).

    Returns
    -------
    casadi.Function
        ``C = F(f, q, qd)`` with f (9,), q (2,) rad, qd (2,) rad/s; C (2, 2)
        in kg m^2/s.  Also returns ``Ddot`` (2, 2), the time derivative of D
        along qd, as a second output.
    """
    return _derive_coriolis_matrix(variant)


@lru_cache(maxsize=None)
def _derive_coriolis_matrix(variant: str) -> ca.Function:
    f, q, qd, _qdd, _grav, D, _h, _g, _tau = _base_expressions(variant)
    n = 2
    dD = [ca.jacobian(D[:, :].reshape((n * n, 1)), q[i]).reshape((n, n)) for i in range(n)]
    C = ca.SX.zeros(n, n)
    for k in range(n):
        for j in range(n):
            acc = 0
            for i in range(n):
                acc += 0.5 * (dD[i][k, j] + dD[j][k, i] - dD[k][i, j]) * qd[i]
            C[k, j] = acc
    Ddot = sum(dD[i] * qd[i] for i in range(n))
    tag = "" if variant == "corrected" else "_" + variant
    return ca.Function(
        "C" + tag, [f, q, qd], [ca.simplify(C), ca.simplify(Ddot)], ["f", "q", "qd"], ["C", "Ddot"]
    )
