"""The recursive solve along a serial chain (Attia §2.4, eqs. (29)–(43)): O(N) instead of the dense O(N^3).

Along a serial chain each body *owns* the particles it does not share with its parent (for a spherical chain
the next joint particle and two off-axis particles; for a revolute chain the two particles of the next joint's
axis). Ordering the unknowns body by body — the owned accelerations and the multipliers of the body's own
distance constraints — makes the saddle-point system block-tridiagonal: a body's rows touch only its own and its
parent's particles. Eliminating from the tip, each body's block is replaced by its Schur complement,

    D~_j = D_j - U_j D~_{j+1}^{-1} U_j^T,     r~_j = r_j - U_j D~_{j+1}^{-1} r~_{j+1},

which is the tip-to-base recursion of Attia's moment equations (29)/(36) written for the particle unknowns: the
subchain beyond joint j enters body j's equations only through the particles it shares with it, as an effective
inertia and an effective force. A forward sweep from the base then gives every body's accelerations. Each step is
a small dense solve, so the cost grows linearly with the number of bodies; the sweeps are ``lax.scan`` loops, so
the compiled program does not grow with it either.

Scope: uniform serial chains (every body the same kind and the same sharing pattern: spherical or revolute
joints), fixed to the ground at the base, with gravity. Anything else uses the dense solve
(:func:`~particlesim.mechanism.accelerations`), against which this one is tested.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..errors import ModelError
from ..particles import primary_mass_matrix
from ._algebra import FULL
from .model import Mechanism

__all__ = ["ChainPlan", "chain_plan", "chain_accelerations", "chain_mass_blocks", "chain_project"]


class ChainPlan(eqx.Module):
    """Static description of a uniform serial chain (see :func:`chain_plan`)."""

    idx: tuple = eqx.field(static=True)  # (N, k) global particle index of every local slot
    shared: tuple = eqx.field(static=True)  # local slots shared with the parent (or the ground)
    owned: tuple = eqx.field(static=True)  # local slots owned by the body
    rows: tuple = eqx.field(static=True)  # local slot pairs of the body's distance constraints
    child_slots: tuple = eqx.field(static=True)  # positions in `owned` of the child's shared particles
    row_index: tuple = eqx.field(static=True)  # (N, R) index of each body row among the mechanism's dot rows


def chain_plan(mech: Mechanism) -> ChainPlan:
    """Recognise a uniform serial chain in ``mech`` (bodies in chain order) or raise :class:`ModelError`."""
    topo = mech.topo
    if len(topo.drive):
        raise ModelError("recursive chain solve: driving constraints need solve='dense'")
    if len(topo.linear) or topo.spring_names or topo.tyre_names or topo.rotational_names or mech.applied or \
            topo.bump_names or topo.bushing_names or topo.torsion_names or \
            len(topo.point_names) != topo.n_particles:
        raise ModelError("recursive chain solve: only bodies, shared particles and gravity are supported")
    if topo.least_squares:
        raise ModelError("recursive chain solve: least-squares multipliers (redundant rows or singular positions) "
                         "need solve='dense'")
    kinds = {len(p) for p in topo.body_particles}
    if len(kinds) != 1 or len(topo.body_particles) < 1:
        raise ModelError("recursive chain solve: every body must be of one kind")
    idx = [tuple(p) for p in topo.body_particles]
    ground = set(topo.ground)
    first = idx[0]
    shared = tuple(s for s, p in enumerate(first) if p in ground)
    owned = tuple(s for s in range(len(first)) if s not in shared)
    if not shared:
        raise ModelError("recursive chain solve: the base body must hold the ground")
    child_slots = None
    for j in range(len(idx)):
        if tuple(s for s in range(len(idx[j])) if (j == 0 and idx[j][s] in ground) or
                 (j > 0 and idx[j][s] in idx[j - 1])) != shared:
            raise ModelError(f"recursive chain solve: body '{topo.body_names[j]}' shares other slots with its "
                             "parent than the base body does with the ground")
        if any(idx[j][s] in ground for s in owned):
            raise ModelError(f"recursive chain solve: body '{topo.body_names[j]}' owns a ground particle")
        if j > 0:
            slots = tuple(owned.index(idx[j - 1].index(idx[j][s])) for s in shared)
            if child_slots is not None and slots != child_slots:
                raise ModelError("recursive chain solve: the joints are not uniform along the chain")
            child_slots = slots
    if child_slots is None:
        child_slots = tuple(range(len(shared)))
    rows = tuple((a, b) for a, b in _all_pairs(len(first)) if not (a in shared and b in shared))
    expected = {frozenset((idx[j][a], idx[j][b])) for j in range(len(idx)) for a, b in rows}
    d = topo.dot
    where = {frozenset((a, b)): k for k, (a, b, c, e) in enumerate(zip(d.a, d.b, d.c, d.d)) if (a, b) == (c, e)}
    if expected != set(where) or len(d) != len(expected):
        raise ModelError("recursive chain solve: the mechanism has constraints beyond its bodies' distances")
    row_index = tuple(tuple(where[frozenset((idx[j][a], idx[j][b]))] for a, b in rows) for j in range(len(idx)))
    return ChainPlan(idx=tuple(idx), shared=shared, owned=owned, rows=rows, child_slots=child_slots,
                     row_index=row_index)


def _all_pairs(k):
    return [(a, b) for a in range(k) for b in range(a + 1, k)]


def chain_mass_blocks(mech: Mechanism) -> Array:
    """Every body's mass matrix in its primaries, ``(N, k, k)`` (:func:`~particlesim.particles.primary_mass_matrix`)."""
    k = len(mech.topo.body_particles[0])
    return jax.vmap(primary_mass_matrix)(mech.body_mass, mech.body_com, mech.body_inertia,
                                         mech.body_primaries[:, :k])


class _System(eqx.Module):
    """The block-tridiagonal saddle-point system of a chain at one configuration."""

    dmat: Array  # (N, nb, nb) diagonal blocks: owned particles' mass and the body's rows
    umat: Array  # (N, nb, nb) coupling of block j with block j + 1
    d: Array  # (N, R, 3) row vectors r_a - r_b


def _system(mech: Mechanism, plan: ChainPlan, mb: Array, q) -> _System:
    idx = np.asarray(plan.idx)  # (N, k)
    n_bodies = idx.shape[0]
    sh, ow = np.asarray(plan.shared), np.asarray(plan.owned)
    no, ns, nr = len(ow), len(sh), len(plan.rows)
    r = mech.all_positions(q)[idx]  # (N, k, 3)
    eye3 = jnp.eye(3, dtype=q.dtype)
    ra, rb = np.asarray([p[0] for p in plan.rows]), np.asarray([p[1] for p in plan.rows])
    d = r[:, ra] - r[:, rb]  # (N, R, 3)
    # Row Jacobians w.r.t. the local slots: (N, R, k, 3).
    jac = jnp.zeros((n_bodies, nr, idx.shape[1], 3), dtype=q.dtype)
    jac = jac.at[:, np.arange(nr), ra].add(d).at[:, np.arange(nr), rb].add(-d)
    g_own = jac[:, :, ow].reshape(n_bodies, nr, 3 * no)
    h_sh = jac[:, :, sh].reshape(n_bodies, nr, 3 * ns)
    m_oo = jnp.einsum("bij,kl->bikjl", mb[:, ow][:, :, ow], eye3).reshape(n_bodies, 3 * no, 3 * no)
    m_ss = jnp.einsum("bij,kl->bikjl", mb[:, sh][:, :, sh], eye3).reshape(n_bodies, 3 * ns, 3 * ns)
    m_so = jnp.einsum("bij,kl->bikjl", mb[:, sh][:, :, ow], eye3).reshape(n_bodies, 3 * ns, 3 * no)
    emb = _embedding(plan)
    c_mss, c_mso, c_h = _child(m_ss), _child(m_so), _child(h_sh)
    nb = 3 * no + nr
    mass_diag = m_oo + jnp.einsum("ij,bjk,lk->bil", emb, c_mss, emb)
    dmat = jnp.zeros((n_bodies, nb, nb), dtype=q.dtype)
    dmat = dmat.at[:, :3 * no, :3 * no].set(mass_diag)
    dmat = dmat.at[:, :3 * no, 3 * no:].set(jnp.swapaxes(g_own, 1, 2))
    dmat = dmat.at[:, 3 * no:, :3 * no].set(g_own)
    umat = jnp.zeros((n_bodies, nb, nb), dtype=q.dtype)
    umat = umat.at[:, :3 * no, :3 * no].set(jnp.einsum("ij,bjk->bik", emb, c_mso))
    umat = umat.at[:, :3 * no, 3 * no:].set(jnp.einsum("ij,bkj->bik", emb, c_h))
    return _System(dmat, umat, d)


def _embedding(plan: ChainPlan) -> np.ndarray:
    """Embedding of a child's shared coordinates into the parent's owned coordinates."""
    no, ns = len(plan.owned), len(plan.shared)
    emb = np.zeros((3 * no, 3 * ns))
    for s, o in enumerate(plan.child_slots):
        emb[3 * o:3 * o + 3, 3 * s:3 * s + 3] = np.eye(3)
    return emb


def _child(a: Array) -> Array:
    """Row j holds body j + 1's entry (the tip's child: zeros)."""
    return jnp.concatenate([a[1:], jnp.zeros_like(a[:1])], axis=0)


def _factor(sys: _System) -> Array:
    """Tip-to-base Schur complements ``D~_j = D_j - U_j D~_{j+1}^-1 U_j^T``; returns their inverses (N, nb, nb)."""

    def backward(dinv_next, inp):
        d_j, u_j = inp
        dinv = jnp.linalg.inv(d_j - u_j @ dinv_next @ u_j.T)
        return dinv, dinv

    nb = sys.dmat.shape[1]
    _, dinv = jax.lax.scan(backward, jnp.zeros((nb, nb), dtype=sys.dmat.dtype), (sys.dmat, sys.umat), reverse=True)
    return dinv


def _solve(sys: _System, dinv: Array, rhs: Array) -> Array:
    """Solve the block-tridiagonal system with the factor of :func:`_factor`: a tip-to-base sweep of the right-hand
    side, then a base-to-tip sweep of the unknowns. ``rhs`` and the result are (N, nb)."""
    dinv_next = _child(dinv)

    def backward(r_next, inp):
        r_j, u_j, dn = inp
        r_t = r_j - u_j @ (dn @ r_next)
        return r_t, r_t

    _, r_til = jax.lax.scan(backward, jnp.zeros_like(rhs[0]), (rhs, sys.umat, dinv_next), reverse=True)
    u_prev = jnp.concatenate([jnp.zeros_like(sys.umat[:1]), sys.umat[:-1]], axis=0)

    def forward(z_prev, inp):
        d_i, r_t, u_p = inp
        z = d_i @ (r_t - u_p.T @ z_prev)
        return z, z

    _, z = jax.lax.scan(forward, jnp.zeros_like(rhs[0]), (dinv, r_til, u_prev))
    return z


def _owned_to_free(mech: Mechanism, plan: ChainPlan, owned: Array) -> Array:
    idx = np.asarray(plan.idx)
    out = jnp.zeros((mech.topo.n_particles, 3), dtype=owned.dtype).at[idx[:, np.asarray(plan.owned)]].set(owned)
    return out[np.asarray(mech.free)].reshape(-1)


def _velocities(mech: Mechanism, plan: ChainPlan, qd) -> Array:
    free_mask = np.zeros(mech.topo.n_particles)
    free_mask[np.asarray(mech.free)] = 1.0
    return (mech.all_positions(qd) * free_mask[:, None])[np.asarray(plan.idx)]  # (N, k, 3)


def _row_pairs(plan: ChainPlan):
    return np.asarray([p[0] for p in plan.rows]), np.asarray([p[1] for p in plan.rows])


def chain_accelerations(mech: Mechanism, plan: ChainPlan, t, q: Float[Array, " 3F"],
                        qd: Float[Array, " 3F"], *, mass_blocks: Array | None = None) -> Float[Array, " 3F"]:
    """Particle accelerations by the tip-to-base elimination; equal to the dense solve (tested). ``mass_blocks``
    from :func:`chain_mass_blocks` (computed here if not given)."""
    del t
    n_bodies = len(plan.idx)
    sh, ow = np.asarray(plan.shared), np.asarray(plan.owned)
    no, ns = len(ow), len(sh)
    mb = chain_mass_blocks(mech) if mass_blocks is None else mass_blocks  # (N, k, k)
    sys = _system(mech, plan, mb, q)
    v = _velocities(mech, plan, qd)
    ra, rb = _row_pairs(plan)
    gamma = -jnp.sum((v[:, ra] - v[:, rb]) ** 2, axis=-1)  # (N, R)
    lumped = jnp.sum(mb, axis=2)  # (N, k): each body's share of its particles' weight
    grav_own = lumped[:, ow, None] * mech.gravity[None, None, :]  # (N, O, 3)
    grav_sh = _child(lumped[:, sh, None] * mech.gravity[None, None, :])  # (N, S, 3)
    rhs = jnp.concatenate([(grav_own.reshape(n_bodies, 3 * no)
                            + jnp.einsum("ij,bj->bi", _embedding(plan), grav_sh.reshape(n_bodies, 3 * ns))),
                           gamma], axis=1)
    z = _solve(sys, _factor(sys), rhs)
    return _owned_to_free(mech, plan, z[:, :3 * no].reshape(n_bodies, no, 3))


def chain_project(mech: Mechanism, plan: ChainPlan, q, qd, *, mass_blocks: Array | None = None,
                  passes: tuple[int, int] = FULL):
    """The mass-orthogonal projection of :mod:`.integrate` along the chain: ``[[M, J^T], [J, 0]] [dx; mu] =
    [0; -Phi]`` solved with one block factorisation (O(N)), ``passes[0]`` position passes, then ``passes[1]``
    velocity passes (two of each reach round-off; between a rollout's steps one of each,
    :data:`~._algebra.BETWEEN_STEPS`)."""
    n_bodies = len(plan.idx)
    no = len(plan.owned)
    mb = chain_mass_blocks(mech) if mass_blocks is None else mass_blocks
    sys = _system(mech, plan, mb, q)
    dinv = _factor(sys)
    ra, rb = _row_pairs(plan)
    kappa = mech.dot_kappa[np.asarray(plan.row_index)]  # (N, R)
    zeros = jnp.zeros((n_bodies, 3 * no), dtype=q.dtype)

    def correction(row_rhs):
        z = _solve(sys, dinv, jnp.concatenate([zeros, row_rhs], axis=1))
        return _owned_to_free(mech, plan, z[:, :3 * no].reshape(n_bodies, no, 3))

    d = sys.d
    for _ in range(passes[0]):
        phi = 0.5 * jnp.sum(d * d, axis=-1) - kappa
        q = q + correction(-phi)
        r = mech.all_positions(q)[np.asarray(plan.idx)]
        d = r[:, ra] - r[:, rb]
    for _ in range(passes[1]):
        v = _velocities(mech, plan, qd)
        qd = qd + correction(-jnp.sum(d * (v[:, ra] - v[:, rb]), axis=-1))
    return q, qd
