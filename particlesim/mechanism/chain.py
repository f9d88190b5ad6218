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
from ..particles import PAIRS, solve_particle_masses
from .model import Mechanism

__all__ = ["ChainPlan", "chain_plan", "chain_accelerations"]


class ChainPlan(eqx.Module):
    """Static description of a uniform serial chain (see :func:`chain_plan`)."""

    idx: tuple = eqx.field(static=True)  # (N, k) global particle index of every local slot
    shared: tuple = eqx.field(static=True)  # local slots shared with the parent (or the ground)
    owned: tuple = eqx.field(static=True)  # local slots owned by the body
    rows: tuple = eqx.field(static=True)  # local slot pairs of the body's distance constraints
    child_slots: tuple = eqx.field(static=True)  # positions in `owned` of the child's shared particles


def chain_plan(mech: Mechanism) -> ChainPlan:
    """Recognise a uniform serial chain in ``mech`` (bodies in chain order) or raise :class:`ModelError`."""
    if mech.coincide_pairs or mech.generic or mech.springs or mech.tyres or mech.applied:
        raise ModelError("recursive chain solve: only bodies, shared particles and gravity are supported")
    kinds = {b.kind for b in mech.bodies}
    if len(kinds) != 1 or len(mech.bodies) < 1:
        raise ModelError("recursive chain solve: every body must be of one kind")
    idx = [tuple(b.primaries) for b in mech.bodies]
    ground = set(mech.ground)
    first = idx[0]
    shared = tuple(s for s, p in enumerate(first) if p in ground)
    owned = tuple(s for s in range(len(first)) if s not in shared)
    if not shared:
        raise ModelError("recursive chain solve: the base body must hold the ground")
    child_slots = None
    for j in range(len(idx)):
        if tuple(s for s in range(len(idx[j])) if (j == 0 and idx[j][s] in ground) or
                 (j > 0 and idx[j][s] in idx[j - 1])) != shared:
            raise ModelError(f"recursive chain solve: body '{mech.bodies[j].name}' shares other slots with its "
                             "parent than the base body does with the ground")
        if any(idx[j][s] in ground for s in owned):
            raise ModelError(f"recursive chain solve: body '{mech.bodies[j].name}' owns a ground particle")
        if j > 0:
            slots = tuple(owned.index(idx[j - 1].index(idx[j][s])) for s in shared)
            if child_slots is not None and slots != child_slots:
                raise ModelError("recursive chain solve: the joints are not uniform along the chain")
            child_slots = slots
    if child_slots is None:
        child_slots = tuple(range(len(shared)))
    rows = tuple((a, b) for a, b in _all_pairs(len(first)) if not (a in shared and b in shared))
    expected = {frozenset((idx[j][a], idx[j][b])) for j in range(len(idx)) for a, b in rows}
    if expected != {frozenset(p[:2]) for p in mech.distance_pairs}:
        raise ModelError("recursive chain solve: the mechanism has constraints beyond its bodies' distances")
    return ChainPlan(idx=tuple(idx), shared=shared, owned=owned, rows=rows, child_slots=child_slots)


def _all_pairs(k):
    return [(a, b) for a in range(k) for b in range(a + 1, k)]


def _mass_blocks(mech: Mechanism) -> Array:
    kind = mech.bodies[0].kind
    k = len(mech.bodies[0].primaries)
    masses = jax.vmap(solve_particle_masses)(jnp.stack(mech.body_mass), jnp.stack(mech.body_com),
                                             jnp.stack(mech.body_inertia), jnp.stack(mech.body_primaries))
    inc = np.zeros((k + len(PAIRS[kind]), k))
    inc[:k] = np.eye(k)
    for r, (i, j) in enumerate(PAIRS[kind]):
        inc[k + r, [i, j]] = 0.5
    return jnp.einsum("ni,bn,nj->bij", inc, masses, inc)  # (N, k, k)


def chain_accelerations(mech: Mechanism, plan: ChainPlan, t, x: Float[Array, " 3F"],
                        xd: Float[Array, " 3F"]) -> Float[Array, " 3F"]:
    """Particle accelerations by the tip-to-base elimination; equal to the dense solve (tested)."""
    del t
    idx = np.asarray(plan.idx)  # (N, k)
    n_bodies = idx.shape[0]
    sh, ow = np.asarray(plan.shared), np.asarray(plan.owned)
    no, ns, nr = len(ow), len(sh), len(plan.rows)
    r = mech.all_positions(x)[idx]  # (N, k, 3)
    free_mask = np.zeros(len(mech.particle_names))
    free_mask[np.asarray(mech.free)] = 1.0
    v = (mech.all_positions(xd) * free_mask[:, None])[idx]
    mb = _mass_blocks(mech)  # (N, k, k)
    eye3 = jnp.eye(3)
    ra, rb = np.asarray([p[0] for p in plan.rows]), np.asarray([p[1] for p in plan.rows])
    d = r[:, ra] - r[:, rb]  # (N, R, 3)
    gamma = -jnp.sum((v[:, ra] - v[:, rb]) ** 2, axis=-1)  # (N, R)
    # Row Jacobians w.r.t. the local slots: (N, R, k, 3).
    jac = jnp.zeros((n_bodies, nr, idx.shape[1], 3))
    jac = jac.at[:, np.arange(nr), ra].add(d).at[:, np.arange(nr), rb].add(-d)
    g_own = jac[:, :, ow].reshape(n_bodies, nr, 3 * no)
    h_sh = jac[:, :, sh].reshape(n_bodies, nr, 3 * ns)
    m_oo = jnp.einsum("bij,kl->bikjl", mb[:, ow][:, :, ow], eye3).reshape(n_bodies, 3 * no, 3 * no)
    m_ss = jnp.einsum("bij,kl->bikjl", mb[:, sh][:, :, sh], eye3).reshape(n_bodies, 3 * ns, 3 * ns)
    m_so = jnp.einsum("bij,kl->bikjl", mb[:, sh][:, :, ow], eye3).reshape(n_bodies, 3 * ns, 3 * no)
    lumped = jnp.sum(mb, axis=2)  # (N, k): each body's share of its particles' weight
    grav_own = lumped[:, ow, None] * mech.gravity[None, None, :]  # (N, O, 3)
    grav_sh = lumped[:, sh, None] * mech.gravity[None, None, :]  # (N, S, 3)
    # Embedding of a child's shared coordinates into the parent's owned coordinates.
    emb = np.zeros((3 * no, 3 * ns))
    for s, o in enumerate(plan.child_slots):
        emb[3 * o:3 * o + 3, 3 * s:3 * s + 3] = np.eye(3)
    zero_child = lambda a: jnp.concatenate([a[1:], jnp.zeros_like(a[:1])], axis=0)  # noqa: E731
    c_mss, c_mso, c_h, c_grav = zero_child(m_ss), zero_child(m_so), zero_child(h_sh), zero_child(grav_sh)
    nb = 3 * no + nr
    mass_diag = m_oo + jnp.einsum("ij,bjk,lk->bil", emb, c_mss, emb)
    dmat = jnp.zeros((n_bodies, nb, nb))
    dmat = dmat.at[:, :3 * no, :3 * no].set(mass_diag)
    dmat = dmat.at[:, :3 * no, 3 * no:].set(jnp.swapaxes(g_own, 1, 2))
    dmat = dmat.at[:, 3 * no:, :3 * no].set(g_own)
    umat = jnp.zeros((n_bodies, nb, nb))  # couples block j (rows) with block j + 1 (columns)
    umat = umat.at[:, :3 * no, :3 * no].set(jnp.einsum("ij,bjk->bik", emb, c_mso))
    umat = umat.at[:, :3 * no, 3 * no:].set(jnp.einsum("ij,bkj->bik", emb, c_h))
    rhs = jnp.concatenate([(grav_own.reshape(n_bodies, 3 * no)
                            + jnp.einsum("ij,bj->bi", emb, c_grav.reshape(n_bodies, 3 * ns))), gamma], axis=1)

    def backward(carry, inp):
        d_next, r_next = carry
        d_j, u_j, r_j = inp
        sol = jnp.linalg.solve(d_next, jnp.concatenate([u_j.T, r_next[:, None]], axis=1))
        d_t = d_j - u_j @ sol[:, :-1]
        r_t = r_j - u_j @ sol[:, -1]
        return (d_t, r_t), (d_t, r_t)

    init = (jnp.eye(nb), jnp.zeros(nb))
    _, (d_til, r_til) = jax.lax.scan(backward, init, (dmat, umat, rhs), reverse=True)

    def forward(z_prev, inp):
        d_t, r_t, u_prev = inp
        z = jnp.linalg.solve(d_t, r_t - u_prev.T @ z_prev)
        return z, z

    u_prev = jnp.concatenate([jnp.zeros_like(umat[:1]), umat[:-1]], axis=0)
    _, z = jax.lax.scan(forward, jnp.zeros(nb), (d_til, r_til, u_prev))
    acc_owned = z[:, :3 * no].reshape(n_bodies, no, 3)
    out = jnp.zeros((len(mech.particle_names), 3)).at[idx[:, ow]].set(acc_owned)
    return out[np.asarray(mech.free)].reshape(-1)
