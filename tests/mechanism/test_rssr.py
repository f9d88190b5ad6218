"""A spatial RSSR linkage (revolute - spherical - spherical - revolute, the two revolute axes skew: z through the
origin and x through (0.3, 0.2, 0)), built through the public builder as the docs describe it: each crank a body
with two ground particles on its axis and its tip, the coupler a rod, the loop closed by a cut joint. Released
from rest under gravity, against an independent solution in joint coordinates: the crank and rocker angles with the
loop as one constraint, its Lagrangian written out by hand (mass matrix, Coriolis terms, gravity, the constraint's
second derivative) in NumPy and integrated by SciPy's DOP853. Also the gradient of the crank angle with respect to
the coupler's mass (reverse mode through the rollout) against a central difference of the reference."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from particlesim.inertia import RigidInertia
from particlesim.mechanism import MechanismBuilder, point_positions, simulate_mechanism, total_energy

#: Crank and rocker angles against the joint-coordinate solution [rad] (ours at rtol 1e-11, the reference at
#: 1e-12; measured 2.0e-10 and 1.8e-10).
ANGLE_TOL = 1e-8
#: Energy change over the run [J] (of 1.13 J; measured 2.8e-11) and the loop's closure |A - B| - L [m] (round-off).
ENERGY_TOL = 1e-9
CLOSURE_TOL = 1e-12
#: d(crank angle at T_GRAD)/d(coupler mass), ours (reverse mode) against the reference's central difference
#: (step 1e-4 kg), relative: measured 3.5e-7 (5.5e-7 at a step of 1e-3, 5.7e-6 at 1e-5, where the reference's own
#: tolerance over the step dominates).
GRAD_RTOL = 1e-5

G = 9.81
M_CRANK, M_ROCKER, M_COUPLER = 0.5, 0.8, 1.2
L_CRANK, L_ROCKER = 0.1, 0.15
PIVOT = np.array([0.3, 0.2, 0.0])  # the rocker's axis: along x through this point
PHI0 = np.deg2rad(40.0)  # the rocker's angle from +z at the start (the crank starts along +x)
T_END, T_GRAD = 2.0, 1.0
TS = np.linspace(0.0, T_END, 101)


def _tips(theta, phi):
    a = np.array([L_CRANK * np.cos(theta), L_CRANK * np.sin(theta), 0.0])
    b = PIVOT + np.array([0.0, L_ROCKER * np.sin(phi), L_ROCKER * np.cos(phi)])
    return a, b


def build(m_coupler=M_COUPLER):
    rod = RigidInertia.slender_rod
    a0, b0 = _tips(0.0, PHI0)
    mb = MechanismBuilder(gravity=(0.0, 0.0, -G))
    mb.ground("G1", (0.0, 0.0, 0.0))
    mb.ground("G2", (0.0, 0.0, 0.1))
    mb.particle("A", a0)
    mb.body("crank", rod(M_CRANK, (0.0, 0.0, 0.0), a0), ["G1", "G2", "A"])  # revolute about z
    mb.ground("H1", PIVOT)
    mb.ground("H2", PIVOT + (0.1, 0.0, 0.0))
    mb.particle("B'", b0)
    mb.body("rocker", rod(M_ROCKER, PIVOT, b0), ["H1", "H2", "B'"])  # revolute about x
    mb.particle("B", b0)
    mb.rod("coupler", "A", "B", mass=m_coupler)  # spherical joints at both ends
    mb.cut_joint("B", "B'")
    return mb.build(dof=1)


def reference(ts, m_coupler=M_COUPLER):
    """(theta, phi) at ``ts``: the joint-coordinate equations with the loop |A - B|^2 = L^2 as a constraint."""
    i_c = M_CRANK * L_CRANK**2 / 3 + m_coupler * L_CRANK**2 / 3
    i_r = M_ROCKER * L_ROCKER**2 / 3 + m_coupler * L_ROCKER**2 / 3

    def rhs(t, y):
        th, ph, thd, phd = y
        a, b = _tips(th, ph)
        da = L_CRANK * np.array([-np.sin(th), np.cos(th), 0.0])  # dA/dtheta
        db = L_ROCKER * np.array([0.0, np.cos(ph), -np.sin(ph)])  # dB/dphi
        dda = L_CRANK * np.array([-np.cos(th), -np.sin(th), 0.0])
        ddb = L_ROCKER * np.array([0.0, -np.sin(ph), -np.cos(ph)])
        # T = 1/2 i_c thd^2 + 1/2 i_r phd^2 + k thd phd, k = m/6 dA.dB (the coupler a uniform rod: m/6 (|A'|^2 +
        # A'.B' + |B'|^2)); dA.dB = Lc Lr cos(theta) cos(phi)
        c = m_coupler / 6 * L_CRANK * L_ROCKER
        k, k_th, k_ph = c * np.cos(th) * np.cos(ph), -c * np.sin(th) * np.cos(ph), -c * np.cos(th) * np.sin(ph)
        mass = np.array([[i_c, k], [k, i_r]])
        coriolis = np.array([k_ph * phd**2, k_th * thd**2])
        dv = np.array([0.0, -G * L_ROCKER * np.sin(ph) * (M_ROCKER / 2 + m_coupler / 2)])  # V: rocker and coupler
        d = a - b
        jac = 2.0 * np.array([d @ da, -(d @ db)])
        rel = da * thd - db * phd
        gamma = -2.0 * (rel @ rel) - 2.0 * d @ (dda * thd**2 - ddb * phd**2)
        kkt = np.block([[mass, jac[:, None]], [jac[None, :], np.zeros((1, 1))]])
        acc = np.linalg.solve(kkt, np.concatenate([-dv - coriolis, [gamma]]))[:2]
        return [thd, phd, *acc]

    sol = solve_ivp(rhs, (0.0, float(ts[-1])), [0.0, PHI0, 0.0, 0.0], method="DOP853", t_eval=ts, rtol=1e-12,
                    atol=1e-14)
    assert sol.success
    return sol.y[0], sol.y[1]


def _angles(mech, qs):
    a = np.asarray(jax.vmap(lambda q: point_positions(mech, q, "A"))(qs))
    b = np.asarray(jax.vmap(lambda q: point_positions(mech, q, "B"))(qs))
    theta = np.unwrap(np.arctan2(a[:, 1], a[:, 0]))
    phi = np.unwrap(np.arctan2(b[:, 1] - PIVOT[1], b[:, 2] - PIVOT[2]))
    return theta, phi, a, b


@pytest.fixture(scope="module")
def rollout(released_from_rest):
    return released_from_rest(build, T_END, TS, rtol=1e-11, atol=1e-13)


def test_rssr_is_one_dof_loop(rollout):
    mech, _, _ = rollout
    assert mech.n_coords == 9 and mech.n_constraints == 8  # A, B, B' free; 2 + 2 + 1 + 3 rows


def test_rssr_matches_joint_coordinates(rollout):
    mech, _, sol = rollout
    theta, phi, a, b = _angles(mech, sol.q)
    ref_theta, ref_phi = reference(TS)
    assert np.ptp(theta) > 2.0  # the crank swings through more than 2 rad
    np.testing.assert_allclose(theta, ref_theta, rtol=0, atol=ANGLE_TOL)
    np.testing.assert_allclose(phi, ref_phi, rtol=0, atol=ANGLE_TOL)
    length = np.linalg.norm(a[0] - b[0])
    assert np.abs(np.linalg.norm(a - b, axis=1) - length).max() < CLOSURE_TOL
    energy = np.asarray(jax.vmap(lambda q, qd: total_energy(mech, q, qd))(sol.q, sol.qd))
    assert np.abs(energy - energy[0]).max() < ENERGY_TOL


def test_rssr_gradient_wrt_coupler_mass(rollout):
    mech, q0, _ = rollout

    def crank_angle(m):
        moved = mech.with_params(body={"coupler": {"mass": m, "inertia": m / M_COUPLER * mech.body_inertia[
            mech.body_index("coupler")]}})  # a uniform rod made heavier
        s = simulate_mechanism(moved, q0, 0 * q0, 0.0, T_GRAD, rtol=1e-11, atol=1e-13)
        tip = point_positions(moved, s.q[-1], "A")
        return jnp.arctan2(tip[1], tip[0])

    ours = float(jax.grad(crank_angle)(jnp.asarray(M_COUPLER)))
    h = 1e-4
    ts = np.array([0.0, T_GRAD])
    fd = (reference(ts, M_COUPLER + h)[0][-1] - reference(ts, M_COUPLER - h)[0][-1]) / (2 * h)
    assert abs(fd) > 1e-2
    assert abs(ours - fd) <= GRAD_RTOL * abs(fd)
