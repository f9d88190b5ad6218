"""Rotational spring-dampers of planar mechanisms against closed-form oscillators: a rod on a fixed pivot held by
a torsional spring-damper to the ground (damped oscillator), and two rods on one pivot joined by a torsional spring
(relative oscillation at sqrt(k (1/I1 + 1/I2)), angular momentum conserved); energy, parameters by name,
gradients and bad input."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from particlesim.errors import ModelError
from particlesim.mechanism import MechanismBuilder, body_angles, simulate_mechanism, total_energy

#: Angles against the closed forms [rad] (Dopri8 rtol 1e-12).
ANGLE_TOL = 1e-9
#: Energy drift without damping, relative (measured 1.8e-10 over 3 s at Dopri8 rtol 1e-12).
ENERGY_RTOL = 1e-9
K, C, W0 = 3.0, 0.2, 2.0  # N m/rad, N m s/rad, initial rate rad/s
TS = np.linspace(0.0, 3.0, 31)


def _one(k=K, c=C):
    mb = MechanismBuilder(gravity=(0.0, 0.0), planar=True)
    mb.ground("O", (0.0, 0.0))
    mb.particle("A", (1.0, 0.0))
    mb.rod("bar", "O", "A", mass=1.0)
    mb.rotational_spring_damper("torsion", None, "bar", k, c)
    return mb.build(dof=1)


def _spin(x0, w):
    r = np.asarray(x0).reshape(-1, 3)
    return jnp.asarray((w * np.stack([-r[:, 1], r[:, 0], 0 * r[:, 0]], axis=1)).reshape(-1))


def test_damped_torsional_pendulum():
    mech, x0 = _one()
    sol = simulate_mechanism(mech, jnp.asarray(x0), _spin(x0, W0), 0.0, TS[-1], solver="dopri8", rtol=1e-12,
                             atol=1e-12, saveat_ts=TS)
    th = np.asarray(jax.vmap(lambda x: body_angles(mech, x))(sol.q))[:, 0]
    i_o = 1.0 / 3.0
    z, wn = C / (2 * np.sqrt(K * i_o)), np.sqrt(K / i_o)
    wd = wn * np.sqrt(1 - z**2)
    exact = W0 / wd * np.exp(-z * wn * TS) * np.sin(wd * TS)
    assert np.max(np.abs(th - exact)) <= ANGLE_TOL
    assert np.max(np.abs(exact)) > 0.3


def test_spring_between_two_moving_bodies():
    mb = MechanismBuilder(gravity=(0.0, 0.0), planar=True)
    mb.ground("O", (0.0, 0.0))
    mb.particle("A", (1.0, 0.0))
    mb.particle("B", (0.0, 2.0))
    mb.rod("one", "O", "A", mass=1.0)
    mb.rod("two", "O", "B", mass=0.5)
    mb.rotational_spring_damper("coupling", "one", "two", K, 0.0, free_angle=0.1)
    mech, x0 = mb.build(dof=2)
    i1, i2 = 1.0 / 3.0, 0.5 * 4.0 / 3.0
    # rod one turns at W0, rod two at rest: relative rate -W0 about the free angle offset 0.1
    r = np.asarray(x0).reshape(-1, 3)
    v = np.zeros_like(r)
    ia = mech.free.index(mech.index("A"))
    v[ia] = W0 * np.array([-r[ia, 1], r[ia, 0], 0.0])
    sol = simulate_mechanism(mech, jnp.asarray(x0), jnp.asarray(v.reshape(-1)), 0.0, TS[-1], solver="dopri8",
                             rtol=1e-12, atol=1e-12, saveat_ts=TS)
    ang = np.asarray(jax.vmap(lambda x: body_angles(mech, x))(sol.q))
    rel = ang[:, 1] - ang[:, 0]
    w = np.sqrt(K * (1 / i1 + 1 / i2))
    # relative coordinate u = rel - 0.1 obeys u'' = -w^2 u, u(0) = -0.1, u'(0) = -W0
    exact = -0.1 * np.cos(w * TS) - W0 / w * np.sin(w * TS) + 0.1
    assert np.max(np.abs(rel - exact)) <= ANGLE_TOL
    # the angular momentum i1 th1' + i2 th2' = i1 W0 is conserved: the centroid angle moves uniformly
    centroid = (i1 * ang[:, 0] + i2 * ang[:, 1]) / (i1 + i2)
    assert np.max(np.abs(np.unwrap(centroid) - i1 * W0 / (i1 + i2) * TS)) <= ANGLE_TOL
    e = np.asarray(jax.vmap(lambda x, xd: total_energy(mech, x, xd))(sol.q, sol.qd))
    assert e[0] == pytest.approx(0.5 * i1 * W0**2 + 0.5 * K * 0.1**2, rel=1e-12)
    assert np.max(np.abs(e - e[0])) <= ENERGY_RTOL * e[0]


def test_parameters_by_name_and_gradient():
    mech, x0 = _one()
    stiff = mech.with_params(rotational={"torsion": {"stiffness": 2 * K}})
    assert float(stiff.rotational_stiffness[0]) == 2 * K
    with pytest.raises(KeyError, match="no rotational named 'nope'"):
        mech.with_params(rotational={"nope": {"stiffness": 1.0}})
    # accelerations away from the rest angle, differentiated in the element's three parameters (fwd and rev
    # against finite differences); rollout gradients share the machinery tested for the other elements
    from jax.test_util import check_grads

    from particlesim.mechanism import accelerations

    theta = 0.4
    a = np.asarray(x0).reshape(-1, 3)[0]
    x = jnp.asarray([np.cos(theta) * a[0], np.sin(theta) * a[0], 0.0])
    xd = jnp.asarray([-np.sin(theta), np.cos(theta), 0.0]) * W0

    @jax.jit
    def acc(params):
        k, c, th0 = params
        m = mech.with_params(rotational={"torsion": {"stiffness": k, "damping": c, "free_angle": th0}})
        return accelerations(m, 0.0, x, xd)

    check_grads(acc, (jnp.asarray([K, C, 0.1]),), order=1, modes=("fwd", "rev"), eps=1e-6, atol=1e-7, rtol=1e-7)
    # and the value: torque -(k (theta - theta0) + c w) about the pivot of a rod with I_O = 1/3
    tangential = float(jnp.dot(acc(jnp.asarray([K, C, 0.1])), jnp.asarray([-np.sin(theta), np.cos(theta), 0.0])))
    assert tangential == pytest.approx(-(K * (theta - 0.1) + C * W0) / (1.0 / 3.0), rel=1e-12)


def test_bad_rotational_springs():
    mb = MechanismBuilder(planar=True)
    mb.ground("O", (0.0, 0.0))
    mb.particle("A", (1.0, 0.0))
    mb.rod("bar", "O", "A", mass=1.0)
    with pytest.raises(ModelError, match="rotational spring 't': stiffness must be a finite and non-negative number"):
        mb.rotational_spring_damper("t", None, "bar", -1.0, 0.0)
    with pytest.raises(ModelError, match="rotational spring 't': free angle must be a finite number"):
        mb.rotational_spring_damper("t", None, "bar", 1.0, 0.0, free_angle=np.nan)
    with pytest.raises(ModelError, match="rotational spring 't': connects body 'bar' to itself"):
        mb.rotational_spring_damper("t", "bar", "bar", 1.0, 0.0)
    mb.rotational_spring_damper("t", "ghost", "bar", 1.0, 0.0)
    with pytest.raises(ModelError, match="rotational spring 't': unknown body 'ghost'"):
        mb.build()
    spatial = MechanismBuilder()
    with pytest.raises(ModelError, match="rotational spring 'u': available in planar mechanisms"):
        spatial.rotational_spring_damper("u", None, "bar", 1.0, 0.0)


def test_body_reactions_with_rotational_springs_balance_the_body():
    """The spring torque is a couple: the pivot takes M a_com - M g (Newton for the bar); the bar's tip, held by
    nothing, takes no force. (Before, the torque's share at the ground pivot was dropped from the balance.)"""
    from particlesim.mechanism import accelerations, body_reactions

    mech, _ = _one()
    x = jnp.asarray([np.cos(0.3), np.sin(0.3), 0.0])  # turned 0.3 rad: the spring pulls back
    xd = jnp.asarray([-np.sin(0.3), np.cos(0.3), 0.0]) * W0
    a_tip = np.asarray(accelerations(mech, 0.0, x, xd))
    r = np.asarray(body_reactions(mech, 0.0, x, xd))[0]
    assert np.max(np.abs(r[0] - 1.0 * a_tip / 2)) < 1e-12  # no gravity here
    assert np.max(np.abs(r[1])) < 1e-12
    assert np.linalg.norm(a_tip) > 1.0  # the spring and the spin act


def test_new_rotational_parameters_reuse_the_compiled_rollout():
    """A planar mechanism with a rotational spring compiles once; new spring constants and states do not retrace."""
    from particlesim import _ode

    mech, x0 = _one()
    x0 = jnp.asarray(x0)
    before = _ode.TRACES["simulate_mechanism"]
    first = simulate_mechanism(mech, x0, _spin(x0, W0), 0.0, 0.3, solver="tsit5", rtol=1e-8)
    assert _ode.TRACES["simulate_mechanism"] == before + 1
    changed = mech.with_params(rotational={"torsion": {"stiffness": 2 * K, "damping": 0.0, "free_angle": 0.2}})
    second = simulate_mechanism(changed, x0, _spin(x0, 0.5 * W0), 0.0, 0.3, solver="tsit5", rtol=1e-8)
    assert _ode.TRACES["simulate_mechanism"] == before + 1
    assert not np.allclose(np.asarray(first.q[-1]), np.asarray(second.q[-1]))
