"""Parameterisations: round trips, reachability of the consistent set, gradients."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from particlesim.identify import (
    inertia_from_log_cholesky, inv_softplus, log_cholesky_from_inertia, params_from_pseudo_inertia,
    params_from_theta, pseudo_inertia, softplus, theta_from_params,
)
from particlesim.inertia import RigidInertia, check_inertia
from particlesim.tree.model import origin_params_check

ROUND_TRIP_RTOL = 1e-10
GRAD_TOL = 1e-6


def _random_body(rng):
    """A random consistent body: mass, CoM, and a CoM inertia from random positive principal second moments."""
    m = rng.uniform(0.1, 10.0)
    c = rng.normal(scale=0.2, size=3)
    s = rng.uniform(1e-4, 1e-1, size=3)  # principal second moments about the CoM (>0 <=> consistent)
    r, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    sig = r @ np.diag(m * s) @ r.T
    i_com = np.trace(sig) * np.eye(3) - sig
    return np.asarray(RigidInertia(m, c, i_com).to_origin_params())


def test_pseudo_inertia_round_trip(arm_model):
    p = np.asarray(arm_model.inertia)
    np.testing.assert_allclose(params_from_pseudo_inertia(pseudo_inertia(p)), p, rtol=0, atol=1e-15)


@pytest.mark.parametrize("seed", range(5))
def test_log_cholesky_round_trip_on_random_consistent_bodies(seed):
    rng = np.random.default_rng(seed)
    p = np.stack([_random_body(rng) for _ in range(8)])
    theta = log_cholesky_from_inertia(p)
    assert np.all(np.isfinite(theta))
    np.testing.assert_allclose(inertia_from_log_cholesky(theta), p, rtol=ROUND_TRIP_RTOL, atol=1e-14)
    # And the other way: any theta -> consistent body -> same theta.
    th = rng.normal(scale=1.5, size=(8, 10))
    np.testing.assert_allclose(log_cholesky_from_inertia(inertia_from_log_cholesky(th)), th, rtol=1e-8, atol=1e-9)


@pytest.mark.parametrize("seed", range(3))
def test_every_theta_is_physically_consistent(seed):
    th = np.random.default_rng(seed).normal(scale=2.0, size=(50, 10))
    p = np.asarray(inertia_from_log_cholesky(th))
    assert np.all(np.linalg.eigvalsh(np.asarray(pseudo_inertia(p))) > 0)
    for i, row in enumerate(p):
        origin_params_check(row, f"sample {i}")  # raises InertiaError if not physical


def test_inconsistent_body_has_no_coordinates():
    # A negative principal second moment: triangle inequality violated; the inverse map must not invent one.
    p = np.array([1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.1, 0.0, 0.1])  # XX > YY + ZZ about the CoM
    with pytest.raises(ValueError):
        check_inertia(1.0, np.zeros(3), np.diag([1.0, 0.1, 0.1]), "bad")
    assert np.all(np.isnan(log_cholesky_from_inertia(p)))


def test_full_parameter_vector_round_trip(true_params):
    theta = theta_from_params(true_params)
    np.testing.assert_allclose(params_from_theta(theta), true_params, rtol=ROUND_TRIP_RTOL, atol=1e-14)
    x = np.array([1e-6, 0.3, 2.0, 80.0])
    np.testing.assert_allclose(softplus(inv_softplus(x)), x, rtol=1e-10)
    assert np.isnan(inv_softplus(-1.0))


def test_check_grads_parameterisation_maps():
    rng = np.random.default_rng(3)
    th = jnp.asarray(rng.normal(scale=0.5, size=(2, 10)))
    check_grads(inertia_from_log_cholesky, (th,), order=2, modes=("fwd", "rev"), atol=GRAD_TOL, rtol=GRAD_TOL)
    p = inertia_from_log_cholesky(th)
    check_grads(log_cholesky_from_inertia, (p,), order=1, modes=("fwd", "rev"), atol=GRAD_TOL, rtol=GRAD_TOL)
    full = jnp.asarray(rng.normal(size=13 * 2))
    check_grads(params_from_theta, (full,), order=1, modes=("fwd", "rev"), atol=GRAD_TOL, rtol=GRAD_TOL)
    check_grads(softplus, (jnp.array([-3.0, 0.0, 5.0]),), order=2, modes=("fwd", "rev"))
