"""Redundant constraints and least-squares multipliers: a four-bar whose loop is closed twice (three redundant rows)
against the same four-bar closed once, the least-squares solve against the exact one on a full-rank mechanism, and
the refusal that stays available."""

import dataclasses
import warnings

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from particlesim.errors import ModelError
from particlesim.mechanism import (accelerations_and_multipliers, project, simulate_mechanism,
                                   velocity_constraints)
from particlesim.mechanism.builder import RedundantConstraintsWarning

#: Accelerations of the doubled and the single loop closure, relative to the largest acceleration.
ACC_RTOL = 1e-10
#: Multipliers: the doubled closure's two shares summed against the single closure's [N].
LAM_TOL = 1e-9
#: Positions of the two along 1.5 s and 3 s, [m] (both integrated at rtol 1e-10; measured 1.9e-10 and 1.1e-10).
ROLLOUT_TOL = 1e-8


@pytest.fixture(scope="module")
def pair(four_bar):
    mech, x0 = four_bar().build()
    mb = four_bar()
    mb.cut_joint("B", "B2", name="the same cut twice")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        doubled, x0d = mb.build()
    xd = jnp.zeros_like(jnp.asarray(x0)).at[0].set(0.3)
    x, xd = project(mech, jnp.asarray(x0), xd)
    return mech, doubled, mb, caught, x, xd


def test_exact_multipliers_refuse_redundant_rows(four_bar):
    mb = four_bar()
    mb.cut_joint("B", "B2", name="the same cut twice")
    with pytest.raises(ModelError, match="over-constrained: 3 redundant .* the same cut twice .*least_squares"):
        mb.build(multipliers="exact")
    with pytest.raises(ValueError, match="unknown multipliers"):
        mb.build(multipliers="pinv")


def test_redundant_rows_are_reported(pair):
    _, doubled, mb, caught, _, _ = pair
    msgs = [str(w.message) for w in caught if issubclass(w.category, RedundantConstraintsWarning)]
    assert len(msgs) == 1 and "3 redundant constraint row(s) among 9 (rank 6)" in msgs[0]
    assert "the same cut twice (x)" in msgs[0]
    rank = mb.constraint_rank
    assert (rank.rows, rank.rank, rank.dof, rank.multipliers) == (9, 6, 3, "least_squares")
    assert rank.redundant == tuple(f"the same cut twice ({c})" for c in "xyz")
    assert doubled.topo.least_squares


def test_doubled_closure_moves_like_the_single_one(pair):
    mech, doubled, _, _, x, xd = pair
    a1, l1 = accelerations_and_multipliers(mech, 0.0, x, xd)
    a2, l2 = accelerations_and_multipliers(doubled, 0.0, x, xd)
    assert _rel_gap(a2, a1) <= ACC_RTOL
    # the loop force is shared between the two closures; their sum is the single closure's multiplier
    n = mech.n_constraints
    np.testing.assert_allclose(np.asarray(l2[n - 3:n] + l2[n:]), np.asarray(l1[n - 3:]), rtol=0, atol=LAM_TOL)
    np.testing.assert_allclose(np.asarray(l2[:n - 3]), np.asarray(l1[:n - 3]), rtol=0, atol=LAM_TOL)


def test_doubled_closure_rollout(pair):
    """The parallelogram four-bar's crank falls through its flat position (t ≈ 1.78 s), where the loop's rows lose
    rank: the single closure's exact solve is singular there (whether a rollout steps across it depends on round-off),
    the doubled closure's least-squares solve is not. So the doubled closure is compared with the single exact
    closure up to 1.5 s, and over 3 s through the flat position with the single closure solved by least squares."""
    mech, doubled, _, _, x, xd = pair
    lsq = _least_squares(mech)
    for single, t1 in ((mech, 1.5), (lsq, 3.0)):
        kw = dict(solver="dopri8", rtol=1e-10, atol=1e-12, saveat_ts=jnp.linspace(0.0, t1, 7))
        s1 = simulate_mechanism(single, x, xd, 0.0, t1, **kw)
        s2 = simulate_mechanism(doubled, x, xd, 0.0, t1, **kw)
        assert float(jnp.max(jnp.abs(s1.q - s2.q))) <= ROLLOUT_TOL
        assert float(jnp.max(jnp.abs(jax.vmap(lambda a, b: velocity_constraints(doubled, a, b))(s2.q, s2.qd)))) <= 1e-12


def _least_squares(mech):
    """The same mechanism with its multipliers solved by least squares."""
    return dataclasses.replace(mech, topo=dataclasses.replace(mech.topo, least_squares=True))


def _rel_gap(a, b) -> float:
    """Largest difference of ``a`` from ``b`` relative to ``b``'s largest entry."""
    return float(jnp.max(jnp.abs(a - b))) / float(jnp.max(jnp.abs(b)))


def _off(x):
    """Positions moved 1e-6 off the constraints (for the projections)."""
    return x + 1e-6 * jnp.sin(jnp.arange(x.shape[0]))


def test_least_squares_equals_exact_on_a_full_rank_mechanism(pair):
    mech, _, _, _, x, xd = pair
    lsq = _least_squares(mech)
    a1, l1 = accelerations_and_multipliers(mech, 0.0, x, xd)
    a2, l2 = accelerations_and_multipliers(lsq, 0.0, x, xd)
    assert _rel_gap(a2, a1) <= ACC_RTOL and _rel_gap(l2, l1) <= ACC_RTOL
    p1, p2 = project(mech, _off(x), xd), project(lsq, _off(x), xd)
    assert max(float(jnp.max(jnp.abs(u - v))) for u, v in zip(p1, p2)) <= 1e-14


def test_saddle_point_path_with_redundant_rows(pair):
    mech, doubled, _, _, x, xd = pair
    kkt = dataclasses.replace(doubled, topo=dataclasses.replace(doubled.topo, saddle_point=True))
    a1, _ = accelerations_and_multipliers(mech, 0.0, x, xd)
    a2, _ = accelerations_and_multipliers(kkt, 0.0, x, xd)
    assert _rel_gap(a2, a1) <= ACC_RTOL
    xq, xdq = project(kkt, _off(x), xd)
    assert float(jnp.max(jnp.abs(jnp.asarray(velocity_constraints(kkt, xq, xdq))))) <= 1e-12


def test_chain_solve_refuses_least_squares(pair):
    from particlesim.mechanism import chain_plan

    _, doubled, _, _, _, _ = pair
    with pytest.raises(ModelError, match="least-squares multipliers .* solve='dense'|only bodies"):
        chain_plan(doubled)


def test_exhausted_step_budget_says_what_usually_causes_it(pair):
    """A mechanism rollout that runs out of steps says what usually causes that: a stiff element (an implicit
    solver is the way out) and, when the mechanism solves for exact multipliers, a singular position (least-squares
    multipliers are); with throw=False it is reported instead. (Whether the exact four-bar's rollout through its
    flat position exhausts the budget depends on round-off, see test_doubled_closure_rollout; a budget of 4 steps
    runs out for certain.)"""
    mech, doubled, _, _, x, xd = pair
    kw = dict(solver="tsit5", rtol=1e-8, atol=1e-10, max_steps=4)
    both = r"(?s)maximum number of solver steps.*solver='kvaerno5'.*singular position.*multipliers='least_squares'"
    with pytest.raises(jax.errors.JaxRuntimeError, match=both):
        jax.block_until_ready(simulate_mechanism(mech, x, xd, 0.0, 1.0, **kw).q)
    # also when only the step count is kept, inside the caller's own jit (the check rides on every output)
    with pytest.raises(jax.errors.JaxRuntimeError, match=both):
        jax.block_until_ready(jax.jit(lambda: simulate_mechanism(mech, x, xd, 0.0, 1.0, **kw).steps)())
    with pytest.raises(jax.errors.JaxRuntimeError, match=r"(?s)maximum number of solver steps.*solver='kvaerno5'") \
            as info:
        jax.block_until_ready(simulate_mechanism(doubled, x, xd, 0.0, 1.0, **kw).q)
    assert "singular position" not in str(info.value)  # least-squares multipliers already
    sol = simulate_mechanism(mech, x, xd, 0.0, 1.0, throw=False, **kw)
    assert not bool(sol.ok) and sol.status == diffrax.RESULTS.max_steps_reached
    assert np.all(np.isnan(np.asarray(sol.q)))
