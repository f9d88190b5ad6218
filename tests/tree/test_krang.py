"""Krang in the report's frames (form a) against the report's own transforms and against the URDF (form b)."""

import numpy as np
import pytest

from particlesim.scenes.krang import (
    KRANG_LENGTHS_2018,
    REPORT_JOINTS,
    REPORT_LINKS,
    REPORT_TO_URDF,
    krang_2018_pitch_urdf,
    krang_report,
    krang_urdf,
    urdf_path,
)
from particlesim.tree import coriolis_times_qdot, gravity_torques, mass_matrix
from particlesim.io import load_urdf
from particlesim.tree.kinematics import joint_transforms
from tree_helpers import DART_DOF_ORDER, KRANG_URDFS, max_rel

EXACT_RTOL = 1e-12
#: The URDF writes pi as 3.14 / 3.1416: its dynamics differ from exact frames by this much, and no less.
APPROX_PI_EFFECT = (1e-5, 1e-2)
L = KRANG_LENGTHS_2018


def _report_transforms(link, c, s):
    """The report's ^iT_j (section 2.1), written out from its matrices: (rotation, origin)."""
    side = link[-1]
    k = int(link[:-1]) if side in "lr" else int(link)
    if link == "1":
        return np.array([[0, s, -c], [-1, 0, 0], [0, c, s]]), np.zeros(3)
    if link == "2":
        return np.array([[1, 0, 0], [0, c, s], [0, -s, c]]), np.array([0, L["L1"], -L["L2"]])
    if link == "3":
        return np.array([[-c, 0, s], [0, 1, 0], [-s, 0, -c]]), np.array([0, L["L3"], L["L4"]])
    if link == "4l":
        return np.array([[0, 1, 0], [c, 0, -s], [-s, 0, -c]]), np.array([L["L6"], L["L5"], 0])
    if link == "4r":
        return np.array([[0, -1, 0], [c, 0, -s], [s, 0, c]]), np.array([-L["L6"], L["L5"], 0])
    if k in (5, 7, 9):
        return np.array([[-1, 0, 0], [0, -c, -s], [0, -s, c]]), np.zeros(3)
    if k in (6, 8):
        return np.array([[-c, 0, s], [0, -1, 0], [s, 0, c]]), np.array([0, -L["L7" if k == 6 else "L8"], 0])
    return np.array([[-c, -s, 0], [0, 0, -1], [s, -c, 0]]), np.array([0, -L["L9"], 0])


@pytest.fixture(scope="module")
def report():
    return krang_report()


def test_report_frames_reproduce_section_2_1(report):
    q = np.random.default_rng(0).uniform(-3, 3, 17)
    rot, pos = joint_transforms(report, q)
    for i, link in enumerate(REPORT_LINKS):
        r_ref, p_ref = _report_transforms(link, np.cos(q[i]), np.sin(q[i]))
        np.testing.assert_allclose(rot[i], r_ref, rtol=0, atol=1e-15, err_msg=link)
        np.testing.assert_allclose(pos[i], p_ref, rtol=0, atol=1e-15, err_msg=link)


def _compare(report, urdf, seed=0, states=3):
    """Max relative differences of (A, C qd, Q) with q_report = sign * q_urdf."""
    perm = [urdf.joint_names.index(REPORT_TO_URDF[j][0]) for j in REPORT_JOINTS]
    sign = np.array([REPORT_TO_URDF[j][1] for j in REPORT_JOINTS])
    rng = np.random.default_rng(seed)
    err = np.zeros(3)
    for _ in range(states):
        q, qd = rng.uniform(-2, 2, 17), rng.normal(size=17)
        qu, qdu = np.zeros(urdf.nq), np.zeros(urdf.nq)
        qu[perm], qdu[perm] = sign * q, sign * qd
        a_u = np.asarray(mass_matrix(urdf, qu))[np.ix_(perm, perm)] * np.outer(sign, sign)
        c_u = np.asarray(coriolis_times_qdot(urdf, qu, qdu))[perm] * sign
        g_u = np.asarray(gravity_torques(urdf, qu))[perm] * sign
        err = np.maximum(err, [max_rel(mass_matrix(report, q), a_u), max_rel(coriolis_times_qdot(report, q, qd), c_u),
                               max_rel(gravity_torques(report, q), g_u)])
    return err


def test_report_form_equals_urdf_with_exact_frames(report):
    """Same A, C qd, Q as krang_2018.urdf (wheels off, base pitch joint) with pi written exactly and the lateral
    offsets zeroed."""
    urdf = load_urdf(krang_2018_pitch_urdf(zero_lateral=True, exact_angles=True), gravity=(0.0, -9.81, 0.0))
    assert np.all(_compare(report, urdf) <= EXACT_RTOL)


def test_lateral_offsets_do_not_change_joint_space_dynamics(report):
    """JWaist x / JTorso x shift the upper body along the pitch axis, the only joint axis above them, and
    perpendicular to gravity: A, C qd and Q are unchanged (the poses are not)."""
    urdf = load_urdf(krang_2018_pitch_urdf(exact_angles=True), gravity=(0.0, -9.81, 0.0))
    assert np.all(_compare(report, urdf) <= EXACT_RTOL)


def test_urdf_approximate_pi_is_visible(report):
    urdf = load_urdf(krang_2018_pitch_urdf(), gravity=(0.0, -9.81, 0.0))
    err = _compare(report, urdf)
    print(f"report frames vs krang_2018.urdf as written: max rel (A, Cqd, Q) = {err}")
    assert np.all(err > APPROX_PI_EFFECT[0]) and np.all(err < APPROX_PI_EFFECT[1])


def test_report_parameters_from_urdf(report):
    """Link 1 is the URDF Base moved to its origin; the total mass is the URDF's without wheels and Kinect."""
    import xml.etree.ElementTree as ET

    root = ET.parse(urdf_path("krang_2018.urdf")).getroot()
    masses = {ln.get("name"): float(ln.find("inertial/mass").get("value")) for ln in root.findall("link")}
    total = sum(m for n, m in masses.items() if n not in ("LWheel", "RWheel"))
    np.testing.assert_allclose(np.sum(report.inertia[:, 0]), total, rtol=1e-14)
    base = root.find("link[@name='Base']/inertial")
    m = float(base.find("mass").get("value"))
    c = np.array([float(x) for x in base.find("origin").get("xyz").split()])
    i = base.find("inertia")
    xx, xy, xz, yy, yz, zz = (float(i.get(k)) for k in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz"))
    j = np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]]) + m * (c @ c * np.eye(3) - np.outer(c, c))
    expected = [m, *(m * c), j[0, 0], j[0, 1], j[0, 2], j[1, 1], j[1, 2], j[2, 2]]
    np.testing.assert_allclose(report.inertia[0], expected, rtol=1e-14)


@pytest.mark.parametrize("name", KRANG_URDFS)
def test_krang_urdfs_load(name):
    model = krang_urdf(name)
    expected = {"krang_fixed_wheel_2018-04.urdf": DART_DOF_ORDER, "krang_2018.urdf": None,
                "krang_fixed_base_2018.urdf": DART_DOF_ORDER[1:], "krang_single_arm_2018.urdf": DART_DOF_ORDER[4:11]}
    if expected[name] is not None:
        assert model.joint_names == expected[name]
    else:
        assert model.joint_names[:2] == ("JLWheel", "JRWheel") and model.nq == 18
