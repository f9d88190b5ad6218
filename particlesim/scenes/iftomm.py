"""IFToMM multibody benchmark problems as particle mechanisms (``shared/reference/mbs-benchmarks.md``).

A03 (Andrews' squeezing mechanism) lives in :mod:`particlesim.scenes.andrews`.

* :func:`a01_pendulum` — A01, the simple pendulum: a 1 kg point mass on a massless 1 m link hinged at the origin,
  released at rest from the horizontal (+1, 0), gravity 9.81 along −y, 2000 s. As particles: a rod body whose
  whole mass sits at its tip (its particle masses solve to 0 at the pivot and the midpoint, 1 kg at the tip).
* :func:`a02_four_bar` — A02, the N-four-bar: a row of N unit squares (N + 1 cranks, N couplers, 1 m and 1 kg
  uniform rods) with B0 moving at +1 m/s, gravity along −y, 20 s. Twice per revolution the linkage lies flat, where
  the constraint Jacobian loses N ranks; it is built with least-squares multipliers to cross those positions. As
  particles: one rod per link; the ground pivots ``A{i}`` and the crank tops ``B{i}`` are the particles, the
  couplers share them (revolute joints in the plane; the out-of-plane freedoms are never excited).
  :func:`a02_reduced` is the one-coordinate model of the parallelogram motion (for checks).
* :func:`a04_bricard` — A04, Bricard's linkage: five 1 m, 1 kg square-section rods (0.1 m × 0.1 m), six revolute
  joints whose axes are each perpendicular to both rods at the joint, gravity along −y, from rest. Its 24 particle
  constraint rows have rank 23 everywhere (Grübler counts 0 freedoms, the linkage has 1): built with least-squares
  multipliers. As particles: each rod is a spatial set of four primaries, the two particles of the joint axis at
  each end (axis particles ``P{i}`` and ``P{i}a``, ``AXIS_OFFSET`` apart); neighbouring rods share them.
"""

from __future__ import annotations

import numpy as np

from ..inertia import RigidInertia
from ..mechanism import MechanismBuilder

__all__ = ["A01", "a01_pendulum", "A02", "a02_four_bar", "a02_reduced", "A04", "a04_bricard", "AXIS_OFFSET"]

#: A01 data: mass [kg], length [m], gravity [m/s^2], time span [s], output samples.
A01 = dict(mass=1.0, length=1.0, g=9.81, t_end=2000.0, outputs=4000)


def a01_pendulum(mass: float = A01["mass"], length: float = A01["length"], g: float = A01["g"]):
    """The A01 pendulum; returns ``(mech, x0)`` (x0: the bob at (length, 0, 0), the link horizontal)."""
    mb = MechanismBuilder(gravity=(0.0, -g, 0.0))
    mb.ground("O", (0.0, 0.0, 0.0))
    mb.particle("P1", (length, 0.0, 0.0))
    mb.body("bob", RigidInertia(mass, (length, 0.0, 0.0), np.zeros((3, 3)), degenerate_ok=True, name="bob"),
            ["O", "P1"])
    return mb.build(dof=2)  # in 3-D: the swing and the out-of-plane swing (never excited)


#: A02 data: links per row (the benchmark's N), link length [m] and mass [kg], gravity, time span, outputs.
A02 = dict(n=40, length=1.0, mass=1.0, g=9.81, t_end=20.0, outputs=400)


def a02_four_bar(n: int = A02["n"], g: float = A02["g"]):
    """The A02 N-four-bar at t = 0; returns ``(mech, x0, xd0)`` (every crank top moving at +1 m/s along x).

    Unit squares: ground pivots ``A{i} = (i, 0)``, crank tops ``B{i} = (i, 1)``, ``i = 0..n``; crank ``i`` is the rod
    ``A{i}-B{i}``, coupler ``i`` (1..n) the rod ``B{i-1}-B{i}``."""
    if int(n) != n or n < 1:
        raise ValueError(f"a02_four_bar: n must be a positive integer, got {n!r}")
    n = int(n)
    mb = MechanismBuilder(gravity=(0.0, -g, 0.0))
    for i in range(n + 1):
        mb.ground(f"A{i}", (float(i), 0.0, 0.0))
        mb.particle(f"B{i}", (float(i), 1.0, 0.0))
        mb.body(f"crank{i}", RigidInertia.slender_rod(1.0, (i, 0.0, 0.0), (i, 1.0, 0.0), name=f"crank{i}"),
                [f"A{i}", f"B{i}"])
    for i in range(1, n + 1):
        mb.body(f"coupler{i}", RigidInertia.slender_rod(1.0, (i - 1, 1.0, 0.0), (i, 1.0, 0.0), name=f"coupler{i}"),
                [f"B{i - 1}", f"B{i}"])
    mech, x0 = mb.build(dof=1 + (n + 1), multipliers="least_squares")  # in-plane 1, out-of-plane one per crank top
    xd0 = np.tile([1.0, 0.0, 0.0], n + 1)
    return mech, x0, xd0


def a02_reduced(n: int = A02["n"], g: float = A02["g"]) -> tuple[float, float]:
    """The parallelogram motion in its one coordinate θ (crank angle from the upward vertical, clockwise positive;
    B0 = (sin θ, cos θ)): ``I θ̈ = c sin θ`` with ``I = (n + 1)/3 + n`` (cranks about their pivots, couplers
    translating) and ``c = g ((n + 1)/2 + n)``; returns ``(I, c)``. Energy ``I θ̇²/2 + c cos θ``."""
    return (n + 1) / 3.0 + n, g * ((n + 1) / 2.0 + n)


#: A04 data: rod length [m], mass [kg], square section side [m], gravity, time span [s].
A04 = dict(length=1.0, mass=1.0, side=0.1, g=9.81, t_end=10.0)
#: Distance between the two particles that carry a joint axis [m] (a choice of this package).
AXIS_OFFSET = 0.1
_BRICARD_P = np.array([[0, 0, 0], [1, 0, 0], [1, -1, 0], [1, -1, 1], [0, -1, 1], [0, 0, 1]], dtype=float)
_BRICARD_AXES = np.eye(3)[[1, 2, 0, 1, 2, 0]]  # P1 y, P2 z, P3 x, P4 y, P5 z, P6 x


def a04_bricard(g: float = A04["g"]):
    """Bricard's linkage (A04) at rest in its initial position; returns ``(mech, x0)``. Joint ``i`` (1..6) sits at
    ``P{i}`` with axis particle ``P{i}a = P{i} + AXIS_OFFSET * axis``; rod ``i`` runs ``P{i} -> P{i+1}``; joints 1 and
    6 are on the ground. P3, the point the benchmark reports, is the particle ``P3``."""
    c = A04
    mb = MechanismBuilder(gravity=(0.0, -g, 0.0))
    for i, (p, a) in enumerate(zip(_BRICARD_P, _BRICARD_AXES), start=1):
        add = mb.ground if i in (1, 6) else mb.particle
        add(f"P{i}", p)
        add(f"P{i}a", p + AXIS_OFFSET * a)
    side, m, ell = c["side"], c["mass"], c["length"]
    axial, transverse = m * (2 * side**2) / 12, m * (ell**2 + side**2) / 12
    for i in range(1, 6):
        p, q = _BRICARD_P[i - 1], _BRICARD_P[i]
        u = (q - p) / np.linalg.norm(q - p)
        inertia = transverse * (np.eye(3) - np.outer(u, u)) + axial * np.outer(u, u)
        mb.body(f"rod{i}", RigidInertia(m, (p + q) / 2, inertia, name=f"rod{i}"),
                [f"P{i}", f"P{i}a", f"P{i + 1}", f"P{i + 1}a"], on_negative="ignore")
    return mb.build(dof=1, multipliers="least_squares")
