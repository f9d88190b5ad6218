"""IFToMM multibody benchmark problems as particle mechanisms (``shared/reference/mbs-benchmarks.md``).

A03 (Andrews' squeezing mechanism) lives in :mod:`particlesim.scenes.andrews`.

* :func:`a01_pendulum` — A01, the simple pendulum: a 1 kg point mass on a massless 1 m link hinged at the origin,
  released at rest from the horizontal (+1, 0), gravity 9.81 along −y, 2000 s. As particles: a rod body whose
  whole mass sits at its tip (its particle masses solve to 0 at the pivot and the midpoint, 1 kg at the tip).
"""

from __future__ import annotations

import numpy as np

from ..inertia import RigidInertia
from ..mechanism import MechanismBuilder

__all__ = ["A01", "a01_pendulum"]

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
