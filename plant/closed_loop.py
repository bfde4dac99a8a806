"""Closed-loop simulation of the rig with any sampled controller.

:func:`simulate_closed_loop` runs the robot (rigid by default, or the
two-mass flexible-joint robot of :class:`plant.plants.FlexibleJoints`) under
a controller that follows the sampled-controller protocol of :mod:`ctc`
(``reset()`` and ``__call__(k, t, q_meas, e_pulses) -> (2,)`` A).  It is a
driver of the one closed-loop core (:mod:`plant.core`) with one lane; at
each sample ``t_k = k Ts``, exactly as the rig's control card and
:func:`plant.simulate_experiment` do:

1. the motor encoders are read (:func:`plant.core.encoder_read`,
   ``act = trunc(q k N / 2 pi)``) and the quantised joint angles
   ``q_meas = act 2 pi / (k N)`` are formed;
2. the integer error ``e = ref - act`` with
   ``ref = trunc(q_ref(t_k) k N / 2 pi)`` is formed;
3. the controller returns the motor currents ``i`` (A), clipped to
   ``[-I_fs, I_fs]`` when the rig's sidecar gives a ``current_full_scale_A``
   (the recorded ``i_A`` is the clipped current that was applied; the
   library's controllers saturate there themselves, with anti-windup, and
   ``n_clipped`` counts the samples at the limit);
4. the current is held over ``[t_k, t_k + Ts)`` (ZOH, no computation delay)
   and the plant is advanced by :func:`plant.core.advance_sample`.

With the paper's P controller this is the logged experiment itself: the
pulses equal :func:`plant.simulate_experiment`'s bit for bit (tested).  The
robot's true parameters ``f_robot`` are independent of whatever model the
controller uses, so model errors can be studied.

The loop over samples is plain Python (the controller is an arbitrary
Python object); the sample step is compiled.  The quantised loop is chaotic
at the pulse level: two runs that differ by rounding errors of 1e-16 agree
for a while and then differ by single pulses at scattered samples.  Use
enough RK4 substeps (24-48; default :data:`DEFAULT_CLOSED_LOOP_SUBSTEPS`)
when pulses must be reproduced.
"""
from __future__ import annotations

import math

import numpy as np

from .anchors import REANCHOR
from .core import STATUS_MESSAGES, STATUS_OK, advance_sample, encoder_read
from .plants import RIGID, FlexibleJoints  # noqa: F401 (re-exported for older code)
from .response import ClosedLoopResponse
from .rig import rig_constants
from .simulate import dummy_problem, kernel, check_substeps, new_lanes
from .model import checked_f, is_positive_definite

# ClosedLoopResponse (plant.response) and FlexibleJoints (plant.plants) are
# importable from here too, for older code; they are documented where defined.
__all__ = [
    "DEFAULT_CLOSED_LOOP_SUBSTEPS",
    "simulate_closed_loop",
]

#: RK4 substeps per sample used by default.  The rigid closed loop's pulses
#: converge at 24-48 substeps (see :mod:`plant.simulate`); 32 is in that range.
DEFAULT_CLOSED_LOOP_SUBSTEPS = 32


@kernel
def _read(X, enc, c, r2, r3):
    """Encoder counts and pulse errors of lane 0: (act2, act3, e2, e3)."""
    _, a2 = encoder_read(X[enc, 0], c.pulses_per_rad[0])
    _, a3 = encoder_read(X[enc + 1, 0], c.pulses_per_rad[1])
    _, t2 = encoder_read(r2, 1.0)
    _, t3 = encoder_read(r3, 1.0)
    return a2, a3, t2 - a2, t3 - a3


@kernel
def _step(kind, lanes, c, substeps, k, i2, i3):
    """Hold the currents (i2, i3) and advance lane 0 over sample ``k``; returns the status."""
    P, X, U, A, S, E, idx, W = lanes
    U[0, 0] = i2
    U[1, 0] = i3
    advance_sample(kind, P, c, X, U, A, S, W, 1, substeps, k % REANCHOR == 0)
    return S[0]


def simulate_closed_loop(
    log_or_rig,
    f_robot,
    controller,
    *,
    trajectory=None,
    n_samples=None,
    substeps=DEFAULT_CLOSED_LOOP_SUBSTEPS,
    q0=None,
    qd0=None,
    flexible=None,
    label=None,
    f_schedule=None,
):
    """Simulate the sampled closed loop of the robot ``f_robot`` and ``controller``.

    Parameters
    ----------
    log_or_rig : plant.ExperimentLog or plant.rig.Rig
        Source of the rig constants (Ts, gears, encoders, Kt, friction,
        gravity, start state, current full scale) and, for a log, of the
        default reference trajectory and run length (``log.n_total`` samples
        from t = 0).
    f_robot : array_like, shape (9,)
        True base parameters f1..f9 of the simulated robot (may differ from
        the controller's model); rigid-equivalent for a flexible robot.
    controller : callable
        Follows the sampled-controller protocol: ``reset()`` (called once
        before the run) and ``controller(k, t, q_meas, e_pulses)`` returning
        the two motor currents (A); ``q_meas`` (2,) rad are the quantised
        encoder angles, ``e_pulses`` (2,) int64 the pulse errors ref - act.
    trajectory : plant.trajectory.Trajectory, optional
        Reference (default: the log's); required with a Rig.
    n_samples : int, optional
        Samples to run from t = 0 (default: ``log.n_total``); required with a Rig.
    substeps : int
        RK4 steps per sample (>= 1).
    q0, qd0 : array_like, shape (2,), optional
        Start angles (rad) and rates (rad/s) (default: the rig's start state).
    flexible : plant.plants.FlexibleJoints, optional
        Simulate the two-mass flexible-joint robot instead of the rigid one;
        it starts with the springs relaxed.
    label : str, optional
        Label of the response (default: the controller's class name).
    f_schedule : sequence of (float, array_like (9,)), optional
        Changes of the robot during the run: from the first sample at or
        after ``t_s`` on, the robot is ``f`` (e.g. a payload picked up:
        ``[(1.0, plant.add_payload(f, payload, a3))]``); the state carries
        over.

    Returns
    -------
    ClosedLoopResponse
        ``success`` is False (and the arrays end at the failure) if D(q)
        stopped being positive definite or the state became non-finite.

    Raises
    ------
    ValueError
        Wrong shapes, NaN/inf in ``f_robot``, ``q0`` or ``qd0``, ``substeps <
        1``, missing trajectory or n_samples with a Rig, a non-PD link model
        of a flexible robot, or a controller output that is not 2 finite
        currents.
    """
    rig = getattr(log_or_rig, "rig", log_or_rig)
    if not hasattr(rig, "sample_time_s") or not hasattr(rig, "gear_ratio"):
        raise ValueError(f"log_or_rig must be an ExperimentLog or a Rig, got {type(log_or_rig).__name__}")
    is_log = rig is not log_or_rig
    if trajectory is None:
        if not is_log:
            raise ValueError("trajectory is required when a Rig (not a log) is given")
        trajectory = log_or_rig.trajectory
    if n_samples is None:
        if not is_log:
            raise ValueError("n_samples is required when a Rig (not a log) is given")
        n_samples = log_or_rig.n_total
    n = int(n_samples)
    if n < 1:
        raise ValueError(f"n_samples must be >= 1, got {n_samples}")
    substeps = check_substeps(substeps)
    f = checked_f(f_robot, "f_robot")
    if not callable(controller) or not callable(getattr(controller, "reset", None)):
        raise ValueError("controller must be callable and have a reset() method (sampled-controller protocol)")
    c = rig_constants(rig, q0=q0, qd0=qd0)
    plant = RIGID if flexible is None else flexible
    if flexible is not None and not is_positive_definite(flexible.link_parameters(f, rig)):
        raise ValueError("link f of the flexible robot (f minus Jm k^2) gives a non-PD D(q)")

    ts = c.sample_time_s
    t = np.arange(n) * ts
    q_ref = np.ascontiguousarray(trajectory.position(t), dtype=float)
    # the same expression as plant.simulate.reference_counts, so both agree bit for bit
    ref = np.ascontiguousarray(trajectory.position(t) * rig.pulses_per_rad)
    s2, s3 = c.pulses_per_rad
    i_fs = rig.current_full_scale_A
    i_fs = math.inf if i_fs is None else float(i_fs)

    lanes = new_lanes(plant.lane_parameters(f[None], rig), 0, 1, plant.initial_state(c))
    X = lanes.X
    enc = plant.encoder_row

    Q = np.zeros((n, 2))
    QD = np.zeros((n, 2))
    E = np.zeros((n, 2), dtype=np.int64)
    I = np.zeros((n, 2))
    changes = []
    for t_s, f_new in (f_schedule or ()):
        k_s = max(0, int(math.ceil(float(t_s) / ts - 1e-9)))
        changes.append((k_s, plant.lane_parameters(checked_f(f_new, "f_schedule f")[None], rig)))
    changes.sort(key=lambda ch: ch[0])
    controller.reset()
    status = STATUS_OK
    n_done = n
    n_clipped = 0
    for k in range(n):
        while changes and changes[0][0] <= k:  # the robot changes (payload picked up)
            lanes.P[:, :] = changes.pop(0)[1]
        a2, a3, e2, e3 = _read(X, enc, c, ref[k, 0], ref[k, 1])
        Q[k] = X[0:2, 0]
        QD[k] = X[2:4, 0]
        E[k, 0] = e2
        E[k, 1] = e3
        i = controller(k, k * ts, np.array([a2 / s2, a3 / s3]), E[k].copy())
        try:
            i2 = float(i[0])
            i3 = float(i[1])
            if len(i) != 2:
                raise TypeError
        except (TypeError, IndexError, ValueError):
            raise ValueError(f"controller must return 2 currents (A), got {i!r} at sample {k}") from None
        if not (math.isfinite(i2) and math.isfinite(i3)):
            raise ValueError(f"controller returned non-finite currents {i2!r}, {i3!r} at sample {k}")
        if abs(i2) >= i_fs or abs(i3) >= i_fs:  # saturated, by the controller or the drive
            n_clipped += 1
            i2 = min(max(i2, -i_fs), i_fs)
            i3 = min(max(i3, -i_fs), i_fs)
        I[k, 0] = i2
        I[k, 1] = i3
        if k == n - 1:
            break
        st = _step(plant.kind, lanes, c, substeps, k, i2, i3)
        if st != STATUS_OK:
            status = st
            n_done = k + 1
            break
    msg = "ok"
    if status != STATUS_OK:
        msg = f"{STATUS_MESSAGES[status]} at t = {n_done * ts:.4f} s"
    sl = slice(0, n_done)
    return ClosedLoopResponse(
        t=t[sl], q=Q[sl], qd=QD[sl], q_ref=q_ref[sl], e_pulses=E[sl], i_A=I[sl],
        success=status == STATUS_OK, message=msg,
        label=label if label is not None else type(controller).__name__,
        n_clipped=n_clipped,
    )


def warm_kernels():
    c, Pall, ref, _ = dummy_problem()
    lanes = new_lanes(Pall, 0, 1, RIGID.initial_state(c))
    _read(lanes.X, 0, c, 0.0, 0.0)
    _step(RIGID.kind, lanes, c, 1, 0, 0.0, 0.0)
