"""A following-error limit: fall back to the rig's own P law when a controller loses the arm.

A computed-torque controller is only as good as its model.  When the robot
changes in a way the model does not describe (a heavy tool picked up by a
flexible-joint robot, a model identified badly) its tracking error can grow
far beyond what the rig's own decentralised P law ever produced -- the
controller is then *less* safe than the one it replaced.  Industrial drives
guard against this with a *following-error limit*: the axis faults when
``|q_ref - q|`` exceeds a set bound.  Here the bound trips a fallback rather
than a fault: from the sample at which the limit trips, the controller is
replaced by the rig's P law ``i = P e`` (the paper's controller, the one the
robot was logged under and known to be stable with), clipped at the drive's
full scale, until :meth:`reset`.

The limit trips as drives' following-error monitoring does, on a level and
a time: at once when any joint's error passes :data:`HARD_FACTOR` times its
limit, or once errors beyond the limit itself add up to more than
:data:`DWELL_S` within the last :data:`DWELL_WINDOW_S` (the samples with
some joint beyond its limit, each counted for one sample time).  A lost
loop does one or the other: an unstable one grows through twice the limit
within a few of its own time constants, a limit cycle or a drift stays
beyond the limit.  A transient of a loop that has not been lost does
neither: after a change its model does not describe -- a tool grabbed, a
few samples at the drive's full scale on a reference the arm cannot quite
follow -- a computed-torque loop of 28.6 Hz or more (its time constant 5.6
ms or less, :mod:`ctc.design`) is back inside the limit within a few time
constants.  Tripping on the level alone handed such transients to the P
law for good: on the sixth draw of the changes benchmark (seed 20261327,
case 0025, a flexible arm carrying 2.34 kg along a multisine) the adaptive
CTC's error after a pick-up peaks at 101 pulses for a limit of 92 and is
beyond the limit for 10 ms, and the true model switched in at the pick-up
(the benchmark's oracle) is beyond it for 10 ms, peaking at 99, after a few
samples at full scale 0.8 s later; the first sample beyond the limit handed
both to the P law, which then held the arm at 88 / 40 and 92 / 40
pulses from 0.5 s after the put-down, where the same controllers, left in
charge, track within 1 / 1 (``docs/figures/changes_20261327_before_model_choice_run.txt``,
this rule's run, against ``..._before_dwell_run.txt``).

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
pulses unguarded; with the limit, 108 / 94, it passes twice the limit and
hands over at 0.17 s, peaking at 179 / 189 -- at 0.14 s and 122 / 110 when
the first sample beyond the limit tripped it), and the rig's P law then
holds the arm near its own logged errors (``tests/test_guard.py``).

Every computed-torque controller built from an identification result
carries the limit (:meth:`ctc.ComputedTorqueController.from_result`,
:meth:`ctc.arm.ArmComputedTorque.from_result`), and so does
:class:`ctc.AdaptiveComputedTorqueController` (``following_error_limit=``)
around its inner controller; :class:`FollowingErrorGuard` wraps any other
sampled controller (:mod:`ctc.protocol`).
"""
from __future__ import annotations

import collections
import math
import reprlib
import warnings

import numpy as np

__all__ = ["FollowingErrorGuard", "FollowingErrorLimit", "FollowingErrorWarning",
           "MIN_LIMIT_PULSES", "LIMIT_FACTOR", "HARD_FACTOR", "DWELL_S", "DWELL_WINDOW_S",
           "lost_bound", "as_limit"]

#: The default limit is this many times the log's largest P-law error per joint.
LIMIT_FACTOR = 2

#: Smallest default limit (pulses): a log whose P law never left a few pulses
#: must not trip the limit on a computed-torque controller's own transients.
MIN_LIMIT_PULSES = 20

#: The limit trips at once where an error passes this many times the limit.
HARD_FACTOR = 2

#: Time (s) beyond the limit, within the last :data:`DWELL_WINDOW_S`, after which it trips:
#: 3.6 time constants of the default computed-torque loop (28.6 Hz, :mod:`ctc.design`).
DWELL_S = 0.02

#: The window (s) over which time beyond the limit is added up.
DWELL_WINDOW_S = 0.1


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
    """A controller's following-error limit tripped (:class:`FollowingErrorLimit`): the rig's P law took over."""


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
    dwell_s : float
        Time beyond the limit (s, >= 0), within the last ``window_s``, after
        which the limit trips (default :data:`DWELL_S`; 0: the first sample
        beyond the limit trips it).
    window_s : float
        The window (s, at least ``dwell_s`` plus one sample time) over which
        that time is added up (default :data:`DWELL_WINDOW_S`).
    hard_factor : float
        The limit trips at once where an error passes this many times the
        limit (>= 1; default :data:`HARD_FACTOR`).

    Attributes
    ----------
    limit_pulses : ndarray, shape (n_joints,)
        The limit per joint (pulses; read-only: build a new limit to change it).
    dwell_s, window_s, hard_factor : float
        As given.
    sample_time_s : float
        The rig's sample time (s): each sample beyond the limit counts for it.
    p_gain : ndarray, shape (n_joints,)
        The rig's P gains (A per pulse).
    current_limit : float
        The drive's full scale (A; ``inf`` when the sidecar gives none).

    Raises
    ------
    ValueError
        If a given limit is not finite and > 0, or has the wrong length;
        ``'log'`` without a log; ``log`` neither a log nor a rig; a bad
        ``dwell_s``, ``window_s`` or ``hard_factor``.
    """

    def __init__(self, log, limit_pulses="log", *, dwell_s=DWELL_S, window_s=DWELL_WINDOW_S,
                 hard_factor=HARD_FACTOR):
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
        values = {}
        for name, v in (("dwell_s", dwell_s), ("window_s", window_s), ("hard_factor", hard_factor)):
            if isinstance(v, (str, bytes, bool)) or not isinstance(v, (int, float, np.integer, np.floating)):
                raise ValueError(f"{name} must be a number, got {reprlib.repr(v)}")
            values[name] = float(v)
        dwell_s, window_s, hard_factor = values["dwell_s"], values["window_s"], values["hard_factor"]
        ts = float(rig.sample_time_s)
        if not (math.isfinite(dwell_s) and dwell_s >= 0.0):
            raise ValueError(f"dwell_s must be a finite number >= 0 (s), got {dwell_s!r}")
        if not (math.isfinite(window_s) and window_s >= dwell_s + ts):
            raise ValueError(f"window_s must be finite and at least dwell_s + one sample time "
                             f"= {dwell_s + ts:.6g} s, got {window_s!r}")
        if not (math.isfinite(hard_factor) and hard_factor >= 1.0):
            raise ValueError(f"hard_factor must be a finite number >= 1, got {hard_factor!r}")
        self.dwell_s, self.window_s, self.hard_factor = dwell_s, window_s, hard_factor
        self.sample_time_s = ts

    def exceeded(self, e_pulses, factor=1.0) -> bool:
        """True when any joint's ``|e|`` is above ``factor`` times its limit.

        Parameters
        ----------
        e_pulses : array_like, shape (n_joints,)
        factor : float
            Multiple of the limit (1: the limit itself).

        Returns
        -------
        bool
        """
        # called every sample ahead of the controller: a plain loop over a few joints
        # costs a fifth of the array expression
        values = e_pulses.tolist() if type(e_pulses) is np.ndarray else list(e_pulses)
        return any(abs(v) > factor * lim for v, lim in zip(values, self._limits))

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

    def trips(self, holder, t, e_pulses) -> bool:
        """Whether the limit trips at this sample (call once per sample, in time order).

        True when some joint's ``|e|`` passes ``hard_factor`` times its
        limit, or when, with this sample, the samples with some joint beyond
        its limit add up (one rig sample time each) to more than ``dwell_s``
        within the last ``window_s``.  The times beyond the limit are kept
        on ``holder`` (``_following_above``, which its ``reset()`` clears);
        a time earlier than the last one kept (a new run) starts them
        afresh, and the same time again counts once.

        Parameters
        ----------
        holder : object
            The controller whose samples are counted.
        t : float
            Time (s).
        e_pulses : array_like, shape (n_joints,)
            Pulse errors of this sample.

        Returns
        -------
        bool
            Whether the limit trips at this sample.
        """
        if not self.exceeded(e_pulses):
            return False
        if self.exceeded(e_pulses, self.hard_factor):
            return True
        above = getattr(holder, "_following_above", None)
        if above is None or (above and above[-1] > t):
            above = collections.deque()
            holder._following_above = above
        if not above or above[-1] != t:
            above.append(float(t))
        while above and above[0] <= t - self.window_s + 0.5 * self.sample_time_s:
            above.popleft()
        return len(above) * self.sample_time_s > self.dwell_s + 1e-12

    def hold(self, holder, t, e_pulses):
        """The P law's currents once the limit has tripped, else None (a controller's first step).

        Trips the limit -- sets ``holder.fallback_t_s`` and warns once --
        at the first sample at which :meth:`trips` says so.

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
            if not self.trips(holder, t, e_pulses):
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
        lim = np.round(self.limit_pulses, 1).tolist()
        if self.exceeded(e_pulses, self.hard_factor):
            what = f"beyond {self.hard_factor:g} x the limit {lim}"
        elif self.dwell_s > 0.0:
            what = (f"beyond the limit {lim} for more than {1e3 * self.dwell_s:g} ms of the "
                    f"last {1e3 * self.window_s:g} ms")
        else:
            what = f"beyond the limit {lim}"
        return (f"following error {e} pulses at t = {t:.3f} s, {what}: "
                "the model does not fit this robot; "
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
        self._following_above = None  # the samples beyond the limit (ctc.guard)
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
