"""Driving constraints (prescribed angles and positions over time) and kinematic analysis, against independent
solutions: the rigid slider-crank of the IVP Test Set's crank problem against its closed-form kinematics and its
driving torque against the energy balance ``tau * Omega = dT/dt`` (T from the closed form); a pendulum whose pivot
is driven sideways against its one-coordinate equation integrated by SciPy, with the driving forces against
Newton's law for the centre of mass; a spatial rotor driven about a skew axis against the rotation it must follow
and the torque ``I_axis theta''``; bad input naming the driver."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from particlesim.errors import ModelError
from particlesim.inertia import RigidInertia
from particlesim.mechanism import (MechanismBuilder, body_angles, body_poses, driver_efforts, kinematic_analysis,
                                   kinetic_energy, project, simulate_mechanism)
from particlesim.scenes.iftomm import CRANK, slider_crank, slider_crank_exact

#: Slider-crank positions [m, rad] against the closed form.
POS_TOL = 1e-12
#: Slider velocity [m/s] (peak ~23 m/s) and acceleration [m/s^2] (peak ~5e3) against the closed form.
VEL_TOL = 1e-11
ACC_TOL = 1e-8
#: Kinetic energy [J] (~43 J) and driving power [W] (peak ~1e4 W) against the closed form.
ENERGY_TOL = 1e-10
POWER_TOL = 1e-8
#: Driven pendulum: angle against SciPy's one-coordinate solution [rad] (both at rtol 1e-12).
PEND_TOL = 1e-8
#: Driving forces against Newton's law for the centre of mass [N] (~10 N).
FORCE_TOL = 1e-8
#: Spatial rotor: rotation against the prescribed one, torque against I theta'' [N m].
ROT_TOL = 1e-12
TORQUE_TOL = 1e-10

TS = np.linspace(0.0, CRANK["t_end"], 201)


@pytest.fixture(scope="module")
def crank():
    mech, x0 = slider_crank()
    sol = kinematic_analysis(mech, x0, TS)
    names = [mech.topo.particle_names[i] for i in mech.topo.free]
    exact = jax.vmap(slider_crank_exact)(jnp.asarray(TS))
    return mech, x0, sol, names.index("B"), exact


def test_slider_crank_kinematics_match_the_closed_form(crank):
    mech, _, sol, ib, (phi1, phi2, x3, _) = crank
    n = len(TS)
    assert float(jnp.max(sol.residual)) < 1e-14
    assert float(jnp.max(jnp.abs(sol.q.reshape(n, -1, 3)[:, ib, 0] - x3))) < POS_TOL
    ang = jax.vmap(lambda x: body_angles(mech, x))(sol.q)
    wrap = lambda a: jnp.arctan2(jnp.sin(a), jnp.cos(a))  # noqa: E731
    assert float(jnp.max(jnp.abs(wrap(ang[:, 0] - phi1)))) < POS_TOL
    assert float(jnp.max(jnp.abs(ang[:, 1] - phi2))) < POS_TOL
    t = jnp.asarray(TS)
    v3 = jax.vmap(jax.grad(lambda s: slider_crank_exact(s)[2]))(t)
    a3 = jax.vmap(jax.grad(jax.grad(lambda s: slider_crank_exact(s)[2])))(t)
    assert float(jnp.max(jnp.abs(sol.qd.reshape(n, -1, 3)[:, ib, 0] - v3))) < VEL_TOL
    assert float(jnp.max(jnp.abs(sol.qdd.reshape(n, -1, 3)[:, ib, 0] - a3))) < ACC_TOL


def test_slider_crank_driving_torque_balances_the_kinetic_energy(crank):
    """No gravity, no other load: the driver's power is the rate of the kinetic energy."""
    from particlesim import _ode

    mech, x0, sol, _, (*_, energy) = crank
    traces = _ode.TRACES["kinematic_analysis"]
    again = kinematic_analysis(mech, np.asarray(x0) + 1e-4, TS + 0.5)  # new start and times: no new trace
    assert _ode.TRACES["kinematic_analysis"] == traces
    assert float(jnp.max(again.residual)) < 1e-14
    t_num = jax.vmap(lambda x, xd: kinetic_energy(mech, x, xd))(sol.q, sol.qd)
    assert float(jnp.max(jnp.abs(t_num - energy))) < ENERGY_TOL
    power = jax.vmap(jax.grad(lambda s: slider_crank_exact(s)[3]))(jnp.asarray(TS))
    assert float(jnp.max(jnp.abs(sol.efforts[:, 0] * CRANK["omega"] - power))) < POWER_TOL
    k = 37
    assert float(jnp.abs(driver_efforts(mech, TS[k], sol.q[k], sol.qd[k])["crank"] - sol.efforts[k, 0])) < 1e-12


def test_slider_crank_rigid_against_the_flexible_reference(crank):
    """Not a check of the engine: the published state at t = 0.1 s belongs to the elastic rod. The rigid slider
    must sit within the rod's deflection (tens of micrometres) of it, and the crank angle is exact."""
    mech, _, sol, ib, _ = crank
    x3 = float(sol.q[-1].reshape(-1, 3)[ib, 0])
    assert abs(x3 - 0.1697373328427860) < 5e-5
    assert abs(float(body_angles(mech, sol.q[-1])[1]) - (-0.3311734988256260)) < 1e-5


def test_driven_slider_crank_simulates_as_its_kinematics(crank):
    mech, x0, sol, ib, (_, _, x3, _) = crank
    x, xd = project(mech, jnp.asarray(x0), jnp.zeros(mech.n_coords), t=0.0)
    out = simulate_mechanism(mech, x, xd, 0.0, CRANK["t_end"], solver="dopri8", rtol=1e-11, atol=1e-13,
                             saveat_ts=TS[::20])
    assert float(jnp.max(jnp.abs(out.q.reshape(len(TS[::20]), -1, 3)[:, ib, 0] - x3[::20]))) < 1e-10
    with pytest.raises(ValueError, match="violates driver 'crank'.*velocity"):
        simulate_mechanism(mech, jnp.asarray(x0), jnp.zeros(mech.n_coords), 0.0, 0.01)


# ---- a pendulum on a pivot driven sideways (dynamics with drivers) ----
M, L, G, AMP, W = 1.3, 0.8, 9.81, 0.1, 5.0


def _xs(t):
    return AMP * jnp.sin(W * t)


def _pendulum():
    mb = MechanismBuilder(planar=True)
    mb.particle("S", (0.0, 0.0))
    mb.particle("P", (0.0, -L))
    mb.rod("pendulum", "S", "P", M)
    mb.drive_position("pivot x", "S", _xs, axis=(1.0, 0.0))
    mb.drive_position("pivot y", "S", lambda t: 0.0 * t, axis=(0.0, 1.0))
    return mb.build(dof=1)


def test_driven_pivot_pendulum_against_its_one_coordinate_equation():
    mech, x0 = _pendulum()
    th0, w0 = 0.4, 0.0
    x0 = jnp.asarray([0.0, 0.0, 0.0, L * np.sin(th0), -L * np.cos(th0), 0.0])
    xd0 = jnp.asarray([AMP * W, 0.0, 0.0, AMP * W + L * w0 * np.cos(th0), L * w0 * np.sin(th0), 0.0])
    ts = np.linspace(0.0, 3.0, 31)
    sol = simulate_mechanism(mech, x0, xd0, 0.0, 3.0, solver="dopri8", rtol=1e-12, atol=1e-14, saveat_ts=ts)
    io = M * L**2 / 3

    def rhs(t, y):  # theta from the downward vertical; the pivot's acceleration acts as a sideways load
        xdd = -AMP * W**2 * np.sin(W * t)
        return [y[1], (-M * G * L / 2 * np.sin(y[0]) - M * L / 2 * xdd * np.cos(y[0])) / io]

    ref = solve_ivp(rhs, (0, 3), [th0, w0], t_eval=ts, rtol=1e-12, atol=1e-14, method="DOP853")
    q = np.asarray(sol.q).reshape(len(ts), -1, 3)
    theta = np.arctan2(q[:, 1, 0] - q[:, 0, 0], -(q[:, 1, 1] - q[:, 0, 1]))
    assert np.max(np.abs(theta - ref.y[0])) < PEND_TOL
    assert np.max(np.abs(q[:, 0, 0] - AMP * np.sin(W * ts))) < 1e-12
    # driving forces: Newton's law for the centre of mass (gravity along -y)
    k = 17
    th, w = ref.y[0, k], ref.y[1, k]
    wd = rhs(ts[k], ref.y[:, k])[1]
    acc = np.array([-AMP * W**2 * np.sin(W * ts[k]) + L / 2 * (wd * np.cos(th) - w**2 * np.sin(th)),
                    L / 2 * (wd * np.sin(th) + w**2 * np.cos(th))])
    eff = driver_efforts(mech, ts[k], sol.q[k], sol.qd[k])
    assert abs(float(eff["pivot x"]) - M * acc[0]) < FORCE_TOL
    assert abs(float(eff["pivot y"]) - (M * acc[1] + M * G)) < FORCE_TOL


# ---- a spatial rotor driven about a skew axis ----
AXIS = np.array([1.0, 2.0, 2.0]) / 3.0


def _theta(t):
    return 0.7 * jnp.sin(2.0 * t) + 0.3 * t


def test_spatial_rotor_follows_its_driver_with_the_torque_of_its_inertia():
    mb = MechanismBuilder(gravity=(0.0, 0.0, 0.0))
    mb.ground("O", (0.0, 0.0, 0.0))
    mb.ground("K", tuple(AXIS))
    mb.particle("p1", (0.5, -0.2, 0.1))
    mb.particle("p2", (-0.1, 0.4, -0.3))
    inertia = np.diag([0.2, 0.3, 0.4])
    mb.body("rotor", RigidInertia(2.0, (0.0, 0.0, 0.0), inertia), ["O", "K", "p1", "p2"], on_negative="ignore")
    mb.drive_angle("motor", "rotor", _theta, axis=tuple(AXIS))
    mech, x0 = mb.build(dof=0)
    ts = np.linspace(0.0, 2.0, 41)
    sol = kinematic_analysis(mech, x0, ts)

    def rot(a):
        k = np.array([[0, -AXIS[2], AXIS[1]], [AXIS[2], 0, -AXIS[0]], [-AXIS[1], AXIS[0], 0]])
        return np.eye(3) + np.sin(a) * k + (1 - np.cos(a)) * k @ k

    err = max(np.max(np.abs(np.asarray(body_poses(mech, sol.q[i])[0][0]) - rot(float(_theta(t)))))
              for i, t in enumerate(ts))
    assert err < ROT_TOL
    tdd = jax.vmap(jax.grad(jax.grad(_theta)))(jnp.asarray(ts))
    assert float(jnp.max(jnp.abs(sol.efforts[:, 0] - AXIS @ inertia @ AXIS * tdd))) < TORQUE_TOL


# ---- bad input ----
def _crank_builder():
    mb = MechanismBuilder(planar=True, gravity=(0.0, 0.0))
    mb.ground("O", (0.0, 0.0))
    mb.particle("A", (1.0, 0.0))
    mb.rod("crank", "O", "A", 1.0)
    return mb


def test_driver_bad_input_names_the_driver():
    mb = _crank_builder()
    with pytest.raises(ModelError, match="driver 'd': f\\(t\\) must return one finite number"):
        mb.drive_angle("d", "crank", lambda t: jnp.stack([t, t]))
    with pytest.raises(ModelError, match="driver 'n': f\\(t\\) must return one finite number"):
        mb.drive_angle("n", "crank", lambda t: t + jnp.nan)
    with pytest.raises(ModelError, match="driver 'f': f\\(0.0\\) failed"):
        mb.drive_angle("f", "crank", lambda t: undefined_name)  # noqa: F821
    with pytest.raises(ModelError, match="driver 'c': needs a function"):
        mb.drive_angle("c", "crank", 3.0)
    with pytest.raises(ModelError, match="driver 'z': axis must be a non-zero vector"):
        mb.drive_position("z", "A", lambda t: t, axis=(0.0, 0.0))
    with pytest.raises(ModelError, match="driver 'x': a planar mechanism turns about z only"):
        mb.drive_angle("x", "crank", lambda t: t, axis=(1.0, 0.0, 0.0))
    mb.drive_angle("d", "crank", lambda t: t)
    with pytest.raises(ModelError, match="driver 'd' is defined twice"):
        mb.drive_angle("d", "crank", lambda t: t)


def test_inconsistent_drivers_are_refused():
    mb = _crank_builder()
    mb.drive_angle("a", "crank", lambda t: t)
    mb.drive_position("b", "A", lambda t: 0.1 * t, axis=(0.0, 1.0))
    with pytest.raises(ModelError, match="driver 'b' is inconsistent with the other constraints"):
        mb.build()


def test_driver_on_the_axis_and_unknown_names_are_refused():
    mb = MechanismBuilder(gravity=(0.0, 0.0, 0.0))
    mb.ground("O", (0.0, 0.0, 0.0))
    mb.particle("A", (0.0, 0.0, 1.0))
    mb.rod("shaft", "O", "A", 1.0)
    mb.drive_angle("spin", "shaft", lambda t: t, axis=(0.0, 0.0, 1.0))
    with pytest.raises(ModelError, match="driver 'spin': the particles of body 'shaft' lie on a line along"):
        mb.build()
    mb = _crank_builder()
    mb.drive_angle("a", "nobody", lambda t: t)
    with pytest.raises(ModelError, match="driver 'a': unknown body 'nobody'"):
        mb.build()


def test_kinematic_analysis_refuses_a_mechanism_with_freedom_left():
    mech, x0 = _crank_builder().build(dof=1)
    with pytest.raises(ModelError, match="1 degree\\(s\\) of freedom left"):
        kinematic_analysis(mech, x0, [0.0, 0.1])
    mech, x0 = slider_crank()
    with pytest.raises(ValueError, match="strictly increasing"):
        kinematic_analysis(mech, x0, [0.1, 0.0])


# ---- a pin in the slot of a rod (planar turned rows), driven and free ----
def _quick_return(driven: bool):
    mb = MechanismBuilder(planar=True)
    mb.ground("O2", (0.0, 0.0))
    mb.ground("O4", (0.0, -0.2))
    mb.particle("A", (0.1, 0.0))
    mb.particle("B", (0.4 / np.sqrt(5.0), -0.2 + 0.8 / np.sqrt(5.0)))
    mb.rod("crank", "O2", "A", mass=0.5)
    mb.rod("lever", "O4", "B", mass=2.0)
    mb.on_line("A", "O4", ("O4", "B"), name="slot")  # a planar line needs no reference point: a rod carries it
    if driven:
        mb.drive_angle("motor", "crank", lambda t: 10.0 * t)
    return mb.build(dof=0 if driven else 1)


def test_pin_in_the_slot_of_a_rod_lever_follows_the_closed_form():
    mech, x0 = _quick_return(True)
    ts = np.linspace(0.0, 2 * np.pi / 10, 37)
    sol = kinematic_analysis(mech, x0, ts)

    def lever(t):  # the lever points at the crank pin
        return jnp.arctan2(0.1 * jnp.sin(10.0 * t) + 0.2, 0.1 * jnp.cos(10.0 * t))

    t = jnp.asarray(ts)
    q = sol.q.reshape(len(ts), -1, 3)
    names = [mech.topo.particle_names[i] for i in mech.topo.free]
    b = q[:, names.index("B")] - jnp.asarray([[0.0, -0.2, 0.0]])
    assert float(jnp.max(jnp.abs(jnp.arctan2(b[:, 1], b[:, 0]) - jax.vmap(lever)(t)))) < POS_TOL
    bd = sol.qd.reshape(len(ts), -1, 3)[:, names.index("B")]
    w = (b[:, 0] * bd[:, 1] - b[:, 1] * bd[:, 0]) / jnp.sum(b[:, :2] ** 2, axis=1)
    assert float(jnp.max(jnp.abs(w - jax.vmap(jax.grad(lever))(t)))) < VEL_TOL
    bdd = sol.qdd.reshape(len(ts), -1, 3)[:, names.index("B")]
    # the lever's angular acceleration from B's acceleration (|OB| fixed): (b x bdd) / |b|^2
    wd = (b[:, 0] * bdd[:, 1] - b[:, 1] * bdd[:, 0]) / jnp.sum(b[:, :2] ** 2, axis=1)
    assert float(jnp.max(jnp.abs(wd - jax.vmap(jax.grad(jax.grad(lever)))(t)))) < ACC_TOL


def test_free_pin_in_a_slot_conserves_energy():
    from particlesim.mechanism import total_energy

    mech, x0 = _quick_return(False)
    sol = simulate_mechanism(mech, jnp.asarray(x0), jnp.zeros(mech.n_coords), 0.0, 2.0, solver="dopri8",
                             rtol=1e-12, atol=1e-14, saveat_ts=np.linspace(0.0, 2.0, 21))
    e = jax.vmap(lambda x, v: total_energy(mech, x, v))(sol.q, sol.qd)
    assert float(jnp.ptp(e)) < 1e-10 * 2.5 * 9.81 * 0.4
    assert float(jnp.ptp(sol.q[:, 0])) > 0.05  # it moves


def test_slots_and_guides_of_zero_length_are_refused_by_name():
    def bar_beside_coincident_points():
        mb = MechanismBuilder(planar=True)
        mb.ground("O", (0.0, 0.0))
        mb.ground("O'", (0.0, 0.0))
        mb.particle("A", (1.0, 0.0))
        mb.particle("A'", (1.5, 0.0))
        mb.rod("bar", "A", "A'", 1.0)
        return mb

    mb = bar_beside_coincident_points()
    mb.on_line("A", "O", ("O", "O'"), name="slot")
    with pytest.raises(ModelError, match="slot: the line's direction points 'O' and 'O'' coincide"):
        mb.build()
    mb = bar_beside_coincident_points()
    mb.prismatic(("O", "O'"), ("A", "A'"), name="guide")
    with pytest.raises(ModelError, match="guide: the guide's axis points 'O' and 'O'' coincide"):
        mb.build()
