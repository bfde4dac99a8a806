"""An independent simulator of any serial arm's rig: the robot the library has never seen.

The n-joint sibling of ``benchmarks/independent_robot.py`` (issue 23).  It
shares no code with the library's plant (:mod:`plant.simulation.arm`, its casadi
derivation, code generator and RK4 core):

* **rigid link dynamics**: Robotics Toolbox for Python (``DHRobot``, its C
  recursive Newton--Euler ``rne``): the inertia matrix column by column and
  the bias torques from one multi-row ``rne`` call, joints outside the
  active set locked at their angles.  Friction and motor inertia are
  removed from the RTB links (the drive below adds its own).  The
  ``urdf`` family's robots are URDF files written here; their link
  dynamics are pinocchio's (its own URDF parser, ``rnea``; the ``bench``
  extra's ``pin``), not Robotics Toolbox's reader that the library's
  ``RobotModel.from_urdf`` uses;
* **drive**, written here from the rig description: motor-shaft encoders
  ``count = trunc(q k N / 2 pi)``, integer error ``e = trunc(q_ref k N / 2
  pi) - count``, current from the sampled controller (``P e`` for the rig's
  card), clipped at ``current_full_scale_A``, held over the sample; joint
  torque ``k Kt i``, reflected motor inertia ``Jm k^2`` on the diagonal,
  motor-side viscous and asymmetric Coulomb friction ramping to zero below
  ``v_reg`` (joint side ``k^2 B``, ``|k| Tc``);
* **compliant joints** (``draw(..., compliant=True)``), written here:
  Spong's two-mass joint per active joint -- the motor (its reflected
  inertia ``Jm k^2``, the current's torque and the drive friction) and the
  link (RTB's rigid dynamics) joined by a spring ``K`` and damper ``D``
  through a gearbox dead zone of width ``b`` (backlash):
  ``tau_s = K (d - clip(d, -b/2, b/2)) + D (th' - q')``, ``d = th - q``;
  the encoders read the motor angle ``th``; springs relaxed at t = 0;
* **payload** (``ArmSettings.payload``): a point mass fixed to the last
  link, merged into the Robotics Toolbox link's mass, centre of mass and
  inertia by parallel axes written here (``benchmarks/bench_arm_payload.py``;
  the ``urdf`` family: added to the last joint's pinocchio inertia);
* **integration**: ``scipy.integrate.solve_ivp(method="DOP853", rtol=1e-9,
  atol=1e-12)`` restarted at every sample (zero-order hold), ``max_step =
  Ts``.

Friction: known (in the sidecar) on half of the draws, ``null`` on the
other half (the library identifies it).

Robots (``family``): ``planar2`` -- a two-link arm in a vertical plane
drawn at random (lengths, masses, centres of mass, inertias); ``puma123``
-- the PUMA 560 joints 1-3 (Corke's parameters, RTB's ``Puma560``), wrist
locked; ``puma6`` -- the six-joint PUMA 560; ``random`` -- a chain of 2-4
revolute joints with a random DH table (standard or modified), random
inertials and a random base tilt (:func:`_random_chain`).  Per draw, also at random: gear
ratios, encoders, torque constants, motor inertias, friction, the P gains
(for a loop natural frequency of 4-10 % of the sample rate, damped by the
drawn viscous friction), and a multisine reference with a quintic ramp.

Only the *reference* (``plant.Trajectory``) and the file format
(``plant.logs.arm_log.ArmLog``) come from the library.  Truth: the base
parameters of the library's robot model built from the same published
table (``RobotModel.base_parameters()`` applied to its standard
parameters); ``tests/test_robot_model.py`` checks that model against RTB's
``rne`` -- the one place the two meet.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

FAMILIES = ("planar2", "puma123", "puma6", "random", "urdf")

#: Gravity of the planar family (the arm moves in the base's x-y plane, y up).
PLANAR_GRAVITY = (0.0, -9.81, 0.0)


@dataclass
class ArmSettings:
    """One randomly drawn robot, rig and reference (all SI, motor side where stated)."""

    family: str
    seed: int
    links: list = field(default_factory=list)   # planar2, random: DH rows with inertials
    convention: str = "standard"                # random: "standard" or "modified" DH
    gravity: tuple = (0.0, 0.0, -9.81)          # in the base frame (m/s^2)
    active: tuple = ()
    gear_ratio: tuple = ()
    encoder_ppr: tuple = ()
    torque_constant: tuple = ()
    motor_inertia: tuple = ()
    p_gain: tuple = ()
    viscous: tuple = ()
    coulomb: tuple = ()
    ramp_speed: float = 0.5
    current_full_scale: float | None = None
    sample_time_s: float = 1e-3
    duration_s: float = 5.0
    trajectory: dict = field(default_factory=dict)
    friction_known: bool = True
    stiffness: tuple | None = None     # compliant joints: K (N m/rad), joint side
    damping: tuple | None = None       # D (N m s/rad)
    backlash: tuple | None = None      # b (rad), joint side
    payload: dict | None = None        # a point mass on the last link: mass_kg, com_m (its frame)
    urdf: dict | None = None           # urdf: the chain's description (_random_urdf)

    @property
    def compliant(self) -> bool:
        return self.stiffness is not None

    @property
    def n_samples(self) -> int:
        return int(round(self.duration_s / self.sample_time_s))

    def to_dict(self) -> dict:
        return asdict(self)


def _rtb_robot(s: ArmSettings):
    """RTB DHRobot of the draw, friction and motor inertia removed."""
    import roboticstoolbox as rtb

    if s.family.startswith("puma"):
        robot = rtb.models.DH.Puma560().nofriction(coulomb=True, viscous=True)
    else:
        kind = rtb.RevoluteMDH if s.convention == "modified" else rtb.RevoluteDH
        links = [kind(a=r["a"], alpha=r["alpha"], d=r["d"], offset=r["offset"], m=r["mass"],
                      r=r["com"], I=np.asarray(r["inertia"]), G=1.0, Jm=0.0)
                 for r in s.links]
        robot = rtb.DHRobot(links, name=s.family, gravity=list(s.gravity))
    for link in robot.links:
        link.Jm = 0.0
        link.B = 0.0
        link.Tc = np.zeros(2)
    if s.payload:
        _add_point_mass(robot.links[-1], float(s.payload["mass_kg"]), s.payload["com_m"])
    robot.dynchanged()
    return robot


def _add_point_mass(link, m, p):
    """Fix a point mass ``m`` at ``p`` (the link's frame) to an RTB link: the combined body's
    mass, centre of mass and inertia about it (parallel axes, written here)."""
    p = np.asarray(p, dtype=float)
    m0, r0, i0 = float(link.m), np.asarray(link.r, dtype=float), np.asarray(link.I, dtype=float)
    mass = m0 + m
    r = (m0 * r0 + m * p) / mass

    def steiner(mu, d):
        return mu * (d @ d * np.eye(3) - np.outer(d, d))

    link.m = mass
    link.r = r
    link.I = i0 + steiner(m0, r0 - r) + steiner(m, p - r)


def library_model(s: ArmSettings):
    """The library's RobotModel of the same robot (for the truth and as the user's model)."""
    from plant.robot.robot_model import PUMA560_DH, Link, RobotModel

    if s.family == "urdf":
        _, names, locked = _urdf_of(s)
        act = [names[i] for i in s.active]
        return RobotModel.from_urdf(
            urdf_path(s), active=act, locked=locked,
            gear_ratios=dict(zip(act, s.gear_ratio)), motor_inertias=dict(zip(act, s.motor_inertia)),
            gravity=s.gravity, name=f"URDF chain {s.seed}")
    if s.family.startswith("puma"):
        rows = [dict(r) for r in PUMA560_DH]
        for k, j in enumerate(s.active):
            rows[j]["gear_ratio"] = s.gear_ratio[k]
            rows[j]["motor_inertia"] = s.motor_inertia[k]
        return RobotModel([Link(**r) for r in rows], active=s.active, name=f"PUMA 560 {s.family}",
                          joint_names=tuple(f"q{j + 1}" for j in s.active))
    rows = []
    for k, r in enumerate(s.links):
        rows.append(Link(a=r["a"], alpha=r["alpha"], d=r["d"], offset=r["offset"], mass=r["mass"],
                         com=tuple(r["com"]), inertia=tuple(map(tuple, r["inertia"])),
                         gear_ratio=s.gear_ratio[k], motor_inertia=s.motor_inertia[k]))
    if s.family == "random":
        return RobotModel(rows, convention=s.convention, gravity=s.gravity,
                          name=f"random {len(rows)}R ({s.convention} DH)")
    return RobotModel(rows, gravity=s.gravity, name="planar 2-link")


def truth_beta(s: ArmSettings, model=None):
    """True base parameters (the library model's QR base, at the draw's standard parameters)."""
    model = library_model(s) if model is None else model
    base = model.base_parameters()
    return base.names, base(model.standard_parameters())


class IndependentArm:
    """The drawn robot under a sampled controller, integrated by DOP853."""

    def __init__(self, s: ArmSettings):
        self.s = s
        self.robot = _PinocchioChain(s) if s.family == "urdf" else _rtb_robot(s)
        self.nall = self.robot.n
        self.act = np.asarray(s.active, dtype=int)
        self.n = self.act.size
        self.k = np.asarray(s.gear_ratio, float)
        self.kt = np.asarray(s.torque_constant, float)
        self.jm = np.asarray(s.motor_inertia, float) * self.k ** 2
        self.visc = self.k ** 2 * np.asarray(s.viscous, float)
        c = np.asarray(s.coulomb, float).reshape(self.n, 2)
        self.tc_pos = np.abs(self.k) * c[:, 0]
        self.tc_neg = np.abs(self.k) * c[:, 1]
        self.v_reg = s.ramp_speed / np.abs(self.k)
        self.spr = self.k * np.asarray(s.encoder_ppr, float) / (2.0 * math.pi)
        self.compliant = s.compliant
        if self.compliant:
            self.K = np.asarray(s.stiffness, float)
            self.D = np.asarray(s.damping, float)
            self.b = np.zeros(self.n) if s.backlash is None else np.asarray(s.backlash, float)
        self.g = np.asarray(s.gravity, dtype=float)
        m = self.n + 2
        self._Q = np.zeros((m, self.nall))
        self._QD = np.zeros((m, self.nall))
        self._QDD = np.zeros((m, self.nall))
        for r, j in enumerate(self.act):
            self._QDD[1 + r, j] = 1.0

    def dynamics(self, q, qd, motor=True):
        """Inertia matrix (n, n) (with the motor inertia unless ``motor`` is False) and bias
        torques (n,), by one rne call."""
        Q, QD = self._Q, self._QD
        Q[:, self.act] = q
        QD[0, self.act] = qd
        tau = np.atleast_2d(self.robot.rne(Q, QD, self._QDD, gravity=self.g))
        g = tau[-1, self.act]
        M = (tau[1:1 + self.n][:, self.act] - g).T
        if motor:
            M[np.diag_indices(self.n)] += self.jm
        return M, tau[0, self.act]

    def friction(self, w):
        r = np.clip(w / self.v_reg, -1.0, 1.0)
        tc = np.where(w > 0.0, self.tc_pos, self.tc_neg)
        return -(self.visc * w + tc * r)

    def rhs(self, t, y, i):
        n = self.n
        if self.compliant:  # y = (q, q', th, th'): link, then motor (joint side)
            q, w, th, v = y[:n], y[n:2 * n], y[2 * n:3 * n], y[3 * n:]
            d = th - q
            ts = self.K * (d - np.clip(d, -self.b / 2, self.b / 2)) + self.D * (v - w)
            M, bias = self.dynamics(q, w, motor=False)
            qdd = np.linalg.solve(M, ts - bias)
            vd = (self.k * self.kt * i + self.friction(v) - ts) / self.jm
            return np.concatenate([w, qdd, v, vd])
        q, w = y[:n], y[n:]
        M, b = self.dynamics(q, w)
        tau = self.k * self.kt * i + self.friction(w) - b
        return np.concatenate([w, np.linalg.solve(M, tau)])

    def run(self, controller, trajectory, n_samples, *, rtol=1e-9, atol=1e-12, changes=()):
        """Sampled closed loop from rest at q = 0; returns dict of e, i, q arrays (time-first).

        ``changes``: ``(k, IndependentArm)`` pairs -- from sample ``k`` on the robot is that
        one (a payload picked up or put down, a drive whose friction changed); the state
        carries over (same joints, same rigid or compliant kind).
        """
        from scipy.integrate import solve_ivp

        pending = sorted(changes, key=lambda c: c[0])
        if any(r.compliant != self.compliant or r.n != self.n for _, r in pending):
            raise ValueError("a change must keep the joints and the rigid or compliant kind")
        robot = self

        ts = self.s.sample_time_s
        lim = math.inf if self.s.current_full_scale is None else self.s.current_full_scale
        t = np.arange(n_samples) * ts
        ref = np.trunc(trajectory.position(t) * self.spr)
        y = np.zeros((4 if self.compliant else 2) * self.n)
        enc = 2 * self.n if self.compliant else 0  # the encoders read the motor
        E = np.zeros((n_samples, self.n), dtype=np.int64)
        I = np.zeros((n_samples, self.n))
        Q = np.zeros((n_samples, self.n))
        controller.reset()
        ok = True
        for k in range(n_samples):
            act = np.trunc(y[enc:enc + self.n] * self.spr)
            E[k] = (ref[k] - act).astype(np.int64)
            Q[k] = y[:self.n]
            i = np.clip(np.asarray(controller(k, t[k], act / self.spr, E[k].copy()), float), -lim, lim)
            I[k] = i
            if k == n_samples - 1:
                break
            while pending and pending[0][0] <= k:
                robot = pending.pop(0)[1]
            sol = solve_ivp(robot.rhs, (t[k], t[k] + ts), y, method="DOP853", rtol=rtol, atol=atol,
                            max_step=ts, args=(i,))
            if not sol.success or not np.all(np.isfinite(sol.y[:, -1])):
                ok = False
                E, I, Q = E[:k + 1], I[:k + 1], Q[:k + 1]
                break
            y = sol.y[:, -1]
        return dict(e=E, i=I, q=Q, ok=ok)


class PCard:
    """The rig's P card, written here (not the library's)."""

    def __init__(self, p_gain):
        self.p = np.asarray(p_gain, float)

    def reset(self):
        pass

    def __call__(self, k, t, q_meas, e_pulses):
        return self.p * e_pulses


def _random_chain(rng):
    """A random serial chain of 2-4 revolute joints (the ``random`` family).

    DH convention standard or modified (half each); per joint ``alpha`` one of
    0, +-pi/2 (80 %) or any angle, ``a`` 0.1-0.6 m (70 %) or 0, ``d`` +-0.3 m
    (half) or 0, an offset (30 %); per link a mass of 0.5-8 kg, a centre of
    mass within half the link's size of its frame, and a physically
    consistent inertia (a rigid body's: principal second moments of mass
    ``m (s L)^2``, s 0.05-0.35, turned by a random rotation).  The base is
    upright on half of the draws, otherwise tilted by up to 90 degrees about
    a random horizontal axis (gravity then loads the first joint too).
    """
    from scipy.spatial.transform import Rotation

    n = int(rng.integers(2, 5))
    convention = "modified" if rng.random() < 0.5 else "standard"
    links = []
    for _ in range(n):
        alpha = float(rng.choice([0.0, math.pi / 2, -math.pi / 2]) if rng.random() < 0.8
                      else rng.uniform(-math.pi, math.pi))
        a = float(rng.uniform(0.1, 0.6)) if rng.random() < 0.7 else 0.0
        d = float(rng.uniform(-0.3, 0.3)) if rng.random() < 0.5 else 0.0
        offset = float(rng.uniform(-math.pi, math.pi)) if rng.random() < 0.3 else 0.0
        m = float(rng.uniform(0.5, 8.0))
        size = max(a, abs(d), 0.1)
        com = rng.uniform(-0.5, 0.5, 3) * size
        sm = m * (size * rng.uniform(0.05, 0.35, 3)) ** 2   # principal second moments of mass
        R = Rotation.random(random_state=rng).as_matrix()
        inertia = R @ np.diag([sm[1] + sm[2], sm[0] + sm[2], sm[0] + sm[1]]) @ R.T
        links.append(dict(a=a, alpha=alpha, d=d, offset=offset, mass=m, com=com.tolist(),
                          inertia=(0.5 * (inertia + inertia.T)).tolist()))
    return links, convention, _random_gravity(rng)


def _random_gravity(rng):
    """Gravity in the base frame: upright on half of the draws, otherwise tilted by up to
    90 degrees about a random horizontal axis."""
    from scipy.spatial.transform import Rotation

    g = np.array([0.0, 0.0, -9.81])
    if rng.random() < 0.5:
        phi = rng.uniform(0.0, 2 * math.pi)
        axis = np.array([math.cos(phi), math.sin(phi), 0.0])
        g = Rotation.from_rotvec(rng.uniform(0.0, math.pi / 2) * axis).apply(g)
    return tuple(float(v) for v in g)


def _random_body(rng, size):
    """A rigid body's inertial as URDF gives it: mass 0.5-8 kg, the centre of mass within
    half ``size`` of the frame, the inertia about it in a frame turned by a random ``rpy``
    (principal second moments ``m (s size)^2``, s 0.05-0.35, and their sums)."""
    m = float(rng.uniform(0.5, 8.0))
    sm = m * (size * rng.uniform(0.05, 0.35, 3)) ** 2
    return dict(mass=m, xyz=(rng.uniform(-0.5, 0.5, 3) * size).tolist(),
                rpy=rng.uniform(-math.pi, math.pi, 3).tolist(),
                diag=[float(sm[1] + sm[2]), float(sm[0] + sm[2]), float(sm[0] + sm[1])])


def _random_urdf(rng):
    """A random serial chain as a URDF would give it (the ``urdf`` family).

    2-4 revolute joints named ``j1``, ``j2``, ...; each joint's origin a
    random ``xyz`` (each coordinate 0 or +-0.4 m) and ``rpy`` (each angle 0,
    +-pi/2 or any), its axis one of +-x, +-y, +-z; each child link's
    inertial at a random origin and ``rpy`` (:func:`_random_body`).  On
    half of the draws a raised, turned base (a fixed joint before the
    first revolute one); on half a tool on a fixed flange after the last;
    on a third of the chains of 3 or more joints one joint other than the
    first locked at a random angle.
    """
    def angle():
        u = rng.random()
        return 0.0 if u < 0.4 else float(rng.choice([math.pi / 2, -math.pi / 2])) if u < 0.75 \
            else float(rng.uniform(-math.pi, math.pi))

    def offset():
        return [float(rng.uniform(-0.4, 0.4)) if rng.random() < 0.6 else 0.0 for _ in range(3)]

    n = int(rng.integers(2, 5))
    joints = []
    for _ in range(n):
        xyz = offset()
        ax = np.zeros(3)
        ax[int(rng.integers(0, 3))] = float(rng.choice([-1.0, 1.0]))
        joints.append(dict(xyz=xyz, rpy=[angle() for _ in range(3)], axis=ax.tolist(),
                           body=_random_body(rng, max(0.1, float(np.linalg.norm(xyz)))),
                           locked=None))
    if n >= 3 and rng.random() < 1 / 3:
        joints[int(rng.integers(1, n))]["locked"] = float(rng.uniform(-1.5, 1.5))
    base = dict(xyz=offset(), rpy=[angle() for _ in range(3)]) if rng.random() < 0.5 else None
    tool = None
    if rng.random() < 0.5:
        tool = dict(xyz=offset(), rpy=[angle() for _ in range(3)], body=_random_body(rng, 0.15))
        tool["body"]["mass"] *= 0.25  # a tool lighter than a link
    return dict(joints=joints, base=base, tool=tool)


def urdf_text(desc: dict, name: str = "random_chain") -> str:
    """The URDF file of a :func:`_random_urdf` description (written here)."""
    def v(x):
        return " ".join(repr(float(a)) for a in x)

    def inertial(b):
        d = b["diag"]
        return (f'<inertial><origin xyz="{v(b["xyz"])}" rpy="{v(b["rpy"])}"/>'
                f'<mass value="{b["mass"]!r}"/><inertia ixx="{d[0]!r}" ixy="0" ixz="0" '
                f'iyy="{d[1]!r}" iyz="0" izz="{d[2]!r}"/></inertial>')

    out = ['<?xml version="1.0"?>', f'<robot name="{name}">', '  <link name="world"/>']
    parent = "world"
    if desc["base"] is not None:
        out.append('  <link name="base"/>')
        out.append(f'  <joint name="base_mount" type="fixed"><parent link="world"/><child link="base"/>'
                   f'<origin xyz="{v(desc["base"]["xyz"])}" rpy="{v(desc["base"]["rpy"])}"/></joint>')
        parent = "base"
    for i, j in enumerate(desc["joints"], start=1):
        out.append(f'  <link name="l{i}">{inertial(j["body"])}</link>')
        out.append(f'  <joint name="j{i}" type="revolute"><parent link="{parent}"/><child link="l{i}"/>'
                   f'<origin xyz="{v(j["xyz"])}" rpy="{v(j["rpy"])}"/><axis xyz="{v(j["axis"])}"/>'
                   f'<limit lower="-10" upper="10" effort="1000" velocity="100"/></joint>')
        parent = f"l{i}"
    if desc["tool"] is not None:
        t = desc["tool"]
        out.append(f'  <link name="tool">{inertial(t["body"])}</link>')
        out.append(f'  <joint name="flange" type="fixed"><parent link="{parent}"/><child link="tool"/>'
                   f'<origin xyz="{v(t["xyz"])}" rpy="{v(t["rpy"])}"/></joint>')
    out.append("</robot>")
    return "\n".join(out) + "\n"


def _urdf_of(s: ArmSettings):
    """A ``urdf`` draw's file text, its joint names (``j1``, ...) and ``{name: angle}`` of
    its locked joints."""
    names = [f"j{i + 1}" for i in range(len(s.urdf["joints"]))]
    locked = {n: j["locked"] for n, j in zip(names, s.urdf["joints"]) if j["locked"] is not None}
    return urdf_text(s.urdf, name=f"urdf_{s.seed}"), names, locked


def urdf_path(s: ArmSettings):
    """The draw's URDF written to a file of the temporary directory (its name the hash of the
    text, so that processes share it); returns the path."""
    import hashlib
    import tempfile
    from pathlib import Path

    text = _urdf_of(s)[0]
    d = Path(tempfile.gettempdir()) / "independent_arm_urdf"
    d.mkdir(parents=True, exist_ok=True)
    path = d / f"urdf_{s.seed}_{hashlib.sha1(text.encode()).hexdigest()[:12]}.urdf"
    if not path.is_file():
        tmp = path.with_name(path.name + f".{id(text)}.tmp")
        tmp.write_text(text)
        tmp.replace(path)
    return path


class _PinocchioChain:
    """The ``urdf`` family's rigid dynamics: pinocchio's model of the draw's URDF text (its
    own parser, its RNEA), behind the ``rne(Q, QD, QDD, gravity)`` rows of an RTB robot."""

    def __init__(self, s: ArmSettings):
        import pinocchio as pin

        self._pin = pin
        self.model = pin.buildModelFromXML(_urdf_of(s)[0])
        if s.payload:  # a point mass fixed to the last link, in its joint frame
            last = self.model.njoints - 1
            self.model.inertias[last] = self.model.inertias[last] + pin.Inertia(
                float(s.payload["mass_kg"]), np.asarray(s.payload["com_m"], dtype=float), np.zeros((3, 3)))
        self.data = self.model.createData()
        self.n = self.model.nq
        self._locked = np.array([0.0 if j["locked"] is None else j["locked"]
                                 for j in s.urdf["joints"]])
        self._act = np.asarray(s.active, dtype=int)

    def rne(self, Q, QD, QDD, gravity):
        self.model.gravity.linear = np.asarray(gravity, dtype=float)
        out = np.empty((Q.shape[0], self.n))
        q = self._locked.copy()
        for r in range(Q.shape[0]):
            q[self._act] = Q[r, self._act]
            out[r] = self._pin.rnea(self.model, self.data, q, QD[r], QDD[r])
        return out


def draw(family: str, seed: int, compliant: bool = False) -> ArmSettings:
    """A random robot, rig and reference of a family (module docstring).

    With ``compliant``, also (drawn after everything else, so the rigid part
    of the draw is the same): per joint a link mode ``sqrt(K / D_link,jj)``
    of 8-40 Hz, a damping ratio of 0.01-0.15 and, on half of the draws, a
    backlash of 0.3-3 mrad on each joint.
    """
    rng = np.random.default_rng(seed)
    s = ArmSettings(family=family, seed=int(seed))
    if family == "planar2":
        links = []
        for _ in range(2):
            L = rng.uniform(0.25, 0.7)
            m = rng.uniform(1.0, 8.0)
            cx = -L * rng.uniform(0.3, 0.7)
            cy = rng.uniform(-0.02, 0.02)
            izz = m * L * L * rng.uniform(0.02, 0.1)
            I = np.diag([izz * 0.2, izz * rng.uniform(0.8, 1.0), izz])
            links.append(dict(a=L, alpha=0.0, d=0.0, offset=0.0, mass=m, com=[cx, cy, 0.0],
                              inertia=I.tolist()))
        s.links = links
        s.active = (0, 1)
        s.gravity = PLANAR_GRAVITY
    elif family == "random":
        s.links, s.convention, s.gravity = _random_chain(rng)
        s.active = tuple(range(len(s.links)))
    elif family == "urdf":
        s.urdf = _random_urdf(rng)
        s.active = tuple(i for i, j in enumerate(s.urdf["joints"]) if j["locked"] is None)
        s.gravity = _random_gravity(rng)
    elif family == "puma123":
        s.active = (0, 1, 2)
    elif family == "puma6":
        s.active = (0, 1, 2, 3, 4, 5)
    else:
        raise ValueError(f"family must be one of {FAMILIES}")
    n = len(s.active)
    sign = rng.choice([-1.0, 1.0], n)
    s.gear_ratio = tuple(float(v) for v in sign * rng.uniform(30.0, 120.0, n))
    s.encoder_ppr = tuple(int(v) for v in rng.choice([500, 1000, 1024, 2000, 2048, 4096], n))
    s.torque_constant = tuple(float(v) for v in rng.uniform(0.1, 0.4, n))
    s.motor_inertia = tuple(float(v) for v in rng.uniform(30e-6, 300e-6, n))
    s.ramp_speed = float(rng.uniform(0.2, 1.0))
    s.coulomb = tuple((float(a), float(b)) for a, b in rng.uniform(0.0, 0.03, (n, 2)))
    s.sample_time_s = float(rng.choice([0.5e-3, 1e-3]))
    s.duration_s = 5.0
    # reference: per joint a multisine with a quintic ramp, amplitude 0.3-0.9 rad in total
    terms, c = [], []
    for j in range(n):
        nt = int(rng.integers(2, 4))
        amp = rng.dirichlet(np.ones(nt)) * rng.uniform(0.3, 0.9)
        w = 2 * math.pi * rng.uniform(0.15, 1.2, nt)
        ph = rng.uniform(0, 2 * math.pi, nt)
        c0 = -float(np.sum(amp * np.cos(ph)))  # starts at q = 0
        terms.append([[float(a), float(o), float(p)] for a, o, p in zip(amp, w, ph)])
        c.append(c0)
    s.trajectory = dict(c=c, terms_A_omega_phi=terms, t_ramp_s=float(rng.uniform(0.3, 0.8)))
    # P gains and viscous friction for a damped, stable sampled P loop (at q = 0, mean inertia)
    model = library_model(s)
    qs = rng.uniform(-0.5, 0.5, (8, n))
    Dm = np.mean([np.diag(model.inertia_matrix(q)) for q in qs], axis=0)
    k = np.abs(np.asarray(s.gear_ratio))
    w_n = 2 * math.pi / s.sample_time_s * rng.uniform(0.006, 0.016, n)
    zeta = rng.uniform(0.3, 0.8, n)
    spr = k * np.asarray(s.encoder_ppr) / (2 * math.pi)
    s.p_gain = tuple(float(v) for v in w_n ** 2 * Dm / (k * np.asarray(s.torque_constant) * spr))
    s.viscous = tuple(float(v) for v in 2 * zeta * w_n * Dm / k ** 2)
    # drawn last, so that the draws before it do not depend on it
    s.friction_known = bool(rng.random() < 0.5)
    if compliant:
        jm = np.asarray(s.motor_inertia) * k ** 2
        link = np.maximum(Dm - jm, 1e-4)           # the link's own diagonal inertia
        f_link = rng.uniform(8.0, 40.0, n)
        K = link * (2 * math.pi * f_link) ** 2
        mu = link * jm / (link + jm)               # the two-mass mode's reduced inertia
        s.stiffness = tuple(float(v) for v in K)
        s.damping = tuple(float(v) for v in 2 * rng.uniform(0.01, 0.15, n) * np.sqrt(K * mu))
        s.backlash = tuple(float(v) for v in (rng.uniform(0.3e-3, 3e-3, n) if rng.random() < 0.5
                                              else np.zeros(n)))
    return s


def make_log(s: ArmSettings, name=None):
    """The P-control log of a draw (independent simulator), as a library ``ArmLog``."""
    from plant.logs.arm_log import ArmLog, column_names
    from plant.logs.trajectory import Trajectory

    model = library_model(s)
    rig = rig_of(s)
    traj = Trajectory.from_sidecar(s.trajectory, "draw", n_joints=len(s.active))
    sim = IndependentArm(s).run(PCard(s.p_gain), traj, s.n_samples)
    if not sim["ok"]:
        raise RuntimeError(f"independent run of draw {s.family}/{s.seed} failed")
    t = np.arange(s.n_samples) * s.sample_time_s
    sidecar = dict(dataset=name or f"{s.family}_{s.seed}", robot=_robot_entry(s, model),
                   n_samples=s.n_samples, sample_time_s=s.sample_time_s,
                   gear_ratio=list(s.gear_ratio), encoder_ppr=list(s.encoder_ppr),
                   p_gain_A_per_pulse=list(s.p_gain), torque_constant_Nm_per_A=list(s.torque_constant),
                   viscous_friction_Nms_per_rad=list(s.viscous) if s.friction_known else None,
                   coulomb_friction_Nm=[list(c) for c in s.coulomb] if s.friction_known else None,
                   coulomb_ramp_speed_rad_per_s=s.ramp_speed, gravity_m_s2=9.81,
                   start_state=dict(q_rad=[0.0] * len(s.active), qd_rad_per_s=[0.0] * len(s.active)),
                   trajectory=dict(parameters=s.trajectory),
                   csv_columns={c: "" for c in column_names(model.joint_names)})
    if s.current_full_scale is not None:
        sidecar["current_full_scale_A"] = s.current_full_scale
    return ArmLog(path=None, name=sidecar["dataset"], model=model, rig=rig, trajectory=traj, t=t,
                  q_ref=traj.position(t), e_pulses=sim["e"], i_A=sim["i"], sidecar=sidecar)


def _robot_entry(s: ArmSettings, model, urdf=None):
    """The sidecar's ``robot`` object: the DH table inline, or for the ``urdf`` family the
    file (``urdf``: its path, default the temporary one of :func:`urdf_path`) and joints."""
    from plant.logs.arm_log import robot_section

    if s.family != "urdf":
        return robot_section(model)
    return dict(urdf=str(urdf or urdf_path(s)), joints=list(model.joint_names),
                locked=_urdf_of(s)[2],
                motor_inertias=dict(zip(model.joint_names, map(float, s.motor_inertia))),
                gravity=list(s.gravity), name=model.name)


def write_log(s: ArmSettings, directory, stem):
    """Write a draw's log (``STEM.csv`` and ``STEM.json``, :class:`plant.logs.arm_log.ArmLog`) and its
    truth (``STEM.truth.json``: the draw's settings, the true base parameters and joints)."""
    import json
    from pathlib import Path

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    log = make_log(s, name=stem)
    names, beta = truth_beta(s, log.model)
    if s.family == "urdf":  # the URDF beside the log, named relative to the sidecar
        (directory / f"{stem}.urdf").write_text(_urdf_of(s)[0])
        log.sidecar["robot"] = _robot_entry(s, log.model, urdf=f"{stem}.urdf")
    log.save(directory / f"{stem}.csv")
    k = np.asarray(s.gear_ratio, float)
    links = "pinocchio rnea of the URDF" if s.family == "urdf" else "RTB DHRobot rne"
    truth = dict(dataset=stem, simulator=f"benchmarks/independent_arm.py ({links}, own "
                 "drive and two-mass joints, solve_ivp DOP853 rtol 1e-9)",
                 base_parameter_names=list(names), beta=[float(v) for v in beta],
                 motor_inertia_reflected_kgm2=(np.asarray(s.motor_inertia) * k ** 2).tolist(),
                 settings=s.to_dict())
    (directory / f"{stem}.truth.json").write_text(json.dumps(truth, indent=1) + "\n")
    return log


def rig_of(s: ArmSettings):
    """The library's Rig of a draw (what the sidecar says)."""
    from plant.logs.rig import Rig

    n = len(s.active)
    return Rig(sample_time_s=s.sample_time_s, gear_ratio=tuple(s.gear_ratio),
               encoder_ppr=tuple(s.encoder_ppr), p_gain_A_per_pulse=tuple(s.p_gain),
               torque_constant_Nm_per_A=tuple(s.torque_constant),
               viscous_friction_Nms_per_rad=tuple(s.viscous) if s.friction_known else None,
               coulomb_friction_Nm=tuple(tuple(c) for c in s.coulomb) if s.friction_known else None,
               coulomb_ramp_speed_rad_per_s=s.ramp_speed, gravity_m_s2=9.81, a3_m=0.0,
               q0_rad=(0.0,) * n, qd0_rad_per_s=(0.0,) * n, f_bounds=(),
               current_full_scale_A=s.current_full_scale)


def check_counts(parser, counts, families):
    """``--n``'s draws per family: 1 to ``len(families)`` counts >= 0, else the parser's
    one-line usage error (``argparse.ArgumentParser.error``)."""
    if len(counts) > len(families) or min(counts) < 0:
        parser.error(f"--n takes 1 to {len(families)} counts >= 0 ({' '.join(families)})")


def run_jobs(job, jobs, n_jobs, line):
    """Run ``job`` over ``jobs`` (in ``n_jobs`` spawned processes when > 1), printing
    ``line(row)`` for each row as it comes; returns the rows in order."""
    rows = []
    if n_jobs > 1:
        import multiprocessing as mp

        with mp.get_context("spawn").Pool(n_jobs) as pool:
            for r in pool.imap(job, jobs):
                print(line(r), flush=True)
                rows.append(r)
    else:
        for j in jobs:
            rows.append(job(j))
            print(line(rows[-1]), flush=True)
    return rows
