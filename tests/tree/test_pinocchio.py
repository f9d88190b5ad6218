"""M, C qd, g and frame Jacobians against Pinocchio on the Krang URDFs and on seeded random trees."""

import numpy as np
import pytest

from particlesim.tree import coriolis_times_qdot
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
