"""The mechanism model: particles, bodies, constraints and force elements in particle Cartesian coordinates.

A mechanism (Attia §2) is a set of *particles*; some are fixed to the ground, the others are the unknowns. Each
rigid body owns 2, 3 or 4 of them as its primary particles (rod, planar, spatial set; :mod:`particlesim.particles`)
and its secondary particles are their midpoints, so they never appear as unknowns (Attia's reduced form, eqs.
(23)–(27)). Bodies that list the same particle share it: a spherical joint (one shared particle), a revolute joint
(two shared particles on the axis), a fixed point or a fixed axis (shared with the ground). Everything else is an
explicit constraint: rigid distances inside each body (eqs. (11)–(16)), massless links, cut joints that close
loops (``r_a = r_b``) and prismatic joints.

State: ``x`` ``(3F,)``, the stacked positions of the F free particles (and ``xd`` their velocities).

Static (``eqx.field(static=True)``): names, index tuples, kinds. Differentiable leaves: body mass, CoM, inertia
and body-frame primaries (the particle masses are solved from them on every call, so ``jax.grad`` w.r.t. a body's
mass or inertia goes through the mass solve), ground positions, constraint lengths, force-element constants and
gravity.
"""

from __future__ import annotations

from typing import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..particles import PAIRS, solve_particle_masses

__all__ = ["Mechanism", "BodySpec", "PointSpec", "SpringSpec", "TyreSpec", "AppliedSpec"]


class BodySpec(eqx.Module):
    """Static description of one body: its particle set kind and the global indices of its primaries."""

    name: str = eqx.field(static=True)
    kind: str = eqx.field(static=True)
    primaries: tuple = eqx.field(static=True)


class PointSpec(eqx.Module):
    """A point attached to a body (``body >= 0``), or a particle (``particle >= 0``).

    Body points are placed by their coordinates ``local`` in the Gram–Schmidt frame of the body's first three
    primaries (rods: ``local[0]`` is the fraction along particle 1 -> 2).
    """

    name: str = eqx.field(static=True)
    particle: int = eqx.field(static=True)
    body: int = eqx.field(static=True)
    local: Float[Array, "3"]


class SpringSpec(eqx.Module):
    """Point-to-point spring-damper: ``f = k (L - l0) + c dL/dt`` pulling the points together when ``f > 0``."""

    name: str = eqx.field(static=True)
    a: int = eqx.field(static=True)  # point indices
    b: int = eqx.field(static=True)
    stiffness: Float[Array, ""]
    damping: Float[Array, ""]
    free_length: Float[Array, ""]


class TyreSpec(eqx.Module):
    """One-sided tyre: ``d = p.n - ground - radius``; force ``-(k d + c dd/dt) n`` while ``d < 0``, else none."""

    name: str = eqx.field(static=True)
    point: int = eqx.field(static=True)
    normal: tuple = eqx.field(static=True)
    stiffness: Float[Array, ""]
    damping: Float[Array, ""]
    radius: Float[Array, ""]
    ground: Float[Array, ""]


class AppliedSpec(eqx.Module):
    """An applied force ``fn(t, x, xd) -> (3,)`` at a point (``kind='force'``) or torque on a body (``'torque'``)."""

    name: str = eqx.field(static=True)
    kind: str = eqx.field(static=True)
    target: int = eqx.field(static=True)  # point index (force) or body index (torque)
    fn: Callable = eqx.field(static=True)


class Mechanism(eqx.Module):
    """A mechanism in particle coordinates; build it with :class:`~particlesim.mechanism.MechanismBuilder`."""

    # --- differentiable parameters ---
    body_mass: tuple
    body_com: tuple
    body_inertia: tuple
    body_primaries: tuple  # body-frame primary positions, (k, 3) each
    ground_xyz: Float[Array, "G 3"]
    lengths: Float[Array, " D"]  # distance constraints
    point_lengths: Float[Array, " K"]  # massless links between points
    offsets: Float[Array, " A"]  # prismatic angle locks
    gravity: Float[Array, "3"]
    points: tuple
    springs: tuple
    tyres: tuple
    applied: tuple
    # --- static topology ---
    particle_names: tuple = eqx.field(static=True)
    free: tuple = eqx.field(static=True)  # global indices of free particles, in state order
    ground: tuple = eqx.field(static=True)  # global indices of ground particles
    bodies: tuple = eqx.field(static=True)
    distance_pairs: tuple = eqx.field(static=True)  # (i, j, label)
    coincide_pairs: tuple = eqx.field(static=True)  # (i, j, label)
    generic: tuple = eqx.field(static=True)  # (kind, point indices, label, parameter index): see constraints

    @property
    def n_free(self) -> int:
        return len(self.free)

    @property
    def n_coords(self) -> int:
        return 3 * len(self.free)

    # ---- positions ----
    def all_positions(self, x: Float[Array, " 3F"]) -> Float[Array, "P 3"]:
        """Positions of every particle (free from ``x``, ground from ``ground_xyz``), in global index order."""
        n = len(self.particle_names)
        out = jnp.zeros((n, 3), dtype=x.dtype)
        out = out.at[np.asarray(self.free, dtype=int)].set(x.reshape(-1, 3))
        if self.ground:
            out = out.at[np.asarray(self.ground, dtype=int)].set(self.ground_xyz.astype(x.dtype))
        return out

    def point_position(self, k: int, r: Float[Array, "P 3"]) -> Float[Array, "3"]:
        """World position of point ``k`` given all particle positions ``r``."""
        return self.point_positions(r)[k]

    def point_positions(self, r: Float[Array, "P 3"]) -> Float[Array, "K 3"]:
        """World positions of all points (particles first, then body points), vectorised over bodies.

        Body points sit at ``r_1 + F l`` with ``F`` the Gram–Schmidt frame of the body's first three primaries
        (rods: ``r_1 + l_0 (r_2 - r_1)``)."""
        body_pts = [k for k, pt in enumerate(self.points) if pt.particle < 0]
        if not body_pts:
            return r
        bodies = np.asarray([self.points[k].body for k in body_pts])
        local = jnp.stack([self.points[k].local for k in body_pts])
        prim = np.asarray([(self.bodies[b].primaries + (self.bodies[b].primaries[-1],) * 3)[:3] for b in bodies])
        p0, p1, p2 = r[prim[:, 0]], r[prim[:, 1]], r[prim[:, 2]]
        is_rod = np.asarray([self.bodies[b].kind == "rod" for b in bodies])
        e1 = p1 - p0
        e1 = e1 / jnp.linalg.norm(e1, axis=1, keepdims=True)
        w = p2 - p0
        w = w - jnp.sum(w * e1, axis=1, keepdims=True) * e1
        # Rods have no third primary (p2 == p1, w == 0): guard the norm, their rows are replaced below.
        wn = jnp.linalg.norm(w, axis=1, keepdims=True)
        e2 = w / jnp.where(wn > 0, wn, 1.0)
        e3 = jnp.cross(e1, e2)
        frame_pts = p0 + local[:, :1] * e1 + local[:, 1:2] * e2 + local[:, 2:3] * e3
        rod_pts = p0 + local[:, :1] * (p1 - p0)
        pts = jnp.where(is_rod[:, None], rod_pts, frame_pts)
        return jnp.concatenate([r, pts], axis=0)

    # ---- masses ----
    def particle_masses(self, b: int) -> Float[Array, " n"]:
        """Masses of body ``b``'s equivalent particles (primaries then secondaries), solved from its inertia."""
        return solve_particle_masses(self.body_mass[b], self.body_com[b], self.body_inertia[b],
                                     self.body_primaries[b])

    def scalar_mass_matrix(self) -> Float[Array, "P P"]:
        """``sum_b B_b^T diag(m_b) B_b`` scattered on all particles (B maps primaries to all nodes).

        Bodies of one kind are solved together (one vmapped mass solve per kind) and scattered in one add.
        """
        n = len(self.particle_names)
        rows, cols, vals = [], [], []
        for kind in ("spatial", "planar", "rod"):
            ids = [b for b, spec in enumerate(self.bodies) if spec.kind == kind]
            if not ids:
                continue
            k = len(self.bodies[ids[0]].primaries)
            pairs = PAIRS[kind]
            incidence = np.zeros((k + len(pairs), k))
            incidence[:k] = np.eye(k)
            for row, (i, j) in enumerate(pairs):
                incidence[k + row, [i, j]] = 0.5
            masses = jax.vmap(solve_particle_masses)(
                jnp.stack([self.body_mass[b] for b in ids]), jnp.stack([self.body_com[b] for b in ids]),
                jnp.stack([self.body_inertia[b] for b in ids]), jnp.stack([self.body_primaries[b] for b in ids]))
            blocks = jnp.einsum("ni,bn,nj->bij", incidence, masses, incidence)  # (B, k, k)
            prim = np.asarray([self.bodies[b].primaries for b in ids])  # (B, k)
            rows.append(np.repeat(prim, k, axis=1).reshape(-1))
            cols.append(np.tile(prim, (1, k)).reshape(-1))
            vals.append(blocks.reshape(-1))
        m_s = jnp.zeros((n, n))
        if vals:
            m_s = m_s.at[np.concatenate(rows), np.concatenate(cols)].add(jnp.concatenate(vals))
        return m_s

    def mass_matrix(self) -> Float[Array, "3F 3F"]:
        """The constant mass matrix of the free coordinates, ``M_s[free, free] (x) I_3``."""
        f = np.asarray(self.free, dtype=int)
        m_s = self.scalar_mass_matrix()[np.ix_(f, f)]
        return jnp.kron(m_s, jnp.eye(3))

    def lumped_masses(self) -> Float[Array, " P"]:
        """Per-particle mass carrying linear momentum and weight: ``m_bar`` of Attia eq. (25), summed over bodies."""
        return jnp.sum(self.scalar_mass_matrix(), axis=1)

    def total_mass(self) -> Float[Array, ""]:
        return sum(self.body_mass)

    # ---- names ----
    def index(self, particle: str) -> int:
        return self.particle_names.index(particle)

    def free_slice(self, particle: str) -> slice:
        """The three entries of ``x`` holding ``particle``'s position."""
        k = self.free.index(self.index(particle))
        return slice(3 * k, 3 * k + 3)

    def body_index(self, name: str) -> int:
        for i, b in enumerate(self.bodies):
            if b.name == name:
                return i
        raise KeyError(f"no body named {name!r}")

    def point_index(self, name: str) -> int:
        for i, p in enumerate(self.points):
            if p.name == name:
                return i
        raise KeyError(f"no point named {name!r}")
