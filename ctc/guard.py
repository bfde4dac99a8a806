"""A following-error limit: fall back to the rig's own P law when a controller loses the arm.

A computed-torque controller is only as good as its model.  When the robot
changes in a way the model does not describe (a heavy tool picked up by a
flexible-joint robot, a model identified badly) its tracking error can grow
far beyond what the rig's own decentralised P law ever produced -- the
controller is then *less* safe than the one it replaced.  Industrial drives
guard against this with a *following-error limit*: the axis faults when
``|q_ref - q|`` exceeds a set bound.  Here the bound trips a fallback rather
than a fault: from the first sample at which any joint's pulse error exceeds
its limit, the controller is replaced by the rig's P law ``i = P e`` (the
paper's controller, the one the robot was logged under and known to be
stable with), clipped at the drive's full scale, until :meth:`reset`.

The limit of each joint is twice the largest pulse error of the log the
controller was built from -- the P law's own following error along the
logged reference -- but at least :data:`MIN_LIMIT_PULSES`.  It is the
library's one definition of a loop that has lost the arm: the bound of the
flexible-joint design's robustness check
(:func:`ctc.flexible.robustness_check`, :func:`lost_bound`).  The limit
guards against a runaway, not a transient.  After a change the robot does
not model (twice the drive damping, a heavier tool) even the P law leaves
its own logged errors, and a computed-torque controller that does too for
a moment and then recovers still tracks far better than the P law would.
Measured on the changes benchmark (``benchmarks/bench_changes.py``, 57
random changes on the independent simulator): a limit at the log's
largest error itself handed 13 of the 114 static and adaptive runs to the
P law, and 8 of them ended worse than the same controller had without a
limit in the benchmark's previous run (up to 72 / 42 pulses where it held
12 / 31).
A runaway passes any such bound within a few samples (a flexible-joint CTC
with its stiffness 3x off runs the drill log's compliant arm to 616 / 941
pulses unguarded; with the limit, 108 / 94, it hands over at 0.14 s and
peaks at 122 / 110), and the rig's P law then holds the arm within twice
the limit (``tests/test_guard.py``).

Every computed-torque controller built from an identification result
carries the limit (:meth:`ctc.ComputedTorqueController.from_result`,
:meth:`ctc.arm.ArmComputedTorque.from_result`), and so does
:class:`ctc.AdaptiveComputedTorqueController` (``following_error_limit=``)
around its inner controller; :class:`FollowingErrorGuard` wraps any other
sampled controller (:mod:`ctc.protocol`).
"""
from __future__ import annotations

import math
import warnings

import numpy as np

__all__ = ["FollowingErrorGuard", "FollowingErrorLimit", "FollowingErrorWarning",
           "MIN_LIMIT_PULSES", "LIMIT_FACTOR", "lost_bound", "as_limit"]

#: The default limit is this many times the log's largest P-law error per joint.
LIMIT_FACTOR = 2

#: Smallest default limit (pulses): a log whose P law never left a few pulses
#: must not trip the limit on a computed-torque controller's own transients.
MIN_LIMIT_PULSES = 20


def lost_bound(e_pulses) -> np.ndarray:
    """Pulses per joint beyond which a loop has lost the arm: ``max(2 max|e|, 20)``.

    Parameters
    ----------
    e_pulses : array_like, shape (n_samples, n_joints)
        The pulse errors of the P-controlled log.

    Returns
    -------
    ndarray, shape (n_joints,)
        :data:`LIMIT_FACTOR` times the largest ``|e|`` per joint, at least
        :data:`MIN_LIMIT_PULSES`.

    Raises
    ------
    ValueError
        If ``e_pulses`` is not two-dimensional.
    """
    e = np.abs(np.asarray(e_pulses, dtype=float))
    if e.ndim != 2:
        raise ValueError(f"e_pulses must have shape (n_samples, n_joints), got {e.shape}")
    top = e.max(axis=0) if e.shape[0] else np.zeros(e.shape[1])
    return np.maximum(LIMIT_FACTOR * top, MIN_LIMIT_PULSES)


class FollowingErrorWarning(RuntimeWarning):
    """A controller's following error passed its limit: the rig's P law took over."""


class FollowingErrorLimit:
    """Per-joint following-error limit and the rig's P law it falls back to.

    Parameters
    ----------
    log : plant.ExperimentLog, plant.logs.arm_log.ArmLog or plant.Rig
        The log the controller was built from: its rig (P gains, current
        full scale) and, for ``limit_pulses='log'``, its pulse errors; or
        a rig alone, with the limit given in pulses.
    limit_pulses : 'log', float or array_like, shape (n_joints,)
        Limit per joint (pulses, > 0).  ``'log'`` (default):
        :func:`lost_bound` of the log, twice its largest ``|e|`` per joint,
        at least :data:`MIN_LIMIT_PULSES`.

    Attributes
    ----------
    limit_pulses : ndarray, shape (n_joints,)
        The limit per joint (pulses; read-only: build a new limit to change it).
    p_gain : ndarray, shape (n_joints,)
        The rig's P gains (A per pulse).
    current_limit : float
        The drive's full scale (A; ``inf`` when the sidecar gives none).

    Raises
    ------
    ValueError
        If a given limit is not finite and > 0, or has the wrong length;
        ``'log'`` without a log; ``log`` neither a log nor a rig.
    """

    def __init__(self, log, limit_pulses="log"):
        rig = getattr(log, "rig", log)
        if not hasattr(rig, "p_gain_A_per_pulse"):
            raise ValueError("log must be a plant log (or a rig for a limit in pulses), got "
                             f"{type(log).__name__}")
        self.p_gain = np.asarray(rig.p_gain_A_per_pulse, dtype=float).reshape(-1)
        n = self.p_gain.size
        fs = rig.current_full_scale_A
        self.current_limit = math.inf if fs is None else float(fs)
        if isinstance(limit_pulses, str):
            if limit_pulses != "log":
                raise ValueError(f"limit_pulses must be 'log' or pulses > 0, got {limit_pulses!r}")
            if not hasattr(log, "e_pulses"):
                raise ValueError("limit_pulses='log' needs the log (its pulse errors), not a rig")
            lim = lost_bound(log.e_pulses)
        else:
            try:
                lim = np.broadcast_to(np.asarray(limit_pulses, dtype=float), (n,)).copy()
            except (TypeError, ValueError):
                raise ValueError(f"limit_pulses must be 'log' or {n} numbers > 0 (pulses), "
                                 f"got {limit_pulses!r}") from None
            if not np.all(np.isfinite(lim)) or np.any(lim <= 0):
                raise ValueError(f"limit_pulses must be finite numbers > 0 (pulses), got {limit_pulses!r}")
        lim.setflags(write=False)  # read-only: the per-sample check keeps its own copy
        self.limit_pulses = lim
        self._limits = tuple(float(v) for v in lim)

    def exceeded(self, e_pulses) -> bool:
        """True when any joint's ``|e|`` is above its limit.

        Parameters
        ----------
        e_pulses : array_like, shape (n_joints,)

        Returns
        -------
        bool
        """
        # called every sample ahead of the controller: a plain loop over a few joints
        # costs a fifth of the array expression
        values = e_pulses.tolist() if type(e_pulses) is np.ndarray else list(e_pulses)
        return any(abs(v) > lim for v, lim in zip(values, self._limits))

    def p_current(self, e_pulses) -> np.ndarray:
        """The rig's P law ``clip(P e, -I_fs, I_fs)`` (n_joints,) A.

        Parameters
        ----------
        e_pulses : array_like, shape (n_joints,)

        Returns
        -------
        ndarray, shape (n_joints,)
        """
        return np.clip(self.p_gain * np.asarray(e_pulses, dtype=float),
                       -self.current_limit, self.current_limit)

    def hold(self, holder, t, e_pulses):
        """The P law's currents once the limit has tripped, else None (a controller's first step).

        Trips the limit -- sets ``holder.fallback_t_s`` and warns once --
        when ``|e|`` first passes it.

        Parameters
        ----------
        holder : object
            The controller; its ``fallback_t_s`` (None: not tripped) is read and set.
        t : float
            Time (s).
        e_pulses : array_like, shape (n_joints,)

        Returns
        -------
        ndarray, shape (n_joints,), or None
            ``clip(P e, -I_fs, I_fs)`` (A) from the trip on; None while the
            controller's own law is in charge.

        Warns
        -----
        FollowingErrorWarning
            When the limit trips.
        """
        if holder.fallback_t_s is None:
            if not self.exceeded(e_pulses):
                return None
            holder.fallback_t_s = float(t)
            warnings.warn(f"{type(holder).__name__}: {self.message(t, e_pulses)}",
                          FollowingErrorWarning, stacklevel=3)
        return self.p_current(e_pulses)

    def message(self, t, e_pulses) -> str:
        """One line saying what tripped and what runs now.

        Parameters
        ----------
        t : float
            Time (s).
        e_pulses : array_like, shape (n_joints,)

        Returns
        -------
        str
        """
        e = np.asarray(e_pulses).astype(int).tolist()
        return (f"following error {e} pulses at t = {t:.3f} s exceeds the limit "
                f"{np.round(self.limit_pulses, 1).tolist()}: the model does not fit this robot; "
                "the rig's P law holds the arm from here on (i = P e; reset() to try the model "
                "again)")


def as_limit(limit, log):
    """A controller's ``following_error_limit`` option as a :class:`FollowingErrorLimit` or None.

    Parameters
    ----------
    limit : None, 'log', float, array_like (n_joints,) or FollowingErrorLimit
        None: no limit; ``'log'`` or pulses: :class:`FollowingErrorLimit`
        of ``log``; a limit: itself.
    log : plant.ExperimentLog or plant.logs.arm_log.ArmLog

    Returns
    -------
    FollowingErrorLimit or None

    Raises
    ------
    ValueError
        As :class:`FollowingErrorLimit`.
    """
    if limit is None or isinstance(limit, FollowingErrorLimit):
        return limit
    return FollowingErrorLimit(log, limit)


class FollowingErrorGuard:
    """Any sampled controller behind a following-error limit (see the module docstring).

    Parameters
    ----------
    controller : SampledController
        The controller to guard (``reset()``, ``__call__(k, t, q_meas, e_pulses)``).
    log : plant.ExperimentLog or plant.logs.arm_log.ArmLog
        Its log (rig and, by default, the limit).
    limit_pulses : 'log', float or array_like, shape (n_joints,)
        See :class:`FollowingErrorLimit`.

    Attributes
    ----------
    controller : SampledController
    limit : FollowingErrorLimit
    fallback_t_s : float or None
        When the P law took over (None: never).
    events : list of dict
        ``t_s``, ``kind`` (``'fallback'``), ``message``.

    Raises
    ------
    ValueError
        On a bad limit.

    Warns
    -----
    FollowingErrorWarning
        When the limit trips (once per run).

    Examples
    --------
    >>> import ctc, plant
    >>> log = plant.load_example()
    >>> guarded = ctc.FollowingErrorGuard(ctc.ComputedTorqueController.from_log(
    ...     [0.3, 0.3, 0.01, -0.5, 0.02, -1.0, 3.0, -0.1, 4.0], log), log)
    >>> guarded.limit.limit_pulses.shape
    (2,)
    """

    def __init__(self, controller, log, *, limit_pulses="log"):
        if not (callable(controller) and callable(getattr(controller, "reset", None))):
            raise ValueError("controller must follow the sampled-controller protocol "
                             "(reset() and __call__(k, t, q_meas, e_pulses))")
        self.controller = controller
        self.limit = FollowingErrorLimit(log, limit_pulses)
        self.reset()

    def reset(self) -> None:
        """Reset the guarded controller and re-arm the limit."""
        self.controller.reset()
        self.fallback_t_s = None
        self.events = []

    def __call__(self, k, t, q_meas, e_pulses) -> np.ndarray:
        """Currents (n_joints,) A: the guarded controller's, or the P law's once tripped.

        Parameters
        ----------
        k : int
        t : float
        q_meas : ndarray, shape (n_joints,)
        e_pulses : ndarray, shape (n_joints,)

        Returns
        -------
        ndarray, shape (n_joints,)
        """
        was = self.fallback_t_s
        i = self.limit.hold(self, t, e_pulses)
        if i is None:
            return self.controller(k, t, q_meas, e_pulses)
        if was is None:
            self.events.append(dict(t_s=float(t), kind="fallback",
                                    message=self.limit.message(t, e_pulses)))
        return i

    def __repr__(self) -> str:
        state = "armed" if self.fallback_t_s is None else f"tripped at {self.fallback_t_s:.3f} s"
        return f"FollowingErrorGuard({self.controller!r}, limit {self.limit.limit_pulses.tolist()}, {state})"
