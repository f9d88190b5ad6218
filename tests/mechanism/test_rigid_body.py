"""A free body and a heavy top in particle coordinates, against Euler's equations solved independently (scipy)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from particlesim.inertia import RigidInertia
from particlesim.mechanism import residuals, simulate_mechanism, total_energy
from particlesim.particles import particle_positions
from particlesim.scenes.rigid import free_body, top
from particlesim.spatial import skew

CONSERVATION_RTOL = 1e-9  # energy and angular momentum over 10 s
EULER_ATOL = 1e-7  # particle positions [m] against the independent Euler-equation solution (both at rtol 1e-12)
CONSTRAINT_ATOL = 1e-12  # projected every step
T_END = 10.0
TS = np.linspace(0.0, T_END, 41)

BODY = RigidInertia(2.0, [0.1, -0.05, 0.2], [[0.30, 0.02, -0.01], [0.02, 0.20, 0.03], [-0.01, 0.03, 0.12]])


def _nodes(mech, x, xd):
    """All node (primary + secondary) positions, velocities and masses of body 0."""
    idx = np.asarray(mech.topo.body_particles[0])
    r = mech.all_positions(x)[idx]
    v = mech.all_positions(xd)[idx] * (~np.isin(idx, mech.ground))[:, None]
    return particle_positions(r), particle_positions(v), mech.particle_masses(0)


def _momentum(mech, x, xd, about):
    r, v, m = _nodes(mech, x, xd)
    return jnp.sum(m[:, None] * jnp.cross(r - about[None, :], v), axis=0)


def _euler_reference(i_body, omega0, com0, v0, pts_body, gravity_torque=None):
    """Integrate R' = R [w]x, I w' = -w x I w + tau (body axes) with scipy; returns points over TS."""
    inv = np.linalg.inv(i_body)

    def rhs(t, y):
        r = y[:9].reshape(3, 3)
        w = y[9:12]
        tau = gravity_torque(r) if gravity_torque is not None else np.zeros(3)
        return np.concatenate([(r @ skew(w)).ravel(), inv @ (tau - np.cross(w, i_body @ w))])

    sol = solve_ivp(rhs, (0, T_END), np.concatenate([np.eye(3).ravel(), omega0]), method="DOP853", rtol=1e-12,
                    atol=1e-13, t_eval=TS)
    out = []
    for k, t in enumerate(TS):
        r = sol.y[:9, k].reshape(3, 3)
        out.append(com0 + v0 * t + (pts_body - com0) @ r.T)
    return np.asarray(out)


@pytest.fixture(scope="module")
def free_run():
    omega = np.array([0.3, 2.0, -1.1])
    mech, x0, xd0 = free_body(BODY, v_com=[0.2, 0.0, -0.1], omega=omega)
    sol = jax.jit(lambda m, x, v: simulate_mechanism(m, x, v, 0.0, T_END, solver="dopri8", rtol=1e-12, atol=1e-13,
                                                     saveat_ts=TS))(mech, jnp.asarray(x0), jnp.asarray(xd0))
    return mech, x0, xd0, omega, sol


def test_free_body_conserves_energy_and_angular_momentum(free_run):
    mech, _, _, _, sol = free_run
    e = jax.vmap(lambda x, v: total_energy(mech, x, v))(sol.q, sol.qd)
    np.testing.assert_allclose(e, e[0], rtol=CONSERVATION_RTOL)
    mass = float(BODY.mass)
    coms = [jnp.sum(_nodes(mech, x, v)[2][:, None] * _nodes(mech, x, v)[0], 0) / mass for x, v in zip(sol.q, sol.qd)]
    h = np.array([_momentum(mech, x, v, c) for x, v, c in zip(sol.q, sol.qd, coms)])
    np.testing.assert_allclose(h, np.broadcast_to(h[0], h.shape), rtol=0, atol=CONSERVATION_RTOL * np.linalg.norm(h[0]))


def test_free_body_matches_euler_equations(free_run):
    mech, x0, _, omega, sol = free_run
    # Body frame = world frame at t = 0; Euler's equations about the CoM in body axes.
    ref = _euler_reference(np.asarray(BODY.inertia), omega, np.asarray(BODY.com), np.array([0.2, 0.0, -0.1]),
                           x0.reshape(-1, 3))
    np.testing.assert_allclose(np.asarray(sol.q).reshape(len(TS), -1, 3), ref, rtol=0, atol=EULER_ATOL)
    for x, v in zip(sol.q, sol.qd):
        pos, vel = residuals(mech, x, v)
        assert np.max(np.abs(pos)) <= CONSTRAINT_ATOL and np.max(np.abs(vel)) <= CONSTRAINT_ATOL


def test_heavy_top_matches_euler_equations_and_conserves():
    omega = np.array([0.5, -0.4, 12.0])
    mech, x0, xd0 = top(BODY, omega)
    sol = jax.jit(lambda m, x, v: simulate_mechanism(m, x, v, 0.0, T_END, solver="dopri8", rtol=1e-12, atol=1e-13,
                                                     saveat_ts=TS))(mech, jnp.asarray(x0), jnp.asarray(xd0))
    g = np.array([0.0, 0.0, -9.81])
    i_o = np.asarray(BODY.about(np.zeros(3)))
    c = np.asarray(BODY.com)
    ref = _euler_reference(i_o, omega, np.zeros(3), np.zeros(3), x0.reshape(-1, 3),
                           gravity_torque=lambda r: np.cross(c, float(BODY.mass) * (r.T @ g)))
    np.testing.assert_allclose(np.asarray(sol.q).reshape(len(TS), -1, 3), ref, rtol=0, atol=EULER_ATOL)
    e = jax.vmap(lambda x, v: total_energy(mech, x, v))(sol.q, sol.qd)
    np.testing.assert_allclose(e, e[0], rtol=CONSERVATION_RTOL)
    lz = np.array([_momentum(mech, x, v, jnp.zeros(3))[2] for x, v in zip(sol.q, sol.qd)])
    np.testing.assert_allclose(lz, lz[0], rtol=CONSERVATION_RTOL)
