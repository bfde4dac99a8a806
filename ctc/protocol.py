"""The sampled-controller protocol and the paper's P controller.

A *sampled controller* is any object with

``reset()``
    Forget everything from a previous run (called once before a run).
``__call__(k, t, q_meas, e_pulses) -> ndarray (2,)``
    The motor currents (A) of joints 2 and 3 to apply over
    ``[t_k, t_k + Ts)``, computed at sample ``k`` (time ``t = k Ts``, s) from

    * ``q_meas`` (2,) rad: the quantised joint angles read from the motor
      encoders, ``count * 2 pi / (k N)`` with ``count = trunc(q k N / 2 pi)``;
    * ``e_pulses`` (2,) int: the pulse errors ``ref - act`` as the rig forms
      them, ``trunc(q_ref k N / 2 pi) - count``.

    It is called once per sample, in order (k = 0, 1, 2, ...).

:func:`plant.simulation.closed_loop.simulate_closed_loop` runs any such object against
the model robot; :class:`PController` (the paper's controller, ``i = P e``)
and :class:`ctc.ComputedTorqueController` follow it.
"""
from __future__ import annotations

import copy
import math
from typing import Protocol, runtime_checkable

import numpy as np

__all__ = ["SampledController", "PController", "current_per_pulse"]


@runtime_checkable
class SampledController(Protocol):
    """Structural type of a sampled controller (see the module docstring)."""

    def reset(self) -> None:  # pragma: no cover - protocol
        """Forget the state of a previous run."""

    def __call__(self, k: int, t: float, q_meas: np.ndarray, e_pulses: np.ndarray) -> np.ndarray:  # pragma: no cover
        """Motor currents (2,) A for sample k."""


class PController:
    """The paper's decentralised P position controller, ``i = P e``.

    Parameters
    ----------
    p_gain_A_per_pulse : array_like, shape (n_joints,)
        P gains (A per pulse of error), > 0: joints 2 and 3 of the PUMA
        links 2-3, or one per joint of a robot model's rig.
    current_full_scale_A : float, optional
        The drive's full scale (A, > 0): the currents are clipped at
        ``+-current_full_scale_A`` (issue 21: every controller saturates).
        None: no clip.

    Raises
    ------
    ValueError
        If the gains are not finite positive numbers (at least one), or the
        full scale is not a number > 0.

    Notes
    -----
    Source: the paper's experiment (section 3): the current reference of an
    ideal current loop is ``P e`` with the integer encoder error ``e``,
    computed at ``t_k`` and held over the sample.  It is stateless.
    """

    def __init__(self, p_gain_A_per_pulse, current_full_scale_A=None):
        p = np.asarray(p_gain_A_per_pulse, dtype=np.float64)
        if p.ndim != 1 or p.size < 1 or not np.all(np.isfinite(p)) or np.any(p <= 0):
            raise ValueError("p_gain_A_per_pulse must be finite numbers > 0, one per joint, "
                             f"got {p_gain_A_per_pulse!r}")
        if current_full_scale_A is not None and not (
                isinstance(current_full_scale_A, (int, float)) and current_full_scale_A > 0):
            raise ValueError(f"current_full_scale_A must be a number > 0 (A) or None, "
                             f"got {current_full_scale_A!r}")
        self.p_gain = p
        self.current_full_scale_A = (None if current_full_scale_A is None
                                     else float(current_full_scale_A))

    @classmethod
    def from_log(cls, log) -> "PController":
        """The P controller of a log's rig (``rig.p_gain_A_per_pulse``).

        Parameters
        ----------
        log : plant.ExperimentLog, plant.logs.arm_log.ArmLog or plant.logs.rig.Rig

        Returns
        -------
        PController
        """
        rig = getattr(log, "rig", log)
        return cls(rig.p_gain_A_per_pulse, rig.current_full_scale_A)

    def reset(self) -> None:
        """Nothing to reset (stateless)."""

    def __call__(self, k, t, q_meas, e_pulses) -> np.ndarray:
        """Currents ``P e`` (n_joints,) A from the pulse errors ``e_pulses`` (n_joints,), clipped at full scale."""
        i = self.p_gain * e_pulses
        if self.current_full_scale_A is not None:
            i = np.clip(i, -self.current_full_scale_A, self.current_full_scale_A)
        return i

    def __repr__(self) -> str:
        return (f"PController(p_gain_A_per_pulse={self.p_gain.tolist()}, "
                f"current_full_scale_A={self.current_full_scale_A})")


def current_per_pulse(controller, log, *, trajectory=None, sample=20) -> np.ndarray:
    """The current step (A) a sampled controller commands for one pulse of measurement.

    A loop that tracks within +-1 pulse reads a count that flickers by one
    pulse from sample to sample; the law's current flickers with it by this
    much.  ``Kp`` grows with the loop bandwidth squared and an observer's
    velocity correction times ``Kv`` with its cube, so a fast design on a
    coarse encoder can swing the drive across its range on every pulse
    (a relay, not the linear loop it was designed as).  Measured, not
    derived: a copy of the controller runs the first ``sample`` samples of
    the quantised reference (zero pulse error), then sample
    ``sample`` is evaluated with the reading of each joint moved by one pulse
    up and down; the step is the largest change of that joint's own current
    whose two ends are inside the drive's full scale.  The controller itself
    is not touched (its state is copied).

    Parameters
    ----------
    controller : SampledController
        Any controller of the protocol (its following-error limit, if any,
        is disarmed in the copy).
    log : plant.ExperimentLog or plant.logs.arm_log.ArmLog
        Rig (encoders, sample time, full scale) and, by default, the reference.
    trajectory : plant.logs.trajectory.Trajectory, optional
        The reference the controller was built for (default: the log's).
    sample : int
        The sample at which the step is measured, >= 1.

    Returns
    -------
    ndarray, shape (n_joints,)
        Current step per joint (A per pulse); ``inf`` where every step
        ends at the full scale (the law saturates on one pulse).

    Raises
    ------
    ValueError
        If ``sample`` is not an integer >= 1.
    """
    if not isinstance(sample, (int, np.integer)) or isinstance(sample, bool) or sample < 1:
        raise ValueError(f"sample must be an integer >= 1, got {sample!r}")
    rig = log.rig
    ts = float(rig.sample_time_s)
    ppr = np.asarray(rig.pulses_per_rad, dtype=float)
    fs = math.inf if rig.current_full_scale_A is None else float(rig.current_full_scale_A)
    traj = log.trajectory if trajectory is None else trajectory
    q = np.atleast_2d(traj.position(np.arange(sample + 1) * ts))
    count = np.trunc(q * ppr)  # the encoders read the reference itself: zero pulse error
    c = copy.deepcopy(controller)
    if getattr(c, "following_error", None) is not None:
        c.following_error = None
    c.reset()
    for k in range(sample):
        c(k, k * ts, count[k] / ppr, np.zeros(ppr.size))
    t = sample * ts

    def at(step):
        return np.asarray(copy.deepcopy(c)(sample, t, (count[sample] + step) / ppr, -step), dtype=float)

    base = at(np.zeros(ppr.size))
    inside = np.abs(base) < fs * (1.0 - 1e-12)
    out = np.full(ppr.size, -math.inf)
    for j in range(ppr.size):
        for s in (1.0, -1.0):
            step = np.zeros(ppr.size)
            step[j] = s
            i = at(step)
            if inside[j] and abs(i[j]) < fs * (1.0 - 1e-12):
                out[j] = max(out[j], abs(i[j] - base[j]))
    out[~np.isfinite(out)] = math.inf
    return out
