"""Fixtures for the tree tests: Krang URDF paths, models loaded once per session."""

import pytest

from particlesim.tree import load_urdf

DART_GRAVITY = (0.0, -9.81, 0.0)


@pytest.fixture(scope="session")
def krang_urdf_dir(shared_data):
    return shared_data / "krang" / "urdf"


@pytest.fixture(scope="session")
def fixed_wheel(krang_urdf_dir):
    """The fixed-wheel Krang that generated the DART data, with the DART gravity."""
    return load_urdf(krang_urdf_dir / "krang_fixed_wheel_2018-04.urdf", gravity=DART_GRAVITY)
