"""Unconstrained parameterisations of physically consistent link inertias, rotor inertias and friction.

Inertia of one link: the report's 10-vector ``pi = [m, m cx, m cy, m cz, XX, XY, XZ, YY, YZ, ZZ]`` about the link
frame origin, in link axes (Zafar §5.1). Its *pseudo-inertia* (Wensing, Kim & Slotine 2017) is the 4x4 matrix of
second moments of the mass distribution ``rho`` in homogeneous coordinates,

    ``P = int [r; 1][r; 1]^T drho = [[Sigma, h], [h^T, m]]``,  ``Sigma = tr(J)/2 E - J``,  ``h = m c``,

with ``J`` the 3x3 inertia about the origin. A 10-vector is realisable by a non-negative mass distribution iff
``P >= 0``; ``P > 0`` is the interior (every body that is not flat, a rod or a point), and it implies ``m > 0``,
a positive-definite inertia about the CoM and the strict triangle inequalities.

:func:`inertia_from_log_cholesky` implements the log-Cholesky map of Rucker & Wensing (2022):
``P = U U^T`` with ``U`` upper triangular,

    ``U = exp(alpha) [[exp(d1), s12, s13, t1], [0, exp(d2), s23, t2], [0, 0, exp(d3), t3], [0, 0, 0, 1]]``,

``theta = [alpha, d1, d2, d3, s12, s23, s13, t1, t2, t3]`` (their ordering). Every ``P > 0`` has exactly one such
factor (a Cholesky factorisation read from the bottom-right corner), so the map is a smooth bijection from
``R^10`` onto **exactly the set of physically consistent, non-degenerate bodies**; it never reaches the boundary
(``m = 0``, or a mass distribution on a plane, line or point), which is approached only as a parameter goes to
``-inf``. ``m = exp(2 alpha)``, ``c = exp(-alpha) [t1, t2, t3]``-like terms keep the scaling well conditioned.

Rotor inertia ``I_a = N^2 J_m`` (eq. 18), viscous ``Fv`` and Coulomb ``Fc`` friction (eq. 17) are positive; they
use ``x = softplus(u) = log(1 + e^u)`` (reaches every ``x > 0``; :func:`inv_softplus` is its inverse), which is
linear for large ``u`` (better conditioned for Gauss–Newton than ``exp``). The sign in eq. (17) is replaced by
``tanh(qd / eps)`` (``smooth_friction=eps`` of :func:`particlesim.tree.inverse_dynamics`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from ..inertia import pack_params, unpack_params

__all__ = [
    "pseudo_inertia",
    "params_from_pseudo_inertia",
    "inertia_from_log_cholesky",
    "log_cholesky_from_inertia",
    "softplus",
    "inv_softplus",
]


def pseudo_inertia(params: Float[ArrayLike, "... 10"]) -> Float[Array, "... 4 4"]:
    """The 4x4 pseudo-inertia ``[[tr(J)/2 E - J, m c], [m c^T, m]]`` of 10-vectors about the frame origin."""
    m, h, j = unpack_params(jnp.asarray(params))
    sig = 0.5 * jnp.trace(j, axis1=-2, axis2=-1)[..., None, None] * jnp.broadcast_to(jnp.eye(3), j.shape) - j  # second moment about the origin
    top = jnp.concatenate([sig, h[..., :, None]], -1)
    bottom = jnp.concatenate([h, m[..., None]], -1)[..., None, :]
    return jnp.concatenate([top, bottom], -2)


def params_from_pseudo_inertia(p4: Float[ArrayLike, "... 4 4"]) -> Float[Array, "... 10"]:
    """Inverse of :func:`pseudo_inertia`: ``J = tr(Sigma) E - Sigma``, ``h = P[:3, 3]``, ``m = P[3, 3]``."""
    p4 = jnp.asarray(p4)
    s = p4[..., :3, :3]
    j = jnp.trace(s, axis1=-2, axis2=-1)[..., None, None] * jnp.broadcast_to(jnp.eye(3), s.shape) - s
    return pack_params(p4[..., 3, 3], p4[..., :3, 3], j)


def _upper_factor(theta):
    alpha, d1, d2, d3, s12, s23, s13, t1, t2, t3 = (theta[..., k] for k in range(10))
    z, one = jnp.zeros_like(alpha), jnp.ones_like(alpha)
    u = jnp.stack([
        jnp.stack([jnp.exp(d1), s12, s13, t1], -1),
        jnp.stack([z, jnp.exp(d2), s23, t2], -1),
        jnp.stack([z, z, jnp.exp(d3), t3], -1),
        jnp.stack([z, z, z, one], -1),
    ], -2)
    return jnp.exp(alpha)[..., None, None] * u


def inertia_from_log_cholesky(theta: Float[ArrayLike, "... 10"]) -> Float[Array, "... 10"]:
    """Log-Cholesky coordinates ``theta`` (see module docstring) -> 10-vector with ``P = U U^T > 0``."""
    u = _upper_factor(jnp.asarray(theta))
    return params_from_pseudo_inertia(u @ jnp.swapaxes(u, -1, -2))


def log_cholesky_from_inertia(params: Float[ArrayLike, "... 10"]) -> Float[Array, "... 10"]:
    """Inverse of :func:`inertia_from_log_cholesky`; NaN where the pseudo-inertia is not positive definite.

    The upper factor of ``P`` is the ordinary Cholesky factor of ``P`` with rows and columns reversed.
    """
    p4 = pseudo_inertia(params)
    flip = p4[..., ::-1, ::-1]
    lower = jnp.linalg.cholesky(flip)  # flip = L L^T  =>  P = U U^T with U = L reversed (upper triangular)
    u = lower[..., ::-1, ::-1]
    a = u[..., 3, 3]  # = exp(alpha)
    alpha = jnp.log(a)
    v = u / a[..., None, None]
    return jnp.stack([
        alpha, jnp.log(v[..., 0, 0]), jnp.log(v[..., 1, 1]), jnp.log(v[..., 2, 2]),
        v[..., 0, 1], v[..., 1, 2], v[..., 0, 2], v[..., 0, 3], v[..., 1, 3], v[..., 2, 3],
    ], -1)


def softplus(u: ArrayLike) -> Array:
    """``log(1 + e^u) > 0`` (numerically stable)."""
    return jax.nn.softplus(jnp.asarray(u))


def inv_softplus(x: ArrayLike) -> Array:
    """Inverse of :func:`softplus` for ``x > 0``: ``u = x + log(-expm1(-x))``; NaN for ``x <= 0``."""
    x = jnp.asarray(x)
    return x + jnp.log(-jnp.expm1(-x))
