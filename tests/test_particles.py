"""Equivalent particle systems: moments, kinetic energy, the literal linear system (1)–(8), gradients, errors."""

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from jax.test_util import check_grads

from particlesim import NegativeMassWarning, PlacementError, RigidInertia
from particlesim.particles import (
    PAIRS,
    equivalent_particles,
    particle_positions,
    pose_from_primaries,
    solve_particle_masses,
)
from particlesim.spatial import rpy_to_matrix

MOMENT_RTOL = 1e-12  # mass, first moment, inertia entries, relative to the quantity's largest magnitude
KE_RTOL = 1e-12
POSE_ATOL = 1e-12
MIN_SHAPE_RATIO = 0.05  # "non-degenerate": smallest/largest singular value of the simplex edges


def _random_rotation(rng):
    return np.asarray(rpy_to_matrix(rng.uniform(-np.pi, np.pi, 3)))


def _random_body(rng):
    """A random physical body: second moments s >= 0 about the CoM give principal moments s_j + s_k (triangle OK)."""
    mass = rng.uniform(0.1, 100.0)
    s = rng.uniform(0.05, 1.0, 3) * mass
    rot = _random_rotation(rng)
    s_mat = rot @ np.diag(s) @ rot.T
    return RigidInertia(mass, rng.normal(size=3) * 0.3, np.trace(s_mat) * np.eye(3) - s_mat)


def _random_placement(rng, k, around=None):
    while True:
        p = rng.normal(size=(k, 3)) + (0 if around is None else around)
        sv = np.linalg.svd(p[1:] - p[0], compute_uv=False)
        if sv[-1] >= MIN_SHAPE_RATIO * sv[0]:
            return p


def _assert_moments(ps, body):
    m = float(body.mass)
    np.testing.assert_allclose(ps.total_mass(), m, rtol=MOMENT_RTOL)
    mc = np.asarray(body.mass * body.com)
    np.testing.assert_allclose(ps.first_moment(), mc, rtol=0, atol=MOMENT_RTOL * max(np.abs(mc).max(), m))
    i_o = np.asarray(body.about(np.zeros(3)))
    np.testing.assert_allclose(ps.inertia_about_origin(), i_o, rtol=0, atol=MOMENT_RTOL * np.abs(i_o).max())


# One compiled mass solve per kind, shared by the property tests.
_solve = jax.jit(solve_particle_masses)


@given(st.integers(0, 2**31 - 1))
@settings(max_examples=60, deadline=None)
def test_spatial_set_reproduces_mass_com_inertia_and_kinetic_energy(seed):
    rng = np.random.default_rng(seed)
    body = _random_body(rng)
    prim = _random_placement(rng, 4)
    ps = equivalent_particles(body, prim, on_negative="ignore")
    _assert_moments(ps, body)
    np.testing.assert_allclose(_solve(body.mass, body.com, body.inertia, prim), ps.masses, rtol=1e-13, atol=1e-13)
    # Independently: kinetic energy of the particles under a random rigid motion (body-frame components).
    v_o, w = rng.normal(size=3) * 3, rng.normal(size=3) * 3
    v = v_o + np.cross(w, np.asarray(ps.positions))
    ke_particles = 0.5 * np.sum(np.asarray(ps.masses) * np.sum(v**2, axis=1))
    ke_rigid = body.kinetic_energy(v_o + np.cross(w, body.com), w)
    scale = 0.5 * np.sum(np.abs(np.asarray(ps.masses)) * np.sum(v**2, axis=1))  # cancellation-aware scale
    np.testing.assert_allclose(ke_particles, ke_rigid, rtol=0, atol=KE_RTOL * scale)


def test_closed_form_equals_the_literal_linear_system():
    """Attia eqs. (1)–(8) assembled as a 10x10 matrix and solved by numpy: an independent route."""
    rng = np.random.default_rng(7)
    for _ in range(10):
        body = _random_body(rng)
        prim = _random_placement(rng, 4)
        r = np.asarray(particle_positions(prim))
        x, y, z = r.T
        a = np.stack([np.ones(10), x, y, z, y**2 + z**2, x**2 + z**2, x**2 + y**2, x * y, x * z, z * y])
        i_o = np.asarray(body.about(np.zeros(3)))
        mc = np.asarray(body.mass * body.com)
        # Attia's I_xi_eta etc. are the sums m x y (products without the minus sign): here -I_o off-diagonals.
        rhs = np.array([body.mass, *mc, i_o[0, 0], i_o[1, 1], i_o[2, 2], -i_o[0, 1], -i_o[0, 2], -i_o[2, 1]])
        expected = np.linalg.solve(a, rhs)
        got = solve_particle_masses(body.mass, body.com, body.inertia, prim)
        np.testing.assert_allclose(got, expected, rtol=0, atol=1e-10 * np.abs(expected).max())


def _planar_body(rng, normal_frame):
    """A body whose mass lies in a plane: a random point cloud in the (e1, e2) plane of ``normal_frame``."""
    pts2 = rng.normal(size=(6, 2)) * rng.uniform(0.1, 1.0, 2)
    m = rng.uniform(0.5, 2.0, 6)
    pts = pts2 @ normal_frame[:, :2].T + normal_frame[:, 2] * 0.7  # plane offset along its normal
    mass = m.sum()
    com = (m[:, None] * pts).sum(0) / mass
    d = pts - com
    i_com = sum(mi * (di @ di * np.eye(3) - np.outer(di, di)) for mi, di in zip(m, d))
    return RigidInertia(mass, com, i_com, degenerate_ok=True)


def test_planar_set_reproduces_planar_bodies():
    rng = np.random.default_rng(11)
    for _ in range(10):
        frame = _random_rotation(rng)
        body = _planar_body(rng, frame)
        tri = rng.normal(size=(3, 2))
        prim = tri @ frame[:, :2].T + frame[:, 2] * 0.7
        ps = equivalent_particles(body, prim, on_negative="ignore")
        assert ps.kind == "planar" and ps.masses.shape == (6,)
        _assert_moments(ps, body)


def test_rod_reproduces_line_bodies():
    rng = np.random.default_rng(12)
    for _ in range(10):
        u = rng.normal(size=3)
        u /= np.linalg.norm(u)
        base = rng.normal(size=3)
        t = rng.uniform(-1, 1, 5)
        m = rng.uniform(0.5, 2.0, 5)
        pts = base + t[:, None] * u
        mass = m.sum()
        com = (m[:, None] * pts).sum(0) / mass
        d = pts - com
        body = RigidInertia(mass, com, sum(mi * (di @ di * np.eye(3) - np.outer(di, di)) for mi, di in zip(m, d)),
                            degenerate_ok=True)
        ps = equivalent_particles(body, np.stack([base - u, base + 1.3 * u]), on_negative="ignore")
        assert ps.kind == "rod" and ps.masses.shape == (3,)
        _assert_moments(ps, body)


def test_uniform_rod_gets_one_sixth_two_thirds_one_sixth():
    """Analytic: a uniform rod is Simpson's rule, masses m/6, m/6 at the ends and 2m/3 at the centre."""
    length, mass = 2.0, 3.0
    body = RigidInertia(mass, [0, 0, 0], np.diag([0.0, 1.0, 1.0]) * mass * length**2 / 12, degenerate_ok=True)
    ps = equivalent_particles(body, [[-1.0, 0, 0], [1.0, 0, 0]])
    np.testing.assert_allclose(ps.masses, [mass / 6, mass / 6, 2 * mass / 3], rtol=1e-14)


def test_planar_and_rod_refuse_what_they_cannot_represent():
    cube = RigidInertia(1.0, [0, 0, 0], np.eye(3) * 0.2, name="knuckle")
    with pytest.raises(PlacementError, match="knuckle: a planar particle set cannot represent.*perpendicular-axis"):
        equivalent_particles(cube, [[1.0, 0, 0], [-1, 1, 0], [-1, -1, 0]], name="knuckle")
    flat = RigidInertia(1.0, [0, 0, 0.5], np.diag([0.1, 0.2, 0.3]), name="arm")
    with pytest.raises(PlacementError, match=r"arm: .*centre of mass \[0.0, 0.0, 0.5\] \(body frame\) lies .* off the plane .* contains the centre"):
        equivalent_particles(flat, [[1.0, 0, 0], [-1, 1, 0], [-1, -1, 0]], name="arm")
    with pytest.raises(PlacementError, match="tie_rod: a rod particle set cannot represent"):
        equivalent_particles(RigidInertia(1.0, [0, 0, 0], np.diag([0.1, 1.0, 1.0])), [[-1.0, 0, 0], [1.0, 0, 0]],
                             name="tie_rod")


@pytest.mark.parametrize(
    "prim, match",
    [
        ([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], "chassis: the 4 primary particles are coplanar"),
        ([[0, 0, 0], [1, 0, 0], [2, 0, 0]], "chassis: the 3 primary particles are collinear"),
        ([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 0]], "chassis: primary particles 1 and 4 coincide"),
        ([[1, 2, 3], [1, 2, 3]], "chassis: primary particles 1 and 2 coincide"),
        ([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 1]], "must number 4 .* got 5"),
        ([[0, 0], [1, 0], [0, 1]], r"shape \(k, 3\)"),
        ([[0, 0, 0], [1, 0, 0], [0, np.nan, 0], [0, 0, 1]], "NaN or inf"),
    ],
)
def test_singular_or_malformed_placements_are_refused(prim, match):
    body = RigidInertia(1.0, [0.2, 0.2, 0.2], np.eye(3) * 0.1)
    with pytest.raises(PlacementError, match=match):
        equivalent_particles(body, prim, name="chassis")


def test_negative_masses_warn_raise_or_ignore():
    slim = RigidInertia(1.0, [0, 0, 0], np.diag([5.0, 5.0, 5.0]))  # needs a spread far beyond a unit tetrahedron
    prim = np.array([[0.1, 0, 0], [-0.1, 0.1, 0], [-0.1, -0.1, 0], [0, 0, 0.1]])
    with pytest.warns(NegativeMassWarning, match="slim: equivalent particles .* negative masses.*farther apart.*"
                                                 "on_negative='ignore'"):
        ps = equivalent_particles(slim, prim, name="slim")
    _assert_moments(ps, slim)  # the dynamics stay exact
    with pytest.raises(PlacementError, match="slim: equivalent particles .* negative"):
        equivalent_particles(slim, prim, name="slim", on_negative="raise")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        equivalent_particles(slim, prim, name="slim", on_negative="ignore")


def test_check_grads_of_the_mass_solve():
    rng = np.random.default_rng(3)
    body = _random_body(rng)
    prim = jnp.asarray(_random_placement(rng, 4))
    tri = jnp.asarray(_random_placement(rng, 3))

    def f(mass, com, inertia, prim):
        return solve_particle_masses(mass, com, inertia, prim)

    check_grads(f, (body.mass, body.com, body.inertia, prim), order=1, modes=("fwd", "rev"), atol=1e-6, rtol=1e-6)
    # Planar kind too (a differently shaped solve).
    check_grads(f, (body.mass, body.com, body.inertia, tri), order=1, modes=("fwd", "rev"), atol=1e-6, rtol=1e-6)


def test_vmap_over_bodies_equals_loop():
    rng = np.random.default_rng(5)
    bodies = [_random_body(rng) for _ in range(4)]
    prim = _random_placement(rng, 4)
    stacked = jax.tree.map(lambda *x: jnp.stack(x), *bodies)
    batched = jax.vmap(lambda b: solve_particle_masses(b.mass, b.com, b.inertia, prim))(stacked)
    for b, row in zip(bodies, batched):
        np.testing.assert_allclose(row, solve_particle_masses(b.mass, b.com, b.inertia, prim), rtol=1e-14, atol=1e-13)


@given(st.integers(0, 2**31 - 1))
@settings(max_examples=20, deadline=None)
def test_pose_round_trip(seed):
    rng = np.random.default_rng(seed)
    for k in (4, 3):
        body_prim = _random_placement(rng, k)
        rot, origin = _random_rotation(rng), rng.normal(size=3) * 5
        world = body_prim @ rot.T + origin
        r_got, p_got = pose_from_primaries(body_prim, world)
        np.testing.assert_allclose(r_got, rot, rtol=0, atol=POSE_ATOL)
        np.testing.assert_allclose(p_got, origin, rtol=0, atol=POSE_ATOL * 10)
        body = _random_body(rng)
        ps = equivalent_particles(body, body_prim, on_negative="ignore") if k == 4 else None
        if ps is not None:
            expected = np.asarray(particle_positions(body_prim)) @ rot.T + origin
            np.testing.assert_allclose(ps.world_positions(r_got, p_got), expected, rtol=0, atol=1e-11)


def test_rod_pose_is_refused():
    with pytest.raises(PlacementError, match="rod.*no unique pose"):
        pose_from_primaries(np.eye(3)[:2], np.eye(3)[:2])


def test_secondary_order_follows_attia():
    assert PAIRS["spatial"] == ((0, 1), (0, 2), (1, 2), (0, 3), (1, 3), (2, 3))
    prim = np.array([[0.0, 0, 0], [2, 0, 0], [0, 2, 0], [0, 0, 2]])
    np.testing.assert_allclose(particle_positions(prim)[4], [1, 0, 0])  # particle 5 between 1 and 2
    np.testing.assert_allclose(particle_positions(prim)[9], [0, 1, 1])  # particle 10 between 3 and 4


def test_reduced_masses_match_eqs_25_27():
    body = RigidInertia(2.0, [0.1, 0.2, 0.3], np.diag([0.5, 0.6, 0.7]))
    ps = equivalent_particles(body, np.eye(4, 3) * 2 - 0.5, on_negative="ignore")
    m = np.asarray(ps.masses)
    bar, bbar = ps.reduced_masses()
    # particle 1 touches secondaries 5 (1-2), 6 (1-3), 8 (1-4)
    np.testing.assert_allclose(bar[0], m[0] + 0.5 * (m[4] + m[5] + m[7]), rtol=1e-14)
    np.testing.assert_allclose(bbar[3], m[3] + 0.25 * (m[7] + m[8] + m[9]), rtol=1e-14)
    np.testing.assert_allclose(np.sum(bar), body.mass, rtol=1e-13)


@pytest.mark.parametrize("kind, n", [("spatial", 10), ("planar", 6), ("rod", 3)])
def test_balanced_layout_gives_equal_positive_masses(kind, n):
    """Analytic: the stretched regular simplex gives every particle m/n."""
    from particlesim.particles import balanced_primaries

    rng = np.random.default_rng({"spatial": 1, "planar": 2, "rod": 3}[kind])
    frame = _random_rotation(rng)
    if kind == "spatial":
        body = _random_body(rng)
    elif kind == "planar":
        body = _planar_body(rng, frame)
    else:
        body = RigidInertia(2.0, [0.1, 0.2, 0.3], frame @ np.diag([0.0, 0.4, 0.4]) @ frame.T, degenerate_ok=True)
    prim = balanced_primaries(body, kind)
    ps = equivalent_particles(body, prim, on_negative="raise")
    np.testing.assert_allclose(ps.masses, np.full(n, float(body.mass) / n), rtol=1e-10)
    _assert_moments(ps, body)


def test_new_parameter_values_do_not_recompile():
    """Parameters are array leaves: a jitted solve (and its gradient) compiles once for all values."""
    rng = np.random.default_rng(9)
    traces = {"f": 0, "g": 0}

    def counted(name):
        def solve(m, c, i, p):
            traces[name] += 1  # runs once per trace, not per call
            return solve_particle_masses(m, c, i, p)
        return solve

    f = jax.jit(counted("f"))
    g = jax.jit(jax.grad(lambda m, c, i, p: jnp.sum(counted("g")(m, c, i, p) ** 2), argnums=(0, 2, 3)))
    for _ in range(3):
        body = _random_body(rng)
        prim = _random_placement(rng, 4)
        f(body.mass, body.com, body.inertia, prim)
        g(body.mass, body.com, body.inertia, prim)
    assert traces == {"f": 1, "g": 1}
