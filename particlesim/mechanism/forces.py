"""Generalised forces on the free particle coordinates, and the potential energies that go with them.

Every force element acts at a point ``p = sum_t w_t r_t`` (:mod:`.constraints`), so its generalised force is
``Q_f = sum_k W[k, f] F_k`` (virtual work; ``W`` the point-to-free-particle weights): forces need not be
redistributed over particles by hand (Attia's reason for the moment equations). Gravity acts on every particle with
its lumped mass ``m_bar`` (Attia eq. (25)) and is a constant of the parameter set. A scene without springs, tyres or
applied loads pays nothing for them: each part below is skipped at trace time.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..errors import ModelError
from ..spatial import frame_from_points, unskew
from ._algebra import lumped_masses
from .curves import curve_integral, curve_value
from .model import AppliedForce, AppliedTorque, BodyLoad, Mechanism
from .._jit import compiled

__all__ = ["generalized_forces", "point_forces", "point_force_terms", "generalized_point_forces", "torque_forces",
           "potential_energy", "spring_lengths", "body_angular_velocity", "rotational_angles", "one_sided_gaps",
           "one_sided_names", "bump_gaps"]


def _pts(mech: Mechanism, q):
    from .constraints import point_weights, points

    return points(mech.topo, point_weights(mech), mech.all_positions(q))


@compiled("spring_lengths")
def spring_lengths(mech: Mechanism, q) -> Float[Array, " S"]:
    """Current length of every spring-damper."""
    p = _pts(mech, q)
    ab = np.asarray(mech.topo.spring_points, dtype=int).reshape(-1, 2)
    return jnp.linalg.norm(p[ab[:, 0]] - p[ab[:, 1]], axis=1)


@compiled("body_angular_velocity", static=('b',))
def body_angular_velocity(mech: Mechanism, b: int, q, qd) -> Float[Array, "3"]:
    """Angular velocity of a (spatial or planar) body from its first three primaries: ``unskew(F' F^T)``."""
    idx = np.asarray(mech.topo.body_particles[b])

    def frame(y):
        p = mech.all_positions(y)[idx]
        return frame_from_points(p[0], p[1], p[2])

    f, fd = jax.jvp(frame, (q,), (qd,))
    return unskew(fd @ f.T)


def tyre_deflections(mech: Mechanism, pts: Float[Array, "K 3"], t=0.0) -> Float[Array, " T"]:
    """Height of every tyre's measuring point above its ground (at time ``t``) minus its radius (negative: in
    contact)."""
    return _tyre_gaps(mech, pts[np.asarray(mech.topo.tyre_points, dtype=int)], t)


def _tyre_gaps(mech: Mechanism, at: Float[Array, "T 3"], t=0.0, vel=None):
    """Every tyre's height above its ground minus its radius, from its measuring points' positions ``at`` at time
    ``t``; with their velocities ``vel``, also the gaps' rates (relative to a moving road)."""
    n = jnp.asarray(mech.topo.tyre_normals, dtype=at.dtype)
    h, h_rate = _road_heights(mech, t, at, vel)
    gap = jnp.sum(at * n, axis=1) - mech.tyre_ground - mech.tyre_radius - h
    return gap if vel is None else (gap, jnp.sum(vel * n, axis=1) - h_rate)


def _road_heights(mech: Mechanism, t, at, vel=None):
    """Each tyre's road height at its measuring point ``at`` and time ``t`` (0 for a plane) and, with the points'
    velocities ``vel``, its rate along the motion (``dh/dt + grad h . v``, by autodiff); zeros without roads."""
    arity = mech.topo.tyre_road_args
    if not arity:
        return 0.0, 0.0
    t = jnp.asarray(t, dtype=at.dtype)
    hs, rates = [], []
    for i, (n, fn) in enumerate(zip(arity, mech.tyre_roads)):
        if n == 0:
            hs.append(jnp.zeros((), at.dtype))
            rates.append(jnp.zeros((), at.dtype))
            continue
        road = (lambda tt, pp, fn=fn: fn(tt)) if n == 1 else fn
        if vel is None:
            h, rate = road(t, at[i]), jnp.zeros((), at.dtype)
        else:
            h, rate = jax.jvp(road, (t, at[i]), (jnp.ones_like(t), vel[i]))
        h = jnp.asarray(h, dtype=at.dtype)
        if h.shape != ():
            raise ModelError(f"tyre '{mech.topo.tyre_names[i]}': the road function must return one number (the "
                             f"ground's height), got shape {h.shape}")
        hs.append(h)
        rates.append(jnp.asarray(rate, dtype=at.dtype))
    return jnp.stack(hs), jnp.stack(rates)


def _curve_tensions(mech: Mechanism, stretch, rate):
    """The tabulated springs' and dampers' tensions (:mod:`.curves`), zero for linear ones; 0 when none."""
    topo = mech.topo
    out = 0.0
    for knots, tables, arg in ((topo.spring_force_knots, mech.spring_force_curve, stretch),
                               (topo.spring_damping_knots, mech.spring_damping_curve, rate)):
        for i, x in enumerate(knots):
            if x:
                out = out + jnp.zeros_like(arg).at[i].set(curve_value(x, tables[i].astype(arg.dtype), arg[i]))
    return out


def one_sided_names(mech: Mechanism) -> tuple[str, ...]:
    """The one-sided elements in switch order (tyres, then bump stops), labelled for messages."""
    return (tuple(f"tyre '{n}'" for n in mech.topo.tyre_names)
            + tuple(f"bump stop '{n}'" for n in mech.topo.bump_names))


def bump_gaps(mech: Mechanism, pts: Float[Array, "K 3"]) -> Float[Array, " S"]:
    """Every bump stop's gap (negative: engaged) from all points' positions: the distance of its points minus the
    length at which it engages, sign turned for a rebound stop."""
    ab = np.asarray(mech.topo.bump_points, dtype=int).reshape(-1, 2)
    ell = jnp.linalg.norm(pts[ab[:, 0]] - pts[ab[:, 1]], axis=1)
    sign = jnp.asarray(np.where(np.asarray(mech.topo.bump_rebound, bool), -1.0, 1.0), dtype=pts.dtype)
    return sign * (ell - mech.bump_length) + mech.bump_clearance


def one_sided_gaps(mech: Mechanism, pts: Float[Array, "K 3"], t=0.0) -> Float[Array, " T"]:
    """The switching functions of every one-sided element (:func:`one_sided_names` order) from all points'
    positions: tyre deflections, bump stop gaps; negative when engaged."""
    parts = []
    if mech.topo.tyre_names:
        parts.append(tyre_deflections(mech, pts, t))
    if mech.topo.bump_names:
        parts.append(bump_gaps(mech, pts))
    return jnp.concatenate(parts) if parts else jnp.zeros(0, pts.dtype)


def point_force_terms(mech: Mechanism, t, q, qd, read, contact=None):
    """The point forces of springs, tyres and applied forces as ``(idx, f)``: forces ``f`` (P, 3) on the points
    ``idx`` (P,), a static index array that may repeat points (the caller sums them); ``None`` if the mechanism has
    none of them. ``read(idx)`` returns the positions and velocities ``(len(idx), 3)`` of the points ``idx`` (static),
    so that only the points the forces read are computed. ``contact`` (T,) fixes each tyre's law (in contact or not)
    instead of reading it from the sign of its deflection: the smooth branch of an evented rollout (:func:`particlesim._ode.integrate_events`).
    An applied force whose function does not return shape (3,) raises ``ModelError`` naming it."""
    topo = mech.topo
    forces_applied = [ap for ap in mech.applied if isinstance(ap, AppliedForce)]
    if not (topo.spring_names or topo.tyre_names or topo.bump_names or forces_applied):
        return None
    n_tyres = len(topo.tyre_names)
    idx, fs = [], []
    if topo.spring_names:
        ab = np.asarray(topo.spring_points, dtype=int)
        a, b = ab[:, 0], ab[:, 1]
        (pa, va), (pb, vb) = read(a), read(b)
        d = pa - pb
        ell = jnp.linalg.norm(d, axis=1)
        u = d / ell[:, None]
        rate = jnp.sum(u * (va - vb), axis=1)
        f = mech.spring_stiffness * (ell - mech.spring_free_length) + mech.spring_damping * rate
        f = f + _curve_tensions(mech, ell - mech.spring_free_length, rate)
        idx += [a, b]
        fs += [-f[:, None] * u, f[:, None] * u]
    if topo.tyre_names:
        k = np.asarray(topo.tyre_points, dtype=int)
        pk, vk = read(k)
        n = jnp.asarray(topo.tyre_normals, dtype=pk.dtype)
        dist, rate = _tyre_gaps(mech, pk, t, vk)
        touching = dist < 0.0 if contact is None else contact[:n_tyres]
        f = jnp.where(touching, -(mech.tyre_stiffness * dist + mech.tyre_damping * rate), 0.0)
        idx.append(np.asarray(topo.tyre_apply, dtype=int) if topo.tyre_apply else k)
        fs.append(f[:, None] * n)
    if topo.bump_names:
        ab = np.asarray(topo.bump_points, dtype=int)
        both = np.concatenate([ab[:, 0], ab[:, 1]])
        p, v = read(both)
        nb = len(topo.bump_names)
        d, dv = p[:nb] - p[nb:], v[:nb] - v[nb:]
        ell = jnp.linalg.norm(d, axis=1)
        u = d / ell[:, None]
        sign = jnp.asarray(np.where(np.asarray(topo.bump_rebound, bool), -1.0, 1.0), dtype=p.dtype)
        gap = sign * (ell - mech.bump_length) + mech.bump_clearance
        rate = sign * jnp.sum(u * dv, axis=1)
        engaged = gap < 0.0 if contact is None else contact[n_tyres:]
        f = jnp.where(engaged, sign * (mech.bump_stiffness * gap + mech.bump_damping * rate), 0.0)  # tension
        idx += [ab[:, 0], ab[:, 1]]
        fs += [-f[:, None] * u, f[:, None] * u]
    for ap in forces_applied:
        idx.append(np.asarray([ap.point], dtype=int))
        fs.append(applied_vector(ap, t, q, qd)[None])
    dtype = jnp.result_type(*fs)
    return np.concatenate(idx), jnp.concatenate([f.astype(dtype) for f in fs])


def applied_vector(ap, t, q, qd) -> Float[Array, "3"]:
    """``ap.fn(t, q, qd)`` of an applied force or torque, refused (naming it) unless it has shape (3,)."""
    v = jnp.asarray(ap.fn(t, q, qd))
    if v.shape != (3,):
        kind = "force" if isinstance(ap, AppliedForce) else "torque"
        raise ModelError(f"applied {kind} '{ap.name}' must return a {kind} of shape (3,) (global x, y, z), got "
                         f"shape {v.shape}")
    return v


def point_forces(mech: Mechanism, t, q, qd, pts: Float[Array, "K 3"], vel: Float[Array, "K 3"], contact=None):
    """Cartesian force on every point from springs, tyres and applied forces, ``(K, 3)``; ``None`` if the
    mechanism has none of them (:func:`point_force_terms`, summed per point; ``contact`` as there: each tyre's law
    fixed instead of read from its deflection's sign)."""
    terms = point_force_terms(mech, t, q, qd, lambda i: (pts[i], vel[i]), contact)
    if terms is None:
        return None
    idx, f = terms
    return jnp.zeros_like(pts).at[idx].add(f)


def generalized_point_forces(wk: Float[Array, "K F"], f_pts: Float[Array, "K 3"]) -> Float[Array, " 3F"]:
    """``Q = W^T F`` flattened to the free coordinates."""
    return (wk.T @ f_pts).reshape(-1)


def rotational_angles(mech: Mechanism, q) -> Float[Array, " R"]:
    """Relative rotation about z of every rotational spring's body ``b`` from its ``a`` (the ground: fixed) since
    the assembly, wrapped to ``(-pi, pi]``: from the directions between each body's first two primaries."""
    topo = mech.topo
    r = mech.all_positions(q)
    ab = np.asarray(topo.rotational_bodies, dtype=int).reshape(-1, 2)

    def direction(bodies, world: bool):
        out = []
        for b in bodies:
            if b < 0:
                out.append(jnp.array([1.0, 0.0], dtype=q.dtype))
                continue
            i, j = topo.body_particles[b][:2]
            d = (r[j] - r[i]) if world else (mech.body_primaries[b, 1] - mech.body_primaries[b, 0])
            out.append(d[:2])
        return jnp.stack(out)

    def angle(u, v):  # rotation taking u to v
        return jnp.arctan2(u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0], jnp.sum(u * v, axis=1))

    th_a = angle(direction(ab[:, 0], False), direction(ab[:, 0], True))
    th_b = angle(direction(ab[:, 1], False), direction(ab[:, 1], True))
    d = th_b - th_a
    return jnp.arctan2(jnp.sin(d), jnp.cos(d))


def _rotational_forces(mech: Mechanism, q, qd):
    """``-(k (theta - theta0) + c theta') dtheta/dx``: one jvp for the rates and one vjp for the forces."""
    th, th_dot = jax.jvp(lambda y: rotational_angles(mech, y), (q,), (qd,))
    tau = mech.rotational_stiffness * (th - mech.rotational_free_angle) + mech.rotational_damping * th_dot
    _, pull = jax.vjp(lambda y: rotational_angles(mech, y), q)
    return -pull(tau)[0]


def body_load_wrenches(mech: Mechanism, ap: BodyLoad, t, q, qd) -> dict:
    """Call a :class:`~.model.BodyLoad` on its bodies' named states; returns ``{body: (force, torque)}``
    checked (a force at the centre of mass and a torque, 3 numbers each, world frame)."""
    from ..errors import ModelError
    from .model import BodyState
    from .outputs import body_poses, body_velocities

    names = [mech.topo.body_names[b] for b in ap.bodies]
    idx = np.asarray(ap.bodies, dtype=int)
    rot, org = body_poses(mech, q)
    com = jnp.einsum("bij,bj->bi", rot, mech.body_com) + org
    v_com, omega = body_velocities(mech, q, qd)
    state = BodyState(position=dict(zip(names, com[idx])), rotation=dict(zip(names, rot[idx])),
                      velocity=dict(zip(names, v_com[idx])), angular_velocity=dict(zip(names, omega[idx])))
    out = ap.fn(t, state)
    if not isinstance(out, dict) or any(k not in names for k in out):
        raise ModelError(f"body load '{ap.name}': must return a dict {{body: (force, torque)}} over its bodies "
                         f"{names}, got {type(out).__name__}" + (f" with keys {list(out)}" if isinstance(out, dict)
                                                                  else ""))
    checked = {}
    for k, (force, torque) in out.items():
        force, torque = jnp.asarray(force, dtype=q.dtype), jnp.asarray(torque, dtype=q.dtype)
        if force.shape != (3,) or torque.shape != (3,):
            raise ModelError(f"body load '{ap.name}': body '{k}' needs a force and a torque of 3 numbers each, got "
                             f"shapes {force.shape} and {torque.shape}")
        checked[k] = (force, torque)
    return checked


def body_load_forces(mech: Mechanism, ap: BodyLoad, t, q, qd):
    """Generalised forces ``(3F,)`` of one body load: virtual power ``F . v_com + tau . omega`` of every body's
    wrench (:func:`body_load_wrenches`) over the free coordinates."""
    from .outputs import body_velocities

    names = [mech.topo.body_names[b] for b in ap.bodies]
    idx = np.asarray(ap.bodies, dtype=int)
    wrenches = body_load_wrenches(mech, ap, t, q, qd)
    f = jnp.zeros((len(names), 3), dtype=q.dtype)
    tau = jnp.zeros((len(names), 3), dtype=q.dtype)
    for k, (force, torque) in wrenches.items():
        i = names.index(k)
        f, tau = f.at[i].set(force), tau.at[i].set(torque)

    def vel(v):
        lin, ang = body_velocities(mech, q, v)
        return lin[idx], ang[idx]

    _, pull = jax.vjp(vel, qd)
    return pull((f, tau))[0]


def torque_forces(mech: Mechanism, t, q, qd):
    """Generalised forces ``(3F,)`` of the applied torques (virtual power ``tau . omega``), the body loads, the
    rotational spring-dampers, bushings and torsion springs (:mod:`.elements`); ``None`` if none."""
    from .elements import element_forces, has_elements

    torques = [ap for ap in mech.applied if isinstance(ap, (AppliedTorque, BodyLoad))]
    if not torques and not mech.topo.rotational_names and not has_elements(mech):
        return None
    gen = jnp.zeros_like(q) if not mech.topo.rotational_names else _rotational_forces(mech, q, qd)
    if has_elements(mech):
        gen = gen + element_forces(mech, q, qd)
    for ap in torques:
        if isinstance(ap, BodyLoad):
            gen = gen + body_load_forces(mech, ap, t, q, qd)
            continue
        _, pull = jax.vjp(lambda v, b=ap.body: body_angular_velocity(mech, b, q, v), qd)
        gen = gen + pull(applied_vector(ap, t, q, qd).astype(q.dtype))[0]
    return gen


@compiled("generalized_forces")
def generalized_forces(mech: Mechanism, t, q: Float[Array, " 3F"], qd: Float[Array, " 3F"], *,
                       lumped=None, contact=None) -> Float[Array, " 3F"]:
    """Gravity + spring-dampers + tyres + applied forces and torques, as forces on the free coordinates.
    ``contact`` fixes the law of each one-sided element (tyres, then bump stops: :func:`one_sided_names`; engaged
    or not) instead of reading it from the sign of its gap."""
    from .constraints import point_free_weights, point_weights, points

    topo = mech.topo
    free = np.asarray(topo.free, dtype=int)
    lumped = lumped_masses(mech) if lumped is None else lumped
    gen = (lumped[free][:, None] * mech.gravity[None, :]).reshape(-1)
    w = point_weights(mech)
    col = topo.free_column()
    pts = points(topo, w, mech.all_positions(q))
    vel = points(topo, w, jnp.where(jnp.asarray(col >= 0)[:, None], mech.all_positions(qd), 0.0))
    f_pts = point_forces(mech, t, q, qd, pts, vel, contact)
    if f_pts is not None:
        gen = gen + generalized_point_forces(point_free_weights(topo, w), f_pts)
    gen_t = torque_forces(mech, t, q, qd)
    return gen if gen_t is None else gen + gen_t


@compiled("potential_energy")
def potential_energy(mech: Mechanism, q: Float[Array, " 3F"], *, t=0.0) -> Float[Array, ""]:
    """Gravity, spring, (compressed) tyre, engaged bump stop, bushing and torsion spring energy; dampers and
    applied loads have none. ``t`` places a tyre's
    moving road (``ground=`` a function)."""
    topo = mech.topo
    r = mech.all_positions(q)
    u = -jnp.sum(lumped_masses(mech) * (r @ mech.gravity))
    if topo.spring_names or topo.tyre_names or topo.bump_names:
        p = _pts(mech, q)
    if topo.spring_names:
        ell = spring_lengths(mech, q)
        u = u + jnp.sum(0.5 * mech.spring_stiffness * (ell - mech.spring_free_length) ** 2)
        for i, x in enumerate(topo.spring_force_knots):
            if x:
                u = u + curve_integral(x, mech.spring_force_curve[i].astype(q.dtype),
                                       ell[i] - mech.spring_free_length[i])
    if topo.tyre_names:
        d = tyre_deflections(mech, p, t)
        u = u + jnp.sum(jnp.where(d < 0.0, 0.5 * mech.tyre_stiffness * d**2, 0.0))
    if topo.rotational_names:
        th = rotational_angles(mech, q) - mech.rotational_free_angle
        u = u + jnp.sum(0.5 * mech.rotational_stiffness * th**2)
    if topo.bump_names:
        g = bump_gaps(mech, p)
        u = u + jnp.sum(jnp.where(g < 0.0, 0.5 * mech.bump_stiffness * g**2, 0.0))
    from .elements import element_energy, has_elements

    if has_elements(mech):
        u = u + element_energy(mech, q)
    return u
