"""Fixtures for the tree tests: Krang URDF paths, models loaded once per session."""

import pytest

from particlesim.io import load_urdf

DART_GRAVITY = (0.0, -9.81, 0.0)


@pytest.fixture(scope="session")
def fixed_wheel(krang_urdf_dir):
    """The fixed-wheel Krang that generated the DART data, with the DART gravity."""
    return load_urdf(krang_urdf_dir / "krang_fixed_wheel_2018-04.urdf", gravity=DART_GRAVITY)


@pytest.fixture(scope="session")
def small_tree():
    """A seeded 5-link random tree with prismatic joints, a merged fixed link, friction and rotor inertia."""
    from tree_helpers import random_tree_urdf

    return load_urdf(random_tree_urdf(7, n=5, prismatic=0.4), gravity=(0.0, 0.0, -9.81),
                     viscous=[0.3, 0.1, 0.2, 0.05, 0.4], coulomb=[0.5, 0.2, 0.1, 0.3, 0.25],
                     rotor_inertia=[0.02, 0.01, 0.03, 0.015, 0.005])


@pytest.fixture(scope="session")
def tiny_tree():
    """A 3-link tree (one prismatic joint) for gradient checks."""
    from tree_helpers import random_tree_urdf

    return load_urdf(random_tree_urdf(11, n=3, prismatic=0.5), gravity=(0.0, -9.81, 0.0),
                     viscous=[0.2, 0.1, 0.3], coulomb=[0.4, 0.3, 0.2], rotor_inertia=[0.01, 0.02, 0.03])
