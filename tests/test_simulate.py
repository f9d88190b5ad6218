"""particlesim.simulate: exact solutions, bad input, batching, gradients, stiffness, energy conservation.

Small models keep compile time down: a linear oscillator (exact solution), and a 2-link spatial pendulum read
from a URDF written here (non-principal inertias, non-parallel axes).
"""

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from particlesim.errors import ModelError
from particlesim.simulate import IMPLICIT_SOLVERS, SOLVERS, simulate

TWO_LINK_URDF = """<?xml version="1.0"?>
<robot name="two_link">
  <link name="world"/>
  <link name="a">
    <inertial><origin xyz="0.02 -0.25 0.01" rpy="0 0 0"/><mass value="1.3"/>
      <inertia ixx="0.030" ixy="0.002" ixz="-0.001" iyy="0.004" iyz="0.0015" izz="0.029"/></inertial>
  </link>
  <link name="b">
    <inertial><origin xyz="-0.01 -0.2 0.03" rpy="0.1 0 0.2"/><mass value="0.8"/>
      <inertia ixx="0.012" ixy="0.0" ixz="0.0" iyy="0.002" iyz="0.0" izz="0.011"/></inertial>
  </link>
  <joint name="j1" type="revolute"><parent link="world"/><child link="a"/>
    <origin xyz="0 0 0" rpy="0 0 0"/><axis xyz="0 0 1"/><limit effort="1" lower="-3" upper="3" velocity="1"/></joint>
  <joint name="j2" type="revolute"><parent link="a"/><child link="b"/>
    <origin xyz="0 -0.5 0" rpy="0 0.3 0"/><axis xyz="1 0 0"/><limit effort="1" lower="-3" upper="3" velocity="1"/></joint>
</robot>
"""

GRAVITY = (0.0, -9.81, 0.0)


@pytest.fixture(scope="session")
def two_link_path(tmp_path_factory):
    p = tmp_path_factory.mktemp("urdf") / "two_link.urdf"
    p.write_text(TWO_LINK_URDF)
    return p


@pytest.fixture(scope="session")
def two_link(two_link_path):
    from particlesim.io import load_urdf

    return load_urdf(two_link_path, gravity=GRAVITY)


def tree_dynamics(model, q, qd, tau):
    from particlesim.tree import forward_dynamics

    return forward_dynamics(model, q, qd, tau)


def oscillator(params, q, qd, tau):
    """q̈ = -ω² q + τ: exact solution q = a cos ωt + (v/ω) sin ωt."""
    return -params["w"] ** 2 * q + tau


OSC = {"w": jnp.array(2.0)}
Q0, QD0 = jnp.array([1.0, -0.5]), jnp.array([0.0, 0.3])


def oscillator_exact(t, w=2.0):
    c, s = np.cos(w * t), np.sin(w * t)
    return np.asarray(Q0) * c + np.asarray(QD0) / w * s


@pytest.mark.parametrize("solver", sorted(SOLVERS))
def test_every_solver_matches_exact_solution(solver):
    # Global error of a tolerance-controlled solve stays within a small multiple of the requested tolerance
    # (here 1e-8 relative); 1e-6 leaves room for error accumulation over ~3 periods without hiding a wrong solver.
    ts = jnp.linspace(0.0, 10.0, 11)
    sol = simulate(oscillator, OSC, Q0, QD0, 0.0, 10.0, solver=solver, rtol=1e-8, atol=1e-10, saveat_ts=ts)
    assert bool(sol.ok)
    exact = np.stack([oscillator_exact(t) for t in np.asarray(ts)])
    np.testing.assert_allclose(sol.q, exact, atol=1e-6)
    assert sol.q.shape == (11, 2) and sol.qd.shape == (11, 2) and sol.ts.shape == (11,)
    assert int(sol.steps) > 0


def test_control_is_evaluated_inside_the_stages():
    # τ = ω² q cancels the spring exactly: q = q0 + qd0 t. A per-step held force would not be exact.
    sol = simulate(oscillator, OSC, Q0, QD0, 0.0, 2.0, control=lambda t, q, qd, p: p["w"] ** 2 * q, solver="dopri5")
    np.testing.assert_allclose(sol.q[-1], Q0 + 2.0 * QD0, atol=1e-12)


def test_bad_input_is_refused_with_named_errors(two_link):
    with pytest.raises(ValueError, match="unknown solver 'rk45'"):
        simulate(oscillator, OSC, Q0, QD0, 0.0, 1.0, solver="rk45")
    with pytest.raises(ValueError, match="unknown adjoint"):
        simulate(oscillator, OSC, Q0, QD0, 0.0, 1.0, adjoint="magic")
    with pytest.raises(ModelError, match="same length"):
        simulate(oscillator, OSC, Q0, jnp.zeros(3), 0.0, 1.0)
    with pytest.raises(ModelError, match="nq = 2"):
        simulate(tree_dynamics, two_link, jnp.zeros(3), jnp.zeros(3), 0.0, 1.0)
    with pytest.raises(ModelError, match="dynamics returned shape"):
        simulate(lambda p, q, qd, tau: q[:1], OSC, Q0, QD0, 0.0, 1.0)
    with pytest.raises(ValueError, match=r"q0 is not finite at coordinates \[1\]"):
        simulate(oscillator, OSC, jnp.array([0.0, jnp.nan]), QD0, 0.0, 1.0)
    with pytest.raises(ValueError, match="qd0 is not finite"):
        simulate(oscillator, OSC, Q0, jnp.array([jnp.inf, 0.0]), 0.0, 1.0)


def test_a_second_call_of_the_same_structure_traces_nothing():
    """The output-shape check traces ``dynamics`` and ``control`` once per structure (their functions, the
    parameters' tree and leaf shapes, the state's shapes): a second call with new values traces neither (nor does
    it recompile); a structure that fails is refused on every call."""
    traces = {"dynamics": 0, "control": 0}

    def dyn(p, q, qd, tau):
        traces["dynamics"] += 1
        return oscillator(p, q, qd, tau)

    def ctl(t, q, qd, p):
        traces["control"] += 1
        return 0.1 * q

    simulate(dyn, OSC, Q0, QD0, 0.0, 0.5, control=ctl)
    first = dict(traces)
    assert first["dynamics"] >= 1 and first["control"] >= 1
    sol = simulate(dyn, {"w": jnp.array(3.0)}, Q0 + 0.1, QD0, 0.0, 0.7, control=ctl, rtol=1e-9)
    assert traces == first
    assert np.all(np.isfinite(np.asarray(sol.q)))
    bad = lambda p, q, qd, tau: q[:1]  # noqa: E731
    for _ in range(2):
        with pytest.raises(ModelError, match="dynamics returned shape"):
            simulate(bad, OSC, Q0, QD0, 0.0, 1.0)
    from particlesim import simulate as simulate_module

    kept = len(simulate_module._SHAPES_PASSED)  # under a caller's trace nothing is remembered (no tracers kept)
    jax.jit(lambda w: simulate(lambda p, q, qd, tau: -p["w"] ** 2 * q, {"w": w}, Q0, QD0, 0.0, 0.1).q)(2.0)
    assert len(simulate_module._SHAPES_PASSED) == kept


def test_nan_initial_state_under_jit_raises_at_run_time():
    f = jax.jit(lambda q0: simulate(oscillator, OSC, q0, QD0, 0.0, 1.0).q)
    with pytest.raises(Exception, match="initial state .* is not finite"):
        jax.block_until_ready(f(jnp.array([jnp.nan, 0.0])))


def test_non_finite_parameters_are_refused(two_link):
    """Parameters set with ``with_params`` (unchecked) reach simulate: NaN/inf is an error naming the leaf (a tree's
    per-link leaves by link), eagerly and under jit, never a NaN trajectory."""
    bad = two_link.with_params(inertia=two_link.inertia.at[1, 0].set(jnp.nan))
    with pytest.raises(ModelError, match=r"parameter inertia of link 'b' is not finite .* at entry \(0,\)"):
        simulate(tree_dynamics, bad, jnp.zeros(2), jnp.zeros(2), 0.0, 0.1)
    with pytest.raises(ModelError, match=r"parameter \['w'\] is not finite"):
        simulate(oscillator, {"w": jnp.array(jnp.inf)}, Q0, QD0, 0.0, 1.0)
    f = jax.jit(lambda w: simulate(oscillator, {"w": w}, Q0, QD0, 0.0, 1.0).q)
    assert np.all(np.isfinite(np.asarray(f(jnp.array(2.0)))))
    with pytest.raises(Exception, match=r"parameter \['w'\] is not finite"):
        jax.block_until_ready(f(jnp.array(jnp.nan)))


def test_step_budget_exhausted_raises_or_reports():
    with pytest.raises(Exception, match="maximum number of solver steps"):
        simulate(oscillator, OSC, Q0, QD0, 0.0, 100.0, max_steps=8)
    sol = simulate(oscillator, OSC, Q0, QD0, 0.0, 100.0, max_steps=8, throw=False)
    assert not bool(sol.ok)
    assert sol.status == diffrax.RESULTS.max_steps_reached
    assert np.all(np.isnan(sol.q)) and np.all(np.isnan(sol.qd))


def _rollout(model, q0, qd0, t1=0.4, **kw):
    return simulate(tree_dynamics, model, q0, qd0, 0.0, t1, solver="tsit5", rtol=1e-10, atol=1e-12, **kw)


def test_vmap_over_parameter_sets_and_states_equals_loop(two_link):
    rng = np.random.default_rng(1)
    models = [two_link.with_params(origin_xyz=two_link.origin_xyz * s) for s in (0.8, 1.0, 1.3)]
    q0s = jnp.asarray(rng.uniform(-1, 1, (3, 2)))
    qd0s = jnp.asarray(rng.uniform(-1, 1, (3, 2)))
    stacked = jax.tree.map(lambda *x: jnp.stack(x), *models)
    f = jax.jit(jax.vmap(lambda m, q0, qd0: _rollout(m, q0, qd0).q[-1]))
    batched = f(stacked, q0s, qd0s)
    looped = np.stack([np.asarray(_rollout(m, q0, qd0).q[-1]) for m, q0, qd0 in zip(models, q0s, qd0s)])
    # Same arithmetic in a different batch layout: equal to rounding, not merely to the solver tolerance.
    np.testing.assert_allclose(batched, looped, rtol=1e-12, atol=1e-13)


@pytest.mark.parametrize("mode,adjoint", [("rev", None), ("fwd", "forward")])
def test_rollout_gradients_wrt_params_and_initial_state(two_link, mode, adjoint):
    # Derivatives of the discrete adaptive solution against central differences. The accept/reject pattern of
    # the controller is locally constant, so at tight tolerances the rollout is smooth in its inputs.
    q0, qd0 = jnp.array([0.4, -0.3]), jnp.array([0.2, 0.5])

    def f(inertia, xyz, q0, qd0):
        sol = _rollout(two_link.with_params(inertia=inertia, origin_xyz=xyz), q0, qd0, t1=0.2, adjoint=adjoint)
        return jnp.concatenate([sol.q[-1], sol.qd[-1]])

    check_grads(f, (two_link.inertia, two_link.origin_xyz, q0, qd0), order=1, modes=(mode,), eps=1e-6, atol=1e-6,
                rtol=1e-5)


def test_implicit_solver_is_stable_on_stiff_friction_with_far_fewer_steps(two_link):
    # Viscous friction c = 2000 N m s/rad; the mass matrix's smallest eigenvalue is ≈ 0.042 kg m², so the fast mode
    # decays at λ ≈ -c/0.042 ≈ -5e4 1/s: Tsit5 is bound by stability (|hλ| ≲ 3.5, h ≲ 7e-5 s, ~1e4 steps in 1 s)
    # while Kvaerno5 (L-stable) is bound only by the accuracy of the slow, overdamped motion.
    stiff = two_link.with_params(viscous=jnp.full(2, 2000.0))
    q0, qd0 = jnp.array([0.5, -0.4]), jnp.array([1.0, 2.0])
    runs = {
        s: simulate(tree_dynamics, stiff, q0, qd0, 0.0, 1.0, solver=s, rtol=1e-6, atol=1e-8, max_steps=200_000)
        for s in ("tsit5", "kvaerno5")
    }
    assert all(bool(r.ok) for r in runs.values())
    assert np.all(np.isfinite(runs["kvaerno5"].q))
    # Both solve the same problem: endpoints agree to the tolerance scale.
    np.testing.assert_allclose(runs["kvaerno5"].q[-1], runs["tsit5"].q[-1], atol=1e-4)
    assert int(runs["kvaerno5"].steps) * 20 < int(runs["tsit5"].steps), {
        s: (int(r.steps), int(r.rejected)) for s, r in runs.items()
    }


def damped(params, q, qd, tau):
    """q̈ = -k q - c q̇: overdamped and stiff for c = 1000, k = 1e4 (rates ≈ -10.1 and -989.9 1/s)."""
    return -params["k"] * q - params["c"] * qd


def damped_exact(t, k, c):
    """The closed form of :func:`damped` from q = 1, q̇ = 0 (differentiable in k and c: the derivative's
    reference)."""
    disc = jnp.sqrt(c**2 - 4.0 * k)
    r1, r2 = (-c + disc) / 2.0, (-c - disc) / 2.0
    return (r2 * jnp.exp(r1 * t) - r1 * jnp.exp(r2 * t)) / (r2 - r1)


#: The stiff oscillator through the implicit solver at rtol 1e-8: position over 1 s against the closed form
#: (measured 1.1e-8), and d q(T)/d(k, c) in both modes against the closed form's derivative, relative (measured
#: 2.6e-10 in reverse mode).
STIFF_TOL = 5e-8
STIFF_GRAD_RTOL = 1e-6


@pytest.mark.parametrize("adjoint", ["checkpoint", "forward"])
def test_implicit_solver_meets_a_stiff_closed_form_with_its_derivatives(adjoint):
    p = {"k": jnp.asarray(1.0e4), "c": jnp.asarray(1.0e3)}
    ts = jnp.linspace(0.0, 1.0, 11)

    def run(params):
        return simulate(damped, params, jnp.ones(1), jnp.zeros(1), 0.0, 1.0, solver="kvaerno5", rtol=1e-8,
                        atol=1e-11, saveat_ts=ts, adjoint=adjoint)

    sol = run(p)
    exact = np.asarray(damped_exact(ts, p["k"], p["c"]))
    assert np.max(np.abs(np.asarray(sol.q[:, 0]) - exact)) < STIFF_TOL

    def end(k, c):
        return run({"k": k, "c": c}).q[-1, 0]

    ref = jax.grad(lambda k, c: damped_exact(1.0, k, c), argnums=(0, 1))(p["k"], p["c"])
    if adjoint == "checkpoint":
        got = jax.grad(end, argnums=(0, 1))(p["k"], p["c"])
    else:
        got = (jax.jvp(lambda k: end(k, p["c"]), (p["k"],), (jnp.ones(()),))[1],
               jax.jvp(lambda c: end(p["k"], c), (p["c"],), (jnp.ones(()),))[1])
    for g, r in zip(got, ref):
        assert abs(float(g) - float(r)) <= STIFF_GRAD_RTOL * abs(float(r)), (got, ref)
