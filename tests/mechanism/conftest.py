"""Shared mechanism fixtures."""

import pytest

from particlesim.inertia import RigidInertia
from particlesim.mechanism import MechanismBuilder, simulate_mechanism


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



def _released_from_rest(build, t_end, ts, *, rtol, atol):
    """``(mech, q0, sol)``: the mechanism ``build()`` returns, released from rest at its assembly and run to
    ``t_end``, saved at ``ts`` (the run must reach ``t_end``)."""
    mech, q0 = build()
    sol = simulate_mechanism(mech, q0, 0 * q0, 0.0, t_end, rtol=rtol, atol=atol, saveat_ts=ts)
    assert bool(sol.ok)
    return mech, q0, sol


@pytest.fixture(scope="session")
def released_from_rest():
    """The factory ``released_from_rest(build, t_end, ts, *, rtol, atol) -> (mech, q0, sol)`` for module fixtures
    of models checked against an independent solution from rest."""
    return _released_from_rest

