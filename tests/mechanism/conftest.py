"""Shared mechanism fixtures."""

import pytest

from particlesim.inertia import RigidInertia
from particlesim.mechanism import MechanismBuilder


def _four_bar(close=True, extra_link=False, offset=0.0) -> MechanismBuilder:
    """Ground O, C; rods O-A (1 m), A-B (2 m), C-B2 (1 + offset); a cut joint B = B2 closes the loop (a planar
    four-bar in 3-D: 3 degrees of freedom, one in the plane and two out of it)."""
    mb = MechanismBuilder(gravity=(0, -9.81, 0))
    mb.ground("O", (0, 0, 0))
    mb.ground("C", (2, 0, 0))
    mb.particle("A", (0, 1, 0))
    mb.particle("B", (2, 1, 0))
    mb.particle("B2", (2, 1 + offset, 0))
    mb.body("crank", RigidInertia.slender_rod(1.0, (0, 0, 0), (0, 1, 0)), ["O", "A"])
    mb.body("coupler", RigidInertia.slender_rod(1.0, (0, 1, 0), (2, 1, 0)), ["A", "B"])
    mb.body("rocker", RigidInertia.slender_rod(1.0, (2, 0, 0), (2, 1 + offset, 0)), ["C", "B2"])
    if close:
        mb.cut_joint("B", "B2", name="loop closure")
    if extra_link:
        mb.link("A", "C", name="redundant diagonal")
    return mb


@pytest.fixture(scope="session")
def four_bar():
    """The four-bar builder factory ``four_bar(close=True, extra_link=False, offset=0.0)``."""
    return _four_bar

