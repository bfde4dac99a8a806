"""Parameterisations: what an identification searches and how it maps to f.

The output error of paper eq. 4 is a function of the base parameters f1..f9;
what the optimisers search is a vector ``x`` that a *parameterisation* maps
to f.  Three are built in, and a user can write another (subclass
:class:`Parameterisation` and implement :meth:`~Parameterisation.names`,
:meth:`~Parameterisation.bounds` and :meth:`~Parameterisation.to_f`):

* :class:`BaseParameters` -- the nine base parameters themselves, in the
  sidecar's search ranges (the paper's search);
* :class:`ConsistentBaseParameters` -- the structure of eq. 3, ``f3 = a3 f5``
  and ``f4 = a3 f6`` (both are ``m3 x3 a3`` and ``m3 y3 a3``), seven free
  parameters;
* :class:`PayloadParameters` -- a rigid payload at the flange on top of the
  unloaded robot's f (the prior), in physically consistent coordinates
  ``[m, xp, yp, Jc]`` (on-line payload identification).

Pass one as ``identification.identify(log, parameters=...)``.
"""
from __future__ import annotations

import os
from abc import ABC, abstractmethod

import numpy as np

from plant.logs.fileio import read_json_object
from plant.robot.payload import payload_delta_matrix, payload_from_vector
from plant.logs.rig import F_NAMES

__all__ = [
    "Parameterisation",
    "BaseParameters",
    "ConsistentBaseParameters",
    "PayloadParameters",
    "HeldModelChange",
    "prior_f",
    "DEFAULT_PAYLOAD_BOUNDS",
    "check_bounds",
]

#: Search box of the payload in its physically consistent coordinates
#: ``[m (kg), xp (m), yp (m), Jc (kg m^2)]``: mass up to 5 kg (twice the PUMA
#: 560's rated payload), centre of mass in link 3's frame within 1 m of its
#: origin (the flange is ~0.43 m from it along the forearm), and inertia about
#: the payload's own centre of mass of a compact tool (Jc <= 0.05 kg m^2, e.g.
#: a 1.5 kg rod 0.6 m long).
DEFAULT_PAYLOAD_BOUNDS = np.array([[0.0, 5.0], [-1.0, 1.0], [-1.0, 1.0], [0.0, 0.05]])


def check_bounds(bounds, n: int) -> np.ndarray:
    """Validate a search box.

    Parameters
    ----------
    bounds : array_like, shape (n, 2)
        (low, high) per parameter.
    n : int
        Expected number of parameters.

    Returns
    -------
    ndarray, shape (n, 2)

    Raises
    ------
    ValueError
        On a wrong shape, NaN/inf, or an inverted or empty range.
    """
    b = np.asarray(bounds, dtype=float)
    if b.shape != (n, 2):
        raise ValueError(f"bounds must have shape ({n}, 2), got {b.shape}")
    if not np.all(np.isfinite(b)):
        raise ValueError("bounds contain NaN or inf")
    bad = np.flatnonzero(b[:, 0] >= b[:, 1])
    if bad.size:
        i = int(bad[0])
        raise ValueError(f"bounds of parameter {i + 1} are inverted or empty: "
                         f"[{b[i, 0]}, {b[i, 1]}]")
    return b


class Parameterisation(ABC):
    """Base class: the searched vector x, its bounds and names, and its map to f.

    Subclasses implement :meth:`names`, :meth:`bounds` and :meth:`to_f`
    (abstract: a subclass without them cannot be instantiated);
    :meth:`extras`, :meth:`refine_starts` and :meth:`initial_state` have
    defaults (nothing extra, starts from the GA, no nuisance state).

    Attributes
    ----------
    name : str
        Short name recorded in the result (``parameters``).
    """

    name = "custom"

    @abstractmethod
    def names(self, log) -> list:
        """Names of the components of x.

        Parameters
        ----------
        log : plant.ExperimentLog

        Returns
        -------
        list of str, length k
        """

    @abstractmethod
    def bounds(self, log) -> np.ndarray:
        """Search box of x.

        Parameters
        ----------
        log : plant.ExperimentLog

        Returns
        -------
        ndarray, shape (k, 2)
        """

    @abstractmethod
    def to_f(self, x, log) -> np.ndarray:
        """Base parameters f1..f9 of x.

        Parameters
        ----------
        x : ndarray, shape (k,) or (m, k)
        log : plant.ExperimentLog

        Returns
        -------
        ndarray, shape (9,) or (m, 9)
        """

    def extras(self, x, log) -> dict:
        """Extra entries of the result for the identified x (default none).

        Parameters
        ----------
        x : ndarray, shape (k,)
        log : plant.ExperimentLog

        Returns
        -------
        dict
        """
        return {}

    def refine_starts(self, log):
        """Start points of the refinement without a global search (default None: the GA's).

        Parameters
        ----------
        log : plant.ExperimentLog

        Returns
        -------
        ndarray, shape (n_starts, k), or None
        """
        return None

    def initial_state(self, log):
        """Initial state estimated with x as a nuisance (default None: the run's start).

        Parameters
        ----------
        log : plant.ExperimentLog

        Returns
        -------
        (ndarray (4,), ndarray (4, 2)) or None
            Guess and box of (q2, q3, qd2, qd3) at the log's first sample.
        """
        return None

    def plant(self, log):
        """The simulated plant (default None: :data:`plant.simulation.plants.RIGID`).

        Parameters
        ----------
        log : plant.ExperimentLog

        Returns
        -------
        plant.simulation.plants.Plant or None
        """
        return None

    def plant_parameters(self, x, log):
        """Per-candidate plant parameters beyond f (default None).

        Parameters
        ----------
        x : ndarray, shape (m, k)
        log : plant.ExperimentLog

        Returns
        -------
        dict or None
            Keyword arrays of the plant's ``lane_parameters``.
        """
        return None

    def __repr__(self) -> str:
        return f"{type(self).__name__}()"


class BaseParameters(Parameterisation):
    """The nine base parameters f1..f9 (paper eq. 3), searched independently.

    Parameters
    ----------
    bounds : array_like, shape (9, 2), optional
        Search ranges; default the sidecar's (``log.rig.bounds``).

    Raises
    ------
    ValueError
        On malformed bounds.
    """

    name = "base"

    def __init__(self, bounds=None):
        self._bounds = None if bounds is None else check_bounds(bounds, 9)

    def names(self, log) -> list:
        """``['f1', ..., 'f9']``.

        Parameters
        ----------
        log : plant.ExperimentLog
        """
        return list(F_NAMES)

    def bounds(self, log) -> np.ndarray:
        """The given box or the sidecar's ranges, shape (9, 2).

        Parameters
        ----------
        log : plant.ExperimentLog

        Raises
        ------
        ValueError
            On malformed sidecar ranges.
        """
        return check_bounds(log.rig.bounds if self._bounds is None else self._bounds, 9)

    def to_f(self, x, log) -> np.ndarray:
        """f = x.

        Parameters
        ----------
        x : ndarray, shape (9,) or (m, 9)
        log : plant.ExperimentLog
        """
        return np.asarray(x, dtype=float)


#: The searched f of :class:`ConsistentBaseParameters` (0-based indices of
#: f1, f2, f5, f6, f7, f8, f9).
CONSISTENT_F = (0, 1, 4, 5, 6, 7, 8)


class ConsistentBaseParameters(BaseParameters):
    """The base parameters with eq. 3's structure ``f3 = a3 f5``, ``f4 = a3 f6``.

    Both pairs are ``m3 x3 a3`` and ``m3 y3 a3``; ``a3`` comes from the
    sidecar.  Searches f1, f2, f5, f6, f7, f8, f9 (their rows of the box).
    On a flexible robot it keeps the unmodelled compliance from pulling f4
    away from a3 f6.

    Parameters
    ----------
    bounds : array_like, shape (9, 2), optional
        Ranges of f1..f9 (rows 3 and 4 unused); default the sidecar's.

    Raises
    ------
    ValueError
        On malformed bounds.
    """

    name = "consistent"

    def names(self, log) -> list:
        """``['f1', 'f2', 'f5', 'f6', 'f7', 'f8', 'f9']``.

        Parameters
        ----------
        log : plant.ExperimentLog
        """
        return [F_NAMES[i] for i in CONSISTENT_F]

    def bounds(self, log) -> np.ndarray:
        """Rows f1, f2, f5, f6, f7, f8, f9 of the box, shape (7, 2).

        Parameters
        ----------
        log : plant.ExperimentLog
        """
        return BaseParameters.bounds(self, log)[list(CONSISTENT_F)]

    def to_f(self, x, log) -> np.ndarray:
        """f with f3 = a3 f5 and f4 = a3 f6.

        Parameters
        ----------
        x : ndarray, shape (7,) or (m, 7)
        log : plant.ExperimentLog
        """
        x = np.asarray(x, dtype=float)
        f = np.zeros(x.shape[:-1] + (9,))
        f[..., list(CONSISTENT_F)] = x
        f[..., 2] = log.rig.a3_m * x[..., 2]
        f[..., 3] = log.rig.a3_m * x[..., 3]
        return f


def prior_f(prior) -> np.ndarray:
    """The unloaded robot's f1..f9 from any form a prior comes in.

    Parameters
    ----------
    prior : IdentificationResult, dict, str, os.PathLike or array_like
        A result (its ``f``), a result's JSON as a dict or a path to that
        file (``IdentificationResult.save_json``, the CLI's ``--output``), or
        the nine numbers themselves.

    Returns
    -------
    ndarray, shape (9,)

    Raises
    ------
    ValueError
        If the prior is missing, the file cannot be read, or it does not hold
        nine finite numbers.
    """
    if prior is None:
        raise ValueError("payload identification needs prior= (the unloaded robot's f)")
    where = ""
    if isinstance(prior, (str, os.PathLike)):
        where = f"{prior}: "
        prior = read_json_object(prior, "prior result file")
    f = prior.get("f") if isinstance(prior, dict) else getattr(prior, "f", prior)
    if isinstance(f, (list, tuple)) and any(isinstance(v, bool) for v in f):
        f = None  # true/false are not numbers here, although numpy would take them
    try:
        f = np.asarray(f, dtype=float)
    except (TypeError, ValueError):
        f = np.empty(0)
    if f.shape != (9,) or not np.all(np.isfinite(f)):
        raise ValueError(f"{where}prior must hold 9 finite numbers f1..f9 (a result's key 'f'), "
                         f"got shape {f.shape}")
    return f


class PayloadParameters(Parameterisation):
    """A rigid payload at the flange on top of the unloaded robot's f.

    Searches ``x = [m, xp, yp, Jc]`` (mass, centre of mass in link 3's frame,
    inertia about the payload's own centre of mass), mapped to the linear
    payload vector ``p = [m, m xp, m yp, Jc + m (xp^2 + yp^2)]``
    (parallel-axis theorem) and to ``f = f_prior + M(a3) p``
    (:func:`plant.robot.payload.payload_delta_matrix`).  Every candidate is thus a
    rigid body with ``Jc >= 0`` (physical consistency; Wensing, Kim and
    Slotine, IEEE RA-L 3(1), 2018).  The refinement starts from four spread
    payloads without a GA, and the state at the log's first sample is
    estimated with x (window logs).

    Parameters
    ----------
    prior : IdentificationResult, dict, str, os.PathLike or array_like
        The unloaded robot's f, in any form :func:`prior_f` takes.
    bounds : array_like, shape (4, 2), optional
        Box of ``[m, xp, yp, Jc]`` (default :data:`DEFAULT_PAYLOAD_BOUNDS`).

    Raises
    ------
    ValueError
        On a prior that is not 9 finite numbers, or malformed bounds.
    """

    name = "payload"
    #: Relative cost decrease at which a refinement start has converged: the
    #: payload moves by < 1e-5 of its box below it (measured), and an
    #: on-line identification must be fast.
    refine_ftol = 1e-6

    def __init__(self, prior, bounds=None):
        self.prior_f = prior_f(prior)
        self._bounds = check_bounds(DEFAULT_PAYLOAD_BOUNDS if bounds is None else bounds, 4)

    def names(self, log) -> list:
        """``['m_kg', 'xp_m', 'yp_m', 'Jc_kgm2']``.

        Parameters
        ----------
        log : plant.ExperimentLog
        """
        return ["m_kg", "xp_m", "yp_m", "Jc_kgm2"]

    def bounds(self, log) -> np.ndarray:
        """The payload box, shape (4, 2).

        Parameters
        ----------
        log : plant.ExperimentLog
        """
        return self._bounds

    @staticmethod
    def linear(x) -> np.ndarray:
        """The linear payload vector ``p = [m, m xp, m yp, Jc + m (xp^2 + yp^2)]``.

        Parameters
        ----------
        x : ndarray, shape (4,) or (m, 4)

        Returns
        -------
        ndarray, same shape
        """
        x = np.asarray(x, dtype=float)
        m, xp, yp, jc = (x[..., i] for i in range(4))
        return np.stack([m, m * xp, m * yp, jc + m * (xp * xp + yp * yp)], axis=-1)

    def to_f(self, x, log) -> np.ndarray:
        """``f_prior + M(a3) p(x)``.

        Parameters
        ----------
        x : ndarray, shape (4,) or (m, 4)
        log : plant.ExperimentLog
        """
        return self.prior_f + self.linear(x) @ payload_delta_matrix(log.rig.a3_m).T

    def extras(self, x, log) -> dict:
        """``payload`` (mass, COM, inertia, linear vector) and ``prior_f``.

        Parameters
        ----------
        x : ndarray, shape (4,)
        log : plant.ExperimentLog
        """
        p = self.linear(x)
        if p[0] > 0:
            pl = payload_from_vector(p, clip_negative_inertia=True)
            mass, com, izz = pl.mass_kg, list(pl.com_m), pl.izz_kgm2
        else:  # no payload (mass at its lower bound 0): no centre of mass to recover
            mass, com, izz = 0.0, [0.0, 0.0], float(max(x[3], 0.0))
        return dict(payload=dict(mass_kg=mass, com_m=com, izz_kgm2=izz,
                                 vector=[float(v) for v in p],
                                 vector_names=["m_kg", "m_xp_kgm", "m_yp_kgm", "J_kgm2"]),
                    prior_f=self.prior_f)

    def refine_starts(self, log) -> np.ndarray:
        """Light and heavy payloads, COM near the axis and along link 3, compact and not.

        Parameters
        ----------
        log : plant.ExperimentLog
        """
        lo, hi = self._bounds[:, 0], self._bounds[:, 1]
        return lo + (hi - lo) * np.array([[0.1, 0.5, 0.35, 0.2], [0.4, 0.5, 0.35, 0.2],
                                          [0.2, 0.6, 0.2, 0.5], [0.6, 0.4, 0.65, 0.5]])

    def initial_state(self, log):
        """Guess and box of the state at the log's first sample.

        Estimated from the window itself
        (:func:`identification.window.estimate_initial_state`: positions
        from the counts within their pulse cell, velocities from the
        reference and the error trend; no quantised simulation before a
        window, which would not be smooth in the payload); box +-2 pulses and
        +-(20 % of the reference rate + 0.05 rad/s).

        Parameters
        ----------
        log : plant.ExperimentLog
        """
        from .window import estimate_initial_state

        return estimate_initial_state(log)

    def model_initial_state(self, log):
        """Guess and box of the start state for the model in use (the rigid plant's:
        :meth:`initial_state`).

        Parameters
        ----------
        log : plant.ExperimentLog
        """
        return self.initial_state(log)

    def __repr__(self) -> str:
        return f"PayloadParameters(prior_f={np.round(self.prior_f, 4).tolist()})"


class HeldModelChange(Parameterisation):
    """A change of a window's plant with the robot's f held: the adaptive CTC's rival hypotheses.

    The base of :class:`identification.friction.FrictionChangeParameters` and
    :class:`identification.flexible.DriveChangeParameters` (:mod:`ctc.adaptive`,
    supervisor step 3): every candidate keeps the model in use, ``f``; the
    window's start state (guess and box) is the wrapped payload space's, so
    the rival and the payload estimate start alike.  Subclasses give the
    names, box, plant and plant parameters of their change.

    Parameters
    ----------
    space : Parameterisation
        The window's payload parameterisation (of :attr:`space_type`).
    f : array_like, shape (9,)
        The model in use (rigid-equivalent base parameters f1..f9).

    Raises
    ------
    ValueError
        On a ``space`` that is not a :attr:`space_type`, or an ``f`` that is
        not 9 finite numbers.
    """

    #: as the payload's (:attr:`PayloadParameters.refine_ftol`)
    refine_ftol = 1e-6
    #: the payload parameterisations the change wraps
    space_type = Parameterisation

    def __init__(self, space, f):
        if not isinstance(space, self.space_type):
            t = self.space_type
            raise ValueError(f"space must be an {t.__module__.rsplit('.', 1)[0]}.{t.__name__}")
        self.space = space
        self.f = np.asarray(f, dtype=float).reshape(-1)
        if self.f.shape != (9,) or not np.all(np.isfinite(self.f)):
            raise ValueError("f must be 9 finite numbers")

    def to_f(self, x, log) -> np.ndarray:
        """The model in use, for every candidate.

        Parameters
        ----------
        x : ndarray, shape (k,) or (m, k)
        log : plant.ExperimentLog

        Returns
        -------
        ndarray, shape (9,) or (m, 9)
        """
        x = np.asarray(x, dtype=float)
        return np.broadcast_to(self.f, x.shape[:-1] + (9,)).copy()

    def initial_state(self, log):
        """The wrapped space's start state (guess, box) on the window.

        Parameters
        ----------
        log : plant.ExperimentLog
        """
        return self.space.initial_state(log)

    def __repr__(self) -> str:
        return f"{type(self).__name__}(space={self.space!r})"
