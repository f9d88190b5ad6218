"""The Coriolis matrix from Christoffel symbols (Zafar eq. 4), for analysis.

``c_ijk = 1/2 (dA_ij/dq_k + dA_ik/dq_j - dA_jk/dq_i)`` and ``C_ij = sum_k c_ijk qd_k``, with ``dA/dq`` by
forward-mode autodiff of :func:`~.dynamics.mass_matrix`. With this choice ``Adot - 2 C`` is skew-symmetric.
For simulation use :func:`~.dynamics.coriolis_times_qdot` (O(n^2), no n^3 tensor).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from .._jit import compiled
from .dynamics import mass_matrix
from .kinematics import _quaternion_checks
from .model import TreeModel

__all__ = ["christoffel_symbols", "coriolis_matrix"]


@compiled("christoffel_symbols", check=_quaternion_checks, arrays_only=True)
def christoffel_symbols(model: TreeModel, q: Float[ArrayLike, " n"]) -> Float[Array, "n n n"]:
    """``c[i, j, k]`` of eq. (4) (first kind). Needs ``q`` and ``qd`` of one length (no floating base)."""
    if model.nq != model.nv:
        from ..errors import ModelError

        raise ModelError("Christoffel symbols need one velocity per configuration entry; a floating base's "
                         "quaternion has four entries for three rotations (use coriolis_times_qdot)")
    da = jax.jacfwd(lambda x: mass_matrix.raw(model, x))(jnp.asarray(q, dtype=float))  # [i, j, k] = dA_ij/dq_k
    return 0.5 * (da + jnp.einsum("ikj->ijk", da) - jnp.einsum("jki->ijk", da))


@compiled("coriolis_matrix", check=_quaternion_checks, arrays_only=True)
def coriolis_matrix(model: TreeModel, q: Float[ArrayLike, " n"], qd: Float[ArrayLike, " n"]) -> Float[Array, "n n"]:
    """``C(q, qd)`` with ``C_ij = sum_k c_ijk qd_k`` (eq. 4)."""
    return christoffel_symbols.raw(model, q) @ jnp.asarray(qd)
