"""A pendulum on a free cart, built in the plane through the public builder as the README and the mechanisms guide
describe it: the cart a rod whose two ends are kept on a horizontal rail (`on_line` with two ground points), the
pole a uniform rod pinned to the cart's first end (a shared particle). No horizontal force acts, so the horizontal
momentum stays zero; energy is conserved. Against an independent solution in (cart position, pole angle): the
Lagrangian written out by hand in NumPy, integrated by SciPy's DOP853. Also the gradient of the pole angle at
``T_GRAD`` with respect to the cart's mass (reverse mode through the rollout) against a central difference of the
reference."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from particlesim.mechanism import (MechanismBuilder, body_angles, body_velocities, point_positions,
                                   simulate_mechanism, total_energy)

#: Pole angle [rad] and cart position [m] against the reference (ours at rtol 1e-10, the reference at 1e-12;
#: measured 2.3e-10 rad and 2.1e-11 m).
ANGLE_TOL = 1e-8
POSITION_TOL = 1e-9
#: Horizontal momentum [kg m/s] (zero at the start; measured 2.3e-15) and energy change [J] (of 1.23 J exchanged
#: between potential and kinetic; measured 1.0e-9 at rtol 1e-10).
MOMENTUM_TOL = 1e-12
ENERGY_TOL = 1e-8
#: d(pole angle at T_GRAD)/d(cart mass), reverse mode against the reference's central difference (step 1e-4 kg),
#: relative: measured 1.4e-9 (5.4e-9 at a step of 1e-5, 1.1e-7 at 1e-3, the difference's own truncation).
GRAD_RTOL = 1e-7

G = 9.81
M_CART, M_POLE, L_POLE = 2.0, 0.5, 1.0
TH0 = np.deg2rad(60.0)  # the pole's angle from hanging straight down
T_END, T_GRAD = 3.0, 1.5
TS = np.linspace(0.0, T_END, 61)


def build():
    mb = MechanismBuilder(planar=True)  # gravity along -y
    mb.ground("R0", (0.0, 0.0))
    mb.ground("R1", (1.0, 0.0))
    mb.particle("C1", (0.0, 0.0))
    mb.particle("C2", (0.4, 0.0))
    mb.particle("P", (L_POLE * np.sin(TH0), -L_POLE * np.cos(TH0)))
    mb.rod("cart", "C1", "C2", mass=M_CART)
    mb.rod("pole", "C1", "P", mass=M_POLE)  # pinned at C1
    mb.on_line("C1", "R0", ("R0", "R1"))
    mb.on_line("C2", "R0", ("R0", "R1"))  # both ends on the rail: the cart only slides
    return mb.build(dof=2)


def reference(ts, m_cart=M_CART):
    """(x, theta) at ``ts``: the cart's position and the pole's angle from hanging down."""
    m, ell = M_POLE, L_POLE

    def rhs(t, y):
        x, th, xd, thd = y
        mass = np.array([[m_cart + m, m * ell / 2 * np.cos(th)], [m * ell / 2 * np.cos(th), m * ell**2 / 3]])
        force = np.array([m * ell / 2 * np.sin(th) * thd**2, -m * G * ell / 2 * np.sin(th)])
        return [xd, thd, *np.linalg.solve(mass, force)]

    sol = solve_ivp(rhs, (0.0, float(ts[-1])), [0.0, TH0, 0.0, 0.0], method="DOP853", t_eval=ts, rtol=1e-12,
                    atol=1e-14)
    assert sol.success
    return sol.y[0], sol.y[1]


@pytest.fixture(scope="module")
def rollout(released_from_rest):
    return released_from_rest(build, T_END, TS, rtol=1e-10, atol=1e-12)


def test_cart_pendulum_is_two_dof(rollout):
    mech, _, _ = rollout
    assert mech.n_coords == 9 and mech.n_constraints == 7  # C1, C2, P free; 2 rods, 2 on the rail, 3 in the plane


def test_cart_pendulum_matches_lagrangian(rollout):
    mech, _, sol = rollout
    ref_x, ref_th = reference(TS)
    angles = np.unwrap(np.asarray(jax.vmap(lambda q: body_angles(mech, q))(sol.q)), axis=0)
    pole = angles[:, mech.body_index("pole")]
    theta = pole - pole[0] + TH0
    x = np.asarray(jax.vmap(lambda q: point_positions(mech, q, "C1"))(sol.q)).reshape(len(TS), -1)[:, 0]
    assert np.ptp(ref_x) > 0.1 and np.ptp(ref_th) > 2.0  # the cart moves, the pole swings
    np.testing.assert_allclose(theta, ref_th, rtol=0, atol=ANGLE_TOL)
    np.testing.assert_allclose(x, ref_x, rtol=0, atol=POSITION_TOL)


def test_cart_pendulum_conserves_momentum_and_energy(rollout):
    mech, _, sol = rollout
    v_com, _ = jax.vmap(lambda q, qd: body_velocities(mech, q, qd))(sol.q, sol.qd)
    masses = np.asarray(mech.body_mass)
    momentum = np.asarray(v_com[:, :, 0]) @ masses
    assert np.abs(np.asarray(v_com[:, :, 0])).max() > 0.1  # the bodies do move sideways
    assert np.abs(momentum).max() < MOMENTUM_TOL
    energy = np.asarray(jax.vmap(lambda q, qd: total_energy(mech, q, qd))(sol.q, sol.qd))
    assert np.abs(energy - energy[0]).max() < ENERGY_TOL


def test_cart_pendulum_gradient_wrt_cart_mass(rollout):
    mech, q0, _ = rollout
    cart = mech.body_index("cart")

    def pole_angle(m):
        heavier = mech.with_params(body={"cart": {"mass": m, "inertia": m / M_CART * mech.body_inertia[cart]}})
        s = simulate_mechanism(heavier, q0, 0 * q0, 0.0, T_GRAD, rtol=1e-10, atol=1e-12)
        c, p = point_positions(heavier, s.q[-1], "C1"), point_positions(heavier, s.q[-1], "P")
        return jnp.arctan2(p[0] - c[0], c[1] - p[1])

    ours = float(jax.grad(pole_angle)(jnp.asarray(M_CART)))
    h = 1e-4
    ts = np.array([0.0, T_GRAD])
    fd = (reference(ts, M_CART + h)[1][-1] - reference(ts, M_CART - h)[1][-1]) / (2 * h)
    assert abs(fd) > 1e-3
    assert abs(ours - fd) <= GRAD_RTOL * abs(fd)
