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
    return lambda x: mech.point_positions(mech.all_positions(x))[k]


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


def _points_fn(mech: Mechanism):
    return lambda y: mech.point_positions(mech.all_positions(y))


def generalized_forces(mech: Mechanism, t, x: Float[Array, " 3F"], xd: Float[Array, " 3F"], *,
                       lumped=None) -> Float[Array, " 3F"]:
    """Gravity + spring-dampers + tyres + applied forces and torques, as forces on the free coordinates.

    Point positions and velocities are evaluated once (one forward-mode pass), the Cartesian forces of all
    elements are summed per point, and one reverse-mode pass maps them to the coordinates (``Q = (dP/dx)^T F``).
    ``lumped``: the particle masses ``m_bar`` if already computed (:func:`~.dynamics.mass_properties`)."""
    free = np.asarray(mech.free, dtype=int)
    lumped = mech.lumped_masses() if lumped is None else lumped
    q = (lumped[free][:, None] * mech.gravity[None, :]).reshape(-1)
    point_elements = mech.springs or mech.tyres or any(ap.kind == "force" for ap in mech.applied)
    if point_elements:
        fn = _points_fn(mech)
        pts, vel = jax.jvp(fn, (x,), (xd,))
        f_pts = jnp.zeros_like(pts)
        if mech.springs:
            a = np.asarray([s.a for s in mech.springs])
            b = np.asarray([s.b for s in mech.springs])
            k = jnp.stack([s.stiffness for s in mech.springs])
            c = jnp.stack([s.damping for s in mech.springs])
            l0 = jnp.stack([s.free_length for s in mech.springs])
            d = pts[a] - pts[b]
            ell = jnp.linalg.norm(d, axis=1)
            u = d / ell[:, None]
            f = k * (ell - l0) + c * jnp.sum(u * (vel[a] - vel[b]), axis=1)
            f_pts = f_pts.at[a].add(-f[:, None] * u).at[b].add(f[:, None] * u)
        for ty in mech.tyres:
            n = jnp.asarray(ty.normal)
            dist = pts[ty.point] @ n - ty.ground - ty.radius
            f = jnp.where(dist < 0.0, -(ty.stiffness * dist + ty.damping * (vel[ty.point] @ n)), 0.0)
            f_pts = f_pts.at[ty.point].add(f * n)
        for ap in mech.applied:
            if ap.kind == "force":
                f_pts = f_pts.at[ap.target].add(ap.fn(t, x, xd))
        _, pull = jax.vjp(fn, x)
        q = q + pull(f_pts)[0]
    for ap in mech.applied:
        if ap.kind == "torque":
            _, pull = jax.vjp(lambda v, b=ap.target: body_angular_velocity(mech, b, x, v), xd)
            q = q + pull(ap.fn(t, x, xd))[0]
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
