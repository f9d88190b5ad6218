"""Test configuration: float64, strict promotion, the reference-data folder. Helpers shared across folders live
beside this file (``tree_helpers.py``), which pytest puts on the import path."""

import os

# The tests' own jax.jit wrappers (losses, check_grads, twins) compile with the options particlesim's entries use
# (particlesim._xla.COMPILE_OPTIONS: about half the compile time, same run time); set before JAX's backend starts.
# test_compile_once checks that they agree with XLA's defaults to round-off. With PARTICLESIM_TEST_XLA_DEFAULTS=1
# they keep XLA's defaults instead, as a user's own jax.jit does (and our entries traced inside it): CI runs the
# round-off-sensitive and reference tests a second time so (make test-xla-defaults, XLA_DEFAULTS_TESTS in the
# Makefile).
XLA_DEFAULTS = os.environ.get("PARTICLESIM_TEST_XLA_DEFAULTS", "") == "1"
if not XLA_DEFAULTS:
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " --xla_cpu_use_fusion_emitters=false").strip()

import jax  # noqa: E402
import pytest  # noqa: E402

jax.config.update("jax_enable_x64", True)
jax.config.update("jax_numpy_rank_promotion", "raise")

import particlesim  # noqa: E402,F401
from particlesim.data import data_dir  # noqa: E402


def pytest_report_header(config):
    return (f"particlesim tests: {'XLA default CPU emitters' if XLA_DEFAULTS else 'fusion emitters off'} for the "
            f"tests' own jits (XLA_FLAGS={os.environ.get('XLA_FLAGS', '')!r})")


@pytest.fixture(scope="session")
def shared_data():
    """Path to ``../shared/data`` (skips nothing: the data are part of CI)."""
    return data_dir()


@pytest.fixture(scope="session")
def krang_urdf_dir(shared_data):
    return shared_data / "krang" / "urdf"
