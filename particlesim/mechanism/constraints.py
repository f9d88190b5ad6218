"""Constraint equations of a mechanism in particle coordinates, their Jacobian and ``gamma``, by row kind.

Points (particles and points fixed to bodies) are affine in the particle positions, ``p_k = sum_t w_kt r_t``
(:func:`point_weights`), so with ``P`` the point positions and ``V`` their velocities each row kind has a closed
form (one vectorised kernel per kind, whatever the number of rows):

=============  ==========================================  =====================================  ==========================
kind           residual                                    d/dp of slots (a, b, c, d)             ``gamma = -d2/dt2 | qdd=0``
=============  ==========================================  =====================================  ==========================
dot            ``s (p_a - p_b).(p_c - p_d) - kappa``       ``s u, -s u, s v, -s v``               ``-2 s (V_a - V_b).(V_c - V_d)``
linear         ``e . (p_a - p_b)``                         ``e, -e``                              ``0``
=============  ==========================================  =====================================  ==========================

with ``u = p_c - p_d`` and ``v = p_a - p_b``. The Jacobian w.r.t. the free coordinates follows by the point
weights: ``J[row, f] = sum_slots block(slot) W[point(slot), f]`` with ``W`` (K, F) the point-to-free-particle
weights, which depend on parameters only (computed once per parameter set, :class:`~.dynamics.Prepared`).

Row order: all dot rows (body distances, then joint rows in declaration order), then all linear rows, then the
driving rows ``n(t) . (p_a - p_b) - c(t)`` (:class:`~.model.DriveRows`), the only rows that depend on time. The
acceleration-level form is ``J(q, t) qdd = gamma(q, qd, t)``, the velocity-level one ``J qd = nu(q, t)``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .model import Mechanism, Topology
from .._jit import compiled

__all__ = ["point_weights", "point_free_weights", "constraints", "constraint_jacobian", "constraint_gamma",
           "constraint_labels", "velocity_constraints", "row_blocks", "row_incidence"]


def point_weights(mech: Mechanism) -> Float[Array, "K 4"]:
    """Affine weights of every point on its (up to four) particles (:meth:`Topology.point_slots`).

    A particle point has weight 1 on itself. A point of a spatial body solves ``[R^T; 1^T] w = [p; 1]`` (``R`` the
    body-frame primaries, 4 x 4); of a planar body the same system in least squares (the point lies in the plane,
    checked at build); of a rod ``w = (1 - s, s)`` with ``s`` its fraction along the rod.
    """
    topo = mech.topo
    w = np.zeros((len(topo.point_names), 4))
    w[:, 0] = 1.0
    w = jnp.asarray(w, dtype=mech.point_local.dtype)
    for n in (4, 3, 2):
        ids = [k for k, b in enumerate(topo.point_body) if b >= 0 and len(topo.body_particles[b]) == n]
        if not ids:
            continue
        bodies = np.asarray([topo.point_body[k] for k in ids])
        prim = mech.body_primaries[bodies][:, :n]  # (m, n, 3)
        loc = mech.point_local[np.asarray(ids)]  # (m, 3)
        if n == 2:
            e = prim[:, 1] - prim[:, 0]
            s = jnp.sum((loc - prim[:, 0]) * e, axis=1) / jnp.sum(e * e, axis=1)
            wk = jnp.stack([1.0 - s, s], axis=1)
        else:
            a = jnp.concatenate([jnp.swapaxes(prim, 1, 2), jnp.ones((len(ids), 1, n))], axis=1)  # (m, 4, n)
            rhs = jnp.concatenate([loc, jnp.ones((len(ids), 1))], axis=1)  # (m, 4)
            if n == 3:
                rhs = jnp.einsum("mij,mi->mj", a, rhs)
                a = jnp.einsum("mij,mik->mjk", a, a)
            wk = jnp.linalg.solve(a, rhs[..., None])[..., 0]
        w = w.at[np.asarray(ids), :n].set(wk).at[np.asarray(ids), n:].set(0.0)
    return w


def point_free_weights(topo: Topology, w: Float[Array, "K 4"]) -> Float[Array, "K F"]:
    """``W[k, f] = d p_k / d r_f`` (a scalar: the weight of free particle ``f`` in point ``k``)."""
    cols = topo.free_column()[topo.point_slots()]  # (K, 4): free column of each slot, -1 for ground particles
    onehot = (cols[..., None] == np.arange(len(topo.free))[None, None, :]).astype(float)  # (K, 4, F)
    return jnp.einsum("kt,ktf->kf", w, onehot)


def row_incidence(topo: Topology, wk: Float[Array, "K F"]) -> tuple[Array, Array]:
    """``(G_dot (D, 4, F), G_lin (L, 2, F))``: the point-to-free weights of every slot of every row."""
    return wk[topo.dot.slots], wk[topo.linear.slots]


def points(topo: Topology, w: Float[Array, "K 4"], r: Float[Array, "P 3"]) -> Float[Array, "K 3"]:
    """Point positions (or velocities, with particle velocities ``r``)."""
    return jnp.einsum("kt,ktj->kj", w, r[topo.point_slots()])


def quarter_turn(u: Float[Array, "n 3"], turn, sign: float = 1.0) -> Float[Array, "n 3"]:
    """``sign * Rz u`` (``Rz`` a quarter turn about z) on the rows flagged in ``turn``, ``u`` elsewhere."""
    if turn is None:
        return u
    r = sign * jnp.stack([-u[:, 1], u[:, 0], jnp.zeros_like(u[:, 0])], axis=1)
    return jnp.where(jnp.asarray(np.asarray(turn, dtype=bool))[:, None], r, u)


def _dot_geometry(topo: Topology, p):
    """``(v, u, s)`` of every dot row, with ``u`` already turned on turned rows (residual ``s v . u``)."""
    rows = topo.dot
    u = p[np.asarray(rows.c, dtype=int)] - p[np.asarray(rows.d, dtype=int)]
    v = p[np.asarray(rows.a, dtype=int)] - p[np.asarray(rows.b, dtype=int)]
    return v, quarter_turn(u, rows.turned), jnp.asarray(rows.scale, dtype=p.dtype)


def _driven_vectors(mech: Mechanism, pts: Float[Array, "K 3"]) -> Float[Array, "K 3"]:
    dr = mech.topo.drive
    a, b = np.asarray(dr.a, dtype=int), np.asarray(dr.b, dtype=int)
    return pts[a] - jnp.where(jnp.asarray(b < 0)[:, None], 0.0, pts[np.where(b < 0, 0, b)])


def row_residuals(mech: Mechanism, pts: Float[Array, "K 3"], t=0.0) -> Float[Array, " C"]:
    """All constraint residuals from the point positions (at time ``t``: driving rows only)."""
    topo = mech.topo
    out = []
    if len(topo.dot):
        v, u, s = _dot_geometry(topo, pts)
        out.append(s * jnp.sum(v * u, axis=1) - mech.dot_kappa)
    if len(topo.linear):
        rows = topo.linear
        d = pts[np.asarray(rows.a, dtype=int)] - pts[np.asarray(rows.b, dtype=int)]
        out.append(jnp.sum(jnp.asarray(rows.axis, dtype=pts.dtype) * d, axis=1))
    if len(topo.drive):
        from ._algebra import drive_at

        drv = drive_at(mech, t)
        out.append(jnp.sum(drv.n * _driven_vectors(mech, pts), axis=1) - drv.c)
    if not out:
        return jnp.zeros((0,), dtype=pts.dtype)
    return jnp.concatenate(out)


def row_blocks(topo: Topology, pts: Float[Array, "K 3"]) -> Float[Array, "D 4 3"]:
    """``d residual / d p`` of every slot of every dot row (the linear rows' blocks are constant, ``+-e``)."""
    v, u, s = _dot_geometry(topo, pts)
    su, sv = s[:, None] * u, s[:, None] * quarter_turn(v, topo.dot.turned, -1.0)  # d/dp_c of v.Rz u is Rz^T v
    return jnp.stack([su, -su, sv, -sv], axis=1)


def linear_blocks(topo: Topology) -> np.ndarray:
    e = np.asarray(topo.linear.axis, dtype=float).reshape(-1, 3)
    return np.stack([e, -e], axis=1)  # (L, 2, 3)


def row_gamma(topo: Topology, vel: Float[Array, "K 3"]) -> Float[Array, " C"]:
    """``gamma`` of every row from the point velocities (affine points have no velocity-squared terms)."""
    out = []
    if len(topo.dot):
        dv, du, s = _dot_geometry(topo, vel)
        out.append(-2.0 * s * jnp.sum(dv * du, axis=1))
    if len(topo.linear):
        out.append(jnp.zeros((len(topo.linear),), dtype=vel.dtype))
    if not out:
        return jnp.zeros((0,), dtype=vel.dtype)
    return jnp.concatenate(out)


def jacobian_from_blocks(blocks: Array, g_dot: Array, j_lin: Array) -> Float[Array, "C F 3"]:
    """``J`` as ``(C, F, 3)`` from the dot-row blocks, their incidence and the constant linear rows."""
    parts = []
    if blocks.shape[0]:
        # A broadcast product summed over the slots (one fused kernel; a batched matmul of 4 x 3 blocks is not).
        parts.append(jnp.sum(blocks[:, :, None, :] * g_dot[:, :, :, None], axis=1))
    if j_lin.shape[0]:
        parts.append(j_lin)
    if not parts:
        return jnp.zeros((0, g_dot.shape[-1], 3))
    return jnp.concatenate(parts, axis=0)


def linear_jacobian(topo: Topology, g_lin: Array) -> Float[Array, "L F 3"]:
    return jnp.sum(jnp.asarray(linear_blocks(topo))[:, :, None, :] * g_lin[:, :, :, None], axis=1)


# ---- public functions of (mech, x): convenient, recompute the point weights on every call ----

def _state(mech: Mechanism, q, qd=None):
    w = point_weights(mech)
    pts = points(mech.topo, w, mech.all_positions(q))
    if qd is None:
        return w, pts
    col = mech.topo.free_column()
    vel_all = jnp.where(jnp.asarray(col >= 0)[:, None], mech.all_positions(qd), 0.0)
    return w, pts, points(mech.topo, w, vel_all)


@compiled("constraints")
def constraints(mech: Mechanism, q: Float[Array, " 3F"], *, t=0.0) -> Float[Array, " C"]:
    """All constraint residuals at ``q`` (zero on the constraint manifold); ``t`` matters only for driving rows."""
    return row_residuals(mech, _state(mech, q)[1], t)


def constraint_labels(mech: Mechanism) -> list[str]:
    """A readable label per constraint row (for error messages and residual reports)."""
    return mech.topo.row_labels()


@compiled("constraint_jacobian")
def constraint_jacobian(mech: Mechanism, q: Float[Array, " 3F"], *, t=0.0) -> Float[Array, "C 3F"]:
    """``J = d constraints / dx`` in closed form, ``(C, 3F)``."""
    topo = mech.topo
    w, pts = _state(mech, q)
    wk = point_free_weights(topo, w)
    g_dot, g_lin = row_incidence(topo, wk)
    blocks = row_blocks(topo, pts) if len(topo.dot) else jnp.zeros((0, 4, 3))
    j = jacobian_from_blocks(blocks, g_dot, linear_jacobian(topo, g_lin))
    if len(topo.drive):
        from ._algebra import drive_at

        dr = topo.drive
        a, b = np.asarray(dr.a, dtype=int), np.asarray(dr.b, dtype=int)
        d = wk[a] - jnp.where(jnp.asarray(b < 0)[:, None], 0.0, wk[np.where(b < 0, 0, b)])
        j = jnp.concatenate([j, d[:, :, None] * drive_at(mech, t).n[:, None, :]], axis=0)
    return j.reshape(j.shape[0], -1)


@compiled("velocity_constraints")
def velocity_constraints(mech: Mechanism, q, qd, *, t=0.0) -> Float[Array, " C"]:
    """``d/dt constraints = J(q, t) qd - nu(q, t)``: zero for admissible velocities (``nu`` is zero except on
    driving rows)."""
    t = jnp.asarray(t, dtype=q.dtype)
    return jax.jvp(lambda y, s: constraints(mech, y, t=s), (q, t), (qd, jnp.ones_like(t)))[1]


@compiled("constraint_gamma")
def constraint_gamma(mech: Mechanism, q, qd, *, t=0.0) -> Float[Array, " C"]:
    """Right-hand side of ``J qdd = gamma``: ``gamma = -(d^2/dt^2 constraints)`` at zero acceleration (closed
    form)."""
    g = row_gamma(mech.topo, _state(mech, q, qd)[2])
    if not len(mech.topo.drive):
        return g
    from ._algebra import drive_at

    drv = drive_at(mech, t)
    _, pts, vel = _state(mech, q, qd)
    u, du = _driven_vectors(mech, pts), _driven_vectors(mech, vel)
    n_fixed = len(mech.topo.dot) + len(mech.topo.linear)
    tail = drv.cdd - 2.0 * jnp.sum(drv.nd * du, axis=1) - jnp.sum(drv.ndd * u, axis=1)
    return jnp.concatenate([g[:n_fixed], tail])
