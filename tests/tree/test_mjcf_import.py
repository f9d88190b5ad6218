"""MJCF import (``particlesim.io.load_mjcf``) against MuJoCo C on the compiled model itself, and against the URDF
import of the same robot."""

import mujoco
import numpy as np
import pytest

from particlesim.errors import ParseError
from particlesim.io import from_mujoco_state, load_mjcf, load_urdf
from particlesim.io.mjcf import mujoco_model
from particlesim.tree import bias_forces, friction_torques, link_jacobian, link_poses, mass_matrix
from tree_helpers import max_rel

#: Float64 implementations of the same rigid-body model.
MJ_RTOL = 1e-10

#: A floating body with: a body carrying two hinges with their own anchors and a nonzero ``ref``, a tilted hinge
#: axis, a slide with ``ref``, a welded body (head), inertias from geoms, damping and armature, and a joint
#: coupling (``<equality><joint>``) that becomes a mimic joint.
HUMANOID = """<mujoco><option gravity="0.3 -0.2 -9.81"/><compiler angle="radian"/><worldbody>
<body name="torso" pos="0 0 1.2" quat="0.9 0.1 0.2 0.1"><freejoint name="root"/>
 <geom type="box" size="0.2 0.15 0.3" density="800"/>
 <body name="head" pos="0 0 0.4"><geom type="sphere" size="0.1" pos="0.02 0 0.05"/></body>
 <body name="thigh" pos="0.1 0.05 -0.35" euler="0.2 -0.1 0.3">
  <joint name="hip_x" type="hinge" axis="1 0 0" pos="0 0 0.05" ref="0.2"/>
  <joint name="hip_y" type="hinge" axis="0 1 0.2" pos="0.01 0 0.04" damping="0.3"/>
  <geom type="capsule" fromto="0 0 0 0 0.02 -0.4" size="0.05"/>
  <body name="shin" pos="0 0.02 -0.42">
   <joint name="knee" type="hinge" axis="0 1 0" pos="0 0 0.02" armature="0.05"/>
   <geom type="capsule" fromto="0 0 0 0.03 0 -0.4" size="0.04"/>
   <body name="foot" pos="0.03 0 -0.42"><joint name="ankle_slide" type="slide" axis="0.3 0 1" ref="0.05"/>
    <geom type="box" size="0.1 0.05 0.02" pos="0.04 0 0"/></body>
  </body>
 </body>
 <body name="arm" pos="-0.1 0.2 0.2"><joint name="sh" axis="0 1 0" pos="0 -0.02 0"/><geom type="capsule" fromto="0 0 0 0 0 -0.3" size="0.03"/>
  <body name="hand" pos="0 0 -0.32"><joint name="wr" axis="1 0 0"/><geom type="sphere" size="0.04" pos="0 0 -0.03"/></body></body>
</body></worldbody>
<equality><joint joint1="wr" joint2="sh" polycoef="0.1 -0.5 0 0 0"/></equality></mujoco>"""


def _reference(m, model, d):
    """MuJoCo's M and bias in our coordinates: ``v_mj = T v`` (free joint: world linear velocity) and the mimic
    map, ``M = Gm^T M_mj Gm``, ``b = Gm^T (b_mj + M_mj dGm/dt v)``."""
    q, qd = from_mujoco_state(model, m, d.qpos, d.qvel)
    rot = np.asarray(link_poses(model, q)[0][0])
    order = []
    for jn, kind in zip(model.joint_names, model.kinds):
        a = m.jnt_dofadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, jn)]
        order += list(range(a, a + (6 if kind == "free" else 1)))
    t = np.eye(len(order))
    t[:3, :3] = rot
    gm = np.zeros((m.nv, model.nv))
    gm[order] = t @ model.coordinate_map[0]
    full = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, d, full)
    extra = np.zeros(m.nv)
    extra[order[:3]] = rot @ np.cross(qd[3:6], qd[:3])  # d/dt (R v) = R (w x v) + R dv/dt
    return q, qd, gm, gm.T @ full @ gm, gm.T @ (d.qfrc_bias + full @ extra)


def test_mjcf_floating_body_with_multi_joint_bodies_against_mujoco():
    m = mujoco.MjModel.from_xml_string(HUMANOID)
    model = load_mjcf(HUMANOID, limits="ignore")
    assert model.joint_names == ("root", "hip_x", "hip_y", "knee", "ankle_slide", "sh", "wr")
    assert (model.nq, model.nv) == (12, 11) and model.mimic[-1][0] == model.joint_names.index("sh")
    assert model.frame("head") is not None
    d = mujoco.MjData(m)
    rng = np.random.default_rng(0)
    for _ in range(2):
        d.qpos[:] = m.qpos0 + np.r_[rng.normal(size=3) * 0.1, np.zeros(4), rng.normal(size=m.nq - 7) * 0.5]
        quat = rng.normal(size=4)
        d.qpos[3:7] = quat / np.linalg.norm(quat)
        d.qvel[:] = rng.normal(size=m.nv)
        adr = {n: (m.jnt_qposadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n)],
                   m.jnt_dofadr[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n)]) for n in ("sh", "wr")}
        # the coupling MuJoCo would enforce: wr - wr0 = 0.1 - 0.5 (sh - sh0)
        d.qpos[adr["wr"][0]] = m.qpos0[adr["wr"][0]] + 0.1 - 0.5 * (d.qpos[adr["sh"][0]] - m.qpos0[adr["sh"][0]])
        d.qvel[adr["wr"][1]] = -0.5 * d.qvel[adr["sh"][1]]
        mujoco.mj_forward(m, d)
        q, qd, gm, m_ref, b_ref = _reference(m, model, d)
        assert max_rel(mass_matrix(model, q), m_ref) <= MJ_RTOL  # armature included
        assert max_rel(bias_forces(model, q, qd), b_ref) <= MJ_RTOL
        assert max_rel(friction_torques(model, qd), -gm.T @ d.qfrc_passive) <= MJ_RTOL  # damping
        # the foot's origin moves as MuJoCo's body frame (slide with ref, after two anchored hinges)
        rot, pos = link_poses(model, q)
        foot = model.link_index("foot")
        assert np.max(np.abs(np.asarray(pos[foot]) - d.xpos[m.body("foot").id])) <= MJ_RTOL
        assert np.max(np.abs(np.asarray(rot[foot]) - d.xmat[m.body("foot").id].reshape(3, 3))) <= MJ_RTOL


def test_mjcf_of_krang_equals_its_urdf_import(krang_urdf_dir):
    path = krang_urdf_dir / "krang_fixed_wheel_2018-04.urdf"
    urdf = load_urdf(path, gravity=(0.0, -9.81, 0.0), limits="ignore")
    mj = load_mjcf(mujoco_model(path, gravity=(0.0, -9.81, 0.0)), limits="ignore")
    perm = [mj.joint_names.index(n) for n in urdf.joint_names]  # MuJoCo orders joints depth first
    rng = np.random.default_rng(1)
    q, qd = rng.uniform(-1.5, 1.5, urdf.nq), rng.normal(size=urdf.nq)
    qm, qdm = np.zeros(urdf.nq), np.zeros(urdf.nq)
    qm[perm], qdm[perm] = q, qd
    assert max_rel(np.asarray(mass_matrix(mj, qm))[np.ix_(perm, perm)], mass_matrix(urdf, q)) <= MJ_RTOL
    assert max_rel(np.asarray(bias_forces(mj, qm, qdm))[perm], bias_forces(urdf, q, qd)) <= MJ_RTOL
    end = urdf.link_names[-1]
    assert max_rel(np.asarray(link_jacobian(mj, qm, end))[:, perm], link_jacobian(urdf, q, end)) <= MJ_RTOL


@pytest.mark.parametrize("body,match", [
    ('<body><joint type="ball"/><geom size="0.1"/></body>', "joint 'joint0' of body 'body1' is a ball joint"),
    ('<body name="a"><joint name="f" type="free"/><geom size="0.1"/></body><body name="b"><joint/><geom size="0.1"/>'
     '</body><equality><connect body1="a" body2="b" anchor="0 0 0"/></equality>',
     "equality constraint 0 \\(mjEQ_CONNECT\\) is not a joint coupling"),
    ('<body><joint name="k" stiffness="3"/><geom size="0.1"/></body>', r"stiffness is not imported \(joints \['k'\]\)"),
    ('<body><geom size="0.1"/></body>', "has no joints"),
])
def test_mjcf_errors_name_the_element(body, match):
    world, _, rest = body.partition("<equality>")
    with pytest.raises(ParseError, match=match):
        load_mjcf(f"<mujoco><worldbody>{world}</worldbody>{'<equality>' + rest if rest else ''}</mujoco>")


def test_mjcf_unreadable_sources():
    with pytest.raises(ParseError, match="MuJoCo cannot compile it"):
        load_mjcf("<mujoco><worldbody><body><joint/></worldbody></mujoco>")
    with pytest.raises(ParseError, match="empty MJCF source"):
        load_mjcf("  ")
    with pytest.raises(ParseError, match="MuJoCo cannot compile it"):
        load_mjcf("/nonexistent/robot.xml")
