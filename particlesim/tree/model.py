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
  (``I_a = N^2 J_m``, eq. 18), and joint springs ``stiffness`` (per velocity coordinate) about ``spring_ref`` (a
  configuration, default the zero one), as MuJoCo's joint ``stiffness``/``springref``, and optional soft joint
  ``limits`` ``(nv, 4)``: per velocity coordinate ``[lower, upper, stiffness, damping]``, a one-sided
  spring-damper that acts only beyond a bound (``-inf``/``inf`` for none; hinges and slides only). ``None`` means
  absent: the code path is skipped at trace time and costs nothing.

Mimic joints (URDF ``<mimic>``, Pinocchio's ``mimic=True``): joint ``i`` may follow another joint ``s`` as
``q_i = multiplier * q_s + offset``. It then has no coordinate of its own: the model's coordinates ``q`` (length
``nq``) are those of the independent joints in joint order (``coordinate_names``), and every function maps them to
the ``n_joints`` joint values with the constant affine map ``q_joint = G q + offset`` and projects joint torques back
with ``G^T`` (so ``A = G^T A_joint G``: an exact reduction, not a constraint).

Batches of parameter sets: build models with the same topology, stack them with
``jax.tree.map(lambda *x: jnp.stack(x), *models)`` and map with ``jax.vmap(f, in_axes=(0, None, ...))``.
"""

from __future__ import annotations

import functools
from typing import Optional, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ..errors import InertiaError, ModelError
from ..inertia import check_inertia, com_params, origin_params, unpack_params
from ..spatial import quaternion_to_matrix

__all__ = ["TreeModel", "REVOLUTE", "PRISMATIC", "FREE", "BALL", "JOINT_KINDS"]

REVOLUTE = "revolute"
PRISMATIC = "prismatic"
#: A free-flyer (floating base) root joint, as Pinocchio's ``JointModelFreeFlyer``: configuration
#: ``[x, y, z, qx, qy, qz, qw]`` (position of the link origin in its parent frame, unit quaternion), velocity
#: ``[v, w]`` (linear velocity of the origin and angular velocity, both in the link's own axes).
FREE = "free"
#: A spherical joint, as Pinocchio's ``JointModelSpherical`` and MuJoCo's ``ball``: configuration a unit quaternion
#: ``[qx, qy, qz, qw]`` (rotation of the child frame after its placement), velocity ``w`` in the child's axes.
BALL = "ball"
JOINT_KINDS = (REVOLUTE, PRISMATIC, FREE, BALL)
_NQ = {FREE: 7, BALL: 4}
_NV = {FREE: 6, BALL: 3}
#: Rate (1/s) at which a free joint's quaternion norm is drawn back to 1 during integration (see
#: ``TreeModel.configuration_rate``); slow beside any step an integrator takes, so it adds no stiffness.
QUATERNION_GAIN = 1.0
#: Names of the six velocity coordinates of a free joint, in order.
FREE_VELOCITY = ("vx", "vy", "vz", "wx", "wy", "wz")


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
    m, _, j = unpack_params(p)
    if not m > 0:
        raise InertiaError(f"{name}: mass must be positive, got {float(m)!r}")
    m, c, i_com = com_params(p)
    # the shift to the centre of mass cancels terms of size |J| + m |c|^2: allow its rounding (a point-like link far
    # from its joint is otherwise judged on round-off, e.g. iCub's 1.3 kg shank with a 1e-18 tensor)
    rounding = 16 * np.finfo(float).eps * (abs(float(np.trace(j))) + m * float(c @ c))
    check_inertia(m, c, i_com, name, degenerate_ok=True, atol=rounding)


class TreeModel(eqx.Module):
    """A tree of rigid links and 1-DOF joints (see module docstring). ``nq == number of links == joints``."""

    inertia: Float[Array, "n 10"]
    origin_xyz: Float[Array, "n 3"]
    gravity: Float[Array, "3"]
    viscous: Optional[Float[Array, " n"]]
    coulomb: Optional[Float[Array, " n"]]
    rotor_inertia: Optional[Float[Array, " n"]]
    stiffness: Optional[Float[Array, " nv"]]
    spring_ref: Optional[Float[Array, " nq"]]
    limits: Optional[Float[Array, "nv 4"]]
    link_names: tuple = eqx.field(static=True)
    joint_names: tuple = eqx.field(static=True)
    parents: tuple = eqx.field(static=True)
    kinds: tuple = eqx.field(static=True)
    axes: tuple = eqx.field(static=True)
    origin_rotations: tuple = eqx.field(static=True)
    frames: tuple = eqx.field(static=True)  # (name, owner link or -1, rotation (9,), translation (3,)) per frame
    mimic: tuple = eqx.field(static=True)  # per joint: () or (source joint index, multiplier, offset)
    #: Whether the links' inertias were checked when built (False for ``load_urdf(..., inertia="warn")``, which keeps
    #: non-physical tensors on purpose): :func:`~.checks.physical_checks` then leaves them alone.
    inertia_checked: bool = eqx.field(static=True, default=True)

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
        stiffness: Optional[ArrayLike] = None,
        spring_ref: Optional[ArrayLike] = None,
        limits: Optional[ArrayLike] = None,
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
            if k == FREE and parents[i] != -1:
                raise ModelError(f"joint '{joint_names[i]}': a free joint must join a root link to the world")
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
        for i, m in enumerate(self.mimic):
            if m and ({kinds[i], kinds[m[0]]} & {FREE, BALL}):
                raise ModelError(f"mimic joint '{joint_names[i]}': free and ball joints neither mimic nor are "
                                 "mimicked")
        coords = tuple(_velocity_names(joint_names, kinds, self.mimic))
        self.inertia = inr
        self.origin_xyz = xyz
        self.gravity = g
        self.viscous = _vec_param(viscous, len(coords), "viscous friction", coords)
        self.coulomb = _vec_param(coulomb, len(coords), "Coulomb friction", coords)
        self.rotor_inertia = _vec_param(rotor_inertia, len(coords), "rotor inertia", coords)
        self.stiffness = _vec_param(stiffness, len(coords), "joint stiffness", coords)
        self.spring_ref = None
        if self.stiffness is not None:
            if _concrete(self.stiffness):
                at = 0
                for i, k in enumerate(kinds):
                    if self.mimic[i]:
                        continue
                    if k == FREE and np.any(np.asarray(self.stiffness[at:at + 6])):
                        raise ModelError(f"joint '{joint_names[i]}': springs on free joints are not modelled")
                    at += _NV.get(k, 1)
            nq = _sizes(kinds, self.mimic)[0]
            if spring_ref is None:  # the zero configuration: angles 0, identity quaternions
                spring_ref = np.concatenate([[0.0, 0.0, 0.0, 1.0] if k == BALL else [0.0] * _NQ.get(k, 1)
                                             for k, m in zip(kinds, self.mimic) if not m])
            ref = jnp.asarray(spring_ref, dtype=float)
            if ref.shape != (nq,):
                raise ModelError(f"spring_ref must be a configuration of shape ({nq},), got {ref.shape}")
            if _concrete(ref) and not np.all(np.isfinite(np.asarray(ref))):
                raise ModelError("spring_ref is NaN or inf")
            self.spring_ref = ref
        elif spring_ref is not None:
            raise ModelError("spring_ref given without stiffness")
        self.limits = None if limits is None else _limits(limits, coords, kinds, self.mimic)
        self.link_names = link_names
        self.joint_names = joint_names
        self.parents = parents
        self.kinds = kinds
        self.axes = tuple(tuple(float(v) for v in a) for a in ax)
        self.origin_rotations = tuple(tuple(float(v) for v in r.ravel()) for r in rot)
        self.frames = _frames(frames or (), link_names, n)
        self.inertia_checked = bool(validate_inertia)

    # ---- static views (numpy, computed at trace time) ----
    @property
    def n_joints(self) -> int:
        """Number of links = joints (mimic joints included)."""
        return len(self.parents)

    @property
    def joint_nq(self) -> tuple:
        """Configuration entries per joint (7 for a free joint, 4 for a ball joint, else 1)."""
        return tuple(_NQ.get(k, 1) for k in self.kinds)

    @property
    def joint_nv(self) -> tuple:
        """Velocity entries (degrees of freedom) per joint (6 for a free joint, 3 for a ball joint, else 1)."""
        return tuple(_NV.get(k, 1) for k in self.kinds)

    @property
    def floating(self) -> bool:
        """True if some root link is joined to the world by a free joint."""
        return FREE in self.kinds

    @property
    def multi_dof(self) -> bool:
        """True if some joint has several degrees of freedom (free or ball): the general per-dof layout is used."""
        return FREE in self.kinds or BALL in self.kinds

    @property
    def nq(self) -> int:
        """Length of the configuration ``q`` (joints that do not mimic another; 7 entries per free joint)."""
        return _sizes(self.kinds, self.mimic)[0]

    @property
    def nv(self) -> int:
        """Length of the velocity ``qd`` (and of ``qdd``, ``tau``; 6 entries per free joint). ``nq`` without a
        floating base."""
        return _sizes(self.kinds, self.mimic)[1]

    @property
    def coordinate_names(self) -> tuple:
        """Names of the joints that own a coordinate, in the order of ``q``."""
        return tuple(name for name, m in zip(self.joint_names, self.mimic) if not m)

    @property
    def velocity_names(self) -> tuple:
        """Names of the ``nv`` velocity coordinates (a free joint's as ``'root_joint:vx'`` ... ``':wz'``)."""
        return tuple(_velocity_names(self.joint_names, self.kinds, self.mimic))

    def _maps(self, sizes) -> tuple[np.ndarray, np.ndarray]:
        """``(G, offset)`` from coordinates to every joint's entries (``sizes`` per joint: ``joint_nq``/``nv``)."""
        own = [0 if m else k for k, m in zip(sizes, self.mimic)]
        col = np.concatenate([[0], np.cumsum(own)])
        row = np.concatenate([[0], np.cumsum(sizes)])
        g, off = np.zeros((row[-1], col[-1])), np.zeros(row[-1])
        for i, m in enumerate(self.mimic):
            if m:
                g[row[i], col[m[0]]], off[row[i]] = m[1], m[2]
            else:
                g[row[i]:row[i + 1], col[i]:col[i + 1]] = np.eye(sizes[i])
        return g, off

    @property
    def coordinate_map(self) -> tuple[np.ndarray, np.ndarray]:
        """``(G (n_dofs, nv), offset (n_joints,))``: joint velocities ``G qd``, and (without free joints) joint
        positions ``G q + offset``."""
        return self._maps(self.joint_nv)[0], self._maps(self.joint_nq)[1]

    def joint_values(self, q, *, offset: bool = True):
        """Every joint's configuration entries (``offset=True``, from ``q``) or velocity/acceleration entries
        (``offset=False``, from ``qd``/``qdd``): mimic joints filled in from their sources."""
        if not any(self.mimic):
            return q
        g, off = self._maps(self.joint_nq if offset else self.joint_nv)
        out = jnp.asarray(g) @ q
        return out + jnp.asarray(off) if offset else out

    def coordinate_forces(self, tau):
        """Forces/torques on every joint degree of freedom projected onto the coordinates, ``G^T tau``."""
        if not any(self.mimic):
            return tau
        return jnp.asarray(self._maps(self.joint_nv)[0]).T @ tau

    def coordinate_matrix(self, a):
        """A matrix over every joint degree of freedom reduced to the coordinates, ``G^T A G``."""
        if not any(self.mimic):
            return a
        g = jnp.asarray(self._maps(self.joint_nv)[0])
        return g.T @ a @ g

    def coordinate_blocks(self) -> tuple:
        """``(joint index, kind, q offset, qd offset)`` of every joint that owns coordinates, in order."""
        return _coordinate_blocks(self.kinds, self.mimic)

    def check_configuration(self, q) -> None:
        """Raise :class:`ModelError` naming the joint if a free or ball joint's quaternion in the concrete
        configuration ``q`` is not of unit length (a zero or drifted quaternion would give NaN or a scaled frame)."""
        if not _concrete(q) or not self.multi_dof:
            return
        slots, joints = _quaternion_slots(self.kinds, self.mimic)
        lengths = np.linalg.norm(np.asarray(q, dtype=float)[slots], axis=-1)
        for j, n in zip(joints, lengths):
            if not abs(n - 1.0) <= 1e-6:
                raise ModelError(f"joint '{self.joint_names[j]}': its quaternion [qx, qy, qz, qw] in q has length "
                                 f"{float(n)!r}; give a unit quaternion")

    def check_quaternions_nonzero(self, q) -> None:
        """Raise :class:`ModelError` naming the joint if a free or ball joint's quaternion in the concrete
        configuration(s) ``q`` (``(..., nq)``) is zero or not finite (:func:`check_quaternions_nonzero`)."""
        check_quaternions_nonzero(self, q)

    def configuration_rate(self, q, qd):
        """``dq/dt`` from the configuration ``q`` (nq) and velocity ``qd`` (nv): ``qd`` itself except on a free
        joint, whose position moves as ``R(quat) v`` and whose quaternion as ``1/2 quat * (w, 0)`` plus the
        restoring term ``QUATERNION_GAIN (1 - |quat|^2) quat``: the unit norm is an attracting invariant of the
        flow, so an integrator keeps it to its tolerance without renormalising the state after a step."""
        if not self.multi_dof:
            return qd
        parts = []
        for _, k, iq, iv in self.coordinate_blocks():
            if k in (FREE, BALL):
                quat = q[iq + 3:iq + 7] if k == FREE else q[iq:iq + 4]
                v, w = (qd[iv:iv + 3], qd[iv + 3:iv + 6]) if k == FREE else (None, qd[iv:iv + 3])
                vec, s = quat[:3], quat[3]
                dvec = 0.5 * (s * w + jnp.cross(vec, w))  # quat (x) [w, 0], vector part
                ds = -0.5 * jnp.dot(vec, w)
                restore = QUATERNION_GAIN * (1.0 - jnp.dot(quat, quat)) * quat
                lin = [quaternion_to_matrix(quat) @ v] if k == FREE else []
                parts += lin + [jnp.concatenate([dvec, ds[None]]) + restore]
            else:
                parts.append(qd[iv:iv + 1])
        return jnp.concatenate(parts)

    # ---- degrees of freedom: one per 1-DOF joint, six per free joint ----
    @property
    def dof_owner(self) -> np.ndarray:
        """``(n_dofs,)`` the link each joint degree of freedom moves (its axis is fixed in that link)."""
        return np.repeat(np.arange(self.n_joints), self.joint_nv)

    @property
    def dof_revolute(self) -> np.ndarray:
        """``(n_dofs,)`` True for rotational degrees of freedom (a free joint: 3 translations, then 3 rotations)."""
        out = []
        for k in self.kinds:
            out += [False] * 3 + [True] * 3 if k == FREE else [True] * 3 if k == BALL else [k == REVOLUTE]
        return np.array(out, dtype=bool)

    @property
    def dof_axes(self) -> np.ndarray:
        """``(n_dofs, 3)`` axis of each degree of freedom in its link's axes (a free joint: the link's own axes)."""
        ax = self.axes_array
        return np.concatenate([np.vstack([np.eye(3), np.eye(3)]) if k == FREE else np.eye(3) if k == BALL
                               else ax[i:i + 1]
                               for i, k in enumerate(self.kinds)], axis=0)

    @property
    def dof_support(self) -> np.ndarray:
        """``(n_links, n_dofs)`` static mask: degree of freedom ``k`` moves link ``j``."""
        return self.support[:, self.dof_owner]

    @property
    def dof_before(self) -> np.ndarray:
        """``(n_dofs, n_dofs)``: ``[k, i]`` iff dof ``k`` acts on dof ``i``'s link and comes first (a strict order
        on the ancestors, used for the lower triangle of the composite-inertia mass matrix)."""
        own = self.dof_owner
        anc = self.support[own][:, own].T  # [k, i]: owner(k) is an ancestor-or-self of owner(i)
        same = own[:, None] == own[None, :]
        idx = np.arange(len(own))
        return anc & (~same | (idx[:, None] <= idx[None, :]))

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

    def with_params(self, link: dict | None = None, **changes) -> "TreeModel":
        """A copy with some array leaves replaced (``inertia=``, ``origin_xyz=``, ``gravity=``, ...), and links'
        inertial parameters replaced by name: ``link={"lGripper": {"mass": 1.2, "com": (0.0, 0.0, 0.05), "inertia":
        i_com}}`` (in the link's frame; ``inertia`` the 3 x 3 tensor about the centre of mass). Each field is replaced
        alone: a new ``mass`` keeps the link's centre of mass and its inertia about it (so a link that scales with
        its mass needs ``inertia`` too). Values may be traced (one compiled program serves all); concrete link values
        are checked as a loaded model's are (:func:`~particlesim.inertia.check_inertia`: positive mass, a symmetric
        positive semi-definite tensor within the triangle inequalities), array leaves are not (every entry refuses
        non-finite ones). Unknown leaves, links or fields, and a leaf of another shape than the model's, raise
        :class:`ModelError`."""
        # the parameter leaves, each with one model's shape (behind leading axes of stacked models): per link, or per
        # velocity coordinate (nv: a free joint has six, a mimic joint none)
        n, nv = self.n_joints, self.nv
        shapes = {"inertia": (n, 10), "origin_xyz": (n, 3), "gravity": (3,), "viscous": (nv,), "coulomb": (nv,),
                  "rotor_inertia": (nv,), "stiffness": (nv,), "spring_ref": (self.nq,), "limits": (nv, 4)}
        for k, v in changes.items():
            if k not in shapes:
                raise ModelError(f"with_params: {k!r} is not a parameter leaf (one of {tuple(shapes)})")
            want = shapes[k]
            got = np.shape(v)  # static under a trace too
            if got[len(got) - len(want):] != want:
                raise ModelError(f"with_params: {k} must have shape {want} for this model (with any leading axes of "
                                 f"stacked models), got {got}")
        if link:
            changes["inertia"] = self._link_inertia(link, changes.get("inertia", self.inertia))
        names = list(changes)
        return eqx.tree_at(lambda m: [getattr(m, k) for k in names], self,
                           [jnp.asarray(changes[k], dtype=float) for k in names], is_leaf=lambda x: x is None)

    def _link_inertia(self, link: dict, inertia) -> Array:
        """``inertia`` (n, 10) with the rows of the links named in ``link`` rebuilt from their (partly replaced)
        mass, centre of mass and inertia about it (:meth:`with_params`)."""
        inertia = jnp.asarray(inertia, dtype=float)
        fields = ("mass", "com", "inertia")
        for name, given in link.items():
            k = self.link_index(name)
            if not isinstance(given, dict) or set(given) - set(fields):
                raise ModelError(f"with_params: link {name!r} takes a dict of {list(fields)}, got {given!r}")
            if set(given) == set(fields):
                m, c, i_com = (given[f] for f in fields)
            else:
                row = inertia[k]
                if _concrete(row) and float(row[0]) == 0.0:
                    raise ModelError(f"with_params: link {name!r} has no mass, so no centre of mass to keep: give "
                                     "its mass, com and inertia together")
                m, c, i_com = com_params(row)
                m, c, i_com = given.get("mass", m), given.get("com", c), given.get("inertia", i_com)
            check_inertia(m, c, i_com, f"with_params: link {name!r}", degenerate_ok=True)  # concrete values only
            m, c, i_com = (jnp.asarray(x, dtype=float) for x in (m, c, i_com))
            if m.shape != () or c.shape != (3,) or i_com.shape != (3, 3):  # traced values (checked above otherwise)
                raise ModelError(f"with_params: link {name!r}: mass must be a scalar, com (3,) and inertia (3, 3), "
                                 f"got {m.shape}, {c.shape} and {i_com.shape}")
            inertia = inertia.at[k].set(origin_params(m, c, i_com))
        return inertia


def _limits(limits, coords, kinds, mimic) -> Array:
    """Validated soft limits ``(nv, 4)``: ``[lower, upper, stiffness, damping]`` per velocity coordinate."""
    a = jnp.asarray(limits, dtype=float)
    if a.shape != (len(coords), 4):
        raise ModelError(f"limits must have shape ({len(coords)}, 4) ([lower, upper, stiffness, damping] per velocity "
                         f"coordinate), got {a.shape}")
    if _concrete(a):
        x = np.asarray(a)
        multi = np.concatenate([[k in (FREE, BALL)] * _NV.get(k, 1) for k, m in zip(kinds, mimic) if not m])
        for i, name in enumerate(coords):
            lo, hi, k, d = x[i]
            if np.isnan(x[i]).any() or not (np.isfinite(k) and np.isfinite(d)):
                raise ModelError(f"limits of '{name}': NaN, or an infinite stiffness or damping: {x[i].tolist()}")
            if k < 0 or d < 0 or lo > hi:
                raise ModelError(f"limits of '{name}': need lower <= upper and non-negative stiffness and damping, "
                                 f"got {x[i].tolist()}")
            if multi[i] and (np.isfinite(lo) or np.isfinite(hi)):
                raise ModelError(f"limits of '{name}': free and ball joints take no limits (use -inf, inf)")
    return a


def _velocity_names(joint_names, kinds, mimic):
    for name, k, m in zip(joint_names, kinds, mimic):
        if not m:
            yield from ([f"{name}:{c}" for c in FREE_VELOCITY] if k == FREE else
                        [f"{name}:{c}" for c in FREE_VELOCITY[3:]] if k == BALL else [name])


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


def check_quaternions_nonzero(model: "TreeModel", q) -> None:
    """Raise :class:`ModelError` naming the joint if a free or ball joint's quaternion in the concrete
    configuration(s) ``q`` (``(..., nq)``) is zero or not finite: the dynamics normalise a quaternion, so any other
    length is read as its direction, but a zero one has none (it would give NaN). Run before every call from
    Python, so kept cheap: a function rather than a method (looking a method up on an equinox module costs more than
    the check), the quaternions' positions in ``q`` found once per structure, the check one vectorised norm."""
    kinds = model.kinds
    if not (FREE in kinds or BALL in kinds) or not _concrete(q):
        return
    slots, joints = _quaternion_slots(kinds, model.mimic)
    n = np.linalg.norm(np.asarray(q, dtype=float)[..., slots], axis=-1)  # (..., quaternions)
    good = np.isfinite(n) & (n > 1e-12)
    if not good.all():
        first = joints[int(np.argmin(good.reshape(-1, len(joints)).all(axis=0)))]
        raise ModelError(f"joint '{model.joint_names[first]}': its quaternion [qx, qy, qz, qw] in q is zero or not "
                         "finite; give a unit quaternion ([0, 0, 0, 1] is the identity)")


@functools.lru_cache(maxsize=256)
def _coordinate_blocks(kinds: tuple, mimic: tuple) -> tuple:
    """:meth:`TreeModel.coordinate_blocks` of a structure (joint kinds and mimic flags)."""
    blocks, iq, iv = [], 0, 0
    for i, (k, m) in enumerate(zip(kinds, mimic)):
        if not m:
            blocks.append((i, k, iq, iv))
            iq, iv = iq + _NQ.get(k, 1), iv + _NV.get(k, 1)
    return tuple(blocks)


@functools.lru_cache(maxsize=256)
def _quaternion_slots(kinds: tuple, mimic: tuple) -> tuple[np.ndarray, tuple]:
    """Positions in ``q`` of every free or ball joint's quaternion (``(k, 4)``: a free joint's after its position)
    and those joints' indices."""
    quats = [(i, iq + 3 if k == FREE else iq) for i, k, iq, _ in _coordinate_blocks(kinds, mimic) if k in (FREE, BALL)]
    return (np.asarray([range(s, s + 4) for _, s in quats], dtype=np.intp).reshape(-1, 4),
            tuple(i for i, _ in quats))


@functools.lru_cache(maxsize=256)
def _sizes(kinds: tuple, mimic: tuple) -> tuple[int, int]:
    """``(nq, nv)`` of a model's joint kinds and mimic flags (read on every call of a public function: remembered)."""
    own = [k for k, m in zip(kinds, mimic) if not m]
    return sum(_NQ.get(k, 1) for k in own), sum(_NV.get(k, 1) for k in own)


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
