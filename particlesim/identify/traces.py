"""Identify mechanism parameters from measured traces, by autodiff through the rollouts.

A :class:`TraceModel` maps named mechanism constants (``(group, element, field)`` paths of
:meth:`~particlesim.mechanism.Mechanism.with_params`, e.g. ``("spring", "suspension", "stiffness")``) to what is
measured along one or several runs: ``observe(mech, q)`` at the sample times ``ts`` of each run, the runs differing
by known changes (a payload, a stiffer spring) added to the constants. :func:`fit_traces` is Gauss–Newton in ``log
p`` on the stacked residuals with step shortening (by 4) when the cost does not decrease; residuals and their
Jacobian come from one compiled forward-mode pass through the rollouts (``jax.jacfwd`` through diffrax with
``adjoint="forward"``), vmapped over the starts, so several starts cost one compile and run side by side. A trial
rollout that fails is NaN and its step is shortened. The Gauss–Newton covariance ``sigma^2 (J^T J)^-1`` at the
optimum (in ``log p``, hence relative) gives the noise-implied standard errors.

Not every set of constants is identifiable from every experiment: a free response scales with masses, stiffnesses
and dampers together, so masses need a second run with a known change of mass. A singular ``J^T J`` shows as
infinite or huge standard errors.
"""

from __future__ import annotations

from typing import Callable, Mapping, NamedTuple, Optional, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from .. import _ode, _xla

__all__ = ["TraceModel", "TraceFit", "trace_model", "fit_traces"]

_GROUPS = {"body": "body_names", "spring": "spring_names", "tyre": "tyre_names", "rotational": "rotational_names",
           "bushing": "bushing_names", "torsion": "torsion_names", "bump": "bump_names"}


class TraceModel(NamedTuple):
    """Compiled measurement model, from :func:`trace_model`.

    ``outputs(p (B, P)) -> y (B, R, T, ...)``: what ``observe`` returns at each of the ``T`` sample times of each of
    the ``R`` runs, for each row of constants (ordered as ``names``). ``residual_jacobian(log_p (B, P), y_meas (R,
    T, ...)) -> (r (B, M), J (B, M, P))``: residuals and their forward-mode Jacobian in ``log p``. Both are jitted
    once; new values, starts and data reuse them."""

    names: tuple
    ts: np.ndarray
    n_runs: int
    output_shape: tuple
    outputs: Callable
    residual_jacobian: Callable


def _current(mech, path):
    group, element, field = path
    if group not in _GROUPS:
        raise ValueError(f"parameter path {path}: group must be one of {list(_GROUPS)}")
    names = getattr(mech.topo, _GROUPS[group])
    if element not in names:
        raise ValueError(f"parameter path {path}: no {group} named {element!r}; {group}s: {list(names)}")
    if not hasattr(mech, f"{group}_{field}"):
        raise ValueError(f"parameter path {path}: a {group} has no parameter {field!r}")
    return getattr(mech, f"{group}_{field}")[names.index(element)]


def trace_model(mech, q0, ts, params: Mapping[str, tuple], observe: Callable, *,
                runs: Sequence[Mapping[tuple, float]] = ({},), qd0=None, solver: str = "dopri8",
                rtol: float = 1e-7, atol: float = 1e-9, events: bool = False, stabilise: bool = False
                ) -> TraceModel:
    """The measurement model of ``mech`` released from ``(q0, qd0)`` (``qd0`` default zero) at ``ts[0]``.

    ``params``: the free constants, ``{label: (group, element, field)}``; the others keep the mechanism's values.
    ``observe(mech, q)``: the measured quantity at particle positions ``q`` (any shape; the mechanism passed is
    the one with the run's constants). ``runs``: one mapping per run, ``{(group, element, field): known change}``
    added to that constant (fitted or not), e.g. ``[{}, {("body", "chassis", "mass"): 100.0}]``; a negative change
    that makes a constant non-physical for some trial value (a mass removed beyond the fitted one) stops the fit with
    :func:`~particlesim.mechanism.simulate_mechanism`'s run-time error naming it. ``solver``,
    ``rtol``, ``atol``, ``events``, ``stabilise`` as in :func:`~particlesim.mechanism.simulate_mechanism` (the
    defaults suit a few seconds of a smooth response measured to ~1e-6; a mechanism with tyres that lift off
    needs ``events=True`` for exact derivatives).

    Raises ``ValueError`` for no or unknown parameters, fewer than two increasing sample times, no runs or a
    non-finite change.
    """
    from ..mechanism import simulate_mechanism

    names = tuple(params)
    paths = [tuple(params[n]) for n in names]
    if not names or len(set(paths)) != len(paths):
        raise ValueError(f"params must name distinct parameter paths; got {dict(params)}")
    for path in paths:
        _current(mech, path)
    ts = np.asarray(ts, dtype=float)
    if ts.ndim != 1 or ts.size < 2 or not np.all(np.diff(ts) > 0):
        raise ValueError(f"ts must be increasing sample times, at least two; got shape {ts.shape}")
    runs = [dict(r) for r in runs]
    if not runs:
        raise ValueError("runs must hold at least one run (use [{}] for one run without changes)")
    changed = sorted({tuple(p) for r in runs for p in r})
    for path in changed:
        _current(mech, path)
    offsets = np.array([[r.get(p, 0.0) for p in changed] for r in runs], dtype=float).reshape(len(runs), -1)
    if not np.all(np.isfinite(offsets)):
        raise ValueError(f"run changes must be finite; got {runs}")
    qd0 = jnp.zeros_like(q0) if qd0 is None else jnp.asarray(qd0)
    t0, t1 = float(ts[0]), float(ts[-1])

    def run(p, offset):
        values = {path: v for path, v in zip(paths, p)}
        for path, d in zip(changed, offset):
            values[path] = values.get(path, _current(mech, path)) + d
        nested: dict = {}
        for (group, element, field), v in values.items():
            nested.setdefault(group, {}).setdefault(element, {})[field] = v
        m = mech.with_params(**nested)
        sol = simulate_mechanism(m, q0, qd0, t0, t1, solver=solver, rtol=rtol, atol=atol, saveat_ts=ts,
                                 adjoint="forward", events=events, stabilise=stabilise,
                                 throw=False)  # a failed trial run is NaN: the fit shortens that step
        return jax.vmap(lambda q: jnp.asarray(observe(m, q)))(sol.q)

    def all_runs(p):  # (P,) -> (R, T, ...)
        return jax.vmap(run, in_axes=(None, 0))(p, jnp.asarray(offsets))

    def residual(log_p, y_meas):
        r = (all_runs(jnp.exp(log_p)) - y_meas).ravel()
        return r, r

    shape = (len(runs), ts.size) + jax.eval_shape(lambda q: jnp.asarray(observe(mech, q)), q0).shape
    outputs = _xla.TopJit(jax.vmap(all_runs))
    def residual_jacobian(log_p, y_meas):  # (B, P) starts at once
        _ode.TRACES["trace_model residual_jacobian"] += 1  # at trace time only: the compile-once tests read it
        return jax.vmap(lambda lp, y: jax.jacfwd(residual, has_aux=True)(lp, y)[::-1],
                        in_axes=(0, None))(log_p, y_meas)

    residual_jacobian = _xla.TopJit(residual_jacobian)
    return TraceModel(names, ts, len(runs), tuple(shape), outputs, residual_jacobian)


class TraceFit(NamedTuple):
    """Result of :func:`fit_traces`: best constants ``p (P,)`` (ordered as the model's ``names``), their standard
    errors relative to ``p`` (``sigma^2 (J^T J)^-1`` in log coordinates; ``nan`` without ``sigma``), RMS residual;
    per start the constants reached ``p_starts (S, P)``, costs, accepted steps and whether it converged; the
    number of residual-and-Jacobian evaluations (each covers every start) and the best start's history of
    costs."""

    p: np.ndarray
    rel_std: np.ndarray
    rms: float
    p_starts: np.ndarray
    cost_starts: np.ndarray
    steps: np.ndarray
    converged: np.ndarray
    evaluations: int
    costs: list


def _gauss_newton_step(r, jac, xtol, stol):
    """Column-scaled Gauss–Newton step and whether it is negligible: below ``xtol`` in every coordinate, or below
    ``stol`` times every coordinate's standard error (noise estimated from the residual)."""
    scale = np.linalg.norm(jac, axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    delta = -np.linalg.lstsq(jac / scale, r, rcond=None)[0] / scale
    dof = max(r.size - delta.size, 1)
    std = np.sqrt(r @ r / dof * np.diag(np.linalg.pinv(jac.T @ jac)))
    return delta, bool(np.all(np.abs(delta) < xtol) or np.all(np.abs(delta) < stol * std))


def fit_traces(model: TraceModel, y_meas, starts, *, sigma: Optional[float] = None, max_evaluations: int = 30,
               xtol: float = 1e-9, stol: float = 1e-2, verbose: bool = False) -> TraceFit:
    """Gauss–Newton in ``log p`` (module docstring) from every row of ``starts (S, P)`` at once.

    ``y_meas``: the measurements, shaped as ``model.output_shape`` (runs, samples, ...). A start has converged
    when its next Gauss–Newton step is negligible: below ``stol`` standard errors of every constant (noise
    estimated from its residual: the data cannot resolve finer) or below ``xtol`` in every ``log p``. A start
    whose step shortening falls below 1e-3 stops unconverged. ``sigma``: the measurement noise standard deviation,
    for the standard errors; given it, the fit also ends as soon as a converged start's residual is at the noise
    floor (sum of squares within three chi-square standard deviations of ``sigma^2 (M - P)``): no other minimum
    can fit better than the noise. At most ``max_evaluations`` evaluations. A step to constants where the residual
    or its Jacobian is not finite is shortened as an uphill one. Raises ``ValueError`` for wrong shapes,
    non-positive or non-finite starts or data, or a start whose rollout or Jacobian is not finite.
    """
    y_meas = np.asarray(y_meas, dtype=float)
    if y_meas.shape != model.output_shape or not np.all(np.isfinite(y_meas)):
        raise ValueError(f"measurements must be finite of shape {model.output_shape} (runs, samples, ...); "
                         f"got {y_meas.shape}")
    starts = np.atleast_2d(np.asarray(starts, dtype=float))
    if starts.ndim != 2 or starts.shape[1] != len(model.names) or not np.all(np.isfinite(starts)) \
            or np.any(starts <= 0):
        raise ValueError(f"starts must be positive, finite, shape (S, {len(model.names)}) for {list(model.names)}; "
                         f"got shape {starts.shape}")
    if sigma is not None and not (np.isfinite(sigma) and sigma > 0):
        raise ValueError(f"sigma must be a positive noise standard deviation; got {sigma}")
    y_j = jnp.asarray(y_meas)

    def evaluate(lp):
        """Residuals, Jacobians and costs; a point whose residual or Jacobian is not finite (a failed rollout, or a
        failed one among a difference Jacobian's) costs ``inf``, so a step onto it is shortened like one uphill."""
        r, jac = model.residual_jacobian(jnp.asarray(lp), y_j)
        r, jac = np.array(r), np.array(jac)
        cost = np.einsum("sm,sm->s", r, r)
        ok = np.isfinite(cost) & np.isfinite(jac).all(axis=(1, 2))
        return r, jac, np.where(ok, cost, np.inf)

    lp = np.log(starts)
    r, jac, cost = evaluate(lp)
    if not np.all(np.isfinite(cost)):
        raise ValueError(f"the rollout or its Jacobian is not finite at starts "
                         f"{np.flatnonzero(~np.isfinite(cost)).tolist()}: {starts[~np.isfinite(cost)].tolist()}")
    n_start, n_par = lp.shape
    dof = max(r.shape[1] - n_par, 1)
    floor = np.inf if sigma is None else sigma**2 * (dof + 3 * np.sqrt(2 * dof))
    delta, converged = map(np.array, zip(*(_gauss_newton_step(r[s], jac[s], xtol, stol) for s in range(n_start))))
    stalled = np.zeros(n_start, dtype=bool)
    a = np.ones(n_start)
    steps = np.zeros(n_start, dtype=int)
    history = [[c] for c in cost]
    evaluations = 1

    def finished():
        return np.all(converged | stalled) or np.any(converged & (cost <= floor))

    while not finished() and evaluations < max_evaluations:
        active = ~(converged | stalled)
        cand = np.where(active[:, None], lp + a[:, None] * delta, lp)
        r_c, jac_c, cost_c = evaluate(cand)
        evaluations += 1
        for s in np.flatnonzero(active):
            if cost_c[s] <= cost[s]:
                lp[s], r[s], jac[s], cost[s] = cand[s], r_c[s], jac_c[s], cost_c[s]
                delta[s], converged[s] = _gauss_newton_step(r[s], jac[s], xtol, stol)
                a[s], steps[s] = 1.0, steps[s] + 1
                history[s].append(cost[s])
            else:
                a[s] /= 4
                stalled[s] = a[s] < 1e-3
        if verbose:
            print(f"  evaluation {evaluations}: RMS {np.sqrt(cost / r.shape[1])}, step {a}, converged {converged}")
    best = int(np.argmin(cost))
    rel_std = np.full(n_par, np.nan)
    if sigma is not None:
        rel_std = sigma * np.sqrt(np.diag(np.linalg.pinv(jac[best].T @ jac[best])))  # std of log p = relative
    return TraceFit(np.exp(lp[best]), rel_std, float(np.sqrt(cost[best] / r.shape[1])), np.exp(lp), cost,
                    steps, converged, evaluations, history[best])
