"""Linearisation about a rest state and its modes (``particlesim.mechanism.linear``): natural frequencies against
closed forms (a two-mass spring chain on a guide, a compound pendulum whose stiffness is the constraint force's,
viscous damping), the acceleration's tangency at rest, derivatives in the parameters, bad input refused, and the
full vehicle's ride modes against its time response."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.optimize import curve_fit

from particlesim._ode import TRACES
from particlesim.errors import InertiaWarning, ModelError
from particlesim.mechanism import (MechanismBuilder, accelerations, body_com_positions, body_poses, body_velocities,
                                   constraint_jacobian, linearize, modes, project, simulate_mechanism,
                                   static_equilibrium)

G = 9.81
FREQ_RTOL = 1e-9  # frequencies and damping ratios against closed forms, relative
TANGENT_RTOL = 1e-10  # |J d(qdd)| against |J| |d(qdd)| at rest
GRAD_RTOL = 1e-7  # derivatives against closed forms, relative
RESPONSE_RTOL = 1e-2  # the acceptance: linearised modes against the time response's frequencies


# ---- small models, each at rest in its assembly (no equilibrium solve needed) ----

def chain(m1=2.0, m2=1.5, k1=800.0, k2=500.0, c1=0.0, c2=0.0):
    """Two uniform rods sliding on a vertical guide (planar, gravity -y), hung from the ground by spring 1 and from
    each other by spring 2; free lengths chosen so that the assembly is at rest."""
    mb = MechanismBuilder(planar=True)
    for name, y in (("top", 3.0), ("g0", 0.0), ("g1", 1.0)):
        mb.ground(name, (0.0, y))
    for name, (y0, y1), m in (("upper", (2.0, 1.8), m1), ("lower", (1.0, 0.8), m2)):
        mb.particle(f"{name} 0", (0.0, y0))
        mb.particle(f"{name} 1", (0.0, y1))
        mb.rod(name, f"{name} 0", f"{name} 1", m)
        mb.prismatic(("g0", "g1"), (f"{name} 0", f"{name} 1"), name=f"{name} on the guide")
    mb.spring_damper("spring 1", "top", "upper 0", k1, c1, 1.0 - (m1 + m2) * G / k1)
    mb.spring_damper("spring 2", "upper 1", "lower 0", k2, c2, 0.8 - m2 * G / k2)
    return mb.build(dof=2)


def chain_frequencies(m1=2.0, m2=1.5, k1=800.0, k2=500.0):
    """``det(K - w^2 M) = 0`` for ``M = diag(m1, m2)``, ``K = [[k1 + k2, -k2], [-k2, k2]]``: a quadratic in w^2."""
    b, c = -(m1 * k2 + m2 * (k1 + k2)) / (m1 * m2), k1 * k2 / (m1 * m2)
    disc = np.sqrt(b * b - 4.0 * c)
    return np.sqrt(np.array([(-b - disc) / 2.0, (-b + disc) / 2.0]))


def pendulum(mass=3.0, length=0.8, d=0.5, moment=0.04):
    """A rod pivoted at the ground particle O, hanging: centre of mass ``d`` below O, moment ``moment`` about it."""
    mb = MechanismBuilder(planar=True)
    mb.ground("O", (0.0, 0.0))
    mb.particle("B", (0.0, -length))
    mb.rod("rod", "O", "B", mass, com=(0.0, -d), moment=moment, on_negative="ignore")
    return mb.build(dof=1)


def oscillator(m=4.0, k=900.0, c=30.0):
    """One rod on a vertical guide hung from a spring-damper, at rest."""
    mb = MechanismBuilder(planar=True)
    for name, y in (("top", 2.0), ("g0", 0.0), ("g1", 1.0)):
        mb.ground(name, (0.0, y))
    mb.particle("a", (0.0, 1.0))
    mb.particle("b", (0.0, 0.8))
    mb.rod("mass", "a", "b", m)
    mb.prismatic(("g0", "g1"), ("a", "b"))
    mb.spring_damper("spring", "top", "a", k, c, 1.0 - m * G / k)
    return mb.build(dof=1)


def test_a_spring_chain_has_its_closed_form_frequencies_and_proportional_damping():
    """Undamped: the 2 x 2 generalised eigenproblem by hand. Dampers ``c_i = a k_i`` (C = a K): the same modes,
    ratios ``a w_i / 2``, damped frequencies ``w_i sqrt(1 - zeta_i^2)`` (same structure: no recompile)."""
    mech, q0 = chain()
    w = chain_frequencies()
    md = modes(mech, q0)
    np.testing.assert_allclose(np.asarray(md.frequency), w / (2 * np.pi), rtol=FREQ_RTOL)
    np.testing.assert_allclose(np.asarray(md.damped_frequency), w / (2 * np.pi), rtol=FREQ_RTOL)
    np.testing.assert_allclose(np.asarray(md.damping_ratio), 0.0, atol=FREQ_RTOL)
    lin = linearize(mech, q0)
    z = np.asarray(lin.basis)
    np.testing.assert_allclose(z.T @ z, np.eye(2), atol=1e-14)
    np.testing.assert_allclose(np.sort(np.abs(np.linalg.eigvals(np.asarray(lin.A)).imag)), np.repeat(w, 2),
                               rtol=FREQ_RTOL)
    v = np.linalg.lstsq(z, np.asarray(md.shapes), rcond=None)[0]
    np.testing.assert_allclose(v.T @ np.asarray(lin.mass) @ v, np.eye(2), atol=1e-12)  # mass-normalised

    a = 2e-3
    mech_c, _ = chain(c1=a * 800.0, c2=a * 500.0)
    traces = TRACES["modes"]
    md = modes(mech_c, q0)
    assert TRACES["modes"] == traces  # new parameters, the same compiled program
    zeta = a * w / 2
    np.testing.assert_allclose(np.asarray(md.frequency), w / (2 * np.pi), rtol=FREQ_RTOL)
    np.testing.assert_allclose(np.asarray(md.damping_ratio), zeta, rtol=FREQ_RTOL)
    np.testing.assert_allclose(np.asarray(md.damped_frequency), w * np.sqrt(1 - zeta**2) / (2 * np.pi),
                               rtol=FREQ_RTOL)


def test_a_compound_pendulum_is_held_by_the_constraint_force_alone():
    """``w^2 = m g d / I_O``: gravity on the free particle is constant, so all the stiffness is the multiplier's
    (geometric) stiffness, ``d(J^T lam)/dq``."""
    mass, length, d, moment = 3.0, 0.8, 0.5, 0.04
    mech, q0 = pendulum(mass, length, d, moment)
    md = modes(mech, q0)
    w = np.sqrt(mass * G * d / (moment + mass * d * d))
    assert float(md.frequency[0]) == pytest.approx(w / (2 * np.pi), rel=FREQ_RTOL)
    shape = np.asarray(md.shapes[:, 0]).reshape(-1, 3)[0]
    assert abs(shape[1]) <= 1e-12 and abs(shape[2]) <= 1e-12  # B swings horizontally


def test_a_damped_oscillator_has_ratio_c_over_2_sqrt_km():
    m, k, c = 4.0, 900.0, 30.0
    mech, q0 = oscillator(m, k, c)
    md = modes(mech, q0)
    zeta, w = c / (2 * np.sqrt(k * m)), np.sqrt(k / m)
    assert float(md.damping_ratio[0]) == pytest.approx(zeta, rel=FREQ_RTOL)
    assert float(md.frequency[0]) == pytest.approx(w / (2 * np.pi), rel=FREQ_RTOL)
    assert float(md.damped_frequency[0]) == pytest.approx(w * np.sqrt(1 - zeta**2) / (2 * np.pi), rel=FREQ_RTOL)
    np.testing.assert_allclose(np.sort(np.asarray(md.poles[0]).imag), [-w * np.sqrt(1 - zeta**2),
                                                                       w * np.sqrt(1 - zeta**2)], rtol=FREQ_RTOL)


def test_frequencies_and_damping_differentiate_in_the_parameters():
    """The pendulum under gravity ``(gx, -g)`` hangs along it (the rest state and the constraints' null space turn
    with ``gx``): ``w^2 = m |g| d / I_O``; the oscillator's ratio ``c / (2 sqrt(k m))``. Reverse and forward mode
    against the closed forms' derivatives."""
    mass, length, d, moment = 3.0, 0.8, 0.5, 0.04
    mech, _ = pendulum(mass, length, d, moment)

    def frequency(gx):
        g = jnp.stack([gx, jnp.asarray(-G), jnp.asarray(0.0)])
        rest = length * g / jnp.linalg.norm(g)  # the particle B, hanging along gravity from O at the origin
        return modes(eqx.tree_at(lambda m: m.gravity, mech, g), rest, dof=1).frequency[0]

    exact = jax.grad(lambda gx: jnp.sqrt(mass * d * jnp.hypot(gx, G) / (moment + mass * d * d)) / (2 * jnp.pi))
    gx = jnp.asarray(2.0)
    assert float(jax.grad(frequency)(gx)) == pytest.approx(float(exact(gx)), rel=GRAD_RTOL)
    assert float(jax.jvp(frequency, (gx,), (jnp.asarray(1.0),))[1]) == pytest.approx(float(exact(gx)), rel=GRAD_RTOL)

    m, k, c = 4.0, 900.0, 30.0
    osc, q0 = oscillator(m, k, c)

    def ratio(c):  # the rest state does not depend on the damping
        return modes(eqx.tree_at(lambda o: o.spring_damping, osc, c[None]), q0, dof=1).damping_ratio[0]

    assert float(jax.grad(ratio)(jnp.asarray(c))) == pytest.approx(1 / (2 * np.sqrt(k * m)), rel=GRAD_RTOL)


def test_bad_states_are_refused():
    mech, q0 = pendulum()
    tilt = jnp.asarray([0.8 * np.sin(0.5), -0.8 * np.cos(0.5), 0.0])  # on the constraint, not at rest
    with pytest.raises(ModelError, match=r"not an equilibrium: max acceleration .* m/s² \(pass "
                                         r"static_equilibrium\(mech, q\)\.q\)"):
        modes(mech, tilt)
    with pytest.raises(ModelError, match=r"q must have shape \(3,\)"):
        linearize(mech, q0[:2])
    with pytest.raises(ModelError, match="non-finite"):
        modes(mech, jnp.full(3, jnp.nan))
    with pytest.raises(ModelError, match="violates the constraints"):
        modes(mech, q0 * 1.01)
    with pytest.raises(ModelError, match=r"dof=2, but .* leaves 1 degrees of freedom"):
        modes(mech, q0, dof=2)
    with pytest.raises(ModelError, match=r"contact must have one entry per one-sided element"):
        modes(mech, q0, contact=[True])


# ---- the full vehicle ----

@pytest.fixture(scope="module")
def car():
    """The vehicle at rest (its assembly is not: the springs are compressed more than its weight needs)."""
    from particlesim.scenes import vehicle as vh

    with pytest.warns(InertiaWarning):  # the file's arms, balanced (by design)
        mech, q0 = vh.full_vehicle()
    q = static_equilibrium(mech, q0).q
    return mech, q, modes(mech, q)


def _chassis_shares(mech, q, shape):
    """Twice the chassis's kinetic energy per motion (heave, pitch, roll, ...) for a mass-normalised shape: shares
    of 1."""
    b = mech.topo.body_names.index("chassis")
    lin, ang = body_velocities(mech, q, shape)
    v, w = np.asarray(lin[b]), np.asarray(ang[b])
    m, inertia = float(mech.body_mass[b]), np.asarray(mech.body_inertia[b])
    return {"surge": m * v[0] ** 2, "sway": m * v[1] ** 2, "heave": m * v[2] ** 2, "roll": inertia[0, 0] * w[0] ** 2,
            "pitch": inertia[1, 1] * w[1] ** 2, "yaw": inertia[2, 2] * w[2] ** 2}


def test_at_rest_the_acceleration_stays_tangent(car):
    """``J d(qdd) = 0`` to first order at rest (``qdd = 0`` and ``gamma`` quadratic in ``qd``), for motions along
    the admissible directions in position and in velocity."""
    mech, q, md = car
    z = md.shapes  # they span the admissible motions
    j = np.asarray(constraint_jacobian(mech, q)).reshape(-1, mech.n_coords)

    @jax.jit
    def tangents(z):
        acc = lambda x, v: accelerations(mech, 0.0, x, v)  # noqa: E731
        zero = jnp.zeros_like(q)
        pos = jax.vmap(lambda dz: jax.jvp(acc, (q, zero), (dz, zero))[1], in_axes=1, out_axes=1)(z)
        vel = jax.vmap(lambda dz: jax.jvp(acc, (q, zero), (zero, dz))[1], in_axes=1, out_axes=1)(z)
        return pos, vel

    for dqdd in map(np.asarray, tangents(z)):
        assert np.linalg.norm(j @ dqdd) <= TANGENT_RTOL * np.linalg.norm(j) * np.linalg.norm(dqdd)


def test_the_vehicle_has_its_ride_modes(car):
    """Ten modes: three free motions (horizontal position and heading on vertical tyres, zero frequency), then
    heave, pitch and roll of the chassis, then four wheel hops; every one with stiffness is damped."""
    mech, q, md = car
    f = np.asarray(md.frequency)
    assert f.shape == (10,) and np.all(f[:3] == 0.0) and np.all(f[3:] > 0.0)
    assert np.all(np.asarray(md.poles[3:]).real < 0.0)
    ratio = np.asarray(md.damping_ratio)
    assert np.all(np.isnan(ratio[:3])) and np.all((ratio[3:] > 0.0) & (ratio[3:] < 1.0))
    shares = [_chassis_shares(mech, q, md.shapes[:, i]) for i in range(10)]
    for s in shares[:3]:  # free motions: the chassis moves horizontally and turns about z only
        assert s["heave"] + s["pitch"] + s["roll"] <= 1e-12
    for i, motion in zip((3, 4, 5), ("heave", "pitch", "roll")):
        assert shares[i][motion] > 0.9
    for s in shares[6:]:  # wheel hop: the chassis hardly moves
        assert sum(s.values()) < 0.02
    assert 10.0 < f[6] and f[9] < 20.0
    hop = np.array([[float(md.shapes[mech.free_slice(f"wheel {c}"), i][2]) for c in ("FL", "FR", "RL", "RR")]
                    for i in range(6, 10)])
    front, rear = hop[:, :2], hop[:, 2:]
    assert np.all(front[0] > 10 * np.abs(rear[0]).max())  # front axle hop: both front wheels up together
    assert np.all(rear[1] > 10 * np.abs(front[1]).max())  # rear axle hop
    for h in hop[2:]:  # axle tramp: left and right in opposition on each axle
        assert h[0] * h[1] < 0.0 and h[2] * h[3] < 0.0


@pytest.mark.slow
@pytest.mark.parametrize("i, motion", [(3, "heave"), (4, "pitch")])
def test_the_vehicle_modes_match_its_time_response(car, i, motion):
    """Released from rest along a mode's shape (1 mm at most, projected onto the constraints), the chassis's heave
    (pitch) is a damped sinusoid whose frequency and decay rate are the paired pole's, within the issue's 1 %."""
    mech, q, md = car
    shape = np.asarray(md.shapes[:, i])
    q_a, qd_a = project(mech, q + 1e-3 / np.abs(shape).max() * shape, jnp.zeros_like(q))
    ts = np.linspace(0.0, 2.5, 501)
    sol = simulate_mechanism(mech, q_a, qd_a, 0.0, 2.5, rtol=1e-10, atol=1e-12, saveat_ts=ts)
    if motion == "heave":
        y = np.asarray(jax.vmap(lambda x: body_com_positions(mech, x)[0, 2])(sol.q))
    else:  # pitch: the z component of the chassis's x axis
        y = np.asarray(jax.vmap(lambda x: body_poses(mech, x)[0][0, 0, 2])(sol.q))
    late = ts >= 0.2  # after the wheel hop it excites has died out (decay rate ~50/s)

    def damped(t, a, sigma, w, phase, c):
        return a * np.exp(-sigma * t) * np.cos(w * t + phase) + c

    p0 = [y[0] - y[-1], 1.0, 2 * np.pi, 0.0, y[-1]]  # 1 Hz, 1/s: a guess, not the answer
    (_, sigma, w, _, _), _ = curve_fit(damped, ts[late], y[late], p0=p0, maxfev=20000)
    pole = complex(md.poles[i, 0])
    assert w / (2 * np.pi) == pytest.approx(float(md.damped_frequency[i]), rel=RESPONSE_RTOL)
    assert sigma == pytest.approx(-pole.real, rel=RESPONSE_RTOL)
