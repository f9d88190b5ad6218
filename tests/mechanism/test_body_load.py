"""Body loads from named body states (``MechanismBuilder.body_load``) against a one-coordinate solution: a planar
rod pendulum with aerodynamic-style drag on its centre of mass and a rotary damper torque, both computed from the
named state handed to the load function, against its equation integrated by SciPy; a load with its coefficients
as traced parameters reuses the compiled rollout (trace counter); bad input names the load."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from particlesim import _ode
from particlesim.errors import ModelError
from particlesim.mechanism import MechanismBuilder, accelerations, body_reactions, simulate_mechanism

#: Pendulum angle against SciPy's one-coordinate solution [rad] (both at rtol 1e-12).
ANGLE_TOL = 1e-9
M, L, G = 1.2, 0.9, 9.81
TS = np.linspace(0.0, 2.0, 21)


class Drag(eqx.Module):
    c: jax.Array  # linear drag on the centre of mass [N s/m]
    d: jax.Array  # rotary damper [N m s/rad]

    def __call__(self, t, s):
        return {"arm": (-self.c * s.velocity["arm"], -self.d * s.angular_velocity["arm"])}


def _pendulum(load):
    mb = MechanismBuilder(planar=True)
    mb.ground("O", (0.0, 0.0))
    mb.particle("P", (L, 0.0))
    mb.rod("arm", "O", "P", M)
    mb.body_load("drag", ["arm"], load)
    return mb.build(dof=1)


def _reference(c, d):
    io = M * L**2 / 3

    def rhs(t, y):  # theta from +x, counter-clockwise; gravity along -y
        return [y[1], (-M * G * L / 2 * np.cos(y[0]) - c * (L / 2) ** 2 * y[1] - d * y[1]) / io]

    return solve_ivp(rhs, (0, 2), [0.0, 0.0], t_eval=TS, rtol=1e-12, atol=1e-14, method="DOP853").y[0]


def test_body_load_from_named_states_against_the_one_coordinate_equation():
    mech, x0 = _pendulum(Drag(jnp.asarray(0.8), jnp.asarray(0.3)))
    before = _ode.TRACES["simulate_mechanism"]
    angles = []
    for c, d in ((0.8, 0.3), (0.2, 1.1)):
        m = eqx.tree_at(lambda mm: mm.applied[0].fn, mech, Drag(jnp.asarray(c), jnp.asarray(d)))
        sol = simulate_mechanism(m, x0, jnp.zeros_like(x0), 0.0, 2.0, solver="dopri8", rtol=1e-12, atol=1e-14,
                                 saveat_ts=TS)
        q = np.asarray(sol.q).reshape(len(TS), -1, 3)
        theta = np.unwrap(np.arctan2(q[:, 0, 1], q[:, 0, 0]))
        assert np.max(np.abs(theta - _reference(c, d))) < ANGLE_TOL
        angles.append(theta)
    assert _ode.TRACES["simulate_mechanism"] - before <= 1  # new coefficients: no new trace
    assert np.max(np.abs(angles[0] - angles[1])) > 1e-2  # the load acts
    # the load enters the body's reactions: the pivot force is M a_com - M g - F_drag (Newton for the rod)
    x, xd = sol.q[7], sol.qd[7]
    a_tip = accelerations(m, TS[7], x, xd)
    r = np.asarray(body_reactions(m, TS[7], x, xd))[0]  # (4, 3): O, P, padding
    expected = M * np.asarray(a_tip) / 2 - M * np.array([0.0, -G, 0.0]) + 0.2 * np.asarray(xd) / 2
    assert np.max(np.abs(r[0] - expected)) < 1e-10
    assert np.max(np.abs(r[1])) < 1e-10  # nothing holds the tip


def test_body_load_bad_input_names_the_load():
    mb = MechanismBuilder(planar=True)
    mb.ground("O", (0.0, 0.0))
    mb.particle("P", (L, 0.0))
    mb.rod("arm", "O", "P", M)
    with pytest.raises(ModelError, match="body load 'x': needs a function"):
        mb.body_load("x", ["arm"], 1.0)
    with pytest.raises(ModelError, match="body load 'x': bodies must be a non-empty list"):
        mb.body_load("x", "arm", lambda t, s: {})
    mb.body_load("x", ["nobody"], lambda t, s: {})
    with pytest.raises(ModelError, match="body load 'x': unknown body 'nobody'"):
        mb.build()
    mech, x0 = _pendulum(lambda t, s: {"wheel": (jnp.zeros(3), jnp.zeros(3))})
    with pytest.raises(ModelError, match="body load 'drag': must return a dict .* keys \\['wheel'\\]"):
        simulate_mechanism(mech, x0, jnp.zeros_like(x0), 0.0, 0.1)
    mech, x0 = _pendulum(lambda t, s: {"arm": (jnp.zeros(2), jnp.zeros(3))})
    with pytest.raises(ModelError, match="body 'arm' needs a force and a torque of 3 numbers"):
        simulate_mechanism(mech, x0, jnp.zeros_like(x0), 0.0, 0.1)
