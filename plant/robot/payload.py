"""Payload model: how a load rigidly attached to the flange changes f1..f9.

With joints 4-6 locked at 0 the flange moves with link 3, so a payload of
mass ``m``, centre of mass ``(xp, yp)`` in the link-3 frame and inertia
``Izz_p`` about its own centre of mass (axis parallel to the joint axes)
simply becomes part of link 3.  Combining the two bodies (mass, first
moments, parallel-axis theorem) and substituting into the base parameters of
the paper's eq. 3 gives a change of f that does not depend on the robot::

    Δf1 = Δf2 = J            Δf3 = m xp a3     Δf4 = m yp a3
    Δf5 = m xp               Δf6 = m yp        Δf7 = m a3² + J
    Δf8 = 0                  Δf9 = m a3

with ``J = Izz_p + m (xp² + yp²)`` the payload inertia about the joint-3
axis.  Δf is linear in the payload vector ``p = [m, m xp, m yp, J]``
(:func:`payload_vector`, :func:`delta_from_payload_vector`), which is what
an on-line payload identification searches over.

The derivation is done symbolically with casadi
(:func:`payload_derivation_function`, :func:`payload_delta_function`); the
closed form used by the numeric functions is checked against it in
``tests/test_payload.py``.  See ``docs/payload.rst``.

Source: paper eq. 3 (base parameters f1..f9 of PUMA 560 links 2-3).
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

__all__ = [
    "LINK_PARAMETER_NAMES",
    "PAYLOAD_VECTOR_NAMES",
    "PAYLOAD_VECTOR_UNITS",
    "Payload",
    "add_payload",
    "delta_from_payload_vector",
    "payload_delta",
    "payload_delta_function",
    "payload_delta_matrix",
    "payload_derivation_function",
    "payload_from_vector",
    "payload_vector",
    "payload_vector_from_delta",
    "recover_payload",
]

#: Physical link parameters entering eq. 3, in the order used by
#: :func:`payload_derivation_function` (link-2 and link-3 COMs in their own
#: link frames, inertias about the link's own COM).
LINK_PARAMETER_NAMES = (
    "Jm2", "k2", "Jm3", "k3",
    "m2", "x2", "y2", "Izz2",
    "m3", "x3", "y3", "Izz3",
)

#: Components of the payload vector p (Δf is linear in p).
PAYLOAD_VECTOR_NAMES = ("m", "m_xp", "m_yp", "izz_joint3")

#: SI units of the payload vector components.
PAYLOAD_VECTOR_UNITS = ("kg", "kg m", "kg m", "kg m^2")

# Relative round-off tolerance below which a slightly negative recovered
# payload inertia (point-mass payload) is set to zero without complaint.
_IZZ_ROUNDOFF_REL = 1e-10


# --------------------------------------------------------------------------
# validation helpers
# --------------------------------------------------------------------------
def _finite_float(value, name: str) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a real number, got {value!r}") from None
    if not math.isfinite(x):
        raise ValueError(f"{name} must be finite, got {x!r}")
    return x


def _check_a3(a3) -> float:
    a3 = _finite_float(a3, "a3")
    if a3 <= 0.0:
        raise ValueError(f"a3 (link length) must be > 0 m, got {a3!r}")
    return a3


def _vector(value, n: int, name: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a numeric array of shape ({n},)") from None
    if arr.shape != (n,):
        raise ValueError(f"{name} must have shape ({n},), got {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {arr.tolist()}")
    return arr


# --------------------------------------------------------------------------
# Payload
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class Payload:
    """A rigid payload attached to the flange (moves with link 3).

    Parameters
    ----------
    mass_kg : float
        Payload mass m (kg), finite, >= 0.
    com_m : sequence of 2 float
        Payload centre of mass (xp, yp) in the link-3 frame (m), the frame in
        which the paper's eq. 3 gives the link-3 COM (x3, y3).  The offset
        along the joint axes (z) does not enter the planar 2-link model.
    izz_kgm2 : float, optional
        Inertia Izz_p about the payload's own COM, about an axis parallel to
        the joint axes (kg m^2), finite, >= 0.  Default 0 (point mass).

    Raises
    ------
    ValueError
        If a value is not a finite real number, ``com_m`` does not have two
        elements, or ``mass_kg`` or ``izz_kgm2`` is negative.

    Notes
    -----
    ``com_m`` is stored as a tuple of two floats.  Source: paper eq. 3.
    """

    mass_kg: float
    com_m: tuple
    izz_kgm2: float = 0.0

    def __post_init__(self):
        mass = _finite_float(self.mass_kg, "Payload.mass_kg")
        if mass < 0.0:
            raise ValueError(f"Payload.mass_kg must be >= 0, got {mass!r}")
        try:
            com = tuple(self.com_m)
        except TypeError:
            raise ValueError(
                f"Payload.com_m must be a pair (xp, yp) in m, got {self.com_m!r}"
            ) from None
        if len(com) != 2:
            raise ValueError(f"Payload.com_m must have 2 elements (xp, yp), got {len(com)}")
        com = (
            _finite_float(com[0], "Payload.com_m[0] (xp)"),
            _finite_float(com[1], "Payload.com_m[1] (yp)"),
        )
        izz = _finite_float(self.izz_kgm2, "Payload.izz_kgm2")
        if izz < 0.0:
            raise ValueError(f"Payload.izz_kgm2 must be >= 0, got {izz!r}")
        object.__setattr__(self, "mass_kg", mass)
        object.__setattr__(self, "com_m", com)
        object.__setattr__(self, "izz_kgm2", izz)

    @property
    def first_moments(self) -> np.ndarray:
        """First moments (m xp, m yp) in the link-3 frame, shape (2,), kg m."""
        return self.mass_kg * np.asarray(self.com_m, dtype=float)

    @property
    def inertia_about_joint3(self) -> float:
        """Inertia about the joint-3 axis, Izz_p + m (xp² + yp²), kg m^2."""
        xp, yp = self.com_m
        return self.izz_kgm2 + self.mass_kg * (xp * xp + yp * yp)

    def to_dict(self) -> dict:
        """JSON-ready dict ``{"mass_kg", "com_m": [xp, yp], "izz_kgm2"}`` (SI units)."""
        return {"mass_kg": self.mass_kg, "com_m": list(self.com_m), "izz_kgm2": self.izz_kgm2}


# --------------------------------------------------------------------------
# casadi derivation (paper eq. 3)
# --------------------------------------------------------------------------
def _eq3(ca, link, a3):
    """Paper eq. 3 as a casadi expression (9x1) of the link parameters."""
    Jm2, k2, Jm3, k3, m2, x2, y2, Izz2, m3, x3, y3, Izz3 = link
    return ca.vertcat(
        Jm3 * k3**2 + Izz3 + m3 * (x3**2 + y3**2),
        Izz3 + m3 * (x3**2 + y3**2),
        m3 * x3 * a3,
        m3 * y3 * a3,
        m3 * x3,
        m3 * y3,
        Jm2 * k2**2 + Izz2 + m2 * (x2**2 + y2**2) + m3 * a3**2 + Izz3 + m3 * (x3**2 + y3**2),
        m2 * y2,
        m2 * x2 + m3 * a3,
    )


@functools.lru_cache(maxsize=None)
def payload_derivation_function():
    """Symbolic derivation of Δf from eq. 3 with casadi, link parameters kept.

    Link 3 and the payload are combined into one body: mass
    ``m3' = m3 + m``; COM ``x3' = (m3 x3 + m xp) / m3'``,
    ``y3' = (m3 y3 + m yp) / m3'``; inertia about the new COM by the
    parallel-axis theorem
    ``Izz3' = Izz3 + m3 |c3 - c3'|² + Izz_p + m |cp - c3'|²``.
    Eq. 3 is evaluated for the combined and for the bare link 3.

    Returns
    -------
    casadi.Function
        ``payload_derivation(link[12], payload[4], a3) ->
        (f_unloaded[9], f_loaded[9], delta_f[9])`` with ``link`` ordered as
        :data:`LINK_PARAMETER_NAMES` and ``payload = [m, xp, yp, Izz_p]``
        (SI units).  Valid for ``m3 + m != 0``.

    Notes
    -----
    casadi does not expand polynomials, so the link parameters are not
    eliminated structurally from ``delta_f``; ``tests/test_payload.py``
    proves that ``delta_f`` does not depend on them (exact rational
    evaluation of this Function and a sympy simplification of its graph).
    Source: paper eq. 3.
    """
    import casadi as ca

    link = ca.SX.sym("link", len(LINK_PARAMETER_NAMES))
    pay = ca.SX.sym("payload", 4)
    a3 = ca.SX.sym("a3")
    Jm2, k2, Jm3, k3, m2, x2, y2, Izz2, m3, x3, y3, Izz3 = ca.vertsplit(link)
    m, xp, yp, izz_p = ca.vertsplit(pay)

    m3c = m3 + m
    x3c = (m3 * x3 + m * xp) / m3c
    y3c = (m3 * y3 + m * yp) / m3c
    izz3c = (
        Izz3 + m3 * ((x3 - x3c) ** 2 + (y3 - y3c) ** 2)
        + izz_p + m * ((xp - x3c) ** 2 + (yp - y3c) ** 2)
    )
    f0 = _eq3(ca, (Jm2, k2, Jm3, k3, m2, x2, y2, Izz2, m3, x3, y3, Izz3), a3)
    f1 = _eq3(ca, (Jm2, k2, Jm3, k3, m2, x2, y2, Izz2, m3c, x3c, y3c, izz3c), a3)
    delta = ca.simplify(f1 - f0)
    return ca.Function(
        "payload_derivation",
        [link, pay, a3],
        [f0, f1, delta],
        ["link", "payload", "a3"],
        ["f_unloaded", "f_loaded", "delta_f"],
    )


#: Reference link used to remove the (proved irrelevant) link parameters
#: from the derivation: m3 = 1 kg, every other link parameter 0.
_REFERENCE_LINK = (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0)


@functools.lru_cache(maxsize=None)
def payload_delta_function():
    """Casadi Function Δf(m, xp, yp, Izz_p, a3) derived from eq. 3.

    Returns
    -------
    casadi.Function
        ``payload_delta(m, xp, yp, izz_p, a3) -> delta_f[9]`` (SI units).

    Notes
    -----
    Obtained from :func:`payload_derivation_function` by substituting a
    reference link (m3 = 1 kg, all other link parameters 0).  This is exact
    for every robot because Δf does not depend on the link parameters
    (proved in ``tests/test_payload.py``); it is defined for m > -1 kg, in
    particular for every physical payload.  Source: paper eq. 3.
    """
    import casadi as ca

    m, xp, yp, izz_p, a3 = (ca.SX.sym(n) for n in ("m", "xp", "yp", "izz_p", "a3"))
    deriv = payload_derivation_function()
    _, _, delta = deriv(ca.DM(_REFERENCE_LINK), ca.vertcat(m, xp, yp, izz_p), a3)
    return ca.Function(
        "payload_delta", [m, xp, yp, izz_p, a3], [ca.simplify(delta)],
        ["m", "xp", "yp", "izz_p", "a3"], ["delta_f"],
    )


# --------------------------------------------------------------------------
# closed form (linear in the payload vector)
# --------------------------------------------------------------------------
def payload_vector(payload: Payload) -> np.ndarray:
    """Payload vector p = [m, m xp, m yp, Izz_p + m (xp² + yp²)].

    Parameters
    ----------
    payload : Payload
        The payload.

    Returns
    -------
    numpy.ndarray, shape (4,)
        ``p`` in kg, kg m, kg m, kg m^2 (:data:`PAYLOAD_VECTOR_NAMES`).
        Δf is linear in ``p`` (:func:`delta_from_payload_vector`).

    Raises
    ------
    ValueError
        If ``payload`` is not a :class:`Payload`.
    """
    if not isinstance(payload, Payload):
        raise ValueError(f"payload must be a Payload, got {type(payload).__name__}")
    mx, my = payload.first_moments
    return np.array([payload.mass_kg, mx, my, payload.inertia_about_joint3])


def payload_delta_matrix(a3: float) -> np.ndarray:
    """Matrix A(a3) with Δf = A p for the payload vector p.

    Parameters
    ----------
    a3 : float
        Link length a3 (m), finite, > 0.

    Returns
    -------
    numpy.ndarray, shape (9, 4)
        Rows f1..f9, columns ``[m, m xp, m yp, J]``::

            Δf1 = J, Δf2 = J, Δf3 = a3 m xp, Δf4 = a3 m yp, Δf5 = m xp,
            Δf6 = m yp, Δf7 = a3² m + J, Δf8 = 0, Δf9 = a3 m

    Raises
    ------
    ValueError
        If ``a3`` is not finite and positive.

    Notes
    -----
    Closed form of the casadi derivation of paper eq. 3
    (:func:`payload_delta_function`); equality is tested.
    """
    a3 = _check_a3(a3)
    A = np.zeros((9, 4))
    A[0, 3] = 1.0
    A[1, 3] = 1.0
    A[2, 1] = a3
    A[3, 2] = a3
    A[4, 1] = 1.0
    A[5, 2] = 1.0
    A[6, 0] = a3 * a3
    A[6, 3] = 1.0
    A[8, 0] = a3
    return A


def delta_from_payload_vector(p, a3: float) -> np.ndarray:
    """Change of f caused by a payload given as payload vector(s).

    Parameters
    ----------
    p : array_like, shape (4,) or (..., 4)
        Payload vector(s) ``[m, m xp, m yp, Izz_p + m (xp² + yp²)]``
        (kg, kg m, kg m, kg m^2).  Any real values are accepted (a search
        may leave the physical region); batches are evaluated row-wise.
    a3 : float
        Link length a3 (m), finite, > 0.

    Returns
    -------
    numpy.ndarray, shape (9,) or (..., 9)
        Δf = A(a3) p (units of f1..f9).

    Raises
    ------
    ValueError
        If ``p`` is not finite or its last dimension is not 4, or ``a3`` is
        not finite and positive.
    """
    A = payload_delta_matrix(a3)
    try:
        p = np.asarray(p, dtype=float)
    except (TypeError, ValueError):
        raise ValueError("p must be a numeric array with last dimension 4") from None
    if p.ndim == 0 or p.shape[-1] != 4:
        raise ValueError(f"p must have last dimension 4, got shape {p.shape}")
    if not np.all(np.isfinite(p)):
        raise ValueError("p must be finite")
    return p @ A.T


def payload_delta(payload: Payload, a3: float) -> np.ndarray:
    """Change Δf = f(loaded) - f(unloaded) of the base parameters.

    Parameters
    ----------
    payload : Payload
        The payload attached to the flange.
    a3 : float
        Link length a3 (m), finite, > 0.

    Returns
    -------
    numpy.ndarray, shape (9,)
        Δf1..Δf9 (kg m^2 for f1-f4, f7; kg m for f5, f6, f8, f9); Δf8 = 0.

    Raises
    ------
    ValueError
        If ``payload`` is not a :class:`Payload` or ``a3`` is not finite and
        positive.

    Notes
    -----
    Independent of the robot's link parameters.  Closed form of the casadi
    derivation from paper eq. 3 (:func:`payload_delta_function`).
    """
    return delta_from_payload_vector(payload_vector(payload), a3)


def add_payload(f, payload: Payload, a3: float) -> np.ndarray:
    """Base parameters of the robot carrying ``payload``.

    Parameters
    ----------
    f : array_like, shape (9,)
        Base parameters f1..f9 of the unloaded robot (paper eq. 3).
    payload : Payload
        The payload attached to the flange.
    a3 : float
        Link length a3 (m), finite, > 0.

    Returns
    -------
    numpy.ndarray, shape (9,)
        ``f + payload_delta(payload, a3)``.

    Raises
    ------
    ValueError
        If ``f`` is not a finite (9,) vector, ``payload`` is not a
        :class:`Payload` or ``a3`` is not finite and positive.
    """
    f = _vector(f, 9, "f")
    return f + payload_delta(payload, a3)


# --------------------------------------------------------------------------
# inverse
# --------------------------------------------------------------------------
def payload_vector_from_delta(delta_f, a3: float) -> np.ndarray:
    """Least-squares payload vector p from a change Δf of the base parameters.

    Parameters
    ----------
    delta_f : array_like, shape (9,)
        f(loaded) - f(unloaded).
    a3 : float
        Link length a3 (m), finite, > 0.

    Returns
    -------
    numpy.ndarray, shape (4,)
        ``p = [m, m xp, m yp, J]`` with J = Izz_p + m (xp² + yp²).

    Raises
    ------
    ValueError
        If ``delta_f`` is not a finite (9,) vector or ``a3`` is not finite
        and positive.

    Notes
    -----
    The eight informative equations Δf = A(a3) p (Δf8 carries none) are made
    dimensionally homogeneous by dividing the kg m^2 rows by a3² and the
    kg m rows by a3, with unknowns q = [m, m xp/a3, m yp/a3, J/a3²] (all in
    kg), and solved by ordinary least squares.  With d_i = Δf_i / a3^k_i:

    * m xp = (Δf3/a3 + Δf5) / 2 and m yp = (Δf4/a3 + Δf6) / 2;
    * m = (3 d9 + 2 d7 - d1 - d2) / 5 and J / a3² = (2 d1 + 2 d2 + d7 - d9) / 5,
      i.e. m uses Δf9/a3 and Δf7 - J jointly, J uses Δf1, Δf2 and Δf7 - m a3².

    The estimate is exact when Δf is consistent (comes from a payload).
    """
    a3 = _check_a3(a3)
    d = _vector(delta_f, 9, "delta_f")
    d1, d2, d7 = d[0] / a3**2, d[1] / a3**2, d[6] / a3**2
    d9 = d[8] / a3
    m = (3.0 * d9 + 2.0 * d7 - d1 - d2) / 5.0
    j = a3**2 * (2.0 * d1 + 2.0 * d2 + d7 - d9) / 5.0
    mx = 0.5 * (d[2] / a3 + d[4])
    my = 0.5 * (d[3] / a3 + d[5])
    return np.array([m, mx, my, j])


def payload_from_vector(p, *, clip_negative_inertia: bool = False) -> Payload:
    """Payload from its payload vector p = [m, m xp, m yp, J].

    Parameters
    ----------
    p : array_like, shape (4,)
        Payload vector (kg, kg m, kg m, kg m^2).
    clip_negative_inertia : bool, optional
        If True, a negative own inertia ``Izz_p = J - ((m xp)² + (m yp)²)/m``
        (an inconsistent, e.g. noisy, p) is set to 0 instead of raising.
        Round-off-sized negatives (relative 1e-10) are always set to 0.

    Returns
    -------
    Payload
        ``mass_kg = m``, ``com_m = (m xp / m, m yp / m)``, ``izz_kgm2 = Izz_p``.

    Raises
    ------
    ValueError
        If ``p`` is not a finite (4,) vector, ``m <= 0`` (no payload, COM
        undefined), or Izz_p < 0 beyond round-off and
        ``clip_negative_inertia`` is False.
    """
    p = _vector(p, 4, "p")
    m, mx, my, j = p
    if m <= 0.0:
        raise ValueError(f"payload mass must be > 0 to recover a payload, got m = {m:.6g} kg")
    steiner = (mx * mx + my * my) / m
    izz = j - steiner
    if izz < 0.0:
        tol = _IZZ_ROUNDOFF_REL * max(abs(j), steiner)
        if izz >= -tol or clip_negative_inertia:
            izz = 0.0
        else:
            raise ValueError(
                f"inconsistent payload vector: own inertia Izz_p = {izz:.6g} kg m^2 < 0 "
                "(use clip_negative_inertia=True to clip it to 0)"
            )
    return Payload(mass_kg=m, com_m=(mx / m, my / m), izz_kgm2=izz)


def recover_payload(f_loaded, f_unloaded, a3: float, *,
                    clip_negative_inertia: bool = False) -> Payload:
    """Recover the payload from the loaded and the unloaded base parameters.

    Parameters
    ----------
    f_loaded : array_like, shape (9,)
        Base parameters f1..f9 of the robot carrying the payload.
    f_unloaded : array_like, shape (9,)
        Base parameters f1..f9 of the same robot without payload.
    a3 : float
        Link length a3 (m), finite, > 0.
    clip_negative_inertia : bool, optional
        Passed to :func:`payload_from_vector`.

    Returns
    -------
    Payload
        Least-squares payload (estimator in
        :func:`payload_vector_from_delta`); exact inverse of
        :func:`add_payload`.

    Raises
    ------
    ValueError
        If an f is not a finite (9,) vector, ``a3`` is not finite and
        positive, the recovered mass is <= 0 (no payload), or the recovered
        own inertia is negative (see :func:`payload_from_vector`).
    """
    delta = _vector(f_loaded, 9, "f_loaded") - _vector(f_unloaded, 9, "f_unloaded")
    p = payload_vector_from_delta(delta, a3)
    return payload_from_vector(p, clip_negative_inertia=clip_negative_inertia)
