"""Gradients across Coulomb friction switches on a tree: a one-joint pendulum with Coulomb (sign law) and viscous
friction released from rest, whose velocity passes through zero three times in 3 s. With ``events=True`` every
reversal is located:

* event times against the pendulum's one-coordinate equation integrated by SciPy's DOP853 with its own event
  location (rtol 1e-13);
* derivatives of the final state and of a trajectory loss with respect to the Coulomb and viscous levels and the
  link's mass parameters that enter a pinned link (first moment, moment of inertia), by reverse and forward mode,
  against central
  differences (Richardson-extrapolated, their convergence shown);
* without events, a differentiated rollout that crosses a reversal warns, naming the joint.
"""

import warnings

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from particlesim._ode import SwitchCrossedWarning
from particlesim.simulate import simulate
from particlesim.tree import TreeModel, forward_dynamics

#: Event times against SciPy's event location [s].
EVENT_TOL = 1e-9
#: Automatic derivatives against converged central differences, relative.
GRAD_RTOL = 1e-6
#: A vmapped member against the same run alone [rad, s]: the batched event root-find runs as a select over
#: members, which moves round-off (measured 1.7e-11 rad after 3 s at rtol 1e-12).
BATCH_TOL = 1e-9
#: The two Richardson extrapolations must agree to this, relative.
FD_AGREE = 1e-6
M, L, IC, FC, FV, G, T_END = 1.0, 0.5, 0.01, 0.4, 0.05, 9.81, 3.0
TS = np.linspace(0.0, T_END, 31)
P0 = np.array([FC, FV, M * L, IC + M * L**2])
NAMES = ["Coulomb", "viscous", "first moment", "moment of inertia"]  # the mass itself does not enter (fixed pin)


def _model(p):
    inertia = jnp.stack([M, p[2], 0.0, 0.0, IC, 0.0, 0.0, p[3], 0.0, p[3]])[None]
    base = TreeModel(parents=[-1], kinds=["revolute"], axes=np.array([[0.0, 0.0, 1.0]]),
                     origin_rotations=np.eye(3)[None], origin_xyz=np.zeros((1, 3)),
                     inertia=np.array([[M, M * L, 0, 0, IC, 0, 0, IC + M * L**2, 0, IC + M * L**2]]),
                     gravity=(0.0, -G, 0.0), joint_names=["pin"], viscous=[FV], coulomb=[FC])
    return eqx.tree_at(lambda m: (m.coulomb, m.viscous, m.inertia), base, (p[0:1], p[1:2], inertia))


def _outputs(p, adjoint=None, events=True):
    sol = simulate(forward_dynamics, _model(p), jnp.zeros(1), jnp.zeros(1), 0.0, T_END, solver="dopri8",
                   rtol=1e-12, atol=1e-14, saveat_ts=TS, events=events, adjoint=adjoint)
    return jnp.stack([sol.q[-1, 0], sol.qd[-1, 0], jnp.mean(sol.q[:, 0] ** 2)])


def _reference_events():
    inertia = IC + M * L**2

    def rhs(t, y, s):
        return [y[1], (-M * G * L * np.cos(y[0]) - FV * y[1] - FC * s) / inertia]

    t, y, s, out = 0.0, np.array([0.0, 0.0]), -1.0, []  # from rest it falls (negative): friction sign -1
    while t < T_END:
        def rev(t, y, s):
            return y[1]
        rev.terminal, rev.direction = True, (-1 if s > 0 else 1)
        sol = solve_ivp(rhs, (t, T_END), y, args=(s,), events=rev, rtol=1e-13, atol=1e-15, method="DOP853")
        if not sol.t_events[0].size:
            break
        t, y, s = sol.t_events[0][0], sol.y_events[0][0], -s
        out.append((t, s > 0))
    return out


def test_reversals_are_located_at_the_reference_event_times():
    sol = simulate(forward_dynamics, _model(jnp.asarray(P0)), jnp.zeros(1), jnp.zeros(1), 0.0, T_END,
                   solver="dopri8", rtol=1e-12, atol=1e-14, saveat_ts=TS, events=True)
    ref = _reference_events()
    n = len(ref)
    assert n >= 3
    assert np.max(np.abs(np.asarray(sol.events.ts[:n]) - [t for t, _ in ref])) < EVENT_TOL
    assert list(np.asarray(sol.events.active[:n])) == [a for _, a in ref]
    assert list(np.asarray(sol.events.element[:n])) == [0] * n
    assert np.all(np.isinf(np.asarray(sol.events.ts[n:])))


def test_derivatives_across_reversals_match_converged_central_differences():
    p0 = jnp.asarray(P0)
    # Reverse mode row by row (one compiled vjp), forward mode column by column (one compiled jvp): the same
    # Jacobians as jacrev / jacfwd, without compiling their vmapped (batched while loop) programs.
    vjp_row = jax.jit(lambda p, ct: jax.vjp(lambda p: _outputs(p, "checkpoint"), p)[1](ct)[0])
    jvp_col = jax.jit(lambda p, t: jax.jvp(lambda p: _outputs(p, "forward"), (p,), (t,))[1])
    rev = np.stack([np.asarray(vjp_row(p0, ct)) for ct in jnp.eye(3)])
    fwd = np.stack([np.asarray(jvp_col(p0, t)) for t in jnp.eye(len(P0))], axis=1)

    def central(rel):
        cols = []
        for i in range(len(P0)):
            e = np.zeros(len(P0))
            e[i] = rel * P0[i]
            cols.append((np.asarray(_outputs(p0 + e)) - np.asarray(_outputs(p0 - e))) / (2 * e[i]))
        return np.stack(cols, axis=1)

    d = {rel: central(rel) for rel in (4e-3, 2e-3, 1e-3)}
    fd = [(4 * d[2e-3] - d[4e-3]) / 3, (4 * d[1e-3] - d[2e-3]) / 3]
    scale = np.abs(fd[1])
    conv = np.abs(fd[0] - fd[1]) / scale
    assert conv.max() < FD_AGREE, f"central differences not converged: {conv.max():.2e}"
    for name, ad in (("reverse", rev), ("forward", fwd)):
        err = np.abs(ad - fd[1]) / scale
        worst = np.unravel_index(np.argmax(err), err.shape)
        assert err.max() < GRAD_RTOL, f"{name}: {err.max():.2e} at output {worst[0]}, {NAMES[worst[1]]}"


def test_a_differentiated_rollout_without_events_warns_when_a_joint_reverses():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        jax.jvp(lambda p: _outputs(p, "forward", events=False), (jnp.asarray(P0),), (jnp.eye(len(P0))[0],))
        jax.effects_barrier()
    hits = [w for w in caught if issubclass(w.category, SwitchCrossedWarning)]
    assert hits and "joint 'pin'" in str(hits[0].message)


def test_events_need_a_switching_element():
    model = TreeModel(parents=[-1], kinds=["revolute"], axes=np.array([[0.0, 0.0, 1.0]]),
                      origin_rotations=np.eye(3)[None], origin_xyz=np.zeros((1, 3)),
                      inertia=np.array([[M, M * L, 0, 0, IC, 0, 0, IC + M * L**2, 0, IC + M * L**2]]))
    with pytest.raises(ValueError, match="events=True: the model has no switching element"):
        simulate(forward_dynamics, model, jnp.zeros(1), jnp.zeros(1), 0.0, 1.0, events=True)


def test_evented_rollouts_batch_under_vmap():
    """Two Coulomb levels in one vmapped call: each member's switches and final state as when run alone."""
    def run(p):
        return simulate(forward_dynamics, _model(p), jnp.zeros(1), jnp.zeros(1), 0.0, T_END, solver="dopri8",
                        rtol=1e-12, atol=1e-14, events=True)

    ps = jnp.stack([jnp.asarray(P0), jnp.asarray(P0).at[0].set(0.6)])
    batch = jax.vmap(run)(ps)
    for i in range(2):
        one = run(ps[i])
        np.testing.assert_allclose(np.asarray(batch.q[i]), np.asarray(one.q), rtol=0, atol=BATCH_TOL)
        n = int(np.sum(np.isfinite(np.asarray(one.events.ts))))
        assert n >= 2
        np.testing.assert_allclose(np.asarray(batch.events.ts[i, :n]), np.asarray(one.events.ts[:n]), atol=BATCH_TOL)
    assert not np.allclose(np.asarray(batch.q[0]), np.asarray(batch.q[1]))


def test_an_evented_rollout_out_of_steps_raises_or_reports():
    """A segment that exhausts the step budget (``max_steps`` counts per smooth segment) ends the evented run: it
    raises diffrax's message (throw=True), also when only the step counts are used, or is reported in the solution,
    whose states are NaN, without running the remaining segments (throw=False)."""
    def run(throw):
        return simulate(forward_dynamics, _model(jnp.asarray(P0)), jnp.zeros(1), jnp.zeros(1), 0.0, T_END,
                        solver="tsit5", rtol=1e-10, atol=1e-12, events=True, max_steps=4, throw=throw)

    with pytest.raises(jax.errors.JaxRuntimeError, match="maximum number of solver steps"):
        jax.block_until_ready(run(True).q)
    with pytest.raises(jax.errors.JaxRuntimeError, match="maximum number of solver steps"):
        jax.block_until_ready(jax.jit(lambda: run(True).steps)())
    sol = run(False)
    assert not bool(sol.ok) and sol.status == diffrax.RESULTS.max_steps_reached
    assert np.all(np.isnan(np.asarray(sol.q)))
    assert int(sol.steps) + int(sol.rejected) <= 4  # the first segment's budget, nothing after it
