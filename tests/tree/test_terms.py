"""Friction (eq. 17), rotor inertia (eq. 18), end-link wrenches (eq. 16), zero-cost absent terms, batching."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from particlesim.tree import (
    forward_dynamics,
    friction_torques,
    link_jacobian,
    link_poses,
    mass_matrix,
    wrench_torques,
)
from particlesim.io import load_urdf
from tree_helpers import max_rel, random_tree_urdf, states

EXACT_RTOL = 1e-12


def test_friction_sign_and_smooth_forms(small_tree):
    qd = jnp.array([-2.0, 0.0, 3.0, 1e-9, -0.01])
    fv, fc = np.asarray(small_tree.viscous), np.asarray(small_tree.coulomb)
    exact = friction_torques(small_tree, qd)
    np.testing.assert_array_equal(exact, fv * qd + fc * np.sign(qd))
    assert exact[1] == 0.0  # sign(0) = 0: no Coulomb torque at rest
    eps = 0.05
    smooth = friction_torques(small_tree, qd, smooth_friction=eps)
    np.testing.assert_allclose(smooth, fv * qd + fc * np.tanh(np.asarray(qd) / eps), rtol=1e-15, atol=0)
    # smooth form tends to the exact one away from zero and is differentiable at zero (slope Fv + Fc / eps)
    far = jnp.array([-2.0, 1.0, 3.0, -1.0, 0.5])
    assert max_rel(friction_torques(small_tree, far, smooth_friction=1e-4), friction_torques(small_tree, far)) < 1e-12
    slope = jax.jacfwd(lambda v: friction_torques(small_tree, v, smooth_friction=eps))(jnp.zeros(5))
    np.testing.assert_allclose(np.diag(slope), fv + fc / eps, rtol=1e-14)


def test_rotor_inertia_adds_to_diagonal(small_tree):
    q = jnp.linspace(-1.0, 1.0, small_tree.nq)
    bare = small_tree.with_params(rotor_inertia=jnp.zeros(small_tree.nq))
    diff = mass_matrix(small_tree, q) - mass_matrix(bare, q)
    np.testing.assert_allclose(diff, np.diag(small_tree.rotor_inertia), rtol=0, atol=1e-15)
    # I_a = N^2 J_m: a 100:1 gearbox on a 1e-5 kg m^2 rotor adds 0.1 kg m^2
    geared = bare.with_params(rotor_inertia=jnp.full(small_tree.nq, 100.0**2 * 1e-5))
    np.testing.assert_allclose(np.diag(mass_matrix(geared, q) - mass_matrix(bare, q)), 0.1, rtol=1e-12)


def test_absent_terms_cost_nothing():
    model = load_urdf(random_tree_urdf(3, n=3))
    assert model.viscous is None and model.coulomb is None and model.rotor_inertia is None
    q = jnp.zeros(3)
    text = str(jax.make_jaxpr(lambda v: forward_dynamics(model, q, v, q, smooth_friction=0.1))(q))
    assert "tanh" not in text and "sign" not in text
    with_friction = load_urdf(random_tree_urdf(3, n=3), coulomb=[0.1, 0.2, 0.3])
    text = str(jax.make_jaxpr(lambda v: forward_dynamics(with_friction, q, v, q, smooth_friction=0.1))(q))
    assert "tanh" in text


def test_wrench_torques_are_jacobian_transpose(fixed_wheel):
    """Eq. (16): a wrench at the left gripper moves no right-arm joint; local and world axes agree."""
    rng = np.random.default_rng(0)
    q = jnp.asarray(rng.uniform(-1, 1, fixed_wheel.nq))
    f = jnp.asarray(rng.normal(size=6))
    tau = wrench_torques(fixed_wheel, q, "lGripper", f)
    # relative to the largest torque: an entry that is a small difference of large terms carries their round-off
    assert max_rel(tau, link_jacobian(fixed_wheel, q, "lGripper").T @ f) <= 1e-14
    right = [i for i, n in enumerate(fixed_wheel.joint_names) if n.startswith("RJ")]
    assert np.all(np.asarray(tau)[right] == 0.0)
    r = link_poses(fixed_wheel, q)[0][fixed_wheel.link_index("lGripper")]
    f_local = jnp.concatenate([r.T @ f[:3], r.T @ f[3:]])
    assert max_rel(wrench_torques(fixed_wheel, q, "lGripper", f_local, frame="local"), tau) <= EXACT_RTOL


def test_vmap_over_stacked_parameter_sets(small_tree):
    scales = [1.0, 1.5, 0.7]
    models = [small_tree.with_params(inertia=small_tree.inertia * s, origin_xyz=small_tree.origin_xyz * s)
              for s in scales]
    batch = jax.tree.map(lambda *x: jnp.stack(x), *models)
    q, qd, tau = jnp.full(5, 0.3), jnp.full(5, -0.2), jnp.linspace(-1, 1, 5)
    out = jax.vmap(forward_dynamics, in_axes=(0, None, None, None))(batch, q, qd, tau)
    for k, m in enumerate(models):
        assert max_rel(out[k], forward_dynamics(m, q, qd, tau)) <= EXACT_RTOL


def test_new_parameter_values_do_not_retrace(small_tree):
    traces = []

    @jax.jit
    def loss(model, q):
        traces.append(1)
        return jnp.sum(forward_dynamics(model, q, q, q, smooth_friction=0.1) ** 2)

    grad = jax.jit(jax.grad(loss))
    q = jnp.full(5, 0.1)
    counts = []
    for s in (1.0, 2.0, 3.0):
        model = small_tree.with_params(inertia=small_tree.inertia * s, gravity=small_tree.gravity * s)
        loss(model, q)
        g = grad(model, q)
        counts.append(len(traces))
    assert counts[0] >= 1 and counts[1] == counts[0] and counts[2] == counts[0]  # traced on first use only
    assert g.inertia.shape == (5, 10) and g.origin_xyz.shape == (5, 3)
    # one gradient entry against a central difference
    e = jnp.zeros((5, 10)).at[2, 0].set(1e-6)
    fd = (loss(model.with_params(inertia=model.inertia + e), q)
          - loss(model.with_params(inertia=model.inertia - e), q)) / 2e-6
    assert abs(float(g.inertia[2, 0]) - float(fd)) <= 1e-6 * max(1.0, abs(float(fd)))


@pytest.mark.parametrize("arg", ["q", "qd", "tau"])
def test_forward_dynamics_gradients(tiny_tree, arg):
    from jax.test_util import check_grads

    rng = np.random.default_rng(4)
    state = {k: jnp.asarray(rng.normal(size=3)) for k in ("q", "qd", "tau")}

    def f(x):
        s = dict(state, **{arg: x})
        return forward_dynamics(tiny_tree, s["q"], s["qd"], s["tau"], smooth_friction=0.5)

    check_grads(f, (state[arg],), order=1, modes=("fwd", "rev"))


def test_forward_dynamics_gradients_wrt_parameters(tiny_tree):
    from jax.test_util import check_grads

    q, qd, tau = jnp.array([0.3, -0.5, 0.8]), jnp.array([0.2, 0.4, -0.3]), jnp.array([1.0, -0.5, 0.2])

    def f(inertia, xyz, rotor):
        m = tiny_tree.with_params(inertia=inertia, origin_xyz=xyz, rotor_inertia=rotor)
        return forward_dynamics(m, q, qd, tau, smooth_friction=0.5)

    check_grads(f, (tiny_tree.inertia, tiny_tree.origin_xyz, tiny_tree.rotor_inertia), order=1,
                modes=("fwd", "rev"))


#: Forward dynamics' derivatives through the applied-matrix solve against those of the formed mass matrix's solve.
APPLIED_SOLVE_RTOL = 1e-10


def _applied_solve_models():
    from test_floating_base import floating_tree
    from test_mimic import with_mimics

    yield "3 links, prismatic, rotor inertia", load_urdf(
        random_tree_urdf(11, n=3, prismatic=0.5), gravity=(0.0, -9.81, 0.0), rotor_inertia=[0.01, 0.02, 0.03])
    yield "mimic joint", load_urdf(with_mimics(random_tree_urdf(0, n=5, prismatic=0.3), {"j3": ("j1", -0.7, 0.25)}),
                                   gravity=(0.0, 0.0, -9.81), limits="ignore")
    yield "floating base", load_urdf(floating_tree(3, 3), floating_base=True, limits="ignore",
                                     gravity=(0.2, -9.81, 0.4))


@pytest.mark.parametrize("case", range(3))
def test_forward_dynamics_derivatives_match_the_formed_mass_matrix_solve(case):
    """One-state forward dynamics take ``dA lam`` from inverse dynamics at zero velocity (``A`` applied, not
    formed); their Jacobians in the state and the link inertias, forward and reverse, against JAX's derivatives of
    ``jnp.linalg.solve`` with the formed ``A``, on a tree with rotor inertias, one with a mimic joint and a floating
    base (quaternion coordinates); and ``A x`` applied against ``A`` formed."""
    from particlesim.tree import dynamics as dyn

    name, model = list(_applied_solve_models())[case]
    assert not dyn.one_state_sweeps(model), name  # the composite-inertia path is the one tested
    q, qd, tau, _ = (jnp.asarray(v[0]) for v in states(np.random.default_rng(case), 1, model.nq, model.nv,
                                                         quaternions=(3,) if name == "floating base" else ()))
    b = dyn._bodies(model, q)
    x = jnp.asarray(np.random.default_rng(10 + case).normal(size=model.nv))
    formed = dyn._mass_matrix(model, b) @ x
    np.testing.assert_allclose(dyn._mass_apply((model, b), x), formed, rtol=0,
                               atol=1e-12 * float(jnp.abs(formed).max()))

    def dense(m, q, qd):
        rhs = dyn._generalised_forces(m, q, qd, tau, None)
        bb = dyn._bodies(m, q)
        return jnp.linalg.solve(dyn._mass_matrix(m, bb), rhs - dyn._rnea(m, bb, qd, None, m.gravity))

    def ours(m, q, qd):
        return dyn._forward_dynamics(m, q, qd, tau, None)

    def by_inertia(f):
        return lambda inertia, q, qd: f(model.with_params(inertia=inertia), q, qd)

    args = (model.inertia, q, qd)
    for jac in (jax.jacfwd, jax.jacrev):
        for got, ref in zip(jac(by_inertia(ours), argnums=(0, 1, 2))(*args),
                            jac(by_inertia(dense), argnums=(0, 1, 2))(*args)):
            np.testing.assert_allclose(got, ref, rtol=0, atol=APPLIED_SOLVE_RTOL * float(jnp.abs(ref).max()))
