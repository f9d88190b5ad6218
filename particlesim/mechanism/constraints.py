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
    for k in range(len(mech.prismatics)):
        rows.append(_prismatic_rows(mech, r, k))
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


def constraint_jacobian(mech: Mechanism, x: Float[Array, " 3F"]) -> Float[Array, "C 3F"]:
    """``J = d constraints / dx``."""
    return jax.jacfwd(lambda y: constraints(mech, y))(x)


def velocity_constraints(mech: Mechanism, x, xd) -> Float[Array, " C"]:
    """``J(x) xd``: zero for admissible velocities."""
    return jax.jvp(lambda y: constraints(mech, y), (x,), (xd,))[1]


def constraint_gamma(mech: Mechanism, x, xd) -> Float[Array, " C"]:
    """Right-hand side of ``J xdd = gamma``: ``gamma = -xd^T (d^2 constraints / dx^2) xd``."""
    return -jax.jvp(lambda y: velocity_constraints(mech, y, xd), (x,), (xd,))[1]
