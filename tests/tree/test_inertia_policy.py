"""Massless intermediate links and the inertia policy (strict / balance as MuJoCo's balanceinertia / warn)."""

import mujoco
import numpy as np
import pytest

from particlesim.errors import InertiaError, InertiaWarning
from particlesim.tree import bias_forces, forward_dynamics, link_jacobian, mass_matrix
from particlesim.io import load_urdf
from tree_helpers import PinocchioOracle, max_rel

#: Float64 implementations of the same rigid-body model (Pinocchio, MuJoCo C).
REF_RTOL = 1e-10
LIMIT = '<limit lower="-3" upper="3" effort="1" velocity="1"/>'


def _inertial(m, ixx, iyy, izz, ixy=0.0, xyz="0 0 0.1", rpy="0.3 0.2 0.1"):
    return (f'<inertial><mass value="{m}"/><origin xyz="{xyz}" rpy="{rpy}"/><inertia ixx="{ixx}" ixy="{ixy}" '
            f'ixz="0" iyy="{iyy}" iyz="0" izz="{izz}"/></inertial>')


def _joint(name, parent, child, axis, xyz="0 0 0"):
    return (f'<joint name="{name}" type="revolute"><parent link="{parent}"/><child link="{child}"/>'
            f'<origin xyz="{xyz}"/><axis xyz="{axis}"/>{LIMIT}</joint>')


def ball_arm() -> str:
    """A shoulder written as three revolutes with two massless links between them (one without <inertial>, one
    with zero mass), then an upper arm and an elbow."""
    return ('<robot name="ball"><link name="base"/><link name="sx"/>'
            '<link name="sy"><inertial><mass value="0"/><inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/>'
            f'</inertial></link><link name="upper">{_inertial(2.0, 0.03, 0.028, 0.004, xyz="0.02 0 -0.15")}</link>'
            f'<link name="fore">{_inertial(1.2, 0.012, 0.011, 0.002, xyz="0 0.01 -0.12")}</link>'
            + _joint("shoulder_x", "base", "sx", "1 0 0", "0 0 1.4") + _joint("shoulder_y", "sx", "sy", "0 1 0")
            + _joint("shoulder_z", "sy", "upper", "0 0 1") + _joint("elbow", "upper", "fore", "0 1 0", "0 0 -0.3")
            + "</robot>")


def test_massless_intermediate_links_against_pinocchio():
    urdf = ball_arm()
    model = load_urdf(urdf, limits="ignore")
    assert model.nq == 4 and not np.any(np.asarray(model.inertia[:2]))
    oracle = PinocchioOracle(urdf, model.joint_names, (0.0, 0.0, -9.81))
    rng = np.random.default_rng(3)
    q, qd, tau = rng.uniform(-1.2, 1.2, 4), rng.normal(size=4), rng.normal(size=4)
    m_ref, b_ref = oracle.mass_matrix(q), oracle.bias(q, qd)
    assert max_rel(mass_matrix(model, q), m_ref) <= REF_RTOL
    assert max_rel(bias_forces(model, q, qd), b_ref) <= REF_RTOL
    assert max_rel(forward_dynamics(model, q, qd, tau), np.linalg.solve(m_ref, tau - b_ref)) <= REF_RTOL
    assert max_rel(link_jacobian(model, q, "fore"), oracle.jacobian(q, "fore", False)) <= REF_RTOL


def _two_links(inertial_a, inertial_b, *, mujoco_balance=False) -> str:
    mj = '<mujoco><compiler balanceinertia="true"/></mujoco>' if mujoco_balance else ""
    return (f'<robot name="r">{mj}<link name="base"/><link name="a">{inertial_a}</link><link name="b">{inertial_b}'
            '</link>' + _joint("j1", "base", "a", "0 0 1") + _joint("j2", "a", "b", "0 1 0", "0 0 0.3") + "</robot>")


# a: a thin plate whose moments break the triangle inequality (0.01 + 0.01 < 0.05); b: physical
BAD, GOOD = _inertial(1.0, 0.01, 0.01, 0.05), _inertial(1.5, 0.02, 0.03, 0.04, xyz="0.05 0 0.1")


def test_strict_refuses_and_points_to_the_policies():
    with pytest.raises(InertiaError, match="link 'a'.*triangle inequality.*inertia='balance'"):
        load_urdf(_two_links(BAD, GOOD), limits="ignore")


def test_balance_matches_mujoco_balanceinertia():
    with pytest.warns(InertiaWarning, match="1 link\\(s\\) repaired.*'a'"):
        model = load_urdf(_two_links(BAD, GOOD), limits="ignore", inertia="balance")
    m = mujoco.MjModel.from_xml_string(_two_links(BAD, GOOD, mujoco_balance=True))
    np.testing.assert_allclose(m.body_inertia[1], [0.07 / 3] * 3, rtol=1e-15)  # MuJoCo: all three to their mean
    d = mujoco.MjData(m)
    for q in ([0.3, -0.7], [1.1, 0.4]):
        d.qpos[:] = q
        mujoco.mj_forward(m, d)
        full = np.zeros((2, 2))
        mujoco.mj_fullM(m, d, full)
        assert max_rel(mass_matrix(model, np.array(q)), full) <= REF_RTOL


def test_warn_loads_the_file_unchanged_and_names_every_link():
    with pytest.warns(InertiaWarning, match="2 link\\(s\\) loaded unchanged: 'a', 'b'"):
        model = load_urdf(_two_links(BAD, BAD), limits="ignore", inertia="warn")
    # the file's tensors as they are: Pinocchio loads them without judging, and the mass matrices agree
    oracle = PinocchioOracle(_two_links(BAD, BAD), model.joint_names, (0.0, 0.0, -9.81))
    q = np.array([0.4, -1.1])
    assert max_rel(mass_matrix(model, q), oracle.mass_matrix(q)) <= REF_RTOL


def test_negative_mass_is_refused_in_every_mode_and_rounded_zero_tensors_load():
    for policy in ("strict", "balance", "warn"):
        with pytest.raises(InertiaError, match="link 'a': mass must be positive"):
            load_urdf(_two_links(_inertial(-1.0, 0.01, 0.01, 0.01), GOOD), limits="ignore", inertia=policy)
    # a point mass whose tensor is rounding residue (principal moments +-1e-35 about a zero trace) is physical
    point = _inertial(0.5, 0.0, 0.0, 0.0, ixy=1e-35)
    model = load_urdf(_two_links(GOOD, point), limits="ignore")
    assert float(model.inertia[1, 0]) == 0.5
    with pytest.raises(ValueError, match="inertia must be 'strict', 'balance' or 'warn'"):
        load_urdf(_two_links(GOOD, GOOD), inertia="fix")


def _arm_with(tip_inertial: str) -> str:
    """A two-link arm whose second link carries a fixed ``tip`` link (a sensor frame) with ``tip_inertial``."""
    return ('<robot name="tip"><link name="base"/>'
            f'<link name="upper">{_inertial(2.0, 0.03, 0.028, 0.004, xyz="0.02 0 -0.15")}</link>'
            f'<link name="fore">{_inertial(1.2, 0.012, 0.011, 0.002, xyz="0 0.01 -0.12")}</link>'
            f'<link name="tip">{tip_inertial}</link>'
            + _joint("shoulder", "base", "upper", "0 1 0", "0 0 1.0") + _joint("elbow", "upper", "fore", "0 1 0", "0 0 -0.3")
            + '<joint name="tip_fixed" type="fixed"><parent link="fore"/><child link="tip"/><origin xyz="0 0 -0.3"/>'
            '</joint></robot>')


def test_zero_mass_with_a_tensor_is_refused_or_dropped_by_name():
    """Bolt's feet: mass 0 with a 5e-7 tensor. Strict (and warn) refuse it naming the link; balance loads the
    link as massless and says so; the result equals the arm without the tip's inertial."""
    urdf = _arm_with(_inertial(0.0, 5.7e-7, 8.4e-7, 5.3e-7))
    for policy in ("strict", "warn"):
        with pytest.raises(InertiaError, match="link 'tip': mass must be positive, got 0.0"):
            load_urdf(urdf, limits="ignore", inertia=policy)
    with pytest.warns(InertiaWarning, match="zero mass and a nonzero inertia tensor loaded as massless.*'tip'"):
        model = load_urdf(urdf, limits="ignore", inertia="balance")
    np.testing.assert_array_equal(np.asarray(model.inertia), np.asarray(load_urdf(_arm_with(""), limits="ignore").inertia))


def test_a_point_like_link_far_from_its_joint_is_judged_beyond_the_shift_rounding():
    """iCub's shank: 1.26 kg 0.1 m from its joint with a ~1e-18 tensor. Balanced, it is a point mass; merged into
    its owner and shifted back to the centre of mass, its tensor is rounding of size eps |J| (1e-18 here), which
    the composite check must not read as a violated triangle inequality."""
    shank = ('<inertial><mass value="1.264"/><origin xyz="-0.1071 0.00182 -0.00211"/><inertia ixx="1.10961e-18" '
             'ixy="5.42101e-20" ixz="-5.42101e-20" iyy="0" iyz="8.47033e-22" izz="0"/></inertial>')
    urdf = ('<robot name="leg"><link name="base"/>'
            f'<link name="thigh">{_inertial(2.0, 0.03, 0.028, 0.004, xyz="0.02 0 -0.15")}</link>'
            f'<link name="shank">{shank}</link>'
            + _joint("hip", "base", "thigh", "0 1 0", "0 0 1.0") + _joint("knee", "thigh", "shank", "0 1 0", "0 0 -0.3")
            + "</robot>")
    with pytest.raises(InertiaError, match="link 'shank': .*(semi-definite|triangle inequality)"):
        load_urdf(urdf, limits="ignore")
    with pytest.warns(InertiaWarning, match="'shank'"):
        model = load_urdf(urdf, limits="ignore", inertia="balance")
    assert float(model.inertia[1, 0]) == 1.264
