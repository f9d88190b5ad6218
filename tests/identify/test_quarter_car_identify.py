"""Quarter-car identification from simulated chassis-height traces (noise-free and noisy)."""

import time

import jax.numpy as jnp
import numpy as np
import pytest

from particlesim.identify.quarter_car import chassis_trace_fn, fit_quarter_car
from particlesim.scenes.quarter_car import SPRING, TYRE

T1, N_SAMPLES = 2.0, 201  # s; 100 Hz chassis-height samples of the settling response
TRUE = np.array([SPRING["stiffness"], SPRING["damping"], TYRE["stiffness"]])
START = TRUE * np.array([1.25, 0.8, 0.75])  # 20-25 % off in every constant
NOISE_FREE_RTOL = 1e-6
NOISE_SIGMA = 1e-5  # m, Gaussian noise on every chassis-height sample
NOISY_RTOL = 1e-3  # 0.1 %
NOISE_BOUND_SIGMAS = 3.0  # noise-implied bound: 3 Gauss-Newton standard errors (measured: tyre 3.2e-4, so 9.5e-4)


@pytest.fixture(scope="module")
def traces():
    ts = np.linspace(0.0, T1, N_SAMPLES)
    trace = chassis_trace_fn(ts)
    t = time.perf_counter()
    z_true = np.asarray(trace(jnp.asarray(TRUE[None])))[0]
    print(f"\n  quarter-car rollout: compile + run {time.perf_counter() - t:.1f} s")
    return trace, z_true


@pytest.mark.slow
def test_quarter_car_round_trip_noise_free_and_noisy(traces):
    trace, z_true = traces
    assert np.ptp(z_true) > 0.1  # the chassis does settle (sag ~0.2 m): the trace is a real response
    fit = fit_quarter_car(trace, z_true, START, max_steps=15)
    rel = np.abs(fit.p / TRUE - 1)
    print(f"  noise-free: {fit.steps} GN steps, p = {fit.p}, relative errors {rel}")
    assert np.all(rel < NOISE_FREE_RTOL), rel

    # Convergence from 20-25 % off is shown above; the noisy fit starts 5 % off (saves half the rollouts).
    noisy = z_true + NOISE_SIGMA * np.random.default_rng(11).standard_normal(z_true.shape)
    fit = fit_quarter_car(trace, noisy, TRUE * np.array([1.05, 0.95, 1.05]), sigma=NOISE_SIGMA, max_steps=15)
    rel = np.abs(fit.p / TRUE - 1)
    print(f"  noisy (sigma {NOISE_SIGMA} m): p = {fit.p}, relative errors {rel}, GN relative std {fit.rel_std}, "
          f"RMS residual {fit.rms:.3e} m")
    assert np.all(rel < NOISY_RTOL), rel
    assert np.all(NOISE_BOUND_SIGMAS * fit.rel_std < NOISY_RTOL), fit.rel_std  # the data can support 0.1 % at 3 sigma
    assert np.all(rel < NOISE_BOUND_SIGMAS * fit.rel_std), (rel, fit.rel_std)
    assert abs(fit.rms / NOISE_SIGMA - 1) < 0.15  # residual is the noise, not model error
