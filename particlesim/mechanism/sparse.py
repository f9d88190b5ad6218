"""The acceleration solve by groups hanging from a hub body: cost linear in the number of groups.

A vehicle is a chassis with corners; a robot's legs hang from its trunk. Remove the hub body's particles from the
mechanism's particle graph (two particles adjacent when a constraint row or a body's mass matrix couples them) and
it falls apart into *groups* (the corners), each touching the rest of the mechanism only through the hub. Ordering
the saddle-point system group by group, hub last, makes it block-arrowhead:

    M_g a_g + M_gh a_h + J_g^T lam_g                              = Q_g        (every group g)
    M_h a_h + sum_g (M_hg a_g + J_gh^T lam_g) + J_h^T lam_h       = Q_h        (the hub's particles)
    J_g a_g + J_gh a_h                                            = gamma_g
    J_h a_h                                                       = gamma_h

(``M_gh`` is zero unless a body holds particles of both: a joint particle the hub shares with a group, as a leg's
hip). Each group is eliminated on its own: with ``N_g = M_g^-1 M_gh``, ``B_g = J_gh - J_g N_g`` and
``S_g = J_g M_g^-1 J_g^T``, ``lam_g = S_g^-1 (J_g M_g^-1 Q_g - gamma_g + B_g a_h)``, which leaves the hub with its
articulated (effective) inertia

    M_h* = M_h - sum_g M_hg N_g + sum_g B_g^T S_g^-1 B_g,      Q_h* = Q_h - sum_g (N_g^T Q_g + B_g^T lam_g(a_h = 0)),

a small saddle-point system of the hub's own rows; then every group's multipliers and accelerations follow. This is
Attia's tip-to-base recursion for one level of a tree of loops: each group is a closed loop or a branch of any
shape, and groups with the same structure are one vectorised kernel (``vmap`` over the corners). The cost per
evaluation is the sum of the groups' small factorisations instead of one of all the rows.

The plan (:class:`SparsePlan`) is found from the topology when the mechanism is built, and kept only if every
group's rows with the hub held still are independent at the assembly (``J_g`` of full row rank: then every ``S_g``
is positive definite); else the mechanism has none and ``solve="sparse"`` says why.
"""

from __future__ import annotations

import dataclasses
import functools
from typing import TYPE_CHECKING

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.linalg import cho_factor, cho_solve

from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from ._algebra import _partner
from .model import Topology

if TYPE_CHECKING:
    from ._algebra import Rows

__all__ = ["SparsePlan", "SplitConstants", "candidates", "choose", "validate", "prepare_split", "solve_sparse"]


@dataclasses.dataclass(frozen=True)
class Bucket:
    """Groups of one shape, stacked: free-particle columns ``parts`` (G, P) and row indices of each kind (into the
    dot, linear and driving rows), ``dot`` (G, Rd), ``lin`` (G, Rl), ``drv`` (G, Rk)."""

    parts: tuple[tuple[int, ...], ...]
    dot: tuple[tuple[int, ...], ...]
    lin: tuple[tuple[int, ...], ...]
    drv: tuple[tuple[int, ...], ...]

    def arrays(self):
        return tuple(np.asarray(x, dtype=int).reshape(len(self.parts), -1)
                     for x in (self.parts, self.dot, self.lin, self.drv))


@dataclasses.dataclass(frozen=True)
class SparsePlan:
    """The hub body, its free particles (columns) and rows, and the groups in buckets of equal shape."""

    hub: str
    hub_parts: tuple[int, ...]
    hub_dot: tuple[int, ...]
    hub_lin: tuple[int, ...]
    hub_drv: tuple[int, ...]
    buckets: tuple[Bucket, ...]
    coupled: bool = False  # a body holds particles of the hub and of a group (a joint particle they share)

    @property
    def n_groups(self) -> int:
        return sum(len(b.parts) for b in self.buckets)


def _row_columns(topo: Topology) -> list[tuple[str, int, frozenset]]:
    """Every row as ``(kind, index within its kind, free columns it touches)``."""
    col = topo.free_column()
    slots = topo.point_slots()

    def touched(points):
        out = set()
        for k in points:
            if k < 0:
                continue
            parts = slots[k][:1] if topo.point_body[k] < 0 else slots[k]
            out.update(int(c) for c in col[parts] if c >= 0)
        return frozenset(out)

    rows = [("dot", i, touched(s)) for i, s in enumerate(topo.dot.slots)]
    rows += [("lin", i, touched(s)) for i, s in enumerate(topo.linear.slots)]
    rows += [("drv", i, touched((a, b))) for i, (a, b) in enumerate(zip(topo.drive.a, topo.drive.b))]
    return rows


def _components(nodes: list[int], edges: list[frozenset]) -> list[list[int]]:
    """The connected components of ``nodes`` joined by the cliques ``edges`` (members outside ``nodes`` ignored)."""
    at = {n: i for i, n in enumerate(nodes)}
    pairs = [(at[e[0]], at[n]) for e in ([n for n in clique if n in at] for clique in edges) for n in e[1:]]
    i, j = (np.asarray(x, dtype=int) for x in zip(*pairs)) if pairs else (np.zeros(0, int), np.zeros(0, int))
    _, label = connected_components(coo_matrix((np.ones(len(i)), (i, j)), shape=(len(nodes),) * 2), directed=False)
    comps: dict[int, list[int]] = {}
    for n, lab in zip(nodes, label):
        comps.setdefault(int(lab), []).append(n)
    return sorted(comps.values())


def _cost(groups, hub_size) -> float:
    """Flops of one evaluation, roughly: each group's ``S_g`` and its factorisation, and the hub's."""
    return sum((3 * len(p) + len(r)) ** 3 for p, r in groups) + (3 * hub_size) ** 3


def candidates(topo: Topology) -> list[SparsePlan]:
    """The hub splits of ``topo`` that at least halve the work of the dense solve (by :func:`_cost`), cheapest
    first; none for a mechanism the plan does not cover (singular mass matrix, least-squares multipliers)."""
    if topo.saddle_point or topo.least_squares or not topo.free:
        return []
    col = topo.free_column()
    rows = _row_columns(topo)
    body_cols = [frozenset(int(c) for c in col[list(ps)] if c >= 0) for ps in topo.body_particles]
    n_free = len(topo.free)
    dense = float((3 * n_free + len(rows)) ** 3)
    found = []
    for h, hub in enumerate(body_cols):
        if not hub:
            continue
        rest = [c for c in range(n_free) if c not in hub]
        comps = _components(rest, [r[2] for r in rows] + list(body_cols))
        if not comps:
            continue
        where = {c: g for g, comp in enumerate(comps) for c in comp}
        grouped: list[list] = [[] for _ in comps]
        hub_rows = []
        for kind, i, cols in rows:
            gs = {where[c] for c in cols - hub}
            (grouped[gs.pop()] if gs else hub_rows).append((kind, i))
        cost = _cost([(p, r) for p, r in zip(comps, grouped)], len(hub))
        if cost < 0.5 * dense:  # a plan must at least halve the work to be worth its bookkeeping
            found.append((cost, h, sorted(hub), comps, grouped, hub_rows))
    return [_plan(topo, body_cols, *f[1:]) for f in sorted(found, key=lambda f: f[0])]


def _plan(topo, body_cols, h, hub, comps, grouped, hub_rows) -> SparsePlan:
    def kinds(rs):
        return tuple(tuple(i for k, i in rs if k == kind) for kind in ("dot", "lin", "drv"))

    shapes: dict[tuple, list] = {}
    for parts, rs in zip(comps, grouped):
        dot, lin, drv = kinds(rs)
        shapes.setdefault((len(parts), len(dot), len(lin), len(drv)), []).append((tuple(parts), dot, lin, drv))
    buckets = tuple(Bucket(*(tuple(g[k] for g in gs) for k in range(4))) for gs in shapes.values())
    coupled = any(b & set(hub) and b - set(hub) for b in body_cols)
    return SparsePlan(topo.body_names[h], tuple(hub), *kinds(hub_rows), buckets, coupled)


def choose(topo: Topology, j: np.ndarray, rank_rtol: float) -> SparsePlan | None:
    """The cheapest of :func:`candidates` that :func:`validate` accepts at the assembly Jacobian ``j``."""
    return next((p for p in candidates(topo) if validate(p, j, len(topo.dot), len(topo.linear), rank_rtol)), None)


def validate(plan: SparsePlan | None, j: np.ndarray, n_dot: int, n_lin: int, rank_rtol: float) -> bool:
    """Whether every group's rows, restricted to its own columns (the hub held still), are independent in the
    numeric Jacobian ``j`` (C, 3F) at the assembly."""
    if plan is None:
        return False
    for b in plan.buckets:
        for parts, dot, lin, drv in zip(b.parts, b.dot, b.lin, b.drv):
            r = list(dot) + [n_dot + i for i in lin] + [n_dot + n_lin + i for i in drv]
            c = (3 * np.asarray(parts)[:, None] + np.arange(3)).reshape(-1)
            if len(r) > len(c):
                return False
            if not len(r):
                continue
            sv = np.linalg.svd(j[np.ix_(r, c)], compute_uv=False)
            if sv[-1] <= rank_rtol * max(sv[0], 1e-300):
                return False
    return True


class SplitConstants(eqx.Module):
    """The parameter-only pieces of the split (computed once per parameter set, in :class:`~._algebra.Prepared`):
    per bucket the rows' constant factors restricted to the group's columns then the hub's, ``(G, R, P + H)``
    (dot rows, scaled: halves ``v`` and ``u``), the linear rows' Jacobian ``(G, Rl, P + H, 3)``, the driving rows'
    ``(G, Rk, P + H)`` and the groups' inverse mass blocks ``(G, P, P)``; the same for the hub's own rows
    (columns: the hub's), and the hub's mass block."""

    dv: tuple
    du: tuple
    lin: tuple
    drv: tuple
    minv: tuple
    mgh: tuple  # per bucket M_g^-1 M_gh (G, P, H): the groups' mass coupling to the hub (zeros if uncoupled)
    mhh: tuple  # per bucket sum over its groups of M_hg M_g^-1 M_gh (H, H)
    hub_dv: jax.Array
    hub_du: jax.Array
    hub_lin: jax.Array
    hub_drv: jax.Array
    ms_hub: jax.Array


def prepare_split(plan: SparsePlan, prep) -> SplitConstants:
    """:class:`SplitConstants` from the dense constants ``prep`` (differentiable in the parameters)."""
    n = prep.scale.shape[0]
    hub = np.asarray(plan.hub_parts, dtype=int)
    drv_d = prep.drv_d if prep.drv_d is not None else jnp.zeros((0, prep.d.shape[1]), prep.d.dtype)

    def restrict(dot, lin, drv, cols):
        sc = prep.scale[dot][..., None]
        return (sc * prep.d[dot[..., None], cols[..., None, :]], sc * prep.d[n + dot[..., None], cols[..., None, :]],
                prep.j_lin[lin[..., None], cols[..., None, :]], drv_d[drv[..., None], cols[..., None, :]])

    dv, du, lin, drv, minv, mgh, mhh = [], [], [], [], [], [], []
    for b in plan.buckets:
        parts, dot, lin_, drv_ = b.arrays()
        cols = np.concatenate([parts, np.broadcast_to(hub, (len(parts), len(hub)))], axis=1)
        for out, x in zip((dv, du, lin, drv), restrict(dot, lin_, drv_, cols)):
            out.append(x)
        if plan.coupled:  # the group's own mass block, inverted (not a block of the whole inverse)
            m_gg = prep.ms[parts[:, :, None], parts[:, None, :]]
            m_gh = prep.ms[parts[:, :, None], hub[None, None, :]]
            minv_g = jnp.linalg.inv(m_gg)
            minv.append(0.5 * (minv_g + jnp.swapaxes(minv_g, 1, 2)))
            mgh.append(minv[-1] @ m_gh)
            mhh.append(jnp.einsum("gph,gpk->hk", m_gh, mgh[-1]))
        else:  # M is block diagonal: the group's block of M^-1 is its block's inverse
            minv.append(prep.minv[parts[:, :, None], parts[:, None, :]])
            mgh.append(None)
            mhh.append(None)
    h = restrict(*(np.asarray(x, dtype=int) for x in (plan.hub_dot, plan.hub_lin, plan.hub_drv)), hub)
    return SplitConstants(tuple(dv), tuple(du), tuple(lin), tuple(drv), tuple(minv), tuple(mgh), tuple(mhh), *h,
                          ms_hub=prep.ms[np.ix_(hub, hub)])


@functools.lru_cache(maxsize=64)
def _layout(plan: SparsePlan, n_dot: int, n_lin: int):
    """Static index arrays: per bucket its rows' positions in the multiplier vector (G, R); the hub's; and the
    gathers that put ``[hub; bucket 0; bucket 1; ...]`` back in state and row order."""
    rows = []
    for b in plan.buckets:
        _, dot, lin, drv = b.arrays()
        rows.append(np.concatenate([dot, n_dot + lin, n_dot + n_lin + drv], axis=1))
    hub_rows = np.concatenate([np.asarray(plan.hub_dot, int), n_dot + np.asarray(plan.hub_lin, int),
                               n_dot + n_lin + np.asarray(plan.hub_drv, int)])
    part_order = np.concatenate([np.asarray(plan.hub_parts, int)] + [b.arrays()[0].reshape(-1)
                                                                      for b in plan.buckets])
    row_order = np.concatenate([hub_rows] + [r.reshape(-1) for r in rows])
    return rows, hub_rows, np.argsort(part_order), np.argsort(row_order)


def _rows_jacobian(e_v, e_u, dv, du, lin, drv, n):
    """``J`` (R, cols, 3) of rows with partner vectors ``e_v``, ``e_u`` (Rd, 3) and driving directions ``n``."""
    parts = [dv[..., None] * e_v[:, None, :] + du[..., None] * e_u[:, None, :], lin]
    if drv.shape[0]:
        parts.append(drv[..., None] * n[:, None, :])
    return jnp.concatenate(parts, axis=0)


def solve_sparse(plan: SparsePlan, prep, r: Rows, g: jax.Array, minv_q: jax.Array):
    """``(qdd (F, 3), lam (C,))`` of ``M qdd + J^T lam = Q``, ``J qdd = g`` by the hub split (module docstring);
    ``minv_q = M^-1 Q`` (F, 3); the constants ``prep.split`` (:func:`prepare_split`) are computed here when
    ``prep`` was prepared without them."""
    sc = prep.split if prep.split is not None else prepare_split(plan, prep)
    n_dot, n_lin = prep.scale.shape[0], prep.c_lin.shape[0]
    rows, hub_rows, part_back, row_back = _layout(plan, n_dot, n_lin)
    hub = np.asarray(plan.hub_parts, dtype=int)
    nh = 3 * len(hub)
    e = _partner(r.vu, prep.turn)
    n_drv = r.drive.n if r.drive is not None else jnp.zeros((0, 3), e.dtype)
    m_eff = jnp.kron(sc.ms_hub, jnp.eye(3, dtype=e.dtype))
    if plan.coupled:  # the forces themselves: Q = M (M^-1 Q)
        q_all = prep.ms @ minv_q
        q_eff = q_all[hub].reshape(-1)
    else:  # Q_h = M_h (M^-1 Q)_h, and (M^-1 Q)_g is the groups' own: M has no group-hub block
        q_eff = (sc.ms_hub @ minv_q[hub]).reshape(-1)
    eye3 = jnp.eye(3, dtype=e.dtype)
    eliminated = []
    for k, (b, rws) in enumerate(zip(plan.buckets, rows)):
        parts, dot, _, drv = b.arrays()
        p = parts.shape[1]

        def group(dv, du, lin, drv_c, minv_g, mgh, ev, eu, nd, y, gr):
            j = _rows_jacobian(ev, eu, dv, du, lin, drv_c, nd)  # (R, P + H, 3)
            jg, jh = j[:, :p], j[:, p:].reshape(j.shape[0], nh)
            jm = jnp.einsum("rpk,pq->rqk", jg, minv_g)  # J_g M_g^-1
            if mgh is not None:  # B_g = J_gh - J_g M_g^-1 M_gh takes J_gh's place
                jh = jh - jnp.einsum("rpk,ph->rhk", jg, mgh).reshape(j.shape[0], nh)
            f = cho_factor(jnp.einsum("rpk,spk->rs", jm, jg))
            sol = cho_solve(f, jnp.concatenate([(jnp.einsum("rpk,pk->r", jg, y) - gr)[:, None], jh], axis=1))
            lam0, t = sol[:, 0], sol[:, 1:]  # multipliers at a_h = 0, and S_g^-1 B_g
            return jm, y, lam0, t, jh.T @ t, jh.T @ lam0

        if plan.coupled:
            y = jnp.einsum("gpq,gqk->gpk", sc.minv[k], q_all[parts])  # M_g^-1 Q_g
            m_eff = m_eff - jnp.kron(sc.mhh[k], eye3)
            q_eff = q_eff - jnp.einsum("gph,gpk->hk", sc.mgh[k], q_all[parts]).reshape(-1)  # M_hg M_g^-1 Q_g
        else:
            y = minv_q[parts]
        out = jax.vmap(group)(sc.dv[k], sc.du[k], sc.lin[k], sc.drv[k], sc.minv[k], sc.mgh[k], e[dot],
                              e[n_dot + dot], n_drv[drv], y, g[rws])
        m_eff = m_eff + out[4].sum(0)
        q_eff = q_eff - out[5].sum(0)
        eliminated.append(out[:4])
    # the hub: [M_h* J_h^T; J_h 0] [a_h; lam_h] = [Q_h*; gamma_h]
    fh = cho_factor(m_eff)
    if len(hub_rows):
        hd = np.asarray(plan.hub_dot, dtype=int)
        j_hub = _rows_jacobian(e[hd], e[n_dot + hd], sc.hub_dv, sc.hub_du, sc.hub_lin, sc.hub_drv,
                               n_drv[np.asarray(plan.hub_drv, dtype=int)]).reshape(len(hub_rows), nh)
        sol = cho_solve(fh, jnp.concatenate([q_eff[:, None], j_hub.T], axis=1))
        u, mj = sol[:, 0], sol[:, 1:]
        lam_h = cho_solve(cho_factor(j_hub @ mj), j_hub @ u - g[hub_rows])
        a_h = u - mj @ lam_h
    else:
        lam_h = jnp.zeros((0,), dtype=g.dtype)
        a_h = cho_solve(fh, q_eff)
    accs, lams = [a_h.reshape(-1, 3)], [lam_h]
    for k, (jm, y, lam0, t) in enumerate(eliminated):
        lam_g = lam0 + t @ a_h  # (G, R)
        a_g = y - jnp.einsum("grqk,gr->gqk", jm, lam_g)
        if plan.coupled:
            a_g = a_g - jnp.einsum("gph,hk->gpk", sc.mgh[k], a_h.reshape(-1, 3))
        accs.append(a_g.reshape(-1, 3))
        lams.append(lam_g.reshape(-1))
    return jnp.concatenate(accs)[part_back], jnp.concatenate(lams)[row_back]
