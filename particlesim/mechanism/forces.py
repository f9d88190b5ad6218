"""Generalised forces on the free particle coordinates, and the potential energies that go with them.

Every force element contributes ``Q = (d p / d x)^T f`` (virtual work) for the point ``p`` it acts on, so forces
need not be redistributed over particles by hand (Attia's reason for the moment equations; here autodiff plays
that role exactly). Gravity acts on every particle with its lumped mass ``m_bar`` (Attia eq. (25)). A scene
without springs, tyres or applied loads pays nothing for them: each loop below is empty at trace time.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..spatial import frame_from_points, unskew
from .model import Mechanism

__all__ = ["generalized_forces", "potential_energy", "spring_lengths", "body_angular_velocity"]


def _point(mech: Mechanism, k: int):
    return lambda x: mech.point_position(k, mech.all_positions(x))


def spring_lengths(mech: Mechanism, x) -> Float[Array, " S"]:
    """Current length of every spring-damper."""
    return jnp.stack([jnp.linalg.norm(_point(mech, s.a)(x) - _point(mech, s.b)(x)) for s in mech.springs])


def body_angular_velocity(mech: Mechanism, b: int, x, xd) -> Float[Array, "3"]:
    """Angular velocity of a (spatial or planar) body from its first three primaries: ``unskew(F' F^T)``."""
    idx = np.asarray(mech.bodies[b].primaries)

    def frame(y):
        p = mech.all_positions(y)[idx]
        return frame_from_points(p[0], p[1], p[2])

    f, fd = jax.jvp(frame, (x,), (xd,))
    return unskew(fd @ f.T)


def generalized_forces(mech: Mechanism, t, x: Float[Array, " 3F"], xd: Float[Array, " 3F"], *,
                       lumped=None) -> Float[Array, " 3F"]:
    """Gravity + spring-dampers + tyres + applied forces and torques, as forces on the free coordinates.

    ``lumped``: the particle masses ``m_bar`` if already computed (:func:`~.dynamics.mass_properties`)."""
    free = np.asarray(mech.free, dtype=int)
    lumped = mech.lumped_masses() if lumped is None else lumped
    q = (lumped[free][:, None] * mech.gravity[None, :]).reshape(-1)
    for s in mech.springs:
        def length(y, s=s):
            return jnp.linalg.norm(_point(mech, s.a)(y) - _point(mech, s.b)(y))

        ell, grad = jax.value_and_grad(length)(x)
        f = s.stiffness * (ell - s.free_length) + s.damping * (grad @ xd)
        q = q - f * grad
    for ty in mech.tyres:
        n = jnp.asarray(ty.normal)

        def height(y, ty=ty, n=n):
            return _point(mech, ty.point)(y) @ n

        h, grad = jax.value_and_grad(height)(x)
        d = h - ty.ground - ty.radius
        f = jnp.where(d < 0.0, -(ty.stiffness * d + ty.damping * (grad @ xd)), 0.0)
        q = q + f * grad
    for ap in mech.applied:
        value = ap.fn(t, x, xd)
        if ap.kind == "force":
            _, pull = jax.vjp(_point(mech, ap.target), x)
            q = q + pull(value)[0]
        else:
            _, pull = jax.vjp(lambda v, b=ap.target: body_angular_velocity(mech, b, x, v), xd)
            q = q + pull(value)[0]
    return q


def potential_energy(mech: Mechanism, x: Float[Array, " 3F"]) -> Float[Array, ""]:
    """Gravity, spring and (compressed) tyre energy; dampers and applied loads have none."""
    r = mech.all_positions(x)
    u = -jnp.sum(mech.lumped_masses() * (r @ mech.gravity))
    for s in mech.springs:
        ell = jnp.linalg.norm(_point(mech, s.a)(x) - _point(mech, s.b)(x))
        u = u + 0.5 * s.stiffness * (ell - s.free_length) ** 2
    for ty in mech.tyres:
        d = _point(mech, ty.point)(x) @ jnp.asarray(ty.normal) - ty.ground - ty.radius
        u = u + jnp.where(d < 0.0, 0.5 * ty.stiffness * d**2, 0.0)
    return u
