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
    mech, x0 = mb.build()

The build works in NumPy on the assembly configuration (its cost grows linearly with the mechanism, apart from
one rank check of the constraint Jacobian) and returns a :class:`~.model.Mechanism` whose rows are typed
(:class:`~.model.DotRows`, :class:`~.model.LinearRows`).
"""

from __future__ import annotations

import dataclasses
import warnings
from typing import Callable, Optional, Sequence

import jax.numpy as jnp
import numpy as np

from ..errors import ModelError
from ..inertia import RigidInertia
from ..particles import N_PRIMARY, check_placement, equivalent_particles
from .model import AppliedForce, AppliedTorque, BodyLoad, DotRows, DriveRows, LinearRows, Mechanism, Topology

__all__ = ["MechanismBuilder", "ConstraintRank", "RedundantConstraintsWarning", "ASSEMBLY_RTOL", "RANK_RTOL"]

#: Constraints must hold at the given positions to this fraction of the mechanism's size.
ASSEMBLY_RTOL = 1e-9
#: Singular values of the constraint Jacobian below this fraction of the largest count as rank loss.
RANK_RTOL = 1e-9
_AXES = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))


#: Name of the hidden ground particle at the origin of a planar mechanism's plane.
_PLANE = "(plane origin)"


class RedundantConstraintsWarning(UserWarning):
    """A mechanism was built with redundant constraint rows (solved with least-squares multipliers)."""


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


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
        self._joints: list[tuple[str, tuple[str, ...], str, Optional[float]]] = []  # kind, names, label, length
        self._points: dict[str, tuple[Optional[str], np.ndarray]] = {}
        self._springs: list[tuple] = []
        self._tyres: list[tuple] = []
        self._rotational: list[tuple] = []
        self._applied: list[tuple] = []
        self._drives: list[tuple] = []  # (name, kind, target, fn, axis, relative_to)

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
        for label, v in (("stiffness", stiffness), ("damping", damping)):
            if not np.isfinite(v) or v < 0:
                raise ModelError(f"rotational spring '{name}': {label} must be finite and non-negative, got {v!r}")
        if not np.isfinite(free_angle):
            raise ModelError(f"rotational spring '{name}': free angle must be finite, got {free_angle!r}")
        if name in (r[0] for r in self._rotational):
            raise ModelError(f"rotational spring '{name}' is defined twice")
        if body_a == body_b:
            raise ModelError(f"rotational spring '{name}': connects body '{body_b}' to itself")
        self._rotational.append((name, body_a, body_b, float(stiffness), float(damping), float(free_angle)))

    def link(self, a: str, b: str, *, name: Optional[str] = None, length: Optional[float] = None) -> None:
        """A massless rigid link (distance constraint) between particles or points ``a`` and ``b``; its length is
        the assembly distance unless given."""
        self._joints.append(("link", (a, b), name or f"link {a}-{b}", length))

    def cut_joint(self, a: str, b: str, *, name: Optional[str] = None) -> None:
        """Close a loop: particles/points ``a`` and ``b`` (on different branches) coincide, ``r_a = r_b``."""
        self._joints.append(("coincide", (a, b), name or f"cut joint {a}={b}", None))

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
        names = (particle, origin, *direction) + (() if ref is None else (ref,))
        self._joints.append(("on_line", names, name or f"{particle} on axis", None))

    def prismatic(self, axis_a: Sequence[str], axis_b: Sequence[str], *, name: Optional[str] = None) -> None:
        """Prismatic joint: ``axis_a = (a0, a1, a2)`` are particles/points of body A (or ground) with a0, a1 on the
        axis and a2 off it; ``axis_b = (b0, b1, b2)`` likewise on body B. B slides along A's axis without turning.
        In a planar mechanism two points a side suffice, ``(a0, a1)`` and ``(b0, b1)``, all on the axis."""
        if self.planar and len(axis_a) == 2 and len(axis_b) == 2:
            self._joints.append(("prismatic2d", (*axis_a, *axis_b), name or f"prismatic {axis_a[0]}-{axis_b[0]}",
                                 None))
            return
        if len(axis_a) != 3 or len(axis_b) != 3:
            two = " (or two, on the axis, in a planar mechanism)" if self.planar else ""
            raise ModelError(f"prismatic joint {name}: needs three particles on each side{two}")
        self._joints.append(("prismatic", (*axis_a, *axis_b), name or f"prismatic {axis_a[0]}-{axis_b[0]}", None))

    def universal(self, center: str, arm_a: str, arm_b: str, *, name: Optional[str] = None) -> None:
        """Universal (Cardan) joint: ``center`` is a particle of both bodies (their spherical joint) and ``arm_a``,
        ``arm_b`` are particles or points of body A and body B marking the cross's two arms from the centre, which
        must be perpendicular at assembly; they stay perpendicular (one row), which leaves two relative rotations."""
        self._joints.append(("universal", (center, arm_a, arm_b), name or f"universal {center}", None))

    def cylindrical(self, axis_a: Sequence[str], axis_b: Sequence[str], *, name: Optional[str] = None) -> None:
        """Cylindrical joint: ``axis_a = (a0, a1, a2)`` particles/points of body A (or ground), a0 and a1 on the
        axis and a2 off it; ``axis_b = (b0, b1)`` of body B on the axis. B slides along and turns about A's axis
        (four rows: b0 and b1 kept on the line). Spatial mechanisms only (in a plane it would be a prismatic joint)."""
        if len(axis_a) != 3 or len(axis_b) != 2:
            raise ModelError(f"cylindrical joint {name}: needs three particles on the guide and two on the slider")
        if self.planar:
            raise ModelError(f"cylindrical joint {name}: not available in a planar mechanism (use prismatic)")
        self._joints.append(("cylindrical", (*axis_a, *axis_b), name or f"cylindrical {axis_a[0]}-{axis_b[0]}",
                             None))

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
        self._joints.append(("fixed", (body_a, body_b, at), label, None))

    # ---- force elements ----
    def point(self, name: str, body: Optional[str], xyz) -> str:
        """A named point fixed to ``body`` at global ``xyz`` (assembly). A point of a planar body must lie in the
        plane of its primaries, a point of a rod on its line (they are affine combinations of the primaries)."""
        if name in self._points or name in self._particles:
            raise ModelError(f"point '{name}' is defined twice")
        self._points[name] = (body, self._vec(xyz, f"point '{name}': position"))
        return name

    def spring_damper(self, name: str, a: str, b: str, stiffness: float, damping: float,
                      free_length: float) -> None:
        """Point-to-point spring-damper between two particles or points."""
        for label, v in (("stiffness", stiffness), ("damping", damping), ("free length", free_length)):
            if not np.isfinite(v) or v < 0:
                raise ModelError(f"spring '{name}': {label} must be finite and non-negative, got {v!r}")
        if name in (s[0] for s in self._springs):
            raise ModelError(f"spring '{name}' is defined twice")
        self._springs.append((name, a, b, stiffness, damping, free_length))

    def tyre(self, name: str, point: str, stiffness: float, damping: float, radius: float, *,
             normal=(0.0, 0.0, 1.0), ground: float = 0.0, apply_at: Optional[str] = None) -> None:
        """One-sided tyre spring-damper acting along ``normal`` while ``point`` (the wheel centre) is within
        ``radius`` of the ground plane ``p.normal = ground``: force ``k (radius - d) - c d'`` with ``d`` the centre's
        height. It acts on ``point``, or on ``apply_at`` (e.g. the contact point below the centre, a point of the
        same body) when given: the deflection is measured at the centre and the force applied at the contact. Its
        :func:`~.forces.potential_energy` is the deflection energy; with a separate application point the force is
        not that energy's gradient once the body turns, so energy balances hold only for the centre-applied tyre."""
        for label, v in (("stiffness", stiffness), ("damping", damping), ("radius", radius), ("ground", ground)):
            if not np.isfinite(v) or (label != "ground" and v < 0):
                raise ModelError(f"tyre '{name}': {label} must be finite" + (" and non-negative" if label != "ground"
                                                                              else "") + f", got {v!r}")
        if name in (t[0] for t in self._tyres):
            raise ModelError(f"tyre '{name}' is defined twice")
        self._tyres.append((name, point, np.asarray(normal, dtype=float), stiffness, damping, radius, ground,
                            apply_at))

    def applied_force(self, name: str, point: str, fn: Callable) -> None:
        """A force ``fn(t, q, qd) -> (3,)`` (global) acting at a particle or point."""
        self._applied.append((name, "force", point, fn))

    def applied_torque(self, name: str, body: str, fn: Callable) -> None:
        """A torque ``fn(t, q, qd) -> (3,)`` (global) acting on a spatial or planar body."""
        self._applied.append((name, "torque", body, fn))

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
        self._applied.append((name, "load", tuple(bodies), fn))

    # ---- driving constraints ----
    def _driver(self, name: str, fn) -> None:
        if any(d[0] == name for d in self._drives):
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
        self._drives.append((name, "angle", body, fn, _unit(k), None))

    def drive_position(self, name: str, point: str, fn: Callable, *, axis, relative_to: Optional[str] = None) -> None:
        """Prescribe the motion of a particle or point along the fixed unit direction ``axis``: it moves ``fn(t)``
        (metres) along ``axis`` from its assembly position, measured from the world origin or from the particle or
        point ``relative_to``. One row; its multiplier is the driving force (:func:`~.outputs.driver_efforts`).
        ``fn`` as in :meth:`drive_angle`."""
        self._driver(name, fn)
        e = self._vec(axis, f"driver '{name}': axis")
        if np.linalg.norm(e) == 0:
            raise ModelError(f"driver '{name}': axis must be a non-zero vector")
        self._drives.append((name, "position", point, fn, _unit(e), relative_to))

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

    def __init__(self, mb: MechanismBuilder):
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
        """Geometry of every joint at assembly: for lines and prismatic joints the host body and the unit
        directions normal to the axis, fixed in the host (as points at ``origin + ell * n``)."""
        plans = []
        for kind, pnames, label, length in self.mb._joints:
            if kind == "fixed":
                plans.append(self._fixed_plan(pnames, label))
                continue
            world = [self.where(n, label)[0] for n in pnames]
            dirs, host, ell = (), None, None
            if kind == "on_line":
                o, d0, d1 = world[1:4]
                u = d1 - d0
                ell = float(np.linalg.norm(u))
                if ell == 0:
                    raise ModelError(f"{label}: the line's direction points '{pnames[2]}' and '{pnames[3]}' "
                                     "coincide (a slot of zero length has no direction)")
                if self.mb.planar:
                    n1 = _unit(np.cross((0.0, 0.0, 1.0), u))
                else:
                    ref = world[4]
                    w = (ref - d0) - ((ref - d0) @ u) / (u @ u) * u
                    if np.linalg.norm(w) <= 1e-9 * ell:
                        raise ModelError(f"{label}: reference point '{pnames[4]}' lies on the line")
                    n1 = _unit(w)
                host = self.host(pnames[1:], label)
                dirs = (n1, np.cross(u / ell, n1))
            elif kind == "cylindrical":
                a0, a1, a2 = world[:3]
                u = a1 - a0
                ell = float(np.linalg.norm(u))
                w = (a2 - a0) - ((a2 - a0) @ u) / (u @ u) * u if ell > 0 else u
                if ell == 0 or np.linalg.norm(w) <= 1e-9 * ell:
                    raise ModelError(f"{label}: point '{pnames[2]}' lies on the axis '{pnames[0]}'-'{pnames[1]}'")
                if np.linalg.norm(world[4] - world[3]) <= 1e-9 * ell:
                    raise ModelError(f"{label}: the slider's axis points '{pnames[3]}' and '{pnames[4]}' coincide")
                n1 = _unit(w)
                host = self.host(pnames[:3], label)
                dirs = (n1, np.cross(u / ell, n1))
            elif kind == "prismatic2d":
                a0, a1, b0, b1 = world
                u = a1 - a0
                ell = float(np.linalg.norm(u))
                if ell == 0:
                    raise ModelError(f"{label}: the guide's axis points '{pnames[0]}' and '{pnames[1]}' coincide")
                if np.linalg.norm(b1 - b0) <= 1e-9 * ell:
                    raise ModelError(f"{label}: the slider's axis points '{pnames[2]}' and '{pnames[3]}' coincide")
                host = self.host(pnames[:2], label)
                dirs = (_unit(np.cross((0.0, 0.0, 1.0), u)),)
            elif kind == "prismatic":
                a0, a1, a2, b0, _, b2 = world
                u = a1 - a0
                ell = float(np.linalg.norm(u))
                w = (a2 - a0) - ((a2 - a0) @ u) / (u @ u) * u if ell > 0 else u
                if ell == 0 or np.linalg.norm(w) <= 1e-9 * ell:
                    raise ModelError(f"{label}: point '{pnames[2]}' lies on the axis '{pnames[0]}'-'{pnames[1]}'")
                u = u / ell
                n1 = _unit(w)
                wb = (b2 - b0) - ((b2 - b0) @ u) * u
                if np.linalg.norm(wb) <= 1e-9 * ell:
                    raise ModelError(f"{label}: point '{pnames[5]}' lies on the axis through '{pnames[3]}'")
                # The rotation lock uses the direction normal to both the axis and b2's offset from it, so its
                # gradient never vanishes (in a planar model too, where b2 lies in the plane of the axis and n1).
                host = self.host(pnames[:3], label)
                dirs = (n1, np.cross(u, n1), _unit(np.cross(u, wb)))
            if self.mb.planar:
                dirs = dirs[:1]  # the in-plane normal; the out-of-plane rows are left out (see joints)
            origin = world[1] if kind == "on_line" else (
                world[0] if kind in ("prismatic", "prismatic2d", "cylindrical") else None)
            names = []
            if self.mb.planar and kind in ("on_line", "prismatic2d"):
                dirs = ()  # turned rows: the line's in-plane normal is a quarter turn of its direction
            if host == -1:  # a ground-side direction: a hidden ground particle
                for j, d in enumerate(dirs):
                    nm = f"{label} / direction {j + 1}"
                    self.index[nm] = len(self.names)
                    self.names.append(nm)
                    self.pos.append(origin + ell * d)
                    self.is_ground.append(True)
                    names.append(nm)
            plans.append((kind, pnames, label, length, host, origin, dirs, ell, names))
        return plans

    def _directions(self, b: int) -> list[np.ndarray]:
        """Unit directions fixed in body ``b`` (``-1``: the ground) at assembly: the axes for the ground and a
        spatial body, the two in-plane directions of a planar set (or the x and y axes in a planar mechanism), the
        line of a rod."""
        if b < 0 or len(self.body_particles[b]) == 4:
            return [np.asarray(e) for e in _AXES[:2 if self.mb.planar else 3]]
        p = np.stack([self.pos[i] for i in self.body_particles[b]])
        e1 = _unit(p[1] - p[0])
        if len(p) == 2:
            return [e1]
        if self.mb.planar:
            return [np.asarray(e) for e in _AXES[:2]]
        w = (p[2] - p[0]) - ((p[2] - p[0]) @ e1) * e1
        return [e1, _unit(w)]

    def _fixed_plan(self, pnames, label):
        """Rows of a fixed joint: the meeting point (coincident points of both bodies) and a set of independent
        direction pairs ``a_i . b_j = const`` chosen at assembly by their sensitivity to a relative rotation
        (``b_j x a_i``), largest first."""
        names = {n: i for i, n in enumerate(self.body_names)}
        ids = []
        for n in pnames[:2]:
            if n is None:
                ids.append(-1)
            elif n not in names:
                raise ModelError(f"{label}: unknown body '{n}'")
            else:
                ids.append(names[n])
        ba, bb = ids
        at = pnames[2] if pnames[2] is not None else self.pos[self.body_particles[bb][0]]
        da, db = self._directions(ba), self._directions(bb)
        rods = sum(1 for b in ids if b >= 0 and len(self.body_particles[b]) == 2)
        need = 1 if self.mb.planar else 3 - rods
        cand = sorted(((np.cross(db[j], da[i]), i, j) for i in range(len(da)) for j in range(len(db))),
                      key=lambda c: -np.linalg.norm(c[0]))
        chosen, basis = [], []
        for g, i, j in cand:
            g = g[2:] if self.mb.planar else g
            r = g - sum((g @ q) * q for q in basis) if basis else g
            if np.linalg.norm(r) > 1e-6 and len(chosen) < need:
                basis.append(r / np.linalg.norm(r))
                chosen.append((i, j))
        if len(chosen) < need:
            raise ModelError(f"{label}: the directions of the two bodies cannot lock their relative rotation (e.g. "
                             "two collinear rods); merge them into one body instead")
        hidden = []
        if ba < 0:  # the ground's side: hidden ground particles at the meeting point and along its directions
            used = sorted({i for i, _ in chosen})
            for nm, xyz in [(f"{label} / at", at)] + [(f"{label} / direction {i + 1}", at + da[i]) for i in used]:
                self.index[nm] = len(self.names)
                self.names.append(nm)
                self.pos.append(np.asarray(xyz, dtype=float))
                self.is_ground.append(True)
                hidden.append(nm)
        return ("fixed", pnames, label, None, (ba, bb), at, (da, db, chosen), None, hidden)

    def _fixed_rows(self, plan):
        _, _, label, _, (ba, bb), at, (da, db, chosen), _, hidden = plan
        side = {}
        for tag, b, dirs in (("a", ba, da), ("b", bb, db)):
            if b < 0:
                pa = self.point_index[hidden[0]]
                side[tag] = (pa, {int(nm.rsplit(" ", 1)[1]) - 1: self.point_index[nm] for nm in hidden[1:]})
                continue
            p = self.add_point(f"{label} / at ({tag})", b, at)
            used = sorted({(i if tag == "a" else j) for i, j in chosen})
            side[tag] = (p, {k: self.add_point(f"{label} / direction {k + 1} ({tag})", b, at + dirs[k]) for k in used})
        (pa, dira), (pb, dirb) = side["a"], side["b"]
        for axis, c in list(zip(_AXES, "xyz"))[:2 if self.mb.planar else 3]:
            self.lin.append((pa, pb, axis, f"{label} ({c})"))
        for i, j in chosen:
            self.dot.append((dira[i], pa, dirb[j], pb, 1.0, float(da[i] @ db[j]), f"{label} (rotation {i + 1}{j + 1})"))

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
        planar = self.mb.planar
        for plan in plans:
            kind, pnames, label, length, host, origin, dirs, ell, ground_names = plan
            if kind == "fixed":
                self._fixed_rows(plan)
                continue
            ks = tuple(self.pidx(n, label) for n in pnames)
            world = [self.point_world[k] for k in ks]
            if kind == "link":
                d = np.linalg.norm(world[0] - world[1]) if length is None else float(length)
                self.dot.append((ks[0], ks[1], ks[0], ks[1], 0.5, 0.5 * d**2, label))
                continue
            if kind == "coincide":
                for axis, c in list(zip(_AXES, "xyz"))[:2 if planar else 3]:
                    self.lin.append((ks[0], ks[1], axis, f"{label} ({c})"))
                continue
            if kind == "universal":
                ha, hb = self.host(pnames[:2], label), self.host(pnames[::2], label)
                if ha == hb:
                    raise ModelError(f"{label}: both arms '{pnames[1]}' and '{pnames[2]}' belong to one body (or "
                                     f"the ground) with the centre '{pnames[0]}': a universal joint joins two bodies "
                                     "that share the centre")
                arm_a, arm_b = world[1] - world[0], world[2] - world[0]
                la, lb = float(np.linalg.norm(arm_a)), float(np.linalg.norm(arm_b))
                if la == 0 or lb == 0:
                    raise ModelError(f"{label}: an arm has zero length (arm point at the centre)")
                if abs(arm_a @ arm_b) > 1e-9 * la * lb:
                    raise ModelError(f"{label}: the arms are not perpendicular at assembly (cos = "
                                     f"{arm_a @ arm_b / (la * lb):.3g})")
                self.dot.append((ks[1], ks[0], ks[2], ks[0], 1.0 / (la * lb), 0.0, f"{label} (cross)"))
                continue
            if host == -1:
                n = [self.point_index[nm] for nm in ground_names]
            else:
                n = [self.add_point(f"{label} / direction {j + 1}", host, origin + ell * d)
                     for j, d in enumerate(dirs)]
            # rows s (N - O).(p - q) with N - O = ell * (unit direction fixed in the host)
            # In a planar mechanism n1 is the in-plane normal of the line and the out-of-plane rows are left out
            # (the particles are held in the plane; a slider with both axis points on the line cannot turn).
            if kind == "on_line" and planar:  # (p - o) . Rz (d1 - d0) / ell
                self.dot.append((ks[0], ks[1], ks[3], ks[2], 1.0 / ell, 0.0, f"{label} (n1)", True))
            elif kind == "on_line":
                for j, c in enumerate(("n1", "n2")):
                    self.dot.append((n[j], ks[1], ks[0], ks[1], 1.0 / ell, 0.0, f"{label} ({c})"))
            elif kind == "prismatic2d":  # (p - a0) . Rz (a1 - a0) / ell for both slider points
                a0 = ks[0]
                for p, tag in ((ks[2], "axis 1"), (ks[3], "axis 2")):
                    self.dot.append((p, a0, ks[1], a0, 1.0 / ell, 0.0, f"{label} ({tag})", True))
            elif kind == "cylindrical":
                a0, b0, b1 = ks[0], ks[3], ks[4]
                for p, tag in ((b0, "axis 1"), (b1, "axis 2")):
                    for j, c in enumerate("ab"):
                        self.dot.append((n[j], a0, p, a0, 1.0 / ell, 0.0, f"{label} ({tag}{c})"))
            else:
                a0, b0, b1, b2 = ks[0], ks[3], ks[4], ks[5]
                for p, tag in ((b0, "axis 1"), (b1, "axis 2")):
                    for j, c in enumerate("ab"[:1 if planar else 2]):
                        self.dot.append((n[j], a0, p, a0, 1.0 / ell, 0.0, f"{label} ({tag}{c})"))
                if not planar:
                    self.dot.append((n[2], a0, b2, b0, 1.0 / ell, 0.0, f"{label} (rotation)"))

    def drives(self):
        size = max(float(np.ptp(np.asarray(self.pos), axis=0).max()), 1e-12) if self.pos else 1.0
        for name, kind, target, fn, axis, rel in self.mb._drives:
            label = f"driver '{name}'"
            if kind == "position":
                a = self.pidx(target, label)
                b = -1 if rel is None else self.pidx(rel, label)
                pb = np.zeros(3) if b < 0 else self.point_world[b]
                if b == a:
                    raise ModelError(f"{label}: the point '{target}' is measured from itself")
                offset = float(axis @ (self.point_world[a] - pb))
                self.drv.append((a, b, tuple(axis), (0.0, 0.0, 0.0), offset, label, fn))
                continue
            if target not in self.body_names:
                raise ModelError(f"{label}: unknown body '{target}'")
            ids = self.body_particles[self.body_names.index(target)]
            best = None
            for s_ in range(len(ids)):
                for t_ in range(s_ + 1, len(ids)):
                    u = self.pos[ids[t_]] - self.pos[ids[s_]]
                    perp = u - (u @ axis) * axis
                    if best is None or np.linalg.norm(perp) > best[0]:
                        best = (float(np.linalg.norm(perp)), ids[s_], ids[t_], u)
            if best[0] <= 1e-9 * size:
                raise ModelError(f"{label}: the particles of body '{target}' lie on a line along the drive axis "
                                 f"{axis.tolist()}; a rotation about it does not move them")
            ell, i, j, u = best
            n0 = np.cross(axis, u) / ell**2
            self.drv.append((self.point_index[self.names[j]], self.point_index[self.names[i]], tuple(n0),
                             tuple(axis), 0.0, label, fn))

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
        for name, a, b, k, c, l0 in mb._springs:
            springs.append((name, (self.pidx(a, f"spring '{name}'"), self.pidx(b, f"spring '{name}'")), k, c, l0))
        for name, pt, normal, k, c, radius, g, apply_at in mb._tyres:
            nrm = np.linalg.norm(normal)
            if normal.shape != (3,) or not np.isfinite(nrm) or nrm == 0:
                raise ModelError(f"tyre '{name}': normal must be a non-zero vector of 3 numbers")
            at = self.pidx(pt if apply_at is None else apply_at, f"tyre '{name}' (application point)")
            tyres.append((name, self.pidx(pt, f"tyre '{name}'"), tuple(float(v) for v in normal / nrm), k, c,
                          radius, g, at))
        applied = []
        for name, kind, target, fn in mb._applied:
            if kind == "force":
                applied.append(AppliedForce(name=name, point=self.pidx(target, f"force '{name}'"), fn=fn))
            elif kind == "load":
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
            tyre_names=tuple(t[0] for t in tyres), tyre_points=tuple(t[1] for t in tyres),
            tyre_normals=tuple(t[2] for t in tyres), tyre_apply=tuple(t[7] for t in tyres),
            saddle_point=any(i not in in_body for i in free), planar=mb.planar,
            rotational_names=tuple(r[0] for r in rot), rotational_bodies=tuple(r[1] for r in rot),
            drive=DriveRows(a=tuple(r[0] for r in self.drv), b=tuple(r[1] for r in self.drv),
                            axis=tuple(tuple(float(v) for v in r[2]) for r in self.drv),
                            spin=tuple(tuple(float(v) for v in r[3]) for r in self.drv),
                            labels=tuple(r[5] for r in self.drv),
                            names=tuple(d[0] for d in self.mb._drives)))
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
            drive_offset=f([r[4] for r in self.drv]).reshape(-1), drive_fns=tuple(r[6] for r in self.drv))


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
