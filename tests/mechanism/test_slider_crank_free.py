"""A free planar slider-crank (crank, connecting rod, and a block sliding on the x axis held by two pins in the
ground's line), released from rest under gravity with a spring pulling the block: built from the builder's planar
vocabulary alone, against the Lagrange equation of the crank angle written here (one coordinate, the constraints
solved in closed form) and integrated by diffrax."""

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from particlesim.mechanism import MechanismBuilder, point_positions, simulate_mechanism, total_energy

#: The block's position, ours against the crank-angle solution [m] (both at rtol 1e-10 or tighter; measured 4e-11).
POSITION_TOL = 1e-9
#: Energy drift over the run, no damping [J] (measured 5e-9 at rtol 1e-10; the spring holds 7 J at the start).
ENERGY_TOL = 1e-7
G = 9.81
R, L, S = 0.3, 1.0, 0.2  # crank, connecting rod, block lengths [m]
M_CRANK, M_ROD, M_BLOCK = 1.0, 2.0, 3.0
K, FREE, WALL = 40.0, 0.5, 2.5  # spring from the block's far end to a wall point on the x axis
THETA0 = 0.7
T1 = 2.0
TS = np.linspace(0.0, T1, 101)
#: The block's travel over the run must exceed this [m] (it swings 0.34 m): a block left still would pass trivially.
MIN_TRAVEL = 0.3


def _slider_x(theta):
    return R * jnp.cos(theta) + jnp.sqrt(L**2 - (R * jnp.sin(theta)) ** 2)


@pytest.fixture(scope="module")
def run():
    xb = float(_slider_x(THETA0))
    mb = MechanismBuilder(planar=True)
    mb.ground("O", (0.0, 0.0))
    mb.ground("X", (1.0, 0.0))
    mb.ground("wall", (WALL, 0.0))
    mb.particle("A", (R * np.cos(THETA0), R * np.sin(THETA0)))
    mb.particle("B", (xb, 0.0))
    mb.particle("B2", (xb + S, 0.0))
    mb.rod("crank", "O", "A", mass=M_CRANK)
    mb.rod("rod", "A", "B", mass=M_ROD)
    mb.rod("block", "B", "B2", mass=M_BLOCK)
    mb.on_line("B", "O", ("O", "X"))
    mb.on_line("B2", "O", ("O", "X"))
    mb.spring_damper("spring", "B2", "wall", stiffness=K, damping=0.0, free_length=FREE)
    mech, q0 = mb.build(dof=1)
    sol = simulate_mechanism(mech, q0, 0 * q0, 0.0, T1, saveat_ts=TS, solver="dopri8", rtol=1e-10, atol=1e-12)
    return mech, sol


def _crank_angle_solution():
    """The Lagrange equation of the crank angle: every centre of mass and body angle as a function of it."""

    def coordinates(th):
        a = R * jnp.array([jnp.cos(th), jnp.sin(th)])
        b = jnp.array([_slider_x(th), 0.0])
        phi = jnp.arctan2(b[1] - a[1], b[0] - a[0])
        return jnp.concatenate([a / 2, (a + b) / 2, b + jnp.array([S / 2, 0.0]), jnp.array([th, phi])])

    def lagrangian(th, thd):
        c, cd = jax.jvp(coordinates, (th,), (thd,))
        m = jnp.array([M_CRANK, M_CRANK, M_ROD, M_ROD, M_BLOCK, M_BLOCK])
        kinetic = 0.5 * jnp.sum(m * cd[:6] ** 2) + 0.5 * M_CRANK * R**2 / 12 * cd[6] ** 2 \
            + 0.5 * M_ROD * L**2 / 12 * cd[7] ** 2
        stretch = WALL - (c[4] + S / 2) - FREE
        potential = G * (M_CRANK * c[1] + M_ROD * c[3] + M_BLOCK * c[5]) + 0.5 * K * stretch**2
        return kinetic - potential

    def field(t, y, args):
        th, thd = y
        mass = jax.grad(jax.grad(lagrangian, 1), 1)(th, thd)
        rhs = jax.grad(lagrangian, 0)(th, thd) - jax.grad(jax.grad(lagrangian, 1), 0)(th, thd) * thd
        return jnp.array([thd, rhs / mass])

    sol = diffrax.diffeqsolve(diffrax.ODETerm(field), diffrax.Dopri8(), 0.0, T1, 1e-3, jnp.array([THETA0, 0.0]),
                              saveat=diffrax.SaveAt(ts=TS), max_steps=100_000,
                              stepsize_controller=diffrax.PIDController(rtol=1e-12, atol=1e-14))
    return np.asarray(jax.vmap(_slider_x)(sol.ys[:, 0]))


def test_free_slider_crank_matches_the_crank_angle_lagrange_equation(run):
    mech, sol = run
    ours = np.asarray(jax.vmap(lambda q: point_positions(mech, q, "B")[0])(sol.q))
    ref = _crank_angle_solution()
    assert np.ptp(ref) > MIN_TRAVEL
    np.testing.assert_allclose(ours, ref, rtol=0.0, atol=POSITION_TOL)


def test_free_slider_crank_conserves_energy(run):
    mech, sol = run
    energy = np.asarray(jax.vmap(lambda q, qd: total_energy(mech, q, qd))(sol.q, sol.qd))
    assert np.abs(energy - energy[0]).max() < ENERGY_TOL
