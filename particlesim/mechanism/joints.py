"""The explicit joints and drivers a :class:`~.builder.MechanismBuilder` records, one final class per kind.

Joints made of shared particles (spherical, revolute, a fixed point or axis) need no record: the bodies list the
same particles. Everything else is one of these classes, each turning itself into typed rows at build time in two
steps, called by the build's stages (:mod:`._build`):

* ``plan(bd)``: the joint's geometry at assembly, before points exist (the host body of a line and the unit
  directions normal to it, fixed in the host; a ground-side direction becomes a hidden ground particle, so it must
  be known before particles are numbered);
* ``rows(bd, plan)``: its constraint rows, appended to the build's :class:`~.model.DotRows` list ``bd.dot``
  (``s (p_a - p_b).(p_c - p_d) - kappa``) or :class:`~.model.LinearRows` list ``bd.lin`` (``e . (p_a - p_b)``).

Drivers (:class:`DriveAngle`, :class:`DrivePosition`) have one step, ``rows(bd, size)``, appending to ``bd.drv``.
Names of particles or points are checked where they are first needed; every error names the joint or driver.
"""

from __future__ import annotations

import abc
import dataclasses
from typing import Callable, NamedTuple, Optional

import numpy as np

from ..errors import ModelError

__all__ = ["Joint", "Link", "CutJoint", "OnLine", "Prismatic", "PlanarPrismatic", "Cylindrical", "Universal", "Fixed",
           "DriveAngle", "DrivePosition", "AXES", "unit"]

AXES = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
_Z = (0.0, 0.0, 1.0)


def unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def _off_axis(u: np.ndarray, p: np.ndarray) -> np.ndarray:
    """The part of ``p`` normal to ``u``."""
    return p - (p @ u) / (u @ u) * u


class LinePlan(NamedTuple):
    """Assembly geometry of a line-like joint: host body (``-1`` the ground, ``None``: no line), the line's origin,
    its unit normal directions fixed in the host, the scale ``ell`` of its rows and the hidden ground particles that
    carry ground-side directions."""

    host: Optional[int] = None
    origin: Optional[np.ndarray] = None
    dirs: tuple = ()
    ell: Optional[float] = None
    ground_names: tuple = ()


class Joint(abc.ABC):
    """An explicit joint: a name (``label``) and the particles/points it joins (``names``)."""

    label: str

    @property
    @abc.abstractmethod
    def names(self) -> tuple: ...

    @abc.abstractmethod
    def plan(self, bd): ...

    @abc.abstractmethod
    def rows(self, bd, plan) -> None: ...


def _checked(joint: Joint, bd) -> list[np.ndarray]:
    """Assembly positions of the joint's particles/points (refusing unknown names, naming the joint)."""
    return [bd.where(n, joint.label)[0] for n in joint.names]


def _line_plan(joint: Joint, bd, host: int, origin: np.ndarray, dirs: tuple, ell: float, turned: bool) -> LinePlan:
    """Finish a line's plan: in a planar mechanism keep only the in-plane normal (or none when the rows are turned:
    the normal is then a quarter turn of the direction); ground-side directions become hidden ground particles."""
    if bd.mb.planar:
        dirs = () if turned else dirs[:1]
    hidden = []
    if host == -1:
        for j, d in enumerate(dirs):
            hidden.append(bd.hidden_ground(f"{joint.label} / direction {j + 1}", origin + ell * d))
    return LinePlan(host, origin, tuple(dirs), ell, tuple(hidden))


def _direction_points(joint: Joint, bd, plan: LinePlan) -> list[int]:
    """Point indices of the plan's directions (``origin + ell * n``, fixed in the host)."""
    if plan.host == -1:
        return [bd.point_index[nm] for nm in plan.ground_names]
    return [bd.add_point(f"{joint.label} / direction {j + 1}", plan.host, plan.origin + plan.ell * d)
            for j, d in enumerate(plan.dirs)]


def _indices(joint: Joint, bd) -> tuple[int, ...]:
    return tuple(bd.pidx(n, joint.label) for n in joint.names)


class _PointPair(Joint):
    """A joint between two particles or points ``a`` and ``b`` (abstract: its rows are the final class's)."""

    a: str
    b: str

    @property
    def names(self) -> tuple:
        return (self.a, self.b)

    def plan(self, bd) -> LinePlan:
        _checked(self, bd)
        return LinePlan()


@dataclasses.dataclass(frozen=True)
class Link(_PointPair):
    """A massless rigid link: ``|p_a - p_b|`` constant (the assembly distance unless ``length`` is given)."""

    a: str
    b: str
    label: str
    length: Optional[float] = None

    def rows(self, bd, plan) -> None:
        ka, kb = _indices(self, bd)
        d = np.linalg.norm(bd.point_world[ka] - bd.point_world[kb]) if self.length is None else float(self.length)
        bd.dot.append((ka, kb, ka, kb, 0.5, 0.5 * d**2, self.label))


@dataclasses.dataclass(frozen=True)
class CutJoint(_PointPair):
    """A cut joint closing a loop: ``p_a = p_b`` (three linear rows; two in a plane)."""

    a: str
    b: str
    label: str

    def rows(self, bd, plan) -> None:
        ka, kb = _indices(self, bd)
        for axis, c in list(zip(AXES, "xyz"))[:2 if bd.mb.planar else 3]:
            bd.lin.append((ka, kb, axis, f"{self.label} ({c})"))


@dataclasses.dataclass(frozen=True)
class Universal(Joint):
    """A universal joint: the cross's arms ``arm_a`` (body A) and ``arm_b`` (body B) from the shared ``center`` stay
    perpendicular (one row)."""

    center: str
    arm_a: str
    arm_b: str
    label: str

    @property
    def names(self) -> tuple:
        return (self.center, self.arm_a, self.arm_b)

    def plan(self, bd) -> LinePlan:
        _checked(self, bd)
        return LinePlan()

    def rows(self, bd, plan) -> None:
        kc, ka, kb = _indices(self, bd)
        ha, hb = bd.host((self.center, self.arm_a), self.label), bd.host((self.center, self.arm_b), self.label)
        if ha == hb:
            raise ModelError(f"{self.label}: both arms '{self.arm_a}' and '{self.arm_b}' belong to one body (or the "
                             f"ground) with the centre '{self.center}': a universal joint joins two bodies that share "
                             "the centre")
        arm_a, arm_b = bd.point_world[ka] - bd.point_world[kc], bd.point_world[kb] - bd.point_world[kc]
        la, lb = float(np.linalg.norm(arm_a)), float(np.linalg.norm(arm_b))
        if la == 0 or lb == 0:
            raise ModelError(f"{self.label}: an arm has zero length (arm point at the centre)")
        if abs(arm_a @ arm_b) > 1e-9 * la * lb:
            raise ModelError(f"{self.label}: the arms are not perpendicular at assembly (cos = "
                             f"{arm_a @ arm_b / (la * lb):.3g})")
        bd.dot.append((ka, kc, kb, kc, 1.0 / (la * lb), 0.0, f"{self.label} (cross)"))


@dataclasses.dataclass(frozen=True)
class OnLine(Joint):
    """``particle`` kept on the line through ``origin`` along ``d0 -> d1`` (points of one body or the ground;
    ``ref`` off the line fixes its normals in space, not needed in a plane)."""

    particle: str
    origin: str
    d0: str
    d1: str
    ref: Optional[str]
    label: str

    @property
    def names(self) -> tuple:
        return (self.particle, self.origin, self.d0, self.d1) + (() if self.ref is None else (self.ref,))

    def plan(self, bd) -> LinePlan:
        world = _checked(self, bd)
        o, d0, d1 = world[1:4]
        u = d1 - d0
        ell = float(np.linalg.norm(u))
        if ell == 0:
            raise ModelError(f"{self.label}: the line's direction points '{self.d0}' and '{self.d1}' coincide (a slot "
                             "of zero length has no direction)")
        if bd.mb.planar:
            n1 = unit(np.cross(_Z, u))
        else:
            w = _off_axis(u, world[4] - d0)
            if np.linalg.norm(w) <= 1e-9 * ell:
                raise ModelError(f"{self.label}: reference point '{self.ref}' lies on the line")
            n1 = unit(w)
        host = bd.host(self.names[1:], self.label)
        return _line_plan(self, bd, host, o, (n1, np.cross(u / ell, n1)), ell, turned=True)

    def rows(self, bd, plan: LinePlan) -> None:
        ks = _indices(self, bd)
        if bd.mb.planar:  # (p - o) . Rz (d1 - d0) / ell: a turned row
            bd.dot.append((ks[0], ks[1], ks[3], ks[2], 1.0 / plan.ell, 0.0, f"{self.label} (n1)", True))
            return
        n = _direction_points(self, bd, plan)
        for j, c in enumerate(("n1", "n2")):
            bd.dot.append((n[j], ks[1], ks[0], ks[1], 1.0 / plan.ell, 0.0, f"{self.label} ({c})"))


@dataclasses.dataclass(frozen=True)
class Cylindrical(Joint):
    """Body B's axis points ``b0, b1`` kept on body A's axis ``a0 -> a1`` (``a2`` off it): B slides along and turns
    about A's axis (four rows; spatial mechanisms only)."""

    a0: str
    a1: str
    a2: str
    b0: str
    b1: str
    label: str

    @property
    def names(self) -> tuple:
        return (self.a0, self.a1, self.a2, self.b0, self.b1)

    def plan(self, bd) -> LinePlan:
        a0, a1, a2, b0, b1 = _checked(self, bd)
        u = a1 - a0
        ell = float(np.linalg.norm(u))
        w = _off_axis(u, a2 - a0) if ell > 0 else u
        if ell == 0 or np.linalg.norm(w) <= 1e-9 * ell:
            raise ModelError(f"{self.label}: point '{self.a2}' lies on the axis '{self.a0}'-'{self.a1}'")
        if np.linalg.norm(b1 - b0) <= 1e-9 * ell:
            raise ModelError(f"{self.label}: the slider's axis points '{self.b0}' and '{self.b1}' coincide")
        n1 = unit(w)
        host = bd.host(self.names[:3], self.label)
        return _line_plan(self, bd, host, a0, (n1, np.cross(u / ell, n1)), ell, turned=False)

    def rows(self, bd, plan: LinePlan) -> None:
        ks = _indices(self, bd)
        n = _direction_points(self, bd, plan)
        for p, tag in ((ks[3], "axis 1"), (ks[4], "axis 2")):
            for j, c in enumerate("ab"):
                bd.dot.append((n[j], ks[0], p, ks[0], 1.0 / plan.ell, 0.0, f"{self.label} ({tag}{c})"))


@dataclasses.dataclass(frozen=True)
class Prismatic(Joint):
    """Body B (``b0, b1`` on the axis, ``b2`` off it) slides along body A's axis ``a0 -> a1`` (``a2`` off it)
    without turning."""

    a0: str
    a1: str
    a2: str
    b0: str
    b1: str
    b2: str
    label: str

    @property
    def names(self) -> tuple:
        return (self.a0, self.a1, self.a2, self.b0, self.b1, self.b2)

    def plan(self, bd) -> LinePlan:
        a0, a1, a2, b0, _, b2 = _checked(self, bd)
        u = a1 - a0
        ell = float(np.linalg.norm(u))
        w = _off_axis(u, a2 - a0) if ell > 0 else u
        if ell == 0 or np.linalg.norm(w) <= 1e-9 * ell:
            raise ModelError(f"{self.label}: point '{self.a2}' lies on the axis '{self.a0}'-'{self.a1}'")
        u = u / ell
        n1 = unit(w)
        wb = (b2 - b0) - ((b2 - b0) @ u) * u
        if np.linalg.norm(wb) <= 1e-9 * ell:
            raise ModelError(f"{self.label}: point '{self.b2}' lies on the axis through '{self.b0}'")
        # The rotation lock uses the direction normal to both the axis and b2's offset from it, so its gradient
        # never vanishes (in a planar model too, where b2 lies in the plane of the axis and n1).
        host = bd.host(self.names[:3], self.label)
        return _line_plan(self, bd, host, a0, (n1, np.cross(u, n1), unit(np.cross(u, wb))), ell, turned=False)

    def rows(self, bd, plan: LinePlan) -> None:
        ks = _indices(self, bd)
        n = _direction_points(self, bd, plan)
        planar = bd.mb.planar  # the out-of-plane rows are left out: the particles are held in the plane
        a0, b0 = ks[0], ks[3]
        for p, tag in ((b0, "axis 1"), (ks[4], "axis 2")):
            for j, c in enumerate("ab"[:1 if planar else 2]):
                bd.dot.append((n[j], a0, p, a0, 1.0 / plan.ell, 0.0, f"{self.label} ({tag}{c})"))
        if not planar:
            bd.dot.append((n[2], a0, ks[5], b0, 1.0 / plan.ell, 0.0, f"{self.label} (rotation)"))


@dataclasses.dataclass(frozen=True)
class PlanarPrismatic(Joint):
    """A planar prismatic joint: body B's axis points ``b0, b1`` kept on body A's axis ``a0 -> a1`` (two turned
    rows ``(p - a0) . Rz (a1 - a0) / ell``; B cannot turn with both points on the line)."""

    a0: str
    a1: str
    b0: str
    b1: str
    label: str

    @property
    def names(self) -> tuple:
        return (self.a0, self.a1, self.b0, self.b1)

    def plan(self, bd) -> LinePlan:
        a0, a1, b0, b1 = _checked(self, bd)
        u = a1 - a0
        ell = float(np.linalg.norm(u))
        if ell == 0:
            raise ModelError(f"{self.label}: the guide's axis points '{self.a0}' and '{self.a1}' coincide")
        if np.linalg.norm(b1 - b0) <= 1e-9 * ell:
            raise ModelError(f"{self.label}: the slider's axis points '{self.b0}' and '{self.b1}' coincide")
        host = bd.host(self.names[:2], self.label)
        return _line_plan(self, bd, host, a0, (unit(np.cross(_Z, u)),), ell, turned=True)

    def rows(self, bd, plan: LinePlan) -> None:
        ka0, ka1, kb0, kb1 = _indices(self, bd)
        for p, tag in ((kb0, "axis 1"), (kb1, "axis 2")):
            bd.dot.append((p, ka0, ka1, ka0, 1.0 / plan.ell, 0.0, f"{self.label} ({tag})", True))


class FixedPlan(NamedTuple):
    """Bodies (``-1`` the ground), meeting point, the bodies' directions and the chosen direction pairs, and the
    hidden ground particles of a ground side."""

    bodies: tuple
    at: np.ndarray
    dirs_a: list
    dirs_b: list
    chosen: list
    hidden: list


@dataclasses.dataclass(frozen=True, eq=False)
class Fixed(Joint):
    """``body_b`` welded to ``body_a`` (``None``: the ground) at ``at`` (default: ``body_b``'s first primary)."""

    body_a: Optional[str]
    body_b: str
    at: Optional[np.ndarray]
    label: str

    @property
    def names(self) -> tuple:
        return (self.body_a, self.body_b)

    def plan(self, bd) -> FixedPlan:
        """The meeting point (coincident points of both bodies) and a set of independent direction pairs
        ``a_i . b_j = const`` chosen at assembly by their sensitivity to a relative rotation (``b_j x a_i``),
        largest first."""
        names = {n: i for i, n in enumerate(bd.body_names)}
        ids = []
        for n in (self.body_a, self.body_b):
            if n is None:
                ids.append(-1)
            elif n not in names:
                raise ModelError(f"{self.label}: unknown body '{n}'")
            else:
                ids.append(names[n])
        ba, bb = ids
        at = self.at if self.at is not None else bd.pos[bd.body_particles[bb][0]]
        da, db = bd.directions(ba), bd.directions(bb)
        rods = sum(1 for b in ids if b >= 0 and len(bd.body_particles[b]) == 2)
        need = 1 if bd.mb.planar else 3 - rods
        cand = sorted(((np.cross(db[j], da[i]), i, j) for i in range(len(da)) for j in range(len(db))),
                      key=lambda c: -np.linalg.norm(c[0]))
        chosen, basis = [], []
        for g, i, j in cand:
            g = g[2:] if bd.mb.planar else g
            r = g - sum((g @ q) * q for q in basis) if basis else g
            if np.linalg.norm(r) > 1e-6 and len(chosen) < need:
                basis.append(r / np.linalg.norm(r))
                chosen.append((i, j))
        if len(chosen) < need:
            raise ModelError(f"{self.label}: the directions of the two bodies cannot lock their relative rotation (e.g. "
                             "two collinear rods); merge them into one body instead")
        hidden = []
        if ba < 0:  # the ground's side: hidden ground particles at the meeting point and along its directions
            used = sorted({i for i, _ in chosen})
            hidden.append(bd.hidden_ground(f"{self.label} / at", at))
            hidden += [bd.hidden_ground(f"{self.label} / direction {i + 1}", at + da[i]) for i in used]
        return FixedPlan((ba, bb), at, da, db, chosen, hidden)

    def rows(self, bd, plan: FixedPlan) -> None:
        (ba, bb), at, da, db, chosen, hidden = plan
        side = {}
        for tag, b, dirs in (("a", ba, da), ("b", bb, db)):
            if b < 0:
                pa = bd.point_index[hidden[0]]
                side[tag] = (pa, {int(nm.rsplit(" ", 1)[1]) - 1: bd.point_index[nm] for nm in hidden[1:]})
                continue
            p = bd.add_point(f"{self.label} / at ({tag})", b, at)
            used = sorted({(i if tag == "a" else j) for i, j in chosen})
            side[tag] = (p, {k: bd.add_point(f"{self.label} / direction {k + 1} ({tag})", b, at + dirs[k])
                             for k in used})
        (pa, dira), (pb, dirb) = side["a"], side["b"]
        for axis, c in list(zip(AXES, "xyz"))[:2 if bd.mb.planar else 3]:
            bd.lin.append((pa, pb, axis, f"{self.label} ({c})"))
        for i, j in chosen:
            bd.dot.append((dira[i], pa, dirb[j], pb, 1.0, float(da[i] @ db[j]),
                           f"{self.label} (rotation {i + 1}{j + 1})"))


@dataclasses.dataclass(frozen=True, eq=False)
class DriveAngle:
    """``body`` turned by ``fn(t)`` about the unit world direction ``axis`` from its pose as built: one row
    ``n(t) . (p_j - p_i)`` on the body's particle pair most normal to the axis, scaled so that its multiplier is the
    driving torque."""

    name: str
    body: str
    fn: Callable
    axis: np.ndarray

    def rows(self, bd, size: float) -> None:
        label = f"driver '{self.name}'"
        if self.body not in bd.body_names:
            raise ModelError(f"{label}: unknown body '{self.body}'")
        ids = bd.body_particles[bd.body_names.index(self.body)]
        best = None
        for s_ in range(len(ids)):
            for t_ in range(s_ + 1, len(ids)):
                u = bd.pos[ids[t_]] - bd.pos[ids[s_]]
                perp = u - (u @ self.axis) * self.axis
                if best is None or np.linalg.norm(perp) > best[0]:
                    best = (float(np.linalg.norm(perp)), ids[s_], ids[t_], u)
        if best[0] <= 1e-9 * size:
            raise ModelError(f"{label}: the particles of body '{self.body}' lie on a line along the drive axis "
                             f"{self.axis.tolist()}; a rotation about it does not move them")
        ell, i, j, u = best
        n0 = np.cross(self.axis, u) / ell**2
        bd.drv.append((bd.point_index[bd.names[j]], bd.point_index[bd.names[i]], tuple(n0), tuple(self.axis), 0.0,
                       label, self.fn))


@dataclasses.dataclass(frozen=True, eq=False)
class DrivePosition:
    """``point`` moved ``fn(t)`` along the unit world direction ``axis`` from its assembly position, measured from
    the world origin or from ``relative_to``: one row ``axis . (p_a - p_b) - offset - f(t)``."""

    name: str
    point: str
    fn: Callable
    axis: np.ndarray
    relative_to: Optional[str] = None

    def rows(self, bd, size: float) -> None:
        label = f"driver '{self.name}'"
        a = bd.pidx(self.point, label)
        b = -1 if self.relative_to is None else bd.pidx(self.relative_to, label)
        pb = np.zeros(3) if b < 0 else bd.point_world[b]
        if b == a:
            raise ModelError(f"{label}: the point '{self.point}' is measured from itself")
        offset = float(self.axis @ (bd.point_world[a] - pb))
        bd.drv.append((a, b, tuple(self.axis), (0.0, 0.0, 0.0), offset, label, self.fn))
