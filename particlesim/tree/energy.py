"""Kinetic and potential energy of a :class:`TreeModel` (Zafar eqs. 11 and 15).

Link parameters are the report's 10-vector about the link frame origin, in link axes:
``m``, ``MS = m S`` (first moment) and ``J`` (inertia about the origin). These functions are the Lagrangian
reference: the fast terms in :mod:`.dynamics` are tested against their derivatives.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from .._jit import compiled
from ..inertia import unpack_params
from .kinematics import _quaternion_checks, limit_deflections, link_poses, link_velocities, spring_deflections
from .model import TreeModel

__all__ = ["link_kinetic_energies", "kinetic_energy", "potential_energy"]


@compiled("link_kinetic_energies", check=_quaternion_checks, arrays_only=True)
def link_kinetic_energies(model: TreeModel, q: Float[ArrayLike, " n"], qd: Float[ArrayLike, " n"]) -> Float[Array, " n"]:
    """Per-link kinetic energy, eq. (11): ``E_j = 1/2 (w^T J w + m V^T V + 2 MS^T (V x w))``, link axes.

    Velocities come from the recursion of eqs. (7)–(8) (:func:`~.kinematics.link_velocities`). Rotor inertia
    (eq. 18) is not a link energy; see :func:`kinetic_energy`.
    """
    w, v = link_velocities.raw(model, q, qd)
    m, ms, j = unpack_params(model.inertia)
    jw = (j @ w[..., None])[..., 0]
    return 0.5 * (jnp.sum(w * jw, -1) + m * jnp.sum(v * v, -1) + 2.0 * jnp.sum(ms * jnp.cross(v, w), -1))


@compiled("kinetic_energy", check=_quaternion_checks, arrays_only=True)
def kinetic_energy(model: TreeModel, q: Float[ArrayLike, " n"], qd: Float[ArrayLike, " n"]) -> Float[Array, ""]:
    """Total kinetic energy ``E = sum_j E_j`` (eq. 9) plus rotor energies ``1/2 I_a qd^2`` (eq. 18)."""
    e = jnp.sum(link_kinetic_energies.raw(model, q, qd))
    if model.rotor_inertia is not None:
        qd = jnp.asarray(qd)
        e = e + 0.5 * jnp.sum(model.rotor_inertia * qd * qd)
    return e


@compiled("potential_energy", check=_quaternion_checks, arrays_only=True)
def potential_energy(model: TreeModel, q: Float[ArrayLike, " n"]) -> Float[Array, ""]:
    """Gravity potential, eq. (15): ``U = -sum_j g^T (m_j P_j + A_j MS_j)`` with world gravity ``g``, plus the
    joint springs' ``1/2 sum K d(q)^2`` when the model has ``stiffness`` and the soft limits' when it has ``limits``."""
    rot, pos = link_poses.raw(model, q)
    m, ms, _ = unpack_params(model.inertia)
    first_moment = m[:, None] * pos + (rot @ ms[..., None])[..., 0]
    u = -jnp.sum(first_moment @ model.gravity)
    if model.stiffness is not None:
        d = spring_deflections(model, q)
        u = u + 0.5 * jnp.sum(model.stiffness * d * d)
    if model.limits is not None:
        d = limit_deflections(model, q)
        u = u + 0.5 * jnp.sum(model.limits[:, 2] * d * d)
    return u
