"""Test configuration: float64, strict promotion, the reference-data folder. Helpers shared across folders live
beside this file (``tree_helpers.py``), which pytest puts on the import path."""

import jax
import pytest

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_rank_promotion", "raise")

import particlesim  # noqa: E402,F401
from particlesim.data import data_dir  # noqa: E402


@pytest.fixture(scope="session")
def shared_data():
    """Path to ``../shared/data`` (skips nothing: the data are part of CI)."""
    return data_dir()


@pytest.fixture(scope="session")
def krang_urdf_dir(shared_data):
    return shared_data / "krang" / "urdf"
