"""The SPD solve differentiated as a solve whose matrix is applied (particlesim._linalg): values and derivatives
against numpy and central differences, fwd and rev, first and second order."""

import jax
import jax.numpy as jnp
import numpy as np
from jax.test_util import check_grads

from particlesim._linalg import spd_solve_applied

GRAD_TOL = 1e-6  # check_grads against central differences
SOLVE_RTOL = 1e-12


def _spd(seed, n=6):
    a = np.random.default_rng(seed).standard_normal((n, n))
    return a @ a.T + n * np.eye(n), np.random.default_rng(seed + 1).standard_normal(n)


S0, B0 = _spd(0)


def _matrix(params):
    """A symmetric positive-definite S(p) (as the dynamics build theirs); ``c`` is a constant part."""
    p, c = params
    m = c + p * jnp.asarray(S0[::-1, ::-1])
    return 0.5 * (m + m.T)


def _apply(params, x):
    return _matrix(params) @ x


def test_spd_solve_applied_matches_numpy_and_its_derivatives_match_central_differences():
    params = (jnp.asarray(0.0), jnp.asarray(S0))
    np.testing.assert_allclose(spd_solve_applied(_apply, params, _matrix(params), jnp.asarray(B0)),
                               np.linalg.solve(S0, B0), rtol=SOLVE_RTOL)

    # Derivatives in a parameter of S (the constant part carries no tangent) and in the right-hand side.
    def f(p, b):
        params = (p, jnp.asarray(S0))
        return spd_solve_applied(_apply, params, _matrix(params), b)

    check_grads(f, (0.3, jnp.asarray(B0)), order=2, modes=("fwd", "rev"), atol=GRAD_TOL, rtol=GRAD_TOL)

    # Every input varied: both parts of S and the right-hand side.
    def g(p, c, b):
        params = (p, 0.5 * (c + c.T))
        return spd_solve_applied(_apply, params, _matrix(params), b)

    check_grads(g, (0.3, jnp.asarray(S0), jnp.asarray(B0)), order=1, modes=("fwd", "rev"), atol=GRAD_TOL,
                rtol=GRAD_TOL)
    # Batched (vmap over right-hand sides and matrices) equals one at a time.
    ss = jnp.stack([jnp.asarray(_spd(k)[0]) for k in range(3)])
    bs = jnp.stack([jnp.asarray(_spd(k)[1]) for k in range(3)])
    out = jax.vmap(lambda s, b: spd_solve_applied(_apply, (jnp.asarray(0.0), s), s, b))(ss, bs)
    for k in range(3):
        np.testing.assert_allclose(out[k], np.linalg.solve(np.asarray(ss[k]), np.asarray(bs[k])), rtol=SOLVE_RTOL)
