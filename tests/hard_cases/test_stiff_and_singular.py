"""Hard cases for the solvers, the particle mass solve and reduced precision (numerical stability).

Each test states its expectation; tolerances are named constants beside the case. Every run must be free of NaN,
and a case that cannot be handled must fail loudly (an exception or ``ok = False``), never return garbage.

1. Stiff spring-damper (k = 1e7 N/m on 1 kg): the exact solution of the linear ODE (matrix exponential). The
   implicit solver takes few steps; the explicit one is held by its stability interval (computed from its
   Butcher tableau) and needs many; a step budget too small for it is reported, not hidden.
2. Near-coplanar / near-collinear primary particles: reproduction error against the conditioning of the
   placement, and a :class:`PlacementError` naming the body beyond the threshold.
3. float32 against float64 (Krang forward dynamics and a 1 s rollout): the error is measured and bounded.

Krang at a singular pose, over 100 s and spinning fast: ``tests/hard_cases/test_hard_krang.py``; mechanisms
(fast spin, 100 s, 64-body chains): ``tests/hard_cases/test_hard_mechanisms.py``.
"""

import warnings

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import scipy.linalg

from particlesim import PlacementError, RigidInertia
from particlesim.particles import PLACEMENT_RTOL, equivalent_particles
from particlesim.scenes.krang import krang_urdf
from particlesim.simulate import simulate
from particlesim.tree import forward_dynamics, mass_matrix
from particlesim.io import load_urdf

# ---------------------------------------------------------------------------------------------------------------
# 1. Stiff spring-damper
# ---------------------------------------------------------------------------------------------------------------

SLIDER_URDF = """<?xml version="1.0"?>
<robot name="slider"><link name="world"/>
  <link name="block"><inertial><origin xyz="0 0 0" rpy="0 0 0"/><mass value="1.0"/>
    <inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial></link>
  <joint name="x" type="prismatic"><parent link="world"/><child link="block"/><origin xyz="0 0 0" rpy="0 0 0"/>
    <axis xyz="1 0 0"/><limit effort="1" lower="-1" upper="1" velocity="1"/></joint>
</robot>
"""
STIFFNESS = 1e7  # N/m, on a 1 kg block
HEAVY_DAMPING = 1e5  # N s/m: eigenvalues -99899.9 and -100.1 (stiffness ratio 1e3)
STIFF_T1 = 0.5  # s: the slow mode decays by e^-50
STIFF_MAX_STEPS = 65536
STIFF_RTOL, STIFF_ATOL = 1e-8, 1e-10
#: Global error of both solvers against the matrix exponential, relative to the initial deflection.
STIFF_SOLUTION_RTOL = 1e-6
#: The implicit solver must take at least this many times fewer steps than the explicit one.
STIFF_STEP_RATIO = 20
#: Undamped: energy 1/2 m v^2 + 1/2 k x^2 kept to this (relative), over 0.01 s = 16 periods.
OSC_ENERGY_RTOL = 1e-6
OSC_T1 = 0.01
X0 = 0.01  # m


@pytest.fixture(scope="module")
def slider():
    return load_urdf(SLIDER_URDF, gravity=(0.0, 0.0, 0.0))


def _spring(stiffness, damping):
    return lambda t, q, qd, p: -stiffness * q - damping * qd


def _exact(stiffness, damping, ts):
    a = np.array([[0.0, 1.0], [-stiffness, -damping]])  # unit mass
    return np.stack([scipy.linalg.expm(a * t) @ np.array([X0, 0.0]) for t in ts])


def _real_stability_interval(tableau) -> float:
    """Largest r with |R(-x)| <= 1 on [0, r], R(z) = 1 + z b^T (I - z A)^-1 1 the stability function."""
    s = len(tableau.b_sol)
    a = np.zeros((s, s))
    for i, row in enumerate(tableau.a_lower):
        a[i + 1, : len(row)] = row
    xs = np.linspace(1e-3, 20.0, 20001)
    r = np.array([1.0 - x * tableau.b_sol @ np.linalg.solve(np.eye(s) + x * a, np.ones(s)) for x in xs])
    return float(xs[np.argmax(np.abs(r) > 1.0 + 1e-12) - 1])


_RUNS = {}


def _slider_run(slider, solver):
    """One compiled run per solver: ``(stiffness, damping, t1) -> Solution`` saved at 11 times in [0, t1]; failures
    are reported in ``ok`` (every caller checks it)."""
    if solver not in _RUNS:
        _RUNS[solver] = jax.jit(lambda k, c, t1: simulate(
            forward_dynamics, slider, jnp.array([X0]), jnp.zeros(1), 0.0, t1, control=_spring(k, c), solver=solver,
            rtol=STIFF_RTOL, atol=STIFF_ATOL, saveat_ts=jnp.linspace(0.0, t1, 11), max_steps=STIFF_MAX_STEPS,
            throw=False))
    return _RUNS[solver]


@pytest.fixture(scope="module")
def stiff_runs(slider):
    return {s: _slider_run(slider, s)(STIFFNESS, HEAVY_DAMPING, STIFF_T1) for s in ("tsit5", "kvaerno5")}


@pytest.mark.parametrize("solver", ["tsit5", "kvaerno5"])
def test_stiff_spring_damper_matches_matrix_exponential(stiff_runs, solver):
    sol = stiff_runs[solver]
    exact = _exact(STIFFNESS, HEAVY_DAMPING, np.asarray(sol.ts))
    assert bool(sol.ok) and np.all(np.isfinite(sol.q)) and np.all(np.isfinite(sol.qd))
    err_q = np.abs(np.asarray(sol.q[:, 0]) - exact[:, 0]).max() / X0
    print(f"\n{solver}: {int(sol.steps)} steps, {int(sol.rejected)} rejected, max |x - exact| / x0 = {err_q:.2e}")
    assert err_q <= STIFF_SOLUTION_RTOL


def test_stiff_spring_damper_explicit_steps_are_stability_bound(stiff_runs):
    lam_fast = abs(min(np.linalg.eigvals(np.array([[0.0, 1.0], [-STIFFNESS, -HEAVY_DAMPING]])).real))
    radius = _real_stability_interval(diffrax.Tsit5.tableau)
    bound = STIFF_T1 * lam_fast / radius  # steps needed to stay stable on the fast mode
    assert all(bool(r.ok) for r in stiff_runs.values())
    n_explicit, n_implicit = int(stiff_runs["tsit5"].steps), int(stiff_runs["kvaerno5"].steps)
    print(f"\n|lambda_fast| = {lam_fast:.6g} 1/s, Tsit5 real stability interval {radius:.4f}, stability bound "
          f"{bound:.0f} steps; tsit5 {n_explicit} steps, kvaerno5 {n_implicit} steps")
    assert 3.0 < radius < 4.0  # the stability function is computed from the tableau, not assumed
    assert n_explicit >= bound  # the explicit solver cannot step past its stability limit
    assert n_implicit * STIFF_STEP_RATIO < n_explicit


def test_stiff_spring_damper_small_step_budget_is_reported(slider):
    # Over 3 s the explicit solver would need ~85 000 steps (stability bound), over its budget of STIFF_MAX_STEPS:
    # the run must say so (simulate(throw=True) raises instead; tested in test_simulate.py).
    sol = _slider_run(slider, "tsit5")(STIFFNESS, HEAVY_DAMPING, 3.0)
    assert not bool(sol.ok) and sol.status == diffrax.RESULTS.max_steps_reached
    assert np.all(np.isnan(sol.q)) and np.all(np.isnan(sol.qd))  # nothing that looks like a valid trajectory


@pytest.mark.parametrize("solver", ["tsit5", "kvaerno5"])
def test_stiff_undamped_spring_keeps_energy(slider, solver):
    # Not stiff in the stability sense (eigenvalues +-3162i): both solvers must resolve the oscillation.
    sol = _slider_run(slider, solver)(STIFFNESS, 0.0, OSC_T1)
    exact = _exact(STIFFNESS, 0.0, np.asarray(sol.ts))
    energy = 0.5 * np.asarray(sol.qd[:, 0]) ** 2 + 0.5 * STIFFNESS * np.asarray(sol.q[:, 0]) ** 2
    e0 = 0.5 * STIFFNESS * X0**2
    err = np.abs(np.asarray(sol.q[:, 0]) - exact[:, 0]).max() / X0
    drift = np.abs(energy - e0).max() / e0
    print(f"\n{solver}: {int(sol.steps)} steps, max |x - exact| / x0 = {err:.2e}, energy drift {drift:.2e}")
    assert bool(sol.ok) and np.all(np.isfinite(sol.q))
    assert err <= STIFF_SOLUTION_RTOL and drift <= OSC_ENERGY_RTOL


# ---------------------------------------------------------------------------------------------------------------
# 2. Near-coplanar / near-collinear primary particles
# ---------------------------------------------------------------------------------------------------------------

EPS64 = np.finfo(np.float64).eps
#: Reproduction error of mass, first moment and inertia (relative) <= this factor x kappa^2 x eps, kappa the ratio of
#: the largest to the smallest singular value of the primaries' edge vectors (particle masses grow like kappa^2).
COND_ERROR_FACTOR = 1.0
#: The worst accepted placement (kappa just below 1 / PLACEMENT_RTOL) is still reproduced to this.
ACCEPTED_WORST_RTOL = 1e-5
BODY = RigidInertia(2.0, [0.1, -0.05, 0.2], [[0.30, 0.02, -0.01], [0.02, 0.20, 0.03], [-0.01, 0.03, 0.12]])
PLATE = RigidInertia(1.0, [0.0, 0.0, 0.0], np.diag([0.01, 0.05, 0.06]), degenerate_ok=True)  # mass in z = 0
DELTAS = [1e-1, 1e-2, 1e-3, 1e-4, 3e-5, 2e-5, 1e-5, 1e-6, 1e-8, 1e-10, 0.0]


def _placement(kind, delta):
    """Primaries with the last one ``delta`` off the plane (spatial) / line (planar) of the others."""
    if kind == "planar":
        return np.array([[0.5, 0.0, 0.0], [-0.5, 0.0, 0.0], [0.1, delta, 0.0]])
    base = np.array([[0.6, 0.0, 0.0], [-0.4, 0.5, 0.1], [-0.3, -0.5, 0.05]])
    n = np.cross(base[1] - base[0], base[2] - base[0])
    n /= np.linalg.norm(n)
    p = base.mean(0) + np.array([0.1, 0.05, 0.0])
    p = p - n * np.dot(p - base[0], n) + delta * n
    return np.vstack([base, p])


def _reproduction_error(ps, body):
    m = float(body.mass)
    mc = np.asarray(body.mass * body.com)
    i_o = np.asarray(body.about(np.zeros(3)))
    return max(abs(float(ps.total_mass()) - m) / m,
               np.abs(np.asarray(ps.first_moment()) - mc).max() / max(np.abs(mc).max(), m),
               np.abs(np.asarray(ps.inertia_about_origin()) - i_o).max() / np.abs(i_o).max())


@pytest.mark.parametrize("kind", ["spatial", "planar"])
def test_near_singular_placements_are_accurate_or_refused(kind):
    body = BODY if kind == "spatial" else PLATE
    rows = []
    for delta in DELTAS:
        prim = _placement(kind, delta)
        sv = np.linalg.svd(prim[1:] - prim[0], compute_uv=False)
        kappa = sv[0] / sv[-1] if sv[-1] > 0 else np.inf
        if kappa * PLACEMENT_RTOL >= 1.0:
            with pytest.raises(PlacementError, match=f"near_{kind}: .*(coplanar|collinear) or nearly so"):
                equivalent_particles(body, prim, name=f"near_{kind}", on_negative="ignore")
            rows.append(f"delta {delta:.0e}: kappa {kappa:.1e} refused")
            continue
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            ps = equivalent_particles(body, prim, name=f"near_{kind}", on_negative="ignore")
        err = _reproduction_error(ps, body)
        rows.append(f"delta {delta:.0e}: kappa {kappa:.1e} error {err:.1e} (bound {kappa**2 * EPS64:.1e})")
        assert np.all(np.isfinite(np.asarray(ps.masses)))
        assert err <= COND_ERROR_FACTOR * kappa**2 * EPS64 and err <= ACCEPTED_WORST_RTOL
    print("\n" + "\n".join(rows))
    assert any("refused" in r for r in rows) and not all("refused" in r for r in rows)


def test_placements_beyond_the_threshold_would_give_garbage():
    # Why the threshold is where it is: the unchecked mass solve at kappa ~ 5e7 (which a threshold of 1e-8 would
    # accept) loses over 1 % of the inertia; the checked entry point refuses it.
    from particlesim.particles import ParticleSet, solve_particle_masses

    prim = _placement("spatial", 3e-8)
    masses = solve_particle_masses(BODY.mass, BODY.com, BODY.inertia, prim)
    err = _reproduction_error(ParticleSet(primaries=jnp.asarray(prim), masses=masses, kind="spatial"), BODY)
    print(f"\nunchecked solve at delta 3e-8: reproduction error {err:.2e}")
    assert err > 1e-2
    with pytest.raises(PlacementError, match="wheel: the 4 primary particles are coplanar or nearly so"):
        equivalent_particles(BODY, prim, name="wheel")


# ---------------------------------------------------------------------------------------------------------------
# 3. float32 against float64
# ---------------------------------------------------------------------------------------------------------------
# ``import particlesim`` turns x64 on; ``jax.enable_x64(False)`` runs a block in float32 (models must be built
# inside it, so that their parameters are float32). simulate() takes the default float type of the mode.

EPS32 = float(np.finfo(np.float32).eps)
#: Forward dynamics at random states: max |qdd32 - qdd64| / max |qdd64| <= this factor x cond(A) x eps32.
F32_ACC_FACTOR = 1.0
#: 1 s rollout of the hanging Krang (Tsit5, rtol = atol = 1e-6 in both precisions) against a float64 Tsit5
#: reference at 1e-12: largest joint-angle error [rad]. The float32 figure depends on the CPU's rounding (fused
#: multiply-adds, vector width): 1.1e-3 rad on one machine, 1.6e-2 rad on another with the same code, on a
#: trajectory whose mass matrix reaches cond(A) = 4.9e4 and whose accelerations reach 620 rad/s^2. The bound guards
#: against a failed float32 rollout (off by more than about 3 degrees), not one CPU's round-off.
F32_ROLLOUT_ATOL = 5e-2
F64_ROLLOUT_ATOL = 1e-3  # the same run in float64: the truncation error alone
F32_RTOL = 1e-6


def _hanging_krang_start(model):
    q0 = np.random.default_rng(2).uniform(-0.2, 0.2, model.nq)
    q0[0] += np.pi  # JLWheel: the body hangs below the wheel axis
    return q0


def test_float32_forward_dynamics_error_is_bounded():
    m64 = krang_urdf()
    rng = np.random.default_rng(0)
    qs, qds = rng.uniform(-2.0, 2.0, (16, m64.nq)), rng.normal(size=(16, m64.nq))
    fd = jax.vmap(forward_dynamics, in_axes=(None, 0, 0, 0))
    a64 = np.asarray(jax.jit(fd)(m64, qs, qds, np.zeros_like(qs)))
    with jax.enable_x64(False):
        m32 = krang_urdf()
        a32 = jax.jit(fd)(m32, jnp.asarray(qs, jnp.float32), jnp.asarray(qds, jnp.float32),
                          jnp.zeros(qs.shape, jnp.float32))
        assert a32.dtype == jnp.float32
    a32 = np.asarray(a32, dtype=np.float64)
    cond = np.linalg.cond(np.asarray(jax.jit(jax.vmap(mass_matrix, in_axes=(None, 0)))(m64, qs)))
    rel = np.abs(a32 - a64).max(axis=1) / np.abs(a64).max(axis=1)
    print(f"\nfloat32 forward dynamics, 16 states: relative error max {rel.max():.2e}, median {np.median(rel):.2e} "
          f"(cond(A) up to {cond.max():.1e}, cond x eps32 up to {cond.max() * EPS32:.1e})")
    assert np.all(np.isfinite(a32)) and np.all(rel <= F32_ACC_FACTOR * cond * EPS32)


def test_float32_rollout_error_is_bounded():
    m64 = krang_urdf()
    q0 = _hanging_krang_start(m64)
    ts = np.linspace(0.0, 1.0, 11)

    @jax.jit
    def run(model, q, tol):  # tolerances traced: the reference and the run share one compilation per precision
        return simulate(forward_dynamics, model, q, jnp.zeros_like(q), 0.0, 1.0, solver="tsit5", rtol=tol,
                        atol=tol, saveat_ts=jnp.asarray(ts, q.dtype), max_steps=4096)

    ref = run(m64, jnp.asarray(q0), 1e-12)
    r64 = run(m64, jnp.asarray(q0), F32_RTOL)
    with jax.enable_x64(False):
        r32 = run(krang_urdf(), jnp.asarray(q0, jnp.float32), jnp.float32(F32_RTOL))
        assert r32.q.dtype == jnp.float32
    err32 = np.abs(np.asarray(r32.q, np.float64) - np.asarray(ref.q)).max()
    err64 = np.abs(np.asarray(r64.q) - np.asarray(ref.q)).max()
    print(f"\n1 s hanging Krang, tsit5 rtol {F32_RTOL:g}: float32 error {err32:.2e} rad ({int(r32.steps)} steps, "
          f"{int(r32.rejected)} rejected), float64 error {err64:.2e} rad ({int(r64.steps)} steps)")
    assert bool(r32.ok) and np.all(np.isfinite(np.asarray(r32.q)))
    assert err32 <= F32_ROLLOUT_ATOL and err64 <= F64_ROLLOUT_ATOL
