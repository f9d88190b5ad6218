"""Rigid-body inertia: validation, parallel-axis shifts and frame changes.

Two equivalent descriptions are used across the package:

* :class:`RigidInertia` — mass ``m``, centre of mass ``c`` and inertia tensor ``I_G`` *about the CoM*, all in the
  body frame.
* the 10-vector of the Krang report (Zafar §5.1), *about the frame origin*:
  ``[m, m cx, m cy, m cz, XX, XY, XZ, YY, YZ, ZZ]`` with ``J_O = I_G + m (|c|^2 E - c c^T)``.

The 10-vector has one codec, here, used by every module: :func:`pack_params` / :func:`unpack_params` (the layout:
``(m, m c, J_O)`` <-> ``(..., 10)``), :func:`origin_params` / :func:`com_params` (with the parallel-axis shift:
``(m, c, I_G)`` <-> 10-vector), :func:`sym_from_six` / :func:`six_from_sym` (a symmetric tensor <-> its six
entries ``XX, XY, XZ, YY, YZ, ZZ``, URDF's ``ixx ixy ixz iyy iyz izz`` order). They work on NumPy arrays in NumPy
(exact, for loaders and checks) and on anything else in JAX (traced, batched over leading axes).

The second moment (``S = sum m_i r_i r_i^T``) and the inertia tensor are related by ``I = tr(S) E - S`` and
``S = tr(I)/2 E - I``; equivalent-particle solves match ``S`` (Attia eqs. (3)–(8)).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ._namespace import xp_of
from .errors import InertiaError

__all__ = [
    "RigidInertia",
    "pack_params",
    "unpack_params",
    "origin_params",
    "com_params",
    "sym_from_six",
    "six_from_sym",
    "inertia_about_point",
    "inertia_about_com",
    "rotate_inertia",
    "second_moment_from_inertia",
    "inertia_from_second_moment",
    "check_inertia",
    "physical_inertia",
    "balance_inertia",
    "rotate_origin_params",
    "PHYSICAL_RTOL",
    "POINT_RADIUS",
]

#: Relative slack (w.r.t. the trace) allowed on triangle inequalities and on zero principal moments.
PHYSICAL_RTOL = 1e-9
#: Radius of gyration (m) below which a body counts as a point mass: the slack is taken relative to
#: ``max(trace, mass * POINT_RADIUS**2)``, so a rounded zero tensor (a -2e-35 principal moment) is not judged against
#: a zero trace.
POINT_RADIUS = 1e-6


def sym_from_six(six) -> Float[Array, "... 3 3"]:
    """``[XX, XY, XZ, YY, YZ, ZZ]`` (last axis) -> the symmetric ``(..., 3, 3)`` tensor."""
    xp = xp_of(six)
    six = xp.asarray(six)
    xx, xy, xz, yy, yz, zz = (six[..., k] for k in range(6))
    return xp.stack([xp.stack([xx, xy, xz], -1), xp.stack([xy, yy, yz], -1), xp.stack([xz, yz, zz], -1)], -2)


def six_from_sym(j) -> Float[Array, "... 6"]:
    """The six independent entries ``[XX, XY, XZ, YY, YZ, ZZ]`` of symmetric ``(..., 3, 3)`` tensors."""
    xp = xp_of(j)
    j = xp.asarray(j)
    return xp.stack([j[..., 0, 0], j[..., 0, 1], j[..., 0, 2], j[..., 1, 1], j[..., 1, 2], j[..., 2, 2]], -1)


def pack_params(mass, first_moment, j_origin) -> Float[Array, "... 10"]:
    """``(m (...), m c (..., 3), J_O (..., 3, 3))`` -> 10-vectors ``[m, m c, XX, XY, XZ, YY, YZ, ZZ]``."""
    xp = xp_of(mass, first_moment, j_origin)
    mass = xp.asarray(mass)
    return xp.concatenate([mass[..., None], xp.asarray(first_moment), six_from_sym(j_origin)], -1)


def unpack_params(params) -> tuple:
    """10-vectors ``(..., 10)`` -> ``(m (...), m c (..., 3), J_O (..., 3, 3))``, the inertia about the origin."""
    xp = xp_of(params)
    p = xp.asarray(params)
    return p[..., 0], p[..., 1:4], sym_from_six(p[..., 4:10])


def origin_params(mass, com, i_com) -> Float[Array, "... 10"]:
    """``(m, c, I_G)`` (one body, its frame) -> the 10-vector about the frame origin (parallel-axis shift)."""
    xp = xp_of(mass, com, i_com)
    c = xp.asarray(com)
    return pack_params(mass, mass * c, inertia_about_point(i_com, mass, c, xp.zeros(3)))


def com_params(params) -> tuple:
    """Inverse of :func:`origin_params` for one 10-vector with ``m != 0``: ``(m, c, I_G)``."""
    xp = xp_of(params)
    m, h, j = unpack_params(params)
    c = h / m
    return m, c, inertia_about_com(j, m, c, xp.zeros(3))


def inertia_about_point(i_com, mass, com, point) -> Float[Array, "3 3"]:
    """Parallel-axis theorem: inertia about ``point`` from the inertia about the CoM (same axes)."""
    xp = xp_of(i_com, mass, com, point)
    d = xp.asarray(com) - xp.asarray(point)
    return xp.asarray(i_com) + mass * (xp.dot(d, d) * xp.eye(3) - xp.outer(d, d))


def inertia_about_com(i_point, mass, com, point) -> Float[Array, "3 3"]:
    """Inverse parallel-axis shift: inertia about the CoM from the inertia about ``point``."""
    xp = xp_of(i_point, mass, com, point)
    d = xp.asarray(com) - xp.asarray(point)
    return xp.asarray(i_point) - mass * (xp.dot(d, d) * xp.eye(3) - xp.outer(d, d))


def rotate_inertia(inertia, rotation) -> Float[Array, "3 3"]:
    """Express a tensor given in frame b in frame a, with ``rotation = R_ab``: ``R I R^T``."""
    r = jnp.asarray(rotation)
    return r @ jnp.asarray(inertia) @ r.T


def second_moment_from_inertia(inertia) -> Float[Array, "3 3"]:
    """``S = tr(I)/2 E - I``, the second moment of mass ``sum m r r^T`` about the same point."""
    xp = xp_of(inertia)
    inertia = xp.asarray(inertia)
    return 0.5 * xp.trace(inertia) * xp.eye(3) - inertia


def inertia_from_second_moment(s) -> Float[Array, "3 3"]:
    """``I = tr(S) E - S``."""
    s = jnp.asarray(s)
    return jnp.trace(s) * jnp.eye(3) - s


def rotate_origin_params(params, rotation) -> Float[Array, "... 10"]:
    """Re-express origin 10-vectors ``[m, m c, XX, XY, XZ, YY, YZ, ZZ]`` (frame b) in frame a with the same origin,
    ``rotation = R_ab``: ``m c -> R m c``, ``J -> R J R^T``."""
    r = jnp.asarray(rotation)
    m, ms, j = unpack_params(jnp.asarray(params))
    return pack_params(m, (r @ ms[..., None])[..., 0], r @ j @ jnp.swapaxes(r, -1, -2))


def _is_concrete(*xs) -> bool:
    return not any(isinstance(x, jax.core.Tracer) for x in jax.tree_util.tree_leaves(xs))


def check_inertia(mass, com, inertia, name: str = "body", *, degenerate_ok: bool = False, atol: float = 0.0) -> None:
    """Raise :class:`InertiaError` naming ``name`` if ``(mass, com, inertia about CoM)`` is not physical.

    Conditions: finite numbers; shapes ``()``, ``(3,)``, ``(3, 3)``; ``mass > 0``; a symmetric tensor; principal
    moments ``> 0`` (``>= 0`` with ``degenerate_ok``, for rods and planar mass distributions); and the triangle
    inequalities ``I_k <= I_i + I_j`` between principal moments. Tolerances are :data:`PHYSICAL_RTOL` relative to
    the trace, plus ``atol`` (the rounding of a tensor recovered from other quantities). Does nothing for traced
    values (checks belong at model construction, outside ``jit``).
    """
    if not _is_concrete(mass, com, inertia):
        return
    m = np.asarray(mass, dtype=float)
    c = np.asarray(com, dtype=float)
    i = np.asarray(inertia, dtype=float)
    if m.shape != ():
        raise InertiaError(f"{name}: mass must be a scalar, got shape {m.shape}")
    if c.shape != (3,):
        raise InertiaError(f"{name}: centre of mass must have shape (3,), got {c.shape}")
    if i.shape != (3, 3):
        raise InertiaError(f"{name}: inertia tensor must have shape (3, 3), got {i.shape}")
    for label, x in (("mass", m), ("centre of mass", c), ("inertia tensor", i)):
        if not np.all(np.isfinite(x)):
            raise InertiaError(f"{name}: {label} contains NaN or inf: {x.tolist()}")
    if not m > 0:
        raise InertiaError(f"{name}: mass must be positive, got {float(m)!r}")
    scale = max(float(np.trace(i)), float(m) * POINT_RADIUS**2, np.finfo(float).tiny)
    if not np.allclose(i, i.T, rtol=0.0, atol=PHYSICAL_RTOL * scale):
        raise InertiaError(f"{name}: inertia tensor is not symmetric: {i.tolist()}")
    eig = np.linalg.eigvalsh(0.5 * (i + i.T))
    tol = PHYSICAL_RTOL * scale + float(atol)
    if degenerate_ok:
        if eig[0] < -tol:
            raise InertiaError(
                f"{name}: inertia tensor is not positive semi-definite (principal moments {eig.tolist()})"
            )
    elif not eig[0] > tol:
        raise InertiaError(f"{name}: inertia tensor is not positive definite (principal moments {eig.tolist()})")
    for k in range(3):
        others = eig.sum() - eig[k]
        if eig[k] > others + tol:
            raise InertiaError(
                f"{name}: principal moments {eig.tolist()} violate the triangle inequality "
                f"(I{k + 1} = {eig[k]:.6g} > sum of the other two = {others:.6g})"
            )


def physical_inertia(mass, inertia, atol=0.0) -> Array:
    """Whether ``(mass, inertia about the centre of mass)`` is physical by :func:`check_inertia`'s conditions with
    ``degenerate_ok`` and its tolerances (shapes ``(...)`` and ``(..., 3, 3)``; traceable, for run-time checks of
    values set under a trace; NumPy in, NumPy out): ``mass > 0``, a symmetric tensor, principal moments ``>= 0``
    meeting the triangle inequalities ``I_k <= I_i + I_j``, each within :data:`PHYSICAL_RTOL` of the tensor's scale
    plus ``atol`` (shape ``(...)``; the symmetry test without it, as there). False for non-finite values. (Its verdict
    only: no derivative passes through it.)"""
    xp = xp_of(mass, inertia, atol)
    cut = (lambda x: x) if xp is np else jax.lax.stop_gradient
    m, i, atol = (cut(xp.asarray(x, dtype=float)) for x in (mass, inertia, atol))
    tr = xp.trace(i, axis1=-2, axis2=-1)
    scale = xp.maximum(xp.maximum(tr, m * POINT_RADIUS**2), np.finfo(float).tiny)
    sym_tol = PHYSICAL_RTOL * scale
    tol = sym_tol + atol
    finite = xp.isfinite(m) & xp.all(xp.isfinite(i), axis=(-2, -1))
    sym = 0.5 * (i + xp.swapaxes(i, -1, -2))
    eig = xp.linalg.eigvalsh(xp.where(finite[..., None, None], sym, 0.0))  # ascending
    others = xp.sum(eig, axis=-1, keepdims=True) - eig
    symmetric = xp.all(xp.abs(i - xp.swapaxes(i, -1, -2)) <= sym_tol[..., None, None], axis=(-2, -1))
    return finite & (m > 0.0) & symmetric & (eig[..., 0] >= -tol) & xp.all(eig <= others + tol[..., None], axis=-1)


def balance_inertia(inertia) -> tuple[np.ndarray, bool]:
    """``(repaired tensor, changed)``: MuJoCo's ``balanceinertia`` repair of an inertia about the CoM.

    Negative principal moments are first clipped to zero; then, if the principal moments violate a triangle
    inequality ``I_k <= I_i + I_j`` (beyond :data:`PHYSICAL_RTOL`), all three are replaced by their mean (an
    isotropic tensor, as MuJoCo does). A physical tensor is returned unchanged.
    """
    i = 0.5 * (np.asarray(inertia, dtype=float) + np.asarray(inertia, dtype=float).T)
    eig, vec = np.linalg.eigh(i)
    clipped = np.maximum(eig, 0.0)
    tol = PHYSICAL_RTOL * max(float(clipped.sum()), np.finfo(float).tiny)
    if clipped[2] > clipped[0] + clipped[1] + tol:
        return np.eye(3) * clipped.mean(), True
    if np.any(eig < 0.0) and eig[0] < -tol:
        return vec @ np.diag(clipped) @ vec.T, True
    return np.asarray(inertia, dtype=float), False


class RigidInertia(eqx.Module):
    """Mass, centre of mass (body frame) and inertia tensor about the centre of mass (body axes).

    All three are ``jax.Array`` leaves, so ``jax.vmap``/``jax.grad`` over bodies work. Construction from concrete
    numbers validates (see :func:`check_inertia`); pass ``name`` to have errors name the body.
    """

    mass: Float[Array, ""]
    com: Float[Array, "3"]
    inertia: Float[Array, "3 3"]

    def __init__(self, mass: ArrayLike, com: ArrayLike, inertia: ArrayLike, *, name: str = "body",
                 degenerate_ok: bool = False):
        check_inertia(mass, com, inertia, name, degenerate_ok=degenerate_ok)
        self.mass = jnp.asarray(mass, dtype=float)
        self.com = jnp.asarray(com, dtype=float)
        self.inertia = jnp.asarray(inertia, dtype=float)

    @classmethod
    def from_principal(cls, mass, com, moments, products=(0.0, 0.0, 0.0), *, name="body", degenerate_ok=False):
        """From ``(Ixx, Iyy, Izz)`` and products ``(Iyz, Ixz, Ixy)`` about the CoM (Attia Table 1 order)."""
        ixx, iyy, izz = moments
        iyz, ixz, ixy = products
        i = [[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]]
        return cls(mass, com, i, name=name, degenerate_ok=degenerate_ok)

    @classmethod
    def slender_rod(cls, mass, p, q, *, com=None, moment=None, name="body"):
        """A slender rod from ``p`` to ``q`` (its frame's coordinates): all mass on the line, inertia ``moment``
        about every axis through the centre of mass perpendicular to the rod and none about the rod. Defaults: a
        uniform rod (``com`` the midpoint, ``moment = mass L^2 / 12``). It is what a rod particle set (two
        primaries on the line) represents exactly."""
        p, q = np.asarray(p, dtype=float), np.asarray(q, dtype=float)
        if p.shape != (3,) or q.shape != (3,) or not np.all(np.isfinite(np.r_[p, q])):
            raise InertiaError(f"{name}: rod end points must be 3 finite numbers each, got {p.tolist()}, {q.tolist()}")
        ell = float(np.linalg.norm(q - p))
        if ell == 0.0:
            raise InertiaError(f"{name}: rod end points coincide at {p.tolist()}")
        u = (q - p) / ell
        c = (p + q) / 2 if com is None else np.asarray(com, dtype=float)
        off = c - p - ((c - p) @ u) * u
        if c.shape != (3,) or not np.all(np.isfinite(c)) or np.linalg.norm(off) > 1e-9 * ell:
            raise InertiaError(f"{name}: a slender rod's centre of mass {np.asarray(com).tolist()} must lie on the "
                               f"line through {p.tolist()} and {q.tolist()}")
        j = float(mass) * ell**2 / 12 if moment is None else moment
        return cls(mass, c, j * (np.eye(3) - np.outer(u, u)), name=name, degenerate_ok=True)

    @classmethod
    def from_origin_params(cls, params: ArrayLike, *, name="body", degenerate_ok=False):
        """From ``[m, m cx, m cy, m cz, XX, XY, XZ, YY, YZ, ZZ]`` with the inertia about the frame origin."""
        p = jnp.asarray(params, dtype=float)
        if p.shape != (10,):
            raise InertiaError(f"{name}: origin parameters must have shape (10,), got {p.shape}")
        m, c, i_com = com_params(p)
        return cls(m, c, i_com, name=name, degenerate_ok=degenerate_ok)

    def about(self, point: ArrayLike) -> Float[Array, "3 3"]:
        """Inertia tensor about ``point`` (body axes)."""
        return inertia_about_point(self.inertia, self.mass, self.com, point)

    def to_origin_params(self) -> Float[Array, "10"]:
        """The report's 10-vector ``[m, m c, XX, XY, XZ, YY, YZ, ZZ]`` about the frame origin."""
        return origin_params(self.mass, self.com, self.inertia)

    def second_moment(self) -> Float[Array, "3 3"]:
        """``sum m r r^T`` about the body-frame origin."""
        return second_moment_from_inertia(self.about(jnp.zeros(3)))

    def transformed(self, rotation: ArrayLike, translation: ArrayLike) -> "RigidInertia":
        """The same body described in a frame a where the body frame b sits at pose ``(R_ab, p_ab)``."""
        r = jnp.asarray(rotation)
        return RigidInertia(self.mass, r @ self.com + jnp.asarray(translation), rotate_inertia(self.inertia, r),
                            degenerate_ok=True)

    def kinetic_energy(self, v_com: ArrayLike, omega: ArrayLike) -> Float[Array, ""]:
        """``1/2 m |v_G|^2 + 1/2 w^T I_G w`` with both vectors in body axes."""
        v = jnp.asarray(v_com)
        w = jnp.asarray(omega)
        return 0.5 * self.mass * jnp.dot(v, v) + 0.5 * w @ self.inertia @ w
