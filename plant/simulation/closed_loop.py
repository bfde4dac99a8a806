"""Closed-loop simulation of the rig with any sampled controller.

:func:`simulate_closed_loop` runs the robot (rigid by default, or the
two-mass flexible-joint robot of :class:`plant.simulation.plants.FlexibleJoints`) under
a controller that follows the sampled-controller protocol of :mod:`ctc`
(``reset()`` and ``__call__(k, t, q_meas, e_pulses) -> (2,)`` A).  It is a
driver of the one closed-loop core (:mod:`plant.simulation.core`) with one lane; at
each sample ``t_k = k Ts``, exactly as the rig's control card and
:func:`plant.simulate_experiment` do:

1. the motor encoders are read (:func:`plant.simulation.core.encoder_read`,
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
   and the plant is advanced by :func:`plant.simulation.core.advance_sample`.

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

from plant.simulation.core import STATUS_MESSAGES, STATUS_OK, encoder_read, hold_and_advance
from plant.simulation.plants import RIGID, FlexibleJoints  # noqa: F401 (re-exported for older code)
from plant.simulation.response import ClosedLoopResponse
from plant.logs.rig import rig_constants
from plant.simulation.simulate import dummy_problem, kernel, check_substeps, for_kinds, new_lanes
from plant.robot.model import checked_f, is_positive_definite

# ClosedLoopResponse (plant.simulation.response) and FlexibleJoints (plant.simulation.plants) are
# importable from here too, for older code; they are documented where defined.
__all__ = [
    "DEFAULT_CLOSED_LOOP_SUBSTEPS",
    "simulate_closed_loop",
]

#: RK4 substeps per sample used by default.  The rigid closed loop's pulses
#: converge at 24-48 substeps (see :mod:`plant.simulation.simulate`); 32 is in that range.
DEFAULT_CLOSED_LOOP_SUBSTEPS = 32


def read_encoders(X, enc, c, ref, act, err):
    """Encoder counts ``act`` and pulse errors ``err`` (n,) of lane 0 against the reference counts."""
    for m in range(act.shape[0]):
        _, a = encoder_read(X[enc + m, 0], c.pulses_per_rad[m])
        _, t = encoder_read(ref[m], 1.0)
        act[m] = a
        err[m] = t - a


_read = kernel(read_encoders)
_step = kernel(hold_and_advance)


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
    plant=None,
):
    """Simulate the sampled closed loop of the robot ``f_robot`` and ``controller``.

    Parameters
    ----------
    log_or_rig : plant.ExperimentLog or plant.logs.rig.Rig
        Source of the rig constants (Ts, gears, encoders, Kt, friction,
        gravity, start state, current full scale) and, for a log, of the
        default reference trajectory and run length (``log.n_total`` samples
        from t = 0).
    f_robot : array_like, shape (9,) or (r,)
        True base parameters f1..f9 of the simulated robot (may differ from
        the controller's model); rigid-equivalent for a flexible robot.  With
        ``plant`` a robot model's arm: its base parameters beta (r,).
    controller : callable
        Follows the sampled-controller protocol: ``reset()`` (called once
        before the run) and ``controller(k, t, q_meas, e_pulses)`` returning
        the n motor currents (A); ``q_meas`` (n,) rad are the quantised
        encoder angles, ``e_pulses`` (n,) int64 the pulse errors ref - act
        (n = 2 for the PUMA links 2-3).
    trajectory : plant.logs.trajectory.Trajectory, optional
        Reference (default: the log's); required with a Rig.
    n_samples : int, optional
        Samples to run from t = 0 (default: ``log.n_total``); required with a Rig.
    substeps : int
        RK4 steps per sample (>= 1).
    q0, qd0 : array_like, shape (2,), optional
        Start angles (rad) and rates (rad/s) (default: the rig's start state).
    flexible : plant.simulation.plants.FlexibleJoints, optional
        Simulate the two-mass flexible-joint robot instead of the rigid one;
        it starts with the springs relaxed.
    label : str, optional
        Label of the response (default: the controller's class name).
    f_schedule : sequence of (float, array_like (9,)[, array_like (6,) or FlexibleJoints]), optional
        Changes of the robot during the run: from the first sample at or
        after ``t_s`` on, the robot is ``f`` (e.g. a payload picked up:
        ``[(1.0, plant.add_payload(f, payload, a3))]``); the state carries
        over.  A third element, when given and not None, is the drive
        friction from then on (motor side, the sidecar's units, in the order
        of :data:`plant.simulation.friction.FRICTION_NAMES`: a friction
        change, e.g. a drive warming up; the rigid robot is then simulated
        with per-lane friction, :data:`plant.simulation.friction.RIGID_FRICTION`,
        which starts with the rig's).  For a flexible robot the third element
        may instead be a :class:`plant.simulation.plants.FlexibleJoints`:
        its joints from then on (a gearbox that wears or warms: stiffness,
        damping, backlash; the motor inertias should stay ``flexible``'s, as
        f is rigid-equivalent).  With ``plant``: base parameters beta (r,),
        no friction.
    plant : plant.simulation.arm.ArmPlant, optional
        Simulate a robot model's rigid arm (:func:`plant.simulation.arm.arm_plant`)
        instead of the PUMA 560 links 2-3; the rig and the trajectory must
        have its joint count.

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
        of a flexible robot, a scheduled friction that is not 6 finite values
        >= 0 (or with ``plant``), or a controller output that is not 2 finite
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
    if not callable(controller) or not callable(getattr(controller, "reset", None)):
        raise ValueError("controller must be callable and have a reset() method (sampled-controller protocol)")
    c = rig_constants(rig, q0=q0, qd0=qd0)
    arm = plant is not None
    schedule = []
    for item in (f_schedule or ()):
        t_s, f_new, *rest = item
        if len(rest) > 1:
            raise ValueError("an f_schedule entry is (t_s, f) or (t_s, f, friction)")
        fr = rest[0] if rest else None
        if isinstance(fr, FlexibleJoints):
            if flexible is None:
                raise ValueError("scheduled FlexibleJoints change a flexible robot: pass flexible=")
            schedule.append((t_s, f_new, fr))
            continue
        if fr is not None:
            fr = np.asarray(fr, dtype=float)
            if arm or fr.shape != (6,) or not np.all(np.isfinite(fr)) or np.any(fr < 0):
                raise ValueError("a scheduled friction is 6 finite motor-side values >= 0 "
                                 "(FRICTION_NAMES order), for the PUMA plants only")
        schedule.append((t_s, f_new, fr))
    frictional = any(fr is not None and not isinstance(fr, FlexibleJoints) for _, _, fr in schedule)
    if arm:
        from plant.simulation.arm import ArmPlant

        if not isinstance(plant, ArmPlant) or flexible is not None:
            raise ValueError("plant must be a plant.simulation.arm.ArmPlant (and flexible None)")
        if len(c.pulses_per_rad) != plant.n_joints:
            raise ValueError(f"the rig has {len(c.pulses_per_rad)} joints, the robot {plant.n_joints}")

        def lane_parameters(values, what, friction=None, joints=None):
            return plant.lane_parameters(np.asarray(values, dtype=float).reshape(1, -1))
        read, step = _read, plant.kernels.hold_and_advance
    else:
        from plant.simulation.friction import RIGID_FRICTION

        plant = (RIGID_FRICTION if frictional else RIGID) if flexible is None else flexible

        def lane_parameters(values, what, friction=None, joints=None):
            kw = {} if friction is None else {"friction": friction}
            return (plant if joints is None else joints).lane_parameters(
                checked_f(values, what)[None], rig, **kw)
        read, step = _read, for_kinds(_step, plant.kind)
    P0 = lane_parameters(f_robot, "f_robot")
    if flexible is not None and not is_positive_definite(
            flexible.link_parameters(checked_f(f_robot, "f_robot"), rig)):
        raise ValueError("link f of the flexible robot (f minus Jm k^2) gives a non-PD D(q)")
    nj = len(c.pulses_per_rad)

    ts = c.sample_time_s
    t = np.arange(n) * ts
    q_ref = np.ascontiguousarray(trajectory.position(t), dtype=float)
    # the same expression as plant.simulation.simulate.reference_counts, so both agree bit for bit
    ref = np.ascontiguousarray(trajectory.position(t) * rig.pulses_per_rad)
    if q_ref.shape != (n, nj):
        raise ValueError(f"the trajectory has {q_ref.shape[1]} joints, the rig {nj}")
    spr = np.asarray(c.pulses_per_rad)
    i_fs = rig.current_full_scale_A
    i_fs = math.inf if i_fs is None else float(i_fs)

    lanes = new_lanes(P0, 0, 1, plant.initial_state(c), n_inputs=nj, n_angles=2 if not arm else nj)
    X = lanes.X
    enc = plant.encoder_row

    Q = np.zeros((n, nj))
    QD = np.zeros((n, nj))
    E = np.zeros((n, nj), dtype=np.int64)
    I = np.zeros((n, nj))
    act = np.zeros(nj)
    err = np.zeros(nj)
    changes = []
    friction_now, joints_now = None, None
    for t_s, f_new, fr in sorted(schedule, key=lambda item: float(item[0])):
        k_s = max(0, int(math.ceil(float(t_s) / ts - 1e-9)))
        # a friction or joint change persists through later entries
        if isinstance(fr, FlexibleJoints):
            joints_now = fr
        elif fr is not None:
            friction_now = fr
        changes.append((k_s, lane_parameters(f_new, "f_schedule f", friction_now, joints_now)))
    controller.reset()
    status = STATUS_OK
    n_done = n
    n_clipped = 0
    for k in range(n):
        while changes and changes[0][0] <= k:  # the robot changes (payload picked up)
            lanes.P[:, :] = changes.pop(0)[1]
        read(X, enc, c, ref[k], act, err)
        Q[k] = X[0:nj, 0]
        QD[k] = X[nj:2 * nj, 0]
        E[k] = err
        i = controller(k, k * ts, act / spr, E[k].copy())
        try:
            iv = np.array([float(v) for v in i])
            if iv.shape != (nj,):
                raise TypeError
        except (TypeError, IndexError, ValueError):
            raise ValueError(f"controller must return {nj} currents (A), got {i!r} at sample {k}") from None
        if not np.all(np.isfinite(iv)):
            raise ValueError(f"controller returned non-finite currents {iv.tolist()!r} at sample {k}")
        if np.any(np.abs(iv) >= i_fs):  # saturated, by the controller or the drive
            n_clipped += 1
            iv = np.minimum(np.maximum(iv, -i_fs), i_fs)
        I[k] = iv
        if k == n - 1:
            break
        st = step(plant.kind, lanes, c, substeps, k, iv)
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
        joint_names=plant.model.joint_names if arm else ("q2", "q3"),
    )


def warm_kernels():
    c, Pall, ref, _ = dummy_problem()
    lanes = new_lanes(Pall, 0, 1, RIGID.initial_state(c))
    _read(lanes.X, 0, c, np.zeros(2), np.zeros(2), np.zeros(2))
    _step(RIGID.kind, lanes, c, 1, 0, np.zeros(2))
