"""Frame algebra (``particlesim.spatial``) against SciPy's rotations, cross products and the defining properties."""

import jax
import jax.numpy as jnp
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from jax.test_util import check_grads
from scipy.spatial.transform import Rotation

from particlesim.spatial import (SINCOS_LIMIT, frame_from_points, quaternion_to_matrix, rot_x, rot_y, rot_z,
                                 rpy_to_matrix, sincos, skew, unit_axis_rotations, unskew)

ATOL = 1e-14  # one rotation or cross product: round-off
GRAD_EPS = 1e-6  # check_grads step (float64)

seeds = st.integers(0, 2**31 - 1)


@given(seeds)
@settings(max_examples=10, deadline=None)
def test_skew_is_the_cross_product_and_unskew_inverts_it(seed):
    a, b = np.random.default_rng(seed).normal(size=(2, 3))
    np.testing.assert_allclose(skew(a) @ b, np.cross(a, b), rtol=0, atol=ATOL * 10)
    np.testing.assert_allclose(unskew(skew(a)), a, rtol=0, atol=ATOL)
    m = np.random.default_rng(seed + 1).normal(size=(3, 3))
    np.testing.assert_allclose(unskew(m), unskew(0.5 * (m - m.T)), rtol=0, atol=ATOL)  # the skew part only


@given(seeds)
@settings(max_examples=10, deadline=None)
def test_elementary_and_rpy_rotations_match_scipy(seed):
    rpy = np.random.default_rng(seed).uniform(-np.pi, np.pi, 3)
    for fn, axis, angle in ((rot_x, "x", rpy[0]), (rot_y, "y", rpy[1]), (rot_z, "z", rpy[2])):
        np.testing.assert_allclose(fn(angle), Rotation.from_euler(axis, angle).as_matrix(), rtol=0, atol=ATOL)
    # URDF roll-pitch-yaw: fixed axes x, then y, then z (SciPy's extrinsic "xyz")
    np.testing.assert_allclose(rpy_to_matrix(rpy), Rotation.from_euler("xyz", rpy).as_matrix(), rtol=0, atol=ATOL)


@given(seeds)
@settings(max_examples=10, deadline=None)
def test_axis_angle_rotations_match_scipy_rotation_vectors(seed):
    rng = np.random.default_rng(seed)
    axes = rng.normal(size=(5, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    angles = rng.uniform(-4.0, 4.0, 5)
    expected = Rotation.from_rotvec(axes * angles[:, None]).as_matrix()
    np.testing.assert_allclose(unit_axis_rotations(axes, angles), expected, rtol=0, atol=ATOL)


@given(seeds)
@settings(max_examples=10, deadline=None)
def test_quaternion_rotation_matches_scipy_and_normalises(seed):
    rng = np.random.default_rng(seed)
    quat = rng.normal(size=4)  # [x, y, z, w], any length
    expected = Rotation.from_quat(quat / np.linalg.norm(quat)).as_matrix()  # SciPy: scalar last
    np.testing.assert_allclose(quaternion_to_matrix(quat), expected, rtol=0, atol=ATOL)
    np.testing.assert_allclose(quaternion_to_matrix(3.7 * quat), expected, rtol=0, atol=ATOL)


def test_frame_from_points_is_right_handed_and_spans_the_points():
    p0, p1, p2 = np.array([0.3, -0.2, 1.0]), np.array([1.1, 0.4, 0.7]), np.array([-0.5, 0.9, 0.2])
    f = np.asarray(frame_from_points(p0, p1, p2))
    np.testing.assert_allclose(f.T @ f, np.eye(3), rtol=0, atol=ATOL)
    assert np.linalg.det(f) > 0
    np.testing.assert_allclose(f[:, 0], (p1 - p0) / np.linalg.norm(p1 - p0), rtol=0, atol=ATOL)
    assert abs((p2 - p0) @ f[:, 2]) < ATOL  # p2 lies in the plane of e1 and e2
    assert (p2 - p0) @ f[:, 1] > 0


def test_rotation_gradients_fwd_and_rev():
    """Derivatives against finite differences, including the zero angle of the axis-angle map (no division)."""
    check_grads(jax.jit(rpy_to_matrix), (jnp.array([0.3, -1.1, 2.0]),), order=1, modes=("fwd", "rev"), eps=GRAD_EPS)
    check_grads(jax.jit(quaternion_to_matrix), (jnp.array([0.1, -0.4, 0.3, 0.8]),), order=1, modes=("fwd", "rev"),
                eps=GRAD_EPS)
    axes = jnp.array([[0.0, 0.6, 0.8], [1.0, 0.0, 0.0]])
    rotations = jax.jit(lambda t: unit_axis_rotations(axes, t))
    for angles in (jnp.array([0.7, -2.0]), jnp.zeros(2)):
        check_grads(rotations, (angles,), order=1, modes=("fwd", "rev"), eps=GRAD_EPS)
    assert np.all(np.isfinite(jax.jacfwd(lambda t: unit_axis_rotations(axes, t))(jnp.zeros(2))))


#: ``sincos`` against NumPy's (correctly rounded in practice) sin and cos: within this many units in the last place
#: of the larger of |result| and 2**-1022 (the polynomials are within 1 ulp; the reduction adds at most 1).
SINCOS_ULP = 2


def test_sincos_matches_numpy_to_two_ulp_eager_and_jitted():
    """Up to SINCOS_LIMIT, both compiled (where XLA may fuse multiply-adds) and op by op (where it does not)."""
    rng = np.random.default_rng(0)
    for fn in (jax.jit(sincos), sincos):
        for scale in (1e-8, 1.0, np.pi, 100.0, 1e4, 1e7, SINCOS_LIMIT):
            x = rng.uniform(-scale, scale, 20_000)
            x[:6] = (0.0, -0.0, np.pi / 4, -np.pi / 2, np.pi, 100 * np.pi)
            s, c = (np.asarray(v) for v in fn(jnp.asarray(x)))
            for ours, ref in ((s, np.sin(x)), (c, np.cos(x))):
                ulp = np.spacing(np.maximum(np.abs(ref), np.finfo(float).tiny))
                assert np.max(np.abs(ours - ref) / ulp) <= SINCOS_ULP, scale
        s, c = fn(jnp.asarray([-0.0]))
        assert np.signbit(s[0]) and float(c[0]) == 1.0  # sin(-0) = -0
        s, c = fn(jnp.asarray([np.nan, np.inf, -np.inf, 1.001 * SINCOS_LIMIT, -1e20]))
        assert np.all(np.isnan(s)) and np.all(np.isnan(c))  # no unbounded or silent numbers
    s, c = sincos(jnp.asarray([0.5], dtype=jnp.float32))  # other types keep XLA's own
    assert s.dtype == jnp.float32 and abs(float(s[0]) - np.sin(0.5)) < 1e-6


def test_sincos_derivatives_are_cos_and_minus_sin():
    x = jnp.asarray(np.random.default_rng(1).uniform(-10.0, 10.0, 7))
    check_grads(sincos, (x,), order=2, modes=("fwd", "rev"), eps=GRAD_EPS)
    ds, dc = jax.jacfwd(sincos)(x)
    np.testing.assert_allclose(np.diag(ds), np.cos(np.asarray(x)), rtol=0, atol=ATOL)
    np.testing.assert_allclose(np.diag(dc), -np.sin(np.asarray(x)), rtol=0, atol=ATOL)
