"""Universal (Cardan) and cylindrical joints against independent solutions: a Cardan shaft pair (input about x,
output about an axis at beta in the x-y plane, the cross between them) against the one-coordinate Lagrangian of
its exact transmission law tan(phi) = tan(theta) / cos(beta), integrated by SciPy; a body sliding and turning on
a fixed cylindrical axis under gravity against its closed form; bad input for both."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from particlesim.errors import ModelError
from particlesim.inertia import RigidInertia
from particlesim.mechanism import MechanismBuilder, simulate_mechanism, total_energy

#: Shaft angles against the one-coordinate solution [rad] (both at rtol 1e-12).
ANGLE_TOL = 1e-8
#: Slider position and spin angle against the closed form [m, rad].
CYL_TOL = 1e-9
BETA = 0.5  # angle between the shafts [rad]
I_A, I_B = 0.02, 0.05  # moments of the shafts about their axes
W0 = 3.0  # input rate [rad/s]
TS = np.linspace(0.0, 3.0, 31)


def _cardan():
    u = np.array([np.cos(BETA), np.sin(BETA), 0.0])
    mb = MechanismBuilder(gravity=(0.0, 0.0, 0.0))
    mb.ground("C", (0, 0, 0))
    mb.ground("Ax", (1.0, 0, 0))
    mb.ground("Bu", u)
    mb.particle("a1", (0, 0.2, 0))  # input cross arm, along y
    mb.particle("a2", (1.0, 0, 0.2))
    mb.particle("b1", (0, 0, 0.2))  # output cross arm, along z (perpendicular to a1 and to u)
    mb.particle("b2", u + 0.2 * np.cross(u, (0, 0, 1.0)))
    ia = np.diag([I_A, 0.3, 0.3])  # about the CoM (0.5, 0, 0): the shaft's axis is a principal axis
    mb.body("input", RigidInertia(1.0, (0.5, 0, 0), ia), ["C", "Ax", "a1", "a2"], on_negative="ignore")
    ib = I_B * np.outer(u, u) + 0.4 * (np.eye(3) - np.outer(u, u))
    mb.body("output", RigidInertia(1.0, 0.5 * u, ib), ["C", "Bu", "b1", "b2"], on_negative="ignore")
    mb.universal("C", "a1", "b1", name="cross")
    return mb.build(dof=1)


def _reduced(ts):
    cb = np.cos(BETA)

    def dphi(th):
        return cb / (np.cos(th) ** 2 * cb**2 + np.sin(th) ** 2)

    def ddphi(th):
        d = np.cos(th) ** 2 * cb**2 + np.sin(th) ** 2
        return -cb * (2 * np.sin(th) * np.cos(th) * (1 - cb**2)) / d**2

    def rhs(t, y):
        th, w = y
        return [w, -I_B * dphi(th) * ddphi(th) * w**2 / (I_A + I_B * dphi(th) ** 2)]

    r = solve_ivp(rhs, (ts[0], ts[-1]), [0.0, W0], method="DOP853", rtol=1e-12, atol=1e-12, t_eval=ts)
    th = r.y[0]
    return th, np.unwrap(np.arctan2(np.sin(th), np.cos(th) * cb))


def test_cardan_shafts_follow_the_transmission_law():
    mech, x0 = _cardan()
    r = np.asarray(x0).reshape(-1, 3)
    v = np.zeros_like(r)
    for n in ("a1", "a2"):  # the input turns about x at W0; the output's arms at the matching rate
        k = mech.free.index(mech.index(n))
        v[k] = np.cross([W0, 0, 0], r[k])
    u = np.array([np.cos(BETA), np.sin(BETA), 0.0])
    w_out = W0 / np.cos(BETA)  # dphi/dtheta at theta = 0 is 1 / cos(beta)
    for n in ("b1", "b2"):
        k = mech.free.index(mech.index(n))
        v[k] = np.cross(w_out * u, r[k])
    sol = simulate_mechanism(mech, jnp.asarray(x0), jnp.asarray(v.reshape(-1)), 0.0, TS[-1], solver="dopri8",
                             rtol=1e-12, atol=1e-12, saveat_ts=TS)
    q = np.asarray(sol.q).reshape(len(TS), -1, 3)
    a1 = q[:, mech.free.index(mech.index("a1"))]
    b1 = q[:, mech.free.index(mech.index("b1"))]
    theta = np.unwrap(np.arctan2(a1[:, 2], a1[:, 1]))
    # the output arm: R_u(phi) e_z = (sin phi sin b, -sin phi cos b, cos phi)
    phi = np.unwrap(np.arctan2(b1[:, 0] / np.sin(BETA), b1[:, 2]))
    th_ref, phi_ref = _reduced(TS)
    assert np.max(np.abs(theta - th_ref)) <= ANGLE_TOL
    assert np.max(np.abs(phi - phi_ref)) <= ANGLE_TOL
    assert np.ptp(theta) > 5.0  # turned about a revolution
    e = np.asarray(jax.vmap(lambda x, xd: total_energy(mech, x, xd))(sol.q, sol.qd))
    assert np.max(np.abs(e - e[0])) <= 1e-9 * e[0]


def test_body_on_a_cylindrical_axis():
    g, v0, w0 = 9.81, 1.5, 4.0
    mb = MechanismBuilder(gravity=(0.0, 0.0, -g))
    mb.ground("a0", (0, 0, 0))
    mb.ground("a1", (0, 0, 1.0))
    mb.ground("a2", (1.0, 0, 0))
    for n, p in (("b0", (0, 0, 0.5)), ("b1", (0, 0, 0.7)), ("b2", (0.1, 0, 0.6)), ("b3", (0.0, 0.1, 0.65))):
        mb.particle(n, p)
    inertia = np.array([[0.01, 0.001, 0.002], [0.001, 0.012, 0.0], [0.002, 0.0, 0.02]])
    mb.body("sleeve", RigidInertia(2.0, (0.02, 0.01, 0.6), inertia), ["b0", "b1", "b2", "b3"],
            on_negative="ignore")
    mb.cylindrical(("a0", "a1", "a2"), ("b0", "b1"), name="guide")
    mech, x0 = mb.build(dof=2)
    r = np.asarray(x0).reshape(-1, 3)
    v = np.cross([0, 0, w0], r) + np.array([0, 0, v0])
    ts = np.linspace(0.0, 0.5, 11)
    sol = simulate_mechanism(mech, jnp.asarray(x0), jnp.asarray(v.reshape(-1)), 0.0, 0.5, solver="dopri8",
                             rtol=1e-12, atol=1e-12, saveat_ts=ts)
    q = np.asarray(sol.q).reshape(len(ts), -1, 3)
    b0, b2 = q[:, 0], q[:, 2]
    np.testing.assert_allclose(b0[:, 2], 0.5 + v0 * ts - g * ts**2 / 2, atol=CYL_TOL)
    np.testing.assert_allclose(b0[:, :2], 0.0, atol=CYL_TOL)
    spin = np.unwrap(np.arctan2(b2[:, 1], b2[:, 0]))
    np.testing.assert_allclose(spin, w0 * ts, atol=CYL_TOL)  # no torque about the axis: constant spin


def test_bad_universal_and_cylindrical_joints():
    mb = MechanismBuilder()
    for n, p in (("c", (0, 0, 0)), ("a", (1, 0, 0)), ("b", (1, 1, 0)), ("d", (0, 0, 1)), ("e", (0, 1, 1))):
        mb.particle(n, p)
    mb.body("one", RigidInertia(1.0, (0.3, 0.3, 0.3), np.eye(3) * 0.1), ["c", "a", "d", "e"], on_negative="ignore")
    mb.particle("f", (0, 2, 0))
    mb.particle("h", (0, 2, 2))
    mb.body("two", RigidInertia(1.0, (0.3, 0.7, 0.3), np.eye(3) * 0.1), ["c", "b", "f", "h"], on_negative="ignore")
    mb.universal("c", "a", "b", name="skew cross")
    with pytest.raises(ModelError, match="skew cross: the arms are not perpendicular at assembly"):
        mb.build()
    mb2 = MechanismBuilder()
    for n, p in (("c", (0, 0, 0)), ("a", (1, 0, 0)), ("b", (0, 1, 0)), ("d", (0, 0, 1))):
        mb2.particle(n, p)
    mb2.body("one", RigidInertia(1.0, (0.3, 0.3, 0.3), np.eye(3) * 0.1), ["c", "a", "b", "d"], on_negative="ignore")
    mb2.universal("c", "a", "b", name="same body")
    with pytest.raises(ModelError, match="same body: both arms 'a' and 'b' belong to one body"):
        mb2.build()
    mb3 = MechanismBuilder()
    for n, p in (("g0", (0, 0, 0)), ("g1", (0, 0, 1)), ("g2", (0, 0, 2))):
        mb3.ground(n, p)
    mb3.cylindrical(("g0", "g1", "g2"), ("g0", "g1"), name="bad guide")
    with pytest.raises(ModelError, match="bad guide: point 'g2' lies on the axis 'g0'-'g1'"):
        mb3.build()
    with pytest.raises(ModelError, match="cylindrical joint flat: not available in a planar mechanism"):
        MechanismBuilder(planar=True).cylindrical(("a", "b", "c"), ("d", "e"), name="flat")
    with pytest.raises(ModelError, match="cylindrical joint short: needs three particles on the guide and two"):
        mb3.cylindrical(("g0", "g1"), ("g0", "g1"), name="short")
