"""Shared fixtures: the single-arm Krang model and the hardware runs (loaded once per session)."""

import numpy as np
import pytest

from particlesim.identify import load_arm_run
from particlesim.io import load_urdf


@pytest.fixture(scope="session")
def arm_model(shared_data):
    return load_urdf(shared_data / "krang" / "urdf" / "krang_single_arm_2018.urdf", gravity=(0.0, -9.81, 0.0))


@pytest.fixture(scope="session")
def arm_train(shared_data):
    return load_arm_run(shared_data / "krang" / "arm_hardware" / "train")


@pytest.fixture(scope="session")
def arm_test(shared_data):
    return load_arm_run(shared_data / "krang" / "arm_hardware" / "test")


@pytest.fixture(scope="session")
def true_params(arm_model):
    """Known parameters for the simulated case: URDF inertias, plausible rotor inertia and friction."""
    n = arm_model.nq
    rotor = np.array([3.0, 3.0, 2.5, 2.5, 0.8, 0.8, 0.5])
    viscous = np.array([60.0, 55.0, 50.0, 40.0, 12.0, 10.0, 8.0])
    coulomb = np.array([8.0, 9.0, 7.0, 6.0, 3.0, 2.5, 2.0])
    return np.concatenate([np.asarray(arm_model.inertia).ravel(), rotor, viscous, coulomb]).reshape(13 * n)
