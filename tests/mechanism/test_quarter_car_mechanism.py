"""The quarter car (Attia §3, assumptions in its module): MuJoCo C twin, static equilibrium, loop closure."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from particlesim.mechanism import constraints, generalized_forces, residuals, simulate_mechanism
from particlesim.mechanism.constraints import constraint_jacobian
from particlesim.scenes import quarter_car as qc
from particlesim.twins.quarter_car import twin_rollout

T_END = 3.0
TS = np.linspace(0.0, T_END, 301)
TWIN_DT = 1e-4
LOOP_ATOL = 1e-9  # m (acceptance)
SAFETY = 3.0
EQUILIBRIUM_RTOL = 1e-6


@pytest.fixture(scope="module")
def qc_run():
    mech, x0 = qc.quarter_car()
    run = jax.jit(lambda m, x: simulate_mechanism(m, x, jnp.zeros_like(x), 0.0, T_END, solver="dopri8", rtol=1e-12,
                                                  atol=1e-14, saveat_ts=TS))
    sol = run(mech, jnp.asarray(x0))
    assert bool(sol.ok)
    return mech, x0, sol


def _heights(mech, q):
    kc = mech.point_index("centre")
    kw = mech.index("P10")
    pts = jax.vmap(lambda x: mech.point_positions(mech.all_positions(x)))(q)
    return np.asarray(pts[:, kc, 2]), np.asarray(pts[:, kw, 2])


@pytest.mark.slow
def test_quarter_car_matches_its_mujoco_twin(qc_run):
    """Tolerance: the twin's own error, i.e. its soft loop residual plus RK4's step-halving error estimate."""
    mech, _, sol = qc_run
    chassis, wheel = _heights(mech, sol.q)
    coarse = twin_rollout(TS, TWIN_DT)
    fine = twin_rollout(TS, TWIN_DT / 2)
    soft = max(coarse["loop_residual"].max(), fine["loop_residual"].max())
    for ours, key in ((chassis, "chassis_z"), (wheel, "wheel_z")):
        rk4 = 16.0 / 15.0 * np.abs(coarse[key] - fine[key]).max()
        err = np.abs(ours - coarse[key]).max()
        print(f"{key}: |ours - twin| = {err:.2e} m; twin soft-loop residual {soft:.2e} m, RK4 estimate {rk4:.2e} m")
        assert err <= SAFETY * (soft + rk4)


def test_loop_closure_over_the_run(qc_run):
    mech, _, sol = qc_run
    worst = max(float(jnp.abs(residuals(mech, x, v)[0]).max()) for x, v in zip(sol.q[::10], sol.qd[::10]))
    assert worst <= LOOP_ATOL


def _static_equilibrium(mech, x_start):
    """Newton on Q(x, 0) - J(x)^T lam = 0, Phi(x) = 0 (positions and constraint forces), from ``x_start``."""
    n = x_start.shape[0]

    def eqs(z):
        x, lam = z[:n], z[n:]
        return jnp.concatenate([generalized_forces(mech, 0.0, x, jnp.zeros_like(x))
                                - constraint_jacobian(mech, x).T @ lam, constraints(mech, x)])

    z = jnp.concatenate([x_start, jnp.zeros(constraints(mech, x_start).shape[0])])
    f = jax.jit(lambda z: (eqs(z), jax.jacfwd(eqs)(z)))
    for _ in range(30):
        r, jac = f(z)
        # Columns scaled to unit norm: positions (forces ~1e5 N/m per m) and multipliers differ by orders of magnitude,
        # and the wheel's spin is a null direction of the statics; unscaled, lstsq's cutoff drops real directions.
        sc = jnp.linalg.norm(jac, axis=0)
        sc = jnp.where(sc > 0, sc, 1.0)
        z = z - jnp.linalg.lstsq(jac / sc[None, :], r)[0] / sc
    return z[:n], float(jnp.abs(f(z)[0]).max())


def test_static_equilibrium_consistent_with_spring_and_tyre(qc_run):
    """Statics, solved independently of the rollout: the tyre carries the whole weight (the vertical slider takes
    no vertical load), and the free response settles onto that equilibrium."""
    mech, _, sol = qc_run
    x_eq, residual = _static_equilibrium(mech, sol.q[-1])
    weight = 9.81 * sum(m for m, _ in qc.TABLE1.values())
    assert residual <= 1e-9 * weight  # N (force rows) and m (constraint rows)
    wheel_z = float(mech.all_positions(x_eq)[mech.index("P10"), 2])
    ground = qc._p(10)[2] - qc.TYRE["radius"]
    tyre_force = -qc.TYRE["stiffness"] * (wheel_z - ground - qc.TYRE["radius"])
    np.testing.assert_allclose(tyre_force, weight, rtol=EQUILIBRIUM_RTOL)
    k = mech.point_index("centre")
    z_eq = float(mech.point_positions(mech.all_positions(x_eq))[k, 2])
    z_end = float(mech.point_positions(mech.all_positions(sol.q[-1]))[k, 2])
    v_end = float(jnp.abs(sol.qd[-1]).max())
    print(f"chassis: equilibrium z {z_eq:.9f} m, end of 3 s run {z_end:.9f} m (speed still {v_end:.1e} m/s)")
    assert abs(z_end - z_eq) <= 1e-3 and abs(z_end - z_eq) <= 10 * v_end  # overdamped creep, ~0.1 s away
