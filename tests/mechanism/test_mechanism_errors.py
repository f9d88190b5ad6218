"""Bad mechanisms are refused at build time with a message naming the culprit."""

import numpy as np
import pytest

from particlesim import ModelError
from particlesim.inertia import RigidInertia
from particlesim.mechanism import MechanismBuilder


def _rod(p, q, m=1.0):
    p, q = np.asarray(p, float), np.asarray(q, float)
    u = q - p
    ell = np.linalg.norm(u)
    u = u / ell
    return RigidInertia(m, (p + q) / 2, m * ell**2 / 12 * (np.eye(3) - np.outer(u, u)), degenerate_ok=True)


def _four_bar(close=True, extra_link=False, offset=0.0):
    """Ground O, C; rods O-A, A-B, C-B' with a cut joint B = B' closing the loop (planar four-bar in 3-D)."""
    mb = MechanismBuilder(gravity=(0, -9.81, 0))
    mb.ground("O", (0, 0, 0))
    mb.ground("C", (2, 0, 0))
    mb.particle("A", (0, 1, 0))
    mb.particle("B", (2, 1, 0))
    mb.particle("B2", (2, 1 + offset, 0))
    mb.body("crank", _rod((0, 0, 0), (0, 1, 0)), ["O", "A"])
    mb.body("coupler", _rod((0, 1, 0), (2, 1, 0)), ["A", "B"])
    mb.body("rocker", _rod((2, 0, 0), (2, 1 + offset, 0)), ["C", "B2"])
    if close:
        mb.cut_joint("B", "B2", name="loop closure")
    if extra_link:
        mb.link("A", "C", name="redundant diagonal")
    return mb


def test_a_consistent_loop_builds():
    mech, x0 = _four_bar().build(dof=3)  # 9 coordinates - 3 rod lengths - 3 loop rows: planar + 2 out-of-plane
    assert mech.n_coords == 9


def test_dangling_particle():
    mb = _four_bar()
    mb.particle("lost", (5, 5, 5))
    with pytest.raises(ModelError, match="particle 'lost' is dangling"):
        mb.build()


def test_over_constrained_loop():
    with pytest.raises(ModelError, match="over-constrained: the mechanism has 2 degrees of freedom, expected 3"):
        _four_bar(extra_link=True).build(dof=3)
    mb = _four_bar()
    mb.cut_joint("B", "B2", name="the same cut twice")
    with pytest.raises(ModelError, match="over-constrained: .*the same cut twice"):
        mb.build()


def test_under_constrained_loop():
    with pytest.raises(ModelError, match="under-constrained: the mechanism has 6 degrees of freedom, expected 3"):
        _four_bar(close=False).build(dof=3)


def test_inconsistent_initial_positions():
    with pytest.raises(ModelError, match="initial positions violate constraints: loop closure"):
        _four_bar(offset=0.01).build()


def test_zero_length_spring():
    mb = _four_bar()
    mb.spring_damper("bad spring", "A", "A", 100.0, 1.0, 0.1)
    with pytest.raises(ModelError, match="spring 'bad spring': .*zero length"):
        mb.build()


@pytest.mark.parametrize("k, c, l0, match", [(-1.0, 0.0, 0.1, "stiffness"), (1.0, np.nan, 0.1, "damping"),
                                             (1.0, 0.0, -0.2, "free length")])
def test_non_physical_spring_constants(k, c, l0, match):
    with pytest.raises(ModelError, match=f"spring 's': {match} must be finite and non-negative"):
        _four_bar().spring_damper("s", "A", "C", k, c, l0)


def test_unknown_names_and_bad_bodies():
    mb = _four_bar()
    mb.cut_joint("A", "nowhere", name="typo joint")
    with pytest.raises(ModelError, match="typo joint: unknown particle or point 'nowhere'"):
        mb.build()
    mb = MechanismBuilder()
    mb.particle("P", (0, 0, 0))
    with pytest.raises(ModelError, match="body 'blob': needs 2 .* got 1"):
        mb.body("blob", _rod((0, 0, 0), (1, 0, 0)), ["P"])
    with pytest.raises(ModelError, match="particle 'P' is defined twice"):
        mb.particle("P", (1, 0, 0))
    with pytest.raises(ModelError, match="particle 'Q': position must be 3 finite numbers"):
        mb.particle("Q", (0, np.nan, 0))


def test_massless_direction_is_refused():
    """A particle held only by a massless link can still move around it: no mass, no dynamics."""
    mb = _four_bar()
    mb.particle("bob", (0, 2, 0))
    mb.link("A", "bob", name="string")
    with pytest.raises(ModelError, match="carries no mass"):
        mb.build()
