"""Building a mechanism by name: particles, bodies, joints, cut joints and force elements, checked on build.

Joints come from shared particles: two bodies listing the same particle are joined by a spherical joint there;
two shared particles make a revolute joint about their line; a body listing ground particles turns about a fixed
point (one) or a fixed axis (two). Prismatic joints and cut joints are explicit. Positions are global at assembly;
each body's inertia is given in its own frame, placed by ``pose``.

Example (a pendulum)::

    mb = MechanismBuilder(gravity=(0, 0, -9.81))
    mb.ground("O", (0, 0, 0))
    mb.particle("tip", (1, 0, 0))
    mb.body("rod", RigidInertia(1.0, (0.5, 0, 0), diag(0, 1/12, 1/12), degenerate_ok=True), ["O", "tip"])
    mech, x0 = mb.build()
"""

from __future__ import annotations

from typing import Callable, Optional, Sequence

import jax.numpy as jnp
import numpy as np

from ..errors import ModelError
from ..inertia import RigidInertia
from ..particles import N_PRIMARY, check_placement, equivalent_particles
from ..spatial import frame_from_points
from .constraints import constraint_jacobian, constraint_labels, constraints
from .model import AppliedSpec, BodySpec, Mechanism, PointSpec, SpringSpec, TyreSpec

__all__ = ["MechanismBuilder", "ASSEMBLY_RTOL", "RANK_RTOL"]

#: Constraints must hold at the given positions to this fraction of the mechanism's size.
ASSEMBLY_RTOL = 1e-9
#: Singular values of the constraint Jacobian below this fraction of the largest count as rank loss.
RANK_RTOL = 1e-9


class MechanismBuilder:
    """Collects a mechanism description; :meth:`build` checks it and returns ``(Mechanism, x0)``."""

    def __init__(self, gravity: Sequence[float] = (0.0, 0.0, -9.81)):
        self.gravity = np.asarray(gravity, dtype=float)
        self._particles: dict[str, tuple[np.ndarray, bool]] = {}
        self._bodies: list[tuple[str, RigidInertia, tuple[str, ...], tuple, str]] = []
        self._joints: list[tuple[str, tuple[str, ...], str, Optional[float]]] = []  # kind, names, label, length
        self._points: dict[str, tuple[Optional[str], np.ndarray]] = {}
        self._springs: list[tuple] = []
        self._tyres: list[tuple] = []
        self._applied: list[tuple] = []

    # ---- particles ----
    def _add_particle(self, name: str, xyz, ground: bool) -> str:
        if name in self._particles or name in self._points:
            raise ModelError(f"particle '{name}' is defined twice")
        p = np.asarray(xyz, dtype=float)
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise ModelError(f"particle '{name}': position must be 3 finite numbers, got {np.asarray(xyz).tolist()}")
        self._particles[name] = (p, ground)
        return name

    def particle(self, name: str, xyz) -> str:
        """A free particle at global position ``xyz`` (assembly configuration)."""
        return self._add_particle(name, xyz, False)

    def ground(self, name: str, xyz) -> str:
        """A particle fixed to the ground (a fixed point of a joint or a force element)."""
        return self._add_particle(name, xyz, True)

    # ---- bodies and joints ----
    def body(self, name: str, inertia: RigidInertia, primaries: Sequence[str], *,
             pose: tuple = (np.eye(3), np.zeros(3)), on_negative: str = "warn") -> str:
        """A rigid body with its inertia in its own frame (placed at ``pose = (R, origin)`` in the world) and its
        2 (rod), 3 (planar) or 4 (spatial) primary particles, named."""
        if any(b[0] == name for b in self._bodies):
            raise ModelError(f"body '{name}' is defined twice")
        if len(primaries) not in N_PRIMARY.values():
            raise ModelError(f"body '{name}': needs 2 (rod), 3 (planar) or 4 (spatial) primary particles, "
                             f"got {len(primaries)}")
        if len(set(primaries)) != len(primaries):
            raise ModelError(f"body '{name}': a primary particle is listed twice: {list(primaries)}")
        self._bodies.append((name, inertia, tuple(primaries), pose, on_negative))
        return name

    def link(self, a: str, b: str, *, name: Optional[str] = None, length: Optional[float] = None) -> None:
        """A massless rigid link (distance constraint) between particles or points ``a`` and ``b``; its length is
        the assembly distance unless given."""
        self._joints.append(("link", (a, b), name or f"link {a}-{b}", length))

    def cut_joint(self, a: str, b: str, *, name: Optional[str] = None) -> None:
        """Close a loop: particles/points ``a`` and ``b`` (on different branches) coincide, ``r_a = r_b``."""
        self._joints.append(("coincide", (a, b), name or f"cut joint {a}={b}", None))

    def on_line(self, particle: str, origin: str, direction: Sequence[str], ref: str, *,
                name: Optional[str] = None) -> None:
        """Keep ``particle`` on the line through point ``origin`` along ``direction = (d0, d1)``; ``origin``,
        ``d0``, ``d1`` and ``ref`` (off the line) are points of one body (or the ground). With a shared particle
        at ``origin`` this makes a revolute joint whose second axis particle belongs to one body only."""
        if len(direction) != 2:
            raise ModelError(f"on_line {name or particle}: direction needs two points")
        self._joints.append(("on_line", (particle, origin, *direction, ref), name or f"{particle} on axis", None))

    def prismatic(self, axis_a: Sequence[str], axis_b: Sequence[str], *, name: Optional[str] = None) -> None:
        """Prismatic joint: ``axis_a = (a0, a1, a2)`` are particles/points of body A (or ground) with a0, a1 on the
        axis and a2 off it; ``axis_b = (b0, b1, b2)`` likewise on body B. B slides along A's axis without turning."""
        if len(axis_a) != 3 or len(axis_b) != 3:
            raise ModelError(f"prismatic joint {name}: needs three particles on each side")
        self._joints.append(("prismatic", (*axis_a, *axis_b), name or f"prismatic {axis_a[0]}-{axis_b[0]}", None))

    # ---- force elements ----
    def point(self, name: str, body: Optional[str], xyz) -> str:
        """A named point fixed to ``body`` (``None``: to the ground) at global ``xyz`` (assembly)."""
        if name in self._points or name in self._particles:
            raise ModelError(f"point '{name}' is defined twice")
        self._points[name] = (body, np.asarray(xyz, dtype=float))
        return name

    def spring_damper(self, name: str, a: str, b: str, stiffness: float, damping: float,
                      free_length: float) -> None:
        """Point-to-point spring-damper between two particles or points."""
        for label, v in (("stiffness", stiffness), ("damping", damping), ("free length", free_length)):
            if not np.isfinite(v) or v < 0:
                raise ModelError(f"spring '{name}': {label} must be finite and non-negative, got {v!r}")
        self._springs.append((name, a, b, stiffness, damping, free_length))

    def tyre(self, name: str, point: str, stiffness: float, damping: float, radius: float, *,
             normal=(0.0, 0.0, 1.0), ground: float = 0.0) -> None:
        """One-sided tyre spring-damper acting along ``normal`` on ``point`` while it is within ``radius`` of the
        ground plane ``p.normal = ground``."""
        self._tyres.append((name, point, np.asarray(normal, dtype=float), stiffness, damping, radius, ground))

    def applied_force(self, name: str, point: str, fn: Callable) -> None:
        """A force ``fn(t, x, xd) -> (3,)`` (global) acting at a particle or point."""
        self._applied.append((name, "force", point, fn))

    def applied_torque(self, name: str, body: str, fn: Callable) -> None:
        """A torque ``fn(t, x, xd) -> (3,)`` (global) acting on a spatial or planar body."""
        self._applied.append((name, "torque", body, fn))

    # ---- build ----
    def build(self, *, dof: Optional[int] = None) -> tuple[Mechanism, np.ndarray]:
        """Check everything and return the mechanism and its assembly state ``x0`` ``(3F,)``.

        Raises :class:`ModelError` naming the culprit for: unknown names, a dangling particle (in no body and no
        link), violated constraints at the given positions, redundant (over-constrained) constraints, a
        mechanism whose degrees of freedom differ from ``dof``, a spring of zero length, a direction of motion
        that carries no mass. Singular particle placements and non-physical inertias are refused by
        :mod:`particlesim.particles` and :mod:`particlesim.inertia` with the body's name.
        """
        names = list(self._particles)
        index = {n: i for i, n in enumerate(names)}
        pos = np.stack([self._particles[n][0] for n in names]) if names else np.zeros((0, 3))
        is_ground = np.array([self._particles[n][1] for n in names], dtype=bool)

        def idx(n: str, what: str) -> int:
            if n not in index:
                raise ModelError(f"{what}: unknown particle '{n}'")
            return index[n]

        bodies, masses, coms, inertias, prims, distance = [], [], [], [], [], []
        lengths = []
        seen: set = set()
        for name, inertia, primaries, (rot, origin), on_negative in self._bodies:
            ids = tuple(idx(p, f"body '{name}'") for p in primaries)
            rot = np.asarray(rot, dtype=float)
            local = (pos[list(ids)] - np.asarray(origin, dtype=float)) @ rot
            kind = check_placement(local, name)
            if all(is_ground[i] for i in ids):
                raise ModelError(f"body '{name}': all its particles are fixed to the ground")
            equivalent_particles(inertia, local, name=name, on_negative=on_negative)  # placement/representability
            bodies.append(BodySpec(name=name, kind=kind, primaries=ids))
            masses.append(inertia.mass)
            coms.append(inertia.com)
            inertias.append(inertia.inertia)
            prims.append(jnp.asarray(local))
            for a in range(len(ids)):
                for b in range(a + 1, len(ids)):
                    pair = frozenset((ids[a], ids[b]))
                    if pair in seen:  # two shared particles (a revolute joint): one constraint for both bodies
                        continue
                    seen.add(pair)
                    if not (is_ground[ids[a]] and is_ground[ids[b]]):
                        distance.append((ids[a], ids[b], f"body '{name}' distance {primaries[a]}-{primaries[b]}"))
                        lengths.append(np.linalg.norm(pos[ids[a]] - pos[ids[b]]))
        free = tuple(int(i) for i in np.flatnonzero(~is_ground))
        used = {i for b in bodies for i in b.primaries}

        points = []
        point_index = {}
        for n in names:
            point_index[n] = len(points)
            points.append(PointSpec(name=n, particle=index[n], body=-1, local=jnp.zeros(3)))
        body_index = {b.name: k for k, b in enumerate(bodies)}
        for pname, (bname, xyz) in self._points.items():
            if bname is None:
                raise ModelError(f"point '{pname}': a ground point must be declared with ground(...)")
            if bname not in body_index:
                raise ModelError(f"point '{pname}': unknown body '{bname}'")
            b = bodies[body_index[bname]]
            p = pos[list(b.primaries)]
            if b.kind == "rod":
                u = p[1] - p[0]
                s = float((xyz - p[0]) @ u / (u @ u))
                if np.linalg.norm(p[0] + s * u - xyz) > ASSEMBLY_RTOL * np.linalg.norm(u):
                    raise ModelError(f"point '{pname}': not on the line of rod body '{bname}'")
                local = np.array([s, 0.0, 0.0])
            else:
                f = np.asarray(frame_from_points(*map(jnp.asarray, p[:3])))
                local = f.T @ (xyz - p[0])
            point_index[pname] = len(points)
            points.append(PointSpec(name=pname, particle=-1, body=body_index[bname], local=jnp.asarray(local)))

        def pidx(n, what):
            if n not in point_index:
                raise ModelError(f"{what}: unknown particle or point '{n}'")
            return point_index[n]

        def where(k):  # assembly position of point k
            pt = points[k]
            if pt.particle >= 0:
                return pos[pt.particle]
            return np.asarray(_point_world(bodies[pt.body], np.asarray(pt.local), pos))

        coincide, generic, point_lengths, offsets = [], [], [], []
        for kind, pnames, label, length in self._joints:
            ks = tuple(pidx(n, label) for n in pnames)
            particles_only = all(points[k].particle >= 0 for k in ks)
            if kind == "link" and particles_only:
                distance.append((ks[0], ks[1], label))
                lengths.append(np.linalg.norm(pos[ks[0]] - pos[ks[1]]) if length is None else float(length))
            elif kind == "coincide" and particles_only:
                coincide.append((ks[0], ks[1], label))
            elif kind == "link":
                generic.append(("link", ks, label, len(point_lengths)))
                point_lengths.append(np.linalg.norm(where(ks[0]) - where(ks[1])) if length is None else float(length))
            elif kind == "coincide":
                generic.append(("coincide", ks, label, -1))
            elif kind == "on_line":
                b, o, d0, d1, ref = (where(k) for k in ks)
                if np.linalg.norm(np.cross(d1 - d0, ref - d0)) <= 1e-9 * np.linalg.norm(d1 - d0) ** 2:
                    raise ModelError(f"{label}: reference point '{pnames[4]}' lies on the line")
                generic.append(("on_line", ks, label, -1))
            else:
                a0, a1, a2, b0, _, b2 = (where(k) for k in ks)
                if np.linalg.norm(np.cross(a1 - a0, a2 - a0)) <= 1e-9 * np.linalg.norm(a1 - a0) ** 2:
                    raise ModelError(f"{label}: point '{pnames[2]}' lies on the axis '{pnames[0]}'-'{pnames[1]}'")
                f = np.asarray(frame_from_points(jnp.asarray(a0), jnp.asarray(a1), jnp.asarray(a2)))
                generic.append(("prismatic", ks, label, len(offsets)))
                offsets.append(float(f[:, 1] @ (b2 - b0)))
        constrained = {k for kind, ks, _, _ in generic for k in ks} | {i for i, j, _ in coincide} | \
            {j for i, j, _ in coincide} | {i for i, j, _ in distance} | {j for i, j, _ in distance}
        for i in free:
            if i not in used and i not in constrained:
                raise ModelError(f"particle '{names[i]}' is dangling: it belongs to no body and no joint")

        mech0 = dict(
            body_mass=tuple(masses), body_com=tuple(coms), body_inertia=tuple(inertias), body_primaries=tuple(prims),
            ground_xyz=jnp.asarray(pos[is_ground]).reshape(-1, 3), lengths=jnp.asarray(lengths, dtype=float),
            point_lengths=jnp.asarray(point_lengths, dtype=float), offsets=jnp.asarray(offsets, dtype=float), gravity=jnp.asarray(self.gravity), points=tuple(points),
            particle_names=tuple(names), free=free, ground=tuple(int(i) for i in np.flatnonzero(is_ground)),
            bodies=tuple(bodies), distance_pairs=tuple(distance), coincide_pairs=tuple(coincide),
            generic=tuple(generic),
        )
        springs = []
        for name, a, b, k, c, l0 in self._springs:
            springs.append(SpringSpec(name=name, a=pidx(a, f"spring '{name}'"), b=pidx(b, f"spring '{name}'"),
                                      stiffness=jnp.asarray(k, dtype=float), damping=jnp.asarray(c, dtype=float),
                                      free_length=jnp.asarray(l0, dtype=float)))
        tyres = []
        for name, pt, normal, k, c, radius, ground in self._tyres:
            nrm = np.linalg.norm(normal)
            if not np.isfinite(nrm) or nrm == 0:
                raise ModelError(f"tyre '{name}': normal must be a non-zero vector")
            tyres.append(TyreSpec(name=name, point=pidx(pt, f"tyre '{name}'"), normal=tuple(float(v) for v in normal / nrm),
                                  stiffness=jnp.asarray(k, dtype=float), damping=jnp.asarray(c, dtype=float),
                                  radius=jnp.asarray(radius, dtype=float), ground=jnp.asarray(ground, dtype=float)))
        applied = []
        for name, kind, target, fn in self._applied:
            if kind == "force":
                applied.append(AppliedSpec(name=name, kind=kind, target=pidx(target, f"force '{name}'"), fn=fn))
            else:
                if target not in body_index or bodies[body_index[target]].kind == "rod":
                    raise ModelError(f"torque '{name}': '{target}' is not a spatial or planar body")
                applied.append(AppliedSpec(name=name, kind=kind, target=body_index[target], fn=fn))
        mech = Mechanism(springs=tuple(springs), tyres=tuple(tyres), applied=tuple(applied), **mech0)
        x0 = pos[list(free)].reshape(-1)
        _check(mech, x0, dof)
        return mech, x0


def _check(mech: Mechanism, x0: np.ndarray, dof: Optional[int]) -> None:
    """Assembly, rank, degrees of freedom, positive kinetic energy, spring lengths."""
    size = max(float(np.ptp(np.asarray(mech.all_positions(jnp.asarray(x0))), axis=0).max()), 1e-12)
    labels = constraint_labels(mech)
    res = np.asarray(constraints(mech, jnp.asarray(x0)))
    bad = [(labels[i], float(res[i])) for i in np.flatnonzero(np.abs(res) > ASSEMBLY_RTOL * size * max(size, 1.0))]
    if bad:
        raise ModelError("initial positions violate constraints: " +
                         ", ".join(f"{lab} (residual {v:.3g})" for lab, v in bad[:6]))
    for s in mech.springs:
        ell = float(np.linalg.norm(np.asarray(mech.point_position(s.a, mech.all_positions(jnp.asarray(x0)))
                                              - mech.point_position(s.b, mech.all_positions(jnp.asarray(x0))))))
        if ell <= ASSEMBLY_RTOL * size:
            raise ModelError(f"spring '{s.name}': its end points coincide (zero length): its direction is undefined")
    j = np.asarray(constraint_jacobian(mech, jnp.asarray(x0)))
    n = j.shape[1]
    if j.shape[0]:
        sv = np.linalg.svd(j, compute_uv=False)
        rank = int(np.sum(sv > RANK_RTOL * sv[0]))
        if rank < j.shape[0]:
            culprit = _redundant_rows(j, labels)
            raise ModelError(f"over-constrained: {j.shape[0] - rank} redundant constraint(s) among "
                             f"{j.shape[0]}; first redundant: {culprit}")
    else:
        rank = 0
    if dof is not None and n - rank != dof:
        what = "under" if n - rank > dof else "over"
        raise ModelError(f"{what}-constrained: the mechanism has {n - rank} degrees of freedom, expected {dof}")
    # Kinetic energy positive on every admissible motion (else the acceleration solve is singular).
    if n - rank:
        _, _, vt = np.linalg.svd(j if j.shape[0] else np.zeros((1, n)))
        z = vt[rank:].T
        m_red = z.T @ np.asarray(mech.mass_matrix()) @ z
        ev = np.linalg.eigvalsh(0.5 * (m_red + m_red.T))
        if ev[0] <= 1e-12 * max(ev[-1], 1e-300):
            raise ModelError("a free motion of the mechanism carries no mass (kinetic energy matrix on the "
                             f"admissible motions is singular, eigenvalues {ev[:3].tolist()}): add mass or "
                             "constraints")


def _redundant_rows(j: np.ndarray, labels: list[str]) -> str:
    kept = []
    for i in range(j.shape[0]):
        trial = j[kept + [i]]
        sv = np.linalg.svd(trial, compute_uv=False)
        if np.sum(sv > RANK_RTOL * sv[0]) == len(kept) + 1:
            kept.append(i)
        else:
            return labels[i]
    return "?"


def _point_world(body: BodySpec, local: np.ndarray, pos: np.ndarray) -> np.ndarray:
    p = pos[list(body.primaries)]
    if body.kind == "rod":
        return p[0] + local[0] * (p[1] - p[0])
    return p[0] + np.asarray(frame_from_points(*map(jnp.asarray, p[:3]))) @ local
