"""Linear solves shared by the tree and mechanism dynamics, differentiated as solves."""

from __future__ import annotations

import jax
from jax.scipy.linalg import cho_factor, cho_solve
from jaxtyping import Array, Float

__all__ = ["spd_solve"]


@jax.custom_jvp
def spd_solve(s: Float[Array, "C C"], rhs: Float[Array, " C"]) -> Float[Array, " C"]:
    """``S^-1 rhs`` for a symmetric positive-definite ``S`` by one Cholesky factorisation, differentiated as a
    solve: the tangent is ``S^-1 (d rhs - dS lam)``, two triangular solves with the same factor per direction.
    (Left to JAX, the tangent goes through the factorisation: each direction then costs matrix-matrix triangular
    solves, O(C^3) — several times the factorisation itself — which made forward-mode sensitivities cost an order
    of magnitude more than the rollout. Reverse mode transposes this tangent.)"""
    return cho_solve(cho_factor(s), rhs)


@spd_solve.defjvp
def _spd_solve_jvp(primals, tangents):
    s, rhs = primals
    ds, drhs = tangents
    chol = cho_factor(s)
    lam = cho_solve(chol, rhs)
    return lam, cho_solve(chol, drhs - ds @ lam)
