"""M, C qd, g and frame Jacobians against Pinocchio on the Krang URDFs and on seeded random trees."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from particlesim.tree import coriolis_times_qdot, link_poses
from particlesim.io import load_urdf
from tree_helpers import KRANG_URDFS, PinocchioOracle, batched_terms, max_rel, random_tree_urdf, states

#: Both sides are float64 implementations of the same rigid-body model.
PIN_RTOL = 1e-10
GRAVITY = (0.0, -9.81, 0.0)
N_STATES = 50


def _compare(model, oracle, seed, jacobian_links):
    rng = np.random.default_rng(seed)
    q, qd, tau, qdd = states(rng, N_STATES, model.nq, model.nq)
    out = {k: np.asarray(v) if k != "jac" else {kk: np.asarray(vv) for kk, vv in v.items()}
           for k, v in batched_terms(model, jacobian_links)(q, qd, tau, qdd).items()}
    for s in range(N_STATES):
        m_ref, b_ref, g_ref = oracle.mass_matrix(q[s]), oracle.bias(q[s], qd[s]), oracle.gravity(q[s])
        assert max_rel(out["m"][s], m_ref) <= PIN_RTOL
        assert max_rel(out["bias"][s], b_ref) <= PIN_RTOL
        assert max_rel(out["grav"][s], g_ref) <= PIN_RTOL
        assert max_rel(out["fd"][s], np.linalg.solve(m_ref, tau[s] - b_ref)) <= PIN_RTOL
        assert max_rel(out["id"][s], m_ref @ qdd[s] + b_ref) <= PIN_RTOL
        for link in jacobian_links:
            for frame, local in (("world", False), ("local", True)):
                assert max_rel(out["jac"][(link, frame)][s], oracle.jacobian(q[s], link, local)) <= PIN_RTOL
    # C qd alone (the eager path) at one state
    assert max_rel(coriolis_times_qdot(model, q[0], qd[0]), out["bias"][0] - out["grav"][0]) <= PIN_RTOL


@pytest.mark.parametrize("name", KRANG_URDFS)
def test_krang_urdf_against_pinocchio(krang_urdf_dir, name):
    path = krang_urdf_dir / name
    model = load_urdf(path, gravity=GRAVITY)
    oracle = PinocchioOracle(str(path), model.joint_names, GRAVITY)
    ends = [ln for i, ln in enumerate(model.link_names) if i not in model.parents]
    _compare(model, oracle, seed=1, jacobian_links=ends + [model.link_names[0]])


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_random_tree_against_pinocchio(seed):
    urdf = random_tree_urdf(seed, n=3 + seed, prismatic=0.4)
    model = load_urdf(urdf, gravity=(0.3, -9.81, 1.2))
    assert model.nq == 3 + seed
    oracle = PinocchioOracle(urdf, model.joint_names, (0.3, -9.81, 1.2))
    _compare(model, oracle, seed=seed, jacobian_links=model.link_names)


@pytest.mark.parametrize("n, chain", [(1, False), (2, True), (9, False), (17, False), (13, True), (17, True)])
def test_link_poses_against_pinocchio(n, chain):
    """World poses of every link (composed over the tree in about log2(depth) rounds) against Pinocchio's frame
    placements, on random trees and chains 1 to 17 links deep (Krang's poses enter the Jacobians above)."""
    urdf = random_tree_urdf(100 + n, n=n, prismatic=0.3, chain=chain)
    model = load_urdf(urdf, gravity=GRAVITY)
    oracle = PinocchioOracle(urdf, model.joint_names, GRAVITY)
    rng = np.random.default_rng(n)
    q = rng.uniform(-2.0, 2.0, (8, model.nq))
    rot, pos = (np.asarray(x) for x in jax.jit(jax.vmap(lambda x: link_poses(model, x)))(jnp.asarray(q)))
    for s in range(q.shape[0]):
        for j, link in enumerate(model.link_names):
            r_ref, p_ref = oracle.placement(q[s], link)
            assert max_rel(rot[s, j], r_ref) <= PIN_RTOL
            assert max_rel(pos[s, j], p_ref) <= PIN_RTOL
