"""The robot model (plant.robot.robot_model): DH table -> dynamics -> regressor -> base parameters."""
import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from plant.robot import model as paper
from plant.robot.robot_model import (
    PUMA560_DH,
    PUMA560_LINKS23_BASIS,
    Link,
    ParameterBasis,
    RobotModel,
)


def planar(convention="standard", **kw):
    """Two-link arm in a vertical plane: l = 1.0 / 0.8 m, COM at the middle, motors."""
    l1, l2 = 1.0, 0.8
    if convention == "standard":  # frame i at the far end of link i
        links = [Link(a=l1, mass=2.0, com=(-l1 / 2, 0, 0), inertia=(0.01, 0.1, 0.17, 0, 0, 0),
                      gear_ratio=50, motor_inertia=1e-4),
                 Link(a=l2, mass=1.5, com=(-l2 / 2, 0, 0), inertia=(0.01, 0.06, 0.08, 0, 0, 0),
                      gear_ratio=30, motor_inertia=1e-4)]
    else:  # modified: frame i on joint i's axis
        links = [Link(a=0.0, mass=2.0, com=(l1 / 2, 0, 0), inertia=(0.01, 0.1, 0.17, 0, 0, 0),
                      gear_ratio=50, motor_inertia=1e-4),
                 Link(a=l1, mass=1.5, com=(l2 / 2, 0, 0), inertia=(0.01, 0.06, 0.08, 0, 0, 0),
                      gear_ratio=30, motor_inertia=1e-4)]
    return RobotModel(links, convention=convention, gravity=(0, -9.81, 0), **kw)


def planar_closed_form(q, qd, qdd):
    """Textbook two-link planar dynamics (Spong, Hutchinson & Vidyasagar, sec. 7.3)."""
    l1, lc1, lc2 = 1.0, 0.5, 0.4
    m1, m2, i1, i2 = 2.0, 1.5, 0.17, 0.08
    ia1, ia2 = 1e-4 * 50 ** 2, 1e-4 * 30 ** 2
    c2, s2 = math.cos(q[1]), math.sin(q[1])
    d11 = m1 * lc1 ** 2 + m2 * (l1 ** 2 + lc2 ** 2 + 2 * l1 * lc2 * c2) + i1 + i2 + ia1
    d12 = m2 * (lc2 ** 2 + l1 * lc2 * c2) + i2
    d22 = m2 * lc2 ** 2 + i2 + ia2
    h = -m2 * l1 * lc2 * s2
    c = np.array([h * (2 * qd[0] * qd[1] + qd[1] ** 2), -h * qd[0] ** 2])
    g = 9.81
    gv = np.array([(m1 * lc1 + m2 * l1) * g * math.cos(q[0]) + m2 * lc2 * g * math.cos(q[0] + q[1]),
                   m2 * lc2 * g * math.cos(q[0] + q[1])])
    D = np.array([[d11, d12], [d12, d22]])
    return D, c, gv, D @ qdd + c + gv


@pytest.mark.parametrize("convention", ["standard", "modified"])
def test_planar_arm_matches_the_textbook(convention):
    arm = planar(convention)
    rng = np.random.default_rng(3)
    for _ in range(5):
        q, qd, qdd = rng.uniform(-3, 3, 2), rng.normal(size=2), rng.normal(size=2)
        D, c, g, tau = planar_closed_form(q, qd, qdd)
        np.testing.assert_allclose(arm.inertia_matrix(q), D, atol=1e-12)
        np.testing.assert_allclose(arm.coriolis_centrifugal(q, qd), c, atol=1e-12)
        np.testing.assert_allclose(arm.gravity_vector(q), g, atol=1e-12)
        np.testing.assert_allclose(arm.inverse_dynamics(q, qd, qdd), tau, atol=1e-12)
        # tau is linear in the standard parameters through the regressor
        np.testing.assert_allclose(arm.regressor(q, qd, qdd) @ arm.standard_parameters(), tau,
                                   atol=1e-12)


def test_planar_arm_base_parameters():
    arm = planar()
    base = arm.base_parameters()
    # the classical result: 7 base parameters for a 2R arm in a vertical plane with rotors
    # (ZZ1R, MX1R, MY1, ZZ2R, MX2R, MY2, Ia2); Ia1 regroups into ZZ1R
    assert base.rank == 7
    assert base.names == ("ZZ1R", "MX1R", "MY1", "ZZ2R", "MX2R", "MY2", "Ia2")
    assert "Ia1" in base.expressions[0]
    # Y p = Y_b beta for any p and state
    rng = np.random.default_rng(0)
    p = rng.normal(size=len(arm.standard_parameter_names))
    W = arm.stacked_regressor(*arm.random_states(30, rng=1))
    np.testing.assert_allclose(W @ p, W[:, base.independent] @ base(p), atol=1e-10)
    # and the base regressor has full column rank
    assert np.linalg.matrix_rank(W[:, base.independent]) == 7


def test_puma_links23_are_the_papers_f():
    """Eq. 3: the DH model's torques are Y_f f with f = K p; two relations tie f3..f6."""
    puma = RobotModel.puma560()
    f = puma.express(PUMA560_LINKS23_BASIS)
    assert f.names == tuple(f"f{i}" for i in range(1, 10))
    # the geometry (a3 = 0.4318 m) ties f3 = a3 f5 and f4 = a3 f6: 7 base parameters,
    # as the numerical QR finds; the paper searches all nine
    assert f.rank == 7 == puma.base_parameters().rank
    assert f.relations == ("f3 - 0.4318 f5 = 0", "f4 - 0.4318 f6 = 0")
    p = puma.standard_parameters()
    fv = f(p)
    # eq. 3: f1 - f2 is the reflected rotor inertia of joint 3, f7 holds joint 2's
    k3 = PUMA560_DH[2]["gear_ratio"]
    assert fv[0] - fv[1] == pytest.approx(200e-6 * k3 ** 2, rel=1e-12)
    assert "Ia2" in f.expressions[6] and "Ia3" in f.expressions[0] and "Ia3" not in f.expressions[1]
    # the library's eq.-2 model with this f is the DH model, in the paper's convention
    rng = np.random.default_rng(7)
    for _ in range(5):
        q, qd, qdd = rng.uniform(-3, 3, 2), rng.normal(size=2), rng.normal(size=2)
        np.testing.assert_allclose(paper.inertia_matrix(fv, -q), puma.inertia_matrix(q), atol=1e-12)
        np.testing.assert_allclose(paper.inverse_dynamics(fv, -q, -qd, -qdd),
                                   -puma.inverse_dynamics(q, qd, qdd), atol=1e-10)


def test_a_basis_that_misses_a_term_is_refused():
    puma = RobotModel.puma560()
    short = ParameterBasis("no gravity of link 2", tuple(f"f{i}" for i in range(1, 9)),
                           lambda q, qd, qdd: PUMA560_LINKS23_BASIS.regressor(q, qd, qdd)[:, :8])
    with pytest.raises(ValueError, match="does not describe") as exc:
        puma.express(short)
    assert "\n" not in str(exc.value)


def test_against_robotics_toolbox_six_joints():
    rtb = pytest.importorskip("roboticstoolbox")
    ref = rtb.models.DH.Puma560().nofriction(coulomb=True, viscous=True)
    puma = RobotModel.puma560(active=range(6))
    rng = np.random.default_rng(11)
    for _ in range(3):
        q, qd, qdd = rng.uniform(-3, 3, 6), rng.normal(size=6), rng.normal(size=6)
        np.testing.assert_allclose(puma.inverse_dynamics(q, qd, qdd), ref.rne(q, qd, qdd), atol=1e-10)
        np.testing.assert_allclose(puma.inertia_matrix(q), ref.inertia(q), atol=1e-10)
        np.testing.assert_allclose(puma.gravity_vector(q), ref.gravload(q), atol=1e-10)
    base = puma.base_parameters()
    p = puma.standard_parameters()
    W = puma.stacked_regressor(*puma.random_states(20, rng=2))
    np.testing.assert_allclose(W @ p, W[:, base.independent] @ base(p), atol=1e-9)


def test_against_robotics_toolbox_modified_dh_with_locked_joint():
    rtb = pytest.importorskip("roboticstoolbox")
    rows = [dict(a=0.0, alpha=0.0, d=0.3, mass=3.0, com=(0.1, 0.02, -0.05),
                 inertia=(0.02, 0.03, 0.04, 0.001, 0.002, 0.003), gear_ratio=80, motor_inertia=5e-5),
            dict(a=0.05, alpha=-math.pi / 2, d=0.1, offset=0.3, mass=2.0, com=(0.2, 0.0, 0.01),
                 inertia=(0.01, 0.05, 0.05, 0, 0, 0), gear_ratio=60, motor_inertia=5e-5),
            dict(a=0.4, alpha=0.0, d=0.0, mass=1.0, com=(0.15, 0.01, 0.0),
                 inertia=(0.002, 0.01, 0.01, 0, 0, 0), gear_ratio=40, motor_inertia=5e-5)]
    ref = rtb.DHRobot([rtb.RevoluteMDH(a=r["a"], alpha=r["alpha"], d=r["d"], offset=r.get("offset", 0.0),
                                       m=r["mass"], r=r["com"], I=r["inertia"], G=r["gear_ratio"],
                                       Jm=r["motor_inertia"]) for r in rows])
    arm = RobotModel.from_dh(rows, convention="modified", active=(0, 2), locked={1: 0.4})
    rng = np.random.default_rng(5)
    for _ in range(3):
        q, qd, qdd = rng.uniform(-3, 3, 2), rng.normal(size=2), rng.normal(size=2)
        Q, QD, QDD = np.array([q[0], 0.4, q[1]]), np.array([qd[0], 0, qd[1]]), np.array([qdd[0], 0, qdd[1]])
        np.testing.assert_allclose(arm.inverse_dynamics(q, qd, qdd), ref.rne(Q, QD, QDD)[[0, 2]],
                                   atol=1e-10)


@pytest.mark.parametrize("make, match", [
    (lambda: RobotModel([]), "non-empty"),
    (lambda: RobotModel([Link()], convention="craig"), "convention"),
    (lambda: RobotModel([Link(), Link()], active=(1, 0)), "active"),
    (lambda: RobotModel([Link()], gravity=(0, 9.81)), "gravity"),
    (lambda: Link(mass=-1.0), "mass"),
    (lambda: Link(gear_ratio=0.0), "gear_ratio"),
    (lambda: Link(inertia=(1, 2, 3)), "inertia"),
    (lambda: RobotModel.from_dh([(0.1, 0.0, 0.0, 0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0)]), "DH row 0"),
    (lambda: planar().inverse_dynamics([0.0], [0.0, 0.0], [0.0, 0.0]), "q must have 2"),
])
def test_bad_input_is_one_line(make, match):
    with pytest.raises(ValueError, match=match) as exc:
        make()
    assert "\n" not in str(exc.value)


def test_docstring_examples():
    import doctest

    import plant.robot.robot_model

    assert doctest.testmod(plant.robot.robot_model, raise_on_error=False).failed == 0


URDF_DIR = Path(__file__).parent / "data" / "urdf"


def test_urdf_planar_arm_is_the_textbook_arm():
    pytest.importorskip("roboticstoolbox")
    arm = RobotModel.from_urdf(URDF_DIR / "planar_2r.urdf", gear_ratios={"shoulder": 50, "elbow": 30},
                               motor_inertias={"shoulder": 1e-4, "elbow": 1e-4})
    assert arm.joint_names == ("shoulder", "elbow") and arm.convention == "urdf"
    rng = np.random.default_rng(4)
    for _ in range(3):
        q, qd, qdd = rng.uniform(-3, 3, 2), rng.normal(size=2), rng.normal(size=2)
        D, c, g, tau = planar_closed_form(q, qd, qdd)
        np.testing.assert_allclose(arm.inverse_dynamics(q, qd, qdd), tau, atol=1e-7)
        np.testing.assert_allclose(arm.inertia_matrix(q), D, atol=1e-9)
    assert arm.base_parameters().rank == 7


def test_urdf_with_fixed_joints_matches_robotics_toolbox():
    """A raised base and a tool on a fixed flange fold into the chain (its mass lumped)."""
    rtb = pytest.importorskip("roboticstoolbox")
    import warnings

    path = URDF_DIR / "arm_3r_tool.urdf"
    arm = RobotModel.from_urdf(path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = rtb.Robot.URDF(str(path.resolve()))
    assert arm.n_joints == 3 and len(arm.links) == 3
    rng = np.random.default_rng(8)
    for _ in range(3):
        q, qd, qdd = rng.uniform(-3, 3, 3), rng.normal(size=3), rng.normal(size=3)
        np.testing.assert_allclose(arm.inverse_dynamics(q, qd, qdd), ref.rne(q, qd, qdd), atol=1e-9)
        np.testing.assert_allclose(arm.inertia_matrix(q), ref.inertia(q), atol=1e-9)
    # the tool's 0.8 kg and the camera's 0.2 kg on it ride on the forearm
    assert arm.links[-1].mass == pytest.approx(1.5 + 0.8 + 0.2)
    # a locked joint by name, and the active joints named after the URDF's
    two = RobotModel.from_urdf(path, active=("shoulder", "elbow"), locked={"waist": 0.7})
    assert two.joint_names == ("shoulder", "elbow")
    q, qd, qdd = np.array([0.2, -0.4]), np.array([0.5, 1.0]), np.array([1.0, -1.0])
    np.testing.assert_allclose(two.inverse_dynamics(q, qd, qdd),
                               ref.rne(np.r_[0.7, q], np.r_[0, qd], np.r_[0, qdd])[1:], atol=1e-9)


@pytest.mark.parametrize("kwargs, match", [
    (dict(path="no_such_file.urdf"), "no URDF file"),
    (dict(gear_ratios={"knee": 50}), "unknown joint names"),
    (dict(active=("knee",)), "unknown joint"),
])
def test_urdf_bad_input_is_one_line(kwargs, match):
    pytest.importorskip("roboticstoolbox")
    kwargs = dict(dict(path=URDF_DIR / "planar_2r.urdf"), **kwargs)
    with pytest.raises(ValueError, match=match) as exc:
        RobotModel.from_urdf(kwargs.pop("path"), **kwargs)
    assert "\n" not in str(exc.value)


def test_parameter_ranges_by_interval_arithmetic():
    """Section 3.6 of the paper: physical ranges -> base-parameter ranges that hold every
    consistent robot; without ranges they collapse to the model's own values."""
    puma = RobotModel.puma560()
    f = puma.express(PUMA560_LINKS23_BASIS)
    nominal = f(puma.standard_parameters())
    np.testing.assert_allclose(puma.parameter_ranges(basis=PUMA560_LINKS23_BASIS),
                               np.column_stack([nominal, nominal]), atol=1e-12)
    ranges = {1: dict(mass=(15.0, 20.0), com=((-0.4, -0.3), (-0.01, 0.02), (0.2, 0.25)),
                      motor_inertia=(1e-4, 3e-4)),
              2: dict(mass=(4.0, 6.0), com=((-0.03, -0.01), (-0.02, 0.0), (0.05, 0.09)),
                      inertia=((0.05, 0.08), (0.07, 0.1), (0.01, 0.02), (-0.01, 0.01), 0, 0)),
              5: dict(mass=(0.0, 2.0), com=((-0.05, 0.05), (-0.05, 0.05), (0.0, 0.1)))}
    box = puma.parameter_ranges(ranges, basis=PUMA560_LINKS23_BASIS)
    base_box = puma.parameter_ranges(ranges)
    assert box.shape == (9, 2) and base_box.shape == (7, 2)
    assert np.all(box[:, 0] <= nominal) and np.all(nominal <= box[:, 1])
    rng = np.random.default_rng(0)
    base = puma.base_parameters()
    for _ in range(200):  # random robots inside the physical ranges
        links = list(puma.links)
        for i, r in ranges.items():
            kw = dict(mass=rng.uniform(*r["mass"]), com=[rng.uniform(*c) for c in r["com"]])
            if "inertia" in r:
                kw["inertia"] = [rng.uniform(*np.broadcast_to(v, 2)) for v in r["inertia"]]
            if "motor_inertia" in r:
                kw["motor_inertia"] = rng.uniform(*r["motor_inertia"])
            links[i] = dataclasses.replace(links[i], **kw)
        robot = RobotModel(links, active=(1, 2))
        p = robot.standard_parameters()
        fv, bv = f(p), base(p)
        assert np.all(box[:, 0] - 1e-12 <= fv) and np.all(fv <= box[:, 1] + 1e-12)
        assert np.all(base_box[:, 0] - 1e-12 <= bv) and np.all(bv <= base_box[:, 1] + 1e-12)
    with pytest.raises(ValueError, match="lo <= hi"):
        puma.parameter_ranges({1: dict(mass=(20.0, 15.0))})
    with pytest.raises(ValueError, match="only moving links"):
        puma.parameter_ranges({0: dict(mass=(1.0, 2.0))})


def test_payload_on_the_last_link_against_robotics_toolbox():
    """A payload fixed to the last link shifts the base parameters by K dp: the six-joint
    PUMA 560 with a 2.5 kg tool (off-axis centre of mass, own inertia) against Robotics
    Toolbox's rne with the tool merged into its link 6."""
    rtb = pytest.importorskip("roboticstoolbox")
    ref = rtb.models.DH.Puma560().nofriction(coulomb=True, viscous=True)
    m, c, ip = 2.5, np.array([0.02, -0.03, 0.1]), np.diag([3e-3, 4e-3, 2e-3])
    link = ref.links[5]
    m0, c0, i0 = link.m, np.asarray(link.r, dtype=float), np.asarray(link.I, dtype=float)
    mt = m0 + m
    ct = (m0 * c0 + m * c) / mt

    def about(i, mi, d):  # parallel axes, written here apart from the library
        return i + mi * (d @ d * np.eye(3) - np.outer(d, d))

    link.m, link.r, link.I = mt, ct, about(i0, m0, c0 - ct) + about(ip, m, c - ct)
    puma = RobotModel.puma560(active=range(6))
    base = puma.base_parameters()
    beta = base(puma.standard_parameters()) + puma.payload_delta(m, c, ip, base=base)
    rng = np.random.default_rng(5)
    for _ in range(3):
        q, qd, qdd = rng.uniform(-3, 3, 6), rng.normal(size=6), rng.normal(size=6)
        tau = puma.regressor(q, qd, qdd)[:, base.independent] @ beta
        np.testing.assert_allclose(tau, ref.rne(q, qd, qdd), atol=1e-10)
    dp = puma.payload_parameters(m, c, ip)
    assert np.count_nonzero(dp) <= 10 and np.all(dp[:50] == 0)
    with pytest.raises(ValueError, match="mass"):
        puma.payload_parameters(-1.0)


def test_point_mass_payload_is_a_body_without_inertia():
    """A point mass (no inertia given: the on-line search's payload) gives the standard
    parameters of a body with zero inertia about its centre of mass, to the bit; bad masses
    and centres of mass are one-line errors."""
    puma = RobotModel.puma560(active=(0, 1, 2))
    for m, c in ((0.0, (0.0, 0.0, 0.0)), (2.5, (0.02, -0.03, 0.1)), (0.7, (-0.2, 0.0, 0.05))):
        assert np.array_equal(puma.payload_parameters(m, c),
                              puma.payload_parameters(m, c, np.zeros((3, 3))))
    with pytest.raises(ValueError, match="mass"):
        puma.payload_parameters(float("nan"))
    with pytest.raises(ValueError, match="centre of mass"):
        puma.payload_parameters(1.0, (0.1, 0.2))


def test_payload_in_the_papers_basis_is_eq3():
    """Links 2-3 with the wrist locked: the payload's shift of f1..f9 has the paper's
    structure (plant.robot.payload.payload_delta_matrix, eq. 3) for a tool given in the
    flange frame."""
    from plant.robot.payload import payload_delta_matrix

    puma = RobotModel.puma560()
    basis = puma.express(PUMA560_LINKS23_BASIS)
    m = 1.7
    df = puma.payload_delta(m, (0.03, 0.01, 0.12), np.diag([2e-3, 1e-3, 3e-3]), base=basis)
    a3 = PUMA560_DH[1]["a"]  # the paper's a3 (modified DH) is the standard table's a2
    # m xp = df5, m yp = df6, J = df1 in the paper's link-3 frame
    np.testing.assert_allclose(df, payload_delta_matrix(a3) @ [m, df[4], df[5], df[0]],
                               atol=1e-12)
    assert df[8] == pytest.approx(a3 * m)


def test_payload_delta_gives_the_drill_logs_truth(truth):
    """The development logs' truth (made with Robotics Toolbox): the drill log's f minus the
    rigid log's f is the 1.5 kg drill of its truth file, fixed to link 6."""
    drill, rigid = truth("puma560_paper_drill_flex"), truth("puma560_paper_rigid")
    tool = drill["payload"]
    puma = RobotModel.puma560()
    df = puma.payload_delta(tool["mass_kg"], tool["com_m_rtb_frame6"],
                            np.diag(tool["inertia_about_com_kgm2"]),
                            base=puma.express(PUMA560_LINKS23_BASIS))
    np.testing.assert_allclose(df, np.subtract(drill["f_vector"], rigid["f_vector"]), atol=1e-9)


# ------------------------------------------------ PUMA 560 links 2-3: the paper's instance
@pytest.fixture(scope="module")
def links23():
    return RobotModel.puma560_links23()


def test_puma_links23_instance_is_the_papers_closed_form(links23):
    """``RobotModel.puma560_links23()`` in the paper's joints: its torques in f1..f9 are
    plant.robot.model's eq. 2 (D q'' + h + g) for any f, at random states."""
    from plant.robot.robot_model import BasisModel

    assert isinstance(links23, BasisModel) and isinstance(links23, RobotModel)
    assert links23.name == "PUMA 560 links 2-3" and links23.joint_names == ("q2", "q3")
    rng = np.random.default_rng(23)
    for _ in range(10):
        f = rng.normal(size=9)
        q, qd, qdd = rng.uniform(-4, 4, 2), rng.normal(0, 3, 2), rng.normal(0, 10, 2)
        tau = paper.inverse_dynamics(f, q, qd, qdd)
        np.testing.assert_allclose(links23.inverse_dynamics(q, qd, qdd, f), tau, rtol=0, atol=1e-12)
        np.testing.assert_allclose(links23.regressor(q, qd, qdd) @ f, tau, rtol=0, atol=1e-12)
        np.testing.assert_allclose(links23.regressor(q, qd, qdd), paper.regressor(q, qd, qdd),
                                   rtol=0, atol=1e-12)
        np.testing.assert_allclose(links23.inertia_matrix(q, f), paper.inertia_matrix(f, q),
                                   rtol=0, atol=1e-12)
        np.testing.assert_allclose(links23.coriolis_centrifugal(q, qd, f),
                                   paper.coriolis_centrifugal(f, q, qd), rtol=0, atol=1e-12)
        np.testing.assert_allclose(links23.gravity_vector(q, f), paper.gravity_vector(f, q),
                                   rtol=0, atol=1e-12)
    # another g is the paper's model at that g
    moon = RobotModel.puma560_links23(gravity_m_s2=1.62)
    np.testing.assert_allclose(moon.gravity_vector(q, f), paper.gravity_vector(f, q, g=1.62),
                               rtol=0, atol=1e-12)


def test_puma_links23_parameters_are_f1_to_f9(links23):
    """The instance's parameter vector and named base parameters are f1..f9 (names, order,
    signs): the nine regressor columns are independent (QR keeps all nine, K = 1), while the
    DH chain's QR gives seven and the definition lists the two ties of eq. 3."""
    names = tuple(f"f{i}" for i in range(1, 10))
    assert links23.standard_parameter_names == names
    base = links23.base_parameters()
    assert base.names == names and base.rank == 9
    np.testing.assert_array_equal(base.independent, np.arange(9))
    np.testing.assert_array_equal(base.K, np.eye(9))
    assert links23.chain.base_parameters().rank == 7
    d = links23.definition
    assert d.names == names and d.rank == 7
    assert d.relations == ("f3 - 0.4318 f5 = 0", "f4 - 0.4318 f6 = 0")
    # the same f as Robotics Toolbox's convention expressed in PUMA560_LINKS23_BASIS (eq. 3):
    # the sign flip of the joints changes neither the standard parameters nor f
    rtb = RobotModel.puma560()
    ref = rtb.express(PUMA560_LINKS23_BASIS)
    np.testing.assert_allclose(d.K, ref.K, rtol=0, atol=1e-12)
    assert d.expressions == ref.expressions
    # the chain is Robotics Toolbox's arm with joints 2 and 3 turned the paper's way, and its
    # torques are the instance's at f = K p for any standard parameters p
    rng = np.random.default_rng(5)
    chain = links23.chain
    for _ in range(5):
        q, qd, qdd = rng.uniform(-3, 3, 2), rng.normal(size=2), rng.normal(size=2)
        p = chain.standard_parameters() * rng.uniform(0.5, 1.5, len(chain.standard_parameter_names))
        np.testing.assert_allclose(chain.inverse_dynamics(q, qd, qdd, p),
                                   -rtb.inverse_dynamics(-q, -qd, -qdd, p), rtol=0, atol=1e-12)
        np.testing.assert_allclose(links23.inverse_dynamics(q, qd, qdd, d(p)),
                                   chain.inverse_dynamics(q, qd, qdd, p), rtol=0, atol=1e-10)
    # the default f is Corke's arm's: f1 - f2 = Jm3 k3^2, f3 = a3 f5, f4 = a3 f6
    f = links23.standard_parameters()
    # (K comes from least squares at random states: exact to rounding, ~1e-14 absolute)
    np.testing.assert_allclose(f, ref(rtb.standard_parameters()), rtol=0, atol=1e-12)
    a3, k3 = PUMA560_DH[1]["a"], PUMA560_DH[2]["gear_ratio"]
    assert f[0] - f[1] == pytest.approx(200e-6 * k3 ** 2, abs=1e-12)
    assert f[2] == pytest.approx(a3 * f[4], abs=1e-12) and f[3] == pytest.approx(a3 * f[5], abs=1e-12)


def test_puma_links23_definition_is_eq3_of_the_link_parameters():
    """Eq. 3 (plant.robot.symbolic.base_parameters_expr) of links 2 and 3 drawn at random (any
    centre of mass and inertia, products included; massless wrist) is the instance's f = K p.

    The paper's planar coordinates from Robotics Toolbox's link frames (standard DH, frame i
    at the far end of link i): link 2's x2 = a2 + cx, y2 = -cy and Izz2 about its z axis;
    link 3's frame is turned by alpha = -pi/2, so x3 = a3' + cx, y3 = -cz and Izz3 is about
    its y axis; the paper's a3 is the table's a2."""
    from plant.robot.symbolic import base_parameters_expr

    rng = np.random.default_rng(31)
    eq3 = base_parameters_expr()
    for _ in range(5):
        rows = [dict(r) for r in PUMA560_DH]
        for r in rows[3:]:
            r.update(mass=0.0, com=(0, 0, 0), inertia=(0,) * 6)
        for j in (1, 2):
            A = rng.normal(size=(3, 3))
            rows[j].update(mass=rng.uniform(1, 20), com=tuple(rng.uniform(-0.3, 0.3, 3)),
                           inertia=A @ A.T * 0.05, motor_inertia=rng.uniform(1e-4, 5e-4),
                           gear_ratio=rng.choice([-1, 1]) * rng.uniform(20, 150))
        puma = RobotModel.puma560_links23(gear_ratios=(rows[1]["gear_ratio"], rows[2]["gear_ratio"]))
        chain = RobotModel([Link(**r) for r in rows], active=(1, 2))
        L2, L3 = rows[1], rows[2]
        phys = [L2["mass"], L2["a"] + L2["com"][0], -L2["com"][1], L2["inertia"][2, 2],
                L2["motor_inertia"], L2["gear_ratio"],
                L3["mass"], L3["a"] + L3["com"][0], -L3["com"][2], L3["inertia"][1, 1],
                L3["motor_inertia"], L3["gear_ratio"], L2["a"], 9.81]
        f_eq3 = np.asarray(eq3(phys)).reshape(-1)
        np.testing.assert_allclose(puma.definition(chain.standard_parameters()), f_eq3,
                                   rtol=1e-10, atol=1e-12)


def test_puma_links23_payload_and_ranges_go_through_eq3(links23):
    """A payload and physical search ranges give the instance's f the shifts and boxes of the
    DH model expressed in eq. 3 (the same chain indices, Robotics Toolbox's link frames)."""
    rtb = RobotModel.puma560()
    m, c, ip = 1.5, np.array([0.02, -0.01, 0.1]), np.diag([2e-3, 1e-3, 3e-3])
    np.testing.assert_allclose(
        links23.payload_delta(m, c, ip),
        rtb.payload_delta(m, c, ip, base=rtb.express(PUMA560_LINKS23_BASIS)), rtol=0, atol=1e-12)
    ranges = {1: dict(mass=(15.0, 20.0), motor_inertia=(1e-4, 3e-4)),
              2: dict(mass=(4.0, 6.0), com=((-0.03, -0.01), (-0.02, 0.0), (0.05, 0.09))),
              5: dict(mass=(0.0, 2.0))}
    box = links23.parameter_ranges(ranges)
    assert box.shape == (9, 2)
    np.testing.assert_allclose(box, rtb.parameter_ranges(ranges, basis=PUMA560_LINKS23_BASIS),
                               rtol=0, atol=1e-12)
    f = links23.standard_parameters()
    assert np.all(box[:, 0] <= f + 1e-12) and np.all(f <= box[:, 1] + 1e-12)


@pytest.mark.parametrize("make, match", [
    (lambda: RobotModel.puma560_links23(gear_ratios=(100.0,)), "gear_ratios"),
    (lambda: RobotModel.puma560_links23(gear_ratios=(100.0, 0.0)), "gear_ratio"),
    (lambda: RobotModel.puma560_links23(gravity_m_s2=0.0), "gravity_m_s2"),
    (lambda: RobotModel.puma560_links23(locked={7: 0.1}), "locked"),
])
def test_puma_links23_bad_input_is_one_line(make, match):
    with pytest.raises(ValueError, match=match) as exc:
        make()
    assert "\n" not in str(exc.value)


def test_a_basis_model_needs_a_torque_and_a_plain_chain(links23):
    from plant.robot.robot_model import BasisModel

    with pytest.raises(ValueError, match="torque"):
        BasisModel(RobotModel.puma560(), PUMA560_LINKS23_BASIS)
    with pytest.raises(ValueError, match="chain"):
        BasisModel(links23, links23.basis)
