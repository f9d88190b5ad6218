"""A revolute joint between two moving bodies in one call (``mb.revolute(body_a, body_b, axis=(p0, p1))``: a cut joint
at ``p0`` and ``p1`` kept on ``a``'s axis, five rows) against the same joint made the established way, the two bodies
sharing two particles on the axis: a chain of two plates on skew axes, the first hinged to the ground, released under
gravity. Both give the same motion (to the solver's error), hold their constraints, and keep the energy; the body's
pose from ``body_poses`` is compared, so the different particle sets do not matter."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from particlesim.errors import ModelError
from particlesim.inertia import RigidInertia
from particlesim.mechanism import MechanismBuilder, body_poses, residuals, simulate_mechanism, total_energy

AXIS_1 = ((0.0, 0.0, 0.0), (0.0, 1.0, 0.0))  # plate 1 about the ground's y axis
AXIS_2 = ((0.6, 0.0, 0.0), (0.6, 0.6, 0.8))  # plate 2 about a skew axis through plate 1's far edge
T_END = 1.5
TS = np.linspace(0.0, T_END, 31)
SAME_TOL = 1e-8  # poses of the two formulations [m, rad-sized entries of R], both at rtol 1e-11
RESIDUAL_TOL = 1e-12
ENERGY_RTOL = 1e-8


def _plate(name, centre, mass=2.0):
    return RigidInertia.from_principal(mass, np.asarray(centre), (0.05, 0.08, 0.11), (0.0, 0.0, 0.0), name=name)


def build():
    """Each plate its own four particles, the joints by ``mb.revolute``."""
    mb = MechanismBuilder(gravity=(0.0, 0.0, -9.81))
    for k, xyz in enumerate([(0.1, 0.2, 0.0), (0.5, -0.1, 0.1), (0.3, 0.4, -0.2), (0.6, 0.1, 0.3)]):
        mb.particle(f"a{k}", xyz)
    for k, xyz in enumerate([(0.9, 0.2, 0.1), (1.2, 0.5, 0.4), (0.8, 0.7, 0.6), (1.1, 0.1, 0.7)]):
        mb.particle(f"b{k}", xyz)
    mb.body("plate 1", _plate("plate 1", (0.3, 0.2, 0.05)), ["a0", "a1", "a2", "a3"], on_negative="ignore")
    mb.body("plate 2", _plate("plate 2", (1.0, 0.4, 0.45)), ["b0", "b1", "b2", "b3"], on_negative="ignore")
    mb.revolute(None, "plate 1", axis=AXIS_1)
    mb.revolute("plate 1", "plate 2", axis=AXIS_2)
    return mb


@pytest.fixture(scope="module")
def runs():
    out = {}
    for one_call in (True, False):
        mb = build() if one_call else _shared_build()
        mech, q0 = mb.build(dof=2)
        sol = simulate_mechanism(mech, q0, 0 * q0, 0.0, T_END, rtol=1e-11, atol=1e-13, saveat_ts=TS)
        assert bool(sol.ok)
        out[one_call] = (mech, sol)
    return out


def _shared_build():
    """The established way: plate 1 on two ground particles of axis 1 and the two particles of axis 2, which plate 2
    shares (its other two primaries its own)."""
    p0, p1 = (np.asarray(p) for p in AXIS_2)
    mb = MechanismBuilder(gravity=(0.0, 0.0, -9.81))
    mb.ground("g0", AXIS_1[0])
    mb.ground("g1", AXIS_1[1])
    mb.particle("h0", p0)
    mb.particle("h1", p1)
    mb.particle("b", (1.2, 0.5, 0.4))
    mb.particle("c", (1.1, 0.1, 0.7))
    mb.body("plate 1", _plate("plate 1", (0.3, 0.2, 0.05)), ["g0", "g1", "h0", "h1"], on_negative="ignore")
    mb.body("plate 2", _plate("plate 2", (1.0, 0.4, 0.45)), ["h0", "h1", "b", "c"], on_negative="ignore")
    return mb


def test_one_call_revolute_moves_as_shared_axis_particles(runs):
    (m1, s1), (m2, s2) = runs[True], runs[False]
    poses = [jax.vmap(lambda q, m=m: body_poses(m, q))(s.q) for m, s in ((m1, s1), (m2, s2))]
    (r1, o1), (r2, o2) = poses
    assert float(jnp.max(jnp.abs(r1 - r2))) <= SAME_TOL and float(jnp.max(jnp.abs(o1 - o2))) <= SAME_TOL
    assert float(jnp.max(jnp.abs(poses[0][0][-1] - poses[0][0][0]))) > 0.1  # it swung
    for m, s in ((m1, s1), (m2, s2)):
        pos, vel = jax.vmap(lambda q, qd, m=m: residuals(m, q, qd))(s.q, s.qd)
        assert float(jnp.max(jnp.abs(pos))) <= RESIDUAL_TOL and float(jnp.max(jnp.abs(vel))) <= RESIDUAL_TOL
        e = jax.vmap(lambda q, qd, m=m: total_energy(m, q, qd))(s.q, s.qd)
        assert float(jnp.max(jnp.abs(e - e[0]))) <= ENERGY_RTOL * float(jnp.max(jnp.abs(e)))


def test_bad_revolutes_are_refused_by_name():
    mb = MechanismBuilder()
    mb.particle("a", (0.0, 0.0, 0.0))
    with pytest.raises(ModelError, match="revolute ground-plate: unknown body 'plate'"):
        mb.revolute(None, "plate", axis=AXIS_1)
    with pytest.raises(ModelError, match="hinge: the axis points coincide"):
        mb.revolute(None, "plate", axis=((0, 0, 0), (0, 0, 0)), name="hinge")
    with pytest.raises(ModelError, match="hinge: axis must be two points"):
        mb.revolute(None, "plate", axis=((0, 0, 0),), name="hinge")
    with pytest.raises(ModelError, match="hinge: in a planar mechanism"):
        MechanismBuilder(planar=True).revolute(None, "plate", axis=AXIS_1, name="hinge")
