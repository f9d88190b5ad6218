"""M, C qd, g and frame Jacobians against Pinocchio on the Krang URDFs and on seeded random trees."""

import numpy as np
import pytest

from particlesim.tree import bias_forces, coriolis_times_qdot, gravity_torques, link_jacobian, load_urdf, mass_matrix
from tree_helpers import KRANG_URDFS, PinocchioOracle, max_rel, random_tree_urdf

#: Both sides are float64 implementations of the same rigid-body model.
PIN_RTOL = 1e-10
GRAVITY = (0.0, -9.81, 0.0)
N_STATES = 2


def _compare(model, oracle, seed, jacobian_links):
    rng = np.random.default_rng(seed)
    for _ in range(N_STATES):
        q = rng.uniform(-2.0, 2.0, model.nq)
        qd = rng.normal(size=model.nq)
        g_ref = oracle.gravity(q)
        assert max_rel(mass_matrix(model, q), oracle.mass_matrix(q)) <= PIN_RTOL
        assert max_rel(bias_forces(model, q, qd), oracle.bias(q, qd)) <= PIN_RTOL
        assert max_rel(gravity_torques(model, q), g_ref) <= PIN_RTOL
        assert max_rel(coriolis_times_qdot(model, q, qd), oracle.bias(q, qd) - g_ref) <= PIN_RTOL
        for link in jacobian_links:
            for frame, local in (("world", False), ("local", True)):
                ref = oracle.jacobian(q, link, local)
                assert max_rel(link_jacobian(model, q, link, frame=frame), ref) <= PIN_RTOL, (link, frame)


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
