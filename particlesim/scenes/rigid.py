"""Single rigid bodies as particle mechanisms: a free body, and a top spinning about a fixed point (Attia §2.2–2.3)."""

from __future__ import annotations

import numpy as np

from ..inertia import RigidInertia
from ..mechanism import MechanismBuilder
from ..particles import balanced_primaries

__all__ = ["free_body", "top", "rigid_velocities"]


def rigid_velocities(points: np.ndarray, origin: np.ndarray, v_origin: np.ndarray, omega: np.ndarray) -> np.ndarray:
    """Velocities ``v_o + w x (r - o)`` of points ``(k, 3)`` moving rigidly."""
    return v_origin + np.cross(omega, points - origin)


def free_body(body: RigidInertia, v_com, omega, *, gravity=(0.0, 0.0, 0.0)):
    """A free spatial body (four primaries in the balanced layout) moving with CoM velocity ``v_com`` and angular
    velocity ``omega`` (world axes; body frame = world frame at t = 0). Returns ``(mech, q0, qd0)``."""
    prim = balanced_primaries(body, "spatial", name="free body")
    mb = MechanismBuilder(gravity=gravity)
    names = [mb.particle(f"p{i + 1}", p) for i, p in enumerate(prim)]
    mb.body("body", body, names, on_negative="raise")
    mech, q0 = mb.build(dof=6)
    qd0 = rigid_velocities(prim, np.asarray(body.com), np.asarray(v_com, float), np.asarray(omega, float))
    return mech, q0, qd0.reshape(-1)


def top(body: RigidInertia, omega, *, gravity=(0.0, 0.0, -9.81)):
    """A top: a spatial body turning about the fixed point at the body-frame origin (particle 1 there, Attia §2.3),
    the other three primaries spread along its principal axes. Returns ``(mech, q0, qd0)``."""
    spread = balanced_primaries(body, "spatial", name="top")[:3]
    mb = MechanismBuilder(gravity=gravity)
    mb.ground("pivot", np.zeros(3))
    names = ["pivot"] + [mb.particle(f"p{i + 2}", p) for i, p in enumerate(spread)]
    mb.body("top", body, names)
    mech, q0 = mb.build(dof=3)
    qd0 = rigid_velocities(spread, np.zeros(3), np.zeros(3), np.asarray(omega, float))
    return mech, q0, qd0.reshape(-1)
