"""Identification through simulation on a small two-joint arm: gradient checks of the rollout loss through diffrax
and a noise-free round trip recovering rotor inertia, friction and a link mass from rollouts."""

import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from particlesim.identify import (
    fit_rollout, make_windows, model_with_params, params_from_theta, params_of_model, rollout_residuals,
    theta_from_params,
)
from particlesim.simulate import simulate
from particlesim.tree import forward_dynamics
from particlesim.io import load_urdf

EPS = 0.05  # rad/s, Coulomb smoothing
ODE_RTOL, ODE_ATOL = 1e-10, 1e-12  # fit (data: 100x tighter, so data and model differ only by solver error)
GRAD_TOL = 1e-5  # check_grads vs central differences of the adaptive solve
ROUND_TRIP_RTOL = 1e-6  # every fitted parameter, noise-free rollouts
RESIDUAL_FLOOR = 1e-8  # rad, RMS position error left by the solver tolerances (measured 1.7e-9)

URDF = """<robot name="two_link">
  <link name="base"/>
  <link name="upper"><inertial><origin xyz="0.02 0 0.15"/><mass value="2.0"/>
    <inertia ixx="0.02" iyy="0.021" izz="0.004" ixy="0.001" ixz="0" iyz="0"/></inertial></link>
  <link name="fore"><inertial><origin xyz="0.18 0.01 0"/><mass value="1.2"/>
    <inertia ixx="0.002" iyy="0.015" izz="0.016" ixy="0" ixz="0.0005" iyz="0"/></inertial></link>
  <joint name="shoulder" type="revolute"><parent link="base"/><child link="upper"/>
    <origin xyz="0 0 0.1"/><axis xyz="0 0 1"/></joint>
  <joint name="elbow" type="revolute"><parent link="upper"/><child link="fore"/>
    <origin xyz="0 0 0.3"/><axis xyz="0 1 0"/></joint>
</robot>"""
N = 2
ROTOR, VISCOUS, COULOMB = np.array([0.05, 0.03]), np.array([0.4, 0.25]), np.array([0.3, 0.2])
# Fitted: link 2's alpha (its mass scale, seen through gravity), rotor inertias, viscous and Coulomb friction.
FREE = np.concatenate([[10], np.arange(10 * N, 13 * N)])


@pytest.fixture(scope="module")
def case():
    model = load_urdf(URDF, gravity=(0.0, 0.0, -9.81))
    pi = np.concatenate([np.asarray(params_of_model(model))[:10 * N], ROTOR, VISCOUS, COULOMB])
    true = model_with_params(model, pi)
    ts = np.linspace(0.0, 2.0, 101)  # 50 Hz
    tau = np.stack([1.5 * np.sin(2 * np.pi * 0.7 * ts) + 0.5 * np.sin(2 * np.pi * 2.1 * ts),
                    1.2 * np.cos(2 * np.pi * 0.9 * ts) + 0.4 * np.sin(2 * np.pi * 2.7 * ts)], axis=1)
    tau_j = jnp.asarray(tau)

    def control(t, q, qd, m):  # the same piecewise-linear input the rollouts use
        return jax.vmap(lambda col: jnp.interp(t, jnp.asarray(ts), col), in_axes=1)(tau_j)

    def dyn(m, q, qd, u):
        return forward_dynamics(m, q, qd, u, smooth_friction=EPS)

    sol = simulate(dyn, true, jnp.zeros(N), jnp.zeros(N), 0.0, 2.0, control=control, saveat_ts=ts,
                   rtol=ODE_RTOL / 100, atol=ODE_ATOL / 100, solver="tsit5", max_steps=100_000)
    q, qd = np.asarray(sol.q), np.asarray(sol.qd)
    assert np.ptp(q, axis=0).min() > 0.2  # both joints move
    return model, np.asarray(theta_from_params(pi)), ts, q, qd, tau


@pytest.mark.slow
def test_check_grads_rollout_loss(case):
    model, theta, ts, q, qd, tau = case
    w = make_windows(ts, q, qd, tau, length=6, starts=[40])  # one 0.1 s window

    def loss(adjoint):
        def f(th):
            r = rollout_residuals(th, model, w, eps=EPS, rtol=ODE_RTOL, atol=ODE_ATOL, adjoint=adjoint)
            return 0.5 * jnp.mean(r ** 2)
        return jax.jit(f)  # compiled once; check_grads differentiates the compiled function

    th = jnp.asarray(theta) + 0.05 * jnp.asarray(np.random.default_rng(0).standard_normal(theta.shape))
    loss_checkpoint = loss("checkpoint")  # one jitted function: its primal compiles once for both uses below
    assert float(loss_checkpoint(th)) > 0
    # Each mode against central differences (jvp for forward mode, vjp through the checkpointed solve for reverse).
    check_grads(loss("forward"), (th,), order=1, modes=("fwd",), atol=GRAD_TOL, rtol=GRAD_TOL)
    check_grads(loss_checkpoint, (th,), order=1, modes=("rev",), atol=GRAD_TOL, rtol=GRAD_TOL)


@pytest.mark.slow
def test_rollout_round_trip_noise_free(case):
    model, theta, ts, q, qd, tau = case
    w = make_windows(ts, q, qd, tau, length=26, starts=[0, 25, 50, 75])  # four 0.5 s windows
    start = theta.copy()
    start[FREE] += np.array([0.2, 0.3, -0.3, 0.25, -0.2, 0.3, -0.25])
    t = time.perf_counter()
    fitted, before, after = fit_rollout(start, model, w, eps=EPS, free=FREE, max_steps=40, rtol=1e-12, atol=1e-14,
                                        ode_rtol=ODE_RTOL, ode_atol=ODE_ATOL, verbose=False)
    p_fit, p_true = np.asarray(params_from_theta(fitted)), np.asarray(params_from_theta(theta))
    sel = np.r_[10, 10 * N:13 * N]  # link 2's mass is pi[10]; then I_a, Fv, Fc
    rel = np.abs(p_fit[sel] / p_true[sel] - 1)
    print(f"\n  rollout fit {time.perf_counter() - t:.1f} s: RMS {before:.2e} -> {after:.2e} rad; "
          f"relative errors (m2, I_a, Fv, Fc) {rel}")
    np.testing.assert_array_equal(fitted[np.setdiff1d(np.arange(13 * N), FREE)],
                                  theta[np.setdiff1d(np.arange(13 * N), FREE)])
    assert before > 1e-3 and after < RESIDUAL_FLOOR
    assert np.all(rel < ROUND_TRIP_RTOL), rel
