"""The constraint algebra of a mechanism, arranged so that one evaluation is a handful of small dense products.

Every dot row is ``s_r v_r . u_r - kappa_r`` with ``v_r = p_a - p_b`` and ``u_r = p_c - p_d`` (:mod:`.model`), and
points are linear in the free particle positions ``X`` (F, 3): ``p = W X + p_0``. Hence

    [v; u] = D X + c,   D = [W_a - W_b; W_c - W_d]   (2D x F, constant for a parameter set)

and the row's Jacobian is ``J_r = s_r (D_v[r] (x) u_r + D_u[r] (x) v_r)``. With ``E = [u; v]`` (the partner of each
half of ``D``) the Schur complement ``S = J M^-1 J^T`` of the dot rows is

    S[r, q] = s_r s_q sum_{i, j in (v, u)} A[(i, r), (j, q)] (E[(i, r)] . E[(j, q)]),     A = D M_s^-1 D^T

so per evaluation it costs one Gram product ``E E^T`` (elementwise outer products in small mechanisms,
:data:`GRAM_OUTER_MAX_ROWS`) and one elementwise combination with the constant ``A``;
``J Y`` and ``M^-1 J^T lam`` likewise reduce to ``D Y`` and ``(D M_s^-1)^T`` times row-scaled ``E``. Linear rows
(cut joints) have a constant Jacobian, so their blocks of ``S`` are constants or (with the dot rows) one
contraction with a constant tensor. Driving rows ``n(t) . (p_a - p_b) - c(t)`` (:class:`~.model.DriveRows`) are
linear in the coordinates with a direction that depends on time only: their blocks of ``S`` are constants times
``n . n'`` or ``E . n``, and their right-hand sides carry the time derivatives of ``n`` and ``c``. Everything that depends on the parameters only lives in :class:`Prepared`,
computed once per parameter set (once per rollout), and is differentiable in the parameters.
"""

from __future__ import annotations

import functools
import operator

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jax.scipy.linalg import cho_factor, cho_solve
from jaxtyping import Array, Float

from ..particles import primary_mass_matrix
from .constraints import linear_blocks, point_free_weights, point_weights, points, quarter_turn
from .model import Mechanism
from .._jit import compiled
from .._linalg import _zero, spd_solve_applied

__all__ = ["Prepared", "prepare", "scalar_mass_matrix", "Rows", "rows", "schur", "apply_j", "apply_minv_jt",
           "residual", "gamma", "velocity_target", "Drive", "drive_at", "SchurFactor", "factor_schur", "solve_schur",
           "schur_solve", "LSQ_RTOL", "LSQ_REFINE", "FULL", "BETWEEN_STEPS"]

#: Least-squares multipliers: ``S`` is factorised as ``S + mu I`` with ``mu`` this fraction of its largest diagonal
#: entry (a Tikhonov/Levenberg damping that keeps the factorisation defined when rows are redundant or the
#: mechanism sits at a singular position, and bounds the force a nearly dependent row can exert at ``1/(2 sqrt mu)``
#: times its right-hand side, so that the integrator's step control is not stalled by amplified round-off and
#: local error while a linkage passes a singular position) ...
LSQ_RTOL = 1e-8
#: ... followed by this many steps of iterative refinement against ``S`` itself, which recover the undamped
#: least-squares solution on every direction with ``sigma^2 >> mu`` (error ``(mu / sigma^2)^(k+1)``: 1e-10 relative
#: at ``sigma^2 = 1e-6 max diag S``), so that a full-rank mechanism agrees with the plain Cholesky solve.
LSQ_REFINE = 4

#: (position iterations, velocity passes) of a full projection onto the constraints (saved outputs, the public
#: ``project``) ...
FULL = (2, 2)
#: ... and of the projection between a rollout's steps (:mod:`.integrate`'s docstring), on the dense and the O(N)
#: chain path alike.
BETWEEN_STEPS = (1, 1)


@compiled("scalar_mass_matrix")
def scalar_mass_matrix(mech: Mechanism) -> Float[Array, "P P"]:
    """``M_s`` over all particles: each body's ``L_b`` (k x k) added at its primaries; one vmapped solve per kind."""
    topo = mech.topo
    n = topo.n_particles
    rows_, cols, vals = [], [], []
    for k in (4, 3, 2):
        ids = np.asarray([b for b, prim in enumerate(topo.body_particles) if len(prim) == k], dtype=int)
        if not ids.size:
            continue
        blocks = jax.vmap(primary_mass_matrix)(mech.body_mass[ids], mech.body_com[ids], mech.body_inertia[ids],
                                               mech.body_primaries[ids, :k])  # (B, k, k)
        prim = np.asarray([topo.body_particles[b] for b in ids])  # (B, k)
        rows_.append(np.repeat(prim, k, axis=1).reshape(-1))
        cols.append(np.tile(prim, (1, k)).reshape(-1))
        vals.append(blocks.reshape(-1))
    m_s = jnp.zeros((n, n), dtype=mech.body_mass.dtype)
    if vals:
        m_s = m_s.at[np.concatenate(rows_), np.concatenate(cols)].add(jnp.concatenate(vals))
    return m_s


@compiled("mass_matrix")
def mass_matrix(mech: Mechanism) -> Float[Array, "3F 3F"]:
    """The constant mass matrix of the free coordinates, ``M_s[free, free] (x) I_3`` (Kronecker product)."""
    f = np.asarray(mech.topo.free, dtype=int)
    return jnp.kron(scalar_mass_matrix(mech)[np.ix_(f, f)], jnp.eye(3))


@compiled("lumped_masses")
def lumped_masses(mech: Mechanism) -> Float[Array, " P"]:
    """Per-particle mass carrying linear momentum and weight: ``m_bar`` of Attia eq. (25), summed over bodies."""
    return jnp.sum(scalar_mass_matrix(mech), axis=1)


class Prepared(eqx.Module):
    """Everything that depends on the parameters only (not on the state): computed once per rollout."""

    w: Float[Array, "K 4"]  # point weights on their particles
    wk: Float[Array, "K F"]  # point-to-free-particle weights
    p0: Float[Array, "K 3"]  # ground contribution to every point
    ms: Float[Array, "F F"]  # scalar mass matrix of the free particles
    lumped: Float[Array, " P"]  # m_bar of every particle (Attia eq. (25))
    qg: Float[Array, "F 3"]  # gravity on the free particles
    d: Float[Array, "2D F"]  # [W_a - W_b; W_c - W_d] of the dot rows
    c: Float[Array, "2D 3"]  # their ground offsets
    scale: Float[Array, " D"]
    j_lin: Float[Array, "L F 3"]  # the (constant) Jacobian of the linear rows
    c_lin: Float[Array, " L"]  # their ground offsets
    # With an invertible mass matrix (None otherwise: the saddle-point solve is used):
    minv: Float[Array, "F F"] | None
    minv_qg: Float[Array, "F 3"] | None
    minv_dt: Float[Array, "F 2D"] | None  # (d @ minv)^T = minv @ d^T, stored transposed (see apply_minv_jt)
    a: Float[Array, "2D 2D"] | None  # d @ minv @ d^T
    jw_lin: Float[Array, "L F 3"] | None  # minv-weighted linear rows
    b_lin: Float[Array, "2D L 3"] | None  # d contracted with jw_lin (dot-linear coupling of S)
    s_lin: Float[Array, "L L"] | None  # the linear rows' block of S
    mwk: Float[Array, "F K"] | None  # minv @ wk^T: point forces to accelerations
    # Driving rows (empty arrays without drivers):
    drv_d: Float[Array, "K F"] | None = None  # W_a - W_b of every driving row
    drv_c0: Float[Array, "K 3"] | None = None  # its ground offset
    drv_minv_dt: Float[Array, "F K"] | None = None  # (drv_d @ minv)^T, stored transposed as minv_dt
    drv_akk: Float[Array, "K K"] | None = None  # drv_d @ minv @ drv_d^T
    drv_adk: Float[Array, "2D K"] | None = None  # d @ minv @ drv_d^T
    drv_blk: Float[Array, "L K 3"] | None = None  # jw_lin contracted with drv_d
    turn: tuple | None = eqx.field(static=True, default=None)  # turned dot rows (planar lines on rods), or None
    split: object = None  # the hub split's constants (:class:`~.sparse.SplitConstants`) when the topology has one


def prepare(mech: Mechanism, split: bool = False) -> Prepared:
    """The parameter-only quantities of :class:`Prepared` (differentiable in the parameters); ``split``: with the
    constants of the hub split (:mod:`.sparse`), when the topology has one."""
    topo = mech.topo
    free = np.asarray(topo.free, dtype=int)
    w = point_weights(mech)
    wk = point_free_weights(topo, w)
    ground_only = jnp.where(jnp.asarray(topo.free_column() < 0)[:, None], mech.all_positions(
        jnp.zeros(3 * len(free), dtype=w.dtype)), 0.0)
    p0 = points(topo, w, ground_only)
    m_all = scalar_mass_matrix(mech)
    ms = m_all[np.ix_(free, free)]
    lumped = jnp.sum(m_all, axis=1)
    qg = lumped[free][:, None] * mech.gravity[None, :]
    dr = topo.dot
    ia, ib, ic, idd = (np.asarray(v, dtype=int) for v in (dr.a, dr.b, dr.c, dr.d))
    d = jnp.concatenate([wk[ia] - wk[ib], wk[ic] - wk[idd]], axis=0)
    c = jnp.concatenate([p0[ia] - p0[ib], p0[ic] - p0[idd]], axis=0)
    scale = jnp.asarray(dr.scale, dtype=w.dtype)
    lr = topo.linear
    la, lb = np.asarray(lr.a, dtype=int), np.asarray(lr.b, dtype=int)
    e = jnp.asarray(linear_blocks(topo)[:, 0], dtype=w.dtype)  # (L, 3)
    j_lin = (wk[la] - wk[lb])[:, :, None] * e[:, None, :]
    c_lin = jnp.sum(e * (p0[la] - p0[lb]), axis=1)
    base = dict(w=w, wk=wk, p0=p0, ms=ms, lumped=lumped, qg=qg, d=d, c=c, scale=scale, j_lin=j_lin, c_lin=c_lin,
                turn=topo.dot.turned)
    dr = topo.drive
    if len(dr):
        da, db = np.asarray(dr.a, dtype=int), np.asarray(dr.b, dtype=int)
        origin = db < 0  # a driver measured from the world origin: no second point
        drv_d = wk[da] - jnp.where(jnp.asarray(origin)[:, None], 0.0, wk[np.where(origin, 0, db)])
        drv_c0 = p0[da] - jnp.where(jnp.asarray(origin)[:, None], 0.0, p0[np.where(origin, 0, db)])
        base.update(drv_d=drv_d, drv_c0=drv_c0)
    if topo.saddle_point:
        return Prepared(**base, minv=None, minv_qg=None, minv_dt=None, a=None, jw_lin=None, b_lin=None, s_lin=None,
                        mwk=None)
    minv = cho_solve(cho_factor(ms), jnp.eye(ms.shape[0], dtype=ms.dtype))
    minv = 0.5 * (minv + minv.T)
    dw = d @ minv
    jw_lin = jnp.einsum("lfk,fg->lgk", j_lin, minv)
    if len(dr):
        drv_dw = base["drv_d"] @ minv
        base.update(drv_minv_dt=drv_dw.T, drv_akk=drv_dw @ base["drv_d"].T, drv_adk=dw @ base["drv_d"].T,
                    drv_blk=jnp.einsum("lfk,qf->lqk", jw_lin, base["drv_d"]))
    out = Prepared(**base, minv=minv, minv_qg=minv @ qg, minv_dt=dw.T, a=dw @ d.T, jw_lin=jw_lin,
                   b_lin=jnp.einsum("if,lfk->ilk", d, jw_lin), s_lin=jnp.einsum("lfk,mfk->lm", j_lin, jw_lin),
                   mwk=minv @ wk.T)
    if split and topo.sparse is not None:
        from .sparse import prepare_split

        out = eqx.tree_at(lambda p: p.split, out, prepare_split(topo.sparse, out), is_leaf=lambda x: x is None)
    return out


class Drive(eqx.Module):
    """The driving rows at one time: directions ``n`` and their first two time derivatives, targets ``c`` and
    theirs (:class:`~.model.DriveRows`)."""

    n: Float[Array, "K 3"]
    nd: Float[Array, "K 3"]
    ndd: Float[Array, "K 3"]
    c: Float[Array, " K"]
    cd: Float[Array, " K"]
    cdd: Float[Array, " K"]


def _derivatives(fn, t):
    """``f(t), f'(t), f''(t)`` of a scalar function of time by forward-mode autodiff."""
    one = jnp.ones_like(t)

    def first(s):
        return jax.jvp(lambda u: jnp.asarray(fn(u), dtype=t.dtype).reshape(()), (s,), (one,))

    (f, fd), (_, fdd) = jax.jvp(first, (t,), (one,))
    return f, fd, fdd


def drive_at(mech: Mechanism, t) -> Drive | None:
    """The driving rows' directions and targets at time ``t`` (``None`` without drivers)."""
    dr = mech.topo.drive
    if not len(dr):
        return None
    dtype = mech.body_mass.dtype
    t = jnp.asarray(t, dtype=dtype)
    f, fd, fdd = (jnp.stack(v) for v in zip(*(_derivatives(fn, t) for fn in mech.drive_fns)))
    a = jnp.asarray(dr.axis, dtype=dtype)
    k = jnp.asarray(dr.spin, dtype=dtype)
    ang = jnp.asarray(dr.angle)
    kxa = jnp.cross(k, a)
    cs, sn = jnp.cos(f)[:, None], jnp.sin(f)[:, None]
    n_rot = cs * a + sn * kxa
    m_rot = -sn * a + cs * kxa  # d n / d theta
    n = jnp.where(ang[:, None], n_rot, a)
    nd = jnp.where(ang[:, None], fd[:, None] * m_rot, 0.0)
    ndd = jnp.where(ang[:, None], fdd[:, None] * m_rot - (fd**2)[:, None] * n_rot, 0.0)
    zero = jnp.zeros_like(f)
    return Drive(n=n, nd=nd, ndd=ndd, c=jnp.where(ang, zero, mech.drive_offset + f), cd=jnp.where(ang, zero, fd),
                 cdd=jnp.where(ang, zero, fdd))


class Rows(eqx.Module):
    """The dot rows' vectors at one state: ``vu = [v; u]`` (2D, 3) and their rates ``dvu``; with drivers their
    values at the state's time and the driven vectors ``p_a - p_b`` (and rates)."""

    vu: Float[Array, "2D 3"]
    dvu: Float[Array, "2D 3"] | None
    drive: Drive | None = None
    du: Float[Array, "K 3"] | None = None
    ddu: Float[Array, "K 3"] | None = None


#: Up to this many free particles, :func:`_mm` is an unrolled sum of outer products; beyond, a matrix product.
MM_UNROLL = 16


def _mm(a: Array, b: Array) -> Array:
    """``a @ b`` for ``b`` (F, 3). Up to :data:`MM_UNROLL` particles a sum of F outer products, unrolled, which XLA
    fuses into one loop reading ``a`` and ``b`` once (a dot call costs more than the arithmetic at these sizes);
    a matrix product beyond. Not the broadcast product ``a[:, :, None] * b[None]`` summed over F: under ``vmap``
    over parameter sets (``a`` batched) XLA hoists its broadcast out of the integrator's loop as a (B, 2D, F, 3)
    array that every evaluation then reads from memory (vmapped quarter cars ran more than twice as slow with it)."""
    f = a.shape[1]
    if f == 0 or f > MM_UNROLL:
        return a @ b
    return _outer_sum(a, b)


@jax.custom_jvp
def _outer_sum(a: Array, b: Array) -> Array:
    """``a @ b`` as the sum of the outer products of ``a``'s columns with ``b``'s rows (:func:`_mm`). Its tangent is
    the broadcast product summed (``da @ b + a @ db`` written as before): differentiated as written, each term's
    transpose is a padded copy of ``a``'s shape, which made the quarter car's reverse-mode gradient compile and run
    slower; with matrix products for the tangent it ran slower still. A tangent that
    is zero (``a`` = the rows' constant matrix, when the gradient is not taken in the geometry) is skipped. Left
    as it is: that tangent is the broadcast product again, so a gradient *vmapped* over parameter sets still meets
    the hoisted broadcast _mm avoids in the forward pass (not measured)."""
    return functools.reduce(operator.add, (a[:, k, None] * b[k][None, :] for k in range(a.shape[1])))


@functools.partial(_outer_sum.defjvp, symbolic_zeros=True)
def _outer_sum_jvp(primals, tangents):
    a, b = primals
    da, db = tangents
    out = _outer_sum(a, b)
    tangent = jnp.zeros_like(out)
    if not _zero(da):
        tangent = tangent + _broadcast_sum(da, b)
    if not _zero(db):
        tangent = tangent + _broadcast_sum(a, db)
    return out, tangent


def _broadcast_sum(a: Array, b: Array) -> Array:
    """``a @ b`` as a broadcast product summed over the inner axis (one fused loop)."""
    return jnp.sum(a[:, :, None] * b[None, :, :], axis=1)


def rows(prep: Prepared, q: Float[Array, " 3F"], qd=None, drive: Drive | None = None) -> Rows:
    """The rows' vectors at ``(q, qd)``; ``drive`` (:func:`drive_at`) is required when the mechanism has drivers."""
    vu = _mm(prep.d, q.reshape(-1, 3)) + prep.c
    dvu = None if qd is None else _mm(prep.d, qd.reshape(-1, 3))
    if prep.drv_d is None:
        return Rows(vu, dvu)
    if drive is None:
        raise ValueError("this mechanism has driving constraints: give the time (drive_at(mech, t))")
    du = _mm(prep.drv_d, q.reshape(-1, 3)) + prep.drv_c0
    ddu = None if qd is None else _mm(prep.drv_d, qd.reshape(-1, 3))
    return Rows(vu, dvu, drive, du, ddu)


def _partner(vu: Array, turn=None) -> Array:
    """``E = [u; v]``: the vector each half of ``D`` is paired with in the Jacobian (``[Rz u; Rz^T v]`` on turned
    rows)."""
    n = vu.shape[0] // 2
    return jnp.concatenate([quarter_turn(vu[n:], turn), quarter_turn(vu[:n], turn, -1.0)], axis=0)


def residual(prep: Prepared, kappa: Array, r: Rows, q: Array) -> Float[Array, " C"]:
    n = prep.scale.shape[0]
    dot = prep.scale * jnp.sum(r.vu[:n] * quarter_turn(r.vu[n:], prep.turn), axis=1) - kappa
    lin = jnp.sum(prep.j_lin * q.reshape(1, -1, 3), axis=(1, 2)) + prep.c_lin
    if r.drive is None:
        return jnp.concatenate([dot, lin])
    return jnp.concatenate([dot, lin, jnp.sum(r.drive.n * r.du, axis=1) - r.drive.c])


def gamma(prep: Prepared, r: Rows) -> Float[Array, " C"]:
    """``-d^2 Phi/dt^2`` at zero acceleration: ``-2 s dv . du`` for dot rows, zero for linear rows."""
    n = prep.scale.shape[0]
    dot = -2.0 * prep.scale * jnp.sum(r.dvu[:n] * quarter_turn(r.dvu[n:], prep.turn), axis=1)
    lin = jnp.zeros(prep.c_lin.shape, dtype=dot.dtype)
    if r.drive is None:
        return jnp.concatenate([dot, lin])
    dv = r.drive
    drv = dv.cdd - 2.0 * jnp.sum(dv.nd * r.ddu, axis=1) - jnp.sum(dv.ndd * r.du, axis=1)
    return jnp.concatenate([dot, lin, drv])


def velocity_target(prep: Prepared, r: Rows) -> Float[Array, " C"] | float:
    """The right-hand side of ``J qd = nu``: zero, except ``c' - n' . (p_a - p_b)`` on driving rows."""
    if r.drive is None:
        return 0.0
    zeros = jnp.zeros(prep.scale.shape[0] + prep.c_lin.shape[0], dtype=r.du.dtype)
    return jnp.concatenate([zeros, r.drive.cd - jnp.sum(r.drive.nd * r.du, axis=1)])


#: Up to this many dot rows, :func:`schur` forms its Gram products as outer products of the three coordinates (one
#: elementwise kernel, the row vectors behind an optimisation barrier); beyond, as the dense product ``E E^T``.
#: Outer products ran single rollouts faster than ``E E^T`` at every size measured (Nikravesh AA, spherical and
#: revolute chains, the quarter car; 5 to 40 rows), and since the multipliers' solve is differentiated with its matrix
#: applied (:func:`schur_solve`) the two forms' gradients cost alike. A least-squares mechanism, whose multipliers are
#: still differentiated through the factorisation (:func:`solve_schur`), keeps them too, for the rollouts, although
#: its reverse gradient ran slightly slower and compiled slower (the 8-link revolute chain, 40 rows; gradients equal
#: to round-off). Not measured: sizes beyond 40 rows, the exact-multiplier 8-link chain's gradient, gradients vmapped
#: over parameter sets.
GRAM_OUTER_MAX_ROWS = 40


def schur(prep: Prepared, r: Rows) -> Float[Array, "C C"]:
    """``S = J M^-1 J^T`` from the Gram matrix of ``E`` and the constant ``A`` (module docstring)."""
    n = prep.scale.shape[0]
    e = _partner(r.vu, prep.turn)
    ab = prep.a.reshape(2, n, 2, n)
    # h[r, q] = sum_{i,j} A[(i, r), (j, q)] E[(i, r)] . E[(j, q)]
    if n <= GRAM_OUTER_MAX_ROWS:
        # Outer products of the three coordinates, one elementwise kernel, E behind an optimisation barrier:
        # without it XLA fuses the rows' products (_mm, which E is made of) into this kernel and recomputes them
        # for every entry (without the barrier this form ran slower than E E^T at every size).
        e = jax.lax.optimization_barrier(e)
        eb = (e[:n], e[n:])
        h = sum(ab[i, :, j, :] * _outer_sum(eb[i], eb[j].T) for i in range(2) for j in range(2))
    else:  # the Gram matrix of E as one small dense product
        g = (e @ e.T).reshape(2, n, 2, n)
        h = sum(ab[i, :, j, :] * g[i, :, j, :] for i in range(2) for j in range(2))
    s_dd = prep.scale[:, None] * prep.scale[None, :] * h
    if prep.c_lin.shape[0] == 0:
        s = s_dd
    else:
        s_dl = prep.scale[:, None] * jnp.sum(e[:, None, :] * prep.b_lin, axis=2).reshape(2, n, -1).sum(axis=0)
        s = jnp.block([[s_dd, s_dl], [s_dl.T, prep.s_lin]])
    if r.drive is None:
        return s
    nk = r.drive.n
    s_dk = prep.scale[:, None] * (prep.drv_adk * (e @ nk.T)).reshape(2, n, -1).sum(axis=0)  # (D, K)
    s_lk = jnp.sum(prep.drv_blk * nk[None], axis=2)  # (L, K)
    s_kk = prep.drv_akk * (nk @ nk.T)
    s_xk = jnp.concatenate([s_dk, s_lk], axis=0)
    return jnp.block([[s, s_xk], [s_xk.T, s_kk]])


def apply_j(prep: Prepared, r: Rows, y: Float[Array, "F 3"], *, matmul: bool = False) -> Float[Array, " C"]:
    """``J y`` for ``y`` (F, 3); ``matmul``: the products with the rows' constant matrices as matrix products (for
    :func:`schur_solve`'s tangent, whose transposes are then matrix products too) instead of :func:`_mm`."""
    n = prep.scale.shape[0]
    mm = jnp.matmul if matmul else _mm
    dy = mm(prep.d, y)
    dot = prep.scale * jnp.sum((_partner(r.vu, prep.turn) * dy).reshape(2, n, 3), axis=(0, 2))
    out = [dot, jnp.sum(prep.j_lin * y[None], axis=(1, 2))]
    if r.drive is not None:
        out.append(jnp.sum(mm(prep.drv_d, y) * r.drive.n, axis=1))
    return jnp.concatenate(out)


def apply_minv_jt(prep: Prepared, r: Rows, lam: Float[Array, " C"]) -> Float[Array, "F 3"]:
    """``M^-1 J^T lam`` as (F, 3)."""
    n = prep.scale.shape[0]
    ls = jnp.tile(lam[:n] * prep.scale, 2)[:, None] * _partner(r.vu, prep.turn)
    nl = prep.c_lin.shape[0]
    # A matrix product rather than a broadcast product summed over rows: see _mm (the same hoisted broadcast). Its
    # constant factor is stored transposed (F, 2D), so that the product inside the integrator's loop contracts its
    # rows' trailing axis: written as ``(d @ minv).T @ ls``, XLA kept the transpose inside the product (a dot on the
    # leading axes, not handed to YNNPACK), which ran a 4-link chain's rollout slower (the quarter car's alike).
    out = prep.minv_dt @ ls + jnp.sum(prep.jw_lin * lam[n:n + nl, None, None], axis=0)
    if r.drive is None:
        return out
    return out + prep.drv_minv_dt @ (lam[n + nl:, None] * r.drive.n)


def jacobian(prep: Prepared, r: Rows) -> Float[Array, "C F 3"]:
    """The dense Jacobian ``(C, F, 3)`` (for the saddle-point solve and the public API)."""
    n = prep.scale.shape[0]
    e = _partner(r.vu, prep.turn)
    # A (2D, F, 3) product with the constant D, as _mm avoids: here it is the dense Jacobian itself (the saddle-point
    # solve of singular mass matrices, the public API), which has that size anyway.
    j_dot = (prep.d[:, :, None] * e[:, None, :]).reshape(2, n, prep.d.shape[1], 3).sum(axis=0)
    out = [prep.scale[:, None, None] * j_dot, prep.j_lin]
    if r.drive is not None:
        out.append(prep.drv_d[:, :, None] * r.drive.n[:, None, :])
    return jnp.concatenate(out, axis=0)


def schur_solve(prep: Prepared, r: Rows, s: Float[Array, "C C"], rhs: Float[Array, " C"]) -> Float[Array, " C"]:
    """``S^-1 rhs`` for ``s = schur(prep, r)`` (passed in, so that several solves with one ``S`` share it) by one
    Cholesky factorisation, differentiated as a solve whose matrix is applied, not formed
    (:func:`~particlesim._linalg.spd_solve_applied`): ``dS lam`` is the tangent of ``J (M^-1 J^T lam)`` at fixed
    ``lam`` (:func:`apply_j` of :func:`apply_minv_jt`, products with the rows' constant matrices, O(C F)).
    Differentiated through ``S``, reverse mode formed the whole cotangent of the Gram matrix of ``E`` (2D x 2D) and
    its products with ``E``: the largest kernels of the quarter car's backward pass."""
    return spd_solve_applied(_schur_apply, (prep, r), s, rhs)


def _schur_apply(params, lam):
    prep, r = params
    return apply_j(prep, r, apply_minv_jt(prep, r, lam), matmul=True)


class SchurFactor(eqx.Module):
    """A factorisation of ``S`` for repeated solves: plain Cholesky, or (``least_squares``) Cholesky of the damped
    ``S + mu I`` kept with ``S`` for the refinement steps (:data:`LSQ_RTOL`, :data:`LSQ_REFINE`)."""

    chol: tuple
    s: Array | None  # S itself, least squares only


def factor_schur(s: Float[Array, "C C"], least_squares: bool) -> SchurFactor:
    if not least_squares:
        return SchurFactor(cho_factor(s), None)
    mu = LSQ_RTOL * jnp.max(jnp.diag(s))
    return SchurFactor(cho_factor(s + mu * jnp.eye(s.shape[0], dtype=s.dtype)), s)


def solve_schur(f: SchurFactor, rhs: Float[Array, " C"]) -> Float[Array, " C"]:
    """``S^-1 rhs``, or least-squares multipliers when ``S`` is (near) singular. With redundant rows the forces
    ``J^T lam`` (and so the accelerations and projections) are unique and are what this solve gets right; the
    split of ``lam`` among redundant rows is not unique and is not normalised here."""
    lam = cho_solve(f.chol, rhs)
    if f.s is not None:
        for _ in range(LSQ_REFINE):
            lam = lam + cho_solve(f.chol, rhs - f.s @ lam)
    return lam
