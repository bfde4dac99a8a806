"""An independent PUMA 560 links-2/3 rig simulator: the robot the library has never seen.

Why it exists
-------------
The library's identification is tested on logs made by its own plant
(``plant.emulate_log``): a bug shared by the plant that writes a log and the
plant that fits it cancels out.  This module makes logs with code that shares
*nothing* with the library's plant:

* **rigid link dynamics**: Robotics Toolbox for Python
  (``roboticstoolbox.models.DH.Puma560``, standard DH, Corke's published
  masses, centres of mass and inertias; its C recursive Newton-Euler
  ``rne``), not the library's casadi/numba model.  Friction and motor
  inertia are removed from the RTB links (the drive below adds its own), a
  payload is merged into link 6 (mass, centre of mass in frame 6, inertia
  about the centre of mass), joints 1, 4, 5, 6 are locked at 0;
* **convention map** (paper <-> RTB, joints 2 and 3):
  ``q_rtb = -q_paper``, ``tau_paper = -tau_rtb`` (the truth files' map;
  checked against the library's model in ``tests/test_independent_logs.py``
  and in :func:`check_convention`, which is never called by the simulator);
* **drive**, written here from the rig description: motor-shaft encoders
  ``count = trunc(th k N / 2 pi)``, integer error
  ``e = trunc(q_ref k N / 2 pi) - count``, current ``i = u`` from the sampled
  controller (``P e`` for the rig's card), saturated at
  ``current_full_scale_A`` and held over the sample, joint torque
  ``k Kt i``; motor-side viscous ``B`` and asymmetric Coulomb
  ``[Tc+, Tc-]`` (by the sign of the joint velocity) ramping linearly to
  zero below the motor speed ``v_reg``; on the joint side ``k^2 B`` and
  ``|k| Tc``;
* **joints**: rigid (state ``q, qd``; reflected motor inertia ``Jm k^2`` on
  the link inertia diagonal), or Spong two-mass flexible::

      Jm k^2 th'' = k Kt i + tau_friction(th') - tau_s
      M(q) q'' + c(q, q') + g(q) = tau_s
      tau_s = K (delta - clip(delta, -b/2, b/2)) + D delta',  delta = th - q

  with a backlash dead zone of total width ``b`` (only in flexible draws:
  a rigid joint has no spring to put the dead zone on).  The encoder reads
  ``th``.  At t = 0 the robot is at rest at ``q0`` with the springs relaxed
  (``th = q``; the brakes release at t = 0), as in the development logs;
* **integration**: ``scipy.integrate.solve_ivp(method="DOP853",
  rtol=1e-9, atol=1e-12)`` restarted at every sample (zero-order hold of the
  current), ``max_step = Ts`` (``Ts/4`` when a backlash dead zone is
  present, :func:`max_step_fraction`).  The right-hand side is continuous but has
  kinks (dead-zone edges, the Coulomb ramp edges at ``|k w| = v_reg``); the
  adaptive error control of DOP853 shrinks the step around them, and the
  ``max_step`` keeps it from stepping across a whole short excursion into or
  out of the dead zone.  :func:`integration_check` reruns a log with
  ``rtol=1e-11, atol=1e-14, max_step=Ts/16`` and counts changed pulses.

Only the *reference* comes from the library: ``plant.logs.trajectory.Trajectory``
evaluates the sidecar's ``trajectory.parameters`` formula, so the logged
``q2_ref_rad``/``q3_ref_rad`` and the reference counts are exactly what the
library will compute from the sidecar.  Writing the log uses the library's
``ExperimentLog.replace`` / ``save`` (the file format), never its plant.

Truth: the rigid-equivalent f1..f9 are the least-squares projection of RTB's
``rne`` (payload included) plus ``Jm k^2 qdd`` onto the paper regressor
(``plant.regressor`` defines the parameterisation only), at 500 random
states; the relative residual is ~1e-15 when the map is right.
"""
from __future__ import annotations

import copy
import dataclasses
import json
import math
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp
from scipy.linalg import expm

__all__ = [
    "RobotSettings", "IndependentRobot", "PCard", "build_rtb_puma", "rigid_equivalent_truth",
    "make_log", "PAPER_F_RANGES", "stability_radius", "integration_check",
]

#: The paper's initial search ranges of f1..f9 (as in the development sidecars).
PAPER_F_RANGES = {
    "f1": [0.28, 4.07], "f2": [0.0, 2.33], "f3": [-0.2, 0.2], "f4": [-1.25, 0.0],
    "f5": [-0.4, 0.4], "f6": [-2.5, 0.0], "f7": [2.23, 17.95], "f8": [-1.75, 1.75],
    "f9": [-2.7, 11.25],
}
F_NAMES = tuple(PAPER_F_RANGES)

#: Paper <-> RTB map of joints 2 and 3: q_rtb = S q_paper, tau_paper = S tau_rtb.
S_MAP = -1.0

REPO = Path(__file__).resolve().parents[1]
TEMPLATE_LOG = REPO / "tests" / "data" / "puma560_paper_drill_flex.csv"


# ----------------------------------------------------------------------------- settings
@dataclasses.dataclass
class RobotSettings:
    """Everything that defines one simulated rig run (all per-joint pairs: joint 2, joint 3).

    Motor-side drive constants (``jm_kgm2``, ``viscous_B``, ``coulomb_Tc``,
    ``v_reg``) follow the sidecar's conventions; ``K``, ``D`` and ``backlash``
    are joint side.  ``payload`` is None or ``{"mass_kg", "com_m_rtb_frame6",
    "inertia_about_com_kgm2"}`` (RTB link-6 frame, inertia diagonal about the
    COM).
    """

    sample_time_s: float = 0.0007
    gear_ratio: tuple = (107.8, -53.7)
    encoder_ppr: tuple = (1000, 1000)
    p_gain: tuple = (0.15, 0.15)
    kt: tuple = (0.22, 0.22)
    jm_kgm2: tuple = (200e-6, 200e-6)
    viscous_B: tuple = (0.006817, 0.00738)
    coulomb_Tc: tuple = ((0.071, 0.126), (0.105, 0.132))
    v_reg: float = 0.5
    flexible: bool = False
    K: tuple | None = None
    D: tuple | None = None
    backlash_rad: tuple = (0.0, 0.0)
    payload: dict | None = None
    current_full_scale_A: float = 15.0
    current_noise_std_A: float = 0.0
    gravity: float = 9.81
    q0: tuple = (0.0, 0.0)
    trajectory: dict | None = None  # sidecar "trajectory.parameters"
    duration_s: float = 3.65
    friction_known: bool = True
    payload_known: bool = True

    def to_dict(self) -> dict:
        return json.loads(json.dumps(dataclasses.asdict(self)))

    @classmethod
    def from_dict(cls, d: dict) -> "RobotSettings":
        names = {f.name for f in dataclasses.fields(cls)}
        return cls(**{k: v for k, v in d.items() if k in names})

    @property
    def n_samples(self) -> int:
        return int(round(self.duration_s / self.sample_time_s)) + 1


# ----------------------------------------------------------------------------- RTB model
def build_rtb_puma(payload: dict | None = None):
    """RTB's Puma560 with friction and motor inertia removed and the payload merged into link 6.

    Returns
    -------
    roboticstoolbox.DHRobot
    """
    import roboticstoolbox as rtb

    robot = rtb.models.DH.Puma560().nofriction(coulomb=True, viscous=True)
    for link in robot.links:
        link.Jm = 0.0
        link.B = 0.0
        link.Tc = np.zeros(2)
    if payload is not None and float(payload.get("mass_kg", 0.0)) > 0.0:
        L = robot.links[5]
        m6, r6, I6 = float(L.m), np.asarray(L.r, float).copy(), np.asarray(L.I, float).copy()
        mp = float(payload["mass_kg"])
        rp = np.asarray(payload.get("com_m_rtb_frame6", [0, 0, 0]), float)
        Ip = np.asarray(payload.get("inertia_about_com_kgm2", [0, 0, 0]), float)
        Ip = np.diag(Ip) if Ip.ndim == 1 else Ip
        m = m6 + mp
        r = (m6 * r6 + mp * rp) / m

        def shift(mass, d):  # parallel axis: inertia of a point mass at d about the origin
            return mass * (float(d @ d) * np.eye(3) - np.outer(d, d))

        I = I6 + shift(m6, r6 - r) + Ip + shift(mp, rp - r)
        L.m, L.r, L.I = m, r, I
    robot.dynchanged()  # RTB caches the C rne's parameters: refresh after editing links
    # guard: the C rne must see the edited links (compare with RTB's pure-Python rne)
    q = np.array([0.0, -0.3, 0.7, 0.0, 0.0, 0.0])
    qd = np.array([0.0, 0.4, -1.1, 0.0, 0.0, 0.0])
    qdd = np.array([0.0, 1.3, 0.2, 0.0, 0.0, 0.0])
    a, b = robot.rne(q, qd, qdd), robot.rne_python(q, qd, qdd)
    if not np.allclose(a, b, rtol=1e-10, atol=1e-10):
        raise RuntimeError(f"RTB C rne disagrees with rne_python: {a} vs {b}")
    return robot


class _Rigid23:
    """Joints 2-3 rigid-body dynamics from RTB in the paper convention (link only, no motor)."""

    def __init__(self, robot, gravity: float):
        self.robot = robot
        self.g = np.array([0.0, 0.0, -gravity])  # RTB: the gravity acceleration vector (robot.gravity)
        # rows: (q, qd, 0) -> bias; (q, 0, e2), (q, 0, e3) -> M column + gravity; (q, 0, 0) -> gravity
        self._Q = np.zeros((4, 6))
        self._QD = np.zeros((4, 6))
        self._QDD = np.zeros((4, 6))
        self._QDD[1, 1] = 1.0
        self._QDD[2, 2] = 1.0

    def dynamics(self, q, qd):
        """M (2, 2) and bias (2,) in the paper convention (tau = M qdd + bias).

        One C ``rne`` call on four rows (RTB convention, joints 1, 4, 5, 6 at 0):
        (q, qd, 0) -> bias b_rtb; (q, 0, e_j) -> M_rtb e_j + g_rtb; (q, 0, 0) -> g_rtb.
        With q_rtb = S q, tau_p = S tau_rtb(S q, S qd, S qdd) = M_rtb qdd + S b_rtb (S^2 = 1).
        """
        Q, QD = self._Q, self._QD
        Q[:, 1] = S_MAP * q[0]
        Q[:, 2] = S_MAP * q[1]
        QD[0, 1] = S_MAP * qd[0]
        QD[0, 2] = S_MAP * qd[1]
        tau = self.robot.rne(Q, QD, self._QDD, gravity=self.g)
        g_rtb = tau[3, 1:3]
        M = np.empty((2, 2))
        M[:, 0] = tau[1, 1:3] - g_rtb
        M[:, 1] = tau[2, 1:3] - g_rtb
        return M, S_MAP * tau[0, 1:3]


# ----------------------------------------------------------------------------- drive
def _friction(w, kg, B, tc_pos, tc_neg, v_reg):
    """Joint-side drive friction torque (2,) at joint speed w (2,) (paper convention).

    ``-(k^2 B w + |k| Tc(sign w) clip(|k| w / v_reg, -1, 1))``.
    """
    ak = np.abs(kg)
    tc = np.where(w >= 0.0, tc_pos, tc_neg)
    return -(kg * kg * B * w + ak * tc * np.clip(ak * w / v_reg, -1.0, 1.0))


class PCard:
    """The rig card's P law ``i = P e`` (sampled-controller protocol), written here."""

    def __init__(self, p_gain):
        self.p = np.asarray(p_gain, dtype=float)

    def reset(self):
        pass

    def __call__(self, k, t, q_meas, e_pulses):
        return self.p * np.asarray(e_pulses, dtype=float)


class IndependentRobot:
    """The simulated rig: RTB links 2-3 + the drive above, rigid or two-mass flexible joints.

    Parameters
    ----------
    settings : RobotSettings
    """

    def __init__(self, settings: RobotSettings):
        self.s = settings
        self.robot = build_rtb_puma(settings.payload)
        self.links = _Rigid23(self.robot, settings.gravity)
        s = settings
        self.kg = np.asarray(s.gear_ratio, float)
        self.ppr = np.asarray(s.encoder_ppr, float)
        # pulses per joint radian: the same expression as the sidecar's rig (k N / (2 pi))
        self.pulses_per_rad = np.array([k * n / (2.0 * math.pi) for k, n in zip(s.gear_ratio, s.encoder_ppr)])
        self.kkt = self.kg * np.asarray(s.kt, float)
        self.jref = np.asarray(s.jm_kgm2, float) * self.kg ** 2  # reflected motor inertia
        self.B = np.asarray(s.viscous_B, float)
        tc = np.asarray(s.coulomb_Tc, float).reshape(2, 2)
        self.tc_pos, self.tc_neg = tc[:, 0].copy(), tc[:, 1].copy()
        self.v_reg = float(s.v_reg)
        self.flexible = bool(s.flexible)
        if self.flexible:
            self.K = np.asarray(s.K, float)
            self.D = np.asarray(s.D, float)
            self.half_b = 0.5 * np.asarray(s.backlash_rad, float)
        self.i_fs = float(s.current_full_scale_A) if s.current_full_scale_A else math.inf
        self.nfev = 0

    # ---------------------------------------------------------------- dynamics
    def friction(self, w):
        return _friction(w, self.kg, self.B, self.tc_pos, self.tc_neg, self.v_reg)

    def spring(self, q, qd, th, thd):
        delta = th - q
        return self.K * (delta - np.clip(delta, -self.half_b, self.half_b)) + self.D * (thd - qd)

    def rhs(self, t, y, i):
        self.nfev += 1
        if not self.flexible:
            q, qd = y[0:2], y[2:4]
            M, bias = self.links.dynamics(q, qd)
            M = M + np.diag(self.jref)
            tau = self.kkt * i + self.friction(qd) - bias
            return np.concatenate([qd, np.linalg.solve(M, tau)])
        q, qd, th, thd = y[0:2], y[2:4], y[4:6], y[6:8]
        M, bias = self.links.dynamics(q, qd)
        ts = self.spring(q, qd, th, thd)
        qdd = np.linalg.solve(M, ts - bias)
        thdd = (self.kkt * i + self.friction(thd) - ts) / self.jref
        return np.concatenate([qd, qdd, thd, thdd])

    def required_current(self, trajectory, n_samples: int, stride: int = 5) -> np.ndarray:
        """Peak motor current (2,) A the reference needs by inverse dynamics (rigid-equivalent).

        ``i = (M(q) qdd + b(q, qd) + Jm k^2 qdd - tau_f(qd)) / (k Kt)`` along
        ``q_ref`` at every ``stride``-th sample: the current a perfect tracker
        would draw (the feasibility of the experiment for the drive).
        """
        t = np.arange(0, n_samples, stride) * self.s.sample_time_s
        q, qd, qdd = trajectory.evaluate(t)
        peak = np.zeros(2)
        for k in range(len(t)):
            M, bias = self.links.dynamics(q[k], qd[k])
            tau = M @ qdd[k] + bias + self.jref * qdd[k] - self.friction(qd[k])
            peak = np.maximum(peak, np.abs(tau / self.kkt))
        return peak

    def initial_state(self):
        q0 = np.asarray(self.s.q0, float)
        x = np.concatenate([q0, np.zeros(2)])
        return np.concatenate([x, x]) if self.flexible else x

    def encoder_angle(self, y):
        return y[4:6] if self.flexible else y[0:2]

    # ---------------------------------------------------------------- run
    def run(self, controller, trajectory, n_samples: int, *, rtol=1e-9, atol=1e-12,
            max_step_fraction=0.25, record_state=False, max_abs_e=1e6, changes=()):
        """Run a sampled controller on the robot along ``trajectory`` for ``n_samples``.

        Parameters
        ----------
        controller : object with ``reset()`` and ``__call__(k, t, q_meas, e_pulses) -> (2,)``
            (the library's sampled-controller protocol, ``ctc/protocol.py``).
        trajectory : plant.logs.trajectory.Trajectory
            The reference (evaluated at t_k = k Ts).
        n_samples : int
        max_abs_e : float
            Stop (``success`` False, "diverged") once an error exceeds this
            many pulses; the remaining rows repeat the last error.
        changes : sequence of (int, IndependentRobot)
            Mid-run plant switches: from sample ``k`` on, the robot's
            dynamics are the given robot's (same joint model, so the state
            carries over; encoder, gears and current limit stay this robot's).

        Returns
        -------
        dict
            ``t`` (n,), ``q_ref`` (n, 2), ``e`` (n, 2) int64, ``i`` (n, 2)
            applied (saturated) currents, ``i_cmd`` (n, 2) commanded,
            ``n_saturated`` (samples with a clipped joint), ``success``,
            ``message``, ``nfev``; ``y`` (n, nx) states at t_k with
            ``record_state``.
        """
        ts = float(self.s.sample_time_s)
        n = int(n_samples)
        t = np.arange(n) * ts
        q_ref = np.ascontiguousarray(trajectory.position(t), dtype=float)
        ref_counts = np.trunc(q_ref * self.pulses_per_rad)
        E = np.zeros((n, 2), dtype=np.int64)
        I = np.zeros((n, 2))
        Icmd = np.zeros((n, 2))
        Y = np.zeros((n, 8 if self.flexible else 4)) if record_state else None
        y = self.initial_state()
        n_sat = 0
        controller.reset()
        ok, msg = True, "ok"
        max_step = ts * float(max_step_fraction)
        switches = sorted(((int(kc), r) for kc, r in changes), key=lambda c: c[0])
        for kc, r in switches:
            if r.flexible != self.flexible:
                raise ValueError("a mid-run change must keep the joint model (rigid or flexible)")
        rhs = self.rhs
        for k in range(n):
            while switches and k >= switches[0][0]:
                rhs = switches.pop(0)[1].rhs
            if record_state:
                Y[k] = y
            count = np.trunc(self.encoder_angle(y) * self.pulses_per_rad)
            e = (ref_counts[k] - count).astype(np.int64)
            q_meas = count / self.pulses_per_rad
            u = np.asarray(controller(k, t[k], q_meas, e), dtype=float).reshape(2)
            Icmd[k] = u
            i = np.clip(u, -self.i_fs, self.i_fs)
            if np.any(i != u):
                n_sat += 1
            E[k], I[k] = e, i
            if k == n - 1:
                break
            if not np.all(np.isfinite(i)) or np.max(np.abs(e)) > max_abs_e:
                ok, msg = False, f"diverged at sample {k} (e = {e.tolist()})"
                E[k + 1:] = E[k]
                break
            sol = solve_ivp(rhs, (t[k], t[k] + ts), y, method="DOP853", rtol=rtol,
                            atol=atol, max_step=max_step, args=(i,))
            if not sol.success or not np.all(np.isfinite(sol.y[:, -1])):
                ok, msg = False, f"integration failed at sample {k}: {sol.message}"
                E[k + 1:] = E[k]
                break
            y = sol.y[:, -1]
        out = dict(t=t, q_ref=q_ref, e=E, i=I, i_cmd=Icmd, n_saturated=n_sat, success=ok,
                   message=msg, nfev=self.nfev)
        if record_state:
            out["y"] = Y
        return out

    # ---------------------------------------------------------------- linear stability
    def linear_loop_radius(self, q_pose, p_gain=None) -> float:
        """Spectral radius of the linearised sampled P loop at a pose (quantisation, Coulomb ignored).

        The continuous plant is linearised by central differences about
        rest at ``q_pose`` (gravity held by a constant current, not part of
        the loop), discretised exactly with a zero-order hold, and closed
        with ``i = -P (k N / 2 pi) th``.  The Coulomb friction is left out
        (its steep ramp near zero speed would count as damping), so the
        test is conservative.
        """
        p = np.asarray(self.s.p_gain if p_gain is None else p_gain, float)
        saved = self.tc_pos.copy(), self.tc_neg.copy()
        self.tc_pos[:] = 0.0
        self.tc_neg[:] = 0.0
        try:
            q = np.asarray(q_pose, float)
            _, bias = self.links.dynamics(q, np.zeros(2))
            i0 = bias / self.kkt  # holding current
            x0 = np.concatenate([q, np.zeros(2)])
            if self.flexible:
                # static deflection holding gravity (inside the dead zone's linear branch)
                defl = bias / self.K + np.sign(bias) * self.half_b
                x0 = np.concatenate([x0, q + defl, np.zeros(2)])
            nx = x0.size
            A = np.zeros((nx, nx))
            Bm = np.zeros((nx, 2))
            for j in range(nx):
                h = 1e-7 * max(1.0, abs(x0[j]))
                dx = np.zeros(nx)
                dx[j] = h
                A[:, j] = (self.rhs(0, x0 + dx, i0) - self.rhs(0, x0 - dx, i0)) / (2 * h)
            for j in range(2):
                di = np.zeros(2)
                di[j] = 1e-4
                Bm[:, j] = (self.rhs(0, x0, i0 + di) - self.rhs(0, x0, i0 - di)) / 2e-4
        finally:
            self.tc_pos[:], self.tc_neg[:] = saved
        ts = float(self.s.sample_time_s)
        aug = np.zeros((nx + 2, nx + 2))
        aug[:nx, :nx] = A * ts
        aug[:nx, nx:] = Bm * ts
        Ed = expm(aug)
        Ad, Bd = Ed[:nx, :nx], Ed[:nx, nx:]
        C = np.zeros((2, nx))
        enc = 4 if self.flexible else 0
        C[0, enc] = 1.0
        C[1, enc + 1] = 1.0
        Kfb = np.diag(p * self.pulses_per_rad)
        Acl = Ad - Bd @ Kfb @ C
        return float(np.max(np.abs(np.linalg.eigvals(Acl))))


def stability_radius(settings: RobotSettings, poses=((0.0, 0.0), (-0.8, 0.8), (-1.0, -1.0), (0.5, 1.5))) -> float:
    """Largest spectral radius of the linearised sampled P loop over a few poses."""
    rob = IndependentRobot(settings)
    return max(rob.linear_loop_radius(p) for p in poses)


# ----------------------------------------------------------------------------- truth
def rigid_equivalent_truth(settings: RobotSettings, n_states: int = 500, seed: int = 12345) -> dict:
    """Rigid-equivalent f1..f9: least squares of RTB rne (+ Jm k^2 qdd) on the paper regressor.

    Returns ``f`` (9,), ``rel_residual``, ``max_abs_residual_Nm``,
    ``condition_number`` and ``physical_consistency`` (f3 - a3 f5,
    f4 - a3 f6, f1 - f2 - Jm3 k3^2).
    """
    from plant.robot.model import regressor  # the parameterisation only (tau = Y f)

    robot = build_rtb_puma(settings.payload)
    g = np.array([0.0, 0.0, -settings.gravity])  # RTB: gravity acceleration vector
    rng = np.random.default_rng(seed)
    q = rng.uniform(-math.pi, math.pi, (n_states, 2))
    qd = rng.normal(0.0, 2.0, (n_states, 2))
    qdd = rng.normal(0.0, 10.0, (n_states, 2))
    Q = np.zeros((n_states, 6))
    QD = np.zeros((n_states, 6))
    QDD = np.zeros((n_states, 6))
    Q[:, 1:3], QD[:, 1:3], QDD[:, 1:3] = S_MAP * q, S_MAP * qd, S_MAP * qdd
    tau_rtb = np.asarray(robot.rne(Q, QD, QDD, gravity=g))[:, 1:3]
    kg = np.asarray(settings.gear_ratio, float)
    jref = np.asarray(settings.jm_kgm2, float) * kg ** 2
    tau = S_MAP * tau_rtb + jref[None, :] * qdd
    Y = regressor(q, qd, qdd, settings.gravity).reshape(-1, 9)
    b = tau.reshape(-1)
    f, *_ = np.linalg.lstsq(Y, b, rcond=None)
    r = Y @ f - b
    a3 = float(robot.links[1].a)
    return dict(
        f=f, rel_residual=float(np.linalg.norm(r) / np.linalg.norm(b)),
        max_abs_residual_Nm=float(np.max(np.abs(r))),
        condition_number=float(np.linalg.cond(Y / np.linalg.norm(Y, axis=0))),
        a3_m=a3,
        physical_consistency=dict(
            f3_minus_a3_f5=float(f[2] - a3 * f[4]), f4_minus_a3_f6=float(f[3] - a3 * f[5]),
            f1_minus_f2_minus_Jm3_k3sq=float(f[0] - f[1] - jref[1])),
        reflected_motor_inertia_kgm2=jref.tolist(),
    )


def check_convention(f, settings: RobotSettings | None = None, n: int = 200, seed: int = 7) -> float:
    """Relative difference between this simulator's rigid dynamics and ``plant.inverse_dynamics(f)``.

    For tests and check scripts only (the simulator never calls the library's model).
    ``f`` must be the rigid-equivalent truth of ``settings`` (motor inertia
    included).  Returns max |tau_sim - tau_lib| / max |tau_lib| over random states.
    """
    import plant

    settings = settings or RobotSettings()
    rob = IndependentRobot(dataclasses.replace(settings, flexible=False))
    rng = np.random.default_rng(seed)
    worst, scale = 0.0, 0.0
    for _ in range(n):
        q = rng.uniform(-math.pi, math.pi, 2)
        qd = rng.normal(0, 2, 2)
        qdd = rng.normal(0, 10, 2)
        M, bias = rob.links.dynamics(q, qd)
        tau_sim = (M + np.diag(rob.jref)) @ qdd + bias
        tau_lib = plant.inverse_dynamics(f, q, qd, qdd, settings.gravity)
        worst = max(worst, float(np.max(np.abs(tau_sim - tau_lib))))
        scale = max(scale, float(np.max(np.abs(tau_lib))))
    return worst / scale


# ----------------------------------------------------------------------------- logs
def widened_ranges(f, margin: float = 0.25) -> tuple[dict, list]:
    """The paper's ranges, widened where the truth falls outside (by ``margin`` of the range width)."""
    ranges = copy.deepcopy(PAPER_F_RANGES)
    widened = []
    for name, v in zip(F_NAMES, np.asarray(f, float)):
        lo, hi = ranges[name]
        w = hi - lo
        if v < lo + 0.02 * w:
            ranges[name] = [float(v - margin * w), hi]
            widened.append(dict(name=name, truth=float(v), paper=[lo, hi], new=ranges[name]))
        elif v > hi - 0.02 * w:
            ranges[name] = [lo, float(v + margin * w)]
            widened.append(dict(name=name, truth=float(v), paper=[lo, hi], new=ranges[name]))
    return ranges, widened


def make_log(settings: RobotSettings, stem_path, *, rng=None, name=None, extra_truth=None):
    """Simulate the P-control experiment and write ``STEM.csv``, ``STEM.json``, ``STEM.truth.json``.

    The log object is built from the development template log with the
    library's ``ExperimentLog.replace`` (new rig, trajectory and columns) and
    written with ``ExperimentLog.save`` (the library's file format).

    Parameters
    ----------
    settings : RobotSettings
    stem_path : str or Path
        ``DIR/STEM`` (no extension).
    rng : numpy.random.Generator, optional
        Source of the logged current noise.
    extra_truth : dict, optional
        Added to the truth file (e.g. the draw's seed).

    Returns
    -------
    dict
        ``csv`` path, ``truth`` dict, ``run`` summary.
    """
    import time

    import plant
    from plant.logs.rig import Rig
    from plant.logs.trajectory import Trajectory

    s = settings
    stem_path = Path(stem_path)
    name = stem_path.name if name is None else name
    traj = Trajectory.from_sidecar(s.trajectory, source=name)
    truth = rigid_equivalent_truth(s)
    f = truth["f"]
    ranges, widened = widened_ranges(f)
    rob = IndependentRobot(s)
    t0 = time.perf_counter()
    run = rob.run(PCard(s.p_gain), traj, s.n_samples, max_step_fraction=max_step_fraction(s))
    sim_time = time.perf_counter() - t0
    if not run["success"]:
        raise RuntimeError(f"{name}: the independent robot failed: {run['message']}")
    rng = np.random.default_rng(rng)
    i_log = run["i"].copy()
    if s.current_noise_std_A > 0:
        i_log = i_log + rng.normal(0.0, s.current_noise_std_A, i_log.shape)

    base = plant.load_log(TEMPLATE_LOG)
    visc = tuple(float(x) for x in s.viscous_B) if s.friction_known else None
    coul = tuple(tuple(float(v) for v in r) for r in s.coulomb_Tc) if s.friction_known else None
    mass = 0.0 if not s.payload else float(s.payload["mass_kg"])
    rig = Rig(
        sample_time_s=float(s.sample_time_s), gear_ratio=tuple(float(x) for x in s.gear_ratio),
        encoder_ppr=tuple(int(x) for x in s.encoder_ppr),
        p_gain_A_per_pulse=tuple(float(x) for x in s.p_gain),
        torque_constant_Nm_per_A=tuple(float(x) for x in s.kt),
        viscous_friction_Nms_per_rad=visc, coulomb_friction_Nm=coul,
        coulomb_ramp_speed_rad_per_s=float(s.v_reg), gravity_m_s2=float(s.gravity),
        a3_m=float(truth["a3_m"]), q0_rad=tuple(float(x) for x in s.q0), qd0_rad_per_s=(0.0, 0.0),
        f_bounds=tuple((float(ranges[n][0]), float(ranges[n][1])) for n in F_NAMES),
        current_full_scale_A=float(s.current_full_scale_A),
        payload_mass_kg=mass if s.payload_known else None,
    )
    sc = copy.deepcopy(dict(base.sidecar))
    for key in ("viscous_friction_note", "trajectory", "current_measurement_noise_std_A"):
        sc.pop(key, None)
    sc["dataset"] = name
    sc["description"] = ("independent simulator (benchmarks/independent_robot.py: RTB Puma560 links, "
                         "drive written afresh); " + ("flexible" if s.flexible else "rigid") + " joints"
                         + (f", {mass:g} kg payload" if mass > 0 else "")
                         + ("" if s.friction_known else ", friction unknown"))
    sc["coulomb_friction_note"] = (
        "motor side, per joint [magnitude when the joint velocity (paper convention) is positive, "
        "magnitude when negative]; opposes motion; joint side = |k| * value; it ramps linearly to "
        f"zero for |motor speed| below {s.v_reg!r} rad/s (no stiction)")
    sc["coulomb_ramp_speed_rad_per_s"] = float(s.v_reg)
    if not s.friction_known:
        sc["friction_note"] = "drive friction unknown (null): to be identified"
    sc["trajectory"] = {"angles": "rad, paper convention (q = 0: DH zero configuration, upper arm horizontal)",
                        "duration_s": float(s.duration_s)}
    sc["payload"] = ({"description": "tool rigidly attached to the flange", "mass_kg": mass}
                     if mass > 0 else None)
    if mass > 0 and not s.payload_known:
        sc["payload"]["mass_kg"] = None
    sc["gearbox_compliance"] = bool(s.flexible)
    sc["current_measurement_noise_std_A"] = float(s.current_noise_std_A)
    sc["current_full_scale_A"] = float(s.current_full_scale_A)
    sc["f_search_ranges_note"] = ("the paper's initial search ranges" if not widened else
                                  "the paper's initial search ranges, widened where the truth falls "
                                  "outside: " + ", ".join(w["name"] for w in widened))
    log = base.replace(path=stem_path.with_suffix(".csv"), name=name, t=run["t"], q_ref=run["q_ref"],
                       e_pulses=run["e"], i_A=i_log, rig=rig, trajectory=traj, start_index=0,
                       window_s=None, sidecar=sc)
    log = log.replace()  # sync the sidecar with rig / trajectory / n_samples
    csv = log.save(stem_path)
    fv = [float(x) for x in f]
    truth_doc = {
        "dataset": name,
        "f": dict(zip(F_NAMES, fv)),
        "f_vector": fv,
        "regression_rel_residual": truth["rel_residual"],
        "regression_max_abs_residual_Nm": truth["max_abs_residual_Nm"],
        "regressor_condition_number": truth["condition_number"],
        "physical_consistency": truth["physical_consistency"],
        "f_ranges_widened": widened,
        "within_paper_ranges": not widened,
        "convention_map": {"formula": "q_rtb = -q_paper (joints 2 and 3); tau_paper = -tau_rtb",
                           "s": [-1, -1], "offset_rad": [0.0, 0.0]},
        "how_computed": ("RTB Puma560 (friction and motor inertia removed, payload merged into link 6) "
                         "rne at 500 random (q2, q3, qd, qdd), joints 1,4,5,6 at 0, mapped to the paper "
                         "convention, plus Jm k^2 qdd (f1: joint 3, f7: joint 2), regressed by least "
                         "squares on the paper regressor (plant.regressor)"),
        "joints": {
            "model": "flexible" if s.flexible else "rigid",
            "stiffness_Nm_per_rad": None if not s.flexible else [float(x) for x in s.K],
            "damping_Nms_per_rad": None if not s.flexible else [float(x) for x in s.D],
            "backlash_rad": [float(x) for x in s.backlash_rad] if s.flexible else [0.0, 0.0],
            "motor_inertia_kgm2": [float(x) for x in s.jm_kgm2],
            "motor_inertia_reflected_kgm2": truth["reflected_motor_inertia_kgm2"],
            "law": ("Spong two-mass: Jm k^2 th'' = k Kt i + tau_f(th') - tau_s; M(q) q'' + c + g = tau_s; "
                    "tau_s = K (d - clip(d, -b/2, b/2)) + D d', d = th - q; encoder reads th; "
                    "springs relaxed at t = 0") if s.flexible else "rigid, Jm k^2 on the diagonal",
        },
        "friction": {
            "known_in_sidecar": bool(s.friction_known),
            "viscous_friction_Nms_per_rad": [float(x) for x in s.viscous_B],
            "coulomb_friction_Nm": [[float(v) for v in r] for r in s.coulomb_Tc],
            "coulomb_ramp_speed_rad_per_s": float(s.v_reg),
            "joint_side": "tau_f = -(B k^2 w + |k| Tc(sign w) clip(|k| w / v_reg, -1, 1))",
        },
        "payload": s.payload,
        "settings": s.to_dict(),
        "run": {"max_abs_e_pulses": np.max(np.abs(run["e"]), axis=0).tolist(),
                "max_abs_i_A": np.max(np.abs(run["i"]), axis=0).tolist(),
                "n_saturated": int(run["n_saturated"]), "rhs_evaluations": int(run["nfev"]),
                "simulation_wall_time_s": sim_time},
        "simulator": {
            "module": "benchmarks/independent_robot.py",
            "rigid_dynamics": "roboticstoolbox-python DHRobot Puma560 C rne (independent of plant/)",
            "integration": f"scipy solve_ivp DOP853, rtol 1e-9, atol 1e-12, max_step {max_step_fraction(s):g} Ts, restarted every sample (ZOH)",
        },
    }
    if extra_truth:
        truth_doc.update(extra_truth)
    with open(stem_path.with_suffix(".truth.json"), "w") as fh:
        json.dump(truth_doc, fh, indent=2)
        fh.write("\n")
    return dict(csv=csv, truth=truth_doc, run=run, sim_time_s=sim_time)


def max_step_fraction(settings: RobotSettings) -> float:
    """``max_step`` of the integrator as a fraction of Ts: Ts/4 with a backlash dead zone, else Ts.

    Without a dead zone one DOP853 step per sample meets rtol 1e-9 (the error
    control subdivides where it must, e.g. at the Coulomb ramp's edges); with
    a dead zone the smaller cap keeps a step from jumping over a short
    crossing of the gap.  Both reproduce the development logs pulse for pulse,
    and :func:`integration_check` (rtol 1e-11, Ts/16) changes no pulse.
    """
    return 0.25 if (settings.flexible and max(settings.backlash_rad) > 0) else 1.0


def integration_check(settings: RobotSettings, n_samples: int | None = None) -> dict:
    """Rerun the P experiment with tighter integration; count pulses that change."""
    from plant.logs.trajectory import Trajectory

    traj = Trajectory.from_sidecar(settings.trajectory)
    n = settings.n_samples if n_samples is None else n_samples
    a = IndependentRobot(settings).run(PCard(settings.p_gain), traj, n,
                                       max_step_fraction=max_step_fraction(settings))
    b = IndependentRobot(settings).run(PCard(settings.p_gain), traj, n, rtol=1e-11, atol=1e-14,
                                       max_step_fraction=1 / 16)
    diff = np.abs(a["e"] - b["e"])
    return dict(n_changed=int(np.count_nonzero(diff)), max_change=int(diff.max()), n=n)
