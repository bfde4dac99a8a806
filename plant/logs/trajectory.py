"""Reference trajectories of joints 2 and 3: a cosine series with an optional quintic ramp.

A trajectory is, per joint j (j = 0 for joint 2, j = 1 for joint 3),

.. math::

    q_j(t) = w(t) \\Big(c_j + \\sum_i A_{ji} \\cos(\\omega_{ji} t + \\varphi_{ji})\\Big)

with the quintic smoothstep ramp :math:`w(t) = 10 s^3 - 15 s^4 + 6 s^5`,
:math:`s = t / t_{ramp}`, :math:`w = 1` for :math:`t \\ge t_{ramp}` and
:math:`w = 0` for :math:`t \\le 0`. Without a ramp (``t_ramp_s == 0``)
:math:`w = 1` everywhere. The ramp multiplies the whole expression, offset
included (``trajectory.formula`` of the validation log:
``q2_ref = w(t)*(-pi/6 + pi/6*cos(2*pi*t/T))``), so a ramped trajectory starts
at q = 0 with zero velocity and acceleration.

The parameters come from a log sidecar's ``trajectory.parameters``
(``c``, ``terms_A_omega_phi``, ``t_ramp_s``); :meth:`Trajectory.paper` builds
the reference of the paper (eq. 6).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from plant._errors import LogError

__all__ = ["Trajectory"]


def _readonly(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=float)  # private copy
    a.setflags(write=False)
    return a


def _is_number(x: Any) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


@dataclass(frozen=True, eq=False)
class Trajectory:
    """Reference joint trajectory of joints 2 and 3 with analytic derivatives.

    Per joint j, ``q_j(t) = w(t) * (c_j + sum_i A_ji cos(omega_ji t + phi_ji))``
    where ``w`` is the quintic smoothstep ramp ``10 s^3 - 15 s^4 + 6 s^5``,
    ``s = t / t_ramp_s`` (``w = 0`` for t <= 0, ``w = 1`` for t >= t_ramp_s,
    ``w = 1`` everywhere when ``t_ramp_s == 0``).

    Build it with :meth:`from_sidecar` (a log's JSON sidecar) or
    :meth:`paper` (the paper's eq. 6). Instances are immutable (the arrays are
    read-only) and compare equal when all parameters are equal.

    Attributes
    ----------
    c : ndarray, shape (n_joints,)
        Offsets c_j (rad); 2 joints (q2, q3) for the PUMA 560 links 2-3,
        one per active joint for a robot model.
    amplitude : ndarray, shape (n_joints, m)
        Amplitudes A_ji (rad); joints with fewer than m terms are padded with
        zero-amplitude terms.
    omega : ndarray, shape (n_joints, m)
        Angular frequencies omega_ji (rad/s); 0 for padding.
    phase : ndarray, shape (n_joints, m)
        Phases phi_ji (rad); 0 for padding.
    t_ramp_s : float
        Duration of the quintic ramp (s); 0 means no ramp.
    n_terms : tuple of n_joints int
        Number of real (non-padding) terms per joint.
    """

    c: np.ndarray
    amplitude: np.ndarray
    omega: np.ndarray
    phase: np.ndarray
    t_ramp_s: float = 0.0
    n_terms: tuple = field(default=None)  # type: ignore[assignment]

    def __post_init__(self) -> None:
        c = _readonly(self.c).reshape(-1)
        amp = _readonly(self.amplitude)
        om = _readonly(self.omega)
        ph = _readonly(self.phase)
        nj = c.shape[0]
        if nj < 1:
            raise ValueError(f"Trajectory: c must have shape (n_joints,), got {c.shape}")
        if amp.ndim != 2 or amp.shape[0] != nj or om.shape != amp.shape or ph.shape != amp.shape:
            raise ValueError(
                f"Trajectory: amplitude, omega and phase must share a shape ({nj}, m), got "
                f"{amp.shape}, {om.shape}, {ph.shape}"
            )
        for name, a in (("c", c), ("amplitude", amp), ("omega", om), ("phase", ph)):
            if not np.all(np.isfinite(a)):
                raise ValueError(f"Trajectory: {name} has non-finite values")
        t_ramp = float(self.t_ramp_s)
        if not math.isfinite(t_ramp) or t_ramp < 0.0:
            raise ValueError(f"Trajectory: t_ramp_s must be finite and >= 0, got {t_ramp}")
        n_terms = self.n_terms
        if n_terms is None:
            n_terms = (amp.shape[1],) * nj
        n_terms = tuple(int(n) for n in n_terms)
        if len(n_terms) != nj or any(n < 0 or n > amp.shape[1] for n in n_terms):
            raise ValueError(f"Trajectory: invalid n_terms {n_terms} for {amp.shape[1]} columns")
        for name, v in (("c", c), ("amplitude", amp), ("omega", om), ("phase", ph)):
            object.__setattr__(self, name, v)
        object.__setattr__(self, "t_ramp_s", t_ramp)
        object.__setattr__(self, "n_terms", n_terms)

    # ------------------------------------------------------------------ builders
    @classmethod
    def from_sidecar(cls, sidecar: Mapping[str, Any], source: str = "sidecar",
                     n_joints: int = 2) -> "Trajectory":
        """Build the trajectory described by a log sidecar.

        Parameters
        ----------
        sidecar : mapping
            The whole sidecar (with key ``trajectory.parameters``), its
            ``trajectory`` entry, or the ``parameters`` mapping itself:
            ``c`` (2 numbers, rad), ``terms_A_omega_phi`` (per joint a list of
            ``[A (rad), omega (rad/s), phi (rad)]`` triples; the two joints may
            have different numbers of terms) and optional ``t_ramp_s``
            (s, default 0 = no ramp).
        source : str, optional
            Name of the file the mapping came from, used in error messages.
        n_joints : int, optional
            Joints of the reference (2 for the PUMA links 2-3; a robot
            model's active joints otherwise): the lengths of ``c`` and
            ``terms_A_omega_phi``.

        Returns
        -------
        Trajectory

        Raises
        ------
        LogError
            If a key is missing, has the wrong shape or holds a non-finite
            number; the one-line message names ``source`` and the key.
        """
        prefix = ""
        p: Any = sidecar
        if isinstance(p, Mapping) and "trajectory" in p:
            p, prefix = p["trajectory"], "trajectory."
            if not isinstance(p, Mapping):
                raise LogError(f"{source}: key 'trajectory' must be an object")
        elif isinstance(p, Mapping) and "c" not in p and "sample_time_s" in p:
            raise LogError(f"{source}: key 'trajectory' is missing")
        if isinstance(p, Mapping) and "parameters" in p:
            p, prefix = p["parameters"], prefix + "parameters."
        elif prefix:
            raise LogError(f"{source}: key 'trajectory.parameters' is missing")
        if not isinstance(p, Mapping):
            raise LogError(f"{source}: key '{prefix.rstrip('.') or 'trajectory'}' must be an object")
        where = prefix or ""

        def err(key: str, msg: str) -> LogError:
            return LogError(f"{source}: key '{where}{key}' {msg}")

        if "c" not in p:
            raise err("c", "is missing")
        c = p["c"]
        nj = int(n_joints)
        if not isinstance(c, (list, tuple)) or len(c) != nj or not all(_is_number(x) for x in c):
            raise err("c", f"must be a list of {nj} numbers")
        if "terms_A_omega_phi" not in p:
            raise err("terms_A_omega_phi", "is missing")
        terms = p["terms_A_omega_phi"]
        if not isinstance(terms, (list, tuple)) or len(terms) != nj:
            raise err("terms_A_omega_phi", f"must be a list of {nj} per-joint term lists")
        rows = []
        for j, tj in enumerate(terms):
            if not isinstance(tj, (list, tuple)):
                raise err(f"terms_A_omega_phi[{j}]", "must be a list of [A, omega, phi] triples")
            for i, term in enumerate(tj):
                if (
                    not isinstance(term, (list, tuple))
                    or len(term) != 3
                    or not all(_is_number(x) for x in term)
                ):
                    raise err(f"terms_A_omega_phi[{j}][{i}]", "must be [A, omega, phi] (3 numbers)")
            rows.append([[float(x) for x in term] for term in tj])
        t_ramp = p.get("t_ramp_s", 0.0)
        if t_ramp is None:
            t_ramp = 0.0
        if not _is_number(t_ramp):
            raise err("t_ramp_s", "must be a number")
        t_ramp = float(t_ramp)
        if not math.isfinite(t_ramp) or t_ramp < 0.0:
            raise err("t_ramp_s", f"must be finite and >= 0, got {t_ramp!r}")
        cf = np.array([float(x) for x in c])
        if not np.all(np.isfinite(cf)):
            raise err("c", "has non-finite values")
        for j, rj in enumerate(rows):
            if rj and not np.all(np.isfinite(np.array(rj))):
                raise err(f"terms_A_omega_phi[{j}]", "has non-finite values")
        return cls.from_terms(cf, rows, t_ramp)

    @classmethod
    def from_terms(cls, c, terms, t_ramp_s: float = 0.0) -> "Trajectory":
        """Build a trajectory from offsets and per-joint term lists.

        Parameters
        ----------
        c : array_like, shape (n_joints,)
            Offsets (rad).
        terms : sequence of n_joints sequences of (A, omega, phi)
            Per-joint cosine terms: amplitude (rad), angular frequency (rad/s),
            phase (rad). The joints may have different numbers of terms.
        t_ramp_s : float, optional
            Quintic ramp duration (s); 0 (default) = no ramp.

        Returns
        -------
        Trajectory
        """
        nj = np.asarray(c, dtype=float).reshape(-1).shape[0]
        if len(terms) != nj:
            raise ValueError(f"terms must hold {nj} per-joint lists (one per offset in c)")
        n_terms = tuple(len(tj) for tj in terms)
        m = max(n_terms)
        amp = np.zeros((nj, m))
        om = np.zeros((nj, m))
        ph = np.zeros((nj, m))
        for j, tj in enumerate(terms):
            for i, (a, w, p) in enumerate(tj):
                amp[j, i], om[j, i], ph[j, i] = a, w, p
        return cls(np.asarray(c, dtype=float), amp, om, ph, float(t_ramp_s), n_terms)

    @classmethod
    def paper(cls, T: float = 3.65) -> "Trajectory":
        """Reference trajectory of the paper (eq. 6).

        ``q2(t) = -pi/4 + pi/4 cos(2 pi t / T)`` and
        ``q3(t) = pi/4 - pi/4 cos(4 pi t / T)`` (rad), no ramp.

        Parameters
        ----------
        T : float, optional
            Period of joint 2 (s); the paper uses T = 3.65 s. Joint 3 has
            period T/2.

        Returns
        -------
        Trajectory
        """
        T = float(T)
        if not math.isfinite(T) or T <= 0.0:
            raise ValueError(f"T must be finite and > 0, got {T!r}")
        q = math.pi / 4.0
        return cls.from_terms(
            [-q, q],
            [[(q, 2.0 * math.pi / T, 0.0)], [(-q, 2.0 * math.pi / (T / 2.0), 0.0)]],
            0.0,
        )

    def to_parameters(self) -> dict:
        """Return the parameters in the sidecar's ``trajectory.parameters`` layout.

        Returns
        -------
        dict
            ``{"c": [c_1, ..., c_n], "terms_A_omega_phi": [[[A, omega, phi], ...], [...]],
            "t_ramp_s": t_ramp}`` with plain Python floats; padding terms are
            dropped. ``Trajectory.from_sidecar(traj.to_parameters()) == traj``.
        """
        terms = []
        for j in range(self.c.shape[0]):
            terms.append(
                [
                    [float(self.amplitude[j, i]), float(self.omega[j, i]), float(self.phase[j, i])]
                    for i in range(self.n_terms[j])
                ]
            )
        return {"c": [float(x) for x in self.c], "terms_A_omega_phi": terms, "t_ramp_s": self.t_ramp_s}

    # ---------------------------------------------------------------- evaluation
    def _ramp(self, t: np.ndarray):
        """Ramp w(t) and its first two time derivatives, each shape (n,)."""
        if self.t_ramp_s == 0.0:
            one = np.ones_like(t)
            return one, np.zeros_like(t), np.zeros_like(t)
        tr = self.t_ramp_s
        s = np.clip(t / tr, 0.0, 1.0)
        s2 = s * s
        w = s2 * s * (10.0 + s * (-15.0 + 6.0 * s))
        wd = 30.0 * s2 * (1.0 + s * (-2.0 + s)) / tr  # 30 s^2 (1 - s)^2 / tr
        wdd = 60.0 * s * (1.0 + s * (-3.0 + 2.0 * s)) / (tr * tr)  # 60 s (1-s)(1-2s) / tr^2
        return w, wd, wdd

    def _series(self, t: np.ndarray):
        """Un-ramped series u, u', u'' each of shape (n, n_joints)."""
        # angle[n, j, i] = omega_ji * t_n + phi_ji
        ang = t[:, None, None] * self.omega[None, :, :] + self.phase[None, :, :]
        cos = np.cos(ang)
        sin = np.sin(ang)
        a = self.amplitude[None, :, :]
        u = self.c[None, :] + np.sum(a * cos, axis=2)
        ud = -np.sum(a * self.omega[None, :, :] * sin, axis=2)
        udd = -np.sum(a * (self.omega * self.omega)[None, :, :] * cos, axis=2)
        return u, ud, udd

    @staticmethod
    def _as_times(t) -> np.ndarray:
        t = np.asarray(t, dtype=float)
        if t.ndim == 0:
            t = t.reshape(1)
        if t.ndim != 1:
            raise ValueError(f"t must be a scalar or a 1-D array, got shape {t.shape}")
        return t

    def position(self, t) -> np.ndarray:
        """Reference joint angles.

        Parameters
        ----------
        t : float or array_like, shape (n,)
            Times (s) measured from the start of the run.

        Returns
        -------
        q : ndarray, shape (n, n_joints)
            Joint angles in rad ((q2, q3) for the PUMA links 2-3; n = 1 for a scalar t).
        """
        return self.evaluate(t)[0]

    __call__ = position

    def evaluate(self, t):
        """Reference angles, velocities and accelerations (analytic).

        With ``q = w u`` (ramp ``w``, cosine series ``u``):
        ``qd = w' u + w u'`` and ``qdd = w'' u + 2 w' u' + w u''``.

        Parameters
        ----------
        t : float or array_like, shape (n,)
            Times (s) measured from the start of the run.

        Returns
        -------
        q : ndarray, shape (n, n_joints)
            Joint angles (rad).
        qd : ndarray, shape (n, n_joints)
            Joint velocities (rad/s).
        qdd : ndarray, shape (n, n_joints)
            Joint accelerations (rad/s^2).
        """
        t = self._as_times(t)
        u, ud, udd = self._series(t)
        if self.t_ramp_s == 0.0:
            return u, ud, udd
        w, wd, wdd = self._ramp(t)
        w, wd, wdd = w[:, None], wd[:, None], wdd[:, None]
        q = w * u
        qd = wd * u + w * ud
        qdd = wdd * u + 2.0 * wd * ud + w * udd
        return q, qd, qdd

    # ------------------------------------------------------------------ equality
    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Trajectory):
            return NotImplemented
        return (
            self.t_ramp_s == other.t_ramp_s
            and self.n_terms == other.n_terms
            and np.array_equal(self.c, other.c)
            and np.array_equal(self.amplitude, other.amplitude)
            and np.array_equal(self.omega, other.omega)
            and np.array_equal(self.phase, other.phase)
        )

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        return (
            f"Trajectory(c={self.c.tolist()}, n_terms={self.n_terms}, "
            f"t_ramp_s={self.t_ramp_s}, terms={self.to_parameters()['terms_A_omega_phi']})"
        )
