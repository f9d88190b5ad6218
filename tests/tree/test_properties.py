"""Structural properties of A, C, Q against autodiff of the energies (eqs. 4, 11, 15) and exact identities."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from particlesim.tree import (
    bias_forces,
    coriolis_matrix,
    coriolis_times_qdot,
    forward_dynamics,
    gravity_torques,
    inverse_dynamics,
    kinetic_energy,
    link_jacobian,
    link_poses,
    mass_matrix,
    potential_energy,
)
from tree_helpers import max_rel

#: Identities that hold exactly in exact arithmetic, compared in float64.
EXACT_RTOL = 1e-11
SEEDS = [0, 1, 2]


def _state(model, seed):
    rng = np.random.default_rng(seed)
    return (jnp.asarray(rng.uniform(-2, 2, model.nq)), jnp.asarray(rng.normal(size=model.nq)),
            jnp.asarray(rng.normal(size=model.nq)))


@pytest.mark.parametrize("seed", SEEDS)
def test_mass_matrix_symmetric_positive_definite(small_tree, seed):
    q, _, _ = _state(small_tree, seed)
    a = np.asarray(mass_matrix(small_tree, q))
    assert np.array_equal(a, a.T)
    assert np.linalg.eigvalsh(a).min() > 0.0


@pytest.mark.parametrize("seed", SEEDS)
def test_mass_matrix_is_hessian_of_kinetic_energy(small_tree, seed):
    q, qd, _ = _state(small_tree, seed)
    h = jax.hessian(lambda v: kinetic_energy(small_tree, q, v))(qd)
    assert max_rel(mass_matrix(small_tree, q), h) <= EXACT_RTOL


@pytest.mark.parametrize("seed", SEEDS)
def test_bias_forces_equal_lagrange_equations(small_tree, seed):
    """``C qd + Q = d/dt dE/dqd - dE/dq + dU/dq`` at ``qdd = 0`` (eq. 1), every term by autodiff of eqs. 11, 15."""
    q, qd, _ = _state(small_tree, seed)
    de_dqd = lambda x: jax.grad(kinetic_energy, argnums=2)(small_tree, x, qd)  # noqa: E731
    ddt = jax.jvp(de_dqd, (q,), (qd,))[1]
    de_dq = jax.grad(kinetic_energy, argnums=1)(small_tree, q, qd)
    du_dq = jax.grad(potential_energy, argnums=1)(small_tree, q)
    assert max_rel(gravity_torques(small_tree, q), du_dq) <= EXACT_RTOL
    assert max_rel(coriolis_times_qdot(small_tree, q, qd), ddt - de_dq) <= EXACT_RTOL
    assert max_rel(bias_forces(small_tree, q, qd), ddt - de_dq + du_dq) <= EXACT_RTOL


@pytest.mark.parametrize("seed", SEEDS)
def test_christoffel_coriolis(small_tree, seed):
    """``C`` of eq. (4): ``C qd`` equals the fast term and ``Adot - 2 C`` is skew-symmetric."""
    q, qd, _ = _state(small_tree, seed)
    c = coriolis_matrix(small_tree, q, qd)
    assert max_rel(c @ qd, coriolis_times_qdot(small_tree, q, qd)) <= EXACT_RTOL
    adot = jax.jvp(lambda x: mass_matrix(small_tree, x), (q,), (qd,))[1]
    n = adot - 2.0 * c
    assert np.max(np.abs(n + n.T)) <= EXACT_RTOL * np.max(np.abs(n))


@pytest.mark.parametrize("seed", SEEDS)
def test_forward_inverse_round_trip(small_tree, seed):
    q, qd, tau = _state(small_tree, seed)
    for eps in (None, 0.05):
        qdd = forward_dynamics(small_tree, q, qd, tau, smooth_friction=eps)
        assert max_rel(inverse_dynamics(small_tree, q, qd, qdd, smooth_friction=eps), tau) <= EXACT_RTOL


def test_jacobian_matches_differentiated_poses(small_tree):
    """Linear rows: d p_j / dq; angular rows: ``skew(w) = Rdot R^T`` (independent of the Jacobian formula)."""
    q, qd, _ = _state(small_tree, 5)
    for j in range(small_tree.nq):
        (r, p), (rdot, pdot) = jax.jvp(lambda x: tuple(a[j] for a in link_poses(small_tree, x)), (q,), (qd,))
        w_hat = rdot @ r.T
        w = jnp.array([w_hat[2, 1], w_hat[0, 2], w_hat[1, 0]])
        jac = link_jacobian(small_tree, q, j)
        assert max_rel(jac @ qd, jnp.concatenate([pdot, w])) <= EXACT_RTOL
        local = link_jacobian(small_tree, q, j, frame="local")
        assert max_rel(local @ qd, jnp.concatenate([r.T @ pdot, r.T @ w])) <= EXACT_RTOL


def test_link_poses_equal_the_link_by_link_products():
    """The pointer-jumping composition of :func:`link_poses` against the plain recursion ``R_i = R_parent R_rel``,
    ``p_i = p_parent + R_parent p_rel`` over :func:`joint_transforms`, on a hand-built forest with a free root, a ball
    joint, prismatic and revolute joints and parents listed after their children: values, derivatives (forward,
    reverse, second order) and both compositions under ``jax.vmap``."""
    from particlesim.tree import TreeModel
    from particlesim.tree.kinematics import VMAP_JUMPING_MAX_STATES, joint_transforms

    rng = np.random.default_rng(5)
    parents = [3, -1, 4, 1, 1, 0, -1, 6]
    kinds = ["revolute", "free", "prismatic", "ball", "revolute", "revolute", "prismatic", "revolute"]
    axes = rng.normal(size=(8, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    rots = np.stack([np.linalg.qr(rng.normal(size=(3, 3)))[0] for _ in range(8)])
    rots *= np.linalg.det(rots)[:, None, None]
    model = TreeModel(parents=parents, kinds=kinds, axes=axes, origin_rotations=rots,
                      origin_xyz=rng.uniform(-0.5, 0.5, (8, 3)),
                      inertia=np.tile([1.0, 0, 0, 0, 1, 0, 0, 1, 0, 1], (8, 1)),
                      joint_names=[f"j{i}" for i in range(8)], gravity=(0.0, 0.0, -9.81))

    def plain(q):  # the reference: R_i = R_parent R_rel, p_i = p_parent + R_parent p_rel, parents found as we go
        r_rel, p_rel = joint_transforms(model, q)
        rs, ps = [None] * 8, [None] * 8
        while any(r is None for r in rs):
            for i, k in enumerate(parents):
                if rs[i] is None and (k < 0 or rs[k] is not None):
                    rs[i] = r_rel[i] if k < 0 else rs[k] @ r_rel[i]
                    ps[i] = p_rel[i] if k < 0 else ps[k] + rs[k] @ p_rel[i]
        return jnp.stack(rs), jnp.stack(ps)

    for _ in SEEDS:
        q = jnp.asarray(rng.uniform(-1.5, 1.5, model.nq))
        for ours, ref in zip(link_poses(model, q), plain(q)):
            assert max_rel(np.asarray(ours), np.asarray(ref)) <= EXACT_RTOL

    # Derivatives: link_poses takes its tangents link by link (a custom JVP beside the pointer-jumping value); against
    # JAX's own derivatives of the plain recursion, forward and reverse, and check_grads to second order.
    def poses(q):
        return link_poses.raw(model, q)

    q = jnp.asarray(rng.uniform(-1.5, 1.5, model.nq))
    v = jnp.asarray(rng.normal(size=model.nq))
    for ours, ref in zip(jax.jvp(poses, (q,), (v,))[1], jax.jvp(plain, (q,), (v,))[1]):
        assert max_rel(np.asarray(ours), np.asarray(ref)) <= EXACT_RTOL
    for ours, ref in zip(jax.jacrev(poses)(q), jax.jacrev(plain)(q)):
        assert max_rel(np.asarray(ours), np.asarray(ref)) <= EXACT_RTOL
    check_grads(poses, (q,), order=2, modes=("fwd", "rev"))
    # Under jax.vmap a few states keep the pointer jumping and many take the link-by-link composition
    # (VMAP_JUMPING_MAX_STATES): both against the plain recursion, values and tangents.
    for states in (3, VMAP_JUMPING_MAX_STATES + 4):
        qs = jnp.asarray(rng.uniform(-1.5, 1.5, (states, model.nq)))
        vs = jnp.asarray(rng.normal(size=(states, model.nq)))
        ours = jax.vmap(lambda q, v: jax.jvp(poses, (q,), (v,)))(qs, vs)
        ref = jax.vmap(lambda q, v: jax.jvp(plain, (q,), (v,)))(qs, vs)
        for a, b in zip(jax.tree.leaves(ours), jax.tree.leaves(ref)):
            assert max_rel(np.asarray(a), np.asarray(b)) <= EXACT_RTOL


def test_changing_a_link_mass_by_its_centre_of_mass_parameters(small_tree):
    """docs/trees.md's recipe: a link's mass changed through ``com_params``/``origin_params`` keeps its centre of
    mass and its inertia about it, so the potential energy changes by exactly ``-dm g . x_com`` (the link's centre of
    mass placed by ``link_poses``), and the recipe differentiates."""
    from particlesim.inertia import com_params, origin_params

    model = small_tree
    k = model.link_index(model.link_names[-1])
    m, c, i_com = com_params(model.inertia[k])

    def heavier(scale):
        return model.with_params(inertia=model.inertia.at[k].set(origin_params(scale * m, c, i_com)))

    m2, c2, i2 = com_params(heavier(1.5).inertia[k])
    assert abs(float(m2 / m) - 1.5) <= EXACT_RTOL
    assert max_rel(c2, c) <= EXACT_RTOL and max_rel(i2, i_com) <= EXACT_RTOL
    for seed in SEEDS:
        q = _state(model, seed)[0]
        rot, pos = link_poses(model, q)
        x_com = rot[k] @ c + pos[k]
        du = potential_energy(heavier(1.5), q) - potential_energy(model, q)
        expected = -0.5 * m * jnp.dot(model.gravity, x_com)
        assert abs(float(du - expected)) <= EXACT_RTOL * float(abs(expected))
    check_grads(lambda s: potential_energy(heavier(s), q), (1.5,), order=1, modes=("fwd", "rev"))


def test_link_parameters_by_name(small_tree):
    """``with_params(link={name: {...}})`` equals the com_params / origin_params recipe field by field (a new mass keeps
    the centre of mass and the inertia about it), traces (one compiled program for new values, gradient against a
    central difference) and refuses unknown links, fields and shapes (traced ones too), a negative, NaN or
    non-physical mass distribution (by ``check_inertia``, naming the link), and a partial change of a massless link."""
    from particlesim.errors import ModelError
    from particlesim.inertia import com_params, origin_params

    model = small_tree
    name = model.link_names[-1]
    k = model.link_index(name)
    m, c, i_com = com_params(model.inertia[k])
    new_c, new_i = c + jnp.array([0.01, -0.02, 0.03]), 1.1 * i_com
    for given, expected in (({"mass": 2.0 * m}, (2.0 * m, c, i_com)), ({"com": new_c}, (m, new_c, i_com)),
                            ({"inertia": new_i, "mass": 0.5 * m}, (0.5 * m, c, new_i))):
        row = model.with_params(link={name: given}).inertia[k]
        assert max_rel(row, origin_params(*expected)) <= EXACT_RTOL, given
        assert max_rel(np.delete(np.asarray(model.with_params(link={name: given}).inertia), k, 0),
                       np.delete(np.asarray(model.inertia), k, 0)) == 0.0  # other links untouched
    q = _state(model, 0)[0]
    rot, pos = link_poses(model, q)  # independent of the recipe: doubling the mass adds m g . x_com, no more
    du = potential_energy(model.with_params(link={name: {"mass": 2.0 * m}}), q) - potential_energy(model, q)
    expected = -m * jnp.dot(model.gravity, rot[k] @ c + pos[k])
    assert abs(float(du - expected)) <= EXACT_RTOL * float(abs(expected))
    traces = []
    energy = jax.jit(lambda mass: traces.append(1) or potential_energy(model.with_params(link={name: {"mass": mass}}),
                                                                       q))
    h = 1e-6
    fd = (energy(m + h) - energy(m - h)) / (2 * h)
    assert abs(float(jax.grad(energy)(m)) - float(fd)) <= 1e-7 * abs(float(fd))
    assert len(traces) == 1  # new values, and the gradient, reuse the traced program
    for bad, match in (({"nowhere": {"mass": 1.0}}, "unknown link"), ({name: {"masss": 1.0}}, "takes a dict"),
                       ({name: {"com": (0.0, 1.0)}}, r"centre of mass must have shape \(3,\)"),
                       ({name: {"mass": -1.0}}, "mass must be positive"),
                       ({name: {"inertia": np.diag([1.0, 1.0, 3.0])}}, "triangle inequality"),
                       ({name: {"mass": float("nan")}}, "NaN or inf")):
        with pytest.raises(ModelError, match=match):
            model.with_params(link=bad)
    with pytest.raises(ModelError, match=r"com \(3,\)"):  # traced values: shapes still refused
        jax.jit(lambda x: model.with_params(link={name: {"com": x}}).inertia)(jnp.zeros(2))
    massless = model.with_params(inertia=model.inertia.at[k].set(0.0))
    with pytest.raises(ModelError, match="has no mass"):
        massless.with_params(link={name: {"mass": 1.0}})
    whole = massless.with_params(link={name: {"mass": m, "com": c, "inertia": i_com}})
    assert max_rel(whole.inertia[k], model.inertia[k]) <= EXACT_RTOL


def test_parameter_leaves_of_another_shape_are_refused_by_name(small_tree):
    """``with_params`` refuses a leaf whose shape is not this model's (behind leading axes of stacked models, which
    stay allowed), naming the leaf and the shape wanted, also for a term the model lacks and under a trace."""
    from particlesim.errors import ModelError

    model, n = small_tree, small_tree.n_joints
    for leaf, value in (("inertia", np.zeros((n - 1, 10))), ("origin_xyz", np.zeros((n, 2))),
                        ("gravity", np.zeros(2)), ("viscous", np.zeros(n + 1)), ("stiffness", np.zeros(n + 2)),
                        ("limits", np.zeros((n, 3)))):
        with pytest.raises(ModelError, match=rf"{leaf} must have shape"):
            model.with_params(**{leaf: value})
    with pytest.raises(ModelError, match="gravity must have shape"):
        jax.jit(lambda g: model.with_params(gravity=g).gravity)(jnp.zeros(4))
    stacked = model.with_params(inertia=jnp.stack([model.inertia, 1.1 * model.inertia]))
    assert stacked.inertia.shape == (2, n, 10)
