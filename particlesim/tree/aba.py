"""Forward dynamics by the articulated-body algorithm (ABA), O(N) in the links and vectorised over a batch.

The same equations as :func:`~.dynamics.forward_dynamics` (``A qdd = tau - C qd - Q - Gamma_f``), solved without
forming ``A``: Featherstone's three sweeps (Rigid Body Dynamics Algorithms, 2008, §7.3), written in world axes about
the world origin as the rest of :mod:`.dynamics` (motion ``[w; v_0]``, force ``[n_0; f]``), so that an articulated
inertia passes to its parent by a plain sum, with no frame change:

1. outward: link poses, joint columns ``s_i``, velocities ``v_i = v_p + s_i qd_i``, velocity-product accelerations
   ``c_i = v_i x s_i qd_i``, rigid inertias ``I_i`` and bias forces ``p_i = v_i x* I_i v_i``;
2. inward: ``U_i = I^A_i s_i``, ``D_i = s_i . U_i + I_a,i`` (rotor inertia), ``u_i = tau_i - s_i . p^A_i``, and the
   parent receives ``I^A_i - U_i U_i^T / D_i`` and ``p^A_i + I^a_i c_i + U_i u_i / D_i``;
3. outward: ``a_i = a_p + c_i``, ``qdd_i = (u_i - U_i . a_i) / D_i``, ``a_i += s_i qdd_i`` from ``a_world = [0; -g]``.

Layout: batch axes come *last* (a link's inertia is ``(6, 6, *B)``), so that every operation is one vectorised loop
over the batch; under ``jax.vmap`` of a one-state function the batch would come first and every small product would
loop over axes of length 3 or 6. Trees up to :data:`UNROLL_LINKS` links have their sweeps written out link by link
(the fastest program; compile time grows with the tree); larger trees run each sweep as one ``lax.scan`` over the
links with one stacked buffer (sweeps 1 and 3 read the parent's row, sweep 2 pulls the children's rows; one row
written per step): compile time flat in N, cost per state O(N). One state of a large or deep tree
takes :func:`aba_one_state`: the same sweeps with only the recursions in loops and the link terms vectorised over links.

Covers trees of revolute and prismatic joints (rotor inertia, viscous and Coulomb friction, joint springs and soft
limits as generalised forces); models with mimic, free or ball joints use the composite-inertia path.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from ..inertia import unpack_params
from .._threads import usable_cores
from ..spatial import sincos
from .model import PRISMATIC, REVOLUTE, TreeModel

__all__ = ["UNROLL_LINKS", "ONE_STATE_SWEEPS_DEPTH", "BATCH_CHUNK", "BATCH_CHUNK_ABOVE", "batch_chunks",
           "batch_lanes", "state_by_state", "WIDE_BATCH", "wide_batch", "LOOP_CHUNK_LINK_STATES", "LOOP_CHUNK_MAX",
           "supports_aba", "one_state_sweeps", "SHALLOW_DEPTH", "SHALLOW_CHUNK", "tree_depth", "aba", "aba_one_state",
           "BATCH_THREADS", "PART_LINK_STATES", "usable_cores", "batch_parts"]


@functools.lru_cache(maxsize=64)
def _depths(parents: tuple) -> tuple[int, ...]:
    """Each link's depth in the tree: 0 for a child of the world."""
    depth = [-1] * len(parents)
    while depth and min(depth) < 0:  # parents are acyclic (checked by TreeModel): at most n passes
        for i, p in enumerate(parents):
            if depth[i] < 0 and (p < 0 or depth[p] >= 0):
                depth[i] = 0 if p < 0 else depth[p] + 1
    return tuple(depth)


@functools.lru_cache(maxsize=64)
def _order(parents: tuple) -> tuple[np.ndarray, np.ndarray]:
    """Links parents first, and each link's parent as a position in that order (``n``: the world)."""
    n = len(parents)
    depth = _depths(parents)
    order = np.asarray(sorted(range(n), key=lambda i: (depth[i], i)), dtype=np.int32)
    pos = np.empty(n, dtype=np.int32)
    pos[order] = np.arange(n, dtype=np.int32)
    parent_pos = np.asarray([pos[parents[i]] if parents[i] >= 0 else n for i in order], dtype=np.int32)
    return order, parent_pos


@functools.lru_cache(maxsize=64)
def _children(parents: tuple) -> np.ndarray:
    """``(n, C)`` positions (in :func:`_order`) of each link's children, padded with ``n``; at least one column."""
    order, parent_pos = _order(parents)
    n = len(parents)
    kids = [[] for _ in range(n)]
    for i, p in enumerate(parent_pos):
        if p < n:
            kids[p].append(i)
    width = max(1, max(len(k) for k in kids))
    return np.asarray([k + [n] * (width - len(k)) for k in kids], dtype=np.int32)


#: Trees up to this many links unroll their sweeps (fastest program); larger ones keep a loop over links, so that
#: the compiled program, and its compile time, do not grow with the tree.
UNROLL_LINKS = 32


#: A batch of states of a deep tree (written-out sweeps, more than :data:`SHALLOW_DEPTH` links from root to tip) runs
#: the sweeps on chunks of about this many states, one chunk after another, once it is larger than
#: :data:`BATCH_CHUNK_ABOVE` (:func:`batch_chunks`). A link's articulated inertias for 1024 states take 295 kB,
#: within a core's L2 cache; the whole batch at once costs more per state as it grows, and smaller batches cost more
#: per state too (even padded off multiples of 64 lanes: :func:`batch_lanes`). Chosen on Krang before it took the
#: shallow rule below; of deeper trees only chains of 18 and 25 links were compared (against chunks of about 128).
BATCH_CHUNK = 1024
#: Batches up to this size run whole (their chunks would fall to about 700 states).
BATCH_CHUNK_ABOVE = 1408
#: Shallow trees (at most :data:`SHALLOW_DEPTH` links from the root to any tip) run a batch in chunks of about
#: :data:`SHALLOW_CHUNK` states instead (136 lanes for 1024 states: :func:`batch_lanes`), so that the three sweeps
#: work on one chunk's link quantities at a time (estimated 1.5 MB, near a core's 1 MB L2 cache here, against 12 MB
#: for 1024 states; that this is the reason is a hypothesis). Per state, faster than the deep trees' rule
#: (:data:`BATCH_CHUNK`) on Krang (18 links, depth 10) and serial chains of 7 and 12 links, slower on chains of 18 and
#: 25 links (why is not established), hence the bound on the depth. Compiled with
#: :data:`particlesim._xla.BATCH_OPTIONS` (not wide), which ran and compiled faster on Krang than the wide options.
SHALLOW_DEPTH = 12
SHALLOW_CHUNK = 128
#: Chunks of at least this many states (of a tree up to :data:`UNROLL_LINKS` links: the whole batch or every chunk
#: of :func:`batch_chunks`) are compiled with XLA's fusion emitters kept (:func:`wide_batch`;
#: ``particlesim._xla.cpu_options(batch="wide")`` says why).
WIDE_BATCH = 705


#: Trees beyond :data:`UNROLL_LINKS` links loop over links with stacked buffers of every link's row for the whole
#: chunk (about 1 kB per link and state); their chunks hold at most about this many link-states (and 8 to
#: :data:`LOOP_CHUNK_MAX` states, a multiple of 4): chains of 50, 100 and 200 links ran fastest per state in such
#: chunks, ahead of the whole batch and of smaller or larger chunks.
LOOP_CHUNK_LINK_STATES = 8800
LOOP_CHUNK_MAX = 88


def batch_chunks(size: int, n_links: int = 0, depth: int | None = None) -> int:
    """How many chunks a batch of ``size`` states is evaluated in. Trees up to :data:`UNROLL_LINKS` links at most
    :data:`SHALLOW_DEPTH` deep (``depth``: links from the root to the deepest tip, :func:`tree_depth`): the nearest
    whole number of :data:`SHALLOW_CHUNK` chunks (at least one). Deeper ones (or ``depth`` not given): 1 up to
    :data:`BATCH_CHUNK_ABOVE` states, else the nearest whole number of :data:`BATCH_CHUNK` chunks (at least two;
    chunks of 705 to 1280 states). Larger trees (``n_links`` above :data:`UNROLL_LINKS`): chunks of at most
    :data:`LOOP_CHUNK_LINK_STATES` / ``n_links`` states rounded down to a multiple of 4 (8 to
    :data:`LOOP_CHUNK_MAX`)."""
    if n_links > UNROLL_LINKS:
        per = min(LOOP_CHUNK_MAX, max(8, LOOP_CHUNK_LINK_STATES // n_links // 4 * 4))
        return max(1, -(-size // per))
    if depth is not None and depth <= SHALLOW_DEPTH:
        return max(1, round(size / SHALLOW_CHUNK))
    if size <= BATCH_CHUNK_ABOVE:
        return 1
    return max(2, round(size / BATCH_CHUNK))


@functools.lru_cache(maxsize=64)
def tree_depth(parents: tuple) -> int:
    """Links from the root to the deepest tip (1 for links all attached to the world; 0 for no link); ``parents`` as
    :attr:`~.model.TreeModel.parents` (a tuple)."""
    return max(_depths(parents), default=-1) + 1


def state_by_state(size: int, n_links: int) -> bool:
    """Whether a batch of ``size`` states of a tree of ``n_links`` links runs as a loop over the one-state program
    rather than through the batched sweeps: at most one state per link, for trees whose sweeps are written out (up to
    :data:`UNROLL_LINKS` links; :func:`~.dynamics.forward_dynamics` applies it to arrays passed from Python only). The
    written-out sweeps are about 29 small kernels per link, paid once per call whatever the batch, and below about 700
    states XLA compiles most of them with its own emitters, which takes seconds where the loop compiles in under one.
    The loop measured faster up to about one state per link on Krang and on serial chains of 7 and 12 links; a bound
    of one state per two links left some of Krang's small batches on the sweeps, slower to run and to compile."""
    return 0 < size <= n_links <= UNROLL_LINKS


def wide_batch(size: int, n_links: int, depth: int | None = None) -> bool:
    """Whether a batch of ``size`` states of a tree of ``n_links`` links (``depth`` as for :func:`batch_chunks`) is
    compiled as a wide batch: written-out sweeps (up to :data:`UNROLL_LINKS` links) on chunks of at least
    :data:`WIDE_BATCH` states (never for shallow trees, whose chunks are narrower)."""
    if n_links > UNROLL_LINKS or size <= 0:
        return False
    return -(-size // batch_chunks(size, n_links, depth)) >= WIDE_BATCH


#: Threads a batch passed from Python is split over (:func:`batch_parts`); ``None``: the cores this process may run
#: on (``os.sched_getaffinity``), so that a process pinned to one core runs one part.
BATCH_THREADS: int | None = None

#: Least link-states (states times links) per part: a part below about this much work gains less from a second core
#: than a thread's hand-over costs.
PART_LINK_STATES = 2048


def batch_parts(size: int, n_links: int) -> int:
    """How many parts, one per thread, a batch of ``size`` states of a tree of ``n_links`` links passed from Python
    is evaluated in (:func:`~.dynamics.forward_dynamics`): one per usable core (:data:`BATCH_THREADS`), as far as
    each part keeps :data:`PART_LINK_STATES` link-states. One batched program gains nothing from a second core
    (XLA's runtime hands its small kernels between the threads of its pool: Krang's part of 512 states keeps 1.35
    cores busy and runs no faster than on one), so the second core is used by a second program beside the first:
    two parts on two threads take about half the time per state of one program."""
    threads = usable_cores() if BATCH_THREADS is None else BATCH_THREADS
    return max(1, min(threads, size * max(1, n_links) // PART_LINK_STATES))


def batch_lanes(per: int, n_links: int = 0) -> int:
    """How many states a chunk of ``per`` states is evaluated with (the extra ones padding): ``per``, plus 8 if it is
    a multiple of 64 below 768. Rows of a multiple of 64 float64 lanes (512 bytes) put the rows of a link's 6 x 6
    inertias at addresses that share cache sets: on Krang, 8 more states took less time per call than such a batch
    alone; 768 and 1024 states are not affected. Trees beyond :data:`UNROLL_LINKS` links (chunks of at most 88)
    instead round ``per`` from 8 states up to a multiple of 4, which ran the 100- and 200-link chains faster per
    state; the multiple-of-64 rule was not measured there."""
    if n_links > UNROLL_LINKS:
        return per if per < 8 else -(-per // 4) * 4
    return per + 8 if per > 0 and per % 64 == 0 and per < 768 else per


#: One state of a tree up to :data:`UNROLL_LINKS` links takes the sweeps rather than composite inertias and a Cholesky
#: solve when its links lie deeper than this on average (the mean depth is the mass matrix's nonzeros per row below
#: and on the diagonal, which the composite-inertia path pays for and the sweeps do not). Inside a compiled loop, with
#: link poses composed by pointer jumping (:func:`~.kinematics.link_poses`): serial revolute chains of 8-32 links
#: (mean depth 4.5-16.5) run as fast or faster on the sweeps, Krang (18 links, mean depth 6.0) about twice as fast
#: on composite inertias. Below depth 8 the chains gain little and branched trees like Krang lose much, so the bound
#: stays at 8.
ONE_STATE_SWEEPS_DEPTH = 8.0


@functools.lru_cache(maxsize=64)
def _mean_depth(parents: tuple) -> float:
    """Mean number of links from each link to the root, itself included."""
    return sum(d + 1 for d in _depths(parents)) / max(1, len(parents))


def one_state_sweeps(model: TreeModel) -> bool:
    """Whether one state of ``model`` runs :func:`aba_one_state` (large or deep trees) rather than composite inertias
    and a Cholesky solve."""
    return supports_aba(model) and (model.n_joints > UNROLL_LINKS
                                    or _mean_depth(model.parents) > ONE_STATE_SWEEPS_DEPTH)


def supports_aba(model: TreeModel) -> bool:
    """Whether :func:`aba` covers the model: revolute and prismatic joints, no mimic joints."""
    return all(k in (REVOLUTE, PRISMATIC) for k in model.kinds) and not any(model.mimic)


def _tail(x, nb: int):
    """``x`` with ``nb`` trailing singleton axes (constants against trailing batch axes)."""
    return jnp.reshape(x, jnp.shape(x) + (1,) * nb)


def _cross1(a, b):
    """Cross product along axis 0 (``(3, *B)``)."""
    return jnp.stack([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]])


def _mm1(a, b):
    """``(3, 3, *B) @ (3, 3, *B)``."""
    return jnp.sum(a[:, :, None] * b[None, :, :], 1)


def _mv1(a, x):
    """``(3, 3, *B) @ (3, *B)``."""
    return jnp.sum(a * x[None], 1)


def _skew1(h):
    """``(3, *B)`` -> ``(3, 3, *B)`` with ``skew(h) v = h x v``."""
    z = jnp.zeros_like(h[0])
    return jnp.stack([jnp.stack([z, -h[2], h[1]]), jnp.stack([h[2], z, -h[0]]), jnp.stack([-h[1], h[0], z])])


def _joint_transforms(model: TreeModel, q, order, dtype):
    """Parent-from-child rotations ``(n, 3, 3, *B)`` and origins ``(n, 3, *B)`` of the links in ``order``:
    ``R0 Rot(a, q) = cos q R0 (E - a a^T) + sin q R0 K + R0 a a^T`` (three constant matrices, no products)."""
    nb = q.ndim - 1
    n = len(order)
    ax = model.axes_array[order]
    rev = model.is_revolute[order]
    r0 = model.origin_rotation_array[order]
    aa = ax[:, :, None] * ax[:, None, :]
    kk = np.zeros((n, 3, 3))
    kk[:, 0, 1], kk[:, 0, 2], kk[:, 1, 2] = -ax[:, 2], ax[:, 1], -ax[:, 0]
    kk = kk - np.swapaxes(kk, 1, 2)
    m_cos = np.where(rev[:, None, None], r0 @ (np.eye(3) - aa), 0.0)
    m_sin = np.where(rev[:, None, None], r0 @ kk, 0.0)
    m_one = np.where(rev[:, None, None], r0 @ aa, r0)
    is_rev = _tail(jnp.asarray(rev), nb)
    angle = jnp.where(is_rev, q, 0.0)
    sq, cq = (v[:, None, None] for v in sincos(angle))
    r_rel = (_tail(jnp.asarray(m_cos, dtype), nb) * cq + _tail(jnp.asarray(m_sin, dtype), nb) * sq
             + _tail(jnp.asarray(m_one, dtype), nb))
    slide = jnp.where(is_rev, 0.0, q)
    p_rel = (_tail(model.origin_xyz[order], nb) + _tail(jnp.asarray((r0 @ ax[:, :, None])[..., 0], dtype), nb)
             * slide[:, None])
    return r_rel, p_rel


def _outward(rot_p, pos_p, vel_p, r_rel, p_rel, axis, rev, qd, m, ms, jl, eye):
    """Sweep 1 for one link: its pose, joint column ``s`` (6), velocity, velocity-product acceleration ``c``, rigid
    inertia about ``O_0`` in world axes ``[[J0, skew(h)], [skew(h)^T, m E]]`` and bias force ``v x* I v``."""
    rot = _mm1(rot_p, r_rel)
    pos = pos_p + _mv1(rot_p, p_rel)
    nb = qd.ndim
    s = _column(rot, pos, _tail(axis, nb), rev)
    own = s * qd
    vel = vel_p + own
    return (rot, pos, vel, s) + _link_terms(rot, pos, vel, own, m, _tail(ms, nb), _tail(jl, nb), eye)


def _column(rot, pos, axis, rev):
    """Joint column ``s`` (6, *B) in world axes about ``O_0`` from the link's pose (``axis`` in link axes, (3, *B) or
    broadcasting to it)."""
    aw = _mv1(rot, axis)
    return jnp.concatenate([rev * aw, rev * _cross1(pos, aw) + (1.0 - rev) * aw])


def _link_terms(rot, pos, vel, own, m, ms, jl, eye):
    """A link's velocity-product acceleration ``c``, rigid inertia about ``O_0`` in world axes and bias force, from
    its pose, velocity and own joint velocity ``s qd`` (every argument with the same trailing axes)."""
    w, v = vel[:3], vel[3:]
    c = jnp.concatenate([_cross1(w, own[:3]), _cross1(w, own[3:]) + _cross1(v, own[:3])])
    hl = _mv1(rot, ms)
    jw = _mm1(_mm1(rot, jl), jnp.swapaxes(rot, 0, 1))
    pp = jnp.sum(pos * pos, 0)
    ph = jnp.sum(pos * hl, 0)
    j0 = (jw + (m * pp + 2.0 * ph) * eye - m * pos[:, None] * pos[None, :] - pos[:, None] * hl[None, :]
          - hl[:, None] * pos[None, :])
    hx = _skew1(m * pos + hl)
    inertia = jnp.concatenate([jnp.concatenate([j0, hx], 1), jnp.concatenate([jnp.swapaxes(hx, 0, 1), m * eye], 1)])
    mom = jnp.sum(inertia * vel[None], 1)
    bias = jnp.concatenate([_cross1(w, mom[:3]) + _cross1(v, mom[3:]), _cross1(w, mom[3:])])
    return c, inertia, bias


def _inward(ia, pa, s, c, tau, arm):
    """Sweep 2 for one link: ``U``, ``1/D``, ``u`` and what the parent receives (articulated inertia and bias)."""
    u_vec = jnp.sum(ia * s[None], 1)
    dinv = 1.0 / (jnp.sum(s * u_vec, 0) + arm)
    u = tau - jnp.sum(s * pa, 0)
    ia = ia - u_vec[:, None] * u_vec[None, :] * dinv
    pa = pa + jnp.sum(ia * c[None], 1) + u_vec * (u * dinv)
    return u_vec, dinv, u, ia, pa


def _acceleration(a_p, c, u_vec, dinv, u, s):
    """Sweep 3 for one link: its joint acceleration and spatial acceleration."""
    a = a_p + c
    qdd = (u - jnp.sum(u_vec * a, 0)) * dinv
    return a + s * qdd, qdd


def _aba_unrolled(model: TreeModel, q, qd, tau):
    """The sweeps written out link by link: every link's arrays are separate values of the program, so XLA fuses
    each link's arithmetic into a few loops over the batch."""
    n, dtype, nb = model.n_joints, q.dtype, q.ndim - 1
    every = np.arange(n)
    r_rel, p_rel = _joint_transforms(model, q, every, dtype)
    m, ms, jl = unpack_params(model.inertia)
    ax, rev = jnp.asarray(model.axes_array, dtype), model.is_revolute.astype(float)
    arm = jnp.zeros(n, dtype) if model.rotor_inertia is None else model.rotor_inertia
    eye = _tail(jnp.eye(3, dtype=dtype), nb) + jnp.zeros(q.shape[1:], dtype)
    world = (eye, jnp.zeros((3,) + q.shape[1:], dtype), jnp.zeros((6,) + q.shape[1:], dtype))
    order = model.topological_order
    state, link = {}, {}
    for i in order:
        k = model.parents[i]
        out = _outward(*(world if k < 0 else state[k]), r_rel[i], p_rel[i], ax[i], rev[i], qd[i], m[i], ms[i],
                       jl[i], eye)
        state[i], link[i] = out[:3], list(out[3:])  # (rot, pos, vel), [s, c, inertia, bias]
    swept = {}
    for i in reversed(order):
        s, c, ia, pa = link[i]
        u_vec, dinv, u, ia, pa = _inward(ia, pa, s, c, tau[i], arm[i])
        swept[i] = (u_vec, dinv, u)
        k = model.parents[i]
        if k >= 0:
            link[k][2] = link[k][2] + ia
            link[k][3] = link[k][3] + pa
    a0 = _tail(jnp.concatenate([jnp.zeros(3, dtype), -model.gravity.astype(dtype)]), nb)
    accs, qdd = {}, [None] * n
    for i in order:
        k = model.parents[i]
        accs[i], qdd[i] = _acceleration(a0 if k < 0 else accs[k], link[i][1], *swept[i], link[i][0])
    return jnp.stack(qdd)


def _aba_loop(model: TreeModel, q, qd, tau):
    """The sweeps as three ``lax.scan`` over the links (parents first, then children first). Each sweep keeps one
    stacked buffer whose rows hold a link's carried state *and* its outputs, written once per step (the last row is
    the world, or zeros): a loop that read rows of one buffer and wrote outputs to another, or wrote two rows, would
    make XLA copy the whole buffer every step (O(N^2) in all); one write per step is done in place."""
    n, dtype, nb = model.n_joints, q.dtype, q.ndim - 1
    bshape = q.shape[1:]
    order, parent_pos = _order(model.parents)
    r_rel, p_rel = _joint_transforms(model, q[order], order, dtype)
    m, ms, jl = unpack_params(model.inertia[order])
    eye = _tail(jnp.eye(3, dtype=dtype), nb) + jnp.zeros(bshape, dtype)
    arm = (jnp.zeros(n, dtype) if model.rotor_inertia is None else model.rotor_inertia[order]).astype(dtype)
    at, parent = jnp.arange(n, dtype=jnp.int32), jnp.asarray(parent_pos)

    def row(buf, i):
        return jax.lax.dynamic_index_in_dim(buf, i, 0, keepdims=False)

    def put(buf, i, x):
        return jax.lax.dynamic_update_index_in_dim(buf, x, i, 0)

    def flat(*parts):
        return jnp.concatenate([x.reshape((-1,) + bshape) for x in parts])

    # Row layout of sweep 1: rot 9, pos 3, vel 6 | s 6, c 6, inertia 36, bias 6.
    def outward(buf, g):
        r = row(buf, g["parent"])
        out = _outward(r[:9].reshape((3, 3) + bshape), r[9:12], r[12:18], g["r_rel"], g["p_rel"], g["axis"],
                       _tail(g["rev"], nb), g["qd"], _tail(g["m"], nb), g["ms"], g["jl"], eye)
        return put(buf, g["at"], flat(*out)), None

    world = flat(eye, jnp.zeros((3,) + bshape, dtype), jnp.zeros((6 + 6 + 6 + 36 + 6,) + bshape, dtype))
    buf = jnp.concatenate([jnp.zeros((n,) + world.shape, dtype), world[None]])
    xs = dict(r_rel=r_rel, p_rel=p_rel, axis=jnp.asarray(model.axes_array[order], dtype),
              rev=jnp.asarray(model.is_revolute[order], dtype), qd=qd[order], m=m, ms=ms, jl=jl, parent=parent, at=at)
    buf, _ = jax.lax.scan(outward, buf, xs)
    s, c = buf[:n, 18:24], buf[:n, 24:30]
    inertia, bias = buf[:n, 30:66].reshape((n, 6, 6) + bshape), buf[:n, 66:72]

    # Row layout of sweep 2: what the link passes to its parent (articulated inertia 36, bias 6) | U 6, 1/D, u.
    # Each link pulls its children's rows (padded to the widest family with the zero row n): one write per step.
    def inward(buf, g):
        got = sum(row(buf, g["kids"][j])[:42] for j in range(kids.shape[1]))
        u_vec, dinv, u, ia, pa = _inward(g["inertia"] + got[:36].reshape((6, 6) + bshape), g["bias"] + got[36:],
                                         g["s"], g["c"], g["tau"], g["arm"])
        return put(buf, g["at"], flat(ia, pa, u_vec, dinv, u)), None

    kids = _children(model.parents)
    buf = jnp.zeros((n + 1, 50) + bshape, dtype)
    buf, _ = jax.lax.scan(inward, buf, dict(inertia=inertia, bias=bias, s=s, c=c, tau=tau[order], arm=arm, at=at,
                                            kids=jnp.asarray(kids)), reverse=True)
    u_vec, dinv, u = buf[:n, 42:48], buf[:n, 48], buf[:n, 49]

    # Row layout of sweep 3: spatial acceleration 6, qdd 1.
    def forward(buf, g):
        a, qdd = _acceleration(row(buf, g["parent"])[:6], g["c"], g["U"], g["dinv"], g["u"], g["s"])
        return put(buf, g["at"], flat(a, qdd)), None

    a0 = jnp.concatenate([jnp.zeros(3, dtype), -model.gravity.astype(dtype), jnp.zeros(1, dtype)])
    buf = jnp.broadcast_to(_tail(a0, nb), (n + 1, 7) + bshape)
    buf, _ = jax.lax.scan(forward, buf, dict(c=c, U=u_vec, dinv=dinv, u=u, s=s, parent=parent, at=at))
    inv = np.empty(n, dtype=np.int32)
    inv[order] = np.arange(n, dtype=np.int32)
    return buf[:n, 6][inv]


def aba_one_state(model: TreeModel, q: Array, qd: Array, tau: Array) -> Array:
    """Joint accelerations of one state ``(n,)`` by the sweeps of :func:`aba` for trees of any size (compile time flat
    in N), laid out for one state: only the recursions loop over links, each carrying a few numbers per link (poses,
    velocities, articulated inertias, accelerations), and everything a link computes from its own pose and velocity
    (joint column, rigid inertia, bias force, velocity-product term) is one vectorised pass over all links. XLA:CPU
    compiles a while loop that touches under 1 kB per step into one kernel instead of dispatching each of its
    operations per step; the pose, velocity and acceleration loops qualify."""
    with jax.numpy_rank_promotion("allow"):  # link terms (n,) meet (3, n) by trailing-axis broadcasting
        return _aba_one_state(model, q, qd, tau)


def _aba_one_state(model: TreeModel, q, qd, tau):
    n, dtype = model.n_joints, jnp.result_type(q, qd, tau, model.inertia)
    q, qd, tau = (jnp.asarray(x, dtype) for x in (q, qd, tau))
    order, parent_pos = _order(model.parents)
    r_rel, p_rel = _joint_transforms(model, q[order], order, dtype)  # (n, 3, 3), (n, 3)
    m, ms, jl = unpack_params(model.inertia[order])
    parent, at = jnp.asarray(parent_pos), jnp.arange(n, dtype=jnp.int32)
    qd_o = qd[order]

    def row(buf, i):
        return jax.lax.dynamic_index_in_dim(buf, i, 0, keepdims=False)

    def put(buf, i, x):
        return jax.lax.dynamic_update_index_in_dim(buf, x, i, 0)

    def pose(buf, x):  # rows: rot 9, pos 3 (last row: the world)
        k, i, rr, pr = x
        r = row(buf, k)
        rot_p, pos_p = r[:9].reshape(3, 3), r[9:]
        return put(buf, i, jnp.concatenate([_mm1(rot_p, rr).reshape(9), pos_p + _mv1(rot_p, pr)])), None

    world = jnp.concatenate([jnp.eye(3, dtype=dtype).reshape(9), jnp.zeros(3, dtype)])
    buf, _ = jax.lax.scan(pose, jnp.zeros((n + 1, 12), dtype).at[n].set(world), (parent, at, r_rel, p_rel))
    # Links on the trailing axis for the vectorised passes: rot (3, 3, n), pos (3, n).
    rot, pos = jnp.moveaxis(buf[:n, :9].reshape(n, 3, 3), 0, -1), buf[:n, 9:].T
    s = _column(rot, pos, jnp.asarray(model.axes_array[order], dtype).T, jnp.asarray(model.is_revolute[order], dtype))
    own = s * qd_o

    def velocity(buf, x):
        k, i, o = x
        return put(buf, i, row(buf, k) + o), None

    vel = jax.lax.scan(velocity, jnp.zeros((n + 1, 6), dtype), (parent, at, own.T))[0][:n].T
    eye = jnp.eye(3, dtype=dtype)[:, :, None] + jnp.zeros(n, dtype)
    c, inertia, bias = _link_terms(rot, pos, vel, own, m, ms.T, jnp.moveaxis(jl, 0, -1), eye)
    arm = (jnp.zeros(n, dtype) if model.rotor_inertia is None else model.rotor_inertia[order]).astype(dtype)
    kids = _children(model.parents)

    def inward(buf, x):  # rows: what the link passes to its parent (36 + 6) | U 6, 1/D, u
        ia, pa, s_i, c_i, tau_i, arm_i, i, kd = x
        got = sum(row(buf, kd[j])[:42] for j in range(kids.shape[1]))
        u_vec, dinv, u, ia, pa = _inward(ia + got[:36].reshape(6, 6), pa + got[36:], s_i, c_i, tau_i, arm_i)
        return put(buf, i, jnp.concatenate([ia.reshape(36), pa, u_vec, dinv[None], u[None]])), None

    buf, _ = jax.lax.scan(inward, jnp.zeros((n + 1, 50), dtype),
                          (jnp.moveaxis(inertia, -1, 0), bias.T, s.T, c.T, tau[order], arm, at, jnp.asarray(kids)),
                          reverse=True)

    def forward(buf, x):  # rows: spatial acceleration 6, qdd
        k, i, c_i, u_vec, dinv, u, s_i = x
        a, qdd = _acceleration(row(buf, k)[:6], c_i, u_vec, dinv, u, s_i)
        return put(buf, i, jnp.concatenate([a, qdd[None]])), None

    a0 = jnp.concatenate([jnp.zeros(3, dtype), -model.gravity.astype(dtype), jnp.zeros(1, dtype)])
    buf, _ = jax.lax.scan(forward, jnp.broadcast_to(a0, (n + 1, 7)),
                          (parent, at, c.T, buf[:n, 42:48], buf[:n, 48], buf[:n, 49], s.T))
    inv = np.empty(n, dtype=np.int32)
    inv[order] = np.arange(n, dtype=np.int32)
    return buf[:n, 6][inv]


def aba(model: TreeModel, q: Array, qd: Array, tau: Array) -> Array:
    """Joint accelerations ``qdd`` (n, *B) from ``q``, ``qd`` and the generalised force ``tau`` (friction, springs
    and limits already included; not the bias, which the sweeps add), each (n, *B) with any trailing batch axes.
    Trees up to :data:`UNROLL_LINKS` links have their sweeps written out; larger ones loop over links."""
    n = model.n_joints
    bshape = jnp.broadcast_shapes(q.shape[1:], qd.shape[1:], tau.shape[1:])
    dtype = jnp.result_type(q, qd, tau, model.inertia)
    q, qd, tau = (jnp.broadcast_to(x, (n,) + bshape).astype(dtype) for x in (q, qd, tau))
    # Link quantities meet the batch by trailing-axis broadcasting (a (3, 3, 1) constant against (3, 3, B)): the
    # layout is the point of this module, so rank promotion is allowed here whatever the caller's setting.
    with jax.numpy_rank_promotion("allow"):
        return (_aba_unrolled if n <= UNROLL_LINKS else _aba_loop)(model, q, qd, tau)
