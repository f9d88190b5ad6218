"""Fixed (welded) joints against one-coordinate solutions written in the test: a planar L-shaped pendulum of two
rods welded at 60 degrees, and a spatial compound rotor (a body turning about a skew fixed axis, a second body
welded to it and a rod welded to that), each against the equation of the rigid composite about its axis
(inertia by the parallel-axis theorem, gravity torque from the composite centre of mass) integrated by SciPy; bad
input naming the joint."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from particlesim.errors import ModelError
from particlesim.inertia import RigidInertia
from particlesim.mechanism import MechanismBuilder, body_poses, simulate_mechanism, total_energy

#: Positions against the composite's one-coordinate solution [m] (both integrated at rtol 1e-12).
POS_TOL = 1e-9
#: Energy drift over the run, relative.
ENERGY_TOL = 1e-9
G = 9.81
TS = np.linspace(0.0, 3.0, 31)


def _rot2(a):
    return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])


def test_planar_rods_welded_at_an_angle_swing_as_one_body():
    m1, l1, m2, l2 = 1.0, 1.0, 0.7, 0.6
    a = np.array([l1, 0.0])
    b = a + l2 * np.array([np.cos(np.pi / 3), np.sin(np.pi / 3)])
    mb = MechanismBuilder(planar=True)
    mb.ground("O", (0.0, 0.0))
    mb.particle("A", a)
    mb.particle("A'", a)
    mb.particle("B", b)
    mb.rod("r1", "O", "A", m1)
    mb.rod("r2", "A'", "B", m2)
    mb.fixed("r1", "r2")
    mech, x0 = mb.build(dof=1)
    sol = simulate_mechanism(mech, x0, jnp.zeros_like(x0), 0.0, 3.0, solver="dopri8", rtol=1e-12, atol=1e-14,
                             saveat_ts=TS)
    c2 = (a + b) / 2
    inertia = m1 * l1**2 / 3 + m2 * l2**2 / 12 + m2 * c2 @ c2
    mc = m1 * a / 2 + m2 * c2

    def rhs(t, y):
        return [y[1], -(_rot2(y[0]) @ mc)[0] * G / inertia]

    ref = solve_ivp(rhs, (0, 3), [0.0, 0.0], t_eval=TS, rtol=1e-12, atol=1e-14, method="DOP853")
    names = [mech.topo.particle_names[i] for i in mech.topo.free]
    q = np.asarray(sol.q).reshape(len(TS), -1, 3)
    b_ref = np.stack([_rot2(th) @ b for th in ref.y[0]])
    assert np.max(np.abs(q[:, names.index("B"), :2] - b_ref)) < POS_TOL
    e = jax.vmap(lambda x, xd: total_energy(mech, x, xd))(sol.q, sol.qd)
    assert float(jnp.ptp(e)) < ENERGY_TOL * m1 * G * l1


AXIS = np.array([2.0, 1.0, 2.0]) / 3.0


def test_spatial_bodies_and_a_rod_welded_to_a_rotor_turn_as_one_body():
    mb = MechanismBuilder(gravity=(0.0, 0.0, -G))
    mb.ground("O", (0.0, 0.0, 0.0))
    mb.ground("K", tuple(AXIS))
    for n, p in (("p1", (0.4, -0.3, 0.1)), ("p2", (-0.2, 0.5, -0.1)), ("w1", (0.6, 0.2, 0.3)),
                 ("w2", (0.9, 0.2, 0.3)), ("w3", (0.6, 0.5, 0.3)), ("w4", (0.6, 0.2, 0.7)), ("r1", (0.9, 0.5, 0.7)),
                 ("r2", (1.3, 0.1, 0.9))):
        mb.particle(n, p)
    rotor = RigidInertia(2.0, (0.1, 0.1, 0.0), np.diag([0.2, 0.3, 0.4]))
    arm = RigidInertia(1.5, (0.7, 0.3, 0.45), np.array([[0.05, 0.01, 0.0], [0.01, 0.06, 0.0], [0.0, 0.0, 0.04]]))
    mb.body("rotor", rotor, ["O", "K", "p1", "p2"], on_negative="ignore")
    mb.body("arm", arm, ["w1", "w2", "w3", "w4"], on_negative="ignore")
    mb.body("stick", RigidInertia.slender_rod(0.8, (0.9, 0.5, 0.7), (1.3, 0.1, 0.9)), ["r1", "r2"])
    mb.fixed("rotor", "arm", at=(0.3, 0.1, 0.2))
    mb.fixed("arm", "stick")
    mech, x0 = mb.build(dof=1)
    th0 = 0.0
    sol = simulate_mechanism(mech, x0, jnp.zeros_like(x0), 0.0, 3.0, solver="dopri8", rtol=1e-12, atol=1e-14,
                             saveat_ts=TS)
    # the composite about the axis through O
    parts = [(2.0, np.array([0.1, 0.1, 0.0]), np.diag([0.2, 0.3, 0.4])),
             (1.5, np.array([0.7, 0.3, 0.45]), np.asarray(arm.inertia)),
             (0.8, np.array([1.1, 0.3, 0.8]), np.asarray(RigidInertia.slender_rod(0.8, (0.9, 0.5, 0.7),
                                                                                   (1.3, 0.1, 0.9)).inertia))]
    i_axis = sum(AXIS @ (ic + m * (c @ c * np.eye(3) - np.outer(c, c))) @ AXIS for m, c, ic in parts)
    mc = sum(m * c for m, c, _ in parts)
    k = np.array([[0, -AXIS[2], AXIS[1]], [AXIS[2], 0, -AXIS[0]], [-AXIS[1], AXIS[0], 0]])

    def rot(a):
        return np.eye(3) + np.sin(a) * k + (1 - np.cos(a)) * k @ k

    def rhs(t, y):
        return [y[1], AXIS @ np.cross(rot(y[0]) @ mc, (0.0, 0.0, -G)) / i_axis]

    ref = solve_ivp(rhs, (0, 3), [th0, 0.0], t_eval=TS, rtol=1e-12, atol=1e-14, method="DOP853")
    names = [mech.topo.particle_names[i] for i in mech.topo.free]
    q = np.asarray(sol.q).reshape(len(TS), -1, 3)
    for n, p0 in (("r2", np.array([1.3, 0.1, 0.9])), ("w4", np.array([0.6, 0.2, 0.7]))):
        p_ref = np.stack([rot(th) @ p0 for th in ref.y[0]])
        assert np.max(np.abs(q[:, names.index(n)] - p_ref)) < POS_TOL
    r, _ = body_poses(mech, sol.q[-1])
    assert np.max(np.abs(np.asarray(r[1]) - rot(ref.y[0, -1]))) < POS_TOL


def test_fixed_joint_bad_input_names_the_joint():
    mb = MechanismBuilder(planar=True)
    mb.ground("O", (0.0, 0.0))
    mb.particle("A", (1.0, 0.0))
    mb.particle("A'", (1.0, 0.0))
    mb.particle("B", (2.0, 0.0))
    mb.rod("r1", "O", "A", 1.0)
    mb.rod("r2", "A'", "B", 1.0)
    with pytest.raises(ModelError, match="weld: welds body 'r1' to itself"):
        mb.fixed("r1", "r1", name="weld")
    mb.fixed("r1", "nobody", name="weld")
    with pytest.raises(ModelError, match="weld: unknown body 'nobody'"):
        mb.build()
    mb = MechanismBuilder()
    mb.ground("O", (0.0, 0.0, 0.0))
    mb.particle("A", (1.0, 0.0, 0.0))
    mb.particle("A'", (1.0, 0.0, 0.0))
    mb.particle("B", (2.0, 0.0, 0.0))
    mb.rod("r1", "O", "A", 1.0)
    mb.rod("r2", "A'", "B", 1.0)
    mb.fixed("r1", "r2", name="collinear")
    with pytest.raises(ModelError, match="collinear: the directions of the two bodies cannot lock"):
        mb.build()
