"""Gradients of projected mechanism rollouts through the adjoints ``simulate_mechanism`` offers, its refusal of
backsolve with the projection, and the run-time guard on non-finite mechanism parameters.

Model: a double pendulum of two uniform rods in particle coordinates (spherical joints, 4 degrees of freedom) with
a spring-damper from the ground to the tip, started swinging out of plane; 0.3 s, Tsit5 at rtol 1e-10. Inputs:
both rod masses, the spring stiffness and damping. Outputs: the final particle positions and a trajectory-sum
loss over seven save times.
"""

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from particlesim import RigidInertia
from particlesim.mechanism import MechanismBuilder, project, simulate_mechanism

T1 = 0.3  # s
TS = np.linspace(0.0, T1, 7)
RTOL, ATOL = 1e-10, 1e-12
MAX_STEPS = 4096
THETA = np.array([1.0, 0.7, 20.0, 0.5])  # kg, kg, N/m, N s/m

FD_EPS = 1e-6  # central differences in check_grads
CHECK_RTOL, CHECK_ATOL = 1e-5, 1e-6
SAME_DISCRETE_RTOL = 1e-11  # direct and forward against checkpoint: the same discrete derivative
# DirectAdjoint's reverse pass (diffrax 0.7.2) departs from the discrete derivative that the checkpointed pass, the
# forward pass and DirectAdjoint's own forward mode agree on (to 1e-15): 4.2e-8 here, 6.8e-7 on the tree arm of
# tests/test_adjoints.py (the same bound there). Here it appears with the spring in the Schur-complement vector field
# (without the spring: 2e-15; the former dense-LU field happened to agree). Cause not found. Its forward mode is exact
# and is checked at SAME_DISCRETE_RTOL.
DIRECT_REV_RTOL = 1e-5
BACKSOLVE_RTOL = 1e-9  # continuous adjoint at rtol 1e-10 against the discrete one, unprojected (measured 3.0e-11)


@pytest.fixture(scope="module")
def pendulum():
    mb = MechanismBuilder(gravity=(0, 0, -9.81))
    mb.ground("O", (0, 0, 0))
    mb.particle("A", (0.5, 0, 0))
    mb.particle("B", (1.0, 0, 0))
    mb.body("link1", RigidInertia.slender_rod(THETA[0], (0, 0, 0), (0.5, 0, 0)), ["O", "A"])
    mb.body("link2", RigidInertia.slender_rod(THETA[1], (0.5, 0, 0), (1.0, 0, 0)), ["A", "B"])
    mb.spring_damper("tip spring", "O", "B", THETA[2], THETA[3], 0.8)
    mech, x0 = mb.build(dof=4)
    x0 = jnp.asarray(x0)
    _, xd0 = project(mech, x0, jnp.zeros_like(x0).at[2].set(0.3).at[4].set(0.8).at[7].set(-0.5))
    return mech, x0, xd0


def with_theta(mech, th):
    return mech.with_params(body={"link1": {"mass": th[0]}, "link2": {"mass": th[1]}},
                            spring={"tip spring": {"stiffness": th[2], "damping": th[3]}})


_ROLLOUTS = {}  # one jitted rollout per (pendulum, adjoint, stabilise, loss_only): each program compiles once


def rollout_fn(pendulum, adjoint, stabilise=True, loss_only=False):
    key = (id(pendulum), adjoint, stabilise, loss_only)
    if key not in _ROLLOUTS:
        _ROLLOUTS[key] = (pendulum, _rollout_fn(pendulum, adjoint, stabilise, loss_only))  # holds pendulum: id stays
    return _ROLLOUTS[key][1]


def _rollout_fn(pendulum, adjoint, stabilise, loss_only):
    mech, x0, xd0 = pendulum

    def f(th):
        sol = simulate_mechanism(with_theta(mech, th), x0, xd0, 0.0, T1, solver="tsit5", rtol=RTOL, atol=ATOL,
                                 saveat_ts=TS, max_steps=MAX_STEPS, adjoint=adjoint, stabilise=stabilise)
        loss = jnp.sum(sol.q**2) + 0.1 * jnp.sum(sol.qd**2)
        return loss if loss_only else jnp.concatenate([sol.q[-1], loss[None]])

    return jax.jit(f)


def _jacobian(f, th, mode):
    if mode == "fwd":
        return np.stack([np.asarray(jax.jvp(f, (th,), (e,))[1]) for e in jnp.eye(th.size)], axis=1)
    out, vjp = jax.vjp(f, th)
    return np.stack([np.asarray(vjp(e)[0]) for e in jnp.eye(out.size)])


def _rel(a, b):
    return float(np.abs(a - b).max() / np.abs(b).max())


@pytest.fixture(scope="module")
def reference(pendulum):
    f = rollout_fn(pendulum, "checkpoint")
    check_grads(f, (jnp.asarray(THETA),), order=1, modes=("rev",), eps=FD_EPS, rtol=CHECK_RTOL, atol=CHECK_ATOL)
    return _jacobian(f, jnp.asarray(THETA), "rev")


def test_checkpoint_check_grads(reference):
    assert np.all(np.isfinite(reference)) and np.abs(reference).max() > 0.0


@pytest.mark.parametrize("adjoint,mode,bound", [("forward", "fwd", SAME_DISCRETE_RTOL),
                                                ("direct", "fwd", SAME_DISCRETE_RTOL),
                                                ("direct", "rev", DIRECT_REV_RTOL)])
def test_other_discrete_adjoints(pendulum, reference, adjoint, mode, bound):
    f = rollout_fn(pendulum, adjoint)
    th = jnp.asarray(THETA)
    check_grads(f, (th,), order=1, modes=(mode,), eps=FD_EPS, rtol=CHECK_RTOL, atol=CHECK_ATOL)
    rel = _rel(_jacobian(f, th, mode), reference)
    print(f"\n  {adjoint} ({mode}) vs checkpoint: max |dJ| / max |J| = {rel:.2e}")
    assert rel <= bound


def test_backsolve_is_refused_with_the_projection(pendulum):
    mech, x0, xd0 = pendulum
    for adjoint in ("backsolve", diffrax.BacksolveAdjoint()):
        with pytest.raises(ValueError, match="backsolve.*cannot see the coordinate projection"):
            simulate_mechanism(mech, x0, xd0, 0.0, T1, adjoint=adjoint)


@pytest.mark.slow  # ~45 s of compiles
def test_backsolve_without_projection_matches_checkpoint(pendulum):
    th = jnp.asarray(THETA)
    bs = rollout_fn(pendulum, "backsolve", stabilise=False, loss_only=True)
    check_grads(bs, (th,), order=1, modes=("rev",), eps=FD_EPS, rtol=CHECK_RTOL, atol=CHECK_ATOL)
    g_bs = np.asarray(jax.grad(bs)(th))
    g_cp = np.asarray(jax.grad(rollout_fn(pendulum, "checkpoint", stabilise=False, loss_only=True))(th))
    rel = _rel(g_bs, g_cp)
    print(f"\n  backsolve vs checkpoint (stabilise=False): max |dg| / max |g| = {rel:.2e}")
    assert 0.0 < rel <= BACKSOLVE_RTOL


def test_unknown_adjoint_is_refused(pendulum):
    mech, x0, xd0 = pendulum
    with pytest.raises(ValueError, match="unknown adjoint 'magic'"):
        simulate_mechanism(mech, x0, xd0, 0.0, T1, adjoint="magic")


def test_non_finite_parameters_are_refused(pendulum):
    import equinox as eqx

    mech, x0, xd0 = pendulum
    # with_params refuses concrete non-finite values itself (test_mechanism_errors.py); set in place, the
    # simulation refuses them before it runs
    with pytest.raises(ValueError, match="spring 'tip spring' stiffness must be finite"):
        mech.with_params(spring={"tip spring": {"stiffness": jnp.nan}})
    bad = eqx.tree_at(lambda m: m.spring_stiffness, mech, jnp.full_like(mech.spring_stiffness, jnp.nan))
    with pytest.raises(ValueError, match="simulate_mechanism: parameter spring 'tip spring' stiffness is not finite"):
        simulate_mechanism(bad, x0, xd0, 0.0, T1)
    bad = eqx.tree_at(lambda m: m.body_mass, mech, mech.body_mass.at[mech.body_index("link2")].set(jnp.inf))
    with pytest.raises(ValueError, match="parameter body 'link2' mass is not finite"):
        simulate_mechanism(bad, x0, xd0, 0.0, T1)
    # Under jit the values are unknown while tracing: the check runs with the rollout.
    run = jax.jit(lambda k: simulate_mechanism(mech.with_params(spring={"tip spring": {"stiffness": k}}), x0, xd0,
                                               0.0, 0.05).q[-1])
    assert np.all(np.isfinite(np.asarray(run(jnp.asarray(THETA[2])))))
    with pytest.raises(Exception, match="simulate_mechanism: parameter spring 'tip spring' stiffness is not finite"):
        jax.block_until_ready(run(jnp.asarray(jnp.nan)))
