"""The mechanism model: particles, bodies, points, constraint rows and force elements in particle coordinates.

A mechanism (Attia §2) is a set of *particles*; some are fixed to the ground, the others are the unknowns. Each
rigid body owns 2, 3 or 4 of them as its primary particles (rod, planar, spatial set; :mod:`particlesim.particles`)
and its secondary particles are their midpoints, so they never appear as unknowns (Attia's reduced form, eqs.
(23)–(27)). Bodies that list the same particle share it: a spherical joint (one shared particle), a revolute joint
(two shared particles on the axis), a fixed point or a fixed axis (shared with the ground).

*Points* are where joints and force elements attach: every particle is a point, and a point fixed to a body is an
affine combination ``p = sum_t w_t r_t`` of the body's primaries (weights summing to one, solved from its body-frame
position; exact under every rigid motion, since rigid motions preserve affine combinations). Points are therefore
linear in the particle coordinates.

Every constraint is one of two typed row kinds on points, each evaluated for all its rows by one vectorised kernel
(:mod:`.constraints`):

* :class:`DotRows` ``s (p_a - p_b).(p_c - p_d) - kappa = 0`` — the rigid distances inside every body (Attia eqs.
  (11)–(16), ``a = c``, ``b = d``, ``s = 1/2``), massless links, a point kept on a body's line and the rows of a
  prismatic joint (the line's perpendicular directions are body points too);
  in a planar mechanism a row may be *turned* (its second vector rotated a quarter turn in the plane), for lines
  carried by rods;
* :class:`LinearRows` ``e . (p_a - p_b) = 0`` for a constant unit ``e`` — cut joints that close loops (``r_a = r_b``,
  Attia §2.4) as three rows.

Both are at most quadratic in the coordinates, so their Jacobians and ``gamma`` are closed-form.

State: ``q`` ``(3F,)``, the stacked positions of the F free particles (and ``qd`` their velocities).

Static (:class:`Topology`, hashable: the compile-cache key): names, index tuples, row layouts. Differentiable
leaves: body mass, CoM, inertia and body-frame primaries, body-point positions, ground positions, row constants,
force-element constants and gravity. Read and replace them by name with :meth:`Mechanism.with_params`.
"""

from __future__ import annotations

import dataclasses
from typing import Callable

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ..errors import ModelError
from ..inertia import _is_concrete, check_inertia

__all__ = ["Mechanism", "Topology", "DotRows", "LinearRows", "DriveRows", "AppliedForce", "AppliedTorque",
           "BodyLoad", "BodyState", "NON_NEGATIVE", "ELEMENT_FIELDS", "ELEMENT_LABELS"]

#: The force elements' parameters that must be non-negative, by kind (``Topology.<kind>_names``, ``Mechanism.<kind>_
#: <field>``): checked by :meth:`Mechanism.with_params` on concrete values and by the simulation (the builder refuses
#: negative ones itself).
NON_NEGATIVE = {"spring": ("stiffness", "damping", "free_length"), "tyre": ("stiffness", "damping", "radius"),
                "rotational": ("stiffness", "damping"), "bushing": ("stiffness", "damping"),
                "torsion": ("stiffness", "damping"), "bump": ("stiffness", "damping", "clearance")}

#: The parameters of each force element kind by name (``with_params(<kind>={name: {field: value}})``), and the
#: label each kind goes by in messages.
ELEMENT_FIELDS = {"spring": ("stiffness", "damping", "free_length"),
                  "tyre": ("stiffness", "damping", "radius", "ground"),
                  "rotational": ("stiffness", "damping", "free_angle"),
                  "bushing": ("stiffness", "damping"),
                  "torsion": ("stiffness", "damping", "free_angle"),
                  "bump": ("stiffness", "damping", "clearance")}
ELEMENT_LABELS = {"spring": "spring", "tyre": "tyre", "rotational": "rotational spring", "bushing": "bushing",
                  "torsion": "torsion spring", "bump": "bump stop"}


@dataclasses.dataclass(frozen=True)
class DotRows:
    """Rows ``scale (p_a - p_b).(p_c - p_d) - kappa``; point indices ``a, b, c, d`` (one entry per row). A *turned*
    row (planar mechanisms) reads ``scale (p_a - p_b).Rz (p_c - p_d) - kappa`` with ``Rz`` the quarter turn about
    z: a point on a line of a rod, whose in-plane normal is no affine combination of the rod's two particles."""

    a: tuple[int, ...]
    b: tuple[int, ...]
    c: tuple[int, ...]
    d: tuple[int, ...]
    scale: tuple[float, ...]
    labels: tuple[str, ...]
    turn: tuple[bool, ...] = ()  # empty: no turned rows

    def __len__(self) -> int:
        return len(self.a)

    @property
    def turned(self) -> tuple[bool, ...] | None:
        """Per-row turn flags, or ``None`` when no row is turned (the common case, which pays nothing)."""
        return tuple(self.turn) if any(self.turn) else None

    @property
    def slots(self) -> np.ndarray:
        """``(R, 4)`` point index of every slot of every row."""
        return np.stack([self.a, self.b, self.c, self.d], axis=1).reshape(-1, 4).astype(int)


@dataclasses.dataclass(frozen=True)
class LinearRows:
    """Rows ``axis . (p_a - p_b)`` with constant unit ``axis``; point indices ``a, b``."""

    a: tuple[int, ...]
    b: tuple[int, ...]
    axis: tuple[tuple[float, float, float], ...]
    labels: tuple[str, ...]

    def __len__(self) -> int:
        return len(self.a)

    @property
    def slots(self) -> np.ndarray:
        return np.stack([self.a, self.b], axis=1).reshape(-1, 2).astype(int)


@dataclasses.dataclass(frozen=True)
class DriveRows:
    """Driving constraints ``n(t) . (p_a - p_b) - c(t)`` that prescribe a motion over time (kinematic analysis,
    driven inputs); point ``b = -1`` stands for the world origin.

    * position drivers (``spin = 0``): ``n = axis`` (unit), ``c(t) = offset + f(t)``: point ``a`` moves ``f(t)``
      along ``axis`` (relative to ``b``) from its assembly position;
    * angle drivers (``spin = k``, unit): ``n(t) = Rot(k, f(t)) axis`` with ``axis = (k x u0) / |u0_perp|^2`` for
      the body vector ``u0 = p_a - p_b`` at assembly, ``c = 0``: the body turns by ``f(t)`` about ``k`` from its
      assembly pose (the row is scaled so that its multiplier is the driving torque).
    """

    a: tuple[int, ...]
    b: tuple[int, ...]
    axis: tuple[tuple[float, float, float], ...]
    spin: tuple[tuple[float, float, float], ...]
    labels: tuple[str, ...]
    names: tuple[str, ...] = ()

    def __len__(self) -> int:
        return len(self.a)

    @property
    def angle(self) -> np.ndarray:
        """Boolean mask of the angle drivers."""
        return np.asarray([any(v != 0.0 for v in k) for k in self.spin], dtype=bool)


@dataclasses.dataclass(frozen=True, eq=False)
class Topology:
    """Everything static about a mechanism (hashable; equal topologies share compiled code). The hash is computed
    once (the compile cache hashes it on every call)."""

    particle_names: tuple[str, ...]
    free: tuple[int, ...]  # global indices of the free particles, in state order
    ground: tuple[int, ...]  # global indices of the ground particles, in ``ground_xyz`` order
    body_names: tuple[str, ...]
    body_particles: tuple[tuple[int, ...], ...]  # primaries of each body (2, 3 or 4 global particle indices)
    point_names: tuple[str, ...]  # particles first (same order), then body points
    point_body: tuple[int, ...]  # -1 for particle points
    dot: DotRows
    linear: LinearRows
    spring_names: tuple[str, ...]
    spring_points: tuple[tuple[int, int], ...]
    tyre_names: tuple[str, ...]
    tyre_points: tuple[int, ...]
    tyre_normals: tuple[tuple[float, float, float], ...]
    tyre_apply: tuple[int, ...] = ()  # the point each tyre's force acts on (its measuring point unless given)
    saddle_point: bool = False  # the mass matrix is singular (a free particle in no body): solve the full KKT
    least_squares: bool = False  # minimum-norm (damped, refined) multipliers: redundant rows, singular positions
    planar: bool = False  # built as a planar mechanism (x-y plane, every free particle held in it)
    rotational_names: tuple[str, ...] = ()  # rotational spring-dampers (planar mechanisms)
    rotational_bodies: tuple[tuple[int, int], ...] = ()  # (body a, body b); -1: the ground
    drive: DriveRows = DriveRows((), (), (), (), (), ())  # driving constraints (rows after the linear rows)
    tyre_road_args: tuple[int, ...] = ()  # per tyre: 0 a plane, 1 a road ground(t), 2 ground(t, p); () no road
    spring_force_knots: tuple = ()  # per spring: its force curve's elongations (() linear); () when none has one
    spring_damping_knots: tuple = ()  # per spring: its damping curve's rates (() linear); () when none has one
    bushing_names: tuple[str, ...] = ()  # bushings (:mod:`.elements`)
    bushing_bodies: tuple[tuple[int, int, int], ...] = ()  # (body a, body b, frame body); -1: the ground
    bushing_rotational: tuple[bool, ...] = ()  # whether each bushing also resists relative rotation
    torsion_names: tuple[str, ...] = ()  # spatial torsion springs (:mod:`.elements`)
    torsion_bodies: tuple[tuple[int, int], ...] = ()  # (body a, body b); -1: the ground
    bump_names: tuple[str, ...] = ()  # bump stops: one-sided springs between two points
    bump_points: tuple[tuple[int, int], ...] = ()
    bump_rebound: tuple[bool, ...] = ()  # False: engages in compression (shorter), True: in extension (longer)
    sparse: object = None  # the hub split of :mod:`.sparse` (a ``SparsePlan``), when one pays and holds at assembly

    def _key(self) -> tuple:
        return tuple(getattr(self, f.name) for f in dataclasses.fields(self))

    def __eq__(self, other) -> bool:
        return self is other or (isinstance(other, Topology) and hash(self) == hash(other)
                                 and self._key() == other._key())

    def __hash__(self) -> int:
        h = self.__dict__.get("_hash")
        if h is None:
            h = hash(self._key())
            object.__setattr__(self, "_hash", h)
        return h

    @property
    def n_particles(self) -> int:
        return len(self.particle_names)

    def body_kind(self, b: int) -> str:
        return {2: "rod", 3: "planar", 4: "spatial"}[len(self.body_particles[b])]

    def point_slots(self) -> np.ndarray:
        """``(K, 4)`` particles each point combines (particles: itself; body points: the body's primaries, padded
        by repeating the last one, whose weight is then zero)."""
        out = np.zeros((len(self.point_names), 4), dtype=int)
        for k, b in enumerate(self.point_body):
            if b < 0:
                out[k] = k
            else:
                prim = self.body_particles[b]
                out[k] = list(prim) + [prim[-1]] * (4 - len(prim))
        return out

    def free_column(self) -> np.ndarray:
        """For every particle its position in the free-particle list, ``-1`` for ground particles."""
        col = -np.ones(self.n_particles, dtype=int)
        col[np.asarray(self.free, dtype=int)] = np.arange(len(self.free))
        return col

    def row_labels(self) -> list[str]:
        return list(self.dot.labels) + list(self.linear.labels) + list(self.drive.labels)


class AppliedForce(eqx.Module):
    """A force ``fn(t, q, qd) -> (3,)`` (world) acting at point ``point`` (its index).

    Applied loads (this class, :class:`AppliedTorque`, :class:`BodyLoad`) are final classes: the force assembly
    dispatches on their type. ``fn`` is static: the same function object reuses compiled code; give it
    parameters by making it an ``equinox.Module`` (its array fields are then traced)."""

    name: str = eqx.field(static=True)
    point: int = eqx.field(static=True)
    fn: Callable


class AppliedTorque(eqx.Module):
    """A torque ``fn(t, q, qd) -> (3,)`` (world) acting on body ``body`` (its index; a spatial or planar body)."""

    name: str = eqx.field(static=True)
    body: int = eqx.field(static=True)
    fn: Callable


class BodyLoad(eqx.Module):
    """Loads from the named states of ``bodies`` (their indices): ``fn(t, BodyState) -> {body: (force, torque)}``,
    each force at that body's centre of mass, each torque on the body (world frame)."""

    name: str = eqx.field(static=True)
    bodies: tuple = eqx.field(static=True)
    fn: Callable


class BodyState(eqx.Module):
    """The states of named bodies handed to a body-load function (:meth:`~.builder.MechanismBuilder.body_load`),
    world frame, each a dict keyed by body name: ``position`` (centre of mass, (3,)), ``rotation`` ((3, 3), body to
    world), ``velocity`` (of the centre of mass) and ``angular_velocity`` ((3,); a rod has none about its line)."""

    position: dict
    rotation: dict
    velocity: dict
    angular_velocity: dict


def _lookup(names: tuple[str, ...], name: str, what: str, *, choices: str = "") -> int:
    """Index of ``name`` among ``names``; ``KeyError`` naming it (and listing them as ``choices`` when given)."""
    try:
        return names.index(name)
    except ValueError:
        raise KeyError(f"no {what} named {name!r}" + (f"; {choices}: {list(names)}" if choices else "")) from None


class Mechanism(eqx.Module):
    """A mechanism in particle coordinates; build it with :class:`~particlesim.mechanism.MechanismBuilder`."""

    # --- differentiable parameters ---
    body_mass: Float[Array, " B"]
    body_com: Float[Array, "B 3"]  # body frame
    body_inertia: Float[Array, "B 3 3"]  # about the CoM, body axes
    body_primaries: Float[Array, "B 4 3"]  # body-frame primaries (planar/rod: padded by repeating the last)
    point_local: Float[Array, "K 3"]  # body-frame position of body points (rows of particle points unused)
    ground_xyz: Float[Array, "G 3"]
    dot_kappa: Float[Array, " D"]  # constants of the dot rows
    spring_stiffness: Float[Array, " S"]
    spring_damping: Float[Array, " S"]
    spring_free_length: Float[Array, " S"]
    tyre_stiffness: Float[Array, " T"]
    tyre_damping: Float[Array, " T"]
    tyre_radius: Float[Array, " T"]
    tyre_ground: Float[Array, " T"]
    gravity: Float[Array, "3"]
    rotational_stiffness: Float[Array, " R"]
    rotational_damping: Float[Array, " R"]
    rotational_free_angle: Float[Array, " R"]
    applied: tuple  # AppliedForce, AppliedTorque, BodyLoad
    # --- static topology ---
    topo: Topology = eqx.field(static=True)
    # --- driving constraints (rows ``n(t).(p_a - p_b) - c(t)``, :class:`DriveRows`) ---
    drive_offset: Float[Array, " K"] = eqx.field(default_factory=lambda: jnp.zeros(0))
    drive_fns: tuple = ()  # f(t) -> scalar per driver (a function, or an equinox Module whose arrays are traced)
    tyre_roads: tuple = ()  # per tyre: None or its road function (``Topology.tyre_road_args``); () when none has one
    spring_force_curve: tuple = ()  # per spring: its force curve's tensions [N] (empty: linear); () when none
    spring_damping_curve: tuple = ()  # per spring: its damping curve's tensions [N] (empty: linear); () when none
    # --- bushings, torsion springs (:mod:`.elements`) and bump stops ---
    bushing_stiffness: Float[Array, "N 6"] = eqx.field(default_factory=lambda: jnp.zeros((0, 6)))  # x y z rx ry rz
    bushing_damping: Float[Array, "N 6"] = eqx.field(default_factory=lambda: jnp.zeros((0, 6)))
    bushing_local: Float[Array, "N 2 3"] = eqx.field(default_factory=lambda: jnp.zeros((0, 2, 3)))  # in a, b frames
    bushing_axes: Float[Array, "N 3 3"] = eqx.field(default_factory=lambda: jnp.zeros((0, 3, 3)))  # frame body's
    bushing_rest: Float[Array, "N 3 3"] = eqx.field(default_factory=lambda: jnp.zeros((0, 3, 3)))  # Ra^T Rb built
    torsion_stiffness: Float[Array, " N"] = eqx.field(default_factory=lambda: jnp.zeros(0))
    torsion_damping: Float[Array, " N"] = eqx.field(default_factory=lambda: jnp.zeros(0))
    torsion_free_angle: Float[Array, " N"] = eqx.field(default_factory=lambda: jnp.zeros(0))
    torsion_axis: Float[Array, "N 3"] = eqx.field(default_factory=lambda: jnp.zeros((0, 3)))  # in body a's frame
    torsion_rest: Float[Array, "N 3 3"] = eqx.field(default_factory=lambda: jnp.zeros((0, 3, 3)))
    bump_stiffness: Float[Array, " N"] = eqx.field(default_factory=lambda: jnp.zeros(0))
    bump_damping: Float[Array, " N"] = eqx.field(default_factory=lambda: jnp.zeros(0))
    bump_clearance: Float[Array, " N"] = eqx.field(default_factory=lambda: jnp.zeros(0))
    bump_length: Float[Array, " N"] = eqx.field(default_factory=lambda: jnp.zeros(0))  # the points' built distance

    # ---- sizes and names ----
    @property
    def particle_names(self) -> tuple[str, ...]:
        return self.topo.particle_names

    @property
    def free(self) -> tuple[int, ...]:
        return self.topo.free

    @property
    def ground(self) -> tuple[int, ...]:
        return self.topo.ground

    @property
    def n_free(self) -> int:
        return len(self.topo.free)

    @property
    def n_coords(self) -> int:
        return 3 * len(self.topo.free)

    @property
    def n_constraints(self) -> int:
        return len(self.topo.dot) + len(self.topo.linear) + len(self.topo.drive)

    def index(self, particle: str) -> int:
        return _lookup(self.topo.particle_names, particle, "particle")

    def free_slice(self, particle: str) -> slice:
        """The three entries of ``q`` holding ``particle``'s position."""
        k = self.topo.free.index(self.index(particle))
        return slice(3 * k, 3 * k + 3)

    def body_index(self, name: str) -> int:
        return _lookup(self.topo.body_names, name, "body", choices="bodies")

    def point_index(self, name: str) -> int:
        return _lookup(self.topo.point_names, name, "point")

    # ---- positions ----
    def all_positions(self, q: Float[Array, " 3F"]) -> Float[Array, "P 3"]:
        """Positions of every particle (free from ``q``, ground from ``ground_xyz``), in global index order."""
        out = jnp.zeros((self.topo.n_particles, 3), dtype=q.dtype)
        out = out.at[np.asarray(self.topo.free, dtype=int)].set(q.reshape(-1, 3))
        if self.topo.ground:
            out = out.at[np.asarray(self.topo.ground, dtype=int)].set(self.ground_xyz.astype(q.dtype))
        return out

    def point_positions(self, r: Float[Array, "P 3"]) -> Float[Array, "K 3"]:
        """World positions of all points (particles first, then body points) from all particle positions."""
        from .constraints import point_weights

        return jnp.einsum("kt,ktj->kj", point_weights(self), r[self.topo.point_slots()])

    def point_position(self, k: int, r: Float[Array, "P 3"]) -> Float[Array, "3"]:
        return self.point_positions(r)[k]

    # ---- masses ----
    def particle_masses(self, b: int) -> Float[Array, " n"]:
        """Masses of body ``b``'s equivalent particles (primaries then secondaries), solved from its inertia."""
        from ..particles import solve_particle_masses

        k = len(self.topo.body_particles[b])
        return solve_particle_masses(self.body_mass[b], self.body_com[b], self.body_inertia[b],
                                     self.body_primaries[b, :k])

    def total_mass(self) -> Float[Array, ""]:
        return jnp.sum(self.body_mass)

    # ---- parameters by name ----
    def with_params(self, *, body: dict | None = None, spring: dict | None = None, tyre: dict | None = None,
                    rotational: dict | None = None, bushing: dict | None = None, torsion: dict | None = None,
                    bump: dict | None = None, gravity=None) -> "Mechanism":
        """A copy with parameters replaced by name (values may be traced: one compiled rollout serves all).

        ``body={"wheel": {"mass": 20.0, "com": ..., "inertia": ...}}``, ``spring={"suspension": {"stiffness": ...,
        "damping": ..., "free_length": ...}}``, ``tyre={"tyre": {"stiffness": ..., "damping": ..., "radius": ...,
        "ground": ...}}``, ``rotational={"torsion bar": {"stiffness": ..., "damping": ..., "free_angle": ...}}``,
        ``bushing={"front bush": {"stiffness": (6,), "damping": (6,)}}`` (x, y, z then rotations about x, y, z, in
        the bushing's axes), ``torsion={"anti-roll bar": {"stiffness": ..., "damping": ..., "free_angle": ...}}``,
        ``bump={"bump stop FL": {"stiffness": ..., "damping": ..., "clearance": ...}}``, ``gravity=(0, 0, -9.81)``. Unknown names or fields raise ``KeyError``. A value of the wrong shape raises
        :class:`~particlesim.errors.ModelError` naming it; concrete values are checked as the builder checks them
        (a body's mass, centre of mass and inertia by :func:`~particlesim.inertia.check_inertia`; stiffness, damping,
        lengths and radii finite and non-negative); traced ones are checked by the simulation when it runs
        (:func:`~.integrate.physical_checks`: non-finite or non-physical values raise, naming the body or element).
        A spring's tables: ``spring={"main": {"force_curve": f, "damping_curve": g}}``, the values at the table's
        abscissae (same length). Each field is replaced alone: a new ``mass`` keeps the body's inertia tensor about
        its centre of mass, so for
        a body that scales with its mass (a uniform rod made heavier) pass ``"inertia": scale *
        mech.body_inertia[mech.body_index(name)]`` with it."""
        new = {}

        def put(field: str, i: int, value, label: str):
            arr = new.get(field, getattr(self, field))
            if np.shape(value) != arr.shape[1:]:
                raise ModelError(f"with_params: {label} must have shape {arr.shape[1:]}, got {np.shape(value)}")
            value = jnp.asarray(value, dtype=arr.dtype)
            kind, name = field.split("_", 1)
            if name in NON_NEGATIVE.get(kind, ()) and _is_concrete(value) \
                    and not (np.all(np.isfinite(np.asarray(value))) and np.all(np.asarray(value) >= 0.0)):
                raise ModelError(f"with_params: {label} must be finite and non-negative, got "
                                 f"{np.asarray(value).tolist()!r}")
            new[field] = arr.at[i].set(value)

        spring = dict(spring or {})
        for name, entries in list(spring.items()):  # the tables: one array per spring
            entries = dict(entries)
            for kind in ("force", "damping"):
                if f"{kind}_curve" not in entries:
                    continue
                value = entries.pop(f"{kind}_curve")
                if name not in self.topo.spring_names:
                    raise KeyError(f"no spring named {name!r}; springs: {list(self.topo.spring_names)}")
                i = self.topo.spring_names.index(name)
                field = f"spring_{kind}_curve"
                tables = list(new.get(field, getattr(self, field)))
                if not tables or tables[i].size == 0:
                    raise ModelError(f"with_params: spring {name!r} has no {kind} curve (it is linear)")
                if np.shape(value) != tables[i].shape:
                    raise ModelError(f"with_params: spring {name!r} {kind} curve must have shape {tables[i].shape}, "
                                     f"got {np.shape(value)}")
                tables[i] = jnp.asarray(value, dtype=tables[i].dtype)
                new[field] = tuple(tables)
            spring[name] = entries
        given = {"spring": spring, "tyre": tyre, "rotational": rotational, "bushing": bushing, "torsion": torsion,
                 "bump": bump}
        groups = ((body, "body", self.topo.body_names, ("mass", "com", "inertia")),
                  *((given[k], k, getattr(self.topo, f"{k}_names"), f) for k, f in ELEMENT_FIELDS.items()))
        for values, prefix, names, fields in groups:
            for name, entries in (values or {}).items():
                if name not in names:
                    raise KeyError(f"no {prefix} named {name!r}; {prefix}s: {list(names)}")
                for field, value in entries.items():
                    if field not in fields:
                        raise KeyError(f"{prefix} {name!r} has no parameter {field!r}; choose from {list(fields)}")
                    put(f"{prefix}_{field}", names.index(name), value, f"{prefix} {name!r} {field.replace('_', ' ')}")
        for name in body or {}:  # the body's mass distribution as a whole, as the builder checks it (concrete only)
            b = self.topo.body_names.index(name)
            check_inertia(*(new.get(f, getattr(self, f))[b] for f in ("body_mass", "body_com", "body_inertia")),
                          f"with_params: body {name!r}", degenerate_ok=True)
        if gravity is not None:
            new["gravity"] = jnp.asarray(gravity, dtype=float)
        return eqx.tree_at(lambda m: [getattr(m, f) for f in new], self, list(new.values()))

    def parameter_label(self, path) -> str:
        """Readable name of a floating leaf from its pytree path, e.g. ``spring 'suspension' stiffness``."""
        keys = [getattr(k, "name", getattr(k, "idx", getattr(k, "key", None))) for k in path]
        head = keys[0]
        for prefix, names in (("body", self.topo.body_names),
                              *((k, getattr(self.topo, f"{k}_names")) for k in ELEMENT_FIELDS)):
            if isinstance(head, str) and head.startswith(prefix + "_"):
                field = head.removeprefix(prefix + "_")
                if len(names) == 1:
                    return f"{prefix} '{names[0]}' {field}"
                return f"{prefix}s' {field} ({', '.join(repr(n) for n in names)})"
        return str(head)
