"""Kinematics of a :class:`TreeModel`: link poses, velocities (Zafar eqs. 7–8), Jacobians (§3), wrench torques (eq. 16).

Frames: ``R[j]`` maps link-``j`` coordinates to world coordinates and ``p[j]`` is the link origin ``O_j`` in the
world (the report's ``^0A_j`` and ``^0P_j``). A frame Jacobian ``J_j`` (6 x n) stacks the linear velocity of ``O_j``
over the angular velocity of link ``j``: ``[v; w] = J_j qd`` (the report's ``\\mathbb{J}_j``), expressed in world axes
(``frame="world"``, the report's ``^0\\mathbb{J}_j``; Pinocchio's LOCAL_WORLD_ALIGNED) or in link axes
(``frame="local"``, ``^j\\mathbb{J}_j``; Pinocchio's LOCAL).
"""

from __future__ import annotations

import functools
import weakref

import jax
import jax.numpy as jnp
import numpy as np
from jax.custom_batching import custom_vmap
from jaxtyping import Array, ArrayLike, Float

from .. import _ode
from .._jit import compiled
from ..errors import ModelError
from ..spatial import quaternion_to_matrix, unit_axis_rotations
from .model import BALL, FREE, TreeModel, check_quaternions_nonzero

__all__ = [
    "joint_transforms",
    "link_poses",
    "link_velocities",
    "world_axes",
    "link_jacobians",
    "link_jacobian",
    "frame_pose",
    "wrench_torques",
    "spring_deflections",
    "limit_deflections",
]


def _mm(a, b):
    """Small matrix product (3x3, 3x4 by 4x4) as a broadcast sum: fuses with its neighbours on CPU (tiny ``dot`` ops
    do not)."""
    return jnp.sum(a[..., :, :, None] * b[..., None, :, :], axis=-2)


def _mv(a, x):
    """3x3 matrix times 3-vector as a broadcast sum."""
    return jnp.sum(a * x[..., None, :], axis=-1)


def joint_transforms(model: TreeModel, q: Float[ArrayLike, " n"]):
    """Parent-from-child poses ``(R (n,3,3), p (n,3))`` of every joint at ``q`` (the report's ``^iT_j``), vectorised.

    ``q`` holds the model's coordinates (mimic joints follow their sources; a free joint reads its position and
    quaternion ``[x, y, z, qx, qy, qz, qw]``)."""
    qf = model.joint_values(jnp.asarray(q))
    free = [i for i, k in enumerate(model.kinds) if k in (FREE, BALL)]
    first = np.concatenate([[0], np.cumsum(model.joint_nq)[:-1]])
    q = qf[first] if free else qf
    ax = model.axes_array
    rev = model.is_revolute
    r0 = jnp.asarray(model.origin_rotation_array)
    if rev.all():
        r = _mm(r0, unit_axis_rotations(jnp.asarray(ax), q))
        p = model.origin_xyz
    else:
        angle = jnp.where(jnp.asarray(rev), q, 0.0)
        slide = jnp.where(jnp.asarray(rev | np.array([k in (FREE, BALL) for k in model.kinds])), 0.0, q)
        r = _mm(r0, unit_axis_rotations(jnp.asarray(ax), angle))
        p = model.origin_xyz + _mv(r0, jnp.asarray(ax) * slide[:, None])
    for i in free:  # a free or ball joint's own motion, after its placement (R0, p0)
        if model.kinds[i] == FREE:
            pos, quat = qf[first[i]:first[i] + 3], qf[first[i] + 3:first[i] + 7]
            p = p.at[i].set(model.origin_xyz[i] + r0[i] @ pos)
        else:
            quat = qf[first[i]:first[i] + 4]
        r = r.at[i].set(r0[i] @ quaternion_to_matrix(quat))
    return r, p


@functools.lru_cache(maxsize=256)
def _has_quaternions(kinds: tuple) -> bool:
    return FREE in kinds or BALL in kinds


#: TreeModels whose parameters passed :func:`_parameters_finite`: ``id -> weak reference``.
_FINITE: dict = {}


def _parameters_finite(model: TreeModel) -> None:
    """Before dispatch: a NaN or infinite parameter (set with ``with_params`` or ``eqx.tree_at``, which do not check)
    is refused by name (``ModelError``) instead of giving NaN. Traced parameters pass (the caller's own entry checks
    them). A model whose parameters are all JAX arrays is remembered by identity while it lives: its fields cannot be
    reassigned and hold arrays directly (no containers), and JAX arrays are immutable, so it stays as checked; the
    identity test is far cheaper than :func:`particlesim._ode.check_finite_eager`'s comparison of leaves, a sizeable
    part of a single call. Models holding NumPy arrays are checked on every call."""
    ref = _FINITE.get(id(model))
    if ref is not None and ref() is model:
        return
    groups = _parameter_groups(model)
    _ode.check_finite("TreeModel", groups)  # raises ModelError on a concrete non-finite entry
    if all(type(arr) is _ode._ArrayImpl for arr in jax.tree.leaves(model)):
        key = id(model)
        _FINITE[key] = weakref.ref(model, lambda _, key=key: _FINITE.pop(key, None))


def _parameter_groups(model: TreeModel) -> list:
    """``(label, array)`` of every parameter; the per-link arrays (inertia, joint origins) labelled link by link;
    soft limits with their infinite bounds (an unlimited side, e.g. a continuous joint's) read as zero, so that only
    NaN bounds and non-finite stiffness or damping count as not finite."""
    per_link = {".inertia": "inertia", ".origin_xyz": "origin_xyz"}
    return [([f"{per_link[label]} of link '{name}'" for name in model.link_names], leaf) if label in per_link
             else (label, _finite_bounds(leaf) if label == ".limits" else leaf)
             for label, leaf in _ode.leaf_groups(model)]


def _finite_bounds(limits):
    """``limits`` ``(nv, 4)`` with a lower bound of ``-inf`` and an upper bound of ``+inf`` (no stop on that side)
    replaced by zero; NaN, and an infinite bound on the wrong side, kept (refused as not finite)."""
    xp = np if _ode._concrete(limits) else jnp
    lim = xp.asarray(limits)
    col = xp.broadcast_to(xp.arange(lim.shape[-1]), lim.shape)
    open_side = ((col == 0) & (lim == -xp.inf)) | ((col == 1) & (lim == xp.inf))
    return xp.where(open_side, 0.0, lim)


def _quaternion_checks(model: TreeModel, arrays: dict) -> None:
    """Before dispatch: a non-finite parameter and a concrete zero quaternion are named (the compiled function
    would return NaN)."""
    _parameters_finite(model)
    if _has_quaternions(model.kinds):
        q = arrays["q"]
        if jnp.shape(q)[-1:] == (model.nq,):
            check_quaternions_nonzero(model, q)


@functools.lru_cache(maxsize=64)
def _ancestor_rounds(parents: tuple) -> tuple[np.ndarray, ...]:
    """The rounds of :func:`link_poses`' composition by pointer jumping: in round ``r`` each link's pose so far (its
    pose relative to its ancestor ``2^r`` generations up) is composed with that ancestor's, ``n`` standing for the
    world; ceil(log2(depth)) rounds for a tree ``depth`` links deep."""
    n = len(parents)
    anc = np.asarray([p if p >= 0 else n for p in parents] + [n], dtype=np.int32)
    rounds = []
    while (anc[:n] < n).any():
        rounds.append(anc[:n].copy())
        anc = anc[anc]
    return tuple(rounds)


#: A ``jax.vmap`` of more than this many states composes link poses link by link (:func:`_composer`): the pointer
#: jumping's fewer kernels win for one state and small batches, its extra arithmetic loses on wide ones.
VMAP_JUMPING_MAX_STATES = 16


def _jumping(parents: tuple, t: Array) -> Array:
    """World ``[R | p]`` (n, 3, 4) by pointer jumping (:func:`_ancestor_rounds`): each round multiplies the
    ancestors' ``[R | p]`` by the links' homogeneous 4 x 4 transforms."""
    n = t.shape[0]
    # the gathered table's last entry is the world; the links' transforms get the homogeneous row [0 0 0 1]
    world = jnp.concatenate([jnp.eye(3, dtype=t.dtype), jnp.zeros((3, 1), t.dtype)], axis=1)[None]
    last = jnp.broadcast_to(jnp.asarray([0.0, 0.0, 0.0, 1.0], t.dtype), (n, 1, 4))
    for anc in _ancestor_rounds(parents):
        t = _mm(jnp.concatenate([t, world])[anc], jnp.concatenate([t, last], axis=1))
    return t


def _link_by_link(parents: tuple, order: tuple, t: Array) -> Array:
    """World ``[R | p]`` (n, 3, 4) link by link, parents first: ``R_i = R_k R_rel``, ``p_i = p_k + R_k p_rel``."""
    rs, ps = [None] * len(parents), [None] * len(parents)
    for i in order:
        k = parents[i]
        if k < 0:
            rs[i], ps[i] = t[i, :, :3], t[i, :, 3]
        else:
            rs[i], ps[i] = _mm(rs[k], t[i, :, :3]), ps[k] + _mv(rs[k], t[i, :, 3])
    return jnp.concatenate([jnp.stack(rs), jnp.stack(ps)[:, :, None]], axis=2)


@functools.lru_cache(maxsize=64)
def _composer(parents: tuple, order: tuple):
    """The pose composition of one tree as a ``custom_vmap`` function of ``t`` (n, 3, 4): pointer jumping, and under
    ``jax.vmap`` of more than :data:`VMAP_JUMPING_MAX_STATES` states link by link. 128 Krang rollouts vmapped
    together took 20.1-20.2 s jumping, 15.4-16.0 s link by link before the jumping, 14.8-15.0 s with this rule;
    in chunks of 4 (``sharded_vmap(..., chunk=4)``) all three the same, 5.7-5.9 s (A/B, fresh processes)."""

    @custom_vmap
    def compose(t):
        return _jumping(parents, t)

    @compose.def_vmap
    def _rule(axis_size, in_batched, t):  # called only with t batched (its one argument)
        if axis_size <= VMAP_JUMPING_MAX_STATES:
            return jax.vmap(functools.partial(_jumping, parents))(t), True
        return jax.vmap(functools.partial(_link_by_link, parents, order))(t), True

    return compose


@functools.partial(jax.custom_jvp, nondiff_argnums=(0, 1))
def _compose(parents: tuple, order: tuple, t: Array) -> Array:
    """World ``[R | p]`` (n, 3, 4) of every link from the parent-from-child ``[R | p]`` (n, 3, 4) (:func:`_composer`;
    ``order`` lists the links parents first)."""
    return _composer(parents, order)(t)


@_compose.defjvp
def _compose_jvp(parents, order, primals, tangents):
    """Tangents link by link, parents first (``dW_i = dW_k T_i + W_k dT_i`` for parent ``k``, as R and p):
    differentiating the pointer-jumping rounds instead repeats every round's product per tangent, which made a
    forward-mode gradient of Krang's rollout much slower than the link-by-link composition; this way it costs what
    that composition's does, and the value keeps the rounds' few kernels."""
    (t,), (dt,) = primals, tangents
    w = _compose(parents, order, t)
    drs, dps = [None] * len(parents), [None] * len(parents)
    for i in order:
        k = parents[i]
        if k < 0:
            drs[i], dps[i] = dt[i, :, :3], dt[i, :, 3]
        else:
            # W_i = [R_k R_i | R_k p_i + p_k]: dR_i^w = dR_k R_i + R_k dR_i, dp_i^w = dR_k p_i + R_k dp_i + dp_k
            r_k = w[k, :, :3]
            drs[i] = _mm(drs[k], t[i, :, :3]) + _mm(r_k, dt[i, :, :3])
            dps[i] = _mv(drs[k], t[i, :, 3]) + _mv(r_k, dt[i, :, 3]) + dps[k]
    return w, jnp.concatenate([jnp.stack(drs), jnp.stack(dps)[:, :, None]], axis=2)


@compiled("link_poses", check=_quaternion_checks, arrays_only=True)
def link_poses(model: TreeModel, q: Float[ArrayLike, " n"]):
    """World poses ``(R (n,3,3), p (n,3))`` of all link frames (forward kinematics).

    Composed by pointer jumping over the tree (:func:`_ancestor_rounds`): every round composes all links at once with
    the pose of an ancestor twice as far up, so a tree of depth ``d`` takes about log2(d) vectorised rounds instead of
    one small product per link. Krang (18 links, 10 deep): 4 rounds instead of 17 link-by-link products, which makes
    its forward dynamics faster, one state or a few vmapped (XLA's CPU runtime pays for every kernel it dispatches:
    its one-state forward dynamics needs 37 kernels instead of 80). Wide ``jax.vmap`` batches compose link by link
    instead, where the rounds' extra arithmetic would show (:func:`_composer`; a batch passed to
    :func:`~.dynamics.forward_dynamics` takes the articulated-body sweeps unless it is a few states from Python).
    Derivatives are taken link by link (:func:`_compose_jvp`). Poses are composed as 3 x 4 ``[R | p]``: faster, one
    state or vmapped, than square 4 x 4 transforms (much slower vmapped) or ``R`` and ``p`` composed separately."""
    r_rel, p_rel = joint_transforms(model, q)
    t = jnp.concatenate([r_rel, p_rel[:, :, None]], axis=2)  # [R | p] (n, 3, 4)
    w = _compose(tuple(model.parents), tuple(model.topological_order), t)
    return w[:, :, :3], w[:, :, 3]


@compiled("link_velocities", check=_quaternion_checks, arrays_only=True)
def link_velocities(model: TreeModel, q: Float[ArrayLike, " n"], qd: Float[ArrayLike, " n"]):
    """Angular and linear velocities ``(w (n,3), v (n,3))`` of the link frames, each in its own link axes.

    The recursion of Zafar eqs. (7)–(8): ``w_j = A_ji w_i + e_j qd_j`` and ``V_j = A_ji (V_i + w_i x P_j)``
    (plus ``e_j qd_j`` for a prismatic joint), with ``A_ji = (^iA_j)^T`` and ``P_j`` the origin of ``j`` in ``i``.
    """
    qd = model.joint_values(jnp.asarray(qd), offset=False)
    r_rel, p_rel = joint_transforms(model, q)
    e = jnp.asarray(model.axes_array)
    rev = model.is_revolute
    first = np.concatenate([[0], np.cumsum(model.joint_nv)[:-1]])
    ws, vs = [None] * model.n_joints, [None] * model.n_joints
    for j in model.topological_order:
        i = model.parents[j]
        a_ji = r_rel[j].T
        if i < 0:
            w, v = jnp.zeros(3), jnp.zeros(3)
        else:
            w = a_ji @ ws[i]
            v = a_ji @ (vs[i] + jnp.cross(ws[i], p_rel[j]))
        d = first[j]
        if model.kinds[j] == FREE:  # [v; w] of the link, in its own axes
            v, w = v + qd[d:d + 3], w + qd[d + 3:d + 6]
        elif model.kinds[j] == BALL:
            w = w + qd[d:d + 3]
        elif rev[j]:
            w = w + e[j] * qd[d]
        else:
            v = v + e[j] * qd[d]
        ws[j], vs[j] = w, v
    return jnp.stack(ws), jnp.stack(vs)


def world_axes(model: TreeModel, rot: Float[Array, "n 3 3"]) -> Float[Array, "d 3"]:
    """Axes of the joint degrees of freedom in world coordinates, ``a_k = R_k e_k`` (the axis is fixed in the
    child link; a free joint contributes its link's three axes twice: translations, then rotations)."""
    if not model.multi_dof:
        return _mv(rot, jnp.asarray(model.axes_array))
    return _mv(rot[model.dof_owner], jnp.asarray(model.dof_axes))


def link_jacobians(model: TreeModel, rot, pos) -> Float[Array, "n 6 nq"]:
    """World-axes Jacobians of all link origins from poses, vectorised with the static support mask (§3).
    Columns are the model's coordinates (a mimic joint's column is added to its source's, times the multiplier).

    Column ``k`` of ``J_j``: ``[a_k x (p_j - p_k); a_k]`` (revolute) or ``[a_k; 0]`` (prismatic) if degree of freedom
    ``k`` moves link ``j``, else zero, with ``p_k`` the origin of the link that carries it (a free joint: three
    prismatic columns along its link's axes, then three revolute ones about them).
    """
    a = world_axes(model, rot)  # (d, 3) indexed by degree of freedom k
    mask = jnp.asarray(model.dof_support, dtype=pos.dtype)  # (j, k)
    rev = model.dof_revolute
    at = pos[model.dof_owner] if model.multi_dof else pos
    r = pos[:, None, :] - at[None, :, :]  # (j, k, 3): p_j - p_owner(k)
    ak = jnp.broadcast_to(a[None, :, :], r.shape)
    if rev.all():
        lin = jnp.cross(ak, r)
        ang = ak
    else:
        rv = jnp.asarray(rev, dtype=pos.dtype)[None, :, None]
        lin = rv * jnp.cross(ak, r) + (1.0 - rv) * ak
        ang = rv * ak
    jac = jnp.concatenate([lin, ang], axis=-1) * mask[:, :, None]  # (j, k, 6)
    jac = jnp.swapaxes(jac, 1, 2)
    if any(model.mimic):
        jac = jac @ jnp.asarray(model.coordinate_map[0])  # joint columns -> coordinate columns
    return jac


def _frame_rotation(rot, frame: str):
    if frame == "world":
        return None
    if frame == "local":
        return jnp.swapaxes(rot, -1, -2)
    raise ModelError(f"unknown Jacobian frame {frame!r} (expected 'world' or 'local')")


@compiled("frame_pose", static=("name",), check=_quaternion_checks, arrays_only=True)
def frame_pose(model: TreeModel, q: Float[ArrayLike, " n"], name) -> tuple[Float[Array, "3 3"], Float[Array, "3"]]:
    """World pose ``(R, p)`` of a link (index or name) or of a frame fixed to one (a URDF link merged by a fixed
    joint: ``tool0``, ``panda_hand``, ...)."""
    rot, pos = link_poses.raw(model, q)
    fr = model.frame(name) if isinstance(name, str) else None
    if fr is None:
        j = model.link_index(name)
        return rot[j], pos[j]
    owner, r, p = fr
    if owner < 0:
        return jnp.asarray(r), jnp.asarray(p)
    return rot[owner] @ r, pos[owner] + rot[owner] @ p


@compiled("link_jacobian", static=("link", "frame"), check=_quaternion_checks, arrays_only=True)
def link_jacobian(model: TreeModel, q: Float[ArrayLike, " n"], link, *, frame: str = "world") -> Float[Array, "6 n"]:
    """The 6 x n Jacobian of link ``link`` (index or name, or a frame fixed to a link): ``[v_O; w] = J qd`` with
    ``v_O`` the velocity of its origin, in world or its own axes (§3)."""
    fr = model.frame(link) if isinstance(link, str) else None
    if fr is not None:
        owner, r, p = fr
        rot, pos = link_poses.raw(model, q)
        if owner < 0:
            return jnp.zeros((6, model.nv))
        jac = link_jacobians(model, rot, pos)[owner]
        off = rot[owner] @ p  # frame origin from the link origin, world axes: v_f = v_O + w x off
        skew = jnp.array([[0.0, -off[2], off[1]], [off[2], 0.0, -off[0]], [-off[1], off[0], 0.0]])
        jac = jnp.concatenate([jac[:3] - skew @ jac[3:], jac[3:]], axis=0)
        rt = _frame_rotation(rot[owner] @ r, frame)
        if rt is not None:
            jac = jnp.concatenate([rt @ jac[:3], rt @ jac[3:]], axis=0)
        return jac
    j = model.link_index(link)
    rot, pos = link_poses.raw(model, q)
    jac = link_jacobians(model, rot, pos)[j]
    rt = _frame_rotation(rot[j], frame)
    if rt is not None:
        jac = jnp.concatenate([rt @ jac[:3], rt @ jac[3:]], axis=0)
    return jac


@compiled("wrench_torques", static=("link", "frame"), check=_quaternion_checks, arrays_only=True)
def wrench_torques(model: TreeModel, q: Float[ArrayLike, " n"], link, wrench: Float[ArrayLike, "6"], *,
                   frame: str = "world") -> Float[Array, " n"]:
    """Joint torques ``J_j^T f`` of a wrench ``f = [force; moment]`` acting on ``link`` at its origin (eq. 16).

    ``frame`` says in which axes ``wrench`` is given (``"world"`` or ``"local"``, as for :func:`link_jacobian`).
    Several wrenches on several links add: sum the results.
    """
    w = jnp.asarray(wrench, dtype=float)
    if w.shape != (6,):
        raise ModelError(f"wrench must have shape (6,) = [force; moment], got {w.shape}")
    return link_jacobian.raw(model, q, link, frame=frame).T @ w


def _quat_mul(a, b):
    """Hamilton product of quaternions ``[x, y, z, w]``."""
    av, aw, bv, bw = a[:3], a[3], b[:3], b[3]
    return jnp.concatenate([aw * bv + bw * av + jnp.cross(av, bv), (aw * bw - av @ bv)[None]])


def _rotation_vector(quat):
    """Rotation vector of a quaternion ``[x, y, z, w]`` (angle in [0, pi], as MuJoCo's ``quat2Vel``)."""
    quat = quat / jnp.linalg.norm(quat)
    quat = jnp.where(quat[3] < 0.0, -quat, quat)
    v, w = quat[:3], quat[3]
    n = jnp.linalg.norm(v)
    safe = jnp.where(n > 1e-12, n, 1.0)
    return jnp.where(n > 1e-12, 2.0 * jnp.arctan2(safe, w) / safe, 2.0 / w) * v


def spring_deflections(model: TreeModel, q: Float[ArrayLike, " nq"]) -> Float[Array, " nv"]:
    """Deflection of each joint spring from ``spring_ref``, one entry per velocity coordinate: ``q - q_ref`` for
    hinges and slides, the rotation vector of ``q_ref^-1 q`` (child axes) for ball joints (MuJoCo's ``subQuat``)."""
    q = jnp.asarray(q)
    ref = model.spring_ref
    parts = []
    for _, kind, iq, _ in model.coordinate_blocks():
        if kind == BALL:
            conj = ref[iq:iq + 4] * jnp.array([-1.0, -1.0, -1.0, 1.0])
            parts.append(_rotation_vector(_quat_mul(conj, q[iq:iq + 4])))
        elif kind == FREE:
            parts.append(jnp.zeros(6))  # no springs on free joints (refused at construction)
        else:
            parts.append(q[iq:iq + 1] - ref[iq:iq + 1])
    return jnp.concatenate(parts)


def limit_deflections(model: TreeModel, q: Float[ArrayLike, " nq"]) -> Float[Array, " nv"]:
    """How far each coordinate is beyond its soft limit (``q - upper > 0``, ``q - lower < 0``, else 0), per velocity
    coordinate (free and ball coordinates: 0)."""
    q = jnp.asarray(q)
    x = jnp.concatenate([jnp.zeros(model.joint_nv[i]) if kind in (FREE, BALL) else q[iq:iq + 1]
                         for i, kind, iq, _ in model.coordinate_blocks()])
    lo, hi = model.limits[:, 0], model.limits[:, 1]
    return jnp.minimum(x - lo, 0.0) + jnp.maximum(x - hi, 0.0)
