"""Spatial torsion springs (``mb.torsion_spring``): two plates hinged in series on one skew axis, the outer one held
to the inner by a torsion spring-damper, against the two-angle equations of motion written out here (Lagrange:
moments of inertia about the axis, gravity's moments) and integrated by SciPy; energy held without damping; the
spring's torque in the joints' reactions; gradients (reverse, forward) against central differences; bad input
refused by name."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from rollout_helpers import assert_derivative_matches_central_difference
from scipy.integrate import solve_ivp

from particlesim.errors import ModelError
from particlesim.inertia import RigidInertia
from particlesim.mechanism import MechanismBuilder, project, simulate_mechanism, total_energy

G = 9.81
AXIS = np.array([0.3, -0.2, 0.9]) / np.linalg.norm([0.3, -0.2, 0.9])
P0 = np.array([0.1, 0.2, 0.0])  # a point of the axis
K_T, C_T, FREE = 40.0, 0.3, 0.2  # N m/rad, N m s/rad, rad
M = (2.0, 1.5)
T_END = 1.0
TS = np.linspace(0.0, T_END, 11)
RTOL, ATOL = 1e-11, 1e-13
REF_TOL = 1e-8  # angles [rad] against SciPy
ENERGY_RTOL = 1e-9  # undamped: total energy over the run, relative to the spring's energy at the start
GRAD_RTOL = 1e-6


def _frame():
    """Two unit vectors normal to the axis."""
    u = np.cross(AXIS, [1.0, 0.0, 0.0])
    u /= np.linalg.norm(u)
    return u, np.cross(AXIS, u)


def plates():
    """Plate 1 hinged to the ground on the axis, plate 2 hinged to plate 1 on it; each a spatial body of its own
    (primaries off the axis), its centre of mass off the axis; the torsion spring between them."""
    u, v = _frame()
    mb = MechanismBuilder(gravity=(0.0, 0.0, -G))
    bodies = []
    for i, (r, s) in enumerate([(0.3, 0.1), (0.25, -0.15)]):
        c = P0 + r * u + s * v + 0.05 * (i + 1) * AXIS
        corners = [c + 0.1 * u, c + 0.1 * v, c - 0.1 * u + 0.05 * AXIS, c - 0.1 * v + 0.1 * AXIS]
        names = [mb.particle(f"plate {i + 1} {k}", p) for k, p in enumerate(corners)]
        inertia = RigidInertia(M[i], c, np.diag([0.03, 0.035, 0.04]) + 0.003 * (i + 1) * (np.ones((3, 3)) - np.eye(3)),
                               name=f"plate {i + 1}")
        bodies.append(mb.body(f"plate {i + 1}", inertia, names, on_negative="ignore"))
    mb.revolute(None, "plate 1", axis=(P0, P0 + 0.2 * AXIS), name="hinge 1")
    mb.revolute("plate 1", "plate 2", axis=(P0 + 0.05 * AXIS, P0 + 0.3 * AXIS), name="hinge 2")
    mb.torsion_spring("bar", "plate 1", "plate 2", AXIS, K_T, C_T, free_angle=FREE)
    mech, q0 = mb.build(dof=2)
    return mech, jnp.asarray(q0), mb


def _axis_data(mech, q0):
    """Each plate's mass, moment of inertia about the axis and centre of mass at assembly (world)."""
    out = []
    for i in range(2):
        m = float(mech.body_mass[i])
        c = np.asarray(mech.body_com[i])  # the body frame is the world's at assembly
        d = (c - P0) - ((c - P0) @ AXIS) * AXIS
        moment = AXIS @ np.asarray(mech.body_inertia[i]) @ AXIS + m * d @ d
        out.append((m, moment, c))
    return out


def reference(mech, q0, w0, damping=C_T):
    """``theta1`` (plate 1 about the axis), ``theta2`` (plate 2 relative to plate 1): Lagrange's equations."""
    (m1, i1, c1), (m2, i2, c2) = _axis_data(mech, q0)
    g = np.array([0.0, 0.0, -G])

    def rot(th):
        k = np.array([[0, -AXIS[2], AXIS[1]], [AXIS[2], 0, -AXIS[0]], [-AXIS[1], AXIS[0], 0]])
        return np.eye(3) + np.sin(th) * k + (1 - np.cos(th)) * k @ k

    def gravity_moment(m, c, th):  # d/dth of m g . (R(th) (c - P0)), the generalised gravity force
        k = np.array([[0, -AXIS[2], AXIS[1]], [AXIS[2], 0, -AXIS[0]], [-AXIS[1], AXIS[0], 0]])
        dr = np.cos(th) * k + np.sin(th) * k @ k
        return m * g @ (dr @ (c - P0))

    def rhs(t, y):
        th1, th2, w1, w2 = y
        tau = -(K_T * (th2 - FREE) + damping * w2)
        q1 = gravity_moment(m1, c1, th1) + gravity_moment(m2, c2, th1 + th2)
        q2 = gravity_moment(m2, c2, th1 + th2) + tau
        mass = np.array([[i1 + i2, i2], [i2, i2]])
        a = np.linalg.solve(mass, [q1, q2])
        return [w1, w2, a[0], a[1]]

    sol = solve_ivp(rhs, (0.0, T_END), [0.0, 0.0, *w0], method="DOP853", rtol=1e-13, atol=1e-15, t_eval=TS)
    return sol.y[:2].T


def _angles(mech, qs):
    """Each plate's rotation angle about the axis from its assembly pose (the body frames are the world's then)."""
    from particlesim.mechanism import body_poses
    from particlesim.spatial import rotation_log

    rot, _ = jax.vmap(lambda q: body_poses(mech, q))(qs)
    phi = jax.vmap(jax.vmap(rotation_log))(rot)  # (T, 2, 3)
    th = np.asarray(phi @ AXIS)
    return np.stack([th[:, 0], th[:, 1] - th[:, 0]], axis=1)


@pytest.fixture(scope="module")
def case():
    mech, q0, _ = plates()
    w0 = (1.5, -2.0)
    u = AXIS
    r = np.asarray(q0).reshape(-1, 3)
    n = r.shape[0] // 2
    qd = np.concatenate([np.cross(w0[0] * u, r[:n] - P0), np.cross((w0[0] + w0[1]) * u, r[n:] - P0)]).reshape(-1)
    q0, qd0 = project(mech, q0, jnp.asarray(qd))
    sol = simulate_mechanism(mech, q0, qd0, 0.0, T_END, rtol=RTOL, atol=ATOL, saveat_ts=TS)
    return mech, q0, qd0, w0, sol


def test_the_plates_turn_as_their_two_angle_equations(case):
    mech, q0, _, w0, sol = case
    assert bool(sol.ok)
    th = _angles(mech, sol.q)
    ref = reference(mech, q0, w0)
    assert np.abs(th - ref).max() <= REF_TOL
    assert np.abs(th[:, 1]).max() > 0.1  # the spring was worked


def test_without_damping_the_energy_is_held(case):
    mech, q0, qd0, w0, _ = case
    free = mech.with_params(torsion={"bar": {"damping": 0.0}})
    sol = simulate_mechanism(free, q0, qd0, 0.0, T_END, rtol=RTOL, atol=ATOL, saveat_ts=TS)
    e = np.asarray(jax.vmap(lambda q, v: total_energy(free, q, v))(sol.q, sol.qd))
    assert np.abs(e - e[0]).max() <= ENERGY_RTOL * 0.5 * K_T * FREE**2
    assert np.abs(_angles(free, sol.q) - reference(free, q0, w0, damping=0.0)).max() <= REF_TOL


def test_the_spring_torque_is_in_the_reactions(case):
    """What plate 2 receives from its hinge about the axis (the moment of its reactions) is what its motion and
    gravity need less the spring's torque on it, ``-(k (theta2 - free) + c theta2')``, with the angle and rate read
    here from the start state (theta2 = 0, its rate w0[1])."""
    mech, q0, qd0, w0, _ = case
    from particlesim.mechanism import accelerations, body_reactions
    from particlesim.particles import primary_mass_matrix

    reactions = np.asarray(body_reactions(mech, 0.0, q0, qd0))
    qdd = accelerations(mech, 0.0, q0, qd0)
    pos = np.asarray(mech.all_positions(q0))
    acc = np.zeros_like(pos)
    acc[np.asarray(mech.topo.free)] = np.asarray(qdd).reshape(-1, 3)
    b = mech.body_index("plate 2")
    prim = np.asarray(mech.topo.body_particles[b])
    lb = np.asarray(primary_mass_matrix(mech.body_mass[b], mech.body_com[b], mech.body_inertia[b],
                                        mech.body_primaries[b, :len(prim)]))
    need = lb @ acc[prim] - lb.sum(axis=1)[:, None] * np.array([0.0, 0.0, -G])  # m a - m g per primary

    def about_axis(forces):
        return sum(AXIS @ np.cross(pos[i] - P0, forces[s]) for s, i in enumerate(prim))

    spring = -(K_T * (0.0 - FREE) + C_T * w0[1])
    assert abs(about_axis(reactions[b]) - (about_axis(need) - spring)) <= 1e-9 * abs(spring)


def test_gradients_in_the_stiffness_match_central_differences(case):
    mech, q0, qd0, _, _ = case
    i = mech.free_slice("plate 2 0")

    def end(k, adjoint=None):
        m = mech.with_params(torsion={"bar": {"stiffness": k}})
        sol = simulate_mechanism(m, q0, qd0, 0.0, 0.5, rtol=1e-12, atol=1e-14, adjoint=adjoint)
        return sol.q[-1, i.start]

    assert_derivative_matches_central_difference(end, K_T, GRAD_RTOL, least=1e-6)


def test_bad_torsion_springs_are_refused_by_name():
    mb = MechanismBuilder()
    for kw, msg in [(dict(axis=(0, 0, 0)), "torsion spring 'x': axis must be a non-zero vector"),
                    (dict(stiffness=-1.0), "torsion spring 'x': stiffness must be a finite and non-negative"),
                    (dict(damping=float("inf")), "torsion spring 'x': damping must be a finite"),
                    (dict(stiffness="stiff"), "torsion spring 'x': stiffness must be")]:
        args = dict(axis=(0, 0, 1), stiffness=1.0, damping=0.0)
        args.update(kw)
        with pytest.raises(ModelError, match=msg):
            mb.torsion_spring("x", None, "a", **args)
    with pytest.raises(ModelError, match="torsion spring 'x': joins body 'a' to itself"):
        mb.torsion_spring("x", "a", "a", (0, 0, 1), 1.0)
    mb = MechanismBuilder()
    mb.ground("O", (0, 0, 0))
    mb.particle("e", (1, 0, 0))
    mb.rod("rod", "O", "e", 1.0)
    mb.torsion_spring("x", None, "rod", (0, 0, 1), 1.0)
    with pytest.raises(ModelError, match="torsion spring 'x': body 'rod' is a rod"):
        mb.build()
    mech, _, _ = plates()
    with pytest.raises(KeyError, match="no torsion named 'nope'"):
        mech.with_params(torsion={"nope": {"stiffness": 1.0}})
    with pytest.raises(ModelError, match="torsion 'bar' damping must be finite and non-negative"):
        mech.with_params(torsion={"bar": {"damping": -1.0}})
