"""Planar mechanisms (``MechanismBuilder(planar=True)``): the README's four-bar run as written, against a
body-coordinate solution (x, y, angle per body, revolute pins, SciPy DOP853) written here; a slider on a turning
bar built from (mass, polar moment, centre of mass) against the Lagrange equations of
``test_planar_prismatic.py``; the degree-of-freedom count in the plane; bad planar input."""

import re
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from particlesim.errors import ModelError
from particlesim.mechanism import (MechanismBuilder, body_angles, body_poses, body_reactions, constraints,
                                   cut_joint_forces, joint_reaction, simulate_mechanism)

README = Path(__file__).resolve().parents[2] / "README.md"
#: Joint positions of the four-bar, ours against the body-coordinate solution [m] (ours at the README's default
#: tsit5 rtol 1e-8: measured 1.7e-9).
FOUR_BAR_TOL = 2e-8
#: Body angles from body_angles against the same solution [rad] (measured 1.9e-9).
ANGLE_TOL = 2e-8
#: Cut-joint reaction against the reference's pin multipliers, relative to the largest (27 N; measured 4e-9).
FORCE_TOL = 5e-8
#: Slider and bar centres of mass against the Lagrange solution [m].
SLOT_TOL = 1e-9
#: Loop-closure residuals of the README four-bar over every saved state [m] and [m/s] (measured ~1e-15).
LOOP_ATOL = 1e-12
#: Allowed rise of the four-bar's total energy between saves, relative to its initial energy (dampers only take
#: energy out; the solver error at rtol 1e-8 is far below this).
ENERGY_RISE_RTOL = 1e-8


def _readme_example() -> dict:
    text = README.read_text()
    block = re.search(r"<!-- planar-four-bar.*?-->\s*```python\n(.*?)```", text, re.S).group(1)
    assert len([ln for ln in block.splitlines() if ln.strip()]) <= 15  # the README's limit on a quickstart
    env: dict = {}
    exec(compile(block, "README planar four-bar", "exec"), env)  # noqa: S102 (our own README)
    return env


def _body_coordinate_four_bar(lengths, masses, phi0, ts, k=80.0, c=0.5, l0=2.0, g=9.81):
    """Crank (about O), coupler, rocker (about C) as uniform rods in body coordinates q = (x, y, phi) x 3 with a
    constant mass matrix and four revolute pins (8 rows), the spring-damper A-C; index-1 with Baumgarte terms."""
    l1, l2, l3 = lengths
    o, cc = np.zeros(2), np.array([2.2, 0.0])
    m = np.repeat(masses, 3).astype(float)
    for b, (mass, ell) in enumerate(zip(masses, lengths)):
        m[3 * b + 2] = mass * ell**2 / 12
    e = lambda p: np.array([np.cos(p), np.sin(p)])  # noqa: E731
    de = lambda p: np.array([-np.sin(p), np.cos(p)])  # noqa: E731
    # pins: (body i, local s_i along its axis, body j or ground point, local s_j)
    pins = [(0, -l1 / 2, None, o), (0, l1 / 2, 1, -l2 / 2), (1, l2 / 2, 2, l3 / 2), (2, -l3 / 2, None, cc)]

    def parts(q, qd):
        phi = q[2::3]
        phid = qd[2::3]
        rows, gam, res = [], [], []
        for i, si, j, sj in pins:
            jr = np.zeros((2, 9))
            jr[:, 3 * i:3 * i + 2] = np.eye(2)
            jr[:, 3 * i + 2] = si * de(phi[i])
            p = q[3 * i:3 * i + 2] + si * e(phi[i])
            gm = si * e(phi[i]) * phid[i] ** 2
            if j is None:
                p = p - sj
            else:
                jr[:, 3 * j:3 * j + 2] = -np.eye(2)
                jr[:, 3 * j + 2] = -sj * de(phi[j])
                p = p - q[3 * j:3 * j + 2] - sj * e(phi[j])
                gm = gm - sj * e(phi[j]) * phid[j] ** 2
            rows.append(jr)
            gam.append(gm)
            res.append(p)
        return np.vstack(rows), np.concatenate(gam), np.concatenate(res)

    def forces(q, qd):
        f = np.zeros(9)
        f[1::3] = -np.asarray(masses) * g
        a = q[0:2] + l1 / 2 * e(q[2])
        va = qd[0:2] + l1 / 2 * de(q[2]) * qd[2]
        d = a - cc
        ell = np.linalg.norm(d)
        u = d / ell
        fa = -(k * (ell - l0) + c * (va @ u)) * u
        f[0:2] += fa
        f[2] += (l1 / 2) * (de(q[2]) @ fa)  # torque of fa about the crank's centre, (r x F)_z
        return f

    def rhs(t, y):
        q, qd = y[:9], y[9:]
        j, gam, res = parts(q, qd)
        a = 50.0
        gam = gam - 2 * a * (j @ qd) - a * a * res
        kkt = np.block([[np.diag(m), j.T], [j, np.zeros((8, 8))]])
        sol = np.linalg.solve(kkt, np.concatenate([forces(q, qd), gam]))
        return np.concatenate([qd, sol[:9]])

    p1, p2, p3 = phi0
    a = l1 * e(p1)
    q0 = np.concatenate([l1 / 2 * e(p1), [p1], a + l2 / 2 * e(p2), [p2], cc + l3 / 2 * e(p3), [p3]])
    r = solve_ivp(rhs, (ts[0], ts[-1]), np.concatenate([q0, np.zeros(9)]), method="DOP853", rtol=1e-12, atol=1e-12,
                  t_eval=ts)
    q = r.y[:9].T
    a = q[:, 0:2] + l1 / 2 * np.stack([np.cos(q[:, 2]), np.sin(q[:, 2])], axis=1)
    b = q[:, 3:5] + l2 / 2 * np.stack([np.cos(q[:, 5]), np.sin(q[:, 5])], axis=1)
    # the pin multipliers (O, A, B, C: rows 0-1, 2-3, 4-5, 6-7); pin (i, j) pushes body i with -lam, j with +lam
    lams = []
    for y in r.y.T:
        qq, qd = y[:9], y[9:]
        j, gam, res = parts(qq, qd)
        gam = gam - 2 * 50.0 * (j @ qd) - 2500.0 * res
        kkt = np.block([[np.diag(m), j.T], [j, np.zeros((8, 8))]])
        lams.append(np.linalg.solve(kkt, np.concatenate([forces(qq, qd), gam]))[9:])
    return a, b, q[:, 2::3], np.asarray(lams)


@pytest.fixture(scope="module")
def readme():
    return _readme_example()


def test_readme_four_bar_builds_in_the_plane_with_one_freedom(readme):
    mb, mech = readme["mb"], readme["mech"]
    assert mech.topo.planar and mb.constraint_rank.dof == 1
    moved = max(np.linalg.norm(v) for v in mb.assembly.moved.values())
    assert 1e-5 < moved < 1e-3  # the rounded loop was closed
    assert float(jnp.max(jnp.abs(constraints(mech, jnp.asarray(readme["q0"]))))) <= 1e-12
    assert float(jnp.max(jnp.abs(readme["sol"].q.reshape(201, -1, 3)[:, :, 2]))) <= 1e-15  # stays in the plane


def test_readme_four_bar_keeps_its_loop_closed_and_loses_energy(readme):
    """The README's mechanism quickstart as run: every saved state on the constraints to round-off, the damped
    four-bar's total energy never rising."""
    from particlesim.mechanism import residuals, total_energy

    mech, sol, angles = readme["mech"], readme["sol"], np.asarray(readme["angles"])
    assert bool(sol.ok)
    assert angles.shape == (len(sol.ts), 3) and np.all(np.isfinite(angles))
    phi, dphi = jax.jit(jax.vmap(lambda q, qd: residuals(mech, q, qd)))(sol.q, sol.qd)
    assert float(np.max(np.abs(phi))) <= LOOP_ATOL
    assert float(np.max(np.abs(dphi))) <= LOOP_ATOL
    energy = np.asarray(jax.jit(jax.vmap(lambda q, qd: total_energy(mech, q, qd)))(sol.q, sol.qd))
    assert np.max(np.diff(energy)) <= ENERGY_RISE_RTOL * abs(energy[0])
    assert energy[-1] < energy[0]


def test_readme_four_bar_against_body_coordinates(readme):
    mech, x0, sol, angles = readme["mech"], np.asarray(readme["q0"]), readme["sol"], readme["angles"]
    ia, ib = mech.free_slice("A"), mech.free_slice("B")
    a0, b0 = x0[ia][:2], x0[ib][:2]
    # the body shapes as built (from the rounded data): rocker length from C to the given B'
    lengths = (1.0, float(np.hypot(1.866, 0.5)), float(np.hypot(2.2 - 1.8661, 1.4999)))
    cc = np.array([2.2, 0.0])
    phi0 = (np.arctan2(a0[1], a0[0]), np.arctan2(*(b0 - a0)[::-1]), np.arctan2(*(b0 - cc)[::-1]))
    assert np.linalg.norm(b0 - cc) == pytest.approx(lengths[2], abs=1e-12)  # assembly kept the rocker's length
    ts = np.asarray(np.linspace(0.0, 2.0, 201))
    a_ref, b_ref, phi_ref, pins = _body_coordinate_four_bar(lengths, (1.0, 2.0, 1.5), phi0, ts)
    pin_b = -pins[:, 4:6]
    q = np.asarray(sol.q)
    assert np.max(np.abs(q[:, ia][:, :2] - a_ref)) <= FOUR_BAR_TOL
    assert np.max(np.abs(q[:, ib][:, :2] - b_ref)) <= FOUR_BAR_TOL
    assert np.ptp(a_ref[:, 0]) > 0.1  # it moves
    # body_angles: rotation from the built orientation; built crank along +y (pi/2), coupler and rocker as drawn
    built = np.array([np.pi / 2, np.arctan2(0.5, 1.866), np.arctan2(1.4999, 1.8661 - 2.2)])
    np.testing.assert_allclose(angles, np.unwrap(phi_ref - built, axis=0), atol=ANGLE_TOL)
    # the cut joint's reaction (rocker on coupler at B) against the body-coordinate pin multipliers
    for k in (0, 50, 137, 200):
        f = cut_joint_forces(mech, ts[k], sol.q[k], sol.qd[k])["cut joint B=B'"]
        assert float(f[2]) == 0.0
        np.testing.assert_allclose(np.asarray(f[:2]), pin_b[k], atol=FORCE_TOL * np.max(np.abs(pin_b)))
    # every joint's reaction from body_reactions / joint_reaction against the pins
    scale = FORCE_TOL * np.max(np.abs(pins))
    for k in (0, 50, 137, 200):
        t, x, xd = ts[k], sol.q[k], sol.qd[k]
        lam = pins[k].reshape(4, 2)
        react = np.asarray(body_reactions(mech, t, x, xd))[:, :2, :2]  # (crank, coupler, rocker) x (first, second)
        p = np.asarray(x).reshape(-1, 3)
        a, v_a = p[mech.free.index(mech.index("A"))][:2], np.asarray(xd).reshape(-1, 3)[mech.free.index(mech.index("A"))][:2]
        d = a - np.array([2.2, 0.0])
        u = d / np.linalg.norm(d)
        spring = -(80.0 * (np.linalg.norm(d) - 2.0) + 0.5 * (v_a @ u)) * u  # the load applied at particle A
        np.testing.assert_allclose(react[0, 0], -lam[0], atol=scale)  # crank at O, from the ground
        np.testing.assert_allclose(react[0, 1], -lam[1] + spring, atol=scale)  # crank at A: coupler + spring
        np.testing.assert_allclose(react[1, 0], lam[1], atol=scale)  # coupler at A, from the crank
        np.testing.assert_allclose(react[1, 1], -lam[2], atol=scale)  # coupler at B, from the rocker
        np.testing.assert_allclose(react[2, 1], lam[2], atol=scale)  # rocker at B', from the coupler
        np.testing.assert_allclose(react[2, 0], -lam[3], atol=scale)  # rocker at C, from the ground
        f, m = joint_reaction(mech, t, x, xd, "rocker", ["C"])
        np.testing.assert_allclose(np.asarray(f[:2]), -lam[3], atol=scale)
        assert float(jnp.max(jnp.abs(m))) == 0.0


def _slot():
    from test_planar_prismatic import C1, C2, I1, I2, M1, M2

    mb = MechanismBuilder(planar=True)
    mb.ground("Z0", (0, 0))
    mb.particle("A1", (1.0, 0))
    mb.particle("A2", (0.5, 0.3))
    mb.planar_body("bar", M1, I1[2, 2], C1[:2], ["Z0", "A1", "A2"], on_negative="ignore")
    mb.point("Q", "bar", (0.3, 0))
    for n, p in (("S0", (0.6, 0)), ("S1", (0.8, 0)), ("S2", (0.7, 0.1))):
        mb.particle(n, p)
    mb.planar_body("slider", M2, I2[2, 2], C2[:2], ["S0", "S1", "S2"], on_negative="ignore")
    mb.prismatic(("Q", "A1", "A2"), ("S0", "S1", "S2"), name="slot")
    mb.point("slider com", "slider", C2[:2])
    mb.point("bar com", "bar", C1[:2])
    return mb


def test_planar_slot_against_lagrange_equations():
    from test_planar_prismatic import OMEGA0, T1, _reference

    mb = _slot()
    mech, x0 = mb.build(dof=2)
    # bar 3 + slider 3 distances, slot 2, five free particles held in the plane
    assert mb.constraint_rank.rows == 3 + 3 + 2 + 5 and mb.constraint_rank.redundant == ()
    r = np.asarray(x0).reshape(-1, 3)
    v0 = np.cross(np.array([0.0, 0.0, OMEGA0]), r)
    ts = np.linspace(0.0, T1, 21)
    sol = simulate_mechanism(mech, jnp.asarray(x0), jnp.asarray(v0.reshape(-1)), 0.0, T1, solver="dopri8",
                             rtol=1e-12, atol=1e-14, saveat_ts=ts)
    bar_ref, slider_ref = _reference(ts)
    def com(x, name):
        k = mech.point_index(name)
        return mech.point_positions(mech.all_positions(x))[k][:2]

    bar = np.asarray(jax.vmap(lambda x: com(x, "bar com"))(sol.q))
    slider = np.asarray(jax.vmap(lambda x: com(x, "slider com"))(sol.q))
    assert np.max(np.abs(bar - bar_ref)) <= SLOT_TOL
    assert np.max(np.abs(slider - slider_ref)) <= SLOT_TOL
    rot, _ = body_poses(mech, sol.q[-1])
    ang = body_angles(mech, sol.q[-1])
    np.testing.assert_allclose(np.asarray(ang), np.arctan2(rot[:, 1, 0], rot[:, 0, 0]), atol=1e-12)


def test_bad_planar_input():
    mb = MechanismBuilder(planar=True)
    with pytest.raises(ModelError, match=r"particle 'P': position has z = 0.1, off the plane"):
        mb.particle("P", (0.0, 1.0, 0.1))
    with pytest.raises(ModelError, match=r"particle 'Q': position must be 2 \(x, y\) or 3 finite numbers"):
        mb.particle("Q", (0.0, np.nan))
    for n, p in (("a", (0, 0)), ("b", (1, 0)), ("c", (0, 1)), ("d", (1, 1))):
        mb.particle(n, p)
    with pytest.raises(ModelError, match="body 'box': a planar mechanism's bodies are rods .* got 4"):
        mb.body("box", None, ["a", "b", "c", "d"])
    with pytest.raises(ModelError, match="planar body 'plate': polar moment must be finite and non-negative"):
        mb.planar_body("plate", 1.0, -0.1, (0.3, 0.3), ["a", "b", "c"])
    with pytest.raises(ModelError, match="planar body 'plate': needs 3 primary particles"):
        mb.planar_body("plate", 1.0, 0.1, (0.3, 0.3), ["a", "b"])
    with pytest.raises(ModelError, match="rod 'r': unknown particle 'zz'"):
        mb.rod("r", "a", "zz", mass=1.0)
    with pytest.raises(ModelError, match="gravity must be 2 \\(x, y\\) or 3"):
        MechanismBuilder(gravity=(0, 1, 2, 3), planar=True)


def test_body_angles_refuses_a_spatial_mechanism(four_bar):
    mech, x0 = four_bar().build()
    with pytest.raises(ModelError, match="body_angles: the mechanism is not planar"):
        body_angles(mech, jnp.asarray(x0))


def test_joint_reaction_refuses_a_particle_of_another_body(four_bar):
    mech, x0 = four_bar().build()
    x0 = jnp.asarray(x0)
    with pytest.raises(ModelError, match="joint_reaction: particle 'B' is not a primary of body 'crank'"):
        joint_reaction(mech, 0.0, x0, jnp.zeros_like(x0), "crank", ["B"])


def test_two_point_planar_prismatic_is_the_checked_three_point_joint():
    """In a plane a prismatic joint needs only the axis points; its rows equal those of the three-point form (whose
    motion test_planar_slot_against_lagrange_equations checks), built for a slider-crank."""
    from particlesim.mechanism import accelerations

    def build(two: bool):
        mb = MechanismBuilder(planar=True)
        mb.ground("O", (0.0, 0.0))
        mb.ground("G1", (1.0, 0.0))
        mb.ground("G2", (0.5, 0.1))
        mb.particle("A", (0.0, 0.1))
        mb.particle("P", (0.2828, 0.0))
        mb.particle("P1", (0.3328, 0.0))
        mb.particle("P2", (0.3078, 0.02))
        mb.rod("crank", "O", "A", mass=0.3)
        mb.rod("rod", "A", "P", mass=0.4)
        mb.planar_body("piston", 0.5, 2e-4, (0.3078, 0.005), ["P", "P1", "P2"], on_negative="ignore")
        if two:
            mb.prismatic(("O", "G1"), ("P", "P1"), name="guide")
        else:
            mb.prismatic(("O", "G1", "G2"), ("P", "P1", "P2"), name="guide")
        mb.spring_damper("return", "P2", "G1", 200.0, 1.0, 0.65)
        return mb.build(dof=1)

    (m3, x3), (m2, x2) = build(False), build(True)
    assert m2.n_constraints == m3.n_constraints
    xd = jnp.zeros(len(x3)).at[m3.free_slice("A")].set(jnp.array([-1.0, 0.0, 0.0]))
    from particlesim.mechanism import project

    x, xd = project(m3, jnp.asarray(x3), xd)
    np.testing.assert_allclose(np.asarray(accelerations(m2, 0.0, x, xd)), np.asarray(accelerations(m3, 0.0, x, xd)),
                               rtol=0, atol=1e-12)
    mb = MechanismBuilder(planar=True)
    mb.ground("O", (0.0, 0.0))
    mb.particle("P", (0.0, 0.0))
    with pytest.raises(ModelError, match="prismatic joint g: needs three particles on each side \\(or two"):
        mb.prismatic(("O",), ("P",), name="g")
