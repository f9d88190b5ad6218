"""Building a mechanism by name: particles, bodies, joints, cut joints and force elements, checked on build.

Joints come from shared particles: two bodies listing the same particle are joined by a spherical joint there;
two shared particles make a revolute joint about their line; a body listing ground particles turns about a fixed
point (one) or a fixed axis (two). Links, cut joints, points kept on a line and prismatic joints are explicit.
Positions are global at assembly; each body's inertia is given in its own frame, placed by ``pose``.

Example (a pendulum)::

    mb = MechanismBuilder(gravity=(0, 0, -9.81))
    mb.ground("O", (0, 0, 0))
    mb.particle("tip", (1, 0, 0))
    mb.body("rod", RigidInertia.slender_rod(1.0, (0, 0, 0), (1, 0, 0)), ["O", "tip"])
    mech, q0 = mb.build()

The build works in NumPy on the assembly configuration (its cost grows linearly with the mechanism, apart from
one rank check of the constraint Jacobian) and returns a :class:`~.model.Mechanism` whose rows are typed
(:class:`~.model.DotRows`, :class:`~.model.LinearRows`).
"""

from __future__ import annotations

from typing import Callable, Optional, Sequence

import jax.numpy as jnp
import numpy as np

from ..errors import ModelError
from ..inertia import RigidInertia
from ..particles import N_PRIMARY
from ._build import ASSEMBLY_RTOL, RANK_RTOL, ConstraintRank, RedundantConstraintsWarning, _Build, _road_arity
from .curves import check_curve
from .joints import (CutJoint, Cylindrical, DriveAngle, DrivePosition, Fixed, Link, OnLine, PlanarPrismatic, Prismatic,
                     Universal, unit)
from .model import AppliedForce, AppliedTorque, BodyLoad, Mechanism

__all__ = ["MechanismBuilder", "ConstraintRank", "RedundantConstraintsWarning", "ASSEMBLY_RTOL", "RANK_RTOL"]


class MechanismBuilder:
    """Collects a mechanism description; :meth:`build` checks it and returns ``(Mechanism, q0)``."""

    def __init__(self, gravity: Optional[Sequence[float]] = None, *, planar: bool = False):
        """``gravity`` (default 9.81 along -z; along -y when ``planar``). ``planar=True``: a planar mechanism in the
        x-y plane. Positions and gravity may then be given as ``(x, y)``; bodies are rods (2 primaries, e.g.
        :meth:`rod`) or planar sets (3 primaries, e.g. :meth:`planar_body` from mass, polar moment and centre of
        mass); every free particle is held in the plane (one row each), so out-of-plane freedoms do not exist and
        ``dof`` counts the freedoms in the plane; cut joints close loops with their two in-plane rows, prismatic
        joints are two rows (both axis points of the slider on the guide's line), a point kept on a line one row.
        Revolute joints are shared particles, as in 3-D. The state stays ``(3F,)`` with ``z = 0``."""
        self.planar = bool(planar)
        if gravity is None:
            gravity = (0.0, -9.81, 0.0) if self.planar else (0.0, 0.0, -9.81)
        self.gravity = self._vec(gravity, "gravity")
        self._particles: dict[str, tuple[np.ndarray, bool]] = {}
        self._bodies: list[tuple[str, RigidInertia, tuple[str, ...], tuple, str]] = []
        self._joints: list = []  # :mod:`.joints` records, in declaration order
        self._points: dict[str, tuple[Optional[str], np.ndarray]] = {}
        self._springs: list[tuple] = []
        self._tyres: list[tuple] = []
        self._rotational: list[tuple] = []
        self._applied: list[tuple] = []  # (AppliedForce | AppliedTorque | BodyLoad, name, target, fn)
        self._drives: list = []  # DriveAngle, DrivePosition
        self._bushings: list[tuple] = []
        self._torsions: list[tuple] = []
        self._bumps: list[tuple] = []

    def _vec(self, xyz, what: str) -> np.ndarray:
        """A 3-vector from 3 numbers (or 2 in a planar mechanism, z = 0); a planar one must have z = 0."""
        p = np.asarray(xyz, dtype=float)
        if self.planar and p.shape == (2,):
            p = np.append(p, 0.0)
        n = "2 (x, y) or 3" if self.planar else "3"
        if p.shape != (3,) or not np.all(np.isfinite(p)):
            raise ModelError(f"{what} must be {n} finite numbers, got {np.asarray(xyz).tolist()}")
        if self.planar and p[2] != 0.0:
            raise ModelError(f"{what} has z = {float(p[2])!r}, off the plane of a planar mechanism (z = 0)")
        return p

    # ---- particles ----
    def _add_particle(self, name: str, xyz, ground: bool) -> str:
        if name in self._particles or name in self._points:
            raise ModelError(f"particle '{name}' is defined twice")
        p = self._vec(xyz, f"particle '{name}': position")
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
        if self.planar and len(primaries) == 4:
            raise ModelError(f"body '{name}': a planar mechanism's bodies are rods (2 primaries) or planar sets (3), "
                             "got 4")
        self._bodies.append((name, inertia, tuple(primaries), pose, on_negative))
        return name

    def _position(self, n: str, what: str) -> np.ndarray:
        if n not in self._particles:
            raise ModelError(f"{what}: unknown particle '{n}' (declare it with particle(...) or ground(...) first)")
        return self._particles[n][0]

    def rod(self, name: str, a: str, b: str, mass: float, *, com=None, moment: Optional[float] = None,
            on_negative: str = "warn") -> str:
        """A slender rod body between the particles ``a`` and ``b`` (at their given positions): uniform by
        default, or with centre of mass ``com`` on the line and transverse ``moment`` about it
        (:meth:`~particlesim.inertia.RigidInertia.slender_rod`)."""
        p, q = self._position(a, f"rod '{name}'"), self._position(b, f"rod '{name}'")
        c = None if com is None else self._vec(com, f"rod '{name}': centre of mass")
        inertia = RigidInertia.slender_rod(mass, p, q, com=c, moment=moment, name=name)
        return self.body(name, inertia, [a, b], on_negative=on_negative)

    def planar_body(self, name: str, mass: float, moment: float, com, primaries: Sequence[str], *,
                    on_negative: str = "warn") -> str:
        """A body moving in the x-y plane from its mass, polar moment of inertia ``moment`` about its centre of mass
        and centre of mass ``com`` (global, at assembly); three primaries in the plane (Attia's planar set). The
        in-plane moments, which planar motion never uses, are taken as ``moment / 2`` each."""
        if len(primaries) != 3:
            raise ModelError(f"planar body '{name}': needs 3 primary particles, got {len(primaries)}")
        c = self._vec(com, f"planar body '{name}': centre of mass")
        if not np.isfinite(moment) or moment < 0:
            raise ModelError(f"planar body '{name}': polar moment must be finite and non-negative, got {moment!r}")
        inertia = RigidInertia(mass, c, np.diag([moment / 2, moment / 2, moment]), name=name)
        return self.body(name, inertia, primaries, on_negative=on_negative)

    def rotational_spring_damper(self, name: str, body_a: Optional[str], body_b: str, stiffness: float,
                                 damping: float, free_angle: float = 0.0) -> None:
        """A torsional spring-damper between two bodies of a planar mechanism (``body_a = None``: the ground): the
        torque on ``body_b`` is ``-(stiffness (theta - free_angle) + damping theta')`` about z, its opposite on
        ``body_a``, with ``theta`` the rotation of ``b`` relative to ``a`` since the assembly (counter-clockwise
        positive; valid for ``|theta - free_angle| < pi``). Stiffness in N m/rad, damping in N m s/rad."""
        if not self.planar:
            raise ModelError(f"rotational spring '{name}': available in planar mechanisms "
                             "(MechanismBuilder(planar=True))")
        for label, v in (("stiffness", stiffness), ("damping", damping), ("free angle", free_angle)):
            _number(f"rotational spring '{name}'", label, v, non_negative=label != "free angle")
        if name in (r[0] for r in self._rotational):
            raise ModelError(f"rotational spring '{name}' is defined twice")
        if body_a == body_b:
            raise ModelError(f"rotational spring '{name}': connects body '{body_b}' to itself")
        self._rotational.append((name, body_a, body_b, float(stiffness), float(damping), float(free_angle)))

    def link(self, a: str, b: str, *, name: Optional[str] = None, length: Optional[float] = None) -> None:
        """A massless rigid link (distance constraint) between particles or points ``a`` and ``b``; its length is
        the assembly distance unless given."""
        self._joints.append(Link(a, b, name or f"link {a}-{b}", length))

    def cut_joint(self, a: str, b: str, *, name: Optional[str] = None) -> None:
        """Close a loop: particles/points ``a`` and ``b`` (on different branches) coincide, ``r_a = r_b``."""
        self._joints.append(CutJoint(a, b, name or f"cut joint {a}={b}"))

    def on_line(self, particle: str, origin: str, direction: Sequence[str], ref: Optional[str] = None, *,
                name: Optional[str] = None) -> None:
        """Keep ``particle`` on the line through point ``origin`` along ``direction = (d0, d1)``; ``origin``,
        ``d0``, ``d1`` and ``ref`` (off the line) are points of one body (or the ground). With a shared particle
        at ``origin`` this makes a revolute joint whose second axis particle belongs to one body only; with a
        particle of another body it is a pin in a slot (revolute-translational joint). In a planar mechanism
        ``ref`` is not needed (the line's normal lies in the plane), so a rod can carry the slot."""
        if len(direction) != 2:
            raise ModelError(f"on_line {name or particle}: direction needs two points")
        if ref is None and not self.planar:
            raise ModelError(f"on_line {name or particle}: a spatial line needs a reference point off it (ref)")
        self._joints.append(OnLine(particle, origin, direction[0], direction[1], ref, name or f"{particle} on axis"))

    def prismatic(self, axis_a: Sequence[str], axis_b: Sequence[str], *, name: Optional[str] = None) -> None:
        """Prismatic joint: ``axis_a = (a0, a1, a2)`` are particles/points of body A (or ground) with a0, a1 on the
        axis and a2 off it; ``axis_b = (b0, b1, b2)`` likewise on body B. B slides along A's axis without turning.
        In a planar mechanism two points a side suffice, ``(a0, a1)`` and ``(b0, b1)``, all on the axis."""
        if self.planar and len(axis_a) == 2 and len(axis_b) == 2:
            self._joints.append(PlanarPrismatic(*axis_a, *axis_b, name or f"prismatic {axis_a[0]}-{axis_b[0]}"))
            return
        if len(axis_a) != 3 or len(axis_b) != 3:
            two = " (or two, on the axis, in a planar mechanism)" if self.planar else ""
            raise ModelError(f"prismatic joint {name}: needs three particles on each side{two}")
        self._joints.append(Prismatic(*axis_a, *axis_b, name or f"prismatic {axis_a[0]}-{axis_b[0]}"))

    def universal(self, center: str, arm_a: str, arm_b: str, *, name: Optional[str] = None) -> None:
        """Universal (Cardan) joint: ``center`` is a particle of both bodies (their spherical joint) and ``arm_a``,
        ``arm_b`` are particles or points of body A and body B marking the cross's two arms from the centre, which
        must be perpendicular at assembly; they stay perpendicular (one row), which leaves two relative rotations."""
        self._joints.append(Universal(center, arm_a, arm_b, name or f"universal {center}"))

    def cylindrical(self, axis_a: Sequence[str], axis_b: Sequence[str], *, name: Optional[str] = None) -> None:
        """Cylindrical joint: ``axis_a = (a0, a1, a2)`` particles/points of body A (or ground), a0 and a1 on the
        axis and a2 off it; ``axis_b = (b0, b1)`` of body B on the axis. B slides along and turns about A's axis
        (four rows: b0 and b1 kept on the line). Spatial mechanisms only (in a plane it would be a prismatic joint)."""
        if len(axis_a) != 3 or len(axis_b) != 2:
            raise ModelError(f"cylindrical joint {name}: needs three particles on the guide and two on the slider")
        if self.planar:
            raise ModelError(f"cylindrical joint {name}: not available in a planar mechanism (use prismatic)")
        self._joints.append(Cylindrical(*axis_a, *axis_b, name or f"cylindrical {axis_a[0]}-{axis_b[0]}"))

    def fixed(self, body_a: Optional[str], body_b: str, *, at=None, name: Optional[str] = None) -> None:
        """Fixed (welded) joint: ``body_b`` keeps its pose relative to ``body_a`` (``None``: the ground). The bodies
        meet at ``at`` (global, assembly; default: ``body_b``'s first primary particle), where their points coincide,
        and rows between directions fixed in each body lock the relative rotation (3 in space, one fewer per rod,
        whose spin about its own line is no freedom; 1 in a plane). ``at`` must be a place both bodies can carry a
        point (on the line of a rod, in the plane of a planar body)."""
        label = name or f"fixed {body_a or 'ground'}-{body_b}"
        if body_a == body_b:
            raise ModelError(f"{label}: welds body '{body_b}' to itself")
        at = None if at is None else self._vec(at, f"{label}: at")
        self._joints.append(Fixed(body_a, body_b, at, label))

    def revolute(self, body_a: Optional[str], body_b: str, *, axis, name: Optional[str] = None) -> None:
        """A revolute joint between two bodies (``body_a=None``: the ground) about the line through the global
        points ``axis = (p0, p1)`` (at assembly): each body's point at ``p0`` made one (a cut joint, three rows) and
        ``body_b``'s point at ``p1`` kept on ``body_a``'s axis (two rows). Bodies sharing two particles on the axis
        are the other way to the same joint. Both bodies must be able to carry points on the axis (any spatial
        body; a rod only along its own line); declare them first. Spatial mechanisms (in a plane, share a particle
        or ``cut_joint`` two points)."""
        label = name or f"revolute {body_a or 'ground'}-{body_b}"
        if self.planar:
            raise ModelError(f"{label}: in a planar mechanism every joint turns about z: share a particle or "
                             "cut_joint two points")
        if isinstance(axis, str) or len(axis) != 2:
            raise ModelError(f"{label}: axis must be two points (p0, p1) on the joint's axis")
        p0, p1 = (self._vec(p, f"{label}: axis point") for p in axis)
        if np.linalg.norm(p1 - p0) <= 1e-9 * max(1.0, np.linalg.norm(p0)):
            raise ModelError(f"{label}: the axis points coincide")
        if body_a == body_b:
            raise ModelError(f"{label}: joins body '{body_b}' to itself")
        known = {b[0]: b[2] for b in self._bodies}
        for body in (body_a, body_b):
            if body is not None and body not in known:
                raise ModelError(f"{label}: unknown body '{body}' (declare the bodies before the joint)")
        e = (p1 - p0) / np.linalg.norm(p1 - p0)

        def off_axis(p):
            d = p - p0
            return np.linalg.norm(d - np.dot(d, e) * e)

        if body_a is None:
            a0, a1 = self.ground(f"{label}: axis 0", p0), self.ground(f"{label}: axis 1", p1)
            side = np.cross(e, np.eye(3)[int(np.argmin(np.abs(e)))])
            ref = self.ground(f"{label}: reference", p0 + side / np.linalg.norm(side))
        else:
            a0, a1 = (self.point(f"{label}: {body_a} axis {k}", body_a, p) for k, p in ((0, p0), (1, p1)))
            ref = max(known[body_a], key=lambda n: off_axis(self._position(n, label)))
            if off_axis(self._position(ref, label)) <= 1e-9:
                raise ModelError(f"{label}: body '{body_a}' has no primary off the axis (a rod along it)")
        b0, b1 = (self.point(f"{label}: {body_b} axis {k}", body_b, p) for k, p in ((0, p0), (1, p1)))
        self.cut_joint(a0, b0, name=f"{label}: axis point")
        self.on_line(b1, a0, (a0, a1), ref, name=f"{label}: axis direction")

    # ---- force elements ----
    def point(self, name: str, body: Optional[str], xyz) -> str:
        """A named point fixed to ``body`` at global ``xyz`` (assembly). A point of a planar body must lie in the
        plane of its primaries, a point of a rod on its line (they are affine combinations of the primaries)."""
        if name in self._points or name in self._particles:
            raise ModelError(f"point '{name}' is defined twice")
        self._points[name] = (body, self._vec(xyz, f"point '{name}': position"))
        return name

    def spring_damper(self, name: str, a: str, b: str, stiffness: float = 0.0, damping: float = 0.0,
                      free_length: Optional[float] = None, *, force_curve=None, damping_curve=None) -> None:
        """Point-to-point spring-damper between two particles or points: the tension ``stiffness (l - free_length)
        + damping l'`` along their line (``l`` their distance; ``free_length`` default: the assembly distance).

        Nonlinear laws from tables (e.g. a vehicle file's spring and shock curves): ``force_curve = (x, f)`` the
        tension ``f`` (N) at elongations ``x = l - free_length`` (m; negative in compression) in place of the
        stiffness, ``damping_curve = (v, f)`` the tension at elongation rates ``v`` (m/s) in place of the damping;
        either as two sequences or as rows ``[[x, f], ...]``, abscissae increasing, at least 3 points. Between the
        points a natural cubic spline (smooth in the elongation and in the values), beyond them the end tangents
        (:mod:`.curves`). The values are parameters: ``with_params(spring={name: {"force_curve": f}})``. The force
        curve's integral is the spring's energy."""
        owner = f"spring '{name}'"
        for label, v in (("stiffness", stiffness), ("damping", damping)) + (
                (("free length", free_length),) if free_length is not None else ()):
            _number(owner, label, v)
        tables = []
        for label, curve, linear in (("force_curve", force_curve, stiffness), ("damping_curve", damping_curve,
                                                                               damping)):
            if curve is None:
                tables.append(None)
                continue
            if linear:
                raise ModelError(f"{owner}: give {label.split('_')[0] == 'force' and 'stiffness' or 'damping'} or "
                                 f"{label}, not both")
            tables.append(check_curve(owner, label.replace("_", " "), curve))
        if name in (s[0] for s in self._springs):
            raise ModelError(f"spring '{name}' is defined twice")
        self._springs.append((name, a, b, stiffness, damping, free_length, *tables))

    def tyre(self, name: str, point: str, stiffness: float, damping: float, radius: float, *,
             normal=(0.0, 0.0, 1.0), ground: float | Callable = 0.0, apply_at: Optional[str] = None) -> None:
        """One-sided tyre spring-damper acting along ``normal`` while ``point`` (the wheel centre) is within
        ``radius`` of the ground: force ``k (radius - d) - c d'`` with ``d`` the centre's height above the ground
        along ``normal``. It acts on ``point``, or on ``apply_at`` (e.g. the contact point below the centre, a point
        of the same body) when given: the deflection is measured at the centre and the force applied at the contact.
        Its :func:`~.forces.potential_energy` is the deflection energy; with a separate application point the force
        is not that energy's gradient once the body turns, so energy balances hold only for the centre-applied tyre.

        ``ground``: the height of a plane ``p.normal = ground`` (a parameter, ``with_params(tyre={name: {"ground":
        ...}})``), or the road as a JAX function: ``ground(t)`` (a post of a four-post rig under the wheel) or
        ``ground(t, p)`` (a profile under the wheel, ``p`` the measuring point's position (3,), e.g. ``lambda t, p:
        profile(p[0])``), returning one number; the height parameter (0) is added to it. The road's rate enters the
        damping (``d'`` relative to the road, by autodiff), and located events (``events=True``) find contact on
        the moving surface. The force stays along ``normal`` (a point-follower tyre: the profile's slope is not
        turned into a horizontal force). An ``equinox.Module`` with array fields makes its arrays parameters."""
        road = None
        if callable(ground):
            road, ground = ground, 0.0
            _road_arity(name, road)
        elif not _is_number(ground):
            raise ModelError(f"tyre '{name}': ground must be a number (the ground plane's height) or a function "
                             f"ground(t) or ground(t, p) of the road, got {type(ground).__name__}")
        for label, v in (("stiffness", stiffness), ("damping", damping), ("radius", radius), ("ground", ground)):
            _number(f"tyre '{name}'", label, v, non_negative=label != "ground")
        if name in (t[0] for t in self._tyres):
            raise ModelError(f"tyre '{name}' is defined twice")
        self._tyres.append((name, point, np.asarray(normal, dtype=float), stiffness, damping, radius, ground,
                            apply_at, road))

    def _element_name(self, kind: str, name: str, taken: list) -> None:
        if not isinstance(name, str) or not name:
            raise ModelError(f"{kind}: needs a name (a non-empty string), got {name!r}")
        if name in (e[0] for e in taken):
            raise ModelError(f"{kind} '{name}' is defined twice")

    def _numbers(self, owner: str, label: str, v, n: int) -> np.ndarray:
        """``n`` finite non-negative numbers (or one, repeated), refused by name otherwise."""
        if _is_number(v):
            v = [v] * n
        arr = np.asarray(v, dtype=object)
        if arr.shape != (n,):
            raise ModelError(f"{owner}: {label} must be {n} numbers, got {v!r}")
        for x in arr:
            _number(owner, label, x)
        return np.asarray(arr, dtype=float)

    def bushing(self, name: str, body_a: Optional[str], body_b: str, *, at, stiffness, damping=0.0,
                rotational_stiffness=None, rotational_damping=None, frame: Optional[str] = "body_a",
                axes=None) -> None:
        """A bushing: a 3-D spring-damper joining ``body_a`` (``None``: the ground) and ``body_b`` at the global
        point ``at`` (their two points coincide at assembly: zero free length). The force on ``body_b`` is
        ``-A (K delta + C delta')`` with ``delta`` the separation of its point from ``body_a``'s in the bushing's
        axes ``A`` (``stiffness = (kx, ky, kz)`` in N/m, ``damping = (cx, cy, cz)`` in N s/m, or one number for
        all three), the opposite on ``body_a``. The axes are ``axes`` (3 x 3, rows the x, y, z directions in the
        world at assembly, orthonormal and right-handed; default the world axes) and turn with ``frame`` (a body
        name, default ``body_a``; ``None``: fixed in the world). With ``rotational_stiffness = (krx, kry, krz)``
        (N m/rad) and/or ``rotational_damping`` it also resists the rotation of ``body_b`` relative to
        ``body_a`` since assembly (its rotation vector in the same axes; below half a turn), for bodies that carry a
        rotation (spatial or planar sets, not rods). Conservative apart from its damping: its energy enters
        :func:`~.forces.potential_energy`. Parameters by name: ``with_params(bushing={name: {"stiffness": (6,),
        "damping": (6,)}})``, translations then rotations."""
        label = f"bushing '{name}'"
        self._element_name("bushing", name, self._bushings)
        k = self._numbers(label, "stiffness", stiffness, 3)
        c = self._numbers(label, "damping", damping, 3)
        rotating = rotational_stiffness is not None or rotational_damping is not None
        kr = self._numbers(label, "rotational stiffness", 0.0 if rotational_stiffness is None
                           else rotational_stiffness, 3)
        cr = self._numbers(label, "rotational damping", 0.0 if rotational_damping is None else rotational_damping, 3)
        where = self._vec(at, f"{label}: at")
        a = np.eye(3) if axes is None else np.asarray(axes, dtype=float)
        if a.shape != (3, 3) or not np.all(np.isfinite(a)):
            raise ModelError(f"{label}: axes must be a 3 x 3 matrix (rows: the bushing's x, y, z directions)")
        if not np.allclose(a @ a.T, np.eye(3), atol=1e-9) or np.linalg.det(a) < 0:
            raise ModelError(f"{label}: axes must be orthonormal and right-handed (rows: x, y, z directions), got "
                             f"{a.tolist()}")
        if body_a == body_b:
            raise ModelError(f"{label}: joins body '{body_b}' to itself")
        frame = body_a if frame == "body_a" else frame
        self._bushings.append((name, body_a, body_b, frame, where, a.T, np.concatenate([k, kr]),
                               np.concatenate([c, cr]), rotating))

    def torsion_spring(self, name: str, body_a: Optional[str], body_b: str, axis, stiffness: float,
                       damping: float = 0.0, free_angle: float = 0.0) -> None:
        """A torsion spring-damper between two bodies about ``axis`` (a direction, global at assembly, fixed in
        ``body_a``; ``None``: the ground): the torque on ``body_b`` is ``-(stiffness (theta - free_angle) + damping
        theta')`` about the axis, its opposite on ``body_a``, with ``theta`` the rotation of ``body_b`` relative to
        ``body_a`` since assembly about the axis (right-handed; the twist component of the relative rotation
        vector, exact for bodies hinged on that axis; below half a turn). An anti-roll bar: two bar halves hinged
        to the chassis on one axis, joined by this spring, each linked to its wheel's arm. Both bodies must carry
        a rotation (spatial or planar sets, not rods). Stiffness in N m/rad, damping in N m s/rad; parameters by
        name: ``with_params(torsion={name: {...}})``."""
        label = f"torsion spring '{name}'"
        self._element_name("torsion spring", name, self._torsions)
        for lab, v in (("stiffness", stiffness), ("damping", damping), ("free angle", free_angle)):
            _number(label, lab, v, non_negative=lab != "free angle")
        e = self._vec(axis, f"{label}: axis")
        if np.linalg.norm(e) == 0:
            raise ModelError(f"{label}: axis must be a non-zero vector")
        if body_a == body_b:
            raise ModelError(f"{label}: joins body '{body_b}' to itself")
        self._torsions.append((name, body_a, body_b, e / np.linalg.norm(e), float(stiffness), float(damping),
                               float(free_angle)))

    def bump_stop(self, name: str, a: str, b: str, clearance: float, stiffness: float, damping: float = 0.0, *,
                  rebound: bool = False) -> None:
        """A one-sided spring-damper between two particles or points (a jounce bumper between an arm and the
        chassis): it engages once their distance has shortened by more than ``clearance`` (m) from its assembly
        value (``rebound=True``: lengthened, a rebound stop), then pushes back along their line with
        ``stiffness`` (N/m) times the penetration plus ``damping`` (N s/m) times its rate. Its switch is a located
        event in ``simulate_mechanism(..., events=True)``; its energy enters :func:`~.forces.potential_energy`.
        Parameters by name: ``with_params(bump={name: {"stiffness", "damping", "clearance"}})``."""
        label = f"bump stop '{name}'"
        self._element_name("bump stop", name, self._bumps)
        for lab, v in (("clearance", clearance), ("stiffness", stiffness), ("damping", damping)):
            _number(label, lab, v)
        if not isinstance(rebound, (bool, np.bool_)):
            raise ModelError(f"{label}: rebound must be True or False, got {rebound!r}")
        self._bumps.append((name, a, b, float(clearance), float(stiffness), float(damping), bool(rebound)))

    def applied_force(self, name: str, point: str, fn: Callable) -> None:
        """A force ``fn(t, q, qd) -> (3,)`` (global) acting at a particle or point."""
        self._applied.append((AppliedForce, name, point, fn))

    def applied_torque(self, name: str, body: str, fn: Callable) -> None:
        """A torque ``fn(t, q, qd) -> (3,)`` (global) acting on a spatial or planar body."""
        self._applied.append((AppliedTorque, name, body, fn))

    def body_load(self, name: str, bodies: Sequence[str], fn: Callable) -> None:
        """Loads computed from the named bodies' states: ``fn(t, state) -> {body: (force, torque)}`` where ``state``
        is a :class:`~.model.BodyState` (``state.position["wheel"]`` the centre of mass, ``.rotation``,
        ``.velocity``, ``.angular_velocity``, world frame) and each force (N, world) acts at that body's centre of
        mass, each torque (N m, world) on the body; bodies left out of the returned dict get no load. The natural
        place for aerodynamic drag, bushings, tyre models or controllers that need body poses rather than particle
        vectors. ``fn`` must be JAX-traceable; an ``equinox.Module`` with array fields makes its arrays parameters
        (differentiable, and new values reuse the compiled rollout)."""
        if not callable(fn):
            raise ModelError(f"body load '{name}': needs a function fn(t, state), got {type(fn).__name__}")
        if isinstance(bodies, str) or not len(bodies):
            raise ModelError(f"body load '{name}': bodies must be a non-empty list of body names")
        self._applied.append((BodyLoad, name, tuple(bodies), fn))

    # ---- driving constraints ----
    def _driver(self, name: str, fn) -> None:
        if any(d.name == name for d in self._drives):
            raise ModelError(f"driver '{name}' is defined twice")
        if not callable(fn):
            raise ModelError(f"driver '{name}': needs a function of time f(t), got {type(fn).__name__}")
        try:
            v = np.asarray(fn(jnp.asarray(0.0)), dtype=float)
        except Exception as e:  # noqa: BLE001 — report any failure of the user's function with the driver's name
            raise ModelError(f"driver '{name}': f(0.0) failed: {type(e).__name__}: {e}") from None
        if v.shape != () or not np.isfinite(v):
            raise ModelError(f"driver '{name}': f(t) must return one finite number, got {v.tolist()!r} at t = 0")

    def drive_angle(self, name: str, body: str, fn: Callable, *, axis=(0.0, 0.0, 1.0)) -> None:
        """Prescribe the rotation of ``body`` about the fixed world direction ``axis`` (through any point): it is
        turned by ``fn(t)`` radians (right-handed about ``axis``) from its pose as built. One row; the body must be
        otherwise free to turn about that direction only (e.g. a crank on a revolute joint to the ground). The row
        is scaled so that its multiplier is the driving torque (:func:`~.outputs.driver_efforts`).

        ``fn`` is a JAX-traceable scalar function of time (its first two derivatives are taken by autodiff), e.g.
        ``lambda t: 150.0 * t``; an ``equinox.Module`` with array fields makes its arrays parameters. At the
        initial time of a run ``fn`` should be 0, or the initial state be made consistent
        (:func:`~.integrate.project` with ``t``)."""
        self._driver(name, fn)
        k = np.asarray(axis, dtype=float)
        if k.shape != (3,) or not np.all(np.isfinite(k)):
            raise ModelError(f"driver '{name}': axis must be 3 finite numbers, got {np.asarray(axis).tolist()}")
        if np.linalg.norm(k) == 0:
            raise ModelError(f"driver '{name}': axis must be a non-zero vector")
        if self.planar and (k[0] != 0 or k[1] != 0):
            raise ModelError(f"driver '{name}': a planar mechanism turns about z only, got axis {k.tolist()}")
        self._drives.append(DriveAngle(name, body, fn, unit(k)))

    def drive_position(self, name: str, point: str, fn: Callable, *, axis, relative_to: Optional[str] = None) -> None:
        """Prescribe the motion of a particle or point along the fixed unit direction ``axis``: it moves ``fn(t)``
        (metres) along ``axis`` from its assembly position, measured from the world origin or from the particle or
        point ``relative_to``. One row; its multiplier is the driving force (:func:`~.outputs.driver_efforts`).
        ``fn`` as in :meth:`drive_angle`."""
        self._driver(name, fn)
        e = self._vec(axis, f"driver '{name}': axis")
        if np.linalg.norm(e) == 0:
            raise ModelError(f"driver '{name}': axis must be a non-zero vector")
        self._drives.append(DrivePosition(name, point, fn, unit(e), relative_to))

    # ---- build ----
    def build(self, *, dof: Optional[int] = None, assemble: bool = False, hold: Sequence = (),
              multipliers: str = "auto") -> tuple[Mechanism, np.ndarray]:
        """Check everything and return the mechanism and its assembly state ``q0`` ``(3F,)``.

        ``multipliers`` says how the constraint forces are solved. "exact": one Cholesky factorisation per
        evaluation; redundant constraints (a Jacobian without full row rank at the assembly) are refused, naming
        the first redundant row. "least_squares": least-squares multipliers from a damped, refined factorisation
        (:data:`~._algebra.LSQ_RTOL`), as mature codes do for redundant constraints (Bricard's linkage, a doubled
        parallelogram) and for mechanisms that pass singular positions (a linkage lying flat); the motion is
        unique, the split of the force among redundant rows is not. "auto" (default): "exact"
        when the rows are independent at the assembly, otherwise "least_squares" with a warning that names the
        redundant rows. Degrees of freedom are counted from the rank. The rank found is left in
        ``self.constraint_rank`` (a :class:`ConstraintRank`).

        With ``assemble=True`` approximate positions (rounded data, a loop drawn open) are first corrected to the
        nearest consistent configuration (:func:`~.assembly.assemble`; body shapes are kept as given, joints and
        loops closed), holding the particles or coordinates listed in ``hold`` (names or ``(name, 'x'|'y'|'z')``);
        the correction is left in ``self.assembly`` (an :class:`~.assembly.Assembly`).

        Raises :class:`ModelError` naming the culprit for: unknown names, a dangling particle (in no body and no
        joint), violated constraints at the given positions, redundant (over-constrained) constraints, a
        mechanism whose degrees of freedom differ from ``dof``, a spring of zero length, a direction of motion
        that carries no mass. Singular particle placements and non-physical inertias are refused by
        :mod:`particlesim.particles` and :mod:`particlesim.inertia` with the body's name.
        """
        if multipliers not in ("auto", "exact", "least_squares"):
            raise ValueError(f"unknown multipliers {multipliers!r}; choose 'auto', 'exact' or 'least_squares'")
        bd = _Build(self)
        out = bd.run(dof, assemble, tuple(hold), multipliers)
        self.assembly = bd.assembly
        self.constraint_rank = bd.constraint_rank
        return out


def _is_number(v) -> bool:
    """A real scalar (a Python or NumPy number, or a 0-d array), not a bool, string or function."""
    return (not isinstance(v, (bool, np.bool_, str, bytes)) and not callable(v)
            and isinstance(v, (int, float, np.integer, np.floating, np.ndarray)) and np.ndim(v) == 0
            and np.isrealobj(v))


def _number(owner: str, label: str, v, *, non_negative: bool = True) -> None:
    """Refuse, naming ``owner`` and ``label``, a value that is not a finite (non-negative) number."""
    if not _is_number(v) or not np.isfinite(v) or (non_negative and v < 0):
        shown = f"a {type(v).__name__}" if not _is_number(v) else repr(v)
        raise ModelError(f"{owner}: {label} must be a finite{' and non-negative' if non_negative else ''} number, "
                         f"got {shown}")
