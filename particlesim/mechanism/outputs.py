"""Named outputs of a mechanism state: body poses, centres of mass and velocities.

A body's pose is the rigid map from its own frame (the frame its inertia was given in, see
:meth:`~.builder.MechanismBuilder.body`) to the world, ``p_world = R p_body + origin``. It is exact from the
primaries: the affine map taking the body-frame primaries to their world positions (four points for a spatial
body; three and the unit normal of their plane for a planar one). A rod has no rotation about its own axis; its
``R`` is the rotation without twist taking the body-frame axis to the current one (undefined when the axis has
turned by exactly 180 degrees).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..errors import ModelError
from ..spatial import unskew
from .model import AppliedTorque, BodyLoad, Mechanism
from .._jit import compiled

__all__ = ["body_poses", "body_com_positions", "body_velocities", "body_angles", "point_positions",
           "cut_joint_forces", "driver_efforts", "body_reactions", "joint_reaction"]


def _check_state(mech: Mechanism, v, what: str) -> None:
    if jnp.shape(v) != (mech.n_coords,):
        raise ModelError(f"{what} must have shape ({mech.n_coords},) (3 per free particle), got {jnp.shape(v)}")


def _unit(v):
    return v / jnp.linalg.norm(v, axis=-1, keepdims=True)


def _frame_points(loc, wld, kind: str):
    """Four affinely independent points per body, body frame and world: ``(n, 4, 3)`` each."""
    if kind == "spatial":
        return loc, wld
    n_l = _unit(jnp.cross(loc[:, 1] - loc[:, 0], loc[:, 2] - loc[:, 0]))
    n_w = _unit(jnp.cross(wld[:, 1] - wld[:, 0], wld[:, 2] - wld[:, 0]))
    return (jnp.concatenate([loc[:, :3], (loc[:, 0] + n_l)[:, None]], axis=1),
            jnp.concatenate([wld[:, :3], (wld[:, 0] + n_w)[:, None]], axis=1))


def _rod_rotation(a, b):
    """Rotation without twist taking unit ``a`` to unit ``b`` (rows of ``(n, 3)``): Rodrigues' formula."""
    v = jnp.cross(a, b)
    c = jnp.sum(a * b, axis=-1)
    vx = jnp.zeros(v.shape[:-1] + (3, 3), v.dtype)
    vx = vx.at[..., 0, 1].set(-v[..., 2]).at[..., 0, 2].set(v[..., 1]).at[..., 1, 0].set(v[..., 2])
    vx = vx.at[..., 1, 2].set(-v[..., 0]).at[..., 2, 0].set(-v[..., 1]).at[..., 2, 1].set(v[..., 0])
    return jnp.broadcast_to(jnp.eye(3), vx.shape) + vx + vx @ vx / (1.0 + c)[..., None, None]


@compiled("body_poses")
def body_poses(mech: Mechanism, q: Float[Array, " 3F"]) -> tuple[Float[Array, "B 3 3"], Float[Array, "B 3"]]:
    """``(R, origin)`` of every body at state ``q``: ``p_world = R p_body + origin`` (body order of
    ``mech.topo.body_names``; :meth:`Mechanism.body_index` gives a body's row)."""
    _check_state(mech, q, "q")
    return _poses_from_positions(mech, mech.all_positions(q))


def _poses_from_positions(mech: Mechanism, r: Float[Array, "P 3"]):
    """:func:`body_poses` from the positions of all particles."""
    return _poses_from_primaries(mech, lambda idx: r[idx], r.dtype)


def _poses_from_primaries(mech: Mechanism, read, dtype):
    """:func:`body_poses` from ``read(idx)``, the positions ``(n, k, 3)`` of the primaries of the bodies ``idx``
    (``(n, k)`` particle indices)."""
    topo = mech.topo
    n_b = len(topo.body_names)
    rot = jnp.zeros((n_b, 3, 3), dtype)
    org = jnp.zeros((n_b, 3), dtype)
    for kind, k in (("spatial", 4), ("planar", 3), ("rod", 2)):
        bs = np.array([b for b in range(n_b) if len(topo.body_particles[b]) == k], dtype=int)
        if not bs.size:
            continue
        idx = np.array([topo.body_particles[b] for b in bs], dtype=int)
        loc = mech.body_primaries[bs, :k]
        wld = read(idx)
        if kind == "rod":
            rr = _rod_rotation(_unit(loc[:, 1] - loc[:, 0]), _unit(wld[:, 1] - wld[:, 0]))
            oo = wld[:, 0] - jnp.einsum("bij,bj->bi", rr, loc[:, 0])
        else:
            lp, wp = _frame_points(loc, wld, kind)
            h = jnp.concatenate([lp, jnp.ones(lp.shape[:2] + (1,), lp.dtype)], axis=2)  # (n, 4, 4)
            # rows: R^T (3 rows) then origin. ``h`` holds parameters only: inverted once, so that a batch of states
            # (a vmapped trajectory) multiplies instead of running a batched LAPACK solve per state, whose work
            # jaxlib spreads over the intra-op threads (particlesim._threads: two such calls at once deadlock)
            a = jnp.linalg.inv(h) @ wp
            rr, oo = jnp.swapaxes(a[:, :3], 1, 2), a[:, 3]
        rot, org = rot.at[bs].set(rr), org.at[bs].set(oo)
    return rot, org


@compiled("body_com_positions")
def body_com_positions(mech: Mechanism, q: Float[Array, " 3F"]) -> Float[Array, "B 3"]:
    """World position of every body's centre of mass."""
    rot, org = body_poses(mech, q)
    return jnp.einsum("bij,bj->bi", rot, mech.body_com) + org


@compiled("body_velocities")
def body_velocities(mech: Mechanism, q: Float[Array, " 3F"], qd: Float[Array, " 3F"]
                    ) -> tuple[Float[Array, "B 3"], Float[Array, "B 3"]]:
    """``(v_com, omega)`` of every body: centre-of-mass velocity and angular velocity, world frame (a rod's
    angular velocity has no component along its axis)."""
    _check_state(mech, qd, "qd")
    (rot, org), (rot_d, org_d) = jax.jvp(lambda y: body_poses(mech, y), (q,), (qd,))
    omega = jax.vmap(unskew)(rot_d @ jnp.swapaxes(rot, 1, 2))
    rods = np.array([b for b, ps in enumerate(mech.topo.body_particles) if len(ps) == 2], dtype=int)
    if rods.size:  # a rod has no spin about its axis: keep u x u' only (its no-twist frame adds a path term)
        r = mech.all_positions(q)[np.array([mech.topo.body_particles[b] for b in rods], dtype=int)]
        u = _unit(r[:, 1] - r[:, 0])
        w = omega[rods]
        omega = omega.at[rods].set(w - jnp.sum(w * u, axis=1, keepdims=True) * u)
    v = jnp.einsum("bij,bj->bi", rot_d, mech.body_com) + org_d
    return v, omega


@compiled("point positions")
def _point_positions(mech: Mechanism, q: Float[Array, " 3F"]) -> Float[Array, "K 3"]:
    return mech.point_positions(mech.all_positions(q))


def point_positions(mech: Mechanism, q: Float[Array, " 3F"], names=None) -> Float[Array, "K 3"]:
    """World positions of named points at state ``q``: particles and points fixed to bodies
    (:meth:`~.builder.MechanismBuilder.point`), one row per name (a single name gives ``(3,)``); every point of
    ``mech.topo.point_names`` when ``names`` is None. Vmap over a trajectory: ``jax.vmap(lambda q:
    point_positions(mech, q, ["M"]))(sol.q)``. An unknown name raises ``KeyError`` naming it."""
    _check_state(mech, q, "q")
    out = _point_positions(mech, q)
    if names is None:
        return out
    if isinstance(names, str):
        return out[mech.point_index(names)]
    return out[np.asarray([mech.point_index(n) for n in names], dtype=int)]


def primary_load_forces(mech: Mechanism, b: int, q, force, torque) -> Float[Array, "k 3"]:
    """Forces on all of body ``b``'s primaries (ground ones too) equivalent to ``force`` at its centre of mass plus
    ``torque``: by virtual power, ``f_i = (d v_com / d v_i)^T F + (d omega / d v_i)^T tau``, with the body's
    velocities as functions of its primaries' velocities (so the forces sum to ``F`` and their moment is the
    load's)."""
    r = mech.all_positions(q)
    idx = np.asarray(mech.topo.body_particles[b], dtype=int)

    def vel(v_prim):
        v_all = jnp.zeros_like(r).at[idx].set(v_prim)
        (rot, org), (rot_d, org_d) = jax.jvp(lambda rr: _poses_from_positions(mech, rr), (r,), (v_all,))
        omega = unskew(rot_d[b] @ rot[b].T)
        if len(idx) == 2:
            u = _unit(r[idx[1]] - r[idx[0]])
            omega = omega - (omega @ u) * u
        return rot_d[b] @ mech.body_com[b] + org_d[b], omega

    _, pull = jax.vjp(vel, jnp.zeros((len(idx), 3), dtype=r.dtype))
    return pull((jnp.asarray(force, dtype=r.dtype), jnp.asarray(torque, dtype=r.dtype)))[0]


@compiled("body_angles")
def body_angles(mech: Mechanism, q: Float[Array, " 3F"]) -> Float[Array, " B"]:
    """Rotation angle about z of every body of a planar mechanism from its given (assembly) orientation, in
    ``(-pi, pi]`` (wrapped; ``numpy.unwrap`` a trajectory), counter-clockwise positive; from the direction between
    the body's first two primaries."""
    topo = mech.topo
    if not topo.planar:
        raise ModelError("body_angles: the mechanism is not planar (build it with MechanismBuilder(planar=True)); "
                         "use body_poses for spatial rotations")
    _check_state(mech, q, "q")
    r = mech.all_positions(q)
    first = np.asarray([p[0] for p in topo.body_particles], dtype=int)
    second = np.asarray([p[1] for p in topo.body_particles], dtype=int)
    d_w = r[second] - r[first]
    d_l = mech.body_primaries[:, 1] - mech.body_primaries[:, 0]
    cross = d_l[:, 0] * d_w[:, 1] - d_l[:, 1] * d_w[:, 0]
    return jnp.arctan2(cross, jnp.sum(d_l[:, :2] * d_w[:, :2], axis=1))


@compiled("cut_joint_forces")
def cut_joint_forces(mech: Mechanism, t, q: Float[Array, " 3F"], qd: Float[Array, " 3F"]) -> dict[str, Array]:
    """Reaction force of every cut joint ``cut_joint(a, b, name=...)`` at state ``(t, q, qd)``: the force ``(3,)``
    (global frame, N) that the ``b`` side exerts on point ``a`` (``b`` receives its opposite), from the joint's
    multipliers (``M qdd + J^T lam = Q``: the rows ``e . (p_a - p_b)`` push ``a`` with ``-lam e``). A planar
    mechanism's cut joints have no z row (z force 0). With redundant rows (least-squares multipliers) the split of
    a force among redundant joints is not unique."""
    from .dynamics import accelerations_and_multipliers

    _check_state(mech, q, "q")
    _check_state(mech, qd, "qd")
    _, lam = accelerations_and_multipliers(mech, t, q, qd)
    lin = mech.topo.linear
    lam_lin = lam[len(mech.topo.dot):]
    out: dict[str, Array] = {}
    for r, (label, axis) in enumerate(zip(lin.labels, lin.axis)):
        if len(label) < 4 or label[-4:] not in (" (x)", " (y)", " (z)"):
            continue  # not a cut-joint row (e.g. a planar mechanism's in-plane rows)
        name = label[:-4]
        f = out.get(name, jnp.zeros(3, dtype=q.dtype))
        out[name] = f - lam_lin[r] * jnp.asarray(axis, dtype=q.dtype)
    return out


@compiled("driver_efforts")
def driver_efforts(mech: Mechanism, t, q: Float[Array, " 3F"], qd: Float[Array, " 3F"]) -> dict[str, Array]:
    """What every driver must supply at state ``(t, q, qd)`` to impose its motion: the torque (N m) about its axis
    of an angle driver, the force (N) along its axis of a position driver (positive: doing positive work when the
    driven coordinate increases), by name. From the multipliers: a driving row is scaled so that its gradient along
    the driven coordinate is one, so its effort is ``-lam``."""
    from .dynamics import accelerations_and_multipliers

    _check_state(mech, q, "q")
    _check_state(mech, qd, "qd")
    dr = mech.topo.drive
    if not len(dr):
        return {}
    _, lam = accelerations_and_multipliers(mech, t, q, qd)
    tail = -lam[mech.n_constraints - len(dr):]
    return {name: tail[i] for i, name in enumerate(dr.names)}


@compiled("body_reactions")
def body_reactions(mech: Mechanism, t, q: Float[Array, " 3F"], qd: Float[Array, " 3F"]) -> Float[Array, "B 4 3"]:
    """The force ``(3,)`` every body receives at each of its primaries (``mech.topo.body_particles`` order, padded
    with zeros to 4) from outside itself: its joints (the other bodies sharing the particle, the ground, cut joints,
    links, lines and prismatic joints acting on its points) and loads applied directly at a shared particle.

    From each body's own equations, ``R_b = L_b xdd_b - Q_b + J_b^T lam_b``: its mass block times the particle
    accelerations, minus its gravity and the loads on its own points and its torques, plus the forces of its own
    rigid-distance rows (a row shared by two bodies, the axis of a revolute joint, split evenly: the split moves
    equal and opposite forces along the axis between its two particles and leaves every joint's net force and
    moment unchanged). :func:`joint_reaction` sums them into a joint's force and moment. Torques (applied, body
    loads, rotational spring-dampers) and the wrenches of bushings and torsion springs act on a body over all its
    primaries, ground ones included."""
    from ..particles import primary_mass_matrix
    from .constraints import point_weights, points
    from .dynamics import accelerations_and_multipliers
    from .forces import applied_vector, point_forces

    topo = mech.topo
    _check_state(mech, q, "q")
    _check_state(mech, qd, "qd")
    qdd, lam = accelerations_and_multipliers(mech, t, q, qd)
    n_p = topo.n_particles
    free = np.asarray(topo.free, dtype=int)
    acc = jnp.zeros((n_p, 3), q.dtype).at[free].set(qdd.reshape(-1, 3))
    vel = jnp.zeros((n_p, 3), q.dtype).at[free].set(qd.reshape(-1, 3))
    pos = mech.all_positions(q)
    # forces of the rigid-distance rows of each body, per particle, with their share
    owners: dict[int, list[int]] = {}
    prim_sets = [set(p) for p in topo.body_particles]
    rows = topo.dot
    for r in range(len(rows)):
        a, b, c, d = rows.a[r], rows.b[r], rows.c[r], rows.d[r]
        if a == c and b == d and max(a, b) < n_p:
            owners[r] = [k for k, ps in enumerate(prim_sets) if a in ps and b in ps]
    w = point_weights(mech)
    pts = points(topo, w, pos)
    f_pts = point_forces(mech, t, q, qd, pts, points(topo, w, vel))
    out = jnp.zeros((len(topo.body_names), 4, 3), q.dtype)
    spring_torque = {}  # body -> torque about z of its rotational spring-dampers
    if topo.rotational_names:
        from .forces import rotational_angles

        th, th_dot = jax.jvp(lambda y: rotational_angles(mech, y), (q,), (qd,))
        tau = mech.rotational_stiffness * (th - mech.rotational_free_angle) + mech.rotational_damping * th_dot
        for r, (ba, bb) in enumerate(topo.rotational_bodies):  # -tau on b, +tau on a (the ground takes its own)
            spring_torque[bb] = spring_torque.get(bb, 0.0) - tau[r]
            if ba >= 0:
                spring_torque[ba] = spring_torque.get(ba, 0.0) + tau[r]
    from .elements import element_primary_forces, has_elements

    elem = element_primary_forces(mech, q, qd) if has_elements(mech) else None
    for bi, prim in enumerate(topo.body_particles):
        k = len(prim)
        idx = np.asarray(prim, dtype=int)
        lb = primary_mass_matrix(mech.body_mass[bi], mech.body_com[bi], mech.body_inertia[bi],
                                 mech.body_primaries[bi, :k])
        r_b = lb @ acc[idx] - jnp.sum(lb, axis=1)[:, None] * mech.gravity[None, :]
        if f_pts is not None:  # loads on the body's own points (not at particles), by their weights
            mine = [k for k, owner in enumerate(topo.point_body) if owner == bi]
            if mine:
                r_b = r_b - jnp.einsum("qt,qj->tj", w[np.asarray(mine)][:, :k], f_pts[np.asarray(mine)])
        if bi in spring_torque:
            z = jnp.zeros((), q.dtype)
            r_b = r_b - primary_load_forces(mech, bi, q, jnp.zeros(3, q.dtype), jnp.stack([z, z, z + spring_torque[bi]]))
        if elem is not None:  # bushings and torsion springs: their forces on the body's primaries
            r_b = r_b - elem[bi, :k]
        for ap in mech.applied:  # loads and torques on the body, on all its primaries (ground ones too)
            if isinstance(ap, BodyLoad) and bi in ap.bodies:
                from .forces import body_load_wrenches

                wrench = body_load_wrenches(mech, ap, t, q, qd).get(topo.body_names[bi])
                if wrench is not None:
                    r_b = r_b - primary_load_forces(mech, bi, q, *wrench)
            if isinstance(ap, AppliedTorque) and ap.body == bi:
                r_b = r_b - primary_load_forces(mech, bi, q, jnp.zeros(3, q.dtype), applied_vector(ap, t, q, qd))
        for r, bodies in owners.items():
            if bi not in bodies:
                continue
            a, b = rows.a[r], rows.b[r]
            g = 2.0 * rows.scale[r] * (pos[a] - pos[b]) * lam[r] / len(bodies)
            r_b = r_b.at[list(prim).index(a)].add(g).at[list(prim).index(b)].add(-g)
        out = out.at[bi, :k].set(r_b)
    return out


@compiled("joint_reaction", static=('body', 'particles'))
def joint_reaction(mech: Mechanism, t, q, qd, body: str, particles) -> tuple[Array, Array]:
    """Net force and moment ``((3,), (3,))`` that ``body`` receives through the listed primaries of it (the
    particles of one joint: one for a spherical joint, the two axis particles of a revolute joint), the moment
    about the first of them; from :func:`body_reactions`."""
    b = mech.body_index(body)
    prim = mech.topo.body_particles[b]
    names = [particles] if isinstance(particles, str) else list(particles)
    slots = []
    for n in names:
        i = mech.index(n)
        if i not in prim:
            raise ModelError(f"joint_reaction: particle '{n}' is not a primary of body '{body}'")
        slots.append(prim.index(i))
    react = body_reactions(mech, t, q, qd)[b]
    pos = mech.all_positions(q)[np.asarray(prim, dtype=int)]
    f = jnp.sum(react[np.asarray(slots)], axis=0)
    m = jnp.sum(jnp.cross(pos[np.asarray(slots)] - pos[slots[0]][None], react[np.asarray(slots)]), axis=0)
    return f, m
