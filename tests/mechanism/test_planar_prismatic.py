"""A translational joint between two moving bodies in a plane (a regression: the rotation row was once degenerate in
every planar configuration): a slider on a bar that turns about a fixed axis, against the Lagrange equations of
the two body coordinates (bar angle, slide) written here and integrated by SciPy."""

import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from particlesim.inertia import RigidInertia
from particlesim.mechanism import MechanismBuilder, constraints, simulate_mechanism

#: Slider and bar centres of mass, ours against the body-coordinate solution [m] (both integrated at rtol 1e-12).
POSITION_TOL = 1e-9
#: Constraint residual along the run [m, m^2].
RESIDUAL_TOL = 1e-12
G = 9.81
M1, C1 = 2.0, np.array([0.5, 0.04, 0.03])  # bar
I1 = np.array([[0.02, 0.001, 0.002], [0.001, 0.17, 0.0005], [0.002, 0.0005, 0.18]])
M2, C2 = 0.6, np.array([0.72, 0.015, 0.02])  # slider
I2 = np.array([[0.0012, 0.0001, 0.0], [0.0001, 0.0015, 0.0002], [0.0, 0.0002, 0.002]])
OMEGA0 = 2.5  # initial bar rate about z [rad/s]
T1 = 1.0


def _model():
    """Bar about the fixed z axis (gravity along -y: it swings in the xy plane); slider on the bar's x axis."""
    mb = MechanismBuilder(gravity=(0.0, -G, 0.0))
    mb.ground("Z0", (0, 0, 0))
    mb.ground("Z1", (0, 0, 1))
    mb.particle("A1", (1.0, 0, 0))
    mb.particle("A2", (0.5, 0.3, 0.2))
    mb.body("bar", RigidInertia(M1, C1, I1), ["Z0", "Z1", "A1", "A2"], on_negative="ignore")
    mb.point("Q", "bar", (0.3, 0, 0))
    for n, p in (("S0", (0.6, 0, 0)), ("S1", (0.8, 0, 0)), ("S2", (0.7, 0.1, 0)), ("S3", (0.7, 0.0, 0.1))):
        mb.particle(n, p)
    mb.body("slider", RigidInertia(M2, C2, I2), ["S0", "S1", "S2", "S3"], on_negative="ignore")
    mb.prismatic(("Q", "A1", "A2"), ("S0", "S1", "S2"), name="slot")
    mb.point("slider com", "slider", C2)
    mb.point("bar com", "bar", C1)
    return mb.build(dof=2)


def _reference(ts):
    """Lagrange equations in (theta, s): T = A th'^2 / 2 + m2 s'^2 / 2 - m2 cy th' s', A = I1O + I2zz + m2 |c|^2."""
    cx, cy = C2[0], C2[1]
    i1o = I1[2, 2] + M1 * (C1[0] ** 2 + C1[1] ** 2)

    def rhs(t, y):
        th, s, w, v = y
        a = i1o + I2[2, 2] + M2 * ((s + cx) ** 2 + cy**2)
        c, sn = np.cos(th), np.sin(th)
        dv_dth = G * (M1 * (C1[0] * c - C1[1] * sn) + M2 * ((s + cx) * c - cy * sn))
        dv_ds = M2 * G * sn
        m = np.array([[a, -M2 * cy], [-M2 * cy, M2]])
        f = np.array([-2 * M2 * (s + cx) * v * w - dv_dth, M2 * (s + cx) * w**2 - dv_ds])
        return [w, v, *np.linalg.solve(m, f)]

    sol = solve_ivp(rhs, (0.0, T1), [0.0, 0.0, OMEGA0, 0.0], method="DOP853", rtol=1e-12, atol=1e-14, t_eval=ts)
    th, s = sol.y[0], sol.y[1]

    def world(p):
        return np.stack([p[0] * np.cos(th) - p[1] * np.sin(th), p[0] * np.sin(th) + p[1] * np.cos(th)], axis=1)

    return world(C1), world(np.array([C2[0] + s, np.full_like(s, C2[1])]))


@pytest.fixture(scope="module")
def run():
    mech, x0 = _model()
    r = np.asarray(x0).reshape(-1, 3)
    v0 = np.cross(np.array([0.0, 0.0, OMEGA0]), r)  # all moving particles turn with the bar at t = 0
    ts = np.linspace(0.0, T1, 21)
    sol = simulate_mechanism(mech, jnp.asarray(x0), jnp.asarray(v0.reshape(-1)), 0.0, T1, solver="dopri8",
                             rtol=1e-12, atol=1e-14, saveat_ts=ts)
    return mech, sol, ts


def test_the_planar_slot_builds_with_two_degrees_of_freedom():
    mech, _ = _model()  # build(dof=2) raised "over-constrained ... slot (rotation)" before the fix
    assert mech.n_constraints == mech.n_coords - 2


def test_slider_on_a_turning_bar_matches_the_lagrange_equations(run):
    mech, sol, ts = run
    k_bar, k_sl = mech.point_index("bar com"), mech.point_index("slider com")
    pts = np.stack([np.asarray(mech.point_positions(mech.all_positions(x))) for x in sol.q])
    ref_bar, ref_sl = _reference(ts)
    np.testing.assert_allclose(pts[:, k_bar, :2], ref_bar, atol=POSITION_TOL)
    np.testing.assert_allclose(pts[:, k_sl, :2], ref_sl, atol=POSITION_TOL)
    np.testing.assert_allclose(pts[:, k_sl, 2], C2[2], atol=POSITION_TOL)  # stays in its plane
    assert np.linalg.norm(ref_sl[-1] - ref_sl[0]) > 0.1  # the slider really moved (along and across)
    res = max(float(jnp.abs(constraints(mech, x)).max()) for x in sol.q)
    assert res <= RESIDUAL_TOL
