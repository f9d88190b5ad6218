"""The SPD solve differentiated as a solve (particlesim._linalg): values and derivatives against numpy and
central differences, fwd and rev."""

import jax
import jax.numpy as jnp
import numpy as np
from jax.test_util import check_grads

from particlesim._linalg import spd_solve

GRAD_TOL = 1e-6  # check_grads against central differences
SOLVE_RTOL = 1e-12


def _spd(seed, n=6):
    a = np.random.default_rng(seed).standard_normal((n, n))
    return a @ a.T + n * np.eye(n), np.random.default_rng(seed + 1).standard_normal(n)


def test_spd_solve_matches_numpy_and_its_derivatives_match_central_differences():
    s, b = _spd(0)
    np.testing.assert_allclose(spd_solve(jnp.asarray(s), jnp.asarray(b)), np.linalg.solve(s, b), rtol=SOLVE_RTOL)

    # Derivatives through a symmetric S(p) (as the dynamics build it) and a right-hand side, fwd and rev.
    def f(p, b):
        m = jnp.asarray(s) + p * jnp.asarray(s[::-1, ::-1])
        return spd_solve(0.5 * (m + m.T), b)

    check_grads(f, (0.3, jnp.asarray(b)), order=2, modes=("fwd", "rev"), atol=GRAD_TOL, rtol=GRAD_TOL)
    # Batched (vmap over right-hand sides and matrices) equals one at a time.
    ss = jnp.stack([jnp.asarray(_spd(k)[0]) for k in range(3)])
    bs = jnp.stack([jnp.asarray(_spd(k)[1]) for k in range(3)])
    out = jax.vmap(spd_solve)(ss, bs)
    for k in range(3):
        np.testing.assert_allclose(out[k], np.linalg.solve(np.asarray(ss[k]), np.asarray(bs[k])), rtol=SOLVE_RTOL)
