"""Shared mechanism fixtures."""

import numpy as np
import pytest

from particlesim.inertia import RigidInertia
from particlesim.mechanism import MechanismBuilder


def rod(p, q, m=1.0) -> RigidInertia:
    """A uniform slender rod of mass ``m`` from ``p`` to ``q`` (global frame)."""
    p, q = np.asarray(p, float), np.asarray(q, float)
    u = q - p
    ell = np.linalg.norm(u)
    u = u / ell
    return RigidInertia(m, (p + q) / 2, m * ell**2 / 12 * (np.eye(3) - np.outer(u, u)), degenerate_ok=True)


def _four_bar(close=True, extra_link=False, offset=0.0) -> MechanismBuilder:
    """Ground O, C; rods O-A (1 m), A-B (2 m), C-B2 (1 + offset); a cut joint B = B2 closes the loop (a planar
    four-bar in 3-D: 3 degrees of freedom, one in the plane and two out of it)."""
    mb = MechanismBuilder(gravity=(0, -9.81, 0))
    mb.ground("O", (0, 0, 0))
    mb.ground("C", (2, 0, 0))
    mb.particle("A", (0, 1, 0))
    mb.particle("B", (2, 1, 0))
    mb.particle("B2", (2, 1 + offset, 0))
    mb.body("crank", rod((0, 0, 0), (0, 1, 0)), ["O", "A"])
    mb.body("coupler", rod((0, 1, 0), (2, 1, 0)), ["A", "B"])
    mb.body("rocker", rod((2, 0, 0), (2, 1 + offset, 0)), ["C", "B2"])
    if close:
        mb.cut_joint("B", "B2", name="loop closure")
    if extra_link:
        mb.link("A", "C", name="redundant diagonal")
    return mb


@pytest.fixture
def four_bar():
    """The four-bar builder factory ``four_bar(close=True, extra_link=False, offset=0.0)``."""
    return _four_bar


@pytest.fixture
def rod_inertia():
    """The slender-rod inertia factory ``rod_inertia(p, q, m=1.0)``."""
    return rod
