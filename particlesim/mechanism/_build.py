"""The stages of :meth:`~.builder.MechanismBuilder.build`, on NumPy arrays at the assembly configuration.

:meth:`_Build.run` reads as the list of stages: bodies (equivalent particles), joint plans (hidden ground particles
for ground-side directions), points, the bodies' rigid distances, the joints' rows (:mod:`.joints`), drivers, the
plane rows of a planar mechanism, a dangling-particle check, the :class:`~.model.Mechanism`, the optional assembly
and the checks (assembly residuals, rank, degrees of freedom, mass on every admissible motion).
"""

from __future__ import annotations

import dataclasses
import inspect
import warnings
from typing import Callable, Optional, Sequence

import jax.numpy as jnp
import numpy as np

from ..errors import ModelError
from ..inertia import RigidInertia
from ..particles import check_placement, equivalent_particles
from . import sparse
from .joints import AXES, unit
from .model import AppliedForce, AppliedTorque, BodyLoad, DotRows, DriveRows, LinearRows, Mechanism, Topology

__all__ = ["ConstraintRank", "RedundantConstraintsWarning", "ASSEMBLY_RTOL", "RANK_RTOL"]

#: Constraints must hold at the given positions to this fraction of the mechanism's size.
ASSEMBLY_RTOL = 1e-9
#: Singular values of the constraint Jacobian below this fraction of the largest count as rank loss.
RANK_RTOL = 1e-9

#: Name of the hidden ground particle at the origin of a planar mechanism's plane.
_PLANE = "(plane origin)"


class RedundantConstraintsWarning(UserWarning):
    """A mechanism was built with redundant constraint rows (solved with least-squares multipliers)."""


@dataclasses.dataclass(frozen=True)
class ConstraintRank:
    """The constraint rows of a built mechanism: their number, the rank of their Jacobian at the assembly, the
    redundant rows (each depends on the rows before it), the degrees of freedom and the multiplier solve used."""

    rows: int
    rank: int
    redundant: tuple[str, ...]
    dof: int
    multipliers: str

    def __str__(self) -> str:
        red = f"; redundant: {', '.join(self.redundant)}" if self.redundant else ""
        return (f"{self.rows} constraint rows of rank {self.rank}, {self.dof} degrees of freedom, "
                f"{self.multipliers} multipliers{red}")


class _Build:
    """One build: the stages of :meth:`MechanismBuilder.build`, in order, on NumPy arrays."""

    def __init__(self, mb):  # a MechanismBuilder (its recorded declarations)
        self.mb = mb
        self.names = list(mb._particles)
        self.index = {n: i for i, n in enumerate(self.names)}
        self.pos = [mb._particles[n][0] for n in self.names]
        self.is_ground = [mb._particles[n][1] for n in self.names]
        self.body_names: list[str] = []
        self.body_particles: list[tuple[int, ...]] = []
        self.body_pose: list[tuple[np.ndarray, np.ndarray]] = []
        self.inertia: list[RigidInertia] = []
        self.local_primaries: list[np.ndarray] = []
        self.particle_masses: list[np.ndarray] = []
        self.member: dict[int, list[int]] = {}  # particle -> bodies listing it
        self.point_names: list[str] = []
        self.point_body: list[int] = []
        self.point_local: list[np.ndarray] = []
        self.point_world: list[np.ndarray] = []
        self.point_index: dict[str, int] = {}
        self.dot: list[tuple] = []  # (a, b, c, d, scale, kappa, label)
        self.lin: list[tuple] = []  # (a, b, axis, label)
        self.drv: list[tuple] = []  # (a, b, axis, spin, offset, label, fn)
        self.jacobian0: np.ndarray | None = None  # the rows' Jacobian at the assembly (the rank check's)

    def run(self, dof, assemble=False, hold=(), multipliers="auto"):
        self.bodies()
        plans = self.joint_plans()  # may add hidden ground particles (ground-side joint directions)
        if self.mb.planar:  # the plane's origin, a hidden ground particle every free particle is held to
            self.index[_PLANE] = len(self.names)
            self.names.append(_PLANE)
            self.pos.append(np.zeros(3))
            self.is_ground.append(True)
        self.points()
        self.body_rows()
        self.joints(plans)
        self.drives()
        if self.mb.planar:
            plane = self.index[_PLANE]
            for i in range(len(self.names)):
                if not self.is_ground[i]:
                    self.lin.append((i, plane, (0.0, 0.0, 1.0), f"{self.names[i]} in plane"))
        self.check_dangling()
        mech = self.mechanism()
        q0 = np.stack([self.pos[i] for i in mech.topo.free]).reshape(-1) if mech.topo.free else np.zeros(0)
        self.assembly = None
        if assemble or hold:
            q0 = self.assemble(mech, q0, hold)
        lsq = _check(self, mech, q0, dof, multipliers)
        if lsq:
            mech = dataclasses.replace(mech, topo=dataclasses.replace(mech.topo, least_squares=True))
        plan = sparse.choose(mech.topo, self.jacobian0, RANK_RTOL)
        if plan is not None:
            mech = dataclasses.replace(mech, topo=dataclasses.replace(mech.topo, sparse=plan))
        return mech, q0

    def assemble(self, mech: Mechanism, q0: np.ndarray, hold) -> np.ndarray:
        """Close joints and loops from approximate positions (NumPy Gauss-Newton on the typed rows); moves the
        free particles and the points they carry."""
        from .assembly import ASSEMBLE_RTOL, gauss_newton, held_columns, report

        topo = mech.topo
        wk = _np_point_weights(self, topo)
        pts0 = np.asarray(self.point_world, dtype=float).reshape(-1, 3)
        kappa = np.asarray(mech.dot_kappa)
        size = max(float(np.ptp(pts0, axis=0).max()) if len(pts0) else 0.0, 1e-12)

        offset = np.asarray(mech.drive_offset)

        def rows(q):
            return _np_rows(topo, kappa, pts0 + wk @ (q - q0).reshape(-1, 3), wk, offset)

        held = held_columns(topo.particle_names, topo.free, hold)
        q, res, it = gauss_newton(rows, q0, held, ASSEMBLE_RTOL * size * max(size, 1.0), topo.row_labels())
        self.point_world = list(pts0 + wk @ (q - q0).reshape(-1, 3))
        for c, i in enumerate(topo.free):
            self.pos[i] = q[3 * c:3 * c + 3]
        self.assembly = report(topo.particle_names, topo.free, q0, q, res, it)
        return q

    # -- stages --
    def particle(self, n: str, what: str) -> int:
        if n not in self.index:
            raise ModelError(f"{what}: unknown particle '{n}'")
        return self.index[n]

    def bodies(self):
        for name, inertia, primaries, (rot, origin), on_negative in self.mb._bodies:
            ids = tuple(self.particle(p, f"body '{name}'") for p in primaries)
            rot = np.asarray(rot, dtype=float)
            origin = np.asarray(origin, dtype=float)
            local = (np.stack([self.pos[i] for i in ids]) - origin) @ rot
            check_placement(local, name)
            if all(self.is_ground[i] for i in ids):
                raise ModelError(f"body '{name}': all its particles are fixed to the ground")
            ps = equivalent_particles(inertia, local, name=name, on_negative=on_negative)  # placement, representable
            self.particle_masses.append(np.asarray(ps.masses))
            b = len(self.body_names)
            self.body_names.append(name)
            self.body_particles.append(ids)
            self.body_pose.append((rot, origin))
            self.inertia.append(inertia)
            self.local_primaries.append(local)
            for i in ids:
                self.member.setdefault(i, []).append(b)

    def where(self, n: str, what: str) -> tuple[np.ndarray, set]:
        """Assembly position of a particle or user point and the bodies it may belong to (``-1``: ground)."""
        if n in self.index:
            i = self.index[n]
            cand = set(self.member.get(i, []))
            if self.is_ground[i]:
                cand.add(-1)
            return self.pos[i], cand
        if n in self.mb._points:
            bname, xyz = self.mb._points[n]
            return xyz, ({self.body_names.index(bname)} if bname in self.body_names else set())
        raise ModelError(f"{what}: unknown particle or point '{n}'")

    def host(self, names: Sequence[str], label: str) -> int:
        """The body (``-1``: the ground) that all the named points belong to."""
        common = None
        for n in names:
            cand = self.where(n, label)[1]
            common = cand if common is None else common & cand
        if not common:
            raise ModelError(f"{label}: points {list(names)} do not all belong to one body (or the ground)")
        return -1 if -1 in common else min(common)

    def joint_plans(self) -> list:
        """Every explicit joint's assembly geometry (:meth:`~.joints.Joint.plan`), before points are numbered."""
        return [joint.plan(self) for joint in self.mb._joints]

    def hidden_ground(self, name: str, xyz) -> str:
        """A ground particle the build adds (a ground-side direction of a joint), named after its joint."""
        self.index[name] = len(self.names)
        self.names.append(name)
        self.pos.append(np.asarray(xyz, dtype=float))
        self.is_ground.append(True)
        return name

    def directions(self, b: int) -> list[np.ndarray]:
        """Unit directions fixed in body ``b`` (``-1``: the ground) at assembly: the axes for the ground and a
        spatial body, the two in-plane directions of a planar set (or the x and y axes in a planar mechanism), the
        line of a rod."""
        if b < 0 or len(self.body_particles[b]) == 4:
            return [np.asarray(e) for e in AXES[:2 if self.mb.planar else 3]]
        p = np.stack([self.pos[i] for i in self.body_particles[b]])
        e1 = unit(p[1] - p[0])
        if len(p) == 2:
            return [e1]
        if self.mb.planar:
            return [np.asarray(e) for e in AXES[:2]]
        w = (p[2] - p[0]) - ((p[2] - p[0]) @ e1) * e1
        return [e1, unit(w)]

    def add_point(self, name: str, body: int, world: np.ndarray) -> int:
        """A point fixed to ``body`` (``-1``: a particle point) at assembly position ``world``."""
        if name in self.point_index:
            raise ModelError(f"point '{name}' is defined twice")
        k = len(self.point_names)
        self.point_names.append(name)
        self.point_body.append(body)
        if body >= 0:
            rot, origin = self.body_pose[body]
            local = rot.T @ (world - origin)
            prim = self.local_primaries[body]
            kind = {2: "rod", 3: "planar", 4: "spatial"}[len(prim)]
            if kind != "spatial":
                e = (prim[1:] - prim[0]).T
                coef = np.linalg.lstsq(e, local - prim[0], rcond=None)[0]
                off = np.linalg.norm(prim[0] + e @ coef - local)
                size = np.max(np.linalg.norm(prim - prim[0], axis=1))
                if off > 1e-9 * max(size, 1.0):
                    where = "plane of the primaries of planar" if kind == "planar" else "line of rod"
                    raise ModelError(f"point '{name}': lies {off:.3g} m off the {where} body "
                                     f"'{self.body_names[body]}' (world {np.asarray(world).tolist()}); a point fixed "
                                     "to it must lie there (give the body 4 primaries to attach points anywhere)")
            self.point_local.append(local)
        else:
            self.point_local.append(np.zeros(3))
        self.point_world.append(np.asarray(world, dtype=float))
        self.point_index[name] = k
        return k

    def points(self):
        for i, n in enumerate(self.names):
            self.add_point(n, -1, self.pos[i])
        for pname, (bname, xyz) in self.mb._points.items():
            if bname is None:
                raise ModelError(f"point '{pname}': a ground point must be declared with ground(...)")
            if bname not in self.body_names:
                raise ModelError(f"point '{pname}': unknown body '{bname}'")
            self.add_point(pname, self.body_names.index(bname), xyz)

    def body_rows(self):
        seen: set = set()
        for b, ids in enumerate(self.body_particles):
            prim_names = [self.names[i] for i in ids]
            for s in range(len(ids)):
                for t in range(s + 1, len(ids)):
                    i, j = ids[s], ids[t]
                    pair = frozenset((i, j))
                    if pair in seen or (self.is_ground[i] and self.is_ground[j]):
                        continue  # two shared particles (a revolute joint): one constraint for both bodies
                    seen.add(pair)
                    ell = np.linalg.norm(self.pos[i] - self.pos[j])
                    self.dot.append((i, j, i, j, 0.5, 0.5 * ell**2,
                                     f"body '{self.body_names[b]}' distance {prim_names[s]}-{prim_names[t]}"))

    def pidx(self, n: str, what: str) -> int:
        if n not in self.point_index:
            raise ModelError(f"{what}: unknown particle or point '{n}'")
        return self.point_index[n]

    def joints(self, plans):
        """Every explicit joint's rows (:meth:`~.joints.Joint.rows`)."""
        for joint, plan in zip(self.mb._joints, plans):
            joint.rows(self, plan)

    def drives(self):
        """Every driver's row (:class:`~.joints.DriveAngle`, :class:`~.joints.DrivePosition`)."""
        size = max(float(np.ptp(np.asarray(self.pos), axis=0).max()), 1e-12) if self.pos else 1.0
        for driver in self.mb._drives:
            driver.rows(self, size)

    def check_dangling(self):
        constrained = set()
        for a, b, c, d, *_ in self.dot:
            constrained |= {a, b, c, d}
        for a, b, *_ in self.lin:
            constrained |= {a, b}
        for i in range(len(self.names)):
            if not self.is_ground[i] and i not in self.member and i not in constrained:
                raise ModelError(f"particle '{self.names[i]}' is dangling: it belongs to no body and no joint")

    def mechanism(self) -> Mechanism:
        mb = self.mb
        free = tuple(i for i in range(len(self.names)) if not self.is_ground[i])
        ground = tuple(i for i in range(len(self.names)) if self.is_ground[i])
        springs, tyres = [], []
        for name, a, b, k, c, l0, f_curve, c_curve in mb._springs:
            ends = (self.pidx(a, f"spring '{name}'"), self.pidx(b, f"spring '{name}'"))
            if l0 is None:
                l0 = float(np.linalg.norm(self.point_world[ends[0]] - self.point_world[ends[1]]))
            springs.append((name, ends, k, c, l0, f_curve, c_curve))
        for name, pt, normal, k, c, radius, g, apply_at, road in mb._tyres:
            nrm = np.linalg.norm(normal)
            if normal.shape != (3,) or not np.isfinite(nrm) or nrm == 0:
                raise ModelError(f"tyre '{name}': normal must be a non-zero vector of 3 numbers")
            at = self.pidx(pt if apply_at is None else apply_at, f"tyre '{name}' (application point)")
            tyres.append((name, self.pidx(pt, f"tyre '{name}'"), tuple(float(v) for v in normal / nrm), k, c,
                          radius, g, at, road))
        applied = []
        for cls, name, target, fn in mb._applied:
            if cls is AppliedForce:
                applied.append(AppliedForce(name=name, point=self.pidx(target, f"force '{name}'"), fn=fn))
            elif cls is BodyLoad:
                for b in target:
                    if b not in self.body_names:
                        raise ModelError(f"body load '{name}': unknown body '{b}'")
                applied.append(BodyLoad(name=name, bodies=tuple(self.body_names.index(b) for b in target), fn=fn))
            else:
                if target not in self.body_names or len(self.body_particles[self.body_names.index(target)]) == 2:
                    raise ModelError(f"torque '{name}': '{target}' is not a spatial or planar body")
                applied.append(AppliedTorque(name=name, body=self.body_names.index(target), fn=fn))
        rot = []
        for name, a, b, k, c, th0 in mb._rotational:
            idx = []
            for body in (a, b):
                if body is None:
                    idx.append(-1)
                elif body not in self.body_names:
                    raise ModelError(f"rotational spring '{name}': unknown body '{body}'")
                else:
                    idx.append(self.body_names.index(body))
            rot.append((name, tuple(idx), k, c, th0))
        bush, tors, bumps = self.elements()
        in_body = set(self.member)
        topo = Topology(
            particle_names=tuple(self.names), free=free, ground=ground, body_names=tuple(self.body_names),
            body_particles=tuple(self.body_particles), point_names=tuple(self.point_names),
            point_body=tuple(self.point_body),
            dot=DotRows(a=tuple(r[0] for r in self.dot), b=tuple(r[1] for r in self.dot),
                        c=tuple(r[2] for r in self.dot), d=tuple(r[3] for r in self.dot),
                        scale=tuple(float(r[4]) for r in self.dot), labels=tuple(r[6] for r in self.dot),
                        turn=tuple(bool(r[7]) if len(r) > 7 else False for r in self.dot)
                        if any(len(r) > 7 and r[7] for r in self.dot) else ()),
            linear=LinearRows(a=tuple(r[0] for r in self.lin), b=tuple(r[1] for r in self.lin),
                              axis=tuple(r[2] for r in self.lin), labels=tuple(r[3] for r in self.lin)),
            spring_names=tuple(s[0] for s in springs), spring_points=tuple(s[1] for s in springs),
            spring_force_knots=tuple(() if s[5] is None else s[5][0] for s in springs)
            if any(s[5] is not None for s in springs) else (),
            spring_damping_knots=tuple(() if s[6] is None else s[6][0] for s in springs)
            if any(s[6] is not None for s in springs) else (),
            tyre_names=tuple(t[0] for t in tyres), tyre_points=tuple(t[1] for t in tyres),
            tyre_normals=tuple(t[2] for t in tyres), tyre_apply=tuple(t[7] for t in tyres),
            tyre_road_args=tuple(0 if t[8] is None else _road_arity(t[0], t[8]) for t in tyres)
            if any(t[8] is not None for t in tyres) else (),
            saddle_point=any(i not in in_body for i in free), planar=mb.planar,
            rotational_names=tuple(r[0] for r in rot), rotational_bodies=tuple(r[1] for r in rot),
            drive=DriveRows(a=tuple(r[0] for r in self.drv), b=tuple(r[1] for r in self.drv),
                            axis=tuple(tuple(float(v) for v in r[2]) for r in self.drv),
                            spin=tuple(tuple(float(v) for v in r[3]) for r in self.drv),
                            labels=tuple(r[5] for r in self.drv),
                            names=tuple(d.name for d in self.mb._drives)),
            bushing_names=tuple(e[0] for e in bush), bushing_bodies=tuple(e[1] for e in bush),
            bushing_rotational=tuple(e[7] for e in bush), torsion_names=tuple(e[0] for e in tors),
            torsion_bodies=tuple(e[1] for e in tors), bump_names=tuple(e[0] for e in bumps),
            bump_points=tuple(e[1] for e in bumps), bump_rebound=tuple(e[6] for e in bumps))
        if not topo.saddle_point and free:
            ev = np.linalg.eigvalsh(_np_mass_matrix(self, topo))
            if ev[0] <= 1e-12 * max(ev[-1], 1e-300):  # singular particle mass matrix: solve the full KKT system
                topo = dataclasses.replace(topo, saddle_point=True)
        prims = np.zeros((len(self.body_names), 4, 3))
        for b, loc in enumerate(self.local_primaries):
            prims[b, :len(loc)] = loc
            prims[b, len(loc):] = loc[-1]
        f = lambda v: jnp.asarray(np.asarray(v, dtype=float))  # noqa: E731
        return Mechanism(
            body_mass=f([float(i.mass) for i in self.inertia]).reshape(-1),
            body_com=f([np.asarray(i.com) for i in self.inertia]).reshape(-1, 3),
            body_inertia=f([np.asarray(i.inertia) for i in self.inertia]).reshape(-1, 3, 3),
            body_primaries=f(prims), point_local=f(self.point_local).reshape(-1, 3),
            ground_xyz=f([self.pos[i] for i in ground]).reshape(-1, 3),
            dot_kappa=f([r[5] for r in self.dot]).reshape(-1),
            spring_stiffness=f([s[2] for s in springs]).reshape(-1), spring_damping=f([s[3] for s in springs]).reshape(-1),
            spring_free_length=f([s[4] for s in springs]).reshape(-1),
            tyre_stiffness=f([t[3] for t in tyres]).reshape(-1), tyre_damping=f([t[4] for t in tyres]).reshape(-1),
            tyre_radius=f([t[5] for t in tyres]).reshape(-1), tyre_ground=f([t[6] for t in tyres]).reshape(-1),
            gravity=f(mb.gravity), rotational_stiffness=f([r[2] for r in rot]).reshape(-1),
            rotational_damping=f([r[3] for r in rot]).reshape(-1),
            rotational_free_angle=f([r[4] for r in rot]).reshape(-1), applied=tuple(applied), topo=topo,
            drive_offset=f([r[4] for r in self.drv]).reshape(-1), drive_fns=tuple(r[6] for r in self.drv),
            tyre_roads=tuple(t[8] for t in tyres) if topo.tyre_road_args else (),
            spring_force_curve=tuple(f(np.zeros(0) if s[5] is None else s[5][1]) for s in springs)
            if any(s[5] is not None for s in springs) else (),
            spring_damping_curve=tuple(f(np.zeros(0) if s[6] is None else s[6][1]) for s in springs)
            if any(s[6] is not None for s in springs) else (),
            bushing_stiffness=f([e[5] for e in bush]).reshape(-1, 6), bushing_damping=f([e[6] for e in bush]).reshape(-1, 6),
            bushing_local=f([e[2] for e in bush]).reshape(-1, 2, 3), bushing_axes=f([e[3] for e in bush]).reshape(-1, 3, 3),
            bushing_rest=f([e[4] for e in bush]).reshape(-1, 3, 3),
            torsion_stiffness=f([e[4] for e in tors]).reshape(-1), torsion_damping=f([e[5] for e in tors]).reshape(-1),
            torsion_free_angle=f([e[6] for e in tors]).reshape(-1), torsion_axis=f([e[2] for e in tors]).reshape(-1, 3),
            torsion_rest=f([e[3] for e in tors]).reshape(-1, 3, 3),
            bump_stiffness=f([e[3] for e in bumps]).reshape(-1), bump_damping=f([e[4] for e in bumps]).reshape(-1),
            bump_clearance=f([e[2] for e in bumps]).reshape(-1), bump_length=f([e[5] for e in bumps]).reshape(-1))

    def _element_body(self, label: str, body, *, rotation: bool) -> int:
        """A force element's body index (``None``: the ground, -1); with ``rotation`` it must carry one."""
        if body is None:
            return -1
        if body not in self.body_names:
            raise ModelError(f"{label}: unknown body '{body}'")
        b = self.body_names.index(body)
        if rotation and len(self.body_particles[b]) == 2:
            raise ModelError(f"{label}: body '{body}' is a rod, whose turn about its own line is no motion: it "
                             "carries no rotation (give it 3 or 4 primaries)")
        return b

    def _pose(self, b: int):
        return (np.eye(3), np.zeros(3)) if b < 0 else self.body_pose[b]

    def elements(self):
        """Bushings, torsion springs and bump stops, resolved: body indices, body-frame data, built lengths."""
        bush, tors, bumps = [], [], []
        for name, a, b, frame, at, axes, k, c, rotating in self.mb._bushings:
            label = f"bushing '{name}'"
            ia, ib = (self._element_body(label, x, rotation=rotating) for x in (a, b))
            i_f = self._element_body(label, frame, rotation=True)
            (ra, oa), (rb, ob), (rf, _) = self._pose(ia), self._pose(ib), self._pose(i_f)
            local = np.stack([ra.T @ (at - oa), rb.T @ (at - ob)])
            bush.append((name, (ia, ib, i_f), local, rf.T @ axes, ra.T @ rb, k, c, bool(rotating)))
        for name, a, b, axis, k, c, th0 in self.mb._torsions:
            label = f"torsion spring '{name}'"
            ia, ib = (self._element_body(label, x, rotation=True) for x in (a, b))
            (ra, _), (rb, _) = self._pose(ia), self._pose(ib)
            tors.append((name, (ia, ib), ra.T @ axis, ra.T @ rb, k, c, th0))
        for name, a, b, clearance, k, c, rebound in self.mb._bumps:
            label = f"bump stop '{name}'"
            ia, ib = self.pidx(a, label), self.pidx(b, label)
            length = float(np.linalg.norm(self.point_world[ia] - self.point_world[ib]))
            if length <= 1e-12 * max(1.0, float(np.linalg.norm(self.point_world[ia]))):
                raise ModelError(f"{label}: its points '{a}' and '{b}' coincide at assembly: its line is undefined")
            if rebound is False and clearance >= length:
                raise ModelError(f"{label}: its clearance {clearance!r} m is not shorter than the points' distance "
                                 f"{length:.6g} m: it could never engage")
            bumps.append((name, (ia, ib), clearance, k, c, length, rebound))
        return bush, tors, bumps


def _np_point_weights(bd: _Build, topo: Topology) -> np.ndarray:
    """``W (K, F)``: the weight of every free particle in every point at assembly (NumPy twin of
    :func:`~.constraints.point_weights` composed with :func:`~.constraints.point_free_weights`)."""
    col = topo.free_column()
    w = np.zeros((len(topo.point_names), len(topo.free)))
    for k, b in enumerate(topo.point_body):
        if b < 0:
            if col[k] >= 0:
                w[k, col[k]] = 1.0
            continue
        prim = bd.local_primaries[b]
        n = len(prim)
        a = np.vstack([prim.T, np.ones((1, n))])
        coef = np.linalg.lstsq(a, np.append(bd.point_local[k], 1.0), rcond=None)[0]
        for i, c in zip(topo.body_particles[b], coef):
            if col[i] >= 0:
                w[k, col[i]] += c
    return w


def _np_rows(topo: Topology, kappa: np.ndarray, pts: np.ndarray, wk: np.ndarray, offset=None):
    """Residuals and Jacobian ``(C, 3F)`` of all rows at point positions ``pts`` (NumPy); driving rows as built
    (``f = 0``, targets ``offset``)."""
    d, lin = topo.dot, topo.linear
    res, jac = [], []
    if len(d):
        a, b, c, e = (np.asarray(v, dtype=int) for v in (d.a, d.b, d.c, d.d))
        s = np.asarray(d.scale)
        v, u = pts[a] - pts[b], pts[c] - pts[e]
        if d.turned is not None:  # v . Rz u; d/du is Rz^T v
            t = np.asarray(d.turned, dtype=bool)[:, None]
            u = np.where(t, np.stack([-u[:, 1], u[:, 0], 0 * u[:, 0]], axis=1), u)
            v_c = np.where(t, np.stack([v[:, 1], -v[:, 0], 0 * v[:, 0]], axis=1), v)
        else:
            v_c = v
        res.append(s * np.sum(v * u, axis=1) - kappa)
        blocks = np.stack([s[:, None] * u, -s[:, None] * u, s[:, None] * v_c, -s[:, None] * v_c], axis=1)
        jac.append(np.einsum("rsk,rsf->rfk", blocks, wk[d.slots]))
    if len(lin):
        axis = np.asarray(lin.axis, dtype=float)
        a, b = np.asarray(lin.a, dtype=int), np.asarray(lin.b, dtype=int)
        res.append(np.sum(axis * (pts[a] - pts[b]), axis=1))
        blocks = np.stack([axis, -axis], axis=1)
        jac.append(np.einsum("rsk,rsf->rfk", blocks, wk[lin.slots]))
    dr = topo.drive
    if len(dr):
        a, b = np.asarray(dr.a, dtype=int), np.asarray(dr.b, dtype=int)
        n0 = np.asarray(dr.axis, dtype=float)
        pb = np.where((b < 0)[:, None], 0.0, pts[np.where(b < 0, 0, b)])
        wb = np.where((b < 0)[:, None], 0.0, wk[np.where(b < 0, 0, b)])
        res.append(np.sum(n0 * (pts[a] - pb), axis=1) - np.asarray(offset, dtype=float))
        jac.append((wk[a] - wb)[:, :, None] * n0[:, None, :])
    n = 3 * len(topo.free)
    if not res:
        return np.zeros(0), np.zeros((0, n))
    j = np.concatenate(jac, axis=0)
    return np.concatenate(res), j.reshape(j.shape[0], n)


def _np_mass_matrix(bd: _Build, topo: Topology) -> np.ndarray:
    """Scalar mass matrix of the free particles at assembly, ``sum_b B_b^T diag(m_b) B_b`` (NumPy)."""
    from ..particles import PAIRS

    col = topo.free_column()
    m = np.zeros((len(topo.free), len(topo.free)))
    for b, ids in enumerate(topo.body_particles):
        k = len(ids)
        pairs = PAIRS[{2: "rod", 3: "planar", 4: "spatial"}[k]]
        inc = np.zeros((k + len(pairs), k))
        inc[:k] = np.eye(k)
        for r, (i, j) in enumerate(pairs):
            inc[k + r, [i, j]] = 0.5
        block = inc.T @ (bd.particle_masses[b][:, None] * inc)
        for s, i in enumerate(ids):
            for t, j in enumerate(ids):
                if col[i] >= 0 and col[j] >= 0:
                    m[col[i], col[j]] += block[s, t]
    return m


def _check(bd: _Build, mech: Mechanism, q0: np.ndarray, dof: Optional[int], multipliers: str = "auto") -> bool:
    """Assembly, spring lengths, rank, degrees of freedom, positive kinetic energy on every admissible motion.
    Returns whether the multipliers are solved by least squares; leaves the rank in ``bd.constraint_rank``."""
    topo = mech.topo
    pts = np.asarray(bd.point_world)
    size = max(float(np.ptp(pts, axis=0).max()) if len(pts) else 0.0, 1e-12)
    wk = _np_point_weights(bd, topo)
    res, j = _np_rows(topo, np.asarray(mech.dot_kappa), pts, wk, np.asarray(mech.drive_offset))
    bd.jacobian0 = j
    labels = topo.row_labels()
    bad = [(labels[i], float(res[i])) for i in np.flatnonzero(np.abs(res) > ASSEMBLY_RTOL * size * max(size, 1.0))]
    if bad:
        raise ModelError("initial positions violate constraints: " +
                         ", ".join(f"{lab} (residual {v:.3g})" for lab, v in bad[:6]) +
                         "; for approximate data build with assemble=True (closes joints and loops, keeps bodies)")
    for name, (a, b) in zip(topo.spring_names, topo.spring_points):
        if np.linalg.norm(pts[a] - pts[b]) <= ASSEMBLY_RTOL * size:
            raise ModelError(f"spring '{name}': its end points coincide (zero length): its direction is undefined")
    n = j.shape[1]
    rank = 0
    redundant: tuple[str, ...] = ()
    if j.shape[0]:
        sv = np.linalg.svd(j, compute_uv=False)
        rank = int(np.sum(sv > RANK_RTOL * sv[0]))
        if rank < j.shape[0]:
            redundant = _redundant_rows(j, labels)
            drivers = [r for r in redundant if r in topo.drive.labels]
            if drivers:
                raise ModelError(f"{drivers[0]} is inconsistent with the other constraints: it prescribes a motion "
                                 "that the joints (or another driver) already fix, so the two may contradict each "
                                 "other; drive a coordinate that is free")
            if multipliers == "exact":
                raise ModelError(f"over-constrained: {j.shape[0] - rank} redundant constraint(s) among "
                                 f"{j.shape[0]}; first redundant: {redundant[0]} (build with "
                                 "multipliers='least_squares' to keep them)")
    lsq = multipliers == "least_squares" or (multipliers == "auto" and bool(redundant))
    bd.constraint_rank = ConstraintRank(rows=int(j.shape[0]), rank=rank, redundant=redundant, dof=n - rank,
                                        multipliers="least_squares" if lsq else "exact")
    if redundant and multipliers == "auto":
        warnings.warn(f"{len(redundant)} redundant constraint row(s) among {j.shape[0]} (rank {rank}): "
                      f"{', '.join(redundant[:6])}{' ...' if len(redundant) > 6 else ''}; the motion is unique and "
                      "solved with least-squares multipliers. Pass multipliers='least_squares' to "
                      "accept this silently or 'exact' to refuse it", RedundantConstraintsWarning, stacklevel=4)
    if dof is not None and n - rank != dof:
        what = "under" if n - rank > dof else "over"
        raise ModelError(f"{what}-constrained: the mechanism has {n - rank} degrees of freedom, expected {dof}")
    # Kinetic energy positive on every admissible motion (else the acceleration solve is singular).
    if n - rank:
        _, _, vt = np.linalg.svd(j if j.shape[0] else np.zeros((1, n)))
        z = vt[rank:].T
        m3 = np.kron(_np_mass_matrix(bd, topo), np.eye(3))
        m_red = z.T @ m3 @ z
        ev = np.linalg.eigvalsh(0.5 * (m_red + m_red.T))
        if ev[0] <= 1e-12 * max(ev[-1], 1e-300):
            raise ModelError("a free motion of the mechanism carries no mass (kinetic energy matrix on the "
                             f"admissible motions is singular, eigenvalues {ev[:3].tolist()}): add mass or "
                             "constraints")
    return lsq


def _redundant_rows(j: np.ndarray, labels: list[str]) -> tuple[str, ...]:
    """Labels of the rows that depend on the rows before them (one Gram-Schmidt pass, reorthogonalised)."""
    kept = np.zeros((0, j.shape[1]))
    scale = np.max(np.linalg.norm(j, axis=1))
    out = []
    for i in range(j.shape[0]):
        r = j[i] - (kept.T @ (kept @ j[i]) if len(kept) else 0.0)
        r = r - (kept.T @ (kept @ r) if len(kept) else 0.0)
        nr = np.linalg.norm(r)
        if nr <= RANK_RTOL * scale:
            out.append(labels[i])
            continue
        kept = np.vstack([kept, r / nr])
    return tuple(out) if out else ("?",)


def _road_arity(name: str, road: Callable) -> int:
    """How many arguments a tyre's road function takes, ``ground(t)`` (1) or ``ground(t, p)`` (2) (its required
    positional parameters), checked by one call at ``t = 0`` (``p`` at the origin): it must return one finite
    number."""
    try:
        sig = inspect.signature(road)
    except (TypeError, ValueError):
        sig = None
    kinds = (inspect.Parameter.POSITIONAL_ONLY, inspect.Parameter.POSITIONAL_OR_KEYWORD)
    n = None if sig is None else sum(p.kind in kinds and p.default is p.empty for p in sig.parameters.values())
    if n not in (1, 2):
        raise ModelError(f"tyre '{name}': the road function must take (t) or (t, p), got "
                         f"{'an unreadable signature' if sig is None else f'signature {sig}'}")
    try:
        v = np.asarray(road(*(jnp.asarray(0.0), jnp.zeros(3))[:n]), dtype=float)
    except Exception as e:  # noqa: BLE001 — report any failure of the user's function with the tyre's name
        raise ModelError(f"tyre '{name}': ground{('(t)', '(t, p)')[n - 1]} failed at t = 0: "
                         f"{type(e).__name__}: {e}") from None
    if v.shape != () or not np.isfinite(v):
        raise ModelError(f"tyre '{name}': the road function must return one finite number (the ground's height), "
                         f"got {v.tolist()!r} at t = 0")
    return n
