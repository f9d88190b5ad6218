"""Constraint equations of a mechanism in particle coordinates and their derivatives.

Rows, in order:

1. distances ``(|r_i - r_j|^2 - d^2) / 2 = 0``: the rigid distances inside every body (Attia eqs. (11)–(16)) and
   massless links;
2. coincidences ``r_a - r_b = 0``: cut joints that close loops (Attia §2.4, the quarter car's ``r7 = r10``);
3. rows on *points* (particles or points fixed to bodies), in declaration order: massless links between points,
   cut joints involving a body point, a particle kept on a body's line (two rows: a revolute joint's second
   axis particle on the other body's axis), and prismatic joints, five rows each: both axis points of body B
   stay on body A's axis (two components perpendicular to it for each) and a third point of B keeps its angle
   about the axis. The prismatic rows are an independent set equivalent to Attia eqs. (44a)–(44c), whose
   cross-product form has redundant rows.

The acceleration-level form is ``J(x) xdd = gamma(x, xd)`` with ``gamma = -(d/dx (J xd)) xd``, obtained by forward
differentiation twice (no constraint has explicit time dependence).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .model import Mechanism

__all__ = ["constraints", "constraint_jacobian", "constraint_gamma", "constraint_labels", "velocity_constraints"]


def _perp_frame(a0, a1, a2):
    u = a1 - a0
    u = u / jnp.linalg.norm(u)
    w = a2 - a0
    n1 = w - jnp.dot(w, u) * u
    n1 = n1 / jnp.linalg.norm(n1)
    return u, n1, jnp.cross(u, n1)


def _generic_rows(mech: Mechanism, allp, spec) -> Array:
    kind, pts, _, k = spec

    def p(i):
        return allp[i]

    if kind == "link":
        d = p(pts[0]) - p(pts[1])
        return (0.5 * (d @ d - mech.point_lengths[k] ** 2))[None]
    if kind == "coincide":
        return p(pts[0]) - p(pts[1])
    if kind == "on_line":
        b, o, d0, d1, ref = (p(i) for i in pts)
        _, n1, n2 = _perp_frame(d0, d1, ref)
        return jnp.stack([n1 @ (b - o), n2 @ (b - o)])
    a0, a1, a2, b0, b1, b2 = (p(i) for i in pts)  # prismatic
    _, n1, n2 = _perp_frame(a0, a1, a2)
    e0, e1 = b0 - a0, b1 - a0
    return jnp.stack([n1 @ e0, n2 @ e0, n1 @ e1, n2 @ e1, n1 @ (b2 - b0) - mech.offsets[k]])


def _generic_all(mech: Mechanism, r) -> Array:
    allp = mech.point_positions(r)
    return jnp.concatenate([_generic_rows(mech, allp, spec) for spec in mech.generic])


def constraints(mech: Mechanism, x: Float[Array, " 3F"]) -> Float[Array, " C"]:
    """All constraint residuals at ``x`` (zero on the constraint manifold)."""
    r = mech.all_positions(x)
    rows = []
    if mech.distance_pairs:
        i = np.asarray([p[0] for p in mech.distance_pairs])
        j = np.asarray([p[1] for p in mech.distance_pairs])
        d = r[i] - r[j]
        rows.append(0.5 * (jnp.sum(d * d, axis=1) - mech.lengths**2))
    if mech.coincide_pairs:
        i = np.asarray([p[0] for p in mech.coincide_pairs])
        j = np.asarray([p[1] for p in mech.coincide_pairs])
        rows.append((r[i] - r[j]).reshape(-1))
    if mech.generic:
        rows.append(_generic_all(mech, r))
    if not rows:
        return jnp.zeros((0,), dtype=x.dtype)
    return jnp.concatenate(rows)


def constraint_labels(mech: Mechanism) -> list[str]:
    """A readable label per constraint row (for error messages and residual reports)."""
    out = [p[2] for p in mech.distance_pairs]
    for p in mech.coincide_pairs:
        out += [f"{p[2]} ({c})" for c in "xyz"]
    parts = {"link": ("",), "coincide": ("x", "y", "z"), "on_line": ("n1", "n2"),
             "prismatic": ("axis 1a", "axis 1b", "axis 2a", "axis 2b", "rotation")}
    for kind, _, label, _ in mech.generic:
        out += [f"{label} ({c})" if c else label for c in parts[kind]]
    return out


def _pair_index(pairs):
    return np.asarray([p[0] for p in pairs], dtype=int), np.asarray([p[1] for p in pairs], dtype=int)


def _free_columns(mech: Mechanism) -> np.ndarray:
    """For every particle, the column of its x-coordinate in ``x`` (-1 for ground particles)."""
    col = -np.ones(len(mech.particle_names), dtype=int)
    col[np.asarray(mech.free, dtype=int)] = 3 * np.arange(len(mech.free))
    return col


def _scatter_rows(rows: int, parts, n_coords: int) -> Array:
    """Assemble ``(R, n_coords)`` from per-row 3-blocks ``parts = [(particle_cols, blocks (R, 3)), ...]``, in one
    scatter; ground particles (column -1) are dropped."""
    r_idx, c_idx, vals = [], [], []
    for cols, block in parts:
        keep = np.flatnonzero(cols >= 0)
        if keep.size == 0:
            continue
        r_idx.append(np.repeat(keep, 3))
        c_idx.append((cols[keep][:, None] + np.arange(3)[None, :]).reshape(-1))
        vals.append(block[keep].reshape(-1))
    out = jnp.zeros((rows, n_coords))
    if not vals:
        return out
    return out.at[np.concatenate(r_idx), np.concatenate(c_idx)].add(jnp.concatenate(vals))


def constraint_jacobian(mech: Mechanism, x: Float[Array, " 3F"]) -> Float[Array, "C 3F"]:
    """``J = d constraints / dx``: closed form for distances and coincidences, forward-mode for point rows."""
    r = mech.all_positions(x)
    col = _free_columns(mech)
    n = mech.n_coords
    blocks = []
    if mech.distance_pairs:
        i, j = _pair_index(mech.distance_pairs)
        d = r[i] - r[j]
        blocks.append(_scatter_rows(len(i), [(col[i], d), (col[j], -d)], n))
    if mech.coincide_pairs:
        i, j = _pair_index(mech.coincide_pairs)
        eye = jnp.tile(jnp.eye(3), (len(i), 1))
        blocks.append(_scatter_rows(3 * len(i), [(np.repeat(col[i], 3), eye), (np.repeat(col[j], 3), -eye)], n))
    if mech.generic:
        blocks.append(jax.jacfwd(lambda y: _generic_all(mech, mech.all_positions(y)))(x))
    if not blocks:
        return jnp.zeros((0, n), dtype=x.dtype)
    return jnp.concatenate(blocks, axis=0)


def velocity_constraints(mech: Mechanism, x, xd) -> Float[Array, " C"]:
    """``J(x) xd``: zero for admissible velocities."""
    return jax.jvp(lambda y: constraints(mech, y), (x,), (xd,))[1]


def constraint_gamma(mech: Mechanism, x, xd) -> Float[Array, " C"]:
    """Right-hand side of ``J xdd = gamma``: ``gamma = -xd^T (d^2 constraints / dx^2) xd`` (closed form for
    distances, ``-|v_i - v_j|^2``; zero for coincidences; forward-mode twice for point rows)."""
    v = mech.all_positions(xd) * jnp.asarray(_free_columns(mech) >= 0, dtype=xd.dtype)[:, None]
    parts = []
    if mech.distance_pairs:
        i, j = _pair_index(mech.distance_pairs)
        dv = v[i] - v[j]
        parts.append(-jnp.sum(dv * dv, axis=1))
    if mech.coincide_pairs:
        parts.append(jnp.zeros(3 * len(mech.coincide_pairs), dtype=x.dtype))
    if mech.generic:
        def rows(y):
            return _generic_all(mech, mech.all_positions(y))

        parts.append(-jax.jvp(lambda y: jax.jvp(rows, (y,), (xd,))[1], (x,), (xd,))[1])
    if not parts:
        return jnp.zeros((0,), dtype=x.dtype)
    return jnp.concatenate(parts)
