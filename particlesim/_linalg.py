"""Linear solves shared by the tree and mechanism dynamics, differentiated as solves."""

from __future__ import annotations

import functools
from typing import Callable

import jax
import jax.numpy as jnp
from jax.scipy.linalg import cho_factor, cho_solve
from jaxtyping import Array, Float

__all__ = ["spd_solve_applied"]


@functools.partial(jax.custom_jvp, nondiff_argnums=(0,))
def spd_solve_applied(apply: Callable, params, s: Float[Array, "C C"], rhs: Float[Array, " C"]) -> Float[Array, " C"]:
    """``S^-1 rhs`` for a symmetric positive-definite ``s`` that equals ``apply(params, ·)`` as a linear map (``s``
    passed in, so that several solves with one matrix share it), by one Cholesky factorisation, differentiated as a
    solve whose matrix is *applied* rather than formed: the tangent is ``S^-1 (d rhs - dS lam)`` with ``dS lam`` the
    tangent of ``apply(params, lam)`` at fixed ``lam``, taken only in the leaves of ``params`` that carry one; the
    tangent of ``s`` is not used. Left to JAX, the tangent would go through the factorisation (matrix-matrix
    triangular solves per direction, O(C^3)); with the formed ``S`` it would cost the whole ``dS`` per direction, and
    in reverse mode the whole cotangent of ``S`` and of what it is built from. When ``apply`` is cheaper than forming
    ``S`` (a mechanism's ``J (M^-1 J^T lam)``, a tree's inverse dynamics at zero velocity), so are the derivatives.
    ``apply`` must be a module-level function (it is part of the compile-cache key)."""
    return cho_solve(cho_factor(s), rhs)


@functools.partial(spd_solve_applied.defjvp, symbolic_zeros=True)
def _spd_solve_applied_jvp(apply, primals, tangents):
    params, s, rhs = primals
    dparams, _, drhs = tangents
    chol = cho_factor(s)
    lam = cho_solve(chol, rhs)
    leaves, treedef = jax.tree.flatten(params)
    dleaves = jax.tree.leaves(dparams, is_leaf=_zero)
    assert len(dleaves) == len(leaves)
    live = [i for i, t in enumerate(dleaves) if not _zero(t)]  # zero tangents would cost their products too
    tangent = jnp.zeros_like(lam) if _zero(drhs) else drhs
    if live:
        def applied(*xs):
            full = list(leaves)
            for i, x in zip(live, xs):
                full[i] = x
            return apply(jax.tree.unflatten(treedef, full), lam)

        tangent = tangent - jax.jvp(applied, [leaves[i] for i in live], [dleaves[i] for i in live])[1]
    return lam, cho_solve(chol, tangent)


def _zero(t) -> bool:
    return isinstance(t, jax.custom_derivatives.SymbolicZero)
