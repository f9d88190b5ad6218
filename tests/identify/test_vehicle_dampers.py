"""The full vehicle's four shock damping rates identified from a four-post rig run (the ride study's acceptance):
chassis heave, pitch and roll over 3 s of an ISO 8608 class C road (left and right tracks independent, the rear
wheels a wheelbase behind; ``particlesim.reports.vehicle_ride``), sampled at 500 Hz with Gaussian noise of 1 % of
each channel's RMS, fitted by Gauss–Newton (``fit_traces``, forward-mode Jacobians through the rollout) from a start
20-30 % off. The same experiment is shown in ``notebooks/vehicle_ride.ipynb``."""

import time

import jax.numpy as jnp
import numpy as np
import pytest

from particlesim.identify import fit_traces, trace_model
from particlesim.mechanism import assemble, body_com_positions, body_poses
from particlesim.reports import vehicle_ride as vr

CORNERS = ("FL", "FR", "RL", "RR")
DURATION, N_SAMPLES = 3.0, 1501  # s; 500 Hz
NOISE = 0.01  # Gaussian noise of each channel, relative to the channel's RMS
START = np.array([1.3, 0.8, 1.2, 0.75])  # times the true rates
SIGMA_BOUND = 3.0  # every rate within 3 standard errors of the truth
RATE_RTOL = 0.005  # and within 0.5 % of it (the acceptance; standard errors measured 0.09-0.14 %)
RESIDUAL_RTOL = 0.1  # the fit's RMS residual at the noise level (converged to the noise floor)
POSE_ATOL = 1e-12  # m, rad: the chassis read-out against body_poses (round-off)


@pytest.fixture(scope="module")
def car():
    """The car on the random road from rest (no bump), at rest, and its chassis read-out."""
    mech, q_rest = vr.ride_car(vr.rig_roads(bump_height=0.0, iso_start=0.0))
    return mech, q_rest, vr.ChassisMotion(mech, q_rest)


def test_the_measured_chassis_motion_is_the_body_pose(car):
    """What the fit observes (heave, pitch, roll from three chassis particles) equals the same quantities from
    ``body_poses``/``body_com_positions`` at states moved off the rest (assembled onto the constraints)."""
    mech, q_rest, motion = car
    b = mech.body_index("chassis")
    rot0, com0 = body_poses(mech, q_rest)[0][b], body_com_positions(mech, q_rest)[b]
    rng = np.random.default_rng(1)
    for _ in range(3):
        q = jnp.asarray(assemble(mech, q_rest + 0.02 * rng.standard_normal(q_rest.shape)).q)
        r = np.asarray(body_poses(mech, q)[0][b] @ rot0.T)
        want = [float(body_com_positions(mech, q)[b, 2] - com0[2]), np.arcsin(-r[2, 0]), np.arctan2(r[2, 1], r[2, 2])]
        assert abs(want[0]) > 1e-3 and max(map(abs, want[1:])) > 1e-3  # it moved
        np.testing.assert_allclose(np.asarray(motion(mech, q)), want, rtol=0, atol=POSE_ATOL)


@pytest.fixture(scope="module")
def fit(car):
    """Truth, fit and the fit's wall time (model built and compiled, fitted)."""
    mech, q_rest, motion = car
    ts = np.linspace(0.0, DURATION, N_SAMPLES)
    params = {c: ("spring", f"shock {c}", "damping") for c in CORNERS}
    true = np.asarray(mech.spring_damping[1::2])
    assert mech.topo.spring_names[1::2] == tuple(f"shock {c}" for c in CORNERS)
    clean = np.asarray(trace_model(mech, q_rest, ts, params, motion).outputs(jnp.asarray(true[None])))[0]
    scale = np.sqrt(np.mean(clean**2, axis=(0, 1)))  # heave [m], pitch and roll [rad]
    measured = clean / scale + NOISE * np.random.default_rng(0).standard_normal(clean.shape)
    t0 = time.perf_counter()
    model = trace_model(mech, q_rest, ts, params, lambda m, x: motion(m, x) / scale)
    result = fit_traces(model, measured, true[None] * START, sigma=NOISE)
    return true, result, time.perf_counter() - t0


@pytest.mark.slow
def test_shock_damping_rates_from_noisy_chassis_motion(fit):
    true, result, seconds = fit
    err = result.p / true - 1
    print(f"\n  relative errors {err}, standard errors {result.rel_std}, {result.evaluations} evaluations, "
          f"fit {seconds:.1f} s (compile included)")
    assert result.converged.all()
    assert np.all(np.abs(err) <= SIGMA_BOUND * result.rel_std), (err, result.rel_std)
    assert np.all(np.abs(err) <= RATE_RTOL), err
    assert abs(result.rms / NOISE - 1) <= RESIDUAL_RTOL
