"""Numeric rigid-body model of PUMA 560 links 2 and 3 in the base parameters f1..f9.

This module holds the library's only numeric copy of the dynamics

.. math::  D(q)\\,\\ddot q + h(q, \\dot q) + g(q) = \\tau

(paper eq. 2, with its two printing errors corrected; see ``docs/model.rst``)::

    D11 = f7 + 2 f3 cos q3 - 2 f4 sin q3      D12 = D21 = f2 + f3 cos q3 - f4 sin q3
    D22 = f1
    h1  = -(f3 sin q3 + f4 cos q3)(2 qd2 qd3 + qd3^2)
    h2  =  (f3 sin q3 + f4 cos q3) qd2^2
    g1  = -f5 g cos(q2+q3) + f6 g sin(q2+q3) + f8 g sin q2 - f9 g cos q2
    g2  = -f5 g cos(q2+q3) + f6 g sin(q2+q3)

and of the joint-side drive friction.  The closed-loop simulator
(:mod:`plant.simulation.simulate`), the identification objective and the computed-torque
controller (:mod:`ctc`) all call the compiled scalar kernels defined here
(``mass_terms``, ``coriolis_terms``, ``gravity_terms``, ``friction_torque``,
``joint_acceleration``); :mod:`plant.robot.symbolic` derives the same expressions
with casadi from Lagrange's equations and the tests prove they agree.

Angles follow the paper's modified-DH (Craig) convention: q = 0 is the DH zero
configuration with the upper arm horizontal.  Joint order is (joint 2, joint 3)
everywhere; the parameter vector ``f`` has shape (9,) and holds f1..f9 in SI
units (see :data:`plant.logs.rig.F_UNITS`).

The public functions accept a single state (``q`` of shape (2,)) or a batch of
states stacked time-first (``q`` of shape (n, 2)).
"""
from __future__ import annotations

import math

import numba
import numpy as np

__all__ = [
    "inertia_matrix",
    "coriolis_centrifugal",
    "gravity_vector",
    "inverse_dynamics",
    "forward_dynamics",
    "regressor",
    "is_positive_definite",
    "min_inertia_eigenvalue",
    "friction_torque",
    "friction_torques",
    "checked_f",
]

_jit = numba.njit(cache=True, nogil=True, error_model="numpy")


# ----------------------------------------------------------------------------
# Compiled scalar kernels (the single numeric copy of the dynamics)
# ----------------------------------------------------------------------------
@_jit
def mass_terms(f, c3, s3):
    """Entries (D11, D12, D22) of the inertia matrix at cos q3 = c3, sin q3 = s3."""
    x = f[2] * c3 - f[3] * s3
    return f[6] + 2.0 * x, f[1] + x, f[0]


@_jit
def coriolis_terms(f, c3, s3, qd2, qd3):
    """Coriolis/centrifugal vector (h1, h2) at q3 (as c3, s3) and joint rates qd2, qd3."""
    a = f[2] * s3 + f[3] * c3
    return -a * (2.0 * qd2 * qd3 + qd3 * qd3), a * qd2 * qd2


@_jit
def gravity_terms(f, c2, s2, c23, s23, grav):
    """Gravity vector (g1, g2) from the cosines and sines of q2 and q2 + q3."""
    g2 = grav * (f[5] * s23 - f[4] * c23)
    return g2 + grav * (f[7] * s2 - f[8] * c2), g2


@_jit
def friction_torque(qd, viscous, coulomb_pos, coulomb_neg, ramp_speed):
    """Joint-side drive friction torque of one joint (N m), opposing the motion.

    ``tau_f = -(viscous qd + Tc clip(qd / ramp_speed, -1, 1))`` with
    ``Tc = coulomb_pos`` for qd > 0 and ``coulomb_neg`` otherwise; all arguments
    joint side (viscous = k^2 B, Coulomb = abs(k) Tc_motor, ramp_speed =
    motor ramp speed / abs(k)).

    Parameters
    ----------
    qd : float
        Joint rate (rad/s).
    viscous : float
        Joint-side viscous coefficient (N m s/rad).
    coulomb_pos, coulomb_neg : float
        Joint-side Coulomb torque for positive / non-positive rate (N m).
    ramp_speed : float
        Joint-side speed of the linear Coulomb ramp (rad/s).

    Returns
    -------
    float
        Friction torque (N m).
    """
    r = qd / ramp_speed
    if r > 1.0:
        r = 1.0
    elif r < -1.0:
        r = -1.0
    tc = coulomb_pos if qd > 0.0 else coulomb_neg
    return -(viscous * qd + tc * r)


def friction_torques(qd, viscous, coulomb_pos, coulomb_neg, ramp_speed):
    """:func:`friction_torque` on arrays (numpy broadcasting; plain numpy, no compile).

    Parameters
    ----------
    qd : array_like, shape (..., n)
        Joint rates (rad/s), the joints along the last axis.
    viscous, coulomb_pos, coulomb_neg, ramp_speed : array_like, shape (n,)
        Per joint, as :func:`friction_torque` (joint side).

    Returns
    -------
    ndarray, shape (..., n)
        Friction torques (N m): the same operations as :func:`friction_torque`.
    """
    qd = np.asarray(qd, dtype=float)
    r = np.clip(qd / np.asarray(ramp_speed, dtype=float), -1.0, 1.0)
    tc = np.where(qd > 0.0, coulomb_pos, coulomb_neg)
    return -(np.asarray(viscous, dtype=float) * qd + tc * r)


@_jit
def joint_acceleration_sc(f, s2, c2, s3, c3, qd2, qd3, tau2, tau3, grav):
    """Forward dynamics from the sines and cosines of q2 and q3.

    Same as :func:`joint_acceleration`, for callers that already hold
    ``sin``/``cos`` of the joint angles (the fast simulation path).  Returns
    ``(qdd2, qdd3, det D)``.
    """
    s23 = s2 * c3 + c2 * s3
    c23 = c2 * c3 - s2 * s3
    d11, d12, d22 = mass_terms(f, c3, s3)
    h1, h2 = coriolis_terms(f, c3, s3, qd2, qd3)
    g1, g2 = gravity_terms(f, c2, s2, c23, s23, grav)
    r1 = tau2 - h1 - g1
    r2 = tau3 - h2 - g2
    det = d11 * d22 - d12 * d12
    inv = 1.0 / det
    return (d22 * r1 - d12 * r2) * inv, (d11 * r2 - d12 * r1) * inv, det


@_jit
def joint_acceleration(f, q2, q3, qd2, qd3, tau2, tau3, grav):
    """Forward dynamics qdd = D^-1 (tau - h - g) of the rigid model.

    Returns ``(qdd2, qdd3, det)``; ``det = det D(q)``.  The caller must treat
    ``det <= 0`` (or ``f1 <= 0``) as a non-positive-definite D(q): the
    accelerations are then meaningless.
    """
    return joint_acceleration_sc(
        f, math.sin(q2), math.cos(q2), math.sin(q3), math.cos(q3), qd2, qd3, tau2, tau3, grav
    )


@_jit
def inverse_dynamics_terms(f, q2, q3, qd2, qd3, qdd2, qdd3, grav):
    """Rigid-body torque (tau2, tau3) = D(q) qdd + h(q, qd) + g(q) at one state."""
    s2 = math.sin(q2)
    c2 = math.cos(q2)
    s3 = math.sin(q3)
    c3 = math.cos(q3)
    s23 = s2 * c3 + c2 * s3
    c23 = c2 * c3 - s2 * s3
    d11, d12, d22 = mass_terms(f, c3, s3)
    h1, h2 = coriolis_terms(f, c3, s3, qd2, qd3)
    g1, g2 = gravity_terms(f, c2, s2, c23, s23, grav)
    return d11 * qdd2 + d12 * qdd3 + h1 + g1, d12 * qdd2 + d22 * qdd3 + h2 + g2


# ----------------------------------------------------------------------------
# Vectorised compiled loops behind the public functions
# ----------------------------------------------------------------------------
@_jit
def _inertia_batch(f, q):
    n = q.shape[0]
    out = np.empty((n, 2, 2))
    for i in range(n):
        d11, d12, d22 = mass_terms(f, math.cos(q[i, 1]), math.sin(q[i, 1]))
        out[i, 0, 0] = d11
        out[i, 0, 1] = d12
        out[i, 1, 0] = d12
        out[i, 1, 1] = d22
    return out


@_jit
def _coriolis_batch(f, q, qd):
    n = q.shape[0]
    out = np.empty((n, 2))
    for i in range(n):
        h1, h2 = coriolis_terms(f, math.cos(q[i, 1]), math.sin(q[i, 1]), qd[i, 0], qd[i, 1])
        out[i, 0] = h1
        out[i, 1] = h2
    return out


@_jit
def _gravity_batch(f, q, grav):
    n = q.shape[0]
    out = np.empty((n, 2))
    for i in range(n):
        q2 = q[i, 0]
        q23 = q2 + q[i, 1]
        g1, g2 = gravity_terms(f, math.cos(q2), math.sin(q2), math.cos(q23), math.sin(q23), grav)
        out[i, 0] = g1
        out[i, 1] = g2
    return out


@_jit
def _inverse_dynamics_batch(f, q, qd, qdd, grav):
    n = q.shape[0]
    out = np.empty((n, 2))
    for i in range(n):
        t2, t3 = inverse_dynamics_terms(
            f, q[i, 0], q[i, 1], qd[i, 0], qd[i, 1], qdd[i, 0], qdd[i, 1], grav
        )
        out[i, 0] = t2
        out[i, 1] = t3
    return out


@_jit
def _forward_dynamics_batch(f, q, qd, tau, grav):
    n = q.shape[0]
    out = np.empty((n, 2))
    det = np.empty(n)
    for i in range(n):
        a2, a3, d = joint_acceleration(
            f, q[i, 0], q[i, 1], qd[i, 0], qd[i, 1], tau[i, 0], tau[i, 1], grav
        )
        out[i, 0] = a2
        out[i, 1] = a3
        det[i] = d
    return out, det


@_jit
def _regressor_batch(q, qd, qdd, grav):
    # tau = Y f: column j is the torque of the model with f = e_j (the model is
    # linear in f), written out so the regressor and the model cannot disagree.
    n = q.shape[0]
    out = np.zeros((n, 2, 9))
    e = np.zeros(9)
    for j in range(9):
        e[:] = 0.0
        e[j] = 1.0
        for i in range(n):
            t2, t3 = inverse_dynamics_terms(
                e, q[i, 0], q[i, 1], qd[i, 0], qd[i, 1], qdd[i, 0], qdd[i, 1], grav
            )
            out[i, 0, j] = t2
            out[i, 1, j] = t3
    return out


# ----------------------------------------------------------------------------
# Public, shape-checking wrappers
# ----------------------------------------------------------------------------
def _as_f(f):
    f = np.ascontiguousarray(f, dtype=np.float64)
    if f.shape != (9,):
        raise ValueError(f"f must have shape (9,) (f1..f9), got {f.shape}")
    return f


def _as_states(*arrays):
    """Broadcast state arrays to (n, 2); return them and whether the input was a single state."""
    arrs = [np.asarray(a, dtype=np.float64) for a in arrays]
    single = all(a.ndim == 1 for a in arrs)
    out = []
    for a in arrs:
        if a.shape[-1:] != (2,) or a.ndim > 2:
            raise ValueError(f"joint arrays must have shape (2,) or (n, 2), got {a.shape}")
        out.append(a.reshape(-1, 2))
    n = max(a.shape[0] for a in out)
    out = [np.ascontiguousarray(np.broadcast_to(a, (n, 2))) for a in out]
    return out, single


def inertia_matrix(f, q):
    """Inertia matrix D(q) of links 2-3 (paper eq. 2, corrected).

    Parameters
    ----------
    f : array_like, shape (9,)
        Base parameters f1..f9 (kg m^2, kg m).
    q : array_like, shape (2,) or (n, 2)
        Joint angles (q2, q3) in rad.

    Returns
    -------
    ndarray, shape (2, 2) or (n, 2, 2)
        D(q) in kg m^2 (joint side, reflected motor inertia included in f1, f7).

    Raises
    ------
    ValueError
        If ``f`` or ``q`` has the wrong shape.
    """
    f = _as_f(f)
    (q,), single = _as_states(q)
    out = _inertia_batch(f, q)
    return out[0] if single else out


def coriolis_centrifugal(f, q, qd):
    """Coriolis/centrifugal vector h(q, qd) (paper eq. 2, corrected).

    Parameters
    ----------
    f : array_like, shape (9,)
        Base parameters f1..f9.
    q, qd : array_like, shape (2,) or (n, 2)
        Joint angles (rad) and rates (rad/s).

    Returns
    -------
    ndarray, shape (2,) or (n, 2)
        h in N m.
    """
    f = _as_f(f)
    (q, qd), single = _as_states(q, qd)
    out = _coriolis_batch(f, q, qd)
    return out[0] if single else out


def gravity_vector(f, q, g=9.81):
    """Gravity torque vector g(q) (paper eq. 2).

    Parameters
    ----------
    f : array_like, shape (9,)
        Base parameters f1..f9.
    q : array_like, shape (2,) or (n, 2)
        Joint angles (rad).
    g : float
        Gravitational acceleration (m/s^2); use the rig's ``gravity_m_s2``.

    Returns
    -------
    ndarray, shape (2,) or (n, 2)
        Gravity torques in N m.
    """
    f = _as_f(f)
    (q,), single = _as_states(q)
    out = _gravity_batch(f, q, float(g))
    return out[0] if single else out


def inverse_dynamics(f, q, qd, qdd, g=9.81):
    """Rigid-body joint torques tau = D(q) qdd + h(q, qd) + g(q) (paper eq. 2).

    Parameters
    ----------
    f : array_like, shape (9,)
        Base parameters f1..f9.
    q, qd, qdd : array_like, shape (2,) or (n, 2)
        Joint angles (rad), rates (rad/s) and accelerations (rad/s^2).
    g : float
        Gravitational acceleration (m/s^2).

    Returns
    -------
    ndarray, shape (2,) or (n, 2)
        Joint torques (N m), friction excluded.
    """
    f = _as_f(f)
    (q, qd, qdd), single = _as_states(q, qd, qdd)
    out = _inverse_dynamics_batch(f, q, qd, qdd, float(g))
    return out[0] if single else out


def forward_dynamics(f, q, qd, tau, g=9.81):
    """Joint accelerations qdd = D(q)^-1 (tau - h(q, qd) - g(q)).

    Parameters
    ----------
    f : array_like, shape (9,)
        Base parameters f1..f9.
    q, qd, tau : array_like, shape (2,) or (n, 2)
        Joint angles (rad), rates (rad/s) and applied joint torques (N m).
    g : float
        Gravitational acceleration (m/s^2).

    Returns
    -------
    ndarray, shape (2,) or (n, 2)
        Joint accelerations (rad/s^2).

    Raises
    ------
    ValueError
        If D(q) is not positive definite at one of the states.
    """
    f = _as_f(f)
    (q, qd, tau), single = _as_states(q, qd, tau)
    out, det = _forward_dynamics_batch(f, q, qd, tau, float(g))
    if f[0] <= 0.0 or np.any(det <= 0.0):
        raise ValueError("D(q) is not positive definite for this f at the given state(s)")
    return out[0] if single else out


def regressor(q, qd, qdd, g=9.81):
    """Regressor Y(q, qd, qdd) of the rigid model, tau = Y f (linear in f1..f9).

    Parameters
    ----------
    q, qd, qdd : array_like, shape (2,) or (n, 2)
        Joint angles (rad), rates (rad/s) and accelerations (rad/s^2).
    g : float
        Gravitational acceleration (m/s^2).

    Returns
    -------
    ndarray, shape (2, 9) or (n, 2, 9)
        Y such that ``Y @ f == inverse_dynamics(f, q, qd, qdd, g)``.
    """
    (q, qd, qdd), single = _as_states(q, qd, qdd)
    out = _regressor_batch(q, qd, qdd, float(g))
    return out[0] if single else out


def min_inertia_eigenvalue(f, q3):
    """Smallest eigenvalue of D(q) (kg m^2) at the joint-3 angle(s) ``q3``.

    D depends on q3 only.

    Parameters
    ----------
    f : array_like, shape (9,)
        Base parameters.
    q3 : float or array_like, shape (n,)
        Joint-3 angle(s) (rad).

    Returns
    -------
    float or ndarray, shape (n,)
    """
    f = _as_f(f)
    q3 = np.asarray(q3, dtype=float)
    x = f[2] * np.cos(q3) - f[3] * np.sin(q3)
    d11, d12, d22 = f[6] + 2 * x, f[1] + x, f[0]
    mean = 0.5 * (d11 + d22)
    rad = np.sqrt((0.5 * (d11 - d22)) ** 2 + d12**2)
    return mean - rad


def is_positive_definite(f, q3=None):
    """Whether D(q) is positive definite for ``f``.

    Parameters
    ----------
    f : array_like, shape (9,)
        Base parameters.
    q3 : array_like, optional
        Joint-3 angles (rad) to check; by default a full turn (D depends on q3
        only, through cos q3 and sin q3).

    Returns
    -------
    bool
    """
    if q3 is None:
        q3 = np.linspace(-np.pi, np.pi, 721)
    return bool(np.all(min_inertia_eigenvalue(f, q3) > 0.0))


def checked_f(f, what="f", result_hint="pass result.f"):
    """Base parameters f1..f9 as a contiguous float array, or a one-line error.

    The one check of an f argument (controllers, closed-loop simulation).

    Parameters
    ----------
    f : array_like, shape (9,)
    what : str
        The argument's name in the message.
    result_hint : str
        What to say when an identification result (a dict or a result
        object) is passed instead of its f.

    Returns
    -------
    ndarray, shape (9,), float64, C-contiguous

    Raises
    ------
    ValueError
        For a result, a non-numeric value, a shape other than (9,), NaN or inf.
    """
    if isinstance(f, dict) or hasattr(f, "to_dict"):
        raise ValueError(f"{what} must be 9 numbers f1..f9; for an identification result "
                         f"{result_hint}")
    try:
        a = np.ascontiguousarray(f, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be 9 numbers f1..f9, got {type(f).__name__}") from None
    if a.shape != (9,):
        raise ValueError(f"{what} must have shape (9,) (f1..f9), got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{what} contains NaN or inf")
    return a
