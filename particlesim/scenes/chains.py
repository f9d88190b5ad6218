"""Pendulum chains of N box links, joined by revolute or spherical joints, as particle mechanisms
(their MuJoCo twins: :mod:`particlesim.twins.chains`).

Geometry (one description feeds both): link ``j`` has its frame at joint ``j`` (world pose ``(R_j, p_j)`` at
assembly) and extends a length ``L`` along its local ``-z``; joint ``j + 1`` sits at ``p_j + R_j (0, 0, -L)``.
Links are uniform boxes ``(a, b, L)``. Initial relative rotations are seeded so the motion is fully spatial.

Particles (Attia §2.4, Fig. 2): a *spherical* chain shares one particle per joint (3N + 1 primaries: the joint
particles plus two off-axis particles per link); a *revolute* chain shares two particles on each joint axis,
and successive axes alternate between the links' y and x directions so every link's four particles span a
tetrahedron. The chain hangs from the ground at joint 1.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..inertia import RigidInertia
from ..mechanism import MechanismBuilder
from ..spatial import rpy_to_matrix

__all__ = ["ChainGeometry", "chain_geometry", "chain_mechanism", "LINK"]

LINK = {"mass": 1.0, "length": 0.5, "a": 0.08, "b": 0.05, "axis_half": 0.05}
_AXES = (np.array([0.0, 1.0, 0.0]), np.array([1.0, 0.0, 0.0]))


@dataclass(frozen=True)
class ChainGeometry:
    joint: str
    rotations: np.ndarray  # (N, 3, 3) link frames at assembly
    origins: np.ndarray  # (N + 1, 3) joint positions (the last is the tip)
    axes: np.ndarray  # (N + 1, 3) local joint axis of each joint (the last: the tip's particle pair direction)

    @property
    def n(self) -> int:
        return len(self.rotations)


def chain_geometry(n: int, joint: str = "revolute", *, seed: int = 0, tilt: float = 0.6) -> ChainGeometry:
    """A chain of ``n`` links with random initial relative rotations of size ~``tilt`` rad."""
    if joint not in ("revolute", "spherical"):
        raise ValueError(f"joint must be 'revolute' or 'spherical', got {joint!r}")
    rng = np.random.default_rng(seed)
    rots, origins = [], [np.zeros(3)]
    r = np.eye(3)
    for j in range(n):
        r = r @ np.asarray(rpy_to_matrix(rng.uniform(-tilt, tilt, 3)))
        rots.append(r)
        origins.append(origins[-1] + r @ np.array([0.0, 0.0, -LINK["length"]]))
    axes = np.array([_AXES[j % 2] for j in range(n + 1)])
    return ChainGeometry(joint, np.asarray(rots), np.asarray(origins), axes)


def _box() -> RigidInertia:
    m, a, b, ell = LINK["mass"], LINK["a"], LINK["b"], LINK["length"]
    i = m / 12 * np.diag([b**2 + ell**2, a**2 + ell**2, a**2 + b**2])
    return RigidInertia(m, [0.0, 0.0, -ell / 2], i)


def _particles(g: ChainGeometry):
    """Per link: list of (name, world position, owner link index or -1 for ground); and link primaries."""
    w = LINK["axis_half"]
    parts, prims = {}, []
    for j in range(g.n):
        r, p, q = g.rotations[j], g.origins[j], g.origins[j + 1]
        if g.joint == "spherical":
            names = [f"J{j}", f"J{j + 1}", f"L{j}a", f"L{j}b"]
            pos = [p, q, p + r @ np.array([w, 0, -LINK["length"] / 2]), p + r @ np.array([0, w, -LINK["length"] / 2])]
        else:
            ax_in = r @ g.axes[j]
            # Joint j+1's axis is fixed in link j+1, whose assembly frame is rotations[j+1] (the tip: link j).
            r_out = g.rotations[j + 1] if j + 1 < g.n else r
            ax_out = r_out @ g.axes[j + 1]
            names = [f"J{j}-", f"J{j}+", f"J{j + 1}-", f"J{j + 1}+"]
            pos = [p - w * ax_in, p + w * ax_in, q - w * ax_out, q + w * ax_out]
        for nm, x in zip(names, pos):
            parts.setdefault(nm, (x, j))
        prims.append(names)
    return parts, prims


def chain_mechanism(g: ChainGeometry, gravity=(0.0, 0.0, -9.81)):
    """The particle mechanism of the chain; returns ``(mech, q0)``."""
    parts, prims = _particles(g)
    mb = MechanismBuilder(gravity=gravity)
    ground = {"J0"} if g.joint == "spherical" else {"J0-", "J0+"}
    for nm, (q, _) in parts.items():
        (mb.ground if nm in ground else mb.particle)(nm, q)
    for j in range(g.n):
        mb.body(f"link{j + 1}", _box(), prims[j], pose=(g.rotations[j], g.origins[j]), on_negative="ignore")
    dof = (3 if g.joint == "spherical" else 1) * g.n
    return mb.build(dof=dof)
