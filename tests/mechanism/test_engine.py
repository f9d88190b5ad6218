"""The Schur-complement engine against an independent saddle-point solve built from autodiff of the residuals.

The reference here shares nothing with :mod:`particlesim.mechanism._algebra` but the model: its constraint Jacobian
and ``gamma`` come from forward-mode differentiation of :func:`~particlesim.mechanism.constraints`, its mass matrix
from :func:`~particlesim.mechanism.mass_matrix` (the bodies' particle masses), its forces from
:func:`~particlesim.mechanism.generalized_forces`, and the system ``[[M, J^T], [J, 0]]`` is solved by LU. Also: the
saddle-point fallback (for singular mass matrices) agrees with both.
"""

import dataclasses
import inspect

import jax
import jax.extend.core
import jax.numpy as jnp
import numpy as np
import pytest

from particlesim.mechanism import (accelerations_and_multipliers, constraints, generalized_forces, mass_matrix,
                                   project)
from particlesim.scenes.chains import chain_geometry, chain_mechanism
from particlesim.scenes.nikravesh import aa_mechanism
from particlesim.scenes.quarter_car import quarter_car

ACC_RTOL = 1e-9  # relative to the largest acceleration / multiplier: three exact solves, round-off apart


def _slider_crank():
    from test_constraints import _slider_crank_like  # every row kind: distances, cut joint, prismatic, ground

    return _slider_crank_like()


SCENES = {
    "revolute chain": lambda: chain_mechanism(chain_geometry(3, "revolute", seed=3)),
    # 18 free particles: beyond MM_UNROLL, the rows' products are matrix products
    "revolute chain, 9 links": lambda: chain_mechanism(chain_geometry(9, "revolute", seed=3)),
    "spherical chain": lambda: chain_mechanism(chain_geometry(3, "spherical", seed=3)),
    "quarter car": quarter_car,
    "Nikravesh AA": aa_mechanism,
    "slider crank": _slider_crank,
}


def _reference(mech, x, xd):
    j = jax.jacfwd(lambda y: constraints(mech, y))(x)
    gamma = -jax.jvp(lambda y: jax.jvp(lambda z: constraints(mech, z), (y,), (xd,))[1], (x,), (xd,))[1]
    m = mass_matrix(mech)
    q = generalized_forces(mech, 0.0, x, xd)
    n, c = m.shape[0], j.shape[0]
    sol = jnp.linalg.solve(jnp.block([[m, j.T], [j, jnp.zeros((c, c))]]), jnp.concatenate([q, gamma]))
    return sol[:n], sol[n:]


@pytest.mark.parametrize("name", list(SCENES))
def test_schur_solve_equals_independent_saddle_point_solve(name):
    mech, x0 = SCENES[name]()
    rng = np.random.default_rng(7)
    x, xd = project(mech, jnp.asarray(x0) + 1e-3 * rng.normal(size=x0.shape), jnp.asarray(rng.normal(size=x0.shape)))
    a_ref, lam_ref = _reference(mech, x, xd)
    a, lam = accelerations_and_multipliers(mech, 0.0, x, xd)
    kkt = dataclasses.replace(mech, topo=dataclasses.replace(mech.topo, saddle_point=True))
    a_kkt, lam_kkt = accelerations_and_multipliers(kkt, 0.0, x, xd)
    # Scale: the largest acceleration, or gravity's (the slider crank is locked: its accelerations are round-off)
    scale = max(float(jnp.abs(a_ref).max()), float(jnp.linalg.norm(mech.gravity)))
    for got in (a, a_kkt):
        np.testing.assert_allclose(got, a_ref, rtol=0, atol=ACC_RTOL * scale)
    # Multipliers are forces: judged against the force scale (they may all be small, e.g. at rest)
    force = max(float(jnp.abs(lam_ref).max()), float(jnp.abs(generalized_forces(mech, 0.0, x, xd)).max()))
    for got in (lam, lam_kkt):
        np.testing.assert_allclose(got, lam_ref, rtol=0, atol=ACC_RTOL * force)


POS_ATOL = 1e-13  # m^2: rows are (|d|^2 - L^2)/2 with |d| ~ 1 m, round-off times the rows' conditioning
VEL_RTOL = 1e-13  # relative to the largest velocity or 1 m/s (the slider crank is locked: its velocity is the noise)


@pytest.mark.parametrize("name", ["quarter car", "slider crank"])
def test_projection_reaches_round_off_from_a_step_sized_error(name):
    """The full projection (one factorisation, two position and two velocity passes): residuals at round-off from an
    admissible state disturbed by 1e-6 (the size of a step's local error, which is what the integrator hands it)."""
    from particlesim.mechanism import residuals

    mech, x0 = SCENES[name]()
    rng = np.random.default_rng(3)
    x, xd = project(mech, jnp.asarray(x0), jnp.asarray(rng.normal(size=x0.shape)))
    x = x + 1e-6 * rng.normal(size=x0.shape)
    xd = xd + 1e-6 * rng.normal(size=x0.shape)
    assert float(jnp.abs(residuals(mech, x, xd)[0]).max()) > 1e3 * POS_ATOL  # the disturbance is real
    xp, xdp = project(mech, x, xd)
    pos, vel = residuals(mech, xp, xdp)
    assert float(jnp.abs(pos).max()) <= POS_ATOL
    assert float(jnp.abs(vel).max()) <= VEL_RTOL * max(float(jnp.abs(xd).max()), 1.0)


#: Residuals left by the projection between steps from a disturbance of size delta (each coordinate delta times a
#: standard normal draw), bounded by this times delta^2: measured 174 (positions) and 1131 (velocities) for the
#: quarter car, 2.8 and 1.7 for the slider crank; and the residuals' growth when delta grows tenfold, quadratic
#: convergence giving a hundredfold (measured 99.7-100.1): the range excludes tenfold (no pass: residuals ~ delta)
#: and onefold or a thousandfold (two passes: round-off, or delta^3).
SQUARE_BOUND = 1e4
GROWTH_RANGE = (30.0, 300.0)


@pytest.mark.parametrize("name", ["quarter car", "slider crank"])
def test_projection_between_steps_leaves_the_square_of_the_error(name):
    """The projection between steps (one position iteration, one velocity pass, :data:`BETWEEN_STEPS`) leaves
    residuals of the order of the disturbance squared (quadratic convergence from the exact factor at the disturbed
    state), which is what the integrator's docstring claims of it."""
    from particlesim.mechanism import mass_properties, residuals
    from particlesim.mechanism.integrate import BETWEEN_STEPS, project_prepared

    mech, x0 = SCENES[name]()
    props = mass_properties(mech)
    rng = np.random.default_rng(5)
    x, xd = project(mech, jnp.asarray(x0), jnp.asarray(rng.normal(size=x0.shape)))
    dx, dxd = rng.normal(size=x0.shape), rng.normal(size=x0.shape)
    pos, vel = [], []
    for delta in (1e-5, 1e-4):
        xp, xdp = project_prepared(mech, props, x + delta * dx, xd + delta * dxd, 0.0, BETWEEN_STEPS)
        p_res, v_res = residuals(mech, xp, xdp)
        pos.append(float(jnp.abs(p_res).max()))
        vel.append(float(jnp.abs(v_res).max()))
        assert pos[-1] <= SQUARE_BOUND * delta**2 and vel[-1] <= SQUARE_BOUND * delta**2
    assert GROWTH_RANGE[0] < pos[1] / pos[0] < GROWTH_RANGE[1]
    assert GROWTH_RANGE[0] < vel[1] / vel[0] < GROWTH_RANGE[1]


@pytest.mark.parametrize("solve", ["dense", "chain"])
def test_a_rollout_projects_lightly_between_steps_and_fully_at_outputs(solve, monkeypatch):
    """What :func:`simulate_mechanism` asks of the projection, read off its trace (no compile): the step's
    projection with :data:`BETWEEN_STEPS` passes, the saved states' with :data:`FULL`, on the dense and the O(N)
    chain path (the test above checks what one light pass leaves; this one that the rollout uses it)."""
    from particlesim.mechanism import integrate, simulate_mechanism

    seen = []
    name = "project_prepared" if solve == "dense" else "chain_project"
    real = getattr(integrate, name)
    signature = inspect.signature(real)

    def spy(*args, **kwargs):
        bound = signature.bind(*args, **kwargs)
        bound.apply_defaults()
        seen.append(tuple(bound.arguments["passes"]))
        return real(*args, **kwargs)

    raw = integrate._simulate.__wrapped__
    monkeypatch.setattr(integrate, name, spy)
    monkeypatch.setattr(integrate, "_simulate", lambda *a, **k: jax.eval_shape(lambda: raw(*a, **k)))
    mech, x0 = SCENES["revolute chain"]()
    simulate_mechanism(mech, jnp.asarray(x0), jnp.zeros(x0.shape), 0.0, 0.05, solve=solve)
    assert integrate.BETWEEN_STEPS != integrate.FULL
    # the step's projection is traced with the solver (diffrax may trace a step more than once), the saved states'
    # after the integration, last
    assert seen[-1] == integrate.FULL and set(seen[:-1]) == {integrate.BETWEEN_STEPS}, seen


@pytest.mark.parametrize("solve", ["dense", "chain"])
@pytest.mark.parametrize("saves", [None, 3], ids=["t0 and t1", "at given times"])
def test_saved_states_lie_on_the_constraints_from_a_disturbed_start(saves, solve):
    """Every saved state of a projected rollout of a moving chain is on the constraints, the initial one included
    when the start is off them by a step-sized error (without save times the initial and the final states are
    projected after the run, to round-off; the steps between make one pass of each kind), on the dense and the
    O(N) chain path."""
    from particlesim.mechanism import residuals, simulate_mechanism

    mech, x0 = SCENES["revolute chain"]()
    rng = np.random.default_rng(5)
    x, xd = project(mech, jnp.asarray(x0), jnp.asarray(rng.normal(size=x0.shape)))
    x = x + 1e-6 * rng.normal(size=x0.shape)
    assert float(jnp.abs(residuals(mech, x, xd)[0]).max()) > 1e3 * POS_ATOL  # the disturbance is real
    ts = None if saves is None else np.linspace(0.0, 0.05, saves)
    sol = simulate_mechanism(mech, x, xd, 0.0, 0.05, rtol=1e-6, atol=1e-8, saveat_ts=ts, solve=solve)
    assert sol.q.shape[0] == (2 if saves is None else saves)
    assert float(jnp.abs(sol.q[-1] - sol.q[0]).max()) > 1e-3  # it moved: the final state ends real steps
    for q, qd in zip(sol.q, sol.qd):
        pos, vel = residuals(mech, q, qd)
        assert float(jnp.abs(pos).max()) <= POS_ATOL
        assert float(jnp.abs(vel).max()) <= VEL_RTOL * max(float(jnp.abs(qd).max()), 1.0)


def _avals(jaxpr):
    """Shapes of every intermediate of a (closed) jaxpr, nested jaxprs (jit, scan, cond...) included."""
    jaxpr = getattr(jaxpr, "jaxpr", jaxpr)
    for eqn in jaxpr.eqns:
        for v in eqn.outvars:
            yield tuple(getattr(v.aval, "shape", ()))
        for param in eqn.params.values():
            for sub in (param if isinstance(param, (tuple, list)) else (param,)):
                if isinstance(sub, (jax.extend.core.ClosedJaxpr, jax.extend.core.Jaxpr)):
                    yield from _avals(sub)


def test_vmapped_engine_forms_no_row_by_particle_broadcasts():
    """Vmapped over parameter sets, the field and the projection form no (B, 2D, F, 3) broadcast product of the
    rows' constant matrix with the particles (XLA hoists such a broadcast out of an integrator's loop and reads
    it from memory at every evaluation: 8 identical quarter cars vmapped took 12.0 ms each with it, 4.8-5.1 ms
    without)."""
    from particlesim.batch import stack
    from particlesim.mechanism import accelerations
    from particlesim.mechanism._algebra import MM_UNROLL

    mech, x0 = quarter_car()
    f, two_d = x0.shape[0] // 3, 2 * len(mech.topo.dot.a)
    assert f <= MM_UNROLL
    mechs = stack([mech.with_params(spring={"suspension": {"stiffness": k}}) for k in (2e4, 3e4, 4e4)])
    xs = jnp.broadcast_to(jnp.asarray(x0), (3, x0.shape[0]))
    shapes = list(_avals(jax.make_jaxpr(jax.vmap(
        lambda m, x, xd: (accelerations(m, 0.0, x, xd), project(m, x, xd))))(mechs, xs, xs)))
    assert any(s[-2:] == (two_d, 3) for s in shapes)  # the rows' vectors are there (the walk sees the engine)
    assert not [s for s in shapes if s[-3:] == (two_d, f, 3)]


@pytest.mark.parametrize("f", [13, 16, 17])
def test_rows_products_equal_matrix_products_with_their_derivatives(f):
    """The rows' products (an unrolled sum of outer products up to MM_UNROLL particles, with its own tangent; a matrix
    product beyond) equal ``a @ b`` and differentiate like it, fwd and rev to second order, also with ``a``
    constant (a symbolic-zero tangent)."""
    from jax.test_util import check_grads

    from particlesim.mechanism._algebra import _mm

    rng = np.random.default_rng(f)
    a, b = jnp.asarray(rng.normal(size=(66, f))), jnp.asarray(rng.normal(size=(f, 3)))
    np.testing.assert_allclose(_mm(a, b), a @ b, rtol=0, atol=1e-13)
    check_grads(_mm, (a, b), order=2, modes=("fwd", "rev"))
    check_grads(lambda y: _mm(a, y), (b,), order=2, modes=("fwd", "rev"))
    np.testing.assert_allclose(jax.jacrev(lambda y: _mm(a, y))(b), jax.jacrev(lambda y: a @ y)(b), rtol=0, atol=1e-13)
    assert _mm(a[:, :0], b[:0]).shape == (66, 3) and not np.any(_mm(a[:, :0], b[:0]))  # no particles: zeros


@pytest.mark.parametrize("scene", ["quarter car", "4-link chain"])
def test_schur_outer_and_gram_forms_agree_with_derivatives(scene, monkeypatch):
    """The Schur complement's two forms of its Gram products (outer products of the coordinates up to
    GRAM_OUTER_MAX_ROWS dot rows, ``E E^T`` beyond) both equal ``J M^-1 J^T`` formed from the dense Jacobian and the
    inverse mass matrix at a displaced state, and the outer form differentiates (fwd and rev, against finite
    differences) in the positions."""
    from jax.test_util import check_grads

    from particlesim.mechanism import _algebra

    mech, x0 = quarter_car() if scene == "quarter car" else chain_mechanism(chain_geometry(4, "revolute", seed=4))
    prep = _algebra.prepare(mech)
    q = jnp.asarray(x0) + 1e-2 * jnp.asarray(np.random.default_rng(0).normal(size=len(x0)))

    def s_of(q):
        return _algebra.schur(prep, _algebra.rows(prep, q))

    def barrier():  # the elementwise form is the one behind an optimisation barrier (a new function each time:
        return "optimization_barrier" in str(jax.make_jaxpr(lambda y: s_of(y))(q))  # make_jaxpr caches by function)

    monkeypatch.setattr(_algebra, "GRAM_OUTER_MAX_ROWS", 10**6)
    assert barrier()
    outer = s_of(q)
    check_grads(s_of, (q,), order=1, modes=("fwd", "rev"))
    monkeypatch.setattr(_algebra, "GRAM_OUTER_MAX_ROWS", -1)
    assert not barrier()
    gram = s_of(q)
    r = _algebra.rows(prep, q)
    j = _algebra.jacobian(prep, r).reshape(mech.n_constraints, -1)
    dense = j @ jnp.kron(prep.minv, jnp.eye(3)) @ j.T
    for s in (outer, gram):
        np.testing.assert_allclose(s, dense, rtol=0, atol=1e-12 * float(jnp.abs(dense).max()))


#: The Schur solve's multipliers and their derivatives against the dense route (relative to the largest entry).
SCHUR_SOLVE_RTOL = 1e-10


@pytest.mark.parametrize("scene", ["quarter car", "driven pendulum", "Nikravesh AA"])
def test_schur_solve_derivatives_match_the_dense_solve(scene):
    """``schur_solve``'s own derivative rule (``dS lam`` applied, never formed) against JAX's derivatives of the
    dense route ``solve(J M^-1 J^T, rhs)`` (the Jacobian, the inverse mass matrix, ``jnp.linalg.solve``), in the
    positions and the body masses (the parameters reach it through the prepared constants), forward and reverse;
    and against central differences (``check_grads``). Scenes with dot and linear rows (quarter car), driving rows
    (a planar pendulum on a driven pivot) and turned planar rows (Nikravesh AA)."""
    from jax.test_util import check_grads

    from particlesim.mechanism import _algebra
    from test_drivers import _pendulum  # the pendulum on a sideways-driven pivot

    mech, x0 = {"quarter car": quarter_car, "driven pendulum": _pendulum, "Nikravesh AA": aa_mechanism}[scene]()
    assert mech.n_constraints and not mech.topo.saddle_point and not mech.topo.least_squares  # the path tested
    names = mech.topo.body_names
    rng = np.random.default_rng(1)
    q0 = jnp.asarray(x0) + 1e-2 * jnp.asarray(rng.normal(size=len(x0)))
    rhs = jnp.asarray(rng.normal(size=mech.n_constraints))
    t = 0.013

    def parts(q, k):
        m = mech.with_params(body={n: {"mass": k * mech.body_mass[i], "inertia": k * mech.body_inertia[i]}
                                   for i, n in enumerate(names)})
        prep = _algebra.prepare(m)
        return prep, _algebra.rows(prep, q, drive=_algebra.drive_at(m, t))

    def ours(q, k):
        prep, r = parts(q, k)
        return _algebra.schur_solve(prep, r, _algebra.schur(prep, r), rhs)

    def dense(q, k):
        prep, r = parts(q, k)
        j = _algebra.jacobian(prep, r).reshape(mech.n_constraints, -1)
        return jnp.linalg.solve(j @ jnp.kron(prep.minv, jnp.eye(3)) @ j.T, rhs)

    k0 = jnp.asarray(1.1)
    ref = dense(q0, k0)
    scale = float(jnp.abs(ref).max())
    np.testing.assert_allclose(ours(q0, k0), ref, rtol=0, atol=SCHUR_SOLVE_RTOL * scale)
    dq = jnp.asarray(rng.normal(size=len(x0)))
    (_, t_ours), (_, t_ref) = (jax.jvp(g, (q0, k0), (dq, jnp.asarray(0.7))) for g in (ours, dense))
    np.testing.assert_allclose(t_ours, t_ref, rtol=0, atol=SCHUR_SOLVE_RTOL * float(jnp.abs(t_ref).max()))
    w = jnp.asarray(rng.normal(size=mech.n_constraints))
    g_ours = jax.grad(lambda q, k: ours(q, k) @ w, argnums=(0, 1))(q0, k0)
    g_ref = jax.grad(lambda q, k: dense(q, k) @ w, argnums=(0, 1))(q0, k0)
    for a, b in zip(g_ours, g_ref):
        np.testing.assert_allclose(a, b, rtol=0, atol=SCHUR_SOLVE_RTOL * float(jnp.abs(b).max()))
    check_grads(ours, (q0, k0), order=1, modes=("fwd", "rev"), eps=1e-6)
