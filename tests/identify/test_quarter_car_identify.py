"""Quarter-car identification by autodiff: spring, damper, tyre stiffness and both masses from noisy chassis-height
traces of two runs (no payload and a known 100 kg on the chassis), Jacobians by forward mode through the rollout."""

import jax.numpy as jnp
import numpy as np
import pytest

from particlesim import _ode
from particlesim.identify.quarter_car import FITTED, chassis_traces, fit_quarter_car
from particlesim.scenes.quarter_car import SPRING, TABLE1, TYRE

T1, N_SAMPLES = 2.0, 201  # s; 100 Hz chassis-height samples of the settling responses
TRUE = np.array([SPRING["stiffness"], SPRING["damping"], TYRE["stiffness"], TABLE1["chassis"][0],
                 TABLE1["wheel"][0]])
# Two starts 20 % off in every constant, in opposite directions, run side by side (vmapped).
STARTS = TRUE * (1 + 0.2 * np.array([[1, -1, -1, 1, -1], [-1, 1, 1, -1, 1]]))
NOISE_SIGMA = 1e-5  # m, Gaussian noise on every chassis-height sample
NOISY_RTOL = 1e-3  # 0.1 %, the acceptance bound
NOISE_BOUND_SIGMAS = 3.0  # every constant within 3 Gauss-Newton standard errors of the truth
JAC_FD_H = 3e-4  # central-difference step in log p
# Per column, relative to the column's norm. The differences carry O(h^2) truncation and the rollout's solver
# noise (rtol 1e-7) over h: measured 7e-6..2.4e-5 for the constants and 3.7e-4 for the weak wheel-mass column
# (norm 0.03 against 0.5..9); with both rollouts at rtol 1e-10 every column agrees to 9e-6.
JAC_FD_RTOL = 1e-3
RESIDUAL_ATOL = 1e-9  # m: residual of the forward-mode pass against the plain rollout (measured 4e-11; batching)


@pytest.fixture(scope="module")
def model():
    assert FITTED == ("spring_stiffness", "spring_damping", "tyre_stiffness", "chassis_mass", "wheel_mass")
    return chassis_traces(np.linspace(0.0, T1, N_SAMPLES))


@pytest.fixture(scope="module")
def data(model):
    """True traces and, from the same compiled batch, the traces at the first start and their central
    differences there."""
    lp = np.log(STARTS[0])
    eye = JAC_FD_H * np.eye(TRUE.size)
    batch = np.exp(np.concatenate([np.log(TRUE)[None], lp[None], lp + eye, lp - eye]))
    z = np.asarray(model.outputs(jnp.asarray(batch)))
    plus, minus = z[2:2 + TRUE.size], z[2 + TRUE.size:]
    jac_fd = ((plus - minus) / (2 * JAC_FD_H)).reshape(TRUE.size, -1).T
    return z[0], z[1], jac_fd


@pytest.mark.slow
def test_quarter_car_jacobian_is_autodiff_and_matches_central_differences(model, data):
    z_true, z_start, jac_fd = data
    r, jac = model.residual_jacobian(jnp.asarray(np.log(STARTS)), jnp.asarray(z_true))
    jac = np.asarray(jac[0])
    assert jac.shape == jac_fd.shape == (2 * N_SAMPLES, TRUE.size)
    err = np.linalg.norm(jac - jac_fd, axis=0) / np.linalg.norm(jac_fd, axis=0)
    print(f"\n  forward-mode Jacobian against central differences, relative error per column: {err}")
    assert np.all(err < JAC_FD_RTOL), err
    np.testing.assert_allclose(np.asarray(r[0]), (z_start - z_true).ravel(), rtol=0,
                               atol=RESIDUAL_ATOL)


@pytest.mark.slow
def test_quarter_car_fit_recovers_constants_and_masses(model, data):
    z_true = data[0]
    assert np.all(np.ptp(z_true, axis=1) > 0.1)  # both runs settle (sag ~0.2 m and ~0.5 m): real responses
    noisy = z_true + NOISE_SIGMA * np.random.default_rng(11).standard_normal(z_true.shape)
    traces = _ode.TRACES["trace_model residual_jacobian"]
    fit = fit_quarter_car(model, noisy, STARTS, sigma=NOISE_SIGMA)
    rel = np.abs(fit.p / TRUE - 1)
    print(f"\n  {fit.evaluations} evaluations (2 starts each), steps {fit.steps}, converged {fit.converged}\n"
          f"  relative errors {rel}\n  Gauss-Newton relative std {fit.rel_std}\n  RMS residual {fit.rms:.3e} m")
    assert fit.converged.any()
    assert np.all(rel < NOISY_RTOL), rel
    assert np.all(rel < NOISE_BOUND_SIGMAS * fit.rel_std), (rel, fit.rel_std)
    assert abs(fit.rms / NOISE_SIGMA - 1) < 0.15  # the residual is the noise, not model error
    # every evaluation and start reused one compile (a trace counter: a jit's cache may evict in a long process)
    assert _ode.TRACES["trace_model residual_jacobian"] - traces <= 1


def test_quarter_car_identification_refuses_bad_input(model):
    with pytest.raises(ValueError, match="distinct keys"):
        chassis_traces([0.0, 1.0], names=("spring_stiffness", "spring_stifness"))
    with pytest.raises(ValueError, match="two distinct chassis payloads"):
        chassis_traces([0.0, 1.0], payloads=(0.0,))
    with pytest.raises(ValueError, match="increasing sample times"):
        chassis_traces([1.0, 0.5])
    z = np.zeros((2, N_SAMPLES))
    with pytest.raises(ValueError, match=r"shape \(2, 201\)"):
        fit_quarter_car(model, z[:1], STARTS)
    with pytest.raises(ValueError, match="positive, finite"):
        fit_quarter_car(model, z, -STARTS)
    with pytest.raises(ValueError, match="sigma"):
        fit_quarter_car(model, z, STARTS, sigma=-1.0)
