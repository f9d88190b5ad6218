"""Named body outputs (poses, centres of mass, velocities): exact under known rigid motions for spatial, planar
and rod bodies, and equal to MuJoCo C's body frames and velocities along a spherical-chain rollout."""

import jax
from jax.test_util import check_grads
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from particlesim.errors import ModelError
from particlesim.inertia import RigidInertia
from particlesim.mechanism import (MechanismBuilder, body_com_positions, body_poses, body_velocities,
                                   point_positions, simulate_mechanism)
from particlesim.scenes.chains import chain_geometry, chain_mechanism
from particlesim.twins.chains import chain_mjcf

#: Poses and velocities under an exact rigid motion (round-off of a 4x4 solve) [m, -, m/s, rad/s].
RIGID_TOL = 1e-12
#: Ours (Dopri8, rtol 1e-12) against MuJoCo C RK4 at dt 1e-4 over 0.5 s: RK4's own error is ~1e-11.
MUJOCO_TOL = 1e-8


def _three_kinds(points=None):
    """A spatial block, a planar plate and a rod (free bodies, no joints), each given in its own frame; ``points``:
    ``{name: (body, xyz)}`` fixed to them."""
    mb = MechanismBuilder()
    pose = (Rotation.from_rotvec([0.3, -0.2, 0.5]).as_matrix(), np.array([0.4, -0.1, 0.2]))
    for n, p in (("s0", (0, 0, 0)), ("s1", (0.3, 0, 0)), ("s2", (0, 0.2, 0)), ("s3", (0, 0, 0.1))):
        mb.particle(n, pose[0] @ np.asarray(p, float) + pose[1])
    mb.body("block", RigidInertia(2.0, (0.1, 0.05, 0.02), np.diag([0.01, 0.02, 0.025])), ["s0", "s1", "s2", "s3"],
            pose=pose, on_negative="ignore")
    for n, p in (("p0", (1, 0, 0)), ("p1", (1.4, 0.1, 0)), ("p2", (1.1, 0.3, 0))):
        mb.particle(n, p)
    mb.body("plate", RigidInertia(1.0, (1.15, 0.12, 0.0), np.diag([0.004, 0.006, 0.01])), ["p0", "p1", "p2"],
            on_negative="ignore")
    mb.particle("r0", (0, 1, 0))
    mb.particle("r1", (0.6, 1.3, 0.2))
    mb.body("rod", RigidInertia.slender_rod(0.5, (0, 1, 0), (0.6, 1.3, 0.2), moment=0.01), ["r0", "r1"])
    for name, (body, xyz) in (points or {}).items():
        mb.point(name, body, xyz)
    return mb.build(), pose


def test_poses_and_velocities_under_a_known_rigid_motion():
    (mech, x0), pose = _three_kinds()
    rot0, org0 = (np.asarray(a) for a in body_poses(mech, jnp.asarray(x0)))
    b = mech.body_index("block")
    np.testing.assert_allclose(rot0[b], pose[0], atol=RIGID_TOL)  # the frame the inertia was given in
    np.testing.assert_allclose(org0[b], pose[1], atol=RIGID_TOL)
    np.testing.assert_allclose(rot0[mech.body_index("plate")], np.eye(3), atol=RIGID_TOL)
    # move everything by a known rigid motion (q, c) with velocity (omega, v) about the point c
    q = Rotation.from_rotvec([-0.7, 1.1, 0.4]).as_matrix()
    c = np.array([0.2, -0.3, 0.5])
    omega, v = np.array([0.3, -1.2, 2.0]), np.array([0.5, 0.1, -0.4])
    r = np.asarray(x0).reshape(-1, 3) @ q.T + c
    x = jnp.asarray(r.reshape(-1))
    xd = jnp.asarray((np.cross(omega, r - c) + v).reshape(-1))
    rot, org = (np.asarray(a) for a in body_poses(mech, x))
    com = np.asarray(body_com_positions(mech, x))
    vel, w = (np.asarray(a) for a in body_velocities(mech, x, xd))
    for name in ("block", "plate", "rod"):
        k = mech.body_index(name)
        com_body = np.asarray(mech.body_com[k])
        com0 = rot0[k] @ com_body + org0[k]
        np.testing.assert_allclose(com[k], q @ com0 + c, atol=RIGID_TOL, err_msg=name)
        np.testing.assert_allclose(vel[k], np.cross(omega, com[k] - c) + v, atol=RIGID_TOL, err_msg=name)
        if name == "rod":  # no twist: the axis turns as the body, the spin about it is not defined
            u = (r[mech.topo.particle_names.index("r1")] - r[mech.topo.particle_names.index("r0")])
            u = u / np.linalg.norm(u)
            np.testing.assert_allclose(w[k], omega - (omega @ u) * u, atol=RIGID_TOL)
            np.testing.assert_allclose(rot[k] @ rot0[k].T @ (q.T @ u), u, atol=RIGID_TOL)  # maps the old axis
            continue
        np.testing.assert_allclose(rot[k], q @ rot0[k], atol=RIGID_TOL, err_msg=name)
        np.testing.assert_allclose(org[k], q @ org0[k] + c, atol=RIGID_TOL, err_msg=name)
        np.testing.assert_allclose(w[k], omega, atol=RIGID_TOL, err_msg=name)


def test_points_follow_a_known_rigid_motion():
    """Points fixed to a spatial block, a planar plate and a rod (and particles) move with the rigid motion applied
    to the whole set: ``Q p + c`` exactly."""
    given = {"on block": (0.7, -0.4, 0.9), "on plate": (1.3, 0.25, 0.0), "on rod": (0.45, 1.225, 0.15)}
    (mech, x0), _ = _three_kinds({name: (name.split()[1], xyz) for name, xyz in given.items()})
    r0 = np.asarray(x0).reshape(-1, 3)
    names = list(given) + ["s2", "r1"]
    start = np.array(list(given.values()) + [r0[mech.free.index(mech.index(n))] for n in ("s2", "r1")])
    np.testing.assert_allclose(point_positions(mech, jnp.asarray(x0), names), start, atol=RIGID_TOL)
    q = Rotation.from_rotvec([-0.7, 1.1, 0.4]).as_matrix()
    c = np.array([0.2, -0.3, 0.5])
    x = jnp.asarray((r0 @ q.T + c).reshape(-1))
    np.testing.assert_allclose(point_positions(mech, x, names), start @ q.T + c, atol=RIGID_TOL)
    np.testing.assert_allclose(point_positions(mech, x, "on rod"), np.asarray(given["on rod"]) @ q.T + c,
                               atol=RIGID_TOL)
    assert point_positions(mech, x).shape == (len(mech.topo.point_names), 3)
    with pytest.raises(KeyError, match="no point named 'nowhere'"):
        point_positions(mech, x, ["nowhere"])


def test_body_outputs_are_differentiable():
    (mech, x0), _ = _three_kinds()
    f = lambda y: jnp.sum(body_com_positions(mech, y) ** 2)  # noqa: E731
    check_grads(f, (jnp.asarray(x0),), order=1, modes=("fwd", "rev"))


@pytest.mark.slow
def test_spherical_chain_bodies_match_mujoco():
    geom = chain_geometry(3, "spherical", seed=3)
    mech, x0 = chain_mechanism(geom)
    ts = np.linspace(0.0, 0.5, 6)
    sol = simulate_mechanism(mech, jnp.asarray(x0), jnp.zeros_like(jnp.asarray(x0)), 0.0, 0.5, solver="dopri8",
                             rtol=1e-12, atol=1e-14, saveat_ts=ts)
    m = mujoco.MjModel.from_xml_string(chain_mjcf(geom, timestep=1e-4)[0])
    d = mujoco.MjData(m)
    ids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"link{j + 1}") for j in range(3)]
    res = np.zeros(6)
    for k in range(len(ts)):
        if k:
            for _ in range(int(round((ts[k] - ts[k - 1]) / 1e-4))):
                mujoco.mj_step(m, d)
        mujoco.mj_forward(m, d)
        x, xd = sol.q[k], sol.qd[k]
        rot, org = (np.asarray(a) for a in body_poses(mech, x))
        com = np.asarray(body_com_positions(mech, x))
        vel, w = (np.asarray(a) for a in body_velocities(mech, x, xd))
        for j, bid in enumerate(ids):
            b = mech.body_index(f"link{j + 1}")
            np.testing.assert_allclose(rot[b], d.xmat[bid].reshape(3, 3), atol=MUJOCO_TOL)
            np.testing.assert_allclose(org[b], d.xpos[bid], atol=MUJOCO_TOL)
            np.testing.assert_allclose(com[b], d.xipos[bid], atol=MUJOCO_TOL)
            mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_BODY, bid, res, 0)  # [rot; lin] at the CoM, world
            np.testing.assert_allclose(w[b], res[:3], atol=MUJOCO_TOL)
            np.testing.assert_allclose(vel[b], res[3:], atol=MUJOCO_TOL)
    assert np.abs(np.asarray(sol.q[-1]) - np.asarray(x0)).max() > 0.05  # the chain really moved


def test_wrong_state_shapes_are_refused():
    (mech, x0), _ = _three_kinds()
    with pytest.raises(ModelError, match=r"q must have shape \(27,\)"):
        body_poses(mech, jnp.zeros(26))
    with pytest.raises(ModelError, match=r"qd must have shape \(27,\)"):
        body_velocities(mech, jnp.asarray(x0), jnp.zeros((27, 1)))
