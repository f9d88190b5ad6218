"""Floating bases (free-flyer root joint): every tree quantity against Pinocchio's JointModelFreeFlyer, the
Lagrangian, a free body's closed-form motion and a MuJoCo C free joint; the quaternion held on the unit sphere by
the flow itself."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from particlesim import _ode
from particlesim.errors import ModelError
from particlesim.simulate import simulate
from particlesim.tree import (TreeModel, bias_forces, christoffel_symbols, forward_dynamics, friction_torques,
                              gravity_torques, inverse_dynamics, kinetic_energy, link_jacobian, link_poses,
                              mass_matrix, potential_energy)
from particlesim.io import load_urdf
from tree_helpers import batched_terms, max_rel, random_tree_urdf, states

#: Float64 implementations of the same rigid-body model.
PIN_RTOL = 1e-10
#: Closed-form free-body motion and conservation laws (relative), integrated at rtol 1e-13 over 5 s.
FREE_BODY_TOL = 1e-9
#: MuJoCo C RK4 at dt = 2.5e-4 s over 1 s against ours at rtol 1e-12 (measured gaps 1e-14..2e-13).
MUJOCO_TOL = 1e-11
GRAVITY = (0.2, -9.81, 0.4)
N_STATES = 50
BASE = ('<link name="base"><inertial><mass value="3"/><origin xyz="0.1 0.05 -0.02" rpy="0.2 0.1 0.3"/>'
        '<inertia ixx="0.1" ixy="0.01" ixz="0" iyy="0.12" iyz="0" izz="0.15"/></inertial></link>')


def floating_tree(seed, n):
    """A random tree on a massive base (continuous joints written as revolute: Pinocchio gives those two q)."""
    return random_tree_urdf(seed, n=n, prismatic=0.3).replace("continuous", "revolute").replace(
        '<link name="base"/>', BASE)


class FreeFlyerOracle:
    """Pinocchio with a JointModelFreeFlyer root, evaluated in our coordinate order (matched by joint name)."""

    def __init__(self, urdf, model, gravity):
        import pinocchio as pin

        self.pin = pin
        self.m = pin.buildModelFromXML(urdf, pin.JointModelFreeFlyer())
        self.m.gravity.linear = np.asarray(gravity, dtype=float)
        self.d = self.m.createData()
        joints = [self.m.joints[self.m.getJointId(n)] for n in model.coordinate_names]
        self.iq = np.concatenate([np.arange(j.idx_q, j.idx_q + j.nq) for j in joints])
        self.iv = np.concatenate([np.arange(j.idx_v, j.idx_v + j.nv) for j in joints])

    def q(self, q):
        out = np.zeros(self.m.nq)
        out[self.iq] = q
        return out

    def v(self, v):
        out = np.zeros(self.m.nv)
        out[self.iv] = v
        return out

    def mass_matrix(self, q):
        a = self.pin.crba(self.m, self.d, self.q(q))
        return (np.triu(a) + np.triu(a, 1).T)[np.ix_(self.iv, self.iv)]

    def jacobian(self, q, link, local):
        pin = self.pin
        pin.computeJointJacobians(self.m, self.d, self.q(q))
        pin.updateFramePlacements(self.m, self.d)
        ref = pin.LOCAL if local else pin.LOCAL_WORLD_ALIGNED
        return pin.getFrameJacobian(self.m, self.d, self.m.getFrameId(link), ref)[:, self.iv]


@pytest.mark.parametrize("seed,n", [(2, 4)])
def test_floating_tree_against_pinocchio_free_flyer(seed, n):
    urdf = floating_tree(seed, n)
    model = load_urdf(urdf, gravity=GRAVITY, limits="ignore", floating_base=True)
    assert (model.nq, model.nv) == (7 + n, 6 + n) and model.joint_names[0] == "root_joint"
    oracle = FreeFlyerOracle(urdf, model, GRAVITY)
    pin, pm, pd = oracle.pin, oracle.m, oracle.d
    q, qd, tau, qdd = states(np.random.default_rng(seed), N_STATES, model.nq, model.nv, quaternions=(3,))
    q[:, :3] *= 0.5
    out = batched_terms(model, model.link_names)(q, qd, tau, qdd)  # the base link included
    energy = jax.jit(jax.vmap(lambda a, b: kinetic_energy(model, a, b)))(q, qd)
    for s in range(N_STATES):
        qp, vp = oracle.q(q[s]), oracle.v(qd[s])
        assert max_rel(out["m"][s], oracle.mass_matrix(q[s])) <= PIN_RTOL
        assert max_rel(out["bias"][s], pin.nonLinearEffects(pm, pd, qp, vp)[oracle.iv]) <= PIN_RTOL
        assert max_rel(out["grav"][s], pin.computeGeneralizedGravity(pm, pd, qp)[oracle.iv]) <= PIN_RTOL
        assert max_rel(out["fd"][s], pin.aba(pm, pd, qp, vp, oracle.v(tau[s]))[oracle.iv]) <= PIN_RTOL
        assert max_rel(out["id"][s], pin.rnea(pm, pd, qp, vp, oracle.v(qdd[s]))[oracle.iv]) <= PIN_RTOL
        e_ref = pin.computeKineticEnergy(pm, pd, qp, vp)
        assert abs(float(energy[s]) - e_ref) <= PIN_RTOL * e_ref
        for link in model.link_names:
            for frame, local in (("world", False), ("local", True)):
                ref = oracle.jacobian(q[s], link, local)
                assert max_rel(out["jac"][(link, frame)][s], ref) <= PIN_RTOL, (link, frame)
    # the Lagrangian: A is the Hessian of the kinetic energy in the six base velocities and the joint rates
    hess = jax.hessian(lambda v: kinetic_energy(model, jnp.asarray(q[0]), v))(jnp.asarray(qd[0]))
    assert max_rel(hess, out["m"][0]) <= PIN_RTOL


FREE_BODY = ('<robot name="b"><link name="box"><inertial><mass value="2"/><origin xyz="0.1 -0.05 0.2"/>'
             '<inertia ixx="0.05" ixy="0.004" ixz="-0.002" iyy="0.12" iyz="0.003" izz="0.15"/></inertial></link>'
             '</robot>')


@pytest.fixture(scope="module")
def tumbling():
    """A free asymmetric body thrown and tumbling under gravity for 5 s (Dopri8, rtol 1e-13)."""
    model = load_urdf(FREE_BODY, floating_base=True)
    q0 = np.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0])
    v0 = np.array([1.0, 0.5, 2.0, 3.0, 0.2, -1.5])
    ts = np.linspace(0.0, 5.0, 51)
    sol = simulate(forward_dynamics, model, q0, v0, 0.0, 5.0, saveat_ts=ts, rtol=1e-13, atol=1e-15, solver="dopri8",
                   max_steps=20000)
    assert bool(sol.ok)
    return model, ts, np.asarray(sol.q), np.asarray(sol.qd)


def test_free_body_follows_its_closed_form_and_keeps_its_quaternion_unit(tumbling):
    model, ts, q, qd = tumbling
    m, c = 2.0, np.array([0.1, -0.05, 0.2])
    i_com = np.array([[0.05, 0.004, -0.002], [0.004, 0.12, 0.003], [-0.002, 0.003, 0.15]])
    rot = np.array([np.asarray(link_poses(model, x)[0][0]) for x in q])
    com = q[:, :3] + np.einsum("tij,j->ti", rot, c)
    vcom0 = rot[0] @ (qd[0, :3] + np.cross(qd[0, 3:], c))
    parabola = com[0] + np.outer(ts, vcom0) + 0.5 * np.outer(ts**2, [0.0, 0.0, -9.81])
    assert np.max(np.abs(com - parabola)) <= FREE_BODY_TOL * np.max(np.abs(parabola))
    # angular momentum about the CoM, in world axes, is constant (gravity has no moment about the CoM)
    h = np.einsum("tij,jk,tk->ti", rot, i_com, qd[:, 3:])
    assert np.max(np.abs(h - h[0])) <= FREE_BODY_TOL * np.linalg.norm(h[0])
    energy = np.array([kinetic_energy(model, a, b) + potential_energy(model, a) for a, b in zip(q, qd)])
    assert np.max(np.abs(energy - energy[0])) <= FREE_BODY_TOL * abs(energy[0])
    # the state's own quaternion (never renormalised) stays on the unit sphere
    assert np.max(np.abs(np.linalg.norm(q[:, 3:7], axis=1) - 1.0)) <= 1e-11


ARM = ('<robot name="arm">' + BASE.replace(' rpy="0.2 0.1 0.3"', '')
       + '<link name="arm"><inertial><mass value="1.2"/><origin xyz="0.05 0 -0.2"/><inertia ixx="0.02" ixy="0.001" '
       'ixz="0" iyy="0.018" iyz="0" izz="0.004"/></inertial></link><joint name="shoulder" type="revolute"><parent '
       'link="base"/><child link="arm"/><origin xyz="0.2 0 0.1"/><axis xyz="0 1 0"/></joint></robot>')
ARM_MJCF = """<mujoco><option gravity="0 0 -9.81" integrator="RK4" timestep="2.5e-4"/><worldbody>
<body name="base" pos="0 0 1"><freejoint/><inertial pos="0.1 0.05 -0.02" mass="3"
 fullinertia="0.1 0.12 0.15 0.01 0 0"/><body name="arm" pos="0.2 0 0.1"><joint name="shoulder" axis="0 1 0"/>
<inertial pos="0.05 0 -0.2" mass="1.2" fullinertia="0.02 0.018 0.004 0.001 0 0"/></body></body></worldbody></mujoco>"""


def test_floating_arm_against_a_mujoco_free_joint():
    model = load_urdf(ARM, floating_base=True, limits="ignore")
    quat = np.array([0.1, -0.2, 0.3, 0.9])
    quat /= np.linalg.norm(quat)
    q0 = np.concatenate([[0.0, 0.0, 1.0], quat, [0.4]])
    qd0 = np.array([0.3, -0.2, 0.5, 1.5, -0.7, 2.0, -1.0])
    traces = _ode.TRACES["simulate"]
    sol = simulate(forward_dynamics, model, q0, qd0, 0.0, 1.0, rtol=1e-12, atol=1e-14, solver="dopri8")
    # a new start, new inertial parameters and a new tolerance reuse the compiled floating-base rollout
    heavier = model.with_params(inertia=model.inertia * 1.1)
    simulate(forward_dynamics, heavier, q0 + np.r_[0.1, 0, 0, 0, 0, 0, 0, 0.2], qd0, 0.0, 0.5, rtol=1e-10,
             atol=1e-12, solver="dopri8")
    assert _ode.TRACES["simulate"] - traces <= 1
    m = mujoco.MjModel.from_xml_string(ARM_MJCF)
    d = mujoco.MjData(m)
    d.qpos[:] = np.concatenate([q0[:3], [quat[3], *quat[:3]], q0[7:]])  # MuJoCo: [w, x, y, z]
    rot0 = np.asarray(link_poses(model, q0)[0][0])
    d.qvel[:] = np.concatenate([rot0 @ qd0[:3], qd0[3:6], qd0[6:]])  # MuJoCo: world linear, local angular
    for _ in range(4000):
        mujoco.mj_step(m, d)
    q1 = np.asarray(sol.q[-1])
    assert np.max(np.abs(q1[:3] - d.qpos[:3])) <= MUJOCO_TOL
    assert np.max(np.abs(q1[[6, 3, 4, 5]] * np.sign(q1[6] * d.qpos[3]) - d.qpos[3:7])) <= MUJOCO_TOL
    assert abs(q1[7] - d.qpos[7]) <= MUJOCO_TOL
    assert np.max(np.abs(np.asarray(sol.qd[-1])[3:] - d.qvel[3:])) <= MUJOCO_TOL


def test_floating_base_input_errors():
    model = load_urdf(ARM, floating_base=True, limits="ignore")
    # joint-space leaves have one entry per velocity coordinate (7 here: six for the root, one for the arm), the
    # per-link ones one per link (2): with_params takes those shapes and refuses the other
    rng = np.random.default_rng(3)
    c = rng.uniform(0.1, 1.0, model.nv)
    qd = rng.normal(size=model.nv)
    damped = model.with_params(viscous=c)
    np.testing.assert_allclose(np.asarray(friction_torques(damped, qd)), c * qd, rtol=1e-15)
    with pytest.raises(ModelError, match=r"with_params: viscous must have shape \(7,\)"):
        model.with_params(viscous=np.zeros(model.n_joints))
    with pytest.raises(ModelError, match=r"with_params: inertia must have shape \(2, 10\)"):
        model.with_params(inertia=np.zeros((model.nv, 10)))
    with pytest.raises(ModelError, match=r"q must have shape \(8,\) \(one entry per configuration entry"):
        forward_dynamics(model, np.zeros(7), np.zeros(7), np.zeros(7))
    with pytest.raises(ModelError, match=r"qd must have shape \(7,\)"):
        forward_dynamics(model, np.zeros(8), np.zeros(8), np.zeros(7))
    with pytest.raises(ModelError, match="Christoffel symbols need one velocity per configuration entry"):
        christoffel_symbols(model, np.r_[0, 0, 0, 0, 0, 0, 1.0, 0])
    with pytest.raises(ModelError, match=r"joint 'root_joint': its quaternion \[qx, qy, qz, qw\] in q has length 0.0"):
        simulate(forward_dynamics, model, np.zeros(8), np.zeros(7), 0.0, 1.0)
    with pytest.raises(ModelError, match="nq = 8, nv = 7"):
        simulate(forward_dynamics, model, np.zeros(8), np.zeros(8), 0.0, 1.0)
    # Direct calls read a quaternion's direction (any length), but a zero one has none: named, not NaN.
    zero = r"joint 'root_joint': its quaternion \[qx, qy, qz, qw\] in q is zero or not finite"
    with pytest.raises(ModelError, match=zero):
        forward_dynamics(model, np.zeros(8), np.zeros(7), np.zeros(7))
    with pytest.raises(ModelError, match=zero):
        mass_matrix(model, np.zeros(8))
    with pytest.raises(ModelError, match=zero):  # a batch: one bad state is enough
        forward_dynamics(model, np.r_[[np.r_[0, 0, 0, 0, 0, 0, 1.0, 0]], [np.zeros(8)]], np.zeros(7), np.zeros(7))
    kw = dict(axes=np.eye(3)[:2], origin_rotations=np.stack([np.eye(3)] * 2), origin_xyz=np.zeros((2, 3)),
              inertia=np.tile([1.0, 0, 0, 0, 1, 0, 0, 1, 0, 1], (2, 1)), joint_names=["a", "b"])
    # the joint named is the one whose quaternion is bad, in any state of a batch
    two = TreeModel(parents=[-1, 0], kinds=["free", "ball"], **kw)
    good = np.r_[0, 0, 0, 0, 0, 0, 1.0, 0, 0, 0, 1.0]
    for bad_at, name in ((slice(7, 11), "b"), (slice(3, 7), "a")):
        bad = good.copy()
        bad[bad_at] = np.nan if name == "a" else 0.0
        with pytest.raises(ModelError, match=f"joint '{name}': its quaternion"):
            mass_matrix(two, bad)
        with pytest.raises(ModelError, match=f"joint '{name}': its quaternion"):
            forward_dynamics(two, np.stack([good, bad]), np.zeros(9), np.zeros(9))
    with pytest.raises(ModelError, match="joint 'b': a free joint must join a root link to the world"):
        TreeModel(parents=[-1, 0], kinds=["revolute", "free"], **kw)
    with pytest.raises(ModelError, match="mimic joint .b.: free and ball joints neither mimic nor are mimicked"):
        TreeModel(parents=[-1, 0], kinds=["free", "revolute"], mimic={"b": ("a", 1.0, 0.0)}, **kw)
