"""Force elements between two bodies' poses: bushings and torsion springs.

Each is a set of coordinates ``delta(q)`` read from the bodies' poses (:func:`~.outputs.body_poses`), with a
diagonal linear law ``tau = k (delta - delta_0) + c delta'`` (``delta'`` by a forward-mode derivative along ``qd``):

* a **bushing** joins a point of body ``a`` and a point of body ``b`` that coincide at assembly (zero free length):
  ``delta`` is their separation in the bushing's axes, which turn with its frame body; a bushing that also resists
  rotation adds the rotation vector of ``b`` relative to ``a`` since assembly (:func:`~particlesim.spatial.
  rotation_log`), in the same axes;
* a **torsion spring** (an anti-roll bar) reads the rotation of ``b`` relative to ``a`` about an axis fixed in ``a``:
  the component of that rotation vector along the axis, the exact angle when the relative rotation is about the axis
  (two bodies hinged on it) and the twist otherwise; valid below half a turn.

By virtual work the generalised force is ``-(d delta / dq)^T tau``, the energy ``k (delta - delta_0)^2 / 2`` and
the forces on each body's primaries ``-(d delta / d r_b)^T tau`` (for :func:`~.outputs.body_reactions`): one coordinate
function serves all three, so they agree by construction. A scene without these elements pays nothing for them.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..spatial import rotation_log
from .model import Mechanism

__all__ = ["element_coordinates", "element_forces", "element_energy", "element_primary_forces", "has_elements"]


def has_elements(mech: Mechanism) -> bool:
    return bool(mech.topo.bushing_names or mech.topo.torsion_names)


def _poses(mech: Mechanism, q):
    """Every body's ``(R, origin)`` with the ground appended last (so that body index ``-1`` reads it)."""
    from .outputs import _poses_from_positions

    rot, org = _poses_from_positions(mech, mech.all_positions(q))
    return (jnp.concatenate([rot, jnp.eye(3, dtype=rot.dtype)[None]]),
            jnp.concatenate([org, jnp.zeros((1, 3), org.dtype)]))


def _laws(mech: Mechanism):
    """``(k, c, delta_0)`` of every coordinate, in :func:`element_coordinates` order."""
    topo = mech.topo
    ks, cs, d0 = [], [], []
    if topo.bushing_names:
        rotating = np.flatnonzero(np.asarray(topo.bushing_rotational, bool))
        ks += [mech.bushing_stiffness[:, :3].reshape(-1), mech.bushing_stiffness[rotating, 3:].reshape(-1)]
        cs += [mech.bushing_damping[:, :3].reshape(-1), mech.bushing_damping[rotating, 3:].reshape(-1)]
        d0.append(jnp.zeros(3 * (len(topo.bushing_names) + rotating.size), mech.bushing_stiffness.dtype))
    if topo.torsion_names:
        ks.append(mech.torsion_stiffness)
        cs.append(mech.torsion_damping)
        d0.append(mech.torsion_free_angle)
    return jnp.concatenate(ks), jnp.concatenate(cs), jnp.concatenate(d0)


def element_coordinates(mech: Mechanism, rot: Float[Array, "B1 3 3"], org: Float[Array, "B1 3"]) -> Array:
    """The coordinates of every bushing (3, and 3 more for a rotating one) and torsion spring (1), from the
    bodies' poses (:func:`_poses`: the ground last)."""
    topo = mech.topo
    out = []
    if topo.bushing_names:
        abf = np.asarray(topo.bushing_bodies, dtype=int)
        a, b, f = abf[:, 0], abf[:, 1], abf[:, 2]
        pa = jnp.einsum("nij,nj->ni", rot[a], mech.bushing_local[:, 0]) + org[a]
        pb = jnp.einsum("nij,nj->ni", rot[b], mech.bushing_local[:, 1]) + org[b]
        axes = rot[f] @ mech.bushing_axes  # columns: the bushing's axes in the world
        out.append(jnp.einsum("nij,ni->nj", axes, pb - pa).reshape(-1))
        turn = np.flatnonzero(np.asarray(topo.bushing_rotational, bool))
        if turn.size:
            phi = _relative_rotation(rot[a[turn]], rot[b[turn]], mech.bushing_rest[turn])
            world = jnp.einsum("nij,nj->ni", rot[a[turn]], phi)
            out.append(jnp.einsum("nij,ni->nj", axes[turn], world).reshape(-1))
    if topo.torsion_names:
        ab = np.asarray(topo.torsion_bodies, dtype=int)
        phi = _relative_rotation(rot[ab[:, 0]], rot[ab[:, 1]], mech.torsion_rest)
        out.append(jnp.sum(phi * mech.torsion_axis, axis=1))
    return jnp.concatenate(out)


def _relative_rotation(ra, rb, rest):
    """Rotation vector, in body a's frame, of body b's rotation relative to a since assembly (``rest = Ra^T Rb``
    then)."""
    delta = jnp.swapaxes(ra, 1, 2) @ rb @ jnp.swapaxes(rest, 1, 2)
    return rotation_log(delta)


def _coords_of_q(mech: Mechanism):
    return lambda y: element_coordinates(mech, *_poses(mech, y))


def element_forces(mech: Mechanism, q, qd) -> Float[Array, " 3F"]:
    """Generalised forces of every bushing and torsion spring: ``-(d delta/dq)^T tau`` (one jvp, one vjp)."""
    k, c, d0 = _laws(mech)
    delta, rate, pull = _jvp_vjp(_coords_of_q(mech), q, qd)
    return -pull(k * (delta - d0) + c * rate)


def _jvp_vjp(fn, q, qd):
    delta, rate = jax.jvp(fn, (q,), (qd,))
    _, pull = jax.vjp(fn, q)
    return delta, rate, lambda tau: pull(tau.astype(delta.dtype))[0]


def element_energy(mech: Mechanism, q) -> Float[Array, ""]:
    """``sum k (delta - delta_0)^2 / 2`` of every bushing and torsion spring."""
    k, _, d0 = _laws(mech)
    return 0.5 * jnp.sum(k * (_coords_of_q(mech)(q) - d0) ** 2)


def element_primary_forces(mech: Mechanism, q, qd) -> Float[Array, "B 4 3"]:
    """The forces of the bushings and torsion springs on every body's primaries (ground ones included; padded with
    zeros to 4), ``-(d delta / d r_b)^T tau`` with each body's pose read from its own primaries: the same split as
    the generalised forces (their sum over the free particles), for :func:`~.outputs.body_reactions`."""
    from .outputs import _poses_from_primaries

    topo = mech.topo
    k, c, d0 = _laws(mech)
    delta, rate = jax.jvp(_coords_of_q(mech), (q,), (qd,))
    tau = k * (delta - d0) + c * rate
    r = mech.all_positions(q)
    prim = np.asarray([list(p) + [p[-1]] * (4 - len(p)) for p in topo.body_particles], dtype=int)
    bodies = {tuple(topo.body_particles[b]): b for b in range(len(topo.body_particles))}

    def coords(own):  # own: (B, 4, 3) every body's primaries' positions
        def read(idx):
            return own[np.asarray([bodies[tuple(row)] for row in idx]), :idx.shape[1]]

        rot, org = _poses_from_primaries(mech, read, own.dtype)
        return element_coordinates(mech, jnp.concatenate([rot, jnp.eye(3, dtype=rot.dtype)[None]]),
                                   jnp.concatenate([org, jnp.zeros((1, 3), org.dtype)]))

    _, pull = jax.vjp(coords, r[prim])
    out = pull(-tau.astype(r.dtype))[0]
    pad = np.asarray([[s >= len(p) for s in range(4)] for p in topo.body_particles])
    return jnp.where(jnp.asarray(pad)[:, :, None], 0.0, out)
