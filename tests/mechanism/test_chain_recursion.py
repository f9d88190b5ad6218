"""The O(N) tip-to-base recursion along serial chains against the dense saddle-point solve."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from particlesim import ModelError
from particlesim.mechanism import accelerations, chain_accelerations, chain_plan, project, simulate_mechanism
from particlesim.scenes.chains import chain_geometry, chain_mechanism
from particlesim.scenes.nikravesh import aa_mechanism

ACC_RTOL = 1e-11  # relative to the largest acceleration: two exact solves differ by round-off only
TRAJ_ATOL = 1e-9  # m, 2 s rollouts with both solves at rtol 1e-12


@pytest.mark.parametrize("joint", ["spherical", "revolute"])
@pytest.mark.parametrize("n", [1, 3, 7])
def test_recursion_equals_dense_solve(joint, n):
    mech, x0 = chain_mechanism(chain_geometry(n, joint, seed=n))
    plan = chain_plan(mech)
    rng = np.random.default_rng(n)
    x, xd = project(mech, jnp.asarray(x0), jnp.asarray(rng.normal(size=x0.shape)))  # an admissible velocity
    dense = accelerations(mech, 0.0, x, xd)
    rec = jax.jit(chain_accelerations, static_argnums=1)(mech, plan, 0.0, x, xd)
    np.testing.assert_allclose(rec, dense, rtol=0, atol=ACC_RTOL * float(jnp.abs(dense).max()))


def test_recursive_rollout_equals_dense_rollout():
    mech, x0 = chain_mechanism(chain_geometry(4, "spherical", seed=4))
    ts = jnp.linspace(0.0, 2.0, 5)
    runs = [jax.jit(lambda m, x, s=s: simulate_mechanism(m, x, jnp.zeros_like(x), 0.0, 2.0, solver="dopri8",
                                                         rtol=1e-12, atol=1e-13, saveat_ts=ts, solve=s))
            for s in ("dense", "chain")]
    a, b = (r(mech, jnp.asarray(x0)) for r in runs)
    np.testing.assert_allclose(b.q, a.q, rtol=0, atol=TRAJ_ATOL)


def test_recursion_refuses_what_is_not_a_uniform_chain():
    mech, _ = aa_mechanism()
    with pytest.raises(ModelError, match="recursive chain solve"):
        chain_plan(mech)
