"""Checks shared by the rollout tests."""


def assert_derivative_matches_central_difference(end, x0: float, rtol: float, *, rel_step: float = 1e-4,
                                                 least: float = 0.0):
    """``end(x, adjoint=None)`` (a rollout's scalar output in one parameter): its reverse-mode derivative and its
    forward-mode one (``adjoint="forward"``) within ``rtol`` of the central difference with step ``rel_step |x0|``,
    which must exceed ``least`` in size (the output depends on the parameter)."""
    import jax
    import jax.numpy as jnp

    f = jax.jit(end)
    h = rel_step * abs(x0)
    cd = (float(f(x0 + h)) - float(f(x0 - h))) / (2 * h)
    rev = float(jax.jit(jax.grad(end))(jnp.asarray(x0)))
    fwd = float(jax.jit(lambda x: jax.jvp(lambda y: end(y, "forward"), (x,), (jnp.ones_like(x),))[1])(
        jnp.asarray(x0)))
    assert abs(cd) > least
    assert abs(rev - cd) <= rtol * abs(cd), (rev, cd)
    assert abs(fwd - cd) <= rtol * abs(cd), (fwd, cd)
