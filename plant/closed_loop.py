"""Closed-loop simulation of the rig with any sampled controller.

:func:`simulate_closed_loop` runs the robot of :mod:`plant.model` (rigid by
default, or the two-mass flexible-joint robot of :class:`FlexibleJoints`)
under a controller that follows the sampled-controller protocol of
:mod:`ctc` (``reset()`` and ``__call__(k, t, q_meas, e_pulses) -> (2,)`` A).
At each sample ``t_k = k Ts``, exactly as the rig's control card and
:func:`plant.simulate.simulate_experiment` do:

1. the motor encoders are read, ``act = trunc(q k N / 2 pi)`` (trunc rounds
   toward zero) and the quantised joint angles
   ``q_meas = act 2 pi / (k N)`` are formed;
2. the integer error ``e = ref - act`` with
   ``ref = trunc(q_ref(t_k) k N / 2 pi)`` is formed;
3. the controller returns the motor currents ``i`` (A), clipped to
   ``[-I_fs, I_fs]`` when the rig's sidecar gives a ``current_full_scale_A``
   (the recorded ``i_A`` is the clipped current that was applied);
4. the joint torque ``k Kt i`` is held over ``[t_k, t_k + Ts)`` (ZOH, no
   computation delay: the current computed from the sample at ``t_k`` acts
   from ``t_k`` on) and the robot, with its drive friction, is integrated
   over the sample by :func:`plant.simulate.integrate_sample` (fixed-step RK4,
   ``substeps`` steps).

The robot's true parameters ``f_robot`` are independent of whatever model
the controller uses, so model errors can be studied.

The loop over samples is plain Python (the controller is an arbitrary
Python object); the robot integration is compiled.  One run of the 5215
samples of the paper log takes about 0.1-0.2 s.

The quantised loop is chaotic at the pulse level: two runs that differ by
rounding errors of 1e-16 agree for a while and then differ by single pulses
at scattered samples.  Use enough RK4 substeps (24-48; default
:data:`DEFAULT_CLOSED_LOOP_SUBSTEPS`) when pulses must be reproduced.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numba
import numpy as np

from .model import friction_torque, is_positive_definite, joint_acceleration
from .simulate import (
    _R_CNEG,
    _R_CPOS,
    _R_G,
    _R_KKT,
    _R_SCALE,
    _R_TS,
    _R_VISC,
    _R_VREG,
    STATUS_MESSAGES,
    STATUS_NONFINITE,
    STATUS_NOT_PD,
    STATUS_OK,
    integrate_sample,
    rig_vector,
)

__all__ = [
    "DEFAULT_CLOSED_LOOP_SUBSTEPS",
    "ClosedLoopResponse",
    "FlexibleJoints",
    "simulate_closed_loop",
]

#: RK4 substeps per sample used by default.  The rigid closed loop's pulses
#: converge at 24-48 substeps (see ``plant.simulate``); 32 is in that range.
DEFAULT_CLOSED_LOOP_SUBSTEPS = 32


# ----------------------------------------------------------------------------
# Response
# ----------------------------------------------------------------------------
@dataclass(frozen=True)
class ClosedLoopResponse:
    """Time response of a sampled closed loop (one value per controller sample).

    Modelled on :class:`control.TimeResponseData`: the raw arrays are stored
    time-first, and the properties :attr:`time`, :attr:`outputs`,
    :attr:`inputs`, :attr:`states` give them signal-first as python-control
    does (``outputs`` are the pulse errors, ``inputs`` the currents, ``states``
    the joint angles and rates).  :meth:`to_time_response` converts to a real
    :class:`control.TimeResponseData`.

    Attributes
    ----------
    t : ndarray, shape (n,)
        Sample times t_k = k Ts (s).
    q : ndarray, shape (n, 2)
        True joint angles at t_k (rad) (link side for a flexible robot).
    qd : ndarray, shape (n, 2)
        True joint rates at t_k (rad/s).
    q_ref : ndarray, shape (n, 2)
        Reference angles at t_k (rad).
    e_pulses : ndarray, shape (n, 2), int64
        Pulse errors ``trunc(q_ref k N/2pi) - trunc(q_enc k N/2pi)`` at t_k,
        where ``q_enc`` is the angle the encoder sees (the motor angle / k for
        a flexible robot).
    i_A : ndarray, shape (n, 2)
        Motor currents applied over [t_k, t_k + Ts) (A), after clipping.
    success : bool
        False when the simulation stopped early (then the arrays hold only the
        samples simulated before the failure).
    message : str
        "ok" or the reason of the failure.
    label : str
        Free-text label (controller name) used in plots.
    """

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    q_ref: np.ndarray
    e_pulses: np.ndarray
    i_A: np.ndarray
    success: bool = True
    message: str = "ok"
    label: str = ""
    n_clipped: int = field(default=0)

    # python-control style accessors (signal-first)
    @property
    def time(self) -> np.ndarray:
        """Sample times (n,), s."""
        return self.t

    @property
    def outputs(self) -> np.ndarray:
        """Pulse errors, shape (2, n) (python-control layout)."""
        return self.e_pulses.T

    @property
    def inputs(self) -> np.ndarray:
        """Motor currents, shape (2, n), A."""
        return self.i_A.T

    @property
    def states(self) -> np.ndarray:
        """Joint angles and rates (q2, q3, qd2, qd3), shape (4, n)."""
        return np.vstack([self.q.T, self.qd.T])

    def to_time_response(self):
        """Return the response as a :class:`control.TimeResponseData`.

        Returns
        -------
        control.TimeResponseData
            outputs ``e2, e3`` (pulses), inputs ``i2, i3`` (A), states
            ``q2, q3, qd2, qd3``.
        """
        import control

        return control.TimeResponseData(
            self.t, self.outputs.astype(float), self.states, self.inputs,
            output_labels=["e2", "e3"], input_labels=["i2", "i3"],
            state_labels=["q2", "q3", "qd2", "qd3"], title=self.label or None,
            success=self.success, message=self.message,
        )

    # ------------------------------------------------------------- statistics
    def _mask(self, after_s: float) -> np.ndarray:
        after_s = float(after_s)
        if not math.isfinite(after_s):
            raise ValueError(f"after_s must be finite, got {after_s!r}")
        m = self.t >= after_s - 1e-12
        if not np.any(m):
            raise ValueError(f"no sample at or after {after_s} s (run ends at {self.t[-1]:.4f} s)")
        return m

    def max_abs_error(self, after_s: float = 0.0) -> np.ndarray:
        """Largest abs(e) per joint over the samples with t >= after_s.

        Parameters
        ----------
        after_s : float
            Start of the evaluated part of the run (s).

        Returns
        -------
        ndarray, shape (2,), int64
            max abs(e) (pulses) of joints 2 and 3.

        Raises
        ------
        ValueError
            If no sample lies at or after ``after_s``.
        """
        return np.max(np.abs(self.e_pulses[self._mask(after_s)]), axis=0)

    def rms_error(self, after_s: float = 0.0) -> np.ndarray:
        """Root-mean-square pulse error per joint over t >= after_s.

        Returns
        -------
        ndarray, shape (2,), float (pulses)
        """
        e = self.e_pulses[self._mask(after_s)].astype(float)
        return np.sqrt(np.mean(e * e, axis=0))

    def within(self, pulses: int = 1, after_s: float = 0.0) -> bool:
        """Whether abs(e) <= pulses on both joints for every sample with t >= after_s.

        A run that failed (``success`` False) is never within.
        """
        return bool(self.success and np.all(self.max_abs_error(after_s) <= pulses))

    # --------------------------------------------------------------- plotting
    def plot(self, *, currents: bool = True, title: str | None = None):
        """Plot the pulse errors (and currents) per joint.

        Parameters
        ----------
        currents : bool
            Add a row with the motor currents.
        title : str, optional
            Figure title (default: the label).

        Returns
        -------
        matplotlib.figure.Figure
            Never shown (no ``plt.show()``); save it or display it yourself.
        """
        from matplotlib.figure import Figure

        rows = 2 if currents else 1
        fig = Figure(figsize=(10, 3.2 * rows), layout="constrained")
        axes = fig.subplots(rows, 2, sharex=True, squeeze=False)
        for j, name in enumerate(("joint 2", "joint 3")):
            ax = axes[0, j]
            ax.step(self.t, self.e_pulses[:, j], where="post", lw=0.8)
            ax.set_ylabel("e (pulses)")
            ax.set_title(f"{name}: max |e| {self.max_abs_error()[j]} pulses")
            ax.grid(True, alpha=0.3)
            if currents:
                ax = axes[1, j]
                ax.step(self.t, self.i_A[:, j], where="post", lw=0.8, color="C1")
                ax.set_ylabel("i (A)")
                ax.grid(True, alpha=0.3)
            axes[-1, j].set_xlabel("t (s)")
        fig.suptitle(title if title is not None else (self.label or "closed-loop response"))
        return fig


# ----------------------------------------------------------------------------
# Flexible-joint robot (optional plant)
# ----------------------------------------------------------------------------
@dataclass(frozen=True)
class FlexibleJoints:
    """Spong two-mass joints: motor and link joined by a spring and damper.

    With ``th`` the motor angle divided by the gear ratio (joint-side motor
    angle, what the encoder reads) and ``q`` the link angle, per joint::

        Jm k^2 th'' = k Kt i + tau_friction(th') - tau_s
        D_link(q) q'' + h(q, q') + g(q) = tau_s
        tau_s = Ks (th - q) + Ds (th' - q')

    ``D_link`` is the rigid model of :mod:`plant.model` with the reflected
    motor inertias removed from f7 (joint 2) and f1 (joint 3) (f1 - Jm k3^2,
    f7 - Jm k2^2); friction acts on the motor side.  Source: M. W. Spong,
    "Modeling and control of elastic joint robots", J. Dyn. Syst. Meas.
    Control 109 (1987); the values of the drill/flex log's truth file.

    Attributes
    ----------
    stiffness_Nm_per_rad : tuple of 2 float
        Joint-side spring stiffness Ks (N m/rad).
    damping_Nms_per_rad : tuple of 2 float
        Joint-side spring damping Ds (N m s/rad).
    motor_inertia_kgm2 : float or tuple of 2 float
        Motor rotor inertia Jm (kg m^2), motor side.
    """

    stiffness_Nm_per_rad: tuple
    damping_Nms_per_rad: tuple
    motor_inertia_kgm2: float | tuple

    def vector(self, rig) -> np.ndarray:
        """Joint-side constants (Ks2, Ks3, Ds2, Ds3, Jm2 k2^2, Jm3 k3^2), shape (6,)."""
        ks = np.broadcast_to(np.asarray(self.stiffness_Nm_per_rad, float), (2,))
        ds = np.broadcast_to(np.asarray(self.damping_Nms_per_rad, float), (2,))
        jm = np.broadcast_to(np.asarray(self.motor_inertia_kgm2, float), (2,))
        k = np.asarray(rig.gear_ratio, float)
        out = np.concatenate([ks, ds, jm * k * k])
        if not np.all(np.isfinite(out)) or np.any(out[[0, 1, 4, 5]] <= 0) or np.any(out[2:4] < 0):
            raise ValueError("FlexibleJoints: stiffness and motor inertia must be > 0, damping >= 0")
        return out

    def link_parameters(self, f, rig) -> np.ndarray:
        """Link-only f: the rigid f minus the reflected motor inertias (f1 - Jm k3^2, f7 - Jm k2^2)."""
        v = self.vector(rig)
        fl = np.array(f, dtype=float)
        fl[6] -= v[4]
        fl[0] -= v[5]
        return fl


_jit = numba.njit(cache=True, nogil=True)


@_jit
def _flex_deriv(fl, r, fx, q2, q3, w2, w3, th2, th3, v2, v3, u2, u3):
    """Accelerations of the flexible robot: (link a2, a3, motor b2, b3, det D_link)."""
    ts2 = fx[0] * (th2 - q2) + fx[2] * (v2 - w2)
    ts3 = fx[1] * (th3 - q3) + fx[3] * (v3 - w3)
    a2, a3, det = joint_acceleration(fl, q2, q3, w2, w3, ts2, ts3, r[_R_G])
    fr2 = friction_torque(v2, r[_R_VISC], r[_R_CPOS], r[_R_CNEG], r[_R_VREG])
    fr3 = friction_torque(v3, r[_R_VISC + 1], r[_R_CPOS + 1], r[_R_CNEG + 1], r[_R_VREG + 1])
    b2 = (u2 + fr2 - ts2) / fx[4]
    b3 = (u3 + fr3 - ts3) / fx[5]
    return a2, a3, b2, b3, det


@_jit
def _flex_integrate_sample(fl, r, fx, x, u2, u3, substeps):
    """RK4 over one sample of the flexible robot; updates ``x`` (8,) in place, returns status.

    ``x = (q2, q3, w2, w3, th2, th3, v2, v3)``: link angles and rates, motor
    angles and rates (joint side, motor angle / k).
    """
    h = r[_R_TS] / substeps
    if not fl[0] > 0.0:
        return STATUS_NOT_PD
    q2, q3, w2, w3, th2, th3, v2, v3 = x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7]
    hh = 0.5 * h
    for _ in range(substeps):
        a12, a13, b12, b13, d1 = _flex_deriv(fl, r, fx, q2, q3, w2, w3, th2, th3, v2, v3, u2, u3)
        a22, a23, b22, b23, d2 = _flex_deriv(
            fl, r, fx, q2 + hh * w2, q3 + hh * w3, w2 + hh * a12, w3 + hh * a13,
            th2 + hh * v2, th3 + hh * v3, v2 + hh * b12, v3 + hh * b13, u2, u3)
        a32, a33, b32, b33, d3 = _flex_deriv(
            fl, r, fx, q2 + hh * (w2 + hh * a12), q3 + hh * (w3 + hh * a13),
            w2 + hh * a22, w3 + hh * a23,
            th2 + hh * (v2 + hh * b12), th3 + hh * (v3 + hh * b13),
            v2 + hh * b22, v3 + hh * b23, u2, u3)
        a42, a43, b42, b43, d4 = _flex_deriv(
            fl, r, fx, q2 + h * (w2 + hh * a22), q3 + h * (w3 + hh * a23),
            w2 + h * a32, w3 + h * a33,
            th2 + h * (v2 + hh * b22), th3 + h * (v3 + hh * b23),
            v2 + h * b32, v3 + h * b33, u2, u3)
        if not (d1 > 0.0 and d2 > 0.0 and d3 > 0.0 and d4 > 0.0):
            x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7] = q2, q3, w2, w3, th2, th3, v2, v3
            return STATUS_NOT_PD
        q2 += h / 6.0 * (w2 + 2.0 * (w2 + hh * a12) + 2.0 * (w2 + hh * a22) + (w2 + h * a32))
        q3 += h / 6.0 * (w3 + 2.0 * (w3 + hh * a13) + 2.0 * (w3 + hh * a23) + (w3 + h * a33))
        th2 += h / 6.0 * (v2 + 2.0 * (v2 + hh * b12) + 2.0 * (v2 + hh * b22) + (v2 + h * b32))
        th3 += h / 6.0 * (v3 + 2.0 * (v3 + hh * b13) + 2.0 * (v3 + hh * b23) + (v3 + h * b33))
        w2 += h / 6.0 * (a12 + 2.0 * a22 + 2.0 * a32 + a42)
        w3 += h / 6.0 * (a13 + 2.0 * a23 + 2.0 * a33 + a43)
        v2 += h / 6.0 * (b12 + 2.0 * b22 + 2.0 * b32 + b42)
        v3 += h / 6.0 * (b13 + 2.0 * b23 + 2.0 * b33 + b43)
    x[0], x[1], x[2], x[3], x[4], x[5], x[6], x[7] = q2, q3, w2, w3, th2, th3, v2, v3
    for i in range(8):
        if not math.isfinite(x[i]):
            return STATUS_NONFINITE
    return STATUS_OK


# ----------------------------------------------------------------------------
# Simulator
# ----------------------------------------------------------------------------
def _check_f(f, what):
    f = np.ascontiguousarray(f, dtype=np.float64)
    if f.shape != (9,):
        raise ValueError(f"{what} must have shape (9,) (f1..f9), got {f.shape}")
    if not np.all(np.isfinite(f)):
        raise ValueError(f"{what} contains NaN or inf")
    return f


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
        the controller's model).
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
        A flexible robot starts with the springs relaxed (motor angles equal
        to the link angles, motor rates equal to the link rates).
    flexible : FlexibleJoints, optional
        Simulate the two-mass flexible-joint robot instead of the rigid one
        (``f_robot`` is then the rigid-equivalent f, link plus reflected motor
        inertia, as in the truth files).
    label : str, optional
        Label of the response (default: the controller's class name).

    Returns
    -------
    ClosedLoopResponse
        ``success`` is False (and the arrays end at the failure) if D(q)
        stopped being positive definite or the state became non-finite.

    Raises
    ------
    ValueError
        Wrong shapes, NaN/inf in ``f_robot``, ``q0`` or ``qd0``, ``substeps <
        1``, missing trajectory or n_samples with a Rig, or a controller
        output that is not 2 finite currents.
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
    substeps = int(substeps)
    if substeps < 1:
        raise ValueError(f"substeps must be >= 1, got {substeps}")
    f = _check_f(f_robot, "f_robot")
    if not callable(controller) or not callable(getattr(controller, "reset", None)):
        raise ValueError("controller must be callable and have a reset() method (sampled-controller protocol)")

    r = rig_vector(rig)
    for name, val, idx in (("q0", q0, 16), ("qd0", qd0, 18)):
        if val is not None:
            v = np.asarray(val, dtype=float)
            if v.shape != (2,) or not np.all(np.isfinite(v)):
                raise ValueError(f"{name} must be 2 finite numbers, got {val!r}")
            r[idx : idx + 2] = v
    ts = float(r[_R_TS])
    t = np.arange(n) * ts
    q_ref = np.ascontiguousarray(trajectory.position(t), dtype=float)
    # Same expression as plant.simulate.reference_counts, so both agree bit for bit.
    ref = np.ascontiguousarray(trajectory.position(t) * rig.pulses_per_rad)
    s2, s3 = float(r[_R_SCALE]), float(r[_R_SCALE + 1])
    kkt2, kkt3 = float(r[_R_KKT]), float(r[_R_KKT + 1])
    i_fs = rig.current_full_scale_A
    i_fs = math.inf if i_fs is None else float(i_fs)

    fl = fx = x = None
    if flexible is not None:
        fx = flexible.vector(rig)
        fl = flexible.link_parameters(f, rig)
        if not is_positive_definite(fl):
            raise ValueError("link f of the flexible robot (f minus Jm k^2) gives a non-PD D(q)")
        x = np.zeros(8)
        x[0:2] = r[16:18]
        x[2:4] = r[18:20]
        x[4:6] = r[16:18]
        x[6:8] = r[18:20]
        q2, q3, w2, w3 = x[0], x[1], x[2], x[3]
        th2, th3 = x[4], x[5]
    else:
        q2, q3, w2, w3 = (float(v) for v in r[16:20])
        th2, th3 = q2, q3

    Q = np.zeros((n, 2))
    QD = np.zeros((n, 2))
    E = np.zeros((n, 2), dtype=np.int64)
    I = np.zeros((n, 2))
    controller.reset()
    status = STATUS_OK
    n_done = n
    n_clipped = 0
    qm = np.empty(2)
    ep = np.empty(2, dtype=np.int64)
    trunc = math.trunc
    for k in range(n):
        c2 = trunc(th2 * s2)
        c3 = trunc(th3 * s3)
        e2 = trunc(ref[k, 0]) - c2
        e3 = trunc(ref[k, 1]) - c3
        Q[k, 0] = q2
        Q[k, 1] = q3
        QD[k, 0] = w2
        QD[k, 1] = w3
        E[k, 0] = e2
        E[k, 1] = e3
        qm[0] = c2 / s2
        qm[1] = c3 / s3
        ep[0] = e2
        ep[1] = e3
        i = controller(k, k * ts, qm.copy(), ep.copy())
        try:
            i2 = float(i[0])
            i3 = float(i[1])
            if len(i) != 2:
                raise TypeError
        except (TypeError, IndexError, ValueError):
            raise ValueError(
                f"controller must return 2 currents (A), got {i!r} at sample {k}"
            ) from None
        if not (math.isfinite(i2) and math.isfinite(i3)):
            raise ValueError(f"controller returned non-finite currents {i2!r}, {i3!r} at sample {k}")
        if abs(i2) > i_fs or abs(i3) > i_fs:
            n_clipped += 1
            i2 = min(max(i2, -i_fs), i_fs)
            i3 = min(max(i3, -i_fs), i_fs)
        I[k, 0] = i2
        I[k, 1] = i3
        if k == n - 1:
            break
        if fx is None:
            q2, q3, w2, w3, st = integrate_sample(f, r, q2, q3, w2, w3, kkt2 * i2, kkt3 * i3, substeps)
            th2, th3 = q2, q3
        else:
            st = _flex_integrate_sample(fl, r, fx, x, kkt2 * i2, kkt3 * i3, substeps)
            q2, q3, w2, w3, th2, th3 = x[0], x[1], x[2], x[3], x[4], x[5]
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
