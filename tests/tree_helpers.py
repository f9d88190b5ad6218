"""Helpers for the tree tests: seeded random trees written as URDF strings, Pinocchio evaluation by joint name."""

from __future__ import annotations

import numpy as np

KRANG_URDFS = (
    "krang_fixed_wheel_2018-04.urdf",
    "krang_2018.urdf",
    "krang_fixed_base_2018.urdf",
    "krang_single_arm_2018.urdf",
)

DART_DOF_ORDER = ("JLWheel", "JWaist", "JTorso", "JKinect", "LJ1", "LJ2", "LJ3", "LJ4", "LJ5", "LJ6", "LJFT",
                  "RJ1", "RJ2", "RJ3", "RJ4", "RJ5", "RJ6", "RJFT")


def _fmt(v) -> str:
    return " ".join(f"{x:.17g}" for x in v)


def _random_rotation(rng) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q * np.linalg.det(q)


def _inertial(rng) -> str:
    m = rng.uniform(0.5, 3.0)
    com = rng.uniform(-0.2, 0.2, 3)
    # principal moments obeying the triangle inequality, then rotated axes
    a, b = rng.uniform(0.01, 0.1, 2)
    c = rng.uniform(abs(a - b) + 0.005, a + b - 0.005)
    rot = _random_rotation(rng)
    i = rot @ np.diag([a, b, c]) @ rot.T
    return (f'<inertial><mass value="{m:.17g}"/><origin xyz="{_fmt(com)}" rpy="{_fmt(rng.uniform(-1, 1, 3))}"/>'
            f'<inertia ixx="{i[0, 0]:.17g}" ixy="{i[0, 1]:.17g}" ixz="{i[0, 2]:.17g}" iyy="{i[1, 1]:.17g}" '
            f'iyz="{i[1, 2]:.17g}" izz="{i[2, 2]:.17g}"/></inertial>')


def random_tree_urdf(seed: int, n: int, *, prismatic: float = 0.3, fixed_extra: bool = True,
                     chain: bool = False) -> str:
    """A seeded random tree of ``n`` moving links (revolute/continuous/prismatic, random axes, origins and
    inertias) under a massless root ``base``; with ``fixed_extra`` one more link welded by a fixed joint; with
    ``chain`` every link the child of the one before."""
    rng = np.random.default_rng(seed)
    links = ['<link name="base"/>']
    joints = []
    for i in range(n):
        links.append(f'<link name="l{i}">{_inertial(rng)}</link>')
        parent = "base" if i == 0 else (f"l{rng.integers(0, i)}" if rng.uniform() < 0.6 else f"l{i - 1}")
        parent = parent if i == 0 or not chain else f"l{i - 1}"
        kind = "prismatic" if rng.uniform() < prismatic else ("revolute" if rng.uniform() < 0.7 else "continuous")
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        joints.append(
            f'<joint name="j{i}" type="{kind}"><parent link="{parent}"/><child link="l{i}"/>'
            f'<origin xyz="{_fmt(rng.uniform(-0.4, 0.4, 3))}" rpy="{_fmt(rng.uniform(-3, 3, 3))}"/>'
            f'<axis xyz="{_fmt(axis)}"/><limit effort="1" lower="-1" upper="1" velocity="1"/></joint>'
        )
    if fixed_extra and n > 0:
        links.append(f'<link name="tool">{_inertial(rng)}</link>')
        joints.append(
            f'<joint name="jtool" type="fixed"><parent link="l{rng.integers(0, n)}"/><child link="tool"/>'
            f'<origin xyz="{_fmt(rng.uniform(-0.3, 0.3, 3))}" rpy="{_fmt(rng.uniform(-3, 3, 3))}"/></joint>'
        )
    return '<robot name="random">' + "".join(links) + "".join(joints) + "</robot>"


class PinocchioOracle:
    """Pinocchio on the same URDF, evaluated in the joint order of a particlesim model (matched by name)."""

    def __init__(self, urdf, joint_names, gravity, *, mimic: bool = False):
        import pinocchio as pin

        self.pin = pin
        if urdf.lstrip().startswith("<"):
            self.model = pin.buildModelFromXML(urdf, mimic=mimic)
        else:
            self.model = pin.buildModelFromUrdf(str(urdf), mimic=mimic)
        self.model.gravity.linear = np.asarray(gravity, dtype=float)
        self.data = self.model.createData()
        self.mimic = mimic
        joints = [self.model.joints[self.model.getJointId(n)] for n in joint_names]
        self.idx = np.array([j.idx_v for j in joints])  # velocity index (continuous joints use (cos, sin) in q)
        self.idx_q = [(j.idx_q, j.nq) for j in joints]
        assert self.model.nv == len(joint_names)

    def _qv(self, q, v=None):
        qp = np.zeros(self.model.nq)
        for (i, nq), x in zip(self.idx_q, q):
            qp[i:i + nq] = [x] if nq == 1 else [np.cos(x), np.sin(x)]
        vp = np.zeros(self.model.nv)
        if v is not None:
            vp[self.idx] = v
        return qp, vp

    def mass_matrix(self, q):
        qp, _ = self._qv(q)
        # Pinocchio 4.1's crba on a model with mimic joints depends on what an earlier call left in its Data
        # (a second call at another q differs by O(1) from rnea's columns): give it a fresh Data each time
        data = self.model.createData() if self.mimic else self.data
        m = self.pin.crba(self.model, data, qp)
        m = np.triu(m) + np.triu(m, 1).T
        return m[np.ix_(self.idx, self.idx)]

    def bias(self, q, v):
        qp, vp = self._qv(q, v)
        return self.pin.nonLinearEffects(self.model, self.data, qp, vp)[self.idx]

    def gravity(self, q):
        qp, _ = self._qv(q)
        return self.pin.computeGeneralizedGravity(self.model, self.data, qp)[self.idx]

    def jacobian(self, q, link, local: bool):
        qp, _ = self._qv(q)
        pin = self.pin
        pin.computeJointJacobians(self.model, self.data, qp)
        pin.updateFramePlacements(self.model, self.data)
        ref = pin.LOCAL if local else pin.LOCAL_WORLD_ALIGNED
        return pin.getFrameJacobian(self.model, self.data, self.model.getFrameId(link), ref)[:, self.idx]

    def placement(self, q, link):
        """The world rotation and origin of ``link``'s frame."""
        qp, _ = self._qv(q)
        self.pin.framesForwardKinematics(self.model, self.data, qp)
        m = self.data.oMf[self.model.getFrameId(link)]
        return np.asarray(m.rotation), np.asarray(m.translation)


def max_rel(a, b) -> float:
    """``max |a - b| / max |b|`` (b is the reference)."""
    a, b = np.asarray(a), np.asarray(b)
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300))


def batched_terms(model, links):
    """One compiled, vmapped evaluation of every tree quantity at a batch of states: M, bias, gravity, forward and
    inverse dynamics, and world/local Jacobians of ``links`` (so many states cost one compile, not many eager runs)."""
    import jax
    import jax.numpy as jnp

    from particlesim.tree import (bias_forces, forward_dynamics, gravity_torques, inverse_dynamics, link_jacobian,
                                  mass_matrix)

    def one(q, qd, tau, qdd):
        jac = {(ln, f): link_jacobian(model, q, ln, frame=f) for ln in links for f in ("world", "local")}
        return dict(m=mass_matrix(model, q), bias=bias_forces(model, q, qd), grav=gravity_torques(model, q),
                    fd=forward_dynamics(model, q, qd, tau), id=inverse_dynamics(model, q, qd, qdd), jac=jac)

    return jax.jit(jax.vmap(one))


def states(rng, n_states, nq, nv, *, quaternions=()):
    """Random states: positions in [-2, 2] (unit quaternions at the given configuration offsets), normal rates."""
    q = rng.uniform(-2.0, 2.0, (n_states, nq))
    for a in quaternions:
        u = rng.normal(size=(n_states, 4))
        q[:, a:a + 4] = u / np.linalg.norm(u, axis=1, keepdims=True)
    return q, rng.normal(size=(n_states, nv)), rng.normal(size=(n_states, nv)), rng.normal(size=(n_states, nv))
