"""Closed-form constraint Jacobian and gamma against forward-mode autodiff of the constraint function."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from particlesim.inertia import RigidInertia
from particlesim.mechanism import MechanismBuilder, constraint_gamma, constraint_jacobian, constraints

DERIV_ATOL = 1e-12


def _slider_crank_like():
    """Spatial body on a prismatic joint to the ground + a rod + a cut joint: every row kind, ground columns."""
    mb = MechanismBuilder()
    for nm, p in (("g0", (0, 0, 0)), ("g1", (1, 0, 0)), ("g2", (0, 1, 0)), ("piv", (0, 0, 1.0))):
        mb.ground(nm, p)
    mb.particle("b0", (0.2, 0, 0))
    mb.particle("b1", (0.7, 0, 0))
    mb.particle("b2", (0.3, 0.4, 0.1))
    mb.particle("b3", (0.4, 0.1, 0.5))
    mb.particle("c", (0.4, 0.1, 0.5))
    body = RigidInertia(1.0, [0.4, 0.1, 0.15], np.diag([0.05, 0.06, 0.07]))
    mb.body("slider", body, ["b0", "b1", "b2", "b3"], on_negative="ignore")
    mb.body("rod", RigidInertia.slender_rod(0.5, (0, 0, 1.0), (0.4, 0.1, 0.5)), ["piv", "c"], on_negative="ignore")
    mb.cut_joint("b3", "c")
    mb.prismatic(("g0", "g1", "g2"), ("b0", "b1", "b2"))
    return mb.build()


@pytest.fixture(scope="module")
def mech_x0():
    return _slider_crank_like()


def test_jacobian_and_gamma_match_autodiff(mech_x0):
    mech, x0 = mech_x0
    rng = np.random.default_rng(0)
    x = jnp.asarray(x0 + 0.01 * rng.normal(size=x0.shape))
    xd = jnp.asarray(rng.normal(size=x0.shape))
    j_ad = jax.jacfwd(lambda y: constraints(mech, y))(x)
    np.testing.assert_allclose(constraint_jacobian(mech, x), j_ad, rtol=0, atol=DERIV_ATOL)
    g_ad = -jax.jvp(lambda y: jax.jvp(lambda z: constraints(mech, z), (y,), (xd,))[1], (x,), (xd,))[1]
    np.testing.assert_allclose(constraint_gamma(mech, x, xd), g_ad, rtol=0, atol=DERIV_ATOL)
