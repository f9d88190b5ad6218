"""Hard cases for particle-coordinate mechanisms (numerical stability).

1. A free rigid body spinning at ~1000 rad/s: energy and angular momentum kept, rigid distances held by the
   projection, particle positions equal to Euler's equations integrated independently (scipy).
2. A 100 s horizon (double pendulum): constraint residual at round-off throughout, energy drift bounded.
3. A stiff spring-damper (k = 1e7 N/m, c = 1e5 N s/m) on a free 1 kg body: the exact solution (matrix
   exponential); through the projected solver, the implicit Kvaerno5 takes far fewer steps than Tsit5, which is
   held by its stability interval.
4. Chains of 64 bodies (spherical and revolute joints): the O(N) recursion equals the dense solve; a short run
   with the recursion keeps the constraints at round-off and the energy to the stated drift, without NaN.

Every tolerance is a named constant; the measured figures are printed (``pytest -s``).
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg
from scipy.integrate import solve_ivp

from particlesim.inertia import RigidInertia
from particlesim.mechanism import (
    MechanismBuilder,
    accelerations,
    chain_accelerations,
    chain_plan,
    project,
    residuals,
    simulate_mechanism,
    total_energy,
)
from particlesim.particles import balanced_primaries, particle_positions
from particlesim.scenes.chains import chain_geometry, chain_mechanism
from particlesim.scenes.rigid import free_body

#: Positions held by the projection [m] (bodies of size ~1 m; the residual is of the order of round-off).
CONSTRAINT_ATOL = 1e-12


def _energies_and_residual(mech, sol):
    """Total energies (T,) and the largest position-constraint residual over the saved states (one compiled call)."""
    f = jax.jit(lambda m, xs, vs: (jax.vmap(lambda x, v: total_energy(m, x, v))(xs, vs),
                                   jnp.abs(jax.vmap(lambda x, v: residuals(m, x, v)[0])(xs, vs)).max()))
    e, phi = f(mech, sol.q, sol.qd)
    return np.asarray(e), float(phi)


# ---------------------------------------------------------------------------------------------------------------
# 1. High-speed spin
# ---------------------------------------------------------------------------------------------------------------

BODY = RigidInertia(2.0, [0.1, -0.05, 0.2], [[0.30, 0.02, -0.01], [0.02, 0.20, 0.03], [-0.01, 0.03, 0.12]])
SPIN = np.array([600.0, -700.0, 400.0])  # rad/s, |w| = 1005
SPIN_T = 0.2  # s: 32 turns
SPIN_TS = np.linspace(0.0, SPIN_T, 21)
#: Energy and angular momentum about the CoM, relative, over the run (Dopri8 at rtol 1e-12).
SPIN_CONSERVATION_RTOL = 1e-9
#: Particle positions against Euler's equations (scipy DOP853 at rtol 1e-13) [m].
SPIN_EULER_ATOL = 1e-7


def _nodes(mech, x, xd):
    """All node (primary + secondary) positions, velocities and masses of body 0."""
    idx = np.asarray(mech.topo.body_particles[0])
    r = mech.all_positions(x)[idx]
    v = mech.all_positions(xd)[idx] * (~np.isin(idx, mech.ground))[:, None]
    return particle_positions(r), particle_positions(v), mech.particle_masses(0)


def _euler_points(i_body, omega0, com0, v0, pts):
    """Points of the body moving by Euler's equations (body axes = world axes at t = 0), at SPIN_TS."""
    inv = np.linalg.inv(i_body)

    def rhs(t, y):
        r, w = y[:9].reshape(3, 3), y[9:]
        return np.concatenate([(r @ np.cross(np.eye(3), w)).ravel(), -inv @ np.cross(w, i_body @ w)])  # R [w]x

    sol = solve_ivp(rhs, (0.0, SPIN_T), np.concatenate([np.eye(3).ravel(), omega0]), method="DOP853", rtol=1e-13,
                    atol=1e-13, t_eval=SPIN_TS)
    return np.stack([com0 + v0 * t + (pts - com0) @ sol.y[:9, k].reshape(3, 3).T for k, t in enumerate(SPIN_TS)])


@pytest.fixture(scope="module")
def spin_run():
    v_com = np.array([0.5, 0.0, -0.2])
    mech, x0, xd0 = free_body(BODY, v_com=v_com, omega=SPIN)
    sol = jax.jit(lambda m, x, v: simulate_mechanism(m, x, v, 0.0, SPIN_T, solver="dopri8", rtol=1e-12, atol=1e-13,
                                                     saveat_ts=SPIN_TS))(mech, jnp.asarray(x0), jnp.asarray(xd0))
    return mech, x0, v_com, sol


def test_fast_spin_keeps_energy_momentum_and_rigidity(spin_run):
    mech, _, _, sol = spin_run
    assert bool(sol.ok) and np.all(np.isfinite(sol.q)) and np.all(np.isfinite(sol.qd))
    e, phi = _energies_and_residual(mech, sol)

    def momentum(x, v):  # about the centre of mass
        r, rd, m = _nodes(mech, x, v)
        com = m @ r / jnp.sum(m)
        return jnp.sum(m[:, None] * jnp.cross(r - com[None, :], rd), axis=0)

    h = np.asarray(jax.jit(jax.vmap(momentum))(sol.q, sol.qd))
    de, dh = np.abs(e - e[0]).max() / e[0], np.abs(h - h[0]).max() / np.linalg.norm(h[0])
    print(f"\nspin {np.linalg.norm(SPIN):.0f} rad/s, {int(sol.steps)} steps: energy drift {de:.2e}, angular momentum "
          f"drift {dh:.2e}, constraint residual {phi:.2e} m")
    assert de <= SPIN_CONSERVATION_RTOL and dh <= SPIN_CONSERVATION_RTOL and phi <= CONSTRAINT_ATOL


def test_fast_spin_matches_euler_equations(spin_run):
    mech, x0, v_com, sol = spin_run
    ref = _euler_points(np.asarray(BODY.inertia), SPIN, np.asarray(BODY.com), v_com, x0.reshape(-1, 3))
    err = np.abs(np.asarray(sol.q).reshape(len(SPIN_TS), -1, 3) - ref).max()
    print(f"\nspin: max |x - Euler| = {err:.2e} m")
    assert err <= SPIN_EULER_ATOL


# ---------------------------------------------------------------------------------------------------------------
# 2. A 100 s horizon
# ---------------------------------------------------------------------------------------------------------------

LONG_T = 100.0
#: Relative drift of the total energy (relative to |E(0)|) over 100 s (Dopri8 at rtol 1e-11).
LONG_ENERGY_RTOL = 1e-9


def test_double_pendulum_100_s_horizon():
    mech, x0 = chain_mechanism(chain_geometry(2, "revolute", seed=2, tilt=1.0))
    ts = jnp.linspace(0.0, LONG_T, 101)
    sol = jax.jit(lambda m, x: simulate_mechanism(m, x, jnp.zeros_like(x), 0.0, LONG_T, solver="dopri8", rtol=1e-11,
                                                  atol=1e-12, saveat_ts=ts))(mech, jnp.asarray(x0))
    assert bool(sol.ok) and np.all(np.isfinite(sol.q))
    e, phi = _energies_and_residual(mech, sol)
    drift = np.abs(e - e[0]).max() / abs(e[0])
    print(f"\n100 s double pendulum: {int(sol.steps)} steps, energy drift {drift:.2e}, constraint residual "
          f"{phi:.2e} m")
    assert phi <= CONSTRAINT_ATOL and drift <= LONG_ENERGY_RTOL


# ---------------------------------------------------------------------------------------------------------------
# 3. A stiff spring-damper on a free body
# ---------------------------------------------------------------------------------------------------------------

STIFFNESS, DAMPING = 1e7, 1e5  # eigenvalues -99899.9 and -100.1 1/s on 1 kg
STRETCH = 0.01  # m
SPRING_T = 0.5
#: CoM position against the matrix exponential [m] (rtol 1e-8); 1e-6 of the stretch.
SPRING_ATOL = 1e-8
#: Kvaerno5 must take at least this many times fewer steps than Tsit5.
SPRING_STEP_RATIO = 20


@pytest.mark.slow  # two compilations of the projected solver (~7 s Tsit5, ~19 s Kvaerno5 on a quiet machine)
def test_stiff_spring_on_a_free_body():
    # The spring acts through the CoM along x, the body starts at rest: a pure translation, x_G'' = -k e - c e'.
    block = RigidInertia(1.0, [0.0, 0.0, 0.0], np.diag([0.01, 0.012, 0.015]))
    mb = MechanismBuilder(gravity=(0.0, 0.0, 0.0))
    names = [mb.particle(f"p{i}", p) for i, p in enumerate(balanced_primaries(block))]
    mb.body("block", block, names, on_negative="raise")
    mb.ground("anchor", [-0.5, 0.0, 0.0])
    mb.point("hook", "block", [0.0, 0.0, 0.0])
    mb.spring_damper("stiff", "anchor", "hook", STIFFNESS, DAMPING, 0.5 - STRETCH)
    mech, x0 = mb.build(dof=6)
    ts = np.linspace(0.0, SPRING_T, 11)
    a = np.array([[0.0, 1.0], [-STIFFNESS, -DAMPING]])
    exact = np.array([scipy.linalg.expm(a * t) @ np.array([STRETCH, 0.0]) for t in ts])[:, 0] - STRETCH
    steps = {}
    for solver in ("tsit5", "kvaerno5"):
        sol = jax.jit(lambda m, x: simulate_mechanism(m, x, jnp.zeros_like(x), 0.0, SPRING_T, solver=solver,
                                                      rtol=1e-8, atol=1e-10, saveat_ts=ts))(mech, jnp.asarray(x0))
        assert bool(sol.ok) and np.all(np.isfinite(sol.q))
        com = np.asarray(sol.q).reshape(len(ts), -1, 3).mean(axis=1)  # balanced layout: the primaries' centroid
        err = np.abs(com[:, 0] - exact).max()
        steps[solver] = int(sol.steps)
        print(f"\nstiff spring on a free body, {solver}: {steps[solver]} steps, max |x_G - exact| = {err:.2e} m")
        assert err <= SPRING_ATOL and np.abs(com[:, 1:]).max() <= SPRING_ATOL
    assert steps["kvaerno5"] * SPRING_STEP_RATIO < steps["tsit5"]


# ---------------------------------------------------------------------------------------------------------------
# 4. Chains of 64 bodies
# ---------------------------------------------------------------------------------------------------------------

N_LONG = 64
#: Recursion against dense solve, relative to the largest acceleration (both exact solves in float64).
CHAIN_ACC_RTOL = 1e-10
CHAIN_T = 0.2
#: Relative energy drift over CHAIN_T (Tsit5 at rtol 1e-9; relative to |E(0)|).
CHAIN_ENERGY_RTOL = 1e-9


@pytest.fixture(scope="module", params=["spherical", "revolute"])
def long_chain(request):
    mech, x0 = chain_mechanism(chain_geometry(N_LONG, request.param, seed=64, tilt=0.3))
    return request.param, mech, jnp.asarray(x0)


def test_chain_of_64_bodies_recursion_equals_dense_solve(long_chain):
    joint, mech, x0 = long_chain
    plan = chain_plan(mech)

    @jax.jit
    def both_solves(m, xd_guess):
        x, xd = project(m, x0, xd_guess)  # an admissible velocity
        return accelerations(m, 0.0, x, xd), chain_accelerations(m, plan, 0.0, x, xd)

    dense, rec = both_solves(mech, jnp.asarray(np.random.default_rng(1).normal(size=x0.shape)))
    acc_err = float(jnp.abs(rec - dense).max() / jnp.abs(dense).max())
    print(f"\n{N_LONG} {joint} links: recursion vs dense {acc_err:.2e} of the largest acceleration")
    assert np.all(np.isfinite(rec)) and acc_err <= CHAIN_ACC_RTOL


@pytest.mark.slow  # the projection after every step is a dense solve (~0.2 s per step for 64 spherical links)
def test_chain_of_64_bodies_rollout(long_chain):
    joint, mech, x0 = long_chain
    sol = jax.jit(lambda m, x: simulate_mechanism(m, x, jnp.zeros_like(x), 0.0, CHAIN_T, solver="tsit5", rtol=1e-9,
                                                  atol=1e-10, saveat_ts=jnp.linspace(0.0, CHAIN_T, 5),
                                                  solve="chain"))(mech, x0)
    assert bool(sol.ok) and np.all(np.isfinite(sol.q)) and np.all(np.isfinite(sol.qd))
    e, phi = _energies_and_residual(mech, sol)
    drift = np.abs(e - e[0]).max() / abs(e[0])
    print(f"\n{N_LONG} {joint} links: {CHAIN_T} s in {int(sol.steps)} steps, energy drift {drift:.2e}, constraint "
          f"residual {phi:.2e} m")
    assert phi <= CONSTRAINT_ATOL and drift <= CHAIN_ENERGY_RTOL
