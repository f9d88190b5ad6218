"""Joint-space dynamics ``A(q) qdd + C(q, qd) qd + Q(q) + Gamma_f(qd) = tau`` (Zafar eqs. 3, 17, 18).

The fast path works with 6-vectors in world axes about the world origin ``O_0`` (motion ``[w; v_0]``, force
``[n_0; f]``), so that every link and joint quantity lives in one frame and the tree enters only through the
static support mask ``S[j, k]`` (joint ``k`` moves link ``j``). The pose loop is the only per-link Python work;
everything else is a broadcast product or a product with the constant mask.

* ``A = sum_j J_j^T M_j J_j + diag(I_a)`` (the Hessian of eq. (11) w.r.t. ``qd``; tested against
  ``jax.hessian``). With joint columns ``s_k`` (``[a_k; p_k x a_k]`` revolute, ``[0; a_k]`` prismatic) the link
  Jacobian about ``O_0`` is ``J_j = [s_k S[j, k]]_k``, so ``A_ki = s_k^T (sum_{j in subtree(i)} M_j) s_i`` for
  ``k`` an ancestor of ``i`` (composite inertias: O(n^2)).
* ``C qd + Q``: link momenta rates ``M_j a_j + v_j x* M_j v_j`` with ``a_j = sum_k S[j,k] (v_k x s_k qd_k)`` and
  gravity as a base acceleration ``-g``, summed over subtrees and projected on ``s_k`` (a masked
  recursive-Newton–Euler). Tested against ``d/dt dE/dqd - dE/dq + dU/dq`` by autodiff of eqs. (11), (15).
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .aba import (aba, aba_one_state, batch_chunks, batch_lanes, batch_parts, one_state_sweeps, state_by_state,
                  supports_aba, tree_depth, wide_batch)
from ..inertia import unpack_params
from .kinematics import _mm, _mv, limit_deflections, link_poses, spring_deflections, world_axes
from .._jit import _as_array, compiled
from .._threads import inline_batch, run_parts, splits_safely, threads_apply
from .._xla import top_level
from .._ode import _ArrayImpl
from .._linalg import spd_solve_applied
from ..errors import ModelError
from .kinematics import _has_quaternions, _parameters_finite
from .model import TreeModel, check_quaternions_nonzero

__all__ = [
    "mass_matrix",
    "bias_forces",
    "coriolis_times_qdot",
    "gravity_torques",
    "friction_torques",
    "spring_torques",
    "limit_torques",
    "inverse_dynamics",
    "forward_dynamics",
]


class _Bodies(NamedTuple):
    """Link inertias about ``O_0`` in world axes, and joint motion columns."""

    m: Array  # (n,) masses
    h: Array  # (n, 3) first moments about O_0: m_j c_j
    j0: Array  # (n, 3, 3) inertia tensors about O_0
    s_w: Array  # (n, 3) angular part of the joint columns
    s_v: Array  # (n, 3) linear part (about O_0)




def _check(model: TreeModel, **vectors) -> None:
    """``q`` must have shape ``(nq,)``, every other named vector ``(nv,)`` (static: holds under tracing too)."""
    for name, v in vectors.items():
        n = model.nq if name == "q" else model.nv
        if jnp.shape(v) != (n,):
            what = "configuration entry" if name == "q" else "velocity coordinate"
            raise ModelError(f"{name} must have shape ({n},) (one entry per {what} of this model), got "
                             f"{jnp.shape(v)}")


def _bodies(model: TreeModel, q) -> _Bodies:
    check_quaternions_nonzero(model, q)  # concrete values only
    rot, pos = jax.lax.optimization_barrier(link_poses.raw(model, q))
    m, ms, j = unpack_params(model.inertia)
    hl = _mv(rot, ms)  # first moment about O_j, world axes
    jw = _mm(_mm(rot, j), jnp.swapaxes(rot, -1, -2))
    eye = jnp.eye(3)[None]
    pp = jnp.sum(pos * pos, -1)[:, None, None]
    ph = jnp.sum(pos * hl, -1)[:, None, None]
    outer_pp = pos[:, :, None] * pos[:, None, :]
    cross_ph = pos[:, :, None] * hl[:, None, :]
    j0 = jw + m[:, None, None] * (pp * eye - outer_pp) + 2.0 * ph * eye - cross_ph - jnp.swapaxes(cross_ph, -1, -2)
    h = m[:, None] * pos + hl
    a = world_axes(model, rot)
    rev = model.dof_revolute
    at = pos[model.dof_owner] if model.multi_dof else pos  # a point on each axis: its link's origin
    if rev.all():
        s_w, s_v = a, jnp.cross(at, a)
    else:
        rv = jnp.asarray(rev, dtype=pos.dtype)[:, None]
        s_w, s_v = rv * a, rv * jnp.cross(at, a) + (1.0 - rv) * a
    return _Bodies(m, h, j0, s_w, s_v)


def _apply_inertia(m, h, j0, w, v):
    """Spatial inertia about ``O_0`` times motion ``[w; v]`` -> momentum ``[n; f]``."""
    return _mv(j0, w) + jnp.cross(h, v), m[..., None] * v + jnp.cross(w, h)


def _mass_matrix(model: TreeModel, b: _Bodies) -> Array:
    sup = jnp.asarray(model.dof_support, dtype=b.m.dtype)  # (j, k)
    # Composite inertias of the subtree of each degree of freedom k: sum_j S[j, k] (m_j, h_j, J0_j).
    comp = sup.T @ jnp.concatenate([b.m[:, None], b.h, b.j0.reshape(-1, 9)], axis=1)
    mc, hc, jc = comp[:, 0], comp[:, 1:4], comp[:, 4:].reshape(-1, 3, 3)
    fn, ff = _apply_inertia(mc, hc, jc, b.s_w, b.s_v)  # (i, 3): composite momentum of unit motion of dof i
    g = jnp.sum(b.s_w[:, None, :] * fn[None, :, :] + b.s_v[:, None, :] * ff[None, :, :], -1)  # g[k, i]
    before = sup.T if not model.multi_dof else jnp.asarray(model.dof_before, dtype=b.m.dtype)
    lower = g * before  # keep k ancestor-or-self of i (one order among a free joint's six)
    a = model.coordinate_matrix(lower + lower.T - jnp.diag(jnp.diagonal(g)))
    if model.rotor_inertia is not None:
        a = a + jnp.diag(model.rotor_inertia)
    return a


def _rnea(model: TreeModel, b: _Bodies, qd, qdd, gravity) -> Array:
    """``sum_j J_j^T (M_j a_j + v_j x* M_j v_j)`` with ``a_j`` from ``qdd``, velocity products and ``-gravity``."""
    n = model.n_joints
    qd = None if qd is None else model.joint_values(qd, offset=False)
    qdd = None if qdd is None else model.joint_values(qdd, offset=False)
    sup = jnp.asarray(model.dof_support, dtype=b.m.dtype)  # (links, dofs)
    own = model.dof_owner if model.multi_dof else slice(None)
    acc_w = jnp.zeros((n, 3))
    acc_v = jnp.zeros((n, 3)) if gravity is None else jnp.broadcast_to(-gravity, (n, 3))
    col_w = jnp.zeros(b.s_w.shape)
    col_v = jnp.zeros(b.s_w.shape)
    if qd is not None:
        sw, sv = b.s_w * qd[:, None], b.s_v * qd[:, None]
        vel = sup @ jnp.concatenate([sw, sv], axis=1)  # link velocities
        vw, vv = vel[:, :3], vel[:, 3:]
        col_w = col_w + jnp.cross(vw[own], sw)  # v_owner(k) x_m (s_k qd_k)
        col_v = col_v + jnp.cross(vw[own], sv) + jnp.cross(vv[own], sw)
    if qdd is not None:
        col_w = col_w + b.s_w * qdd[:, None]
        col_v = col_v + b.s_v * qdd[:, None]
    if qd is not None or qdd is not None:
        acc = sup @ jnp.concatenate([col_w, col_v], axis=1)
        acc_w, acc_v = acc_w + acc[:, :3], acc_v + acc[:, 3:]
    fn, ff = _apply_inertia(b.m, b.h, b.j0, acc_w, acc_v)
    if qd is not None:
        pn, pf = _apply_inertia(b.m, b.h, b.j0, vw, vv)
        fn = fn + jnp.cross(vw, pn) + jnp.cross(vv, pf)  # v x* (M v)
        ff = ff + jnp.cross(vw, pf)
    sub = sup.T @ jnp.concatenate([fn, ff], axis=1)  # force transmitted by each joint
    return model.coordinate_forces(jnp.sum(b.s_w * sub[:, :3] + b.s_v * sub[:, 3:], -1))


def _concrete_checks(model: TreeModel, arrays: dict) -> None:
    """Checks before a compiled entry is dispatched, for models with quaternions: the shapes of the state vectors,
    then concrete values (a zero quaternion would give NaN). Other models need none here: shapes are checked when
    the entry is traced. Every model: non-finite parameters refused by name."""
    _parameters_finite(model)
    if _has_quaternions(model.kinds):
        _check(model, **{k: v for k, v in arrays.items() if k in ("q", "qd", "qdd", "tau")})
        check_quaternions_nonzero(model, arrays["q"])


@compiled("mass_matrix", check=_concrete_checks, arrays_only=True)
def mass_matrix(model: TreeModel, q: Float[ArrayLike, " n"]) -> Float[Array, "n n"]:
    """The inertia matrix ``A(q)`` of eq. (2), including rotor inertia ``I_a`` on the diagonal (eq. 18)."""
    _check(model, q=q)
    return _mass_matrix(model, _bodies(model, jnp.asarray(q)))


@compiled("bias_forces", check=_concrete_checks, arrays_only=True)
def bias_forces(model: TreeModel, q: Float[ArrayLike, " n"], qd: Float[ArrayLike, " n"]) -> Float[Array, " n"]:
    """``C(q, qd) qd + Q(q)`` (Coriolis, centrifugal and gravity torques; no friction)."""
    _check(model, q=q, qd=qd)
    return _rnea(model, _bodies(model, jnp.asarray(q)), jnp.asarray(qd), None, model.gravity)


@compiled("coriolis_times_qdot", check=_concrete_checks, arrays_only=True)
def coriolis_times_qdot(model: TreeModel, q: Float[ArrayLike, " n"], qd: Float[ArrayLike, " n"]) -> Float[Array, " n"]:
    """``C(q, qd) qd`` alone (no gravity); equals ``coriolis_matrix(model, q, qd) @ qd``."""
    _check(model, q=q, qd=qd)
    return _rnea(model, _bodies(model, jnp.asarray(q)), jnp.asarray(qd), None, None)


@compiled("gravity_torques", check=_concrete_checks, arrays_only=True)
def gravity_torques(model: TreeModel, q: Float[ArrayLike, " n"]) -> Float[Array, " n"]:
    """``Q(q) = dU/dq`` (eq. 5), as the joint torques holding the tree still against gravity."""
    _check(model, q=q)
    return _rnea(model, _bodies(model, jnp.asarray(q)), None, None, model.gravity)


def friction_torques(model: TreeModel, qd: Float[ArrayLike, " n"], *,
                     smooth_friction: Optional[float] = None) -> Float[Array, " n"]:
    """``Gamma_f = Fv qd + Fc sign(qd)`` (eq. 17); with ``smooth_friction=eps``, ``sign`` -> ``tanh(qd / eps)``.

    Zero (and free) when the model has no friction parameters.
    """
    qd = jnp.asarray(qd)
    out = jnp.zeros_like(qd)
    if model.viscous is not None:
        out = out + model.viscous * qd
    if model.coulomb is not None:
        s = jnp.sign(qd) if smooth_friction is None else jnp.tanh(qd / smooth_friction)
        out = out + model.coulomb * s
    return out


def spring_torques(model: TreeModel, q: Float[ArrayLike, " nq"]) -> Float[Array, " nv"]:
    """Generalised forces of the joint springs, ``-K d(q)`` (zero, and free, without ``stiffness``)."""
    if model.stiffness is None:
        return jnp.zeros(model.nv)
    return -model.stiffness * spring_deflections(model, q)


def limit_torques(model: TreeModel, q: Float[ArrayLike, " nq"], qd: Float[ArrayLike, " nv"]) -> Float[Array, " nv"]:
    """Soft joint limits: ``-k d - c qd`` while a coordinate is beyond a bound by ``d`` (zero inside), per velocity
    coordinate; zero, and free, without ``limits``. The damping acts only during a violation (as MuJoCo's soft
    limits), so the force jumps when a moving joint reaches its bound: an integrator meets a kink there."""
    qd = jnp.asarray(qd)
    if model.limits is None:
        return jnp.zeros_like(qd)
    x = limit_deflections(model, q)
    lo, hi, k, c = (model.limits[:, i] for i in range(4))
    return jnp.where(x != 0.0, -k * x - c * qd, 0.0)


@compiled("inverse_dynamics", static=("smooth_friction",), check=_concrete_checks, arrays_only=True)
def inverse_dynamics(model: TreeModel, q: Float[ArrayLike, " n"], qd: Float[ArrayLike, " n"],
                     qdd: Float[ArrayLike, " n"], *, smooth_friction: Optional[float] = None) -> Float[Array, " n"]:
    """``tau = A qdd + C qd + Q + Gamma_f`` (eqs. 3, 17, 18)."""
    _check(model, q=q, qd=qd, qdd=qdd)
    qd, qdd = jnp.asarray(qd), jnp.asarray(qdd)
    tau = _rnea(model, _bodies(model, jnp.asarray(q)), qd, qdd, model.gravity)
    if model.rotor_inertia is not None:
        tau = tau + model.rotor_inertia * qdd
    if model.viscous is not None or model.coulomb is not None:
        tau = tau + friction_torques(model, qd, smooth_friction=smooth_friction)
    if model.stiffness is not None:
        tau = tau - spring_torques(model, q)
    if model.limits is not None:
        tau = tau - limit_torques(model, q, qd)
    return tau


def _generalised_forces(model: TreeModel, q, qd, tau, smooth_friction):
    """``tau - Gamma_f + spring + limit`` forces for one state (nq,)/(nv,)."""
    if model.viscous is not None or model.coulomb is not None:
        tau = tau - friction_torques(model, qd, smooth_friction=smooth_friction)
    if model.stiffness is not None:
        tau = tau + spring_torques(model, q)
    if model.limits is not None:
        tau = tau + limit_torques(model, q, qd)
    return tau


def _forward_dynamics(model: TreeModel, q, qd, tau, smooth_friction):
    """One state: composite inertias and a Cholesky solve (small, shallow trees), or the articulated-body sweeps
    (large or deep trees, O(N) in time and in compile time)."""
    rhs = _generalised_forces(model, q, qd, tau, smooth_friction)
    if one_state_sweeps(model):
        return aba_one_state(model, q, qd, rhs)
    b = _bodies(model, q)
    return spd_solve_applied(_mass_apply, (model, b), _mass_matrix(model, b), rhs - _rnea(model, b, qd, None,
                                                                                      model.gravity))


def _mass_apply(params, x):
    """``A x`` without forming ``A``: inverse dynamics at zero velocity and gravity (O(N)); derivatives of the
    Cholesky solve take their ``dA lam`` from it (:func:`~particlesim._linalg.spd_solve_applied`)."""
    model, b = params
    ax = _rnea(model, b, None, x, None)
    return ax if model.rotor_inertia is None else ax + model.rotor_inertia * x


@compiled("forward_dynamics", static=("smooth_friction",), check=_concrete_checks, arrays_only=True)
def _one_state(model: TreeModel, q, qd, tau, smooth_friction=None):
    """One state, checked and compiled (the entry :func:`forward_dynamics` dispatches to)."""
    _check(model, q=q, qd=qd, tau=tau)
    return _forward_dynamics(model, q, qd, tau, smooth_friction)


def forward_dynamics(model: TreeModel, q: Float[ArrayLike, "... nq"], qd: Float[ArrayLike, "... nv"],
                     tau: Float[ArrayLike, "... nv"], *, smooth_friction: Optional[float] = None
                     ) -> Float[Array, "... nv"]:
    """``qdd = A^-1 (tau - C qd - Q - Gamma_f)``: one state, or a batch along leading axes.

    One state ``(nq,)``: a Cholesky factorisation of ``A`` (composite inertias) for trees of up to
    :data:`~.aba.UNROLL_LINKS` links, the articulated-body algorithm (:func:`~.aba.aba_one_state`, O(N)) beyond and
    for deep trees (mean link depth above :data:`~.aba.ONE_STATE_SWEEPS_DEPTH`, such as long chains). A batch
    ``(..., nq)`` (leading axes broadcast between ``q``, ``qd`` and ``tau``): the articulated-body sweeps with the batch
    as the innermost axis of every operation, several times faster per state than ``jax.vmap`` of the one-state
    call. A batch of at most one state per link of a tree up to :data:`~.aba.UNROLL_LINKS` links, passed from
    Python, runs state by state (:func:`~.aba.state_by_state`: the sweeps' fixed cost is not repaid by a few states);
    inside a caller's trace (``jit``, ``vmap``, ``grad``) a batch always takes the sweeps. A larger batch passed from
    Python is split into one part per usable core, each run on its own thread (:func:`~.aba.batch_parts`; set
    ``particlesim.tree.aba.BATCH_THREADS = 1`` for one program). Pass batches directly rather than vmapping; models
    with mimic, free or ball joints evaluate a batch state by state, where ``jax.jit(jax.vmap(...))`` of the one-state
    call is faster on one core (the direct call splits the batch over the cores).

    External wrenches enter through ``tau``: add :func:`~.kinematics.wrench_torques` (``J^T f``, eq. 16).
    ``smooth_friction=eps`` replaces ``sign(qd)`` by ``tanh(qd / eps)`` (differentiable at ``qd = 0``).
    """
    if _ndim(q) <= 1 and _ndim(qd) <= 1 and _ndim(tau) <= 1:  # one state (the common call: kept cheap)
        return _one_state(model, q, qd, tau, smooth_friction)
    # Python's work before dispatch is a small batch's largest cost: arrays pass through as they are (even a
    # conversion of an array already on the device costs time), and equal batch axes skip broadcasting.
    q, qd, tau = _as_array(q), _as_array(qd), _as_array(tau)
    nq, nv = model.nq, model.nv  # properties: read once
    for name, v, n in (("q", q, nq), ("qd", qd, nv), ("tau", tau, nv)):
        if v.ndim == 0 or v.shape[-1] != n:
            raise ModelError(f"{name} must have shape (..., {n}) (batch axes first, one entry per "
                             f"{'configuration entry' if name == 'q' else 'velocity coordinate'} last), got {v.shape}")
    if not q.shape[:-1] == qd.shape[:-1] == tau.shape[:-1]:
        try:
            batch = jnp.broadcast_shapes(q.shape[:-1], qd.shape[:-1], tau.shape[:-1])
        except ValueError:
            raise ModelError(f"batch axes of q {q.shape}, qd {qd.shape} and tau {tau.shape} do not "
                             "broadcast") from None
        q, qd, tau = (jnp.broadcast_to(v, batch + v.shape[-1:]) for v in (q, qd, tau))
    _parameters_finite(model)
    if _has_quaternions(model.kinds):  # (a method looked up on an equinox module is costly: only when needed)
        check_quaternions_nonzero(model, q)
    # A few states passed from Python (concrete arrays, no trace active) run state by state; inside a caller's trace
    # the sweeps stay, since an outer jax.vmap (over the states or only over parameters, the states captured) would
    # turn the loop into a loop of vmapped one-state programs, measured slower than the sweeps.
    size, links = math.prod(q.shape[:-1]), model.n_joints
    concrete = type(q) is _ArrayImpl and type(qd) is _ArrayImpl and type(tau) is _ArrayImpl and top_level()
    by_state = concrete and state_by_state(size, links)
    depth = tree_depth(model.parents)
    if concrete and not by_state:
        parts = batch_parts(size, links)
        if parts > 1 and threads_apply():  # a part per core, each on its own thread
            out = _in_parts(model, q, qd, tau, smooth_friction, size, parts, depth)
            if out is not None:
                return out
    wide = wide_batch(size, links, depth) and supports_aba(model)
    entry = _batched_wide if wide else _batched  # the same program; other XLA options for wide batches
    return entry(model, q, qd, tau, smooth_friction, by_state)


def _ndim(x) -> int:
    """``numpy.ndim`` without its dispatch for arrays (which carry ``ndim``)."""
    n = getattr(x, "ndim", None)
    return np.ndim(x) if n is None else n


@compiled("forward_dynamics batch", static=("smooth_friction", "by_state"), arrays_only=True, batch=True)
def _batched(model: TreeModel, q, qd, tau, smooth_friction, by_state=False):
    """A batch, compiled once per model structure and batch shape (hundreds of small operations would otherwise
    be dispatched one by one when called outside ``jit``), with XLA's reductions on its YNNPACK kernels
    (:data:`particlesim._xla.BATCH_OPTIONS`: the sweeps' reductions run over the trailing batch axis). Batches run in
    chunks (:func:`~.aba.batch_chunks`: of about 128 states for trees up to 32 links and 12 deep, past 1408 states
    for deeper ones up to 32 links, past about 8800 / N states beyond), padded
    as :func:`~.aba.batch_lanes` says (multiples of 64 lanes avoided; a multiple of 4 per chunk beyond 32 links). At
    most one state per link passed from Python (``by_state``, decided by :func:`forward_dynamics` with
    :func:`~.aba.state_by_state`): a loop over the one-state program. Wide batches go through :data:`_batched_wide`,
    the same function compiled with other XLA options."""
    per_state = functools.partial(_forward_dynamics, model, smooth_friction=smooth_friction)
    if by_state or not supports_aba(model):  # one after another; or composite inertias, in blocks
        # Blocks of states whose Cholesky factorisations one LAPACK call runs on its own thread: a larger batch of
        # them would spread over XLA's intra-op pool and block it, so that two parts could wait on each other
        # (particlesim._threads).
        flat = tuple(x.reshape(-1, x.shape[-1]) for x in (q, qd, tau))
        block = None if by_state else inline_batch(model.nv)
        out = jax.lax.map(lambda x: per_state(*x), flat, batch_size=block)
        return out.reshape(q.shape[:-1] + out.shape[-1:])
    rhs = tau
    if any(x is not None for x in (model.viscous, model.coulomb, model.stiffness, model.limits)):
        extra = functools.partial(_generalised_forces, model, smooth_friction=smooth_friction)
        rhs = jnp.vectorize(extra, signature="(a),(b),(b)->(b)")(q, qd, tau)
    batch, n = q.shape[:-1], q.shape[-1]
    q, qd, rhs = (x.reshape(-1, x.shape[-1]) for x in (q, qd, rhs))  # (B, n): one batch axis
    size = q.shape[0]
    k = batch_chunks(size, model.n_joints, tree_depth(model.parents))
    lanes = batch_lanes(-(-size // k), model.n_joints)
    if size == 0 or (k == 1 and lanes == size):
        return aba(model, q.T, qd.T, rhs.T).T.reshape(batch + (n,))
    # padded at the end with copies of the last state (cut off below), then k chunks of `lanes` states
    chunked = tuple(jnp.pad(x, ((0, k * lanes - size), (0, 0)), mode="edge").reshape(k, lanes, -1).transpose(0, 2, 1)
                    for x in (q, qd, rhs))
    if k == 1:
        out = aba(model, *(x[0] for x in chunked))[None]
    else:
        out = jax.lax.map(lambda x: aba(model, *x), chunked)  # (k, n, lanes), chunk after chunk
    return out.transpose(0, 2, 1).reshape(k * lanes, -1)[:size].reshape(batch + (n,))


def _in_parts(model: TreeModel, q, qd, tau, smooth_friction, size: int, parts: int, depth: int):
    """A concrete batch in ``parts`` equal parts of ``count`` states, each run by one compiled program
    (:func:`_batched_part`) on its own thread (:func:`particlesim._threads.run_parts`). The parts start at
    ``i * count``, the last at ``size - count`` (it overlaps its neighbour when ``parts`` does not divide ``size``;
    :func:`_join` drops the repeated states). ``None`` when the part program cannot run beside its copies
    (:func:`particlesim._threads.splits_safely`): the caller then runs the batch as one program."""
    count = -(-size // parts)
    parts = -(-size // count)  # (many parts of a small batch: fewer, so that at most the last one overlaps)
    wide = wide_batch(count, model.n_joints, depth) and supports_aba(model)
    entry = _batched_part_wide if wide else _batched_part
    starts = [min(i * count, size - count) for i in range(parts)]
    args = [(model, q, qd, tau, _offset(s), smooth_friction, count) for s in starts]
    key = (jax.tree.structure(model), q.shape, qd.shape, tau.shape, smooth_friction, count)
    if not splits_safely(entry.jit, args[0], key):  # run unsplit (None); not met by our own programs (_batched)
        return None
    # Concurrent first calls compile once (JAX waits for a compile in flight; TopJit builds its jit under a lock).
    outs = run_parts(entry, args, what=f"forward_dynamics over a batch of {size} states in {parts} parts",
                     describe=lambda k: f"part {k + 1} (states {starts[k]}..{starts[k] + count - 1})")
    return _join(tuple(outs), parts * count - size, q.shape[:-1])


@functools.lru_cache(maxsize=256)
def _offset(start: int):
    """A part's first state as a device scalar (kept: making one on every call costs time)."""
    return jnp.asarray(start, dtype=jnp.int32)


@functools.partial(jax.jit, static_argnames=("repeated", "batch"))
def _join(outs, repeated: int, batch: tuple):
    """The parts' results as one batch of shape ``batch + (n,)``, the last part's first ``repeated`` states (also in
    the part before it) dropped."""
    outs = (*outs[:-1], outs[-1][repeated:])
    return jnp.concatenate(outs).reshape(batch + outs[0].shape[-1:])


@compiled("forward_dynamics batch part", static=("smooth_friction", "count"), arrays_only=True, batch=True)
def _batched_part(model: TreeModel, q, qd, tau, start, smooth_friction, count):
    """States ``start .. start + count`` of a batch (flattened over its batch axes), as :func:`_batched` evaluates
    them; ``start`` is traced, so that every part of a batch shares one program."""
    part = tuple(jax.lax.dynamic_slice_in_dim(x.reshape(-1, x.shape[-1]), start, count) for x in (q, qd, tau))
    return _batched.raw(model, *part, smooth_friction)


_batched_part_wide = compiled("forward_dynamics wide batch part", static=("smooth_friction", "count"),
                              arrays_only=True, batch="wide")(_batched_part.raw)


#: The batch entry for wide batches (:func:`~.aba.wide_batch`): the same program compiled with XLA's fusion emitters
#: kept (``particlesim._xla.cpu_options(batch="wide")``), 3-5 % faster per state there at no cost in compile time.
_batched_wide = compiled("forward_dynamics wide batch", static=("smooth_friction", "by_state"), arrays_only=True,
                         batch="wide")(_batched.raw)
