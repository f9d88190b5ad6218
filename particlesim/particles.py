"""Dynamically equivalent particle systems (Attia §2.1, eqs. (1)–(8)).

A rigid body is replaced by point masses that have its mass, centre of mass and inertia tensor. ``k`` *primary*
particles are placed freely in the body frame; one *secondary* particle sits at the midpoint of every pair:

=========  ===  =========  =======================================================================
kind        k    particles  represents
=========  ===  =========  =======================================================================
spatial     4   4 + 6      any rigid body (10 conditions, 10 masses)
planar      3   3 + 3      a body whose mass lies in the plane of the primaries (6 conditions)
rod         2   2 + 1      a body whose mass lies on the line of the primaries (3 conditions)
=========  ===  =========  =======================================================================

The mass solve
--------------
The ``k + k(k-1)/2`` particles are exactly the nodes of the quadratic Lagrange element on the simplex spanned by
the primaries (tetrahedron, triangle, segment). Matching mass, first and second moments means integrating every
quadratic polynomial exactly, so each particle mass is the integral of its nodal basis function over the body:

    m_i  = sum over the body of  lambda_i (2 lambda_i - 1)  dm  = 2 L_ii - mu_i         (primary i)
    m_ij = sum over the body of  4 lambda_i lambda_j         dm  = 4 L_ij              (secondary between i, j)

with ``lambda`` the barycentric coordinates of the simplex, ``mu = int lambda dm`` and ``L = int lambda lambda^T dm``.
Both follow linearly from ``(m, m c, S)`` (``S`` the second moment, :func:`second_moment_from_inertia`), so this is
the unique solution of the 10x10 linear system (1)–(8), in closed form, smooth in the inertia and the placement.
It exists iff the primaries span a simplex (not coplanar / collinear / coincident).

Secondary-particle order follows Attia: ``(1,2), (1,3), (2,3), (1,4), (2,4), (3,4)``, i.e. ``m5 .. m10``.
"""

from __future__ import annotations

import warnings
from typing import Literal

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .errors import NegativeMassWarning, PlacementError
from ._namespace import xp_of
from .inertia import RigidInertia, check_inertia, inertia_about_point, second_moment_from_inertia
from .spatial import frame_from_points

__all__ = [
    "ParticleSet",
    "PAIRS",
    "N_PRIMARY",
    "solve_particle_masses",
    "primary_mass_matrix",
    "equivalent_particles",
    "particle_positions",
    "pose_from_primaries",
    "positions_from_pose",
    "check_placement",
    "balanced_primaries",
    "PLACEMENT_RTOL",
    "NEGATIVE_MASS_RTOL",
    "REPRESENTABLE_RTOL",
]

Kind = Literal["spatial", "planar", "rod"]

N_PRIMARY: dict[str, int] = {"spatial": 4, "planar": 3, "rod": 2}

#: Primary-index pairs of the secondary particles, in Attia's numbering order.
PAIRS: dict[str, tuple[tuple[int, int], ...]] = {
    "spatial": ((0, 1), (0, 2), (1, 2), (0, 3), (1, 3), (2, 3)),
    "planar": ((0, 1), (0, 2), (1, 2)),
    "rod": ((0, 1),),
}

#: A placement is refused as singular when the smallest singular value of its edge vectors falls below this
#: fraction of the largest (or two primaries are closer than this fraction of the placement's size). With
#: ``kappa`` the ratio largest/smallest, the particle masses grow like ``kappa**2`` and the mass, first moment and
#: inertia are reproduced to about ``kappa**2 * eps`` relative (measured in ``tests/hard_cases/test_stiff_and_singular.py``): 1e-5
#: keeps that error below ~2e-6, where 1e-8 let through placements whose moments were wrong by 15 %.
PLACEMENT_RTOL = 1e-5
#: Particle masses below ``-NEGATIVE_MASS_RTOL * m`` count as negative (smaller ones are round-off).
NEGATIVE_MASS_RTOL = 1e-8
#: A planar/rod set refuses a body whose mass leaves its plane/line by more than this (relative to the body's
#: second moment about the first primary).
REPRESENTABLE_RTOL = 1e-9

_DIM = {"spatial": "a tetrahedron (4 non-coplanar points)", "planar": "a triangle (3 non-collinear points)",
        "rod": "a segment (2 distinct points)"}


def _kind_of(primaries: ArrayLike) -> str:
    k = np.shape(primaries)[0]
    for kind, n in N_PRIMARY.items():
        if n == k:
            return kind
    raise PlacementError(f"primary particles must number 4 (spatial), 3 (planar) or 2 (rod); got {k}")


def check_placement(primaries: ArrayLike, name: str = "body") -> str:
    """Validate a placement of primary particles and return its kind; :class:`PlacementError` names ``name``.

    Refused: wrong shape, NaN/inf, two coincident primaries, coplanar (spatial) or collinear (planar) primaries.
    """
    p = np.asarray(primaries, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3:
        raise PlacementError(f"{name}: primary particle positions must have shape (k, 3), got {p.shape}")
    kind = _kind_of(p)
    if not np.all(np.isfinite(p)):
        raise PlacementError(f"{name}: primary particle positions contain NaN or inf")
    edges = p[1:] - p[0]
    size = max(np.max(np.linalg.norm(p[:, None] - p[None], axis=-1)), np.finfo(float).tiny)
    for i in range(len(p)):
        for j in range(i + 1, len(p)):
            if np.linalg.norm(p[i] - p[j]) <= PLACEMENT_RTOL * size or size == np.finfo(float).tiny:
                raise PlacementError(f"{name}: primary particles {i + 1} and {j + 1} coincide at {p[i].tolist()}")
    sv = np.linalg.svd(edges, compute_uv=False)
    if sv[-1] <= PLACEMENT_RTOL * sv[0]:
        what = {"spatial": "coplanar", "planar": "collinear", "rod": "coincident"}[kind]
        raise PlacementError(
            f"{name}: the {N_PRIMARY[kind]} primary particles are {what} or nearly so (singular values of the edge "
            f"vectors {sv.tolist()}, ratio {sv[-1] / sv[0]:.3g} <= PLACEMENT_RTOL = {PLACEMENT_RTOL:g}); a {kind} "
            f"particle set needs {_DIM[kind]}"
        )
    return kind


def _barycentric_moments(mass, com, s_origin, primaries):
    """``mu = int lambda dm`` (k,) and ``L = int lambda lambda^T dm`` (k, k), plus the out-of-span residuals (NumPy
    for NumPy inputs, as when a mechanism is built; JAX otherwise)."""
    xp = xp_of(mass, com, s_origin, primaries)
    r1 = primaries[0]
    e = (primaries[1:] - r1[None, :]).T  # (3, k-1) edge vectors
    # Moments about the first primary.
    d = com - r1
    s1 = s_origin - mass * (xp.outer(com, r1) + xp.outer(r1, com)) + mass * xp.outer(r1, r1)
    # Least-squares coordinates beta of a point along the edges (exact when the point lies in their span).
    gram = e.T @ e
    e_pinv = xp.linalg.solve(gram, e.T)  # (k-1, 3)
    beta_first = e_pinv @ (mass * d)  # int beta dm
    beta_second = e_pinv @ s1 @ e_pinv.T  # int beta beta^T dm
    # lambda = P (1, beta) with P = [[1, -1^T], [0, I]]
    k = primaries.shape[0]
    p = xp.concatenate([xp.concatenate([xp.ones((1,)), -xp.ones((k - 1,))])[None, :],
                         xp.concatenate([xp.zeros((k - 1, 1)), xp.eye(k - 1)], axis=1)], axis=0)
    mom = xp.block([[mass[None, None], beta_first[None, :]], [beta_first[:, None], beta_second]])
    big_l = p @ mom @ p.T
    mu = p @ xp.concatenate([mass[None], beta_first])
    # Residual of the part of the mass distribution outside span(e) (zero for a spatial set).
    proj = xp.eye(3) - e @ e_pinv
    res_first = proj @ (mass * d)
    res_second = proj @ s1
    return mu, big_l, res_first, res_second, s1


def solve_particle_masses(mass: ArrayLike, com: ArrayLike, inertia_com: ArrayLike,
                          primaries: Float[ArrayLike, "k 3"]) -> Float[Array, "n"]:
    """Masses ``(k + k(k-1)/2,)`` of the equivalent particles: primaries first, then secondaries in :data:`PAIRS`.

    Pure and differentiable in all arguments (``inertia_com`` about the CoM, body axes; positions in the body
    frame). Solves Attia eqs. (1)–(8) in closed form (see module docstring). No validation: see
    :func:`equivalent_particles` for the checked entry point.
    """
    xp = xp_of(mass, com, inertia_com, primaries)
    mass = xp.asarray(mass, dtype=float)
    com = xp.asarray(com, dtype=float)
    primaries = xp.asarray(primaries, dtype=float)
    kind = _kind_of(primaries)
    s_origin = second_moment_from_inertia(inertia_about_point(xp.asarray(inertia_com, dtype=float), mass, com,
                                                              xp.zeros(3)))
    mu, big_l, _, _, _ = _barycentric_moments(mass, com, s_origin, primaries)
    prim = 2.0 * xp.diagonal(big_l) - mu
    sec = xp.stack([4.0 * big_l[i, j] for i, j in PAIRS[kind]])
    return xp.concatenate([prim, sec])


def primary_mass_matrix(mass: ArrayLike, com: ArrayLike, inertia_com: ArrayLike,
                        primaries: Float[ArrayLike, "k 3"]) -> Float[Array, "k k"]:
    """The body's scalar mass matrix in its primary particles, ``L = int lambda lambda^T dm`` (``k x k``).

    With the secondaries eliminated (Attia eqs. (23)–(27)) the body's kinetic energy is ``1/2 sum_ij L_ij
    v_i . v_j`` over its primaries: ``L = B^T diag(m) B`` for the particle masses ``m`` of
    :func:`solve_particle_masses` and ``B`` the midpoint incidence, computed here directly. ``L`` is a Gram matrix
    of the mass distribution, so it is positive semi-definite whatever the signs of the particle masses.
    """
    mass = jnp.asarray(mass, dtype=float)
    com = jnp.asarray(com, dtype=float)
    primaries = jnp.asarray(primaries, dtype=float)
    s_origin = second_moment_from_inertia(inertia_about_point(inertia_com, mass, com, jnp.zeros(3)))
    return _barycentric_moments(mass, com, s_origin, primaries)[1]


def particle_positions(primaries: Float[ArrayLike, "k 3"]) -> Float[Array, "n 3"]:
    """All particle positions: the primaries, then the midpoints of :data:`PAIRS` (Attia eqs. (17)–(22))."""
    p = jnp.asarray(primaries)
    kind = _kind_of(p)
    mids = jnp.stack([0.5 * (p[i] + p[j]) for i, j in PAIRS[kind]])
    return jnp.concatenate([p, mids], axis=0)


class ParticleSet(eqx.Module):
    """An equivalent particle system of one body, in the body frame.

    ``primaries`` ``(k, 3)`` and ``masses`` ``(n,)`` are ``jax.Array`` leaves; ``kind`` and ``name`` are static.
    """

    primaries: Float[Array, "k 3"]
    masses: Float[Array, "n"]
    kind: str = eqx.field(static=True)
    name: str = eqx.field(static=True, default="body")

    @property
    def positions(self) -> Float[Array, "n 3"]:
        """Body-frame positions of all particles (primaries, then secondaries)."""
        return particle_positions(self.primaries)

    @property
    def pairs(self) -> tuple[tuple[int, int], ...]:
        return PAIRS[self.kind]

    def reduced_masses(self) -> tuple[Float[Array, "k"], Float[Array, "k"]]:
        """Attia eqs. (25) and (27): ``m_bar_i = m_i + 1/2 sum_j m_ij`` and ``m_bbar_i = m_i + 1/4 sum_j m_ij``.

        ``m_bar`` carries the linear momentum once the secondaries are eliminated; ``m_bbar`` enters the
        moment coefficients ``A_i`` of eq. (26).
        """
        k = self.primaries.shape[0]
        incidence = np.zeros((k, len(self.pairs)))
        for col, (i, j) in enumerate(self.pairs):
            incidence[i, col] = incidence[j, col] = 1.0
        sec = self.masses[k:]
        prim = self.masses[:k]
        return prim + 0.5 * (incidence @ sec), prim + 0.25 * (incidence @ sec)

    def total_mass(self) -> Float[Array, ""]:
        return jnp.sum(self.masses)

    def first_moment(self) -> Float[Array, "3"]:
        """``sum m_i r_i`` in the body frame (equals ``m c``)."""
        return self.masses @ self.positions

    def inertia_about_origin(self) -> Float[Array, "3 3"]:
        """``sum m_i (|r_i|^2 E - r_i r_i^T)`` about the body-frame origin (Attia eqs. (3)–(8))."""
        r = self.positions
        s = jnp.einsum("i,ij,ik->jk", self.masses, r, r)
        return jnp.trace(s) * jnp.eye(3) - s

    def world_positions(self, rotation: ArrayLike, origin: ArrayLike) -> Float[Array, "n 3"]:
        """Positions of all particles for a body at pose ``(R, p)``: ``p + R r_i``."""
        return positions_from_pose(self.positions, rotation, origin)


def equivalent_particles(body: RigidInertia, primaries: Float[ArrayLike, "k 3"], *, name: str = "body",
                         on_negative: Literal["warn", "raise", "ignore"] = "warn") -> ParticleSet:
    """Build the checked equivalent particle set of ``body`` with primaries at ``primaries`` (body frame).

    The kind follows from the number of primaries (4 spatial, 3 planar, 2 rod). Raises
    :class:`~particlesim.errors.PlacementError` naming ``name`` for a singular placement, or for a planar/rod set
    whose plane/line does not contain the body's mass (a non-planar inertia, a CoM off the plane, ...). Negative
    particle masses keep the dynamics exact but lose physical consistency; ``on_negative`` chooses to warn
    (:class:`~particlesim.errors.NegativeMassWarning`), raise, or ignore. Validation runs on concrete values only;
    under ``jit`` use :func:`solve_particle_masses`.
    """
    if on_negative not in ("warn", "raise", "ignore"):
        raise ValueError(f"on_negative must be 'warn', 'raise' or 'ignore', got {on_negative!r}")
    kind = check_placement(primaries, name)
    check_inertia(body.mass, body.com, body.inertia, name, degenerate_ok=kind != "spatial")
    # concrete values: the checks and the solve run in NumPy (eager JAX would compile every operation once)
    mass, com, i_com = (np.asarray(v, dtype=float) for v in (body.mass, body.com, body.inertia))
    prim = np.asarray(primaries, dtype=float)
    if kind != "spatial":
        s_origin = second_moment_from_inertia(inertia_about_point(i_com, mass, com, np.zeros(3)))
        _, _, res_first, res_second, s1 = _barycentric_moments(mass, com, s_origin, prim)
        scale_second = float(np.trace(s1))
        scale_first = float(mass * np.max(np.linalg.norm(prim - prim[0][None, :], axis=-1)))
        off_first = float(np.linalg.norm(res_first))
        off_second = float(np.max(np.abs(res_second)))
        where = "plane" if kind == "planar" else "line"
        if off_first > REPRESENTABLE_RTOL * scale_first:
            raise PlacementError(
                f"{name}: a {kind} particle set cannot represent this body: its centre of mass "
                f"{com.tolist()} (body frame) lies {off_first / float(mass):.3g} m off the "
                f"{where} of the primaries {prim.round(12).tolist()} (body frame); place the primaries "
                f"so that their {where} contains the centre of mass")
        if off_second > REPRESENTABLE_RTOL * scale_second:
            need = ("the perpendicular-axis theorem I_n = I_a + I_b about the plane normal"
                    if kind == "planar" else "zero inertia about the rod axis and equal transverse moments")
            raise PlacementError(
                f"{name}: a {kind} particle set cannot represent this body: its mass extends out of the {where} of "
                f"the primaries (out-of-{where} second moment {off_second:.3g} kg m^2; a {kind} body needs {need})")
    masses = solve_particle_masses(mass, com, i_com, prim)
    neg = np.flatnonzero(np.asarray(masses) < -NEGATIVE_MASS_RTOL * float(body.mass))
    if neg.size and on_negative != "ignore":
        msg = (f"{name}: equivalent particles {[int(i) + 1 for i in neg]} have negative masses "
               f"{np.asarray(masses)[neg].round(6).tolist()} kg; the dynamics stay exact but the particle system is "
               "not physically consistent. To avoid it, place the primaries farther apart along the body's "
               "principal axes through its centre of mass, or pass on_negative='ignore' if only the motion matters")
        if on_negative == "raise":
            raise PlacementError(msg)
        warnings.warn(msg, NegativeMassWarning, stacklevel=2)
    return ParticleSet(primaries=jnp.asarray(prim), masses=jnp.asarray(masses), kind=kind, name=name)


def positions_from_pose(body_positions: Float[ArrayLike, "n 3"], rotation: ArrayLike,
                        origin: ArrayLike) -> Float[Array, "n 3"]:
    """World positions ``p + R r`` of body-frame points ``r`` (row-wise)."""
    return jnp.asarray(body_positions) @ jnp.asarray(rotation).T + jnp.asarray(origin)[None, :]


def pose_from_primaries(body_primaries: Float[ArrayLike, "k 3"],
                        world_primaries: Float[ArrayLike, "k 3"]) -> tuple[Float[Array, "3 3"], Float[Array, "3"]]:
    """Recover the body pose ``(R, p)`` with ``world = p + R body`` from (at least three) primary particles.

    Builds the Gram–Schmidt frame of the first three primaries in both frames (:func:`~particlesim.spatial.frame_from_points`),
    so ``R`` is exactly orthonormal and smooth in the positions. Exact for rigidly placed particles. A rod (two
    primaries) fixes no spin about its axis: refused with a :class:`PlacementError`.
    """
    b = jnp.asarray(body_primaries, dtype=float)
    w = jnp.asarray(world_primaries, dtype=float)
    if b.shape != w.shape or b.ndim != 2 or b.shape[1] != 3:
        raise PlacementError(f"body and world primaries must have equal shapes (k, 3); got {b.shape} and {w.shape}")
    if b.shape[0] < 3:
        raise PlacementError("a rod's two particles do not fix its rotation about its own axis: no unique pose")
    f_b = frame_from_points(b[0], b[1], b[2])
    f_w = frame_from_points(w[0], w[1], w[2])
    rot = f_w @ f_b.T
    return rot, w[0] - rot @ b[0]




# Scale of the regular simplex (unit circumradius) in units of the body's radii of gyration that makes every
# particle mass equal: 10 x m/10 (spatial), 6 x m/6 (planar), 3 x m/3 (rod). Derived from the nodal-mass formula
# with barycentric coordinates of a regular simplex; checked in the tests.
_BALANCED_SCALE2 = {"spatial": 5.0, "planar": 16.0 / 5.0, "rod": 1.5}


def _regular_simplex(kind: str) -> np.ndarray:
    if kind == "spatial":
        v = np.array([[1, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]], dtype=float)
        return v / np.sqrt(3.0)
    if kind == "planar":
        a = 2 * np.pi * np.arange(3) / 3
        return np.stack([np.cos(a), np.sin(a)], axis=1)
    return np.array([[-1.0], [1.0]])


def balanced_primaries(body: RigidInertia, kind: Kind = "spatial", *, name: str = "body") -> np.ndarray:
    """Primary positions (body frame) that give every equivalent particle the same positive mass.

    A regular simplex stretched along the body's principal axes by ``sqrt(scale) * radius of gyration``
    (``scale`` 5 spatial, 16/5 planar, 3/2 rod), centred on the CoM. Useful for free bodies whose joints do not
    pin the particles down; a planar/rod kind needs a planar/line mass distribution (refused otherwise).
    """
    check_inertia(body.mass, body.com, body.inertia, name, degenerate_ok=kind != "spatial")
    m = float(body.mass)
    sigma = np.asarray(second_moment_from_inertia(body.inertia)) / m  # about the CoM, per unit mass
    w, u = np.linalg.eigh(sigma)
    w, u = w[::-1], u[:, ::-1]  # largest first
    dim = {"spatial": 3, "planar": 2, "rod": 1}[kind]
    if dim < 3 and np.any(np.abs(w[dim:]) > REPRESENTABLE_RTOL * max(w[0], np.finfo(float).tiny)):
        raise PlacementError(f"{name}: a {kind} particle set cannot represent this body: its mass extends over "
                             f"{int(np.sum(w > REPRESENTABLE_RTOL * w[0]))} dimensions (second moments {w.tolist()})")
    stretch = u[:, :dim] * np.sqrt(np.clip(w[:dim], 0.0, None) * _BALANCED_SCALE2[kind])
    return np.asarray(body.com) + _regular_simplex(kind) @ stretch.T
