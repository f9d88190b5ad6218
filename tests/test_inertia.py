"""Rigid-body inertia: conversions against independent point-mass sums, and refusal of non-physical bodies."""

import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from particlesim import InertiaError, RigidInertia
from particlesim.inertia import (
    com_params,
    inertia_about_com,
    inertia_about_point,
    inertia_from_second_moment,
    origin_params,
    pack_params,
    rotate_inertia,
    second_moment_from_inertia,
    unpack_params,
)
from particlesim.spatial import rpy_to_matrix

RTOL = 1e-12  # conversions are exact up to round-off


def _cloud(seed, n=7):
    """An independent reference: a random point-mass cloud and its inertia computed by brute summation."""
    rng = np.random.default_rng(seed)
    m = rng.uniform(0.1, 3.0, n)
    r = rng.normal(size=(n, 3))
    return m, r


def _inertia_of_cloud(m, r, about):
    d = r - about
    return sum(mi * (di @ di * np.eye(3) - np.outer(di, di)) for mi, di in zip(m, d))


@given(st.integers(0, 2**31 - 1))
@settings(max_examples=30, deadline=None)
def test_parallel_axis_and_rotation_match_point_mass_sums(seed):
    m, r = _cloud(seed)
    mass = m.sum()
    com = (m[:, None] * r).sum(0) / mass
    i_com = _inertia_of_cloud(m, r, com)
    point = np.random.default_rng(seed + 1).normal(size=3)
    expected = _inertia_of_cloud(m, r, point)
    got = inertia_about_point(i_com, mass, com, point)
    np.testing.assert_allclose(got, expected, rtol=0, atol=RTOL * np.abs(expected).max())
    back = inertia_about_com(expected, mass, com, point)
    np.testing.assert_allclose(back, i_com, rtol=0, atol=RTOL * np.abs(expected).max())
    rot = np.asarray(rpy_to_matrix(np.random.default_rng(seed + 2).uniform(-3, 3, 3)))
    expected_rot = _inertia_of_cloud(m, r @ rot.T, com @ rot.T)
    np.testing.assert_allclose(rotate_inertia(i_com, rot), expected_rot, rtol=0, atol=RTOL * np.abs(i_com).max())
    body = RigidInertia(mass, com, i_com)
    moved = body.transformed(rot, point)
    np.testing.assert_allclose(moved.com, rot @ com + point, rtol=0, atol=1e-13)
    s = second_moment_from_inertia(body.about(np.zeros(3)))
    np.testing.assert_allclose(s, np.einsum("i,ij,ik->jk", m, r, r), rtol=0, atol=RTOL * np.abs(s).max())
    np.testing.assert_allclose(inertia_from_second_moment(s), body.about(np.zeros(3)), rtol=0, atol=1e-12)


def test_origin_params_round_trip():
    body = RigidInertia(2.5, [0.1, -0.2, 0.3], [[0.3, 0.01, 0.02], [0.01, 0.4, -0.03], [0.02, -0.03, 0.5]])
    p = body.to_origin_params()
    np.testing.assert_allclose(p[:4], [2.5, 0.25, -0.5, 0.75], rtol=RTOL)
    j = body.about(jnp.zeros(3))
    np.testing.assert_allclose(p[4:], [j[0, 0], j[0, 1], j[0, 2], j[1, 1], j[1, 2], j[2, 2]], rtol=RTOL)
    again = RigidInertia.from_origin_params(p)
    np.testing.assert_allclose(again.inertia, body.inertia, rtol=0, atol=1e-15)
    np.testing.assert_allclose(again.com, body.com, rtol=0, atol=1e-15)


@given(st.integers(0, 2**31 - 1))
@settings(max_examples=20, deadline=None)
def test_ten_vector_codec_against_point_mass_sums_and_pinocchio(seed):
    """One codec for the 10-vector: its NumPy path (loaders) and JAX path (dynamics) agree, each equals the brute
    sums of a point-mass cloud about the origin and Pinocchio's dynamic parameters (their order is XX, XY, YY, XZ,
    YZ, ZZ), and com_params inverts origin_params."""
    import pinocchio as pin

    m, r = _cloud(seed)
    mass = m.sum()
    com = (m[:, None] * r).sum(0) / mass
    i_com = _inertia_of_cloud(m, r, com)
    expected = np.concatenate([[mass], (m[:, None] * r).sum(0), _inertia_of_cloud(m, r, np.zeros(3))[np.triu_indices(3)]])
    scale = np.abs(expected).max()
    p_np = origin_params(mass, com, i_com)
    assert isinstance(p_np, np.ndarray)
    np.testing.assert_allclose(p_np, expected, rtol=0, atol=RTOL * scale)
    np.testing.assert_allclose(origin_params(jnp.asarray(mass), jnp.asarray(com), jnp.asarray(i_com)), p_np, rtol=0,
                               atol=RTOL * scale)
    dyn = pin.Inertia(mass, com, i_com).toDynamicParameters()
    np.testing.assert_allclose(p_np[[0, 1, 2, 3, 4, 5, 7, 6, 8, 9]], dyn, rtol=0, atol=RTOL * scale)
    m2, c2, i2 = com_params(p_np)
    np.testing.assert_allclose(c2, com, rtol=0, atol=RTOL * np.abs(com).max())
    np.testing.assert_allclose(i2, i_com, rtol=0, atol=RTOL * scale)
    batch = np.stack([p_np, 2.0 * p_np])
    np.testing.assert_array_equal(pack_params(*unpack_params(batch)), batch)
    np.testing.assert_array_equal(np.asarray(pack_params(*unpack_params(jnp.asarray(batch)))), batch)


def test_kinetic_energy_matches_cloud():
    m, r = _cloud(3)
    mass = m.sum()
    com = (m[:, None] * r).sum(0) / mass
    body = RigidInertia(mass, com, _inertia_of_cloud(m, r, com))
    v0, w = np.array([0.3, -1.0, 2.0]), np.array([1.5, 0.2, -0.7])
    ke_cloud = 0.5 * sum(mi * np.sum((v0 + np.cross(w, ri)) ** 2) for mi, ri in zip(m, r))
    v_com = v0 + np.cross(w, com)
    np.testing.assert_allclose(body.kinetic_energy(v_com, w), ke_cloud, rtol=RTOL)


GOOD_I = np.diag([1.0, 2.0, 2.5])


@pytest.mark.parametrize(
    "mass, com, inertia, match",
    [
        (0.0, [0, 0, 0], GOOD_I, "mass must be positive"),
        (-1.0, [0, 0, 0], GOOD_I, "mass must be positive"),
        (1.0, [0, 0, 0], GOOD_I + np.triu(np.ones((3, 3)), 1) * 0.1, "not symmetric"),
        (1.0, [0, 0, 0], np.diag([1.0, -2.0, 2.5]), "not positive definite"),
        (1.0, [0, 0, 0], np.diag([1.0, 0.0, 1.0]), "not positive definite"),
        (1.0, [0, 0, 0], np.diag([1.0, 1.0, 3.0]), "triangle inequality"),
        (np.nan, [0, 0, 0], GOOD_I, "NaN or inf"),
        (1.0, [0, np.inf, 0], GOOD_I, "NaN or inf"),
        (1.0, [0, 0, 0], np.full((3, 3), np.nan), "NaN or inf"),
        (1.0, [0, 0], GOOD_I, r"shape \(3,\)"),
        (1.0, [0, 0, 0], np.eye(2), r"shape \(3, 3\)"),
        ([1.0, 2.0], [0, 0, 0], GOOD_I, "scalar"),
    ],
)
def test_non_physical_bodies_are_refused_by_name(mass, com, inertia, match):
    with pytest.raises(InertiaError, match="wheel_hub: .*" + match):
        RigidInertia(mass, com, inertia, name="wheel_hub")


def test_degenerate_only_when_allowed():
    rod = np.diag([1.0, 1.0, 0.0])
    with pytest.raises(InertiaError, match="positive definite"):
        RigidInertia(1.0, np.zeros(3), rod, name="rod")
    RigidInertia(1.0, np.zeros(3), rod, name="rod", degenerate_ok=True)


def test_slender_rod_against_point_masses_along_the_line():
    """A uniform rod as 2001 equal point masses along the segment (midpoint rule): mass, CoM and inertia."""
    p, q, m = np.array([0.1, -0.2, 0.3]), np.array([0.9, 0.4, -0.5]), 2.5
    s = (np.arange(2001) + 0.5) / 2001
    pts = p + s[:, None] * (q - p)
    c = pts.mean(axis=0)
    r = pts - c
    inertia = m / len(s) * (np.sum(r * r) * np.eye(3) - r.T @ r)
    rod = RigidInertia.slender_rod(m, p, q)
    np.testing.assert_allclose(rod.com, c, atol=1e-15)
    np.testing.assert_allclose(rod.inertia, inertia, atol=1e-6 * np.abs(inertia).max())  # midpoint rule O(1/n^2)
    off = RigidInertia.slender_rod(m, p, q, com=p + 0.25 * (q - p), moment=0.01)
    u = (q - p) / np.linalg.norm(q - p)
    np.testing.assert_allclose(np.asarray(off.inertia) @ u, 0.0, atol=1e-15)  # none about the rod
    with pytest.raises(InertiaError, match="link: rod end points coincide"):
        RigidInertia.slender_rod(1.0, p, p, name="link")
    with pytest.raises(InertiaError, match="link: a slender rod's centre of mass .* must lie on the line"):
        RigidInertia.slender_rod(1.0, p, q, com=(0, 0, 0), name="link")
    with pytest.raises(InertiaError, match="link: rod end points must be 3 finite numbers"):
        RigidInertia.slender_rod(1.0, p, (0, np.nan, 0), name="link")
