"""Mechanism identification from traces on a mechanism built through the public API: the README's planar four-bar
with a spring, its spring constants and coupler mass from noisy crank angles of two runs (the second with a known
extra 1 kg on the rocker, a constant that is not fitted)."""

import jax.numpy as jnp
import numpy as np
import pytest

from particlesim.identify import fit_traces, trace_model
from particlesim.mechanism import MechanismBuilder, body_angles

TRUE = np.array([80.0, 0.5, 2.0])  # spring stiffness N/m, damping N s/m, coupler mass kg
STARTS = TRUE * np.array([[1.2, 0.8, 0.8], [0.8, 1.3, 1.2]])
NOISE_SIGMA = 1e-4  # rad
NOISE_BOUND_SIGMAS = 3.0


def _four_bar():
    mb = MechanismBuilder(planar=True)
    mb.ground("O", (0.0, 0.0)); mb.ground("C", (2.2, 0.0))
    mb.particle("A", (0.0, 1.0)); mb.particle("B", (1.866, 1.5)); mb.particle("B'", (1.8661, 1.4999))
    mb.rod("crank", "O", "A", mass=1.0)
    mb.rod("coupler", "A", "B", mass=2.0)
    mb.rod("rocker", "C", "B'", mass=1.5)
    mb.cut_joint("B", "B'")
    mb.spring_damper("spring", "A", "C", stiffness=80.0, damping=0.5, free_length=2.0)
    return mb.build(dof=1, assemble=True)


@pytest.mark.slow
def test_four_bar_spring_and_mass_from_crank_angles():
    mech, x0 = _four_bar()
    params = {"k": ("spring", "spring", "stiffness"), "c": ("spring", "spring", "damping"),
              "m_coupler": ("body", "coupler", "mass")}
    model = trace_model(mech, x0, np.linspace(0.0, 2.0, 101), params, lambda m, x: body_angles(m, x)[0],
                        runs=[{}, {("body", "rocker", "mass"): 1.0}])
    assert model.output_shape == (2, 101)
    y = np.asarray(model.outputs(jnp.asarray(TRUE[None])))
    assert np.all(np.ptp(y[0], axis=1) > 0.5)  # the crank swings (~1 rad) in both runs
    assert np.max(np.abs(y[0, 1] - y[0, 0])) > 10 * NOISE_SIGMA  # the extra rocker mass changes the motion
    noisy = y[0] + NOISE_SIGMA * np.random.default_rng(0).standard_normal(y[0].shape)
    fit = fit_traces(model, noisy, STARTS, sigma=NOISE_SIGMA)
    rel = np.abs(fit.p / TRUE - 1)
    print(f"\n  relative errors {rel}, standard errors {fit.rel_std}, {fit.evaluations} evaluations")
    assert fit.converged.any()
    assert np.all(rel < NOISE_BOUND_SIGMAS * fit.rel_std), (rel, fit.rel_std)
    assert np.all(fit.rel_std < 1e-3)  # the data pin each constant to 0.1 %
    assert abs(fit.rms / NOISE_SIGMA - 1) < 0.2


def test_trace_model_refuses_unknown_paths_and_bad_runs():
    mech, x0 = _four_bar()
    observe = lambda m, x: body_angles(m, x)[0]  # noqa: E731
    with pytest.raises(ValueError, match="no spring named 'sprung'"):
        trace_model(mech, x0, [0.0, 1.0], {"k": ("spring", "sprung", "stiffness")}, observe)
    with pytest.raises(ValueError, match="has no parameter 'stifness'"):
        trace_model(mech, x0, [0.0, 1.0], {"k": ("spring", "spring", "stifness")}, observe)
    with pytest.raises(ValueError, match="group must be one of"):
        trace_model(mech, x0, [0.0, 1.0], {"k": ("springs", "spring", "stiffness")}, observe)
    with pytest.raises(ValueError, match="at least one run"):
        trace_model(mech, x0, [0.0, 1.0], {"k": ("spring", "spring", "stiffness")}, observe, runs=[])
    with pytest.raises(ValueError, match="finite"):
        trace_model(mech, x0, [0.0, 1.0], {"k": ("spring", "spring", "stiffness")}, observe,
                    runs=[{("body", "rocker", "mass"): np.nan}])


def _toy_model(jac_fails):
    """A two-constant exponential-decay TraceModel in plain numpy (no rollout): y = p0 exp(-p1 t). Its Jacobian is
    NaN wherever ``jac_fails(log_p)`` holds (as a difference Jacobian is when one perturbed rollout fails)."""
    from particlesim.identify.traces import TraceModel

    ts = np.linspace(0.0, 2.0, 21)

    def outputs(p):
        p = np.asarray(p)
        return (p[:, :1] * np.exp(-p[:, 1:] * ts[None]))[:, None]

    def residual_jacobian(lp, y):
        lp = np.asarray(lp)
        p = np.exp(lp)
        e = np.exp(-p[:, 1:] * ts[None])
        r = p[:, :1] * e - np.asarray(y)[0][None]
        jac = np.stack([p[:, :1] * e, -p[:, :1] * p[:, 1:] * ts[None] * e], axis=2)
        jac[np.array([bool(jac_fails(x)) for x in lp])] = np.nan
        return r, jac

    return TraceModel(("a", "k"), ts, 1, (1, ts.size), outputs, residual_jacobian)


def test_fit_shortens_a_step_onto_a_non_finite_jacobian_and_names_a_failing_start():
    """A Gauss-Newton step whose Jacobian is not finite (a failed rollout among a difference Jacobian's, found in
    the quarter-car identification benchmark, where it had reached a least-squares solve and raised LinAlgError) is
    shortened like an uphill step; a start whose Jacobian is not finite is refused, naming it."""
    true = np.array([2.0, 1.5])
    y = _toy_model(lambda lp: False).outputs(true[None])[0]
    start = np.array([[1.0, 0.5]])
    clean = fit_traces(_toy_model(lambda lp: False), y, start)
    # the first full step from this start lands beyond k = 1.0; a Jacobian there fails
    fails = _toy_model(lambda lp: np.exp(lp[1]) > 1.0 and np.exp(lp[1]) < 1.45)
    fit = fit_traces(fails, y, start)
    np.testing.assert_allclose(fit.p, true, rtol=1e-8)
    assert fit.evaluations > clean.evaluations  # the failed point was met and stepped around
    with pytest.raises(ValueError, match=r"not finite at starts \[0\]"):
        fit_traces(_toy_model(lambda lp: True), y, start)
