"""Quarter-car identification: suspension spring and damper, tyre stiffness and masses from chassis-height traces.

The traces are free responses of :func:`particlesim.scenes.quarter_car.quarter_car` from rest in its assembly
configuration (assumption A6: spring and tyre unloaded), which settle under gravity: the static sag fixes the
series stiffness ``(1/k_s + 1/k_t)^-1`` over the sprung weight (through the suspension's motion ratio), the
sprung-mass mode (~1.5 Hz) fixes ``k_s / m`` and ``c_s / m`` and the wheel-hop mode (~16 Hz, strongly damped by
``c_s``) separates ``k_t``. One free response cannot tell the masses from the constants: scaling every mass,
stiffness and damper together leaves it unchanged (exactly so but for the small known masses of the arms and
knuckle). A second run with a known payload on the chassis breaks that symmetry, so fitting a mass needs at
least two distinct ``payloads``.

Fit: Gauss–Newton in ``log p`` on ``z_model(t_k; p) - z_meas(t_k)`` over every run, with step halving (by 4)
when the cost does not decrease. Residual and Jacobian come from one compiled forward-mode pass through the
rollout (``jax.jacfwd`` through diffrax with ``adjoint="forward"``; the tyre's contact switches located as
events so that the derivatives are those of the switching solution), vmapped over the starts: several starts
cost one compile and run side by side. The Gauss–Newton covariance ``sigma^2 (J^T J)^-1`` at the optimum (in
``log p``, so relative) gives the noise-implied standard errors.
"""

from __future__ import annotations

from typing import Callable, NamedTuple, Optional, Sequence

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["PARAMETERS", "FITTED", "ChassisTraces", "QuarterCarFit", "chassis_traces", "fit_quarter_car"]

#: Identifiable constants by name: ``(group, element, field)`` of :meth:`~particlesim.mechanism.Mechanism.with_params`.
PARAMETERS = {
    "spring_stiffness": ("spring", "suspension", "stiffness"),
    "spring_damping": ("spring", "suspension", "damping"),
    "tyre_stiffness": ("tyre", "tyre", "stiffness"),
    "tyre_damping": ("tyre", "tyre", "damping"),
    "chassis_mass": ("body", "chassis", "mass"),
    "wheel_mass": ("body", "wheel", "mass"),
}
#: What :func:`chassis_traces` fits unless told otherwise.
FITTED = ("spring_stiffness", "spring_damping", "tyre_stiffness", "chassis_mass", "wheel_mass")


class ChassisTraces(NamedTuple):
    """Compiled model of the measurement, from :func:`chassis_traces`.

    ``heights(p (B, P)) -> z (B, R, T)``: chassis height (point ``centre``, m) at ``ts`` for each row of constants
    (ordered as ``names``) and each of the ``R`` runs (one per payload). ``residual_jacobian(log_p (B, P),
    z_meas (R, T)) -> (r (B, R T), J (B, R T, P))``: residuals and their forward-mode Jacobian in ``log p``.
    Both are jitted once here; new values, starts and data reuse them."""

    names: tuple
    ts: np.ndarray
    payloads: np.ndarray
    heights: Callable
    residual_jacobian: Callable


def chassis_traces(ts, *, names: Sequence[str] = FITTED, payloads: Sequence[float] = (0.0, 100.0), mech=None,
                   x0=None, solver: str = "dopri8", rtol: float = 1e-7, atol: float = 1e-9,
                   events: bool = True, stabilise: bool = False) -> ChassisTraces:
    """The measurement model: free responses from rest of the quarter car with ``payloads`` (kg) added to the
    chassis mass, sampled at ``ts``; the constants ``names`` (keys of :data:`PARAMETERS`) are free, the rest keep
    the mechanism's values. ``mech, x0``: default :func:`~particlesim.scenes.quarter_car.quarter_car`.

    Raises ``ValueError`` for an unknown name, a repeated name, fewer than two sample times, or a mass among
    ``names`` with fewer than two distinct payloads (module docstring: the masses are then not identifiable)."""
    from ..mechanism import simulate_mechanism
    from ..scenes.quarter_car import quarter_car

    names = tuple(names)
    unknown = [n for n in names if n not in PARAMETERS]
    if unknown or not names or len(set(names)) != len(names):
        raise ValueError(f"names must be distinct keys of PARAMETERS {list(PARAMETERS)}; got {list(names)}")
    payloads = np.asarray(payloads, dtype=float).reshape(-1)
    if not np.all(np.isfinite(payloads)) or payloads.size == 0:
        raise ValueError(f"payloads must be finite masses in kg; got {payloads}")
    masses = [n for n in names if PARAMETERS[n][0] == "body"]
    if masses and np.unique(payloads).size < 2:
        raise ValueError(f"fitting {masses} needs runs with at least two distinct chassis payloads (one free "
                         f"response cannot separate masses from stiffnesses and dampers); got payloads {payloads}")
    ts = np.asarray(ts, dtype=float)
    if ts.ndim != 1 or ts.size < 2 or not np.all(np.diff(ts) > 0):
        raise ValueError(f"ts must be increasing sample times, at least two; got shape {ts.shape}")
    if mech is None:
        mech, x0 = quarter_car()
    k = mech.point_index("centre")
    chassis = mech.topo.body_names.index("chassis")
    base_chassis_mass = mech.body_mass[chassis]
    t0, t1 = float(ts[0]), float(ts[-1])
    xd0 = jnp.zeros_like(x0)

    def run(p, payload):
        values: dict = {}
        for (group, element, field), v in zip((PARAMETERS[n] for n in names), p):
            values.setdefault(group, {}).setdefault(element, {})[field] = v
        chassis_values = values.setdefault("body", {}).setdefault("chassis", {})
        chassis_values["mass"] = chassis_values.get("mass", base_chassis_mass) + payload
        m = mech.with_params(**values)
        sol = simulate_mechanism(m, x0, xd0, t0, t1, solver=solver, rtol=rtol, atol=atol, saveat_ts=ts,
                                 adjoint="forward", events=events, stabilise=stabilise,
                                 throw=False)  # a failed trial run is NaN: the fit rejects that step
        return jax.vmap(lambda x: m.point_positions(m.all_positions(x))[k, 2])(sol.q)

    def runs(p):  # (P,) -> (R, T)
        return jax.vmap(run, in_axes=(None, 0))(p, jnp.asarray(payloads))

    def residual(log_p, z_meas):
        r = (runs(jnp.exp(log_p)) - z_meas).ravel()
        return r, r

    heights = jax.jit(jax.vmap(runs))
    residual_jacobian = jax.jit(jax.vmap(lambda lp, z: jax.jacfwd(residual, has_aux=True)(lp, z)[::-1],
                                         in_axes=(0, None)))
    return ChassisTraces(names, ts, payloads, heights, residual_jacobian)


class QuarterCarFit(NamedTuple):
    """Result of :func:`fit_quarter_car`: best constants ``p (P,)`` (ordered as the model's ``names``), their
    standard errors relative to ``p`` (``sigma^2 (J^T J)^-1`` in log coordinates; ``nan`` without ``sigma``), RMS
    residual (m); per start the constants reached ``p_starts (S, P)``, costs, accepted steps and whether it
    converged; the number of residual-and-Jacobian evaluations (each covers every start) and the best start's
    history of costs."""

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


def fit_quarter_car(model: ChassisTraces, z_meas, starts, *, sigma: Optional[float] = None,
                    max_evaluations: int = 30, xtol: float = 1e-9, stol: float = 1e-2,
                    verbose: bool = False) -> QuarterCarFit:
    """Gauss–Newton in ``log p`` (module docstring) from every row of ``starts (S, P)`` at once.

    ``z_meas (R, T)``: measured chassis heights, one row per payload of ``model``. A start has converged when its
    next Gauss–Newton step is negligible: below ``stol`` standard errors of every constant (noise estimated from
    its residual: the data cannot resolve finer) or below ``xtol`` in every ``log p``. A start whose step
    halving falls below 1e-3 stops unconverged. ``sigma``: the measurement noise standard deviation (m), for the
    standard errors; given it, the fit also ends as soon as a converged start's residual is at the noise floor
    (sum of squares within three chi-square standard deviations of ``sigma^2 (M - P)``): no other minimum can
    fit better than the noise. At most ``max_evaluations`` evaluations. Raises ``ValueError`` for wrong shapes,
    non-positive or non-finite starts or data, or a start whose rollout fails.
    """
    z_meas = np.asarray(z_meas, dtype=float)
    shape = (model.payloads.size, model.ts.size)
    if z_meas.shape != shape or not np.all(np.isfinite(z_meas)):
        raise ValueError(f"z_meas must be finite of shape {shape} (runs, samples); got {z_meas.shape}")
    starts = np.atleast_2d(np.asarray(starts, dtype=float))
    if starts.ndim != 2 or starts.shape[1] != len(model.names) or not np.all(np.isfinite(starts)) \
            or np.any(starts <= 0):
        raise ValueError(f"starts must be positive, finite, shape (S, {len(model.names)}) for {list(model.names)}; "
                         f"got shape {starts.shape}")
    if sigma is not None and not (np.isfinite(sigma) and sigma > 0):
        raise ValueError(f"sigma must be a positive noise standard deviation in m; got {sigma}")
    z_j = jnp.asarray(z_meas)

    def evaluate(lp):
        r, jac = model.residual_jacobian(jnp.asarray(lp), z_j)
        r, jac = np.array(r), np.array(jac)
        cost = np.einsum("sm,sm->s", r, r)
        return r, jac, np.where(np.isfinite(cost), cost, np.inf)

    lp = np.log(starts)
    r, jac, cost = evaluate(lp)
    if not np.all(np.isfinite(cost)):
        raise ValueError(f"the rollout fails at starts {np.flatnonzero(~np.isfinite(cost)).tolist()}")
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
            print(f"  evaluation {evaluations}: RMS {np.sqrt(cost / r.shape[1])} m, step {a}, converged {converged}")
    best = int(np.argmin(cost))
    rel_std = np.full(n_par, np.nan)
    if sigma is not None:
        rel_std = sigma * np.sqrt(np.diag(np.linalg.pinv(jac[best].T @ jac[best])))  # std of log p = relative
    return QuarterCarFit(np.exp(lp[best]), rel_std, float(np.sqrt(cost[best] / r.shape[1])), np.exp(lp), cost,
                         steps, converged, evaluations, history[best])
