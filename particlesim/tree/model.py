"""The tree model: rigid links joined by revolute and prismatic joints (fixed joints merged away).

Each moving link ``i`` has exactly one joint ``i`` connecting it to its parent link ``parents[i]`` (``-1`` is the
world). Joint ``i`` places the child link frame in the parent link frame as

    ``T_parent_child(q_i) = (R0_i, p0_i) o joint_motion(axis_i, q_i)``

(URDF convention; the report's ``^iT_j`` of Zafar §2.1), where ``joint_motion`` is a rotation by ``q_i`` about
``axis_i`` (revolute) or a translation ``axis_i q_i`` (prismatic), ``axis_i`` given in the child frame (the
report's ``^je_j``).

Static (topology, in the treedef): names, ``parents``, ``kinds``, ``axes``, ``origin_rotations`` (``R0_i``).
Differentiable ``jax.Array`` leaves:

* ``inertia``  ``(n, 10)``: per link ``[m, m cx, m cy, m cz, XX, XY, XZ, YY, YZ, ZZ]``, inertia about the link frame
  origin, in link axes (Zafar §5.1, eq. 11 uses ``J_j`` about the origin);
* ``origin_xyz`` ``(n, 3)``: ``p0_i``, the joint origin in the parent frame (geometric lengths, e.g. L1..L9);
* ``gravity`` ``(3,)`` in the world frame;
* optional per-coordinate ``viscous`` (``Fv``), ``coulomb`` (``Fc``) (eq. 17) and ``rotor_inertia``
  (``I_a = N^2 J_m``, eq. 18). ``None`` means absent: the code path is skipped at trace time and costs nothing.

Mimic joints (URDF ``<mimic>``, Pinocchio's ``mimic=True``): joint ``i`` may follow another joint ``s`` as
``q_i = multiplier * q_s + offset``. It then has no coordinate of its own: the model's coordinates ``q`` (length
``nq``) are those of the independent joints in joint order (``coordinate_names``), and every function maps them to
the ``n_joints`` joint values with the constant affine map ``q_joint = G q + offset`` and projects joint torques back
with ``G^T`` (so ``A = G^T A_joint G``: an exact reduction, not a constraint).

Batches of parameter sets: build models with the same topology, stack them with
``jax.tree.map(lambda *x: jnp.stack(x), *models)`` and map with ``jax.vmap(f, in_axes=(0, None, ...))``.
"""

from __future__ import annotations

from typing import Optional, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ..errors import InertiaError, ModelError
from ..inertia import check_inertia

__all__ = ["TreeModel", "REVOLUTE", "PRISMATIC", "JOINT_KINDS"]

REVOLUTE = "revolute"
PRISMATIC = "prismatic"
JOINT_KINDS = (REVOLUTE, PRISMATIC)


def _concrete(x) -> bool:
    return not isinstance(x, jax.core.Tracer)


def _vec_param(x, n, name, joint_names) -> Optional[Array]:
    if x is None:
        return None
    a = jnp.asarray(x, dtype=float)
    if a.shape == ():
        a = jnp.full((n,), a)
    if a.shape != (n,):
        raise ModelError(f"{name} must have shape ({n},) (one per joint), got {a.shape}")
    if _concrete(a):
        bad = ~np.isfinite(np.asarray(a))
        if bad.any():
            raise ModelError(f"{name} of joint '{joint_names[int(np.argmax(bad))]}' is NaN or inf")
        neg = np.asarray(a) < 0
        if neg.any():
            i = int(np.argmax(neg))
            raise ModelError(f"{name} of joint '{joint_names[i]}' is negative ({float(np.asarray(a)[i])!r}): it would "
                             "feed energy in; friction levels and rotor inertias are non-negative")
    return a


def origin_params_check(params, name: str) -> None:
    """Raise :class:`InertiaError` naming ``name`` unless the 10-vector (about the origin) is a physical body or
    exactly zero (a massless link, e.g. between the revolutes that make up a spherical joint)."""
    p = np.asarray(params, dtype=float)
    if not np.all(np.isfinite(p)):
        raise InertiaError(f"{name}: inertial parameters contain NaN or inf: {p.tolist()}")
    if not np.any(p):
        return
    m = p[0]
    if not m > 0:
        raise InertiaError(f"{name}: mass must be positive, got {m!r}")
    c = p[1:4] / m
    j = np.array([[p[4], p[5], p[6]], [p[5], p[7], p[8]], [p[6], p[8], p[9]]])
    i_com = j - m * (c @ c * np.eye(3) - np.outer(c, c))
    check_inertia(m, c, i_com, name, degenerate_ok=True)


class TreeModel(eqx.Module):
    """A tree of rigid links and 1-DOF joints (see module docstring). ``nq == number of links == joints``."""

    inertia: Float[Array, "n 10"]
    origin_xyz: Float[Array, "n 3"]
    gravity: Float[Array, "3"]
    viscous: Optional[Float[Array, " n"]]
    coulomb: Optional[Float[Array, " n"]]
    rotor_inertia: Optional[Float[Array, " n"]]
    link_names: tuple = eqx.field(static=True)
    joint_names: tuple = eqx.field(static=True)
    parents: tuple = eqx.field(static=True)
    kinds: tuple = eqx.field(static=True)
    axes: tuple = eqx.field(static=True)
    origin_rotations: tuple = eqx.field(static=True)
    frames: tuple = eqx.field(static=True)  # (name, owner link or -1, rotation (9,), translation (3,)) per frame
    mimic: tuple = eqx.field(static=True)  # per joint: () or (source joint index, multiplier, offset)

    def __init__(
        self,
        *,
        parents: Sequence[int],
        kinds: Sequence[str],
        axes: ArrayLike,
        origin_rotations: ArrayLike,
        origin_xyz: ArrayLike,
        inertia: ArrayLike,
        gravity: ArrayLike = (0.0, 0.0, -9.81),
        link_names: Optional[Sequence[str]] = None,
        joint_names: Optional[Sequence[str]] = None,
        viscous: Optional[ArrayLike] = None,
        coulomb: Optional[ArrayLike] = None,
        rotor_inertia: Optional[ArrayLike] = None,
        frames: Optional[Sequence] = None,
        mimic: Optional[dict] = None,
        validate_inertia: bool = True,
    ):
        n = len(parents)
        link_names = tuple(link_names) if link_names is not None else tuple(f"link{i}" for i in range(n))
        joint_names = tuple(joint_names) if joint_names is not None else tuple(f"joint{i}" for i in range(n))
        if len(link_names) != n or len(joint_names) != n:
            raise ModelError(f"need {n} link and joint names, got {len(link_names)} and {len(joint_names)}")
        for what, names in (("joint", joint_names), ("link", link_names)):
            dup = [x for i, x in enumerate(names) if x in names[:i]]
            if dup:
                raise ModelError(f"{what} name '{dup[0]}' is used twice")
        parents = tuple(int(p) for p in parents)
        for i, p in enumerate(parents):
            if not -1 <= p < n or p == i:
                raise ModelError(f"joint '{joint_names[i]}': parent index {p} is not a link of this model")
        _topological_order(parents, joint_names)  # raises on cycles
        kinds = tuple(kinds)
        if len(kinds) != n:
            raise ModelError(f"need {n} joint kinds, got {len(kinds)}")
        for i, k in enumerate(kinds):
            if k not in JOINT_KINDS:
                raise ModelError(f"joint '{joint_names[i]}': unknown joint kind {k!r} (expected one of {JOINT_KINDS})")
        ax = np.asarray(axes, dtype=float)
        if ax.shape != (n, 3):
            raise ModelError(f"axes must have shape ({n}, 3), got {ax.shape}")
        norms = np.linalg.norm(ax, axis=1)
        for i in range(n):
            if not (np.isfinite(norms[i]) and abs(norms[i] - 1.0) < 1e-9):
                raise ModelError(f"joint '{joint_names[i]}': axis {ax[i].tolist()} is not a unit vector")
        rot = np.asarray(origin_rotations, dtype=float)
        if rot.shape != (n, 3, 3):
            raise ModelError(f"origin_rotations must have shape ({n}, 3, 3), got {rot.shape}")
        for i in range(n):
            r = rot[i]
            if not (np.all(np.isfinite(r)) and np.allclose(r.T @ r, np.eye(3), atol=1e-9)
                    and np.linalg.det(r) > 0):
                raise ModelError(f"joint '{joint_names[i]}': origin rotation is not a proper rotation matrix")
        xyz = jnp.asarray(origin_xyz, dtype=float)
        if xyz.shape != (n, 3):
            raise ModelError(f"origin_xyz must have shape ({n}, 3), got {xyz.shape}")
        inr = jnp.asarray(inertia, dtype=float)
        if inr.shape != (n, 10):
            raise ModelError(f"inertia must have shape ({n}, 10), got {inr.shape}")
        g = jnp.asarray(gravity, dtype=float)
        if g.shape != (3,):
            raise ModelError(f"gravity must have shape (3,), got {g.shape}")
        if _concrete(xyz):
            bad = ~np.all(np.isfinite(np.asarray(xyz)), axis=1)
            if bad.any():
                raise ModelError(f"joint '{joint_names[int(np.argmax(bad))]}': origin_xyz is NaN or inf")
        if _concrete(g) and not np.all(np.isfinite(np.asarray(g))):
            raise ModelError(f"gravity is NaN or inf: {np.asarray(g).tolist()}")
        if _concrete(inr):
            if validate_inertia:
                for i in range(n):
                    origin_params_check(np.asarray(inr[i]), f"link '{link_names[i]}'")
            sub = _support(parents).T @ np.asarray(inr[:, 0])  # mass moved by each joint
            for i in range(n):
                if not sub[i] > 0:
                    raise InertiaError(f"joint '{joint_names[i]}' moves no mass (link '{link_names[i]}' and every "
                                       "link after it are massless): the mass matrix would be singular")
        self.mimic = _mimic(mimic or {}, joint_names)
        coords = tuple(joint_names[i] for i in range(n) if not self.mimic[i])
        self.inertia = inr
        self.origin_xyz = xyz
        self.gravity = g
        self.viscous = _vec_param(viscous, len(coords), "viscous friction", coords)
        self.coulomb = _vec_param(coulomb, len(coords), "Coulomb friction", coords)
        self.rotor_inertia = _vec_param(rotor_inertia, len(coords), "rotor inertia", coords)
        self.link_names = link_names
        self.joint_names = joint_names
        self.parents = parents
        self.kinds = kinds
        self.axes = tuple(tuple(float(v) for v in a) for a in ax)
        self.origin_rotations = tuple(tuple(float(v) for v in r.ravel()) for r in rot)
        self.frames = _frames(frames or (), link_names, n)

    # ---- static views (numpy, computed at trace time) ----
    @property
    def n_joints(self) -> int:
        """Number of links = joints (mimic joints included)."""
        return len(self.parents)

    @property
    def nq(self) -> int:
        """Number of coordinates (joints that do not mimic another)."""
        return sum(1 for m in self.mimic if not m)

    @property
    def coordinate_names(self) -> tuple:
        """Names of the joints that own a coordinate, in the order of ``q``."""
        return tuple(name for name, m in zip(self.joint_names, self.mimic) if not m)

    @property
    def coordinate_map(self) -> tuple[np.ndarray, np.ndarray]:
        """``(G (n_joints, nq), offset (n_joints,))`` with joint values ``G q + offset``."""
        col = np.cumsum([not m for m in self.mimic]) - 1
        g, off = np.zeros((self.n_joints, self.nq)), np.zeros(self.n_joints)
        for i, m in enumerate(self.mimic):
            if m:
                g[i, col[m[0]]], off[i] = m[1], m[2]
            else:
                g[i, col[i]] = 1.0
        return g, off

    def joint_values(self, q, *, offset: bool = True):
        """Joint positions (``offset=True``) or velocities/accelerations (``False``) from coordinates ``q``."""
        if not any(self.mimic):
            return q
        g, off = self.coordinate_map
        out = jnp.asarray(g) @ q
        return out + jnp.asarray(off) if offset else out

    def coordinate_forces(self, tau):
        """Joint forces/torques ``(n_joints,)`` projected onto the coordinates, ``G^T tau``."""
        if not any(self.mimic):
            return tau
        return jnp.asarray(self.coordinate_map[0]).T @ tau

    def coordinate_matrix(self, a):
        """A joint-space matrix ``(n_joints, n_joints)`` reduced to the coordinates, ``G^T A G``."""
        if not any(self.mimic):
            return a
        g = jnp.asarray(self.coordinate_map[0])
        return g.T @ a @ g

    @property
    def axes_array(self) -> np.ndarray:
        """``(n, 3)`` joint axes in the child link frames."""
        return np.asarray(self.axes, dtype=float).reshape(self.n_joints, 3)

    @property
    def origin_rotation_array(self) -> np.ndarray:
        """``(n, 3, 3)`` constant rotations ``R0_i`` of the joint frames in the parent frames."""
        return np.asarray(self.origin_rotations, dtype=float).reshape(self.n_joints, 3, 3)

    @property
    def is_revolute(self) -> np.ndarray:
        return np.array([k == REVOLUTE for k in self.kinds], dtype=bool)

    @property
    def topological_order(self) -> tuple:
        """Link indices ordered parents first."""
        return _topological_order(self.parents, self.joint_names)

    @property
    def support(self) -> np.ndarray:
        """``(n, n)`` static mask: ``support[j, k]`` is True iff joint ``k`` moves link ``j`` (k is j or an ancestor)."""
        return _support(self.parents)

    def link_index(self, link) -> int:
        """Index of ``link`` given by index or by link name (or by the name of its joint)."""
        if isinstance(link, (int, np.integer)):
            if not 0 <= int(link) < self.n_joints:
                raise ModelError(f"link index {link} out of range for a model with {self.n_joints} links")
            return int(link)
        if link in self.link_names:
            return self.link_names.index(link)
        if link in self.joint_names:
            return self.joint_names.index(link)
        frames = [f[0] for f in self.frames]
        more = f" and frames {frames}" if frames else ""
        raise ModelError(f"unknown link {link!r}; links are {list(self.link_names)}{more}")

    def frame(self, name) -> tuple | None:
        """``(owner, R, p)`` of a frame fixed to a link (``owner`` -1: the world), or None if ``name`` is not one."""
        for f in self.frames:
            if f[0] == name:
                return f[1], np.asarray(f[2]).reshape(3, 3), np.asarray(f[3])
        return None

    def with_params(self, **changes) -> "TreeModel":
        """A copy with some array leaves replaced (``inertia=``, ``origin_xyz=``, ``gravity=``, ...), unchecked."""
        leaves = ("inertia", "origin_xyz", "gravity", "viscous", "coulomb", "rotor_inertia")
        for k in changes:
            if k not in leaves:
                raise ModelError(f"with_params: {k!r} is not a parameter leaf (one of {leaves})")
        names = list(changes)
        return eqx.tree_at(lambda m: [getattr(m, k) for k in names], self,
                           [jnp.asarray(changes[k], dtype=float) for k in names], is_leaf=lambda x: x is None)


def _support(parents) -> np.ndarray:
    n = len(parents)
    s = np.zeros((n, n), dtype=bool)
    for j in range(n):
        k = j
        while k >= 0:
            s[j, k] = True
            k = parents[k]
    return s


def _mimic(mimic: dict, joint_names) -> tuple:
    """Validated mimic map ``{joint: (source joint, multiplier, offset)}`` -> per joint ``()`` or
    ``(source index, multiplier, offset)``; chains (a mimic of a mimic) are composed down to their source."""
    if not isinstance(mimic, dict):
        raise ModelError("mimic must be a dict {joint name: (source joint name, multiplier, offset)}")
    raw = {}
    for name, spec in mimic.items():
        if name not in joint_names:
            raise ModelError(f"mimic: unknown joint {name!r}; joints are {list(joint_names)}")
        try:
            src, mult, off = spec
            mult, off = float(mult), float(off)
        except (TypeError, ValueError):
            raise ModelError(f"mimic joint '{name}': expected (source joint, multiplier, offset), got {spec!r}") from None
        if src not in joint_names:
            raise ModelError(f"mimic joint '{name}' follows unknown joint {src!r}")
        if src == name:
            raise ModelError(f"mimic joint '{name}' follows itself")
        if not (np.isfinite(mult) and np.isfinite(off)):
            raise ModelError(f"mimic joint '{name}': multiplier and offset must be finite, got {mult!r}, {off!r}")
        raw[name] = (src, mult, off)
    out = []
    for i, name in enumerate(joint_names):
        if name not in raw:
            out.append(())
            continue
        src, mult, off, seen = *raw[name], {name}
        while src in raw:  # compose q = m1 (m2 q_s + o2) + o1
            if src in seen:
                raise ModelError(f"mimic joints {sorted(seen)} follow each other in a cycle")
            seen.add(src)
            s2, m2, o2 = raw[src]
            src, mult, off = s2, mult * m2, mult * o2 + off
        out.append((joint_names.index(src), mult, off))
    return tuple(out)


def _frames(frames, link_names, n) -> tuple:
    """Validated frames fixed to links: ``(name, owner, R, p)`` with ``owner`` a link index or -1 (the world)."""
    out, seen = [], set(link_names)
    for name, owner, r, p in frames:
        if name in seen:
            raise ModelError(f"frame '{name}' is defined twice (or shares a link's name)")
        seen.add(name)
        if not -1 <= int(owner) < n:
            raise ModelError(f"frame '{name}': owner link {owner} is not a link of this model")
        r, p = np.asarray(r, dtype=float).reshape(3, 3), np.asarray(p, dtype=float).reshape(3)
        if not (np.all(np.isfinite(r)) and np.all(np.isfinite(p))) or np.abs(r @ r.T - np.eye(3)).max() > 1e-9:
            raise ModelError(f"frame '{name}': pose is not finite or not a rotation")
        out.append((str(name), int(owner), tuple(float(v) for v in r.ravel()), tuple(float(v) for v in p)))
    return tuple(out)


def _topological_order(parents, joint_names) -> tuple:
    n = len(parents)
    order, placed = [], [False] * n
    for _ in range(n):
        progressed = False
        for i in range(n):
            if not placed[i] and (parents[i] < 0 or placed[parents[i]]):
                placed[i] = True
                order.append(i)
                progressed = True
        if len(order) == n:
            break
        if not progressed:
            stuck = [joint_names[i] for i in range(n) if not placed[i]]
            raise ModelError(f"joints {stuck} form a kinematic loop (no path to the world)")
    return tuple(order)
