"""Identification round trips on simulated Krang-arm trajectories, gradients of the losses, standard errors and
bootstrap (the real-arm report, its consistency and its test RMSE are checked by notebooks/identify_arm.ipynb,
executed by tests/test_notebooks.py)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads
from scipy.stats import chi2

from particlesim.identify import (
    compress, fit_base_consistent, fit_consistent, identifiable_basis, model_with_params, params_from_theta, pseudo_inertia, regressor,
    base_uncertainty, bootstrap_base, robust_base_uncertainty, theta_from_params, torque_residuals,
)
from particlesim.simulate import simulate
from particlesim.tree import forward_dynamics, gravity_torques, inverse_dynamics

EPS = 0.05  # rad/s, Coulomb smoothing used throughout the simulated case
NOISE_FREE_RTOL = 1e-6  # identifiable combinations and predicted torques, noise-free data
NOISE_SIGMA = 0.5  # N m, torque noise of the noisy case
NOISE_QUANTILE = 0.999  # chi-square quantile of the noise-implied bound
REGRESSOR_RTOL = 1e-10
GRAD_TOL = 1e-5
IDENTIFIABLE_RTOL = 1e-6  # singular-value cut (column-scaled regressor) defining identifiable combinations
PSD_RTOL = 1e-12  # rounding allowance on pseudo-inertia eigenvalues (relative to the largest of the body)


@pytest.fixture(scope="session")
def simulated(arm_model, true_params):
    """One 2 s closed-loop simulation of the arm with the true parameters: PD tracking of a multi-sine reference
    plus gravity compensation. Returns (q, qd, qdd, tau) at 201 samples; qdd from the forward dynamics."""
    model = model_with_params(arm_model, true_params)
    amp = jnp.array([0.8, 0.6, 0.9, 0.7, 1.0, 0.8, 1.0])
    freq = jnp.array([0.6, 0.8, 0.7, 0.9, 1.1, 1.3, 1.2]) * 2 * jnp.pi
    kp, kd = 400.0, 60.0

    def ref(t):
        return amp * jnp.sin(freq * t), amp * freq * jnp.cos(freq * t)

    def control(t, q, qd, m):
        qr, qdr = ref(t)
        return gravity_torques(m, q) + kp * (qr - q) + kd * (qdr - qd)

    def dynamics(m, q, qd, tau):
        return forward_dynamics(m, q, qd, tau, smooth_friction=EPS)

    ts = jnp.linspace(0.0, 2.0, 201)
    sol = jax.jit(lambda m: simulate(dynamics, m, jnp.zeros(7), jnp.zeros(7), 0.0, 2.0, control=control,
                                     saveat_ts=ts, rtol=1e-9, atol=1e-11))(model)
    tau = jax.vmap(lambda t, q, qd: control(t, q, qd, model))(ts, sol.q, sol.qd)
    qdd = jax.vmap(lambda q, qd, u: dynamics(model, q, qd, u))(sol.q, sol.qd, tau)
    return np.asarray(sol.q), np.asarray(sol.qd), np.asarray(qdd), np.asarray(tau)


@pytest.fixture(scope="session")
def sim_regressor(arm_model, simulated):
    q, qd, qdd, _ = simulated
    return np.asarray(regressor(arm_model, q, qd, qdd, eps=EPS))


def test_regressor_reproduces_inverse_dynamics(arm_model, true_params, simulated, sim_regressor):
    q, qd, qdd, tau = simulated
    model = model_with_params(arm_model, true_params)
    direct = jax.vmap(lambda a, b, c: inverse_dynamics(model, a, b, c, smooth_friction=EPS))(q, qd, qdd)
    np.testing.assert_allclose(sim_regressor @ true_params, direct, rtol=REGRESSOR_RTOL, atol=1e-9)
    np.testing.assert_allclose(direct, tau, rtol=1e-8, atol=1e-7)  # the simulation obeyed the same dynamics


def _start(true_params, seed, scale=0.3):
    th = np.asarray(theta_from_params(true_params))
    return th + scale * np.random.default_rng(seed).standard_normal(th.shape)


def test_round_trip_noise_free(true_params, simulated, sim_regressor):
    """Base parameters (column-scaled, singular values above IDENTIFIABLE_RTOL) and torques are recovered to
    NOISE_FREE_RTOL by a physically consistent fit, from three starts 0.3 (log-Cholesky units) off the truth."""
    tau = simulated[3]
    basis, rank = identifiable_basis(sim_regressor, rtol=IDENTIFIABLE_RTOL)
    assert 40 < rank < 91  # rank-deficient: only base parameters are identifiable
    starts = np.stack([_start(true_params, s) for s in range(3)])
    fit = fit_base_consistent(compress(sim_regressor, tau), starts, rtol=IDENTIFIABLE_RTOL)
    for s in range(3):
        err = fit.pi[s] - true_params
        proj_rel = np.linalg.norm(basis.T @ err) / np.linalg.norm(basis.T @ true_params)
        torque_rel = np.linalg.norm(sim_regressor.reshape(-1, 91) @ err) / np.linalg.norm(tau)
        print(f"  start {s}: base-parameter error {proj_rel:.2e}, torque error {torque_rel:.2e}, "
              f"{int(fit.steps[s])} LM steps")
        assert proj_rel < NOISE_FREE_RTOL, (s, proj_rel)
        assert torque_rel < NOISE_FREE_RTOL, (s, torque_rel)
        # Consistent: every pseudo-inertia positive semidefinite (to rounding; non-identifiable parts of a body may
        # settle near the boundary, i.e. a nearly flat mass distribution), rotor inertia and friction positive.
        eig = np.linalg.eigvalsh(np.asarray(pseudo_inertia(fit.pi[s][:70].reshape(7, 10))))
        assert np.all(eig >= -PSD_RTOL * eig.max(axis=1, keepdims=True)), eig
        assert np.all(fit.pi[s][70:] > 0)


def test_identifiable_basis_spans_the_row_space(sim_regressor):
    """Regression: the basis was once D^-1 V (not the row space) and the scaling blew structurally zero columns
    (norm ~1e-26 from rounding) up to unit norm. Every null vector of the regressor must be invisible to it."""
    w = sim_regressor.reshape(-1, 91)
    basis, rank = identifiable_basis(w, rtol=IDENTIFIABLE_RTOL)
    _, s, vt = np.linalg.svd(w, full_matrices=False)
    null = vt[s < 1e-12 * s[0]]  # exact null directions (raw units)
    assert null.shape[0] >= 91 - rank - 2
    assert np.max(np.abs(null @ basis)) < 1e-8 * np.max(np.abs(basis))
    # And W is reproduced from the base parameters: w x = 0 for x orthogonal (scaled) to the basis.
    x = np.random.default_rng(0).standard_normal(91)
    x -= basis @ np.linalg.lstsq(basis, x, rcond=None)[0]
    assert np.linalg.norm(w @ x) < 1e-6 * np.linalg.norm(w, 2) * np.linalg.norm(x)


def test_round_trip_noisy_within_noise_bound(true_params, simulated, sim_regressor):
    tau = simulated[3]
    _, rank = identifiable_basis(sim_regressor)
    noisy = tau + NOISE_SIGMA * np.random.default_rng(7).standard_normal(tau.shape)
    fit = fit_consistent(compress(sim_regressor, noisy), _start(true_params, 0)[None], max_steps=400, verbose=False)
    # For Gaussian noise the least-squares error of the predicted torques satisfies
    # ||W (pi_hat - pi)||^2 / sigma^2 ~ chi^2(rank); the consistent fit equals it when the optimum is interior.
    stat = np.sum((sim_regressor @ (fit.best_pi - true_params)) ** 2) / NOISE_SIGMA ** 2
    assert stat < chi2.ppf(NOISE_QUANTILE, rank), (stat, rank)
    assert stat > chi2.ppf(1 - NOISE_QUANTILE, rank)  # not suspiciously small either (fit did use the noise)


def test_check_grads_identification_loss(arm_model, arm_train, true_params):
    d = arm_train.subsample(400)  # 12 samples

    def loss(theta):
        r = torque_residuals(theta, arm_model, d.q, d.qd, d.qdd, d.torque, eps=0.05)
        return 0.5 * jnp.mean(r ** 2)

    th = jnp.asarray(theta_from_params(true_params))
    check_grads(loss, (th,), order=1, modes=("fwd", "rev"), atol=GRAD_TOL, rtol=GRAD_TOL)
    # The compressed residual used by the fitter has the same gradient.
    w = np.asarray(regressor(arm_model, d.q, d.qd, d.qdd, eps=0.05))
    lsq = compress(w, d.torque)
    fast = lambda t: 0.5 * (jnp.sum((lsq.r @ params_from_theta(t) - lsq.y) ** 2) + lsq.rest) / lsq.count  # noqa
    np.testing.assert_allclose(jax.grad(fast)(th), jax.grad(loss)(th), rtol=1e-7, atol=1e-9)


UNCERTAINTY_LEVELS = (0.01, 0.05)  # torque noise, fraction of the pooled RMS torque
COVERAGE = 0.90  # fraction of base parameters whose error must lie inside 2 standard errors
WELL_IDENTIFIED = 0.1  # relative standard error below which a base parameter counts as well identified
BOOTSTRAP_FACTOR = 2.0  # bootstrap spread and Gauss-Newton standard error agree within this factor


@pytest.fixture(scope="module")
def noisy_fits(true_params, simulated, sim_regressor):
    """Consistent fits to the simulated torques with independent Gaussian noise at each level."""
    tau = simulated[3]
    rms = float(np.sqrt(np.mean(tau ** 2)))
    out = {}
    for k, level in enumerate(UNCERTAINTY_LEVELS):
        sigma = level * rms
        noisy = tau + sigma * np.random.default_rng(100 + k).standard_normal(tau.shape)
        lsq = compress(sim_regressor, noisy)
        fit = fit_consistent(lsq, _start(true_params, 0)[None], max_steps=2000, verbose=False)  # shares a compile
        out[level] = (sigma, noisy, lsq, fit)
    return out


def test_fit_consistent_compiles_once_for_new_data(noisy_fits, true_params):
    """Both noise levels were fitted by one compiled solver; another data set and start do not retrace it."""
    from particlesim import _ode

    before = _ode.TRACES["fit_consistent"]
    _, _, lsq, _ = noisy_fits[0.01]
    fit_consistent(lsq, _start(true_params, 5)[None], max_steps=2000, verbose=False)
    assert _ode.TRACES["fit_consistent"] == before


def test_a_start_with_zero_friction_is_refused_by_name(arm_model, noisy_fits):
    """``params_of_model`` of a model without rotor inertia or friction has zeros there; their unconstrained
    coordinates are -inf. The fit says so instead of returning NaN."""
    from particlesim.identify import params_of_model

    _, _, lsq, _ = noisy_fits[0.01]
    with pytest.raises(ValueError, match="start 0: joint 0 rotor inertia"):
        fit_consistent(lsq, theta_from_params(params_of_model(arm_model))[None], verbose=False)
    with pytest.raises(ValueError, match="joint 0 rotor inertia"):
        fit_base_consistent(lsq, theta_from_params(params_of_model(arm_model))[None])


def test_standard_errors_cover_the_truth(true_params, sim_regressor, noisy_fits):
    """Gauss-Newton standard errors of the base parameters: at 1 % and 5 % noise at least COVERAGE of the base
    parameters lie within 2 standard errors of the truth, and the noise estimate is within 10 % of the true one."""
    basis, _ = identifiable_basis(sim_regressor, rtol=IDENTIFIABLE_RTOL)
    for level, (sigma, _, lsq, fit) in noisy_fits.items():
        u = base_uncertainty(lsq, fit.best_theta, basis=basis)
        z = (u.beta - basis.T @ true_params) / u.std
        inside = float(np.mean(np.abs(z) < 2))
        print(f"  noise {level:.0%}: sigma {u.sigma:.3f} (true {sigma:.3f}), {inside:.0%} of {z.size} base "
              f"parameters within 2 standard errors, max |z| {np.abs(z).max():.2f}")
        assert inside >= COVERAGE, (level, inside)
        assert abs(u.sigma / sigma - 1) < 0.1, (u.sigma, sigma)


def test_bootstrap_spread_agrees_with_gauss_newton(sim_regressor, noisy_fits):
    """Spread of least-squares fits to 32 resamples of the samples vs the Gauss-Newton standard errors at the
    consistent fit (5 % noise; interior, so the two describe the same estimator),
    for the well-identified base parameters."""
    basis, _ = identifiable_basis(sim_regressor, rtol=IDENTIFIABLE_RTOL)
    sigma, noisy, lsq, fit = noisy_fits[0.05]
    u = base_uncertainty(lsq, fit.best_theta, basis=basis)
    boot = bootstrap_base(sim_regressor, noisy, fit.best_theta, basis, count=32, seed=3)
    good = u.rel_std < WELL_IDENTIFIED
    ratio = boot.std(axis=0)[good] / u.std[good]
    print(f"  {good.sum()} well-identified base parameters: bootstrap / Gauss-Newton spread "
          f"{ratio.min():.2f} .. {ratio.max():.2f} (median {np.median(ratio):.2f})")
    assert good.sum() >= 10
    assert np.all(ratio < BOOTSTRAP_FACTOR) and np.all(ratio > 1 / BOOTSTRAP_FACTOR), ratio


HETERO_LEVELS = np.array([0.002, 0.005, 0.01, 0.02, 0.04, 0.06, 0.08])  # torque noise per joint, of its RMS torque


def test_sandwich_errors_follow_unequal_noise_where_pooled_ones_do_not(true_params, sim_regressor, simulated,
                                                                       noisy_fits):
    """Noise 40x larger on the last joint than the first: the pooled-sigma Gauss-Newton errors misstate the
    spread; the sandwich errors (scores per sample) agree with the bootstrap within the factor and cover the
    truth. On equal noise (5 %) sandwich and pooled errors agree within the factor."""
    basis, _ = identifiable_basis(sim_regressor, rtol=IDENTIFIABLE_RTOL)
    sigma, noisy, lsq, fit = noisy_fits[0.05]
    u = base_uncertainty(lsq, fit.best_theta, basis=basis)
    robust = robust_base_uncertainty(sim_regressor, noisy, fit.best_theta, basis)
    good = u.rel_std < WELL_IDENTIFIED
    ratio = robust.std[good] / u.std[good]
    assert np.all(ratio < BOOTSTRAP_FACTOR) and np.all(ratio > 1 / BOOTSTRAP_FACTOR), ratio

    tau = simulated[3]
    per_joint = HETERO_LEVELS * np.sqrt(np.mean(tau ** 2, axis=0))
    noisy = tau + per_joint * np.random.default_rng(7).standard_normal(tau.shape)
    lsq = compress(sim_regressor, noisy)
    fit = fit_consistent(lsq, _start(true_params, 0)[None], max_steps=2000, verbose=False)
    pooled = base_uncertainty(lsq, fit.best_theta, basis=basis)
    robust = robust_base_uncertainty(sim_regressor, noisy, fit.best_theta, basis)
    boot = bootstrap_base(sim_regressor, noisy, fit.best_theta, basis, count=32, seed=3)
    good = robust.rel_std < WELL_IDENTIFIED
    r_robust = boot.std(axis=0)[good] / robust.std[good]
    r_pooled = boot.std(axis=0)[good] / pooled.std[good]
    z = (robust.beta - basis.T @ true_params) / robust.std
    print(f"  unequal noise, {good.sum()} well-identified: bootstrap / sandwich {r_robust.min():.2f} .. "
          f"{r_robust.max():.2f}, bootstrap / pooled {r_pooled.min():.2f} .. {r_pooled.max():.2f}; "
          f"{np.mean(np.abs(z) < 2):.0%} within 2 sandwich errors")
    assert good.sum() >= 10
    assert np.all(r_robust < BOOTSTRAP_FACTOR) and np.all(r_robust > 1 / BOOTSTRAP_FACTOR), r_robust
    assert np.max(np.abs(np.log(r_pooled))) > np.max(np.abs(np.log(r_robust)))
    assert np.mean(np.abs(z) < 2) >= COVERAGE
    with pytest.raises(ValueError, match="block must be"):
        robust_base_uncertainty(sim_regressor, noisy, fit.best_theta, basis, block=0)
    with pytest.raises(ValueError, match=r"w must be \(N, n, p\)"):
        robust_base_uncertainty(sim_regressor[0], noisy, fit.best_theta, basis)


def test_base_uncertainty_refuses_too_few_residuals(true_params, sim_regressor, simulated):
    few = compress(sim_regressor[:2], simulated[3][:2])  # 14 residuals: as many base parameters as residuals
    with pytest.raises(ValueError, match="do not exceed"):
        base_uncertainty(few, theta_from_params(true_params), rtol=1e-12)
    zero_friction = np.array(true_params)
    zero_friction[-1] = 0.0  # last joint's Coulomb friction: its coordinate is -inf
    with pytest.raises(ValueError, match="joint 6 Coulomb friction"):
        base_uncertainty(few, theta_from_params(zero_friction))
    with pytest.raises(ValueError, match="block must be"):
        bootstrap_base(sim_regressor, simulated[3], theta_from_params(true_params), np.eye(91), block=10_000)
