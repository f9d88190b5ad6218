"""Rotations, skew matrices and rigid transforms: the one place frame algebra lives.

Conventions
-----------
* A rotation ``R`` of shape ``(3, 3)`` maps coordinates in a child frame to its parent frame:
  ``x_parent = R @ x_child + p``.
* URDF roll-pitch-yaw: ``R = Rz(yaw) @ Ry(pitch) @ Rx(roll)``.

All functions are pure, jit/vmap/grad friendly and work on the trailing dimensions only where stated.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

__all__ = [
    "sincos",
    "SINCOS_LIMIT",
    "skew",
    "unskew",
    "rot_x",
    "rot_y",
    "rot_z",
    "rpy_to_matrix",
    "unit_axis_rotations",
    "quaternion_to_matrix",
    "frame_from_points",
    "rotation_log",
]


# Cody-Waite reduction by pi/2: four parts of 26 significant bits (k * part exact for |k| < 2**27, with or without
# fused multiply-adds) and the remainder in full precision; then the classic minimax polynomials of sin and cos on
# [-pi/4, pi/4] (the coefficients of the freely distributed fdlibm kernels).
_PIO2 = (1.5707963407039642, -1.3909067675399456e-08, 6.123233932053594e-17, 6.368317178484799e-25,
         -1.4973849048591698e-33)
#: ``sincos`` covers ``|x| <= SINCOS_LIMIT`` (2**27 * pi/2, about 2.1e8 rad or 3.4e7 turns): beyond, the reduction
#: would no longer be exact and the result is NaN (no joint of a simulation that has not diverged gets there).
SINCOS_LIMIT = 2.0**27 * np.pi / 2
_SIN = (-1.66666666666666324348e-01, 8.33333333332248946124e-03, -1.98412698298579493134e-04,
        2.75573137070700676789e-06, -2.50507602534068634195e-08, 1.58969099521155010221e-10)
_COS = (4.16666666666666019037e-02, -1.38888888888741095749e-03, 2.48015872894767294178e-05,
        -2.75573143513906633035e-07, 2.08757232129817482790e-09, -1.13596475577881948265e-11)


def _horner(coeffs, z):
    out = coeffs[-1]
    for c in coeffs[-2::-1]:
        out = c + z * out
    return out


@jax.custom_jvp
def sincos(x: Float[ArrayLike, "..."]) -> tuple[Float[Array, "..."], Float[Array, "..."]]:
    """``(sin x, cos x)`` elementwise, within 2 ulp of the correctly rounded values for ``|x| <=``
    :data:`SINCOS_LIMIT` (about 2.1e8; NaN beyond, and for non-finite ``x``, as ``jnp.sin`` gives for the latter).

    XLA:CPU evaluates a float64 ``jnp.sin`` or ``jnp.cos`` by a scalar library call per element (about 14 ns each on
    this project's CI machine), while these few multiply-adds and selects vectorise with the surrounding fusion
    (about 3 ns for both): a batch of tree states spends a tenth of its time in its joint angles' sines and cosines
    otherwise. ``sin(-0.0)`` is ``-0.0``. Derivatives are exact: ``d sin = cos dx``, ``d cos = -sin dx``. Other
    dtypes than float64 use ``jnp.sin`` and ``jnp.cos``."""
    x = jnp.asarray(x)
    if x.dtype != jnp.float64:
        return jnp.sin(x), jnp.cos(x)  # the polynomials are float64's; other types keep XLA's own
    x = jnp.where(jnp.abs(x) <= SINCOS_LIMIT, x, jnp.nan)
    k = jnp.round(x * (2.0 / np.pi))
    r = x
    for part in _PIO2:
        r = r - k * part
    z = r * r
    s = r + r * z * _horner(_SIN, z)
    hz = 0.5 * z
    w = 1.0 - hz
    c = w + (((1.0 - w) - hz) + z * z * _horner(_COS, z))
    quadrant = k - 4.0 * jnp.floor(0.25 * k)  # 0, 1, 2, 3 (NaN for non-finite x: NaN results)
    odd = (quadrant == 1.0) | (quadrant == 3.0)
    s, c = jnp.where(odd, c, s), jnp.where(odd, s, c)
    s = jnp.where(quadrant >= 2.0, -s, s)
    return jnp.where(x == 0.0, x, s), jnp.where((quadrant == 1.0) | (quadrant == 2.0), -c, c)  # keeps sin(-0) = -0


@sincos.defjvp
def _sincos_jvp(primals, tangents):
    (x,), (dx,) = primals, tangents
    s, c = sincos(x)
    return (s, c), (c * dx, -s * dx)


def skew(v: Float[ArrayLike, "3"]) -> Float[Array, "3 3"]:
    """The cross-product matrix: ``skew(a) @ b == cross(a, b)``."""
    v = jnp.asarray(v)
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    o = jnp.zeros_like(x)
    return jnp.stack(
        [jnp.stack([o, -z, y], -1), jnp.stack([z, o, -x], -1), jnp.stack([-y, x, o], -1)], -2
    )


def unskew(m: Float[ArrayLike, "3 3"]) -> Float[Array, "3"]:
    """The vector of the skew-symmetric part of ``m`` (inverse of :func:`skew`)."""
    m = jnp.asarray(m)
    return 0.5 * jnp.stack(
        [m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]], -1
    )


def _rot(c, s, axis: int) -> Array:
    o, i = jnp.zeros_like(c), jnp.ones_like(c)
    if axis == 0:
        rows = [[i, o, o], [o, c, -s], [o, s, c]]
    elif axis == 1:
        rows = [[c, o, s], [o, i, o], [-s, o, c]]
    else:
        rows = [[c, -s, o], [s, c, o], [o, o, i]]
    return jnp.stack([jnp.stack(r, -1) for r in rows], -2)


def rot_x(angle: ArrayLike) -> Float[Array, "3 3"]:
    """Rotation by ``angle`` about x."""
    a = jnp.asarray(angle)
    return _rot(jnp.cos(a), jnp.sin(a), 0)


def rot_y(angle: ArrayLike) -> Float[Array, "3 3"]:
    """Rotation by ``angle`` about y."""
    a = jnp.asarray(angle)
    return _rot(jnp.cos(a), jnp.sin(a), 1)


def rot_z(angle: ArrayLike) -> Float[Array, "3 3"]:
    """Rotation by ``angle`` about z."""
    a = jnp.asarray(angle)
    return _rot(jnp.cos(a), jnp.sin(a), 2)


def rpy_to_matrix(rpy: Float[ArrayLike, "3"]) -> Float[Array, "3 3"]:
    """URDF roll-pitch-yaw to a rotation matrix, ``Rz(yaw) @ Ry(pitch) @ Rx(roll)``."""
    rpy = jnp.asarray(rpy)
    return rot_z(rpy[..., 2]) @ rot_y(rpy[..., 1]) @ rot_x(rpy[..., 0])


def unit_axis_rotations(axes: Float[ArrayLike, "n 3"], angles: Float[ArrayLike, " n"]) -> Float[Array, "n 3 3"]:
    """Rotations by ``angles[i]`` about the **unit** vectors ``axes[i]`` (Rodrigues: ``I + sin(t) K + (1 - cos(t))
    K^2`` with ``K^2 = a a^T - I`` written out; no matrix products: cheap under ``jit`` on CPU, where tiny ``dot``
    ops do not fuse). Smooth in the angle (no division), so gradients are finite at zero angle."""
    a = jnp.asarray(axes)
    sin, cos = (v[..., None, None] for v in sincos(jnp.asarray(angles)))
    outer = a[..., :, None] * a[..., None, :]
    eye = jnp.broadcast_to(jnp.eye(3), outer.shape)
    return cos * eye + sin * skew(a) + (1.0 - cos) * outer


def quaternion_to_matrix(quat: Float[ArrayLike, "4"]) -> Float[Array, "3 3"]:
    """Rotation of a quaternion ``[x, y, z, w]`` (Pinocchio's and ROS's order; MuJoCo's is ``[w, x, y, z]``),
    normalised here so a quaternion that drifted off the unit sphere still gives a rotation."""
    x, y, z, w = jnp.asarray(quat) / jnp.linalg.norm(quat)
    return jnp.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def frame_from_points(p0, p1, p2) -> Float[Array, "3 3"]:
    """An orthonormal right-handed frame (columns) built by Gram-Schmidt from three points.

    ``e1`` along ``p1 - p0``; ``e2`` the part of ``p2 - p0`` orthogonal to ``e1``; ``e3 = e1 x e2``.
    The points must not be collinear (the caller checks; this function does not divide by a guard).
    """
    a = p1 - p0
    e1 = a / jnp.linalg.norm(a)
    b = p2 - p0
    b = b - jnp.dot(b, e1) * e1
    e2 = b / jnp.linalg.norm(b)
    e3 = jnp.cross(e1, e2)
    return jnp.stack([e1, e2, e3], axis=-1)


def rotation_log(r: Float[ArrayLike, "3 3"]) -> Float[Array, "3"]:
    """The rotation vector ``theta * axis`` of a rotation matrix (the inverse of Rodrigues' formula), for rotations
    by less than pi; smooth at the identity (a series there), so its derivatives are finite everywhere in that range.
    """
    r = jnp.asarray(r)
    v = unskew(r)  # sin(theta) * axis
    c = 0.5 * (jnp.trace(r, axis1=-2, axis2=-1) - 1.0)  # cos(theta)
    s2 = jnp.sum(v * v, axis=-1)
    small = (s2 < 1e-8) & (c > 0.0)
    s = jnp.sqrt(jnp.where(small, 1.0, s2))
    f = jnp.where(small, 1.0 + s2 / 6.0 + 3.0 * s2 * s2 / 40.0, jnp.arctan2(s, c) / s)  # theta / sin(theta)
    return f[..., None] * v
