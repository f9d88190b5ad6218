"""The hub split (``solve="sparse"``, :mod:`particlesim.mechanism.sparse`) against the dense solve, its reference.

The split is the same linear algebra in another order: accelerations and multipliers equal the dense solve's to
round-off at any state, and so do their derivatives with respect to the parameters (reverse and forward mode)."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from particlesim import _ode
from particlesim.inertia import RigidInertia
from particlesim.mechanism import MechanismBuilder, body_com_positions, residuals, simulate_mechanism
from particlesim.mechanism.dynamics import _solve, prepare
from particlesim.scenes import quarter_car as qc
from particlesim.scenes import roads as rd
from particlesim.scenes.vehicle import full_vehicle

SOLVE_RTOL = 1e-12  # relative to the largest entry (the car: measured 5e-15 for accelerations, 3e-15 for multipliers)
#: hubs sharing joint particles with their groups: the groups' own mass blocks are inverted, and the spider's
#: saddle-point system has condition number 1.4e5 (eps x cond = 3e-11): measured 1.4e-12 and 1.9e-12 (spider's
#: accelerations and multipliers), 1.3e-12 and 4.8e-13 (quarter car's)
COUPLED_RTOL = 1e-10
GRAD_RTOL = 1e-10  # the bound for derivatives through the split against the dense path's
ROLLOUT_ATOL = 1e-9  # m: chassis heave of a rollout, both solves at rtol 1e-10 (measured ~1e-12)
RESIDUAL_ATOL = 1e-12  # m, m/s: constraint residuals of saved states (the dense path's, measured ~1e-15)
N_STATES = 4


@pytest.fixture(scope="module")
def car():
    mech, q0 = full_vehicle(stops={"stiffness": 1e6, "damping": 1e3},
                            roads={"FL": rd.Bump(0.06, 0.02, 0.06), "FR": rd.Bump(0.06, 0.02, 0.06)})
    return mech, jnp.asarray(q0)


def spider(legs: int = 4):
    """A trunk whose four primaries are the hips of four two-body legs (ball joints: the hip particle shared with
    the trunk, the knee shared between thigh and shin), a spring from each hip to its foot: groups coupled to the
    hub through the mass matrix."""
    mb = MechanismBuilder(gravity=(0.0, 0.0, -9.81))
    hips = [np.array([np.cos(a) * 0.3, np.sin(a) * 0.3, 0.5 + 0.05 * (k % 2)])
            for k, a in enumerate(np.linspace(0, 2 * np.pi, legs, endpoint=False))]
    mb.body("trunk", RigidInertia.from_principal(10.0, np.mean(hips, 0), (0.3, 0.3, 0.5)),
            [mb.particle(f"hip {k}", h) for k, h in enumerate(hips)])
    for k, h in enumerate(hips):
        out = np.array([h[0], h[1], 0.0]) / np.linalg.norm(h[:2])
        side = np.cross(out, [0, 0, 1.0])
        knee = h + 0.25 * out + [0, 0, 0.05]
        foot = knee + 0.1 * out - [0, 0, 0.45]
        mb.body(f"thigh {k}", RigidInertia.from_principal(1.0, (h + knee) / 2, (0.002, 0.006, 0.006)),
                [f"hip {k}", mb.particle(f"knee {k}", knee), mb.particle(f"thigh a {k}", (h + knee) / 2 + 0.05 * side),
                 mb.particle(f"thigh b {k}", (h + knee) / 2 - 0.05 * side + [0, 0, 0.04])], on_negative="ignore")
        mb.body(f"shin {k}", RigidInertia.from_principal(0.6, (knee + foot) / 2, (0.004, 0.004, 0.001)),
                [f"knee {k}", mb.particle(f"foot {k}", foot),
                 mb.particle(f"shin a {k}", (knee + foot) / 2 + 0.04 * side),
                 mb.particle(f"shin b {k}", (knee + foot) / 2 - 0.04 * side + 0.03 * out)], on_negative="ignore")
        mb.spring_damper(f"leg spring {k}", f"hip {k}", f"foot {k}", 500.0, 5.0)
    mech, q0 = mb.build()
    return mech, jnp.asarray(q0)


@pytest.fixture(scope="module")
def coupled():
    return {"spider": spider(), "quarter car": tuple(jnp.asarray(a) if i else a for i, a in enumerate(qc.quarter_car()))}


def _both(mech, q, qd, t=0.0):
    prep = prepare(mech)
    return [_solve(mech, prep, t, q, qd, 0.0, split=s) for s in (False, True)]


_both_jit = jax.jit(_both)


def test_plan_of_the_vehicle(car):
    mech, _ = car
    plan = mech.topo.sparse
    assert plan is not None and plan.hub == "chassis" and plan.n_groups == 4
    assert len(plan.buckets) == 1  # four corners of one shape: one vectorised kernel
    assert len(plan.hub_dot) + len(plan.hub_lin) == 6  # the chassis' own rigid-body rows


def test_accelerations_and_multipliers_equal_dense(car):
    mech, q0 = car
    rng = np.random.default_rng(1)
    for k in range(N_STATES):
        q = q0 + 1e-3 * k * jnp.asarray(rng.normal(size=q0.shape))  # off the constraints too: the algebra holds
        qd = jnp.asarray(rng.normal(size=q0.shape))
        (a, lam), (a_s, lam_s) = _both_jit(mech, q, qd, 0.07)
        print(f"state {k}: |a - a_dense| {np.abs(a_s - a).max():.1e} of {np.abs(a).max():.1e}, |lam - lam_dense| "
              f"{np.abs(lam_s - lam).max():.1e} of {np.abs(lam).max():.1e}")
        np.testing.assert_allclose(a_s, a, rtol=0, atol=SOLVE_RTOL * np.abs(a).max())
        np.testing.assert_allclose(lam_s, lam, rtol=0, atol=SOLVE_RTOL * np.abs(lam).max())


@pytest.mark.parametrize("name, hub, groups", [("spider", "trunk", 4), ("quarter car", "chassis", 1)])
def test_hubs_sharing_particles_with_their_groups(coupled, name, hub, groups):
    """The plan found and the solve equal to the dense one where a hub's particles are also its groups' (joint
    particles): the groups' mass coupling enters the hub's articulated inertia."""
    mech, q0 = coupled[name]
    plan = mech.topo.sparse
    assert plan is not None and (plan.hub, plan.n_groups, plan.coupled) == (hub, groups, True)
    qd = jnp.asarray(np.random.default_rng(4).normal(size=q0.shape))
    (a, lam), (a_s, lam_s) = _both_jit(mech, q0, qd)
    print(f"{name}: |a - a_dense| {np.abs(a_s - a).max():.1e} of {np.abs(a).max():.1e}, |lam - lam_dense| "
          f"{np.abs(lam_s - lam).max():.1e} of {np.abs(lam).max():.1e}")
    np.testing.assert_allclose(a_s, a, rtol=0, atol=COUPLED_RTOL * np.abs(a).max())
    np.testing.assert_allclose(lam_s, lam, rtol=0, atol=COUPLED_RTOL * np.abs(lam).max())
    dense, split = _grads(mech.spring_stiffness, mech.spring_damping, mech.body_mass, mech, q0, qd)
    for gd, gs in zip(dense, split):
        np.testing.assert_allclose(gs, gd, rtol=0, atol=GRAD_RTOL * np.abs(gd).max())


def _loss(split):
    def loss(stiffness, damping, masses, mech, q, qd):
        m = dataclasses.replace(mech, spring_stiffness=stiffness, spring_damping=damping, body_mass=masses)
        a, lam = _solve(m, prepare(m), 0.07, q, qd, 0.0, split=split)
        return jnp.sum(a[2::3] ** 2) + 1e-8 * jnp.sum(lam**2)

    return loss


_grads = jax.jit(lambda *a: [jax.grad(_loss(s), argnums=(0, 1, 2))(*a) for s in (False, True)])


def test_gradients_equal_dense(car):
    mech, q0 = car
    qd = jnp.asarray(np.random.default_rng(2).normal(size=q0.shape))
    args = (mech.spring_stiffness, mech.spring_damping, mech.body_mass, mech, q0, qd)
    dense, split = _grads(*args)
    for name, gd, gs in zip(("spring stiffness", "spring damping", "body mass"), dense, split):
        print(f"d loss / d {name}: {np.abs(gs - gd).max():.1e} of {np.abs(gd).max():.1e}")
        assert np.abs(gd).max() > 0
        np.testing.assert_allclose(gs, gd, rtol=0, atol=GRAD_RTOL * np.abs(gd).max())


def test_check_grads_through_split(car):
    """Forward and reverse mode against finite differences, through the split alone (masses of the corner bodies
    and the chassis, the multipliers included)."""
    mech, q0 = car
    qd = jnp.asarray(np.random.default_rng(3).normal(size=q0.shape))
    loss = _loss(True)
    f = jax.jit(lambda m: loss(mech.spring_stiffness, mech.spring_damping, m, mech, q0, qd))
    check_grads(f, (mech.body_mass,), order=1, modes=("fwd", "rev"), eps=1e-3, atol=1e-6, rtol=1e-6)


def test_rollout_with_events_equals_dense(car):
    """The bump lifts the front wheels off the road: located events on both paths, the same switch times and the
    same heave."""
    mech, q0 = car
    ts = jnp.linspace(0.0, 0.4, 41)
    runs = [simulate_mechanism(mech, q0, jnp.zeros_like(q0), 0.0, 0.4, rtol=1e-10, atol=1e-12, saveat_ts=ts,
                               events=True, solve=s) for s in ("dense", "sparse")]
    b = mech.body_index("chassis")
    heave = [np.asarray(jax.vmap(lambda x: body_com_positions(mech, x)[b, 2])(r.q)) for r in runs]
    ev = [np.asarray(r.events.ts) for r in runs]
    print(f"heave |sparse - dense| {np.abs(heave[1] - heave[0]).max():.1e} m; events {ev[0][np.isfinite(ev[0])]}")
    assert all(bool(r.ok) for r in runs)
    # the front wheels leave the road together and land: every saved state finite, also in the segment after the
    # simultaneous switch (whose saves were once interpolated from a spurious event on a rejected first step)
    assert np.all(np.isfinite(heave[0])) and np.all(np.isfinite(heave[1]))
    assert np.isfinite(ev[0]).sum() >= 2
    np.testing.assert_allclose(ev[1], ev[0], rtol=0, atol=1e-9)
    np.testing.assert_allclose(heave[1], heave[0], rtol=0, atol=ROLLOUT_ATOL)
    # new parameter values reuse the compiled split rollout (traces counted, not timed)
    before = _ode.TRACES["simulate_mechanism"]
    stiffer = mech.with_params(spring={n: {"stiffness": 1.1 * float(k)}
                                       for n, k in zip(mech.topo.spring_names, mech.spring_stiffness)})
    again = simulate_mechanism(stiffer, q0, jnp.zeros_like(q0), 0.0, 0.4, rtol=1e-10, atol=1e-12, saveat_ts=ts,
                               events=True, solve="sparse")
    assert bool(again.ok) and _ode.TRACES["simulate_mechanism"] == before
    # every saved state on the constraints (positions and velocities)
    phi, vel = (np.asarray(a) for a in jax.vmap(lambda x, v: residuals(mech, x, v))(runs[1].q, runs[1].qd))
    print(f"saved states' residuals: {np.abs(phi).max():.1e} m, {np.abs(vel).max():.1e} m/s")
    assert np.abs(phi).max() <= RESIDUAL_ATOL and np.abs(vel).max() <= RESIDUAL_ATOL


def test_mechanism_without_a_plan_is_refused():
    mb = MechanismBuilder()  # one body: nothing hangs from it
    mb.rod("rod", mb.particle("a", (0.0, 0.0, 0.0)), mb.particle("b", (1.0, 0.0, 0.0)), 1.0)
    mech, x0 = mb.build()
    assert mech.topo.sparse is None
    with pytest.raises(ValueError, match="solve='sparse' needs a hub body"):
        simulate_mechanism(mech, x0, jnp.zeros_like(x0), 0.0, 0.1, solve="sparse")
