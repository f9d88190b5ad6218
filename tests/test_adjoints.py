"""Gradients of tree-robot rollouts through every adjoint that ``simulate`` offers.

Model: a three-joint spatial arm (non-parallel axes, non-principal inertias, viscous friction) driven by a smooth
torque, 0.3 s, Tsit5 at rtol 1e-10. Outputs: the final state (q, q̇) and a trajectory-sum loss over seven save
times. Inputs: the 3 x 10 inertial parameters, the viscous friction coefficients and the initial state.

Two checks per adjoint:
  * ``check_grads`` against central differences, in the modes the adjoint supports (rev: checkpoint, direct,
    backsolve; fwd: forward, direct);
  * its full Jacobian against the checkpointed one. "direct" and "forward" differentiate the same discrete
    computation as "checkpoint", so they agree to rounding; "backsolve" integrates the continuous adjoint equations
    backwards, so it agrees to the solver tolerance only.

``simulate`` hands the parameters to diffrax through ``args``, so backsolve (which differentiates only the initial
state, ``args`` and the terms) covers them as well as the initial state.
"""

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from particlesim.simulate import simulate
from particlesim.tree import forward_dynamics
from particlesim.io import load_urdf

THREE_LINK_URDF = """<?xml version="1.0"?>
<robot name="three_link">
  <link name="world"/>
  <link name="a">
    <inertial><origin xyz="0.02 -0.22 0.01" rpy="0 0 0"/><mass value="1.3"/>
      <inertia ixx="0.030" ixy="0.002" ixz="-0.001" iyy="0.004" iyz="0.0015" izz="0.029"/></inertial>
  </link>
  <link name="b">
    <inertial><origin xyz="-0.01 -0.2 0.03" rpy="0.1 0 0.2"/><mass value="0.8"/>
      <inertia ixx="0.012" ixy="0.0" ixz="0.0" iyy="0.002" iyz="0.0" izz="0.011"/></inertial>
  </link>
  <link name="c">
    <inertial><origin xyz="0.0 -0.15 -0.02" rpy="0 0.2 0"/><mass value="0.5"/>
      <inertia ixx="0.005" ixy="0.0005" ixz="0.0" iyy="0.001" iyz="0.0" izz="0.0045"/></inertial>
  </link>
  <joint name="j1" type="revolute"><parent link="world"/><child link="a"/>
    <origin xyz="0 0 0" rpy="0 0 0"/><axis xyz="0 0 1"/><limit effort="1" lower="-3" upper="3" velocity="1"/></joint>
  <joint name="j2" type="revolute"><parent link="a"/><child link="b"/>
    <origin xyz="0 -0.45 0" rpy="0 0.3 0"/><axis xyz="1 0 0"/><limit effort="1" lower="-3" upper="3" velocity="1"/></joint>
  <joint name="j3" type="revolute"><parent link="b"/><child link="c"/>
    <origin xyz="0 -0.4 0.02" rpy="0.2 0 0"/><axis xyz="0 0.6 0.8"/><limit effort="1" lower="-3" upper="3" velocity="1"/></joint>
</robot>
"""

GRAVITY = (0.0, -9.81, 0.0)
T1 = 0.3  # s
TS = np.linspace(0.0, T1, 7)
RTOL, ATOL = 1e-10, 1e-12
MAX_STEPS = 4096  # bounds DirectAdjoint's reverse-mode memory; the rollout takes ~40 steps

# check_grads: central differences with step FD_EPS (truncation ~eps^2, rounding ~1e-16/eps relative, solver
# tolerance 1e-10 relative amplified by ~1/eps through the step-size choices at worst); compared with rtol/atol.
FD_EPS = 1e-6
CHECK_RTOL, CHECK_ATOL = 1e-5, 1e-6
# Agreement with the checkpointed Jacobian, relative to its largest entry.
SAME_DISCRETE_RTOL = 1e-11  # direct, forward: the same discrete derivative; differences are rounding only
# DirectAdjoint's reverse pass (diffrax 0.7.2) deviates on this model: 6.8e-7 measured against the checkpointed
# Jacobian, while DirectAdjoint's own forward mode, ForwardMode and the checkpointed reverse pass agree to 1e-14
# and central differences extrapolated in the step side with them (1e-8, the step-size freezing of diffrax's
# controller) and not with it. It is a gradient to the accuracy of check_grads, hence the looser bound.
DIRECT_REV_RTOL = 1e-5
BACKSOLVE_RTOL = 1e-9  # continuous adjoint solved at rtol 1e-10, ten times that (measured 9.9e-11)

Q0 = np.array([0.4, -0.3, 0.2])
QD0 = np.array([0.2, 0.5, -0.4])
VISCOUS = np.array([0.3, 0.2, 0.1])


def torque(t, q, qd, params):
    """Smooth joint torques (N m), the same at every stage evaluation."""
    return jnp.array([1.5, -0.8, 0.4]) * jnp.sin(jnp.array([7.0, 11.0, 5.0]) * t + jnp.array([0.0, 0.5, 1.0]))


@pytest.fixture(scope="module")
def model():
    return load_urdf(THREE_LINK_URDF, gravity=GRAVITY)


def rollout_fn(model, adjoint):
    """``(inertia (3, 10), viscous (3,), q0 (3,), qd0 (3,)) -> (7,)``: final (q, q̇) and a trajectory-sum loss."""

    def f(inertia, viscous, q0, qd0):
        m = model.with_params(inertia=inertia, viscous=viscous)
        sol = simulate(lambda p, q, qd, tau: forward_dynamics(p, q, qd, tau), m, q0, qd0, 0.0, T1, control=torque,
                       solver="tsit5", rtol=RTOL, atol=ATOL, saveat_ts=TS, max_steps=MAX_STEPS, adjoint=adjoint)
        loss = jnp.sum(sol.q**2) + 0.1 * jnp.sum(sol.qd**2)
        return jnp.concatenate([sol.q[-1], sol.qd[-1], loss[None]])

    return jax.jit(f)


def _args(model):
    return (model.inertia, jnp.asarray(VISCOUS), jnp.asarray(Q0), jnp.asarray(QD0))


def _jacobian_rev(f, args):
    """Full Jacobian (rows: outputs) by one vjp per output, blocks per argument concatenated."""
    out, vjp = jax.vjp(f, *args)
    rows = [vjp(e) for e in jnp.eye(out.size)]
    return np.stack([np.concatenate([np.ravel(g) for g in r]) for r in rows])


def _jacobian_fwd(f, args):
    """Full Jacobian by one jvp per input coordinate."""
    cols = []
    for i, a in enumerate(args):
        for k in range(a.size):
            tangents = [jnp.zeros_like(b) for b in args]
            tangents[i] = jnp.zeros(a.size).at[k].set(1.0).reshape(a.shape)
            cols.append(np.asarray(jax.jvp(f, args, tuple(tangents))[1]))
    return np.stack(cols, axis=1)


@pytest.fixture(scope="module")
def fns(model):
    """One jitted rollout per adjoint, shared by the tests (XLA compiles dominate the run time)."""
    cache = {}

    def get(adjoint):
        if adjoint not in cache:
            cache[adjoint] = rollout_fn(model, adjoint)
        return cache[adjoint]

    return get


@pytest.fixture(scope="module")
def reference(model, fns):
    """The checkpointed Jacobian (7 x 39), the reference for the other adjoints."""
    return _jacobian_rev(fns("checkpoint"), _args(model))


def _rel(a, b):
    return float(np.abs(a - b).max() / np.abs(b).max())


@pytest.mark.parametrize("adjoint,modes", [("checkpoint", ("rev",)),
                                           pytest.param("direct", ("fwd", "rev"), marks=pytest.mark.slow),
                                           ("forward", ("fwd",))])
def test_check_grads_through_rollout(model, fns, adjoint, modes):
    f = fns(adjoint)
    out = f(*_args(model))
    assert np.all(np.isfinite(np.asarray(out)))
    check_grads(f, _args(model), order=1, modes=modes, eps=FD_EPS, rtol=CHECK_RTOL, atol=CHECK_ATOL)


@pytest.mark.parametrize("adjoint,mode,bound", [("forward", "fwd", SAME_DISCRETE_RTOL),
                                                ("direct", "fwd", SAME_DISCRETE_RTOL),
                                                ("direct", "rev", DIRECT_REV_RTOL)])
def test_discrete_adjoints_equal_checkpoint(model, fns, reference, adjoint, mode, bound):
    f = fns(adjoint)
    jac = _jacobian_fwd(f, _args(model)) if mode == "fwd" else _jacobian_rev(f, _args(model))
    rel = _rel(jac, reference)
    print(f"\n  {adjoint} ({mode}) vs checkpoint: max |dJ| / max |J| = {rel:.2e}")
    assert rel <= bound


def test_backsolve_check_grads_wrt_all_inputs(model, fns):
    """Parameters reach diffrax through ``args``, so backsolve differentiates them too."""
    check_grads(fns("backsolve"), _args(model), order=1, modes=("rev",), eps=FD_EPS, rtol=CHECK_RTOL,
                atol=CHECK_ATOL)


def test_backsolve_parameter_gradients_agree_with_checkpoint(model, fns, reference):
    rel = _rel(_jacobian_rev(fns("backsolve"), _args(model)), reference)
    print(f"\n  backsolve vs checkpoint (all inputs): max |dJ| / max |J| = {rel:.2e}")
    assert 0.0 < rel <= BACKSOLVE_RTOL


def test_forward_mode_through_a_reverse_mode_adjoint_is_named(model):
    """``jax.jacfwd`` of a rollout left at the default (reverse-mode) adjoint: our error names the entry and the
    adjoint to pass, instead of JAX's bare ``can't apply forward-mode autodiff (jvp) to a custom_vjp function``.
    (Under the caller's own ``jit`` JAX raises its own error later, when it differentiates the compiled program.)"""

    def final_q(q0):
        return simulate(forward_dynamics, model, q0, jnp.asarray(QD0), 0.0, 0.05, rtol=1e-6, atol=1e-8).q[-1]

    with pytest.raises(TypeError, match="simulate: forward-mode differentiation .* needs adjoint='forward'"):
        jax.jacfwd(final_q)(jnp.asarray(Q0))
