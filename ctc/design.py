"""Gain design of the computed-torque controller with python-control.

After exact feedback linearisation (computed torque with the true model) each
joint's tracking error obeys a double integrator driven by the outer-loop
acceleration command ``a = qdd_d + Kv e_dot + Kp e`` (Craig, *Introduction to
Robotics*, ch. 10; Spong, Hutchinson & Vidyasagar, *Robot Modeling and
Control*, ch. 8).  The controller is sampled, so the design is done on the
discrete model of that double integrator:

* **ZOH at Ts.**  The acceleration command is held over each sample:
  ``x[k+1] = A x[k] + B a[k]`` with ``A = [[1, Ts], [0, 1]]``,
  ``B = [Ts^2/2, Ts]`` (``control.c2d`` of ``1/s^2`` with ``"zoh"``).
* **Computation delay.**  In :func:`plant.simulation.closed_loop.simulate_closed_loop`
  (and in the rig's control card as the logs describe it) the current
  computed from the sample at ``t_k`` is applied over ``[t_k, t_k + Ts)``:
  there is **no** one-sample delay, so the default is ``delay_samples=0``.
  A real control PC that applies the current only at ``t_{k+1}`` is
  analysed with ``delay_samples=1`` (the plant becomes ``z^-1 P(z)``; the
  gains are kept, the poles and margins then show the cost of the delay).
* **Velocity estimator.**  The encoder gives positions quantised to one
  pulse (7.3e-5 rad on joint 2, 1.2e-4 rad on joint 3); a raw backward
  difference has a noise of one pulse per sample, 0.10-0.17 rad/s, which
  ``Kv`` would turn into acceleration noise of tens of rad/s^2.  Two
  estimators are provided and analysed:

  - ``"observer"`` (default): a *current* Luenberger observer of the same
    double integrator (Franklin, Powell & Workman, *Digital Control of
    Dynamic Systems*, sec. 8.2), driven by the commanded acceleration and
    the quantised position taken at the centre of its pulse cell:
    ``xbar = A xhat[k-1] + B a[k-1]``, ``xhat[k] = xbar + L (y[k] - C xbar)``.
    Its error poles (``A - L C A``) are placed at a double real pole of
    bandwidth ``observer_bandwidth_hz``.
  - ``"difference"``: a backward difference through a first-order low-pass,
    ``v[k] = alpha v[k-1] + (1 - alpha) (y[k] - y[k-1]) / Ts`` with
    ``alpha = exp(-2 pi f_c Ts)``.

Design rule
-----------
``Kp, Kv`` place the closed-loop poles of the discrete double integrator
exactly at ``z = exp(s Ts)``, ``s`` the roots of
``s^2 + 2 zeta w s + w^2`` with ``w = 2 pi bandwidth_hz`` (Ackermann's
formula, ``control.place_acker``).  Default: **bandwidth = fs / 50** (28.6 Hz
at Ts = 0.7 ms, ``w Ts = 0.126``), **zeta = 1** (no overshoot of the error),
**observer bandwidth = 3 x the loop bandwidth** (85.7 Hz; the observer poles
are then well separated from the loop poles yet far below Nyquist, 714 Hz).
This gives Kp = 28459 1/s^2, Kv = 327.4 1/s, phase margin 47.8 deg, gain
margin 5.94 (15.5 dB) without delay and 39.8 deg / 3.29 (10.3 dB) with a
one-sample computation delay.

The bandwidth is a compromise measured on the paper trajectory
(``docs/tutorial_ctc.rst``): with the true model every bandwidth from 15 to
60 Hz tracks within one pulse, but the error caused by a model error scales
as ``1 / w^2`` (robot f 20 % off the model: max abs(e) 9 pulses at 15 Hz,
3 at 28.6 Hz, 1 at 60 Hz), while the quantisation noise in the current
and the peak current grow with ``w`` (12.4 A of the 15 A full scale at
60 Hz) and the margins with a computation delay shrink (30 deg at 60 Hz).
On the flexible-joint robot (gearbox modes near 25-30 Hz) a higher
bandwidth does not help either.  fs / 50 keeps the peak current within 8 A,
the margins comfortable with or without a delay, and a 20 % model error at
3 pulses.

That measurement was made with 800 / 1000-pulse encoders.  A finer encoder
counts the same disturbance in more pulses (``N / w^2``), and its
quantisation puts less noise into the current, so the default bandwidth of a
joint grows as ``sqrt(N / 1000)`` up to ``fs / 25``
(:func:`default_bandwidth_hz`; the rigs of the paper keep ``fs / 50``).

Integral action
---------------
``integral_bandwidth_hz`` adds ``Ki z`` to the command, ``z`` the sum of
``Ts (q_d - q_hat)`` (a PID outer loop).  ``Kp, Kv, Ki`` then place the
poles of the double integrator augmented with that sum at ``exp(s Ts)``,
``s`` the roots of ``(s^2 + 2 zeta w s + w^2)(s + w_i)`` (Ackermann again,
``_pid_gains``).  A torque the model gets wrong and that varies slowly
(a payload's gravity; on a flexible-joint arm the spring-torque error of its
link model) is the reason: the PD loop leaves it as an error ``d / (D Kp)``,
the sum removes it.  Its pole at a tenth of the loop's (the robust
flexible-joint design's :data:`ctc.flexible.INTEGRAL_FRACTION`) costs 2.8
degrees of phase margin at the default bandwidth (45.0 against 47.8, no
delay).  The controllers freeze the sum on a sample whose current the drive
limits (conditional integration, against windup).  Default: off.

Analysis
--------
:func:`design_gains` builds, per joint, the discrete plant ``P(z)`` (with
``delay_samples``), the feedback compensator ``C(z)`` (position + velocity
estimate -> acceleration), the loop ``L = C P`` (broken at the plant input),
and the closed loop ``feedback(P, C)``; it reports the closed-loop poles
(``control.poles``), their damping and natural frequency (``control.damp``)
and the gain/phase/stability margins (``control.stability_margins``).
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, field

import numpy as np

# python-control is imported inside the functions that use it: it takes about
# 2 s to import, and a process that loads a cached kernel naming a CTC law's kind
# (the identification command line, say) imports this module without designing gains.

__all__ = ["ESTIMATORS", "GainDesign", "design_gains", "gains_for", "double_integrator",
           "default_bandwidth_hz"]

#: Velocity estimators understood by :func:`design_gains` and the controller.
ESTIMATORS = ("observer", "difference")

#: Default loop bandwidth as a fraction of the sample rate.
BANDWIDTH_FRACTION = 1.0 / 50.0

#: Encoder resolution (pulses per motor revolution) at which the default
#: bandwidth is ``fs * BANDWIDTH_FRACTION``; finer encoders get a faster loop
#: (see :func:`default_bandwidth_hz`).
REFERENCE_PPR = 1000.0

#: Largest resolution factor of the default bandwidth (fs / 25 at most).
MAX_RESOLUTION_FACTOR = 2.0

#: Default observer bandwidth as a multiple of the loop bandwidth.
OBSERVER_FACTOR = 3.0

#: Default cut-off of the difference filter as a multiple of the loop bandwidth.
DIFFERENCE_FACTOR = 3.0


def double_integrator(ts: float, delay_samples: int = 0):
    """Discrete (ZOH) double integrator ``1/s^2`` from acceleration to position.

    Parameters
    ----------
    ts : float
        Sample time (s), > 0.
    delay_samples : int
        Whole samples of computation delay in front of the plant (0 or more).

    Returns
    -------
    control.StateSpace
        Discrete-time system (dt = ts); with a delay, the delayed inputs are
        extra states.
    """
    import control

    ct_sys = control.ss([[0.0, 1.0], [0.0, 0.0]], [[0.0], [1.0]], [[1.0, 0.0]], [[0.0]])
    p = control.c2d(ct_sys, ts, method="zoh")
    for _ in range(int(delay_samples)):
        p = control.series(control.ss([[0.0]], [[1.0]], [[1.0]], [[0.0]], ts), p)
    return p


def _matrices(ts):
    a = np.array([[1.0, ts], [0.0, 1.0]])
    b = np.array([[0.5 * ts * ts], [ts]])
    c = np.array([[1.0, 0.0]])
    return a, b, c


def _pd_gains(ts, w, zeta):
    """Kp, Kv placing the ZOH double-integrator poles at exp(s Ts)."""
    import control

    a, b, _ = _matrices(ts)
    s = np.roots([1.0, 2.0 * zeta * w, w * w]).astype(complex)
    z = np.exp(s * ts)
    k = np.real(control.place_acker(a, b, z)).ravel()
    return float(k[0]), float(k[1])


def _pid_gains(ts, w, zeta, w_i):
    """Kp, Kv, Ki placing the ZOH double integrator with a summed position error at exp(s Ts).

    The augmented state is ``(q, qd, z)`` with ``z[k+1] = z[k] + Ts q[k]`` (the
    error sum of the law) and ``a = -(Kp q + Kv qd + Ki z)``; the poles are
    ``exp(s Ts)`` for the roots of ``(s^2 + 2 zeta w s + w^2)(s + w_i)``.
    """
    import control

    a = np.array([[1.0, ts, 0.0], [0.0, 1.0, 0.0], [ts, 0.0, 1.0]])
    b = np.array([[0.5 * ts * ts], [ts], [0.0]])
    s = np.concatenate([np.roots([1.0, 2.0 * zeta * w, w * w]), [-w_i]]).astype(complex)
    k = np.real(control.place_acker(a, b, np.exp(s * ts))).ravel()
    return float(k[0]), float(k[1]), float(k[2])


def _observer_gain(ts, w_o, zeta_o=1.0):
    """Current-estimator gain L (2,) placing eig(A - L C A) at exp(s Ts)."""
    import control

    a, _, c = _matrices(ts)
    s = np.roots([1.0, 2.0 * zeta_o * w_o, w_o * w_o]).astype(complex)
    z = np.exp(s * ts)
    # eig(A - L C A) = eig(A^T - (C A)^T L^T): place on the dual system.
    l = np.real(control.place_acker(a.T, (c @ a).T, z)).ravel()
    return l


def _compensator(ts, kp, kv, estimator, l=None, alpha=None, ki=0.0):
    """Feedback part C(z) (position y -> acceleration -a) of the controller.

    With ``ki`` the law adds ``Ki z``, ``z[k+1] = z[k] + Ts q_hat[k]`` (the
    error sum, updated after the sample's command).
    """
    import control

    a, b, c = _matrices(ts)
    k = np.array([[kp, kv]])
    if estimator == "observer":
        lc = np.asarray(l, float).reshape(2, 1)
        phi = (np.eye(2) - lc @ c) @ (a - b @ k)
        if not ki:
            return control.ss(phi, lc, k @ phi, k @ lc, ts)
        # state (x_bar, z): x_hat = M x_bar + L y, M = I - L C;
        # x_bar' = (A - B K) x_hat - B Ki z, z' = z + Ts C x_hat, -a = K x_hat + Ki z
        m = np.eye(2) - lc @ c
        abk = a - b @ k
        big = np.block([[abk @ m, -b * ki], [ts * c @ m, np.ones((1, 1))]])
        gam = np.vstack([abk @ lc, ts * c @ lc])
        out = np.hstack([k @ m, [[ki]]])
        return control.ss(big, gam, out, k @ lc, ts)
    # difference: a = -(Kp y + Kv v), v = (1-alpha)/Ts (z-1)/(z-alpha) y
    g = (1.0 - alpha) / ts
    pd = control.tf([kp + kv * g, -kp * alpha - kv * g], [1.0, -alpha], ts)
    if not ki:
        return pd
    return pd + control.tf([ki * ts], [1.0, -1.0], ts)


def _margins(loop):
    """(gm, pm_deg, sm, w_gm, w_pm) of a discrete loop; gm is the upper gain margin."""
    import control

    with warnings.catch_warnings():
        # the polynomial method warns and falls back to frequency data for
        # this lightly damped discrete loop; the fallback is what we want
        warnings.simplefilter("ignore")
        gm, pm, sm, wpc, wgc, wms = control.stability_margins(loop, returnall=True)
    gm = np.atleast_1d(gm)
    wpc = np.atleast_1d(wpc)
    pm = np.atleast_1d(pm)
    wgc = np.atleast_1d(wgc)
    sm = np.atleast_1d(sm)
    up = gm > 1.0
    if np.any(up):
        i = int(np.argmin(np.where(up, gm, np.inf)))
        g, wg = float(gm[i]), float(wpc[i])
    else:
        g, wg = math.inf, math.nan
    if pm.size:
        i = int(np.argmin(np.abs(pm)))
        p, wp = float(pm[i]), float(wgc[i])
    else:
        p, wp = math.inf, math.nan
    s = float(np.min(sm)) if sm.size else math.nan
    return g, p, s, wg, wp


@dataclass(frozen=True)
class GainDesign:
    """Gains and analysis of the sampled computed-torque outer loop.

    Attributes
    ----------
    ts : float
        Sample time (s).
    Kp : ndarray, shape (n_joints,)
        Position gains (1/s^2) per joint (joints 2 and 3 of the PUMA links 2-3).
    Kv : ndarray, shape (n_joints,)
        Velocity gains (1/s).
    Ki : ndarray, shape (n_joints,)
        Integral gains (1/s^3) on the summed position error; zeros without
        integral action.
    estimator : str
        ``"observer"`` or ``"difference"``.
    observer_gain : ndarray, shape (n_joints, 2)
        Current-estimator gains ``[l_q, l_w]`` per joint (rows), for
        ``"observer"`` (zeros otherwise).
    alpha : ndarray, shape (n_joints,)
        Pole of the difference low-pass per joint, for ``"difference"``.
    bandwidth_hz, damping : ndarray, shape (n_joints,)
        Design loop bandwidth (Hz) and damping ratio.
    estimator_bandwidth_hz : ndarray, shape (n_joints,)
        Observer bandwidth or difference cut-off (Hz).
    integral_bandwidth_hz : ndarray, shape (n_joints,)
        Frequency of the integral action's real pole (Hz); zeros without it.
    delay_samples : int
        Computation delay assumed in the analysis.
    poles : list of n_joints ndarray
        Closed-loop poles (z-plane) per joint.
    pole_damping, pole_frequency_hz : list of n_joints ndarray
        Damping ratio and natural frequency (Hz) of each pole (``control.damp``).
    gain_margin : ndarray, shape (n_joints,)
        Upper gain margin (factor; inf if none).
    phase_margin_deg : ndarray, shape (n_joints,)
        Phase margin (deg).
    stability_margin : ndarray, shape (n_joints,)
        Smallest distance of the Nyquist curve from -1.
    crossover_hz : ndarray, shape (n_joints,)
        Gain-crossover frequency (Hz).
    phase_crossover_hz : ndarray, shape (n_joints,)
        Phase-crossover frequency of the gain margin (Hz).
    """

    ts: float
    Kp: np.ndarray
    Kv: np.ndarray
    Ki: np.ndarray
    estimator: str
    observer_gain: np.ndarray
    alpha: np.ndarray
    bandwidth_hz: np.ndarray
    damping: np.ndarray
    estimator_bandwidth_hz: np.ndarray
    integral_bandwidth_hz: np.ndarray
    delay_samples: int
    poles: list = field(repr=False)
    pole_damping: list = field(repr=False)
    pole_frequency_hz: list = field(repr=False)
    gain_margin: np.ndarray = field(repr=False)
    phase_margin_deg: np.ndarray = field(repr=False)
    stability_margin: np.ndarray = field(repr=False)
    crossover_hz: np.ndarray = field(repr=False)
    phase_crossover_hz: np.ndarray = field(repr=False)

    @property
    def stable(self) -> bool:
        """All closed-loop poles strictly inside the unit circle."""
        return all(bool(np.all(np.abs(p) < 1.0)) for p in self.poles)

    def plant(self, joint: int = 0):
        """Discrete plant ``P(z)`` (acceleration -> position, with the delay).

        Parameters
        ----------
        joint : int
            0 (joint 2) or 1 (joint 3).

        Returns
        -------
        control.TransferFunction
        """
        return double_integrator(self.ts, self.delay_samples)

    def compensator(self, joint: int = 0):
        """Feedback compensator ``C(z)`` (position -> -acceleration) of a joint (0 or 1).

        Parameters
        ----------
        joint : int
            0 (joint 2) or 1 (joint 3).

        Returns
        -------
        control.TransferFunction
        """
        return _compensator(
            self.ts, self.Kp[joint], self.Kv[joint], self.estimator,
            self.observer_gain[joint], self.alpha[joint], self.Ki[joint],
        )

    def loop(self, joint: int = 0):
        """Loop transfer ``L(z) = C(z) P(z)`` broken at the plant input.

        Parameters
        ----------
        joint : int
            0 (joint 2) or 1 (joint 3).

        Returns
        -------
        control.TransferFunction
        """
        import control

        return control.series(self.plant(joint), self.compensator(joint))

    def closed_loop(self, joint: int = 0):
        """Closed loop ``feedback(P, C)`` (disturbance acceleration -> position).

        Parameters
        ----------
        joint : int
            0 (joint 2) or 1 (joint 3).

        Returns
        -------
        control.TransferFunction
        """
        import control

        return control.feedback(self.plant(joint), self.compensator(joint))

    def report(self) -> str:
        """A plain-text report: gains, poles, damping and margins per joint."""
        fs = 1.0 / self.ts
        lines = [
            f"Computed-torque outer loop, Ts = {self.ts * 1e3:.3f} ms (fs = {fs:.1f} Hz), "
            f"estimator '{self.estimator}', computation delay {self.delay_samples} sample(s)",
        ]
        for j, name in enumerate(("joint 2", "joint 3")):
            lines.append(
                f"{name}: bandwidth {self.bandwidth_hz[j]:.2f} Hz (fs/{fs / self.bandwidth_hz[j]:.0f}), "
                f"zeta {self.damping[j]:.2f}, estimator {self.estimator_bandwidth_hz[j]:.1f} Hz"
            )
            lines.append(f"  Kp = {self.Kp[j]:.6g} 1/s^2, Kv = {self.Kv[j]:.6g} 1/s"
                         + (f", Ki = {self.Ki[j]:.6g} 1/s^3 (integral pole "
                            f"{self.integral_bandwidth_hz[j]:.2f} Hz)" if self.Ki[j] else ""))
            if self.estimator == "observer":
                lines.append(
                    f"  observer L = [{self.observer_gain[j, 0]:.6g}, {self.observer_gain[j, 1]:.6g} 1/s]"
                )
            else:
                lines.append(f"  difference filter alpha = {self.alpha[j]:.6g}")
            for p, z, w in zip(self.poles[j], self.pole_damping[j], self.pole_frequency_hz[j]):
                lines.append(
                    f"  pole z = {p.real:+.6f}{p.imag:+.6f}j  |z| = {abs(p):.6f}  "
                    f"zeta = {z:.3f}  f_n = {w:.2f} Hz"
                )
            gm = self.gain_margin[j]
            gm_txt = "inf" if not math.isfinite(gm) else f"{gm:.3f} ({20 * math.log10(gm):.2f} dB)"
            lines.append(
                f"  gain margin {gm_txt} at {self.phase_crossover_hz[j]:.1f} Hz, "
                f"phase margin {self.phase_margin_deg[j]:.2f} deg at {self.crossover_hz[j]:.2f} Hz, "
                f"stability margin {self.stability_margin[j]:.3f}"
            )
        lines.append("stable: " + ("yes" if self.stable else "NO"))
        return "\n".join(lines)


def default_bandwidth_hz(rig_or_ts) -> np.ndarray:
    """Default loop bandwidth per joint (Hz): ``fs / 50``, faster for fine encoders.

    ``bw_j = fs * BANDWIDTH_FRACTION * clip(sqrt(N_j / REFERENCE_PPR), 1,
    MAX_RESOLUTION_FACTOR)`` with ``N_j`` the joint's encoder pulses per
    motor revolution.  Reason: a disturbance torque ``d`` that the model
    does not cancel (friction at a velocity reversal, current noise, a
    coupling torque) leaves a tracking error ``d / (D Kp)`` rad, i.e.
    ``d N / (2 pi D_m Kp)`` pulses on the motor-side encoder, and
    ``Kp ~ w^2``; keeping the error *in pulses* of a fine encoder at the
    level of a 1000-pulse one needs ``w ~ sqrt(N)``.  Coarse encoders keep
    ``fs / 50``: their one-pulse quantisation, multiplied by a higher ``Kp``,
    would put current noise into the drive that the inertia coupling passes
    on to the other joint.  Measured on the randomized robustness suite
    (``benchmarks/bench_robustness.py``): with one bandwidth for both
    joints, 7 of the 54 rigid robots (each with a 2000-4096 pulse encoder
    on one joint) missed +-1 pulse by one or two pulses at friction
    reversals; raising the bandwidth of both joints made them worse (up to
    11 pulses, from the coarse joint's quantisation), raising only the fine
    joint's fixed all seven.

    Parameters
    ----------
    rig_or_ts : plant.logs.rig.Rig, plant.ExperimentLog or float
        A rig (or log) with ``sample_time_s`` and ``encoder_ppr``; a bare
        sample time (s) gives ``fs / 50`` for both joints.

    Returns
    -------
    ndarray, shape (n_joints,)
        Bandwidth per joint (Hz): joints 2 and 3 of the PUMA links 2-3, the
        rig's joints in order for another robot.
    """
    rig = getattr(rig_or_ts, "rig", rig_or_ts)
    ts = float(getattr(rig, "sample_time_s", rig))
    base = BANDWIDTH_FRACTION / ts
    ppr = getattr(rig, "encoder_ppr", None)
    if ppr is None:
        return np.full(_n_joints(rig_or_ts), base)
    factor = np.clip(np.sqrt(np.asarray(ppr, dtype=float) / REFERENCE_PPR), 1.0, MAX_RESOLUTION_FACTOR)
    return base * factor


def _per_joint(x, n, name, positive=True):
    try:
        a = np.broadcast_to(np.asarray(x, dtype=float), (n,)).copy() if np.ndim(x) <= 1 else None
    except ValueError:
        a = None
    if a is None or a.shape != (n,) or not np.all(np.isfinite(a)) or (positive and np.any(a <= 0)):
        raise ValueError(f"{name} must be a finite positive number or {n} of them, got {x!r}")
    return a


def _n_joints(rig_or_ts) -> int:
    """Joints of a rig (its per-joint gear ratios), 2 (the PUMA links 2-3) for a bare Ts."""
    rig = getattr(rig_or_ts, "rig", rig_or_ts)
    k = getattr(rig, "gear_ratio", None)
    return 2 if k is None else len(k)


def design_gains(
    rig_or_ts,
    *,
    bandwidth_hz=None,
    damping=1.0,
    estimator="observer",
    estimator_bandwidth_hz=None,
    delay_samples=0,
    integral_bandwidth_hz=None,
) -> GainDesign:
    """Design Kp, Kv (and the velocity estimator) of the CTC outer loop.

    Parameters
    ----------
    rig_or_ts : plant.logs.rig.Rig, plant.ExperimentLog or float
        The rig (its sample time, and its encoders for the default
        bandwidth: after feedback linearisation the error dynamics do not
        depend on the robot) or Ts in s.
    bandwidth_hz : float or array_like (n_joints,), optional
        Natural frequency of the closed-loop error poles (Hz); default
        :func:`default_bandwidth_hz` (``fs / 50``, up to ``fs / 25`` for
        encoders finer than 1000 pulses per revolution).  Must stay below
        ``fs / 6``.
    damping : float or array_like (n_joints,)
        Damping ratio zeta of the error poles (> 0); default 1.
    estimator : {"observer", "difference"}
        Velocity estimator (see the module docstring).
    estimator_bandwidth_hz : float or array_like (n_joints,), optional
        Observer bandwidth, or cut-off of the difference low-pass (Hz);
        default 3x ``bandwidth_hz``.  Must stay below ``fs / 3``.
    delay_samples : int
        Computation delay (samples) assumed in the analysis; 0 for the
        simulator and the rig as logged.
    integral_bandwidth_hz : float or array_like (n_joints,), optional
        Integral action (a PID outer loop, ``a = qdd_d + Kv e' + Kp e + Ki sum(e Ts)``):
        the frequency (Hz) of its real error pole, placed with the two loop
        poles by Ackermann's formula on the augmented double integrator
        (``_pid_gains``); must stay below ``bandwidth_hz``.  None
        (default): no integral action, ``Ki = 0``.  The sum is frozen while
        the drive saturates (anti-windup by conditional integration).  It
        removes the steady part of the torque the model gets wrong (a
        payload's gravity, a spring-torque error of the flexible-joint CTC)
        that the PD loop leaves as an error of ``d / (D Kp)``.

    Returns
    -------
    GainDesign

    Raises
    ------
    ValueError
        Non-positive or non-finite bandwidths or damping, bandwidths too
        close to the Nyquist rate, an integral pole not below the loop
        bandwidth, unknown estimator, negative delay.
    """
    import control

    ts = rig_or_ts
    rig = getattr(rig_or_ts, "rig", rig_or_ts)
    if hasattr(rig, "sample_time_s"):
        ts = rig.sample_time_s
    try:
        ts = float(ts)
    except (TypeError, ValueError):
        raise ValueError(f"rig_or_ts must be a Rig, a log or a sample time, got {rig_or_ts!r}") from None
    if not (math.isfinite(ts) and ts > 0):
        raise ValueError(f"sample time must be finite and > 0, got {ts!r}")
    fs = 1.0 / ts
    if estimator not in ESTIMATORS:
        raise ValueError(f"estimator must be one of {ESTIMATORS}, got {estimator!r}")
    d = int(delay_samples)
    if d < 0 or d != delay_samples:
        raise ValueError(f"delay_samples must be an integer >= 0, got {delay_samples!r}")
    nj = _n_joints(rig_or_ts)
    bw = _per_joint(default_bandwidth_hz(rig_or_ts) if bandwidth_hz is None else bandwidth_hz, nj,
                    "bandwidth_hz")
    zeta = _per_joint(damping, nj, "damping")
    if np.any(bw >= fs / 6.0):
        raise ValueError(f"bandwidth_hz must be < fs/6 = {fs / 6:.1f} Hz, got {bw.tolist()}")
    factor = OBSERVER_FACTOR if estimator == "observer" else DIFFERENCE_FACTOR
    ebw = _per_joint(factor * bw if estimator_bandwidth_hz is None else estimator_bandwidth_hz, nj,
                     "estimator_bandwidth_hz")
    if np.any(ebw >= fs / 3.0):
        raise ValueError(f"estimator_bandwidth_hz must be < fs/3 = {fs / 3:.1f} Hz, got {ebw.tolist()}")
    ibw = np.zeros(nj)
    if integral_bandwidth_hz is not None:
        ibw = _per_joint(integral_bandwidth_hz, nj, "integral_bandwidth_hz")
        if np.any(ibw >= bw):
            raise ValueError(f"integral_bandwidth_hz must be below bandwidth_hz {bw.tolist()}, "
                             f"got {ibw.tolist()}")

    kp = np.empty(nj)
    kv = np.empty(nj)
    ki = np.zeros(nj)
    lg = np.zeros((nj, 2))
    alpha = np.zeros(nj)
    poles, pz, pw = [], [], []
    gm = np.empty(nj)
    pm = np.empty(nj)
    sm = np.empty(nj)
    wg = np.empty(nj)
    wp = np.empty(nj)
    plant = double_integrator(ts, d)
    for j in range(nj):
        w = 2.0 * math.pi * bw[j]
        if ibw[j]:
            kp[j], kv[j], ki[j] = _pid_gains(ts, w, zeta[j], 2.0 * math.pi * ibw[j])
        else:
            kp[j], kv[j] = _pd_gains(ts, w, zeta[j])
        if estimator == "observer":
            lg[j] = _observer_gain(ts, 2.0 * math.pi * ebw[j])
        else:
            alpha[j] = math.exp(-2.0 * math.pi * ebw[j] * ts)
        comp = _compensator(ts, kp[j], kv[j], estimator, lg[j], alpha[j], ki[j])
        cl = control.feedback(plant, comp)
        p = np.asarray(control.poles(cl), dtype=complex)
        wn, z, _ = control.damp(cl, doprint=False)
        order = np.argsort(-np.abs(p))
        poles.append(p[order])
        # damp returns its values in the order of control.poles
        pz.append(np.asarray(z)[order])
        pw.append(np.asarray(wn)[order] / (2.0 * math.pi))
        g, m, s, w_g, w_p = _margins(control.series(plant, comp))
        gm[j], pm[j], sm[j] = g, m, s
        wg[j], wp[j] = w_p / (2.0 * math.pi), w_g / (2.0 * math.pi)
    return GainDesign(
        ts=ts, Kp=kp, Kv=kv, Ki=ki, estimator=estimator, observer_gain=lg, alpha=alpha,
        bandwidth_hz=bw, damping=zeta, estimator_bandwidth_hz=ebw, integral_bandwidth_hz=ibw,
        delay_samples=d,
        poles=poles, pole_damping=pz, pole_frequency_hz=pw,
        gain_margin=gm, phase_margin_deg=pm, stability_margin=sm,
        crossover_hz=wg, phase_crossover_hz=wp,
    )


def gains_for(rig, gains=None, **design):
    """Ready-made gains, or a design for the rig from keywords (not both).

    Parameters
    ----------
    rig : plant.logs.rig.Rig
        The rig the gains are designed for.
    gains : GainDesign, optional
        Ready-made gains, returned as they are.
    **design
        Keyword arguments of :func:`design_gains` (when ``gains`` is None).

    Returns
    -------
    GainDesign

    Raises
    ------
    ValueError
        If ``gains`` and design keywords are both given, or as
        :func:`design_gains`.
    """
    if gains is None:
        return design_gains(rig, **design)
    if design:
        raise ValueError(f"give either gains or design keywords, not both ({sorted(design)})")
    return gains
