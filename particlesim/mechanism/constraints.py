"""Constraint equations of a mechanism in particle coordinates and their derivatives.

Rows, in order:

1. distances ``(|r_i - r_j|^2 - d^2) / 2 = 0``: the rigid distances inside every body (Attia eqs. (11)–(16)) and
   massless links;
2. coincidences ``r_a - r_b = 0``: cut joints that close loops (Attia §2.4, the quarter car's ``r7 = r10``);
3. prismatic joints, five rows each: both axis particles of body B stay on body A's axis (two components
   perpendicular to it for each particle) and a third particle of B keeps its angle about the axis. This is an
   independent set equivalent to Attia eqs. (44a)–(44c), whose cross-product form has redundant rows.

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


def _prismatic_rows(mech: Mechanism, r, k: int) -> Array:
    (a0, a1, a2), (b0, b1, b2), _ = mech.prismatics[k]
    _, n1, n2 = _perp_frame(r[a0], r[a1], r[a2])
    d0, d1 = r[b0] - r[a0], r[b1] - r[a0]
    return jnp.stack([n1 @ d0, n2 @ d0, n1 @ d1, n2 @ d1, n1 @ (r[b2] - r[b0]) - mech.offsets[k]])


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
    if mech.prismatics:
        rows.append(_prismatic_all(mech, r))
    if not rows:
        return jnp.zeros((0,), dtype=x.dtype)
    return jnp.concatenate(rows)


def constraint_labels(mech: Mechanism) -> list[str]:
    """A readable label per constraint row (for error messages and residual reports)."""
    out = [p[2] for p in mech.distance_pairs]
    for p in mech.coincide_pairs:
        out += [f"{p[2]} ({c})" for c in "xyz"]
    for p in mech.prismatics:
        out += [f"{p[2]} ({c})" for c in ("axis 1a", "axis 1b", "axis 2a", "axis 2b", "rotation")]
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
    """``J = d constraints / dx``: closed form for distances and coincidences, forward-mode for prismatic rows."""
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
    if mech.prismatics:
        blocks.append(jax.jacfwd(lambda y: _prismatic_all(mech, mech.all_positions(y)))(x))
    if not blocks:
        return jnp.zeros((0, n), dtype=x.dtype)
    return jnp.concatenate(blocks, axis=0)


def _prismatic_all(mech: Mechanism, r) -> Array:
    return jnp.concatenate([_prismatic_rows(mech, r, k) for k in range(len(mech.prismatics))])


def velocity_constraints(mech: Mechanism, x, xd) -> Float[Array, " C"]:
    """``J(x) xd``: zero for admissible velocities."""
    return jax.jvp(lambda y: constraints(mech, y), (x,), (xd,))[1]


def constraint_gamma(mech: Mechanism, x, xd) -> Float[Array, " C"]:
    """Right-hand side of ``J xdd = gamma``: ``gamma = -xd^T (d^2 constraints / dx^2) xd`` (closed form for
    distances, ``-|v_i - v_j|^2``; zero for coincidences; forward-mode twice for prismatic rows)."""
    v = mech.all_positions(xd) * jnp.asarray(_free_columns(mech) >= 0, dtype=xd.dtype)[:, None]
    parts = []
    if mech.distance_pairs:
        i, j = _pair_index(mech.distance_pairs)
        dv = v[i] - v[j]
        parts.append(-jnp.sum(dv * dv, axis=1))
    if mech.coincide_pairs:
        parts.append(jnp.zeros(3 * len(mech.coincide_pairs), dtype=x.dtype))
    if mech.prismatics:
        def rows(y):
            return _prismatic_all(mech, mech.all_positions(y))

        parts.append(-jax.jvp(lambda y: jax.jvp(rows, (y,), (xd,))[1], (x,), (xd,))[1])
    if not parts:
        return jnp.zeros((0,), dtype=x.dtype)
    return jnp.concatenate(parts)
