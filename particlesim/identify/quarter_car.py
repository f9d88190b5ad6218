"""Quarter-car identification: spring stiffness and damping and tyre stiffness from a chassis-height trace.

The trace is the free response of :func:`particlesim.scenes.quarter_car.quarter_car` from rest in its assembly
configuration (assumption A6: spring and tyre unloaded), which settles under gravity: the static sag fixes the
series stiffness ``(1/k_s + 1/k_t)^-1`` (through the suspension's motion ratio), the sprung-mass mode (~1.5 Hz)
fixes ``k_s`` and ``c_s`` and the wheel-hop mode (~16 Hz, strongly damped by ``c_s``) separates ``k_t``. The
model parameters are replaced in the built mechanism by name (``Mechanism.with_params``; one compile serves every
value).

Fit: Gauss–Newton in ``log p`` on ``z_model(t_k; p) - z_meas(t_k)`` with a backtracking step. The Jacobian is
taken by forward differences of the same compiled rollout, vmapped over the ``P + 1`` parameter sets (a forward
sensitivity pass through the projected mechanism solver compiles ~4x slower than the rollout itself on CPU);
its error only slows convergence (linear, rate ~ step size), the fixed point is that of the exact residual.
The Gauss–Newton covariance ``sigma^2 (J^T J)^-1`` at the optimum gives the noise-implied standard errors.
"""

from __future__ import annotations

from typing import NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["PARAMETERS", "QuarterCarFit", "chassis_trace_fn", "fit_quarter_car"]

#: Fitted constants, in order (the last is optional: ``fit_tyre_damping``).
PARAMETERS = ("spring_stiffness", "spring_damping", "tyre_stiffness", "tyre_damping")


def _with(mech, p):
    names = (("spring", "suspension", "stiffness"), ("spring", "suspension", "damping"),
             ("tyre", "tyre", "stiffness"), ("tyre", "tyre", "damping"))
    values: dict = {"spring": {"suspension": {}}, "tyre": {"tyre": {}}}
    for (group, name, field), v in zip(names, p):
        values[group][name][field] = v
    return mech.with_params(**values)


def chassis_trace_fn(ts, *, mech=None, x0=None, rtol: float = 1e-9, atol: float = 1e-11, solver: str = "dopri5"):
    """A jitted ``p (B, P) -> z (B, T)``: chassis height (point ``centre``, m) at ``ts`` for each row of
    constants ``p`` (``P`` = 3 or 4 leading entries of :data:`PARAMETERS`), free response from rest."""
    from ..mechanism import simulate_mechanism
    from ..scenes.quarter_car import quarter_car

    if mech is None:
        mech, x0 = quarter_car()
    ts = np.asarray(ts, dtype=float)
    t0, t1 = float(ts[0]), float(ts[-1])
    k = mech.point_index("centre")

    def one(p):
        m = _with(mech, p)
        sol = simulate_mechanism(m, x0, jnp.zeros_like(x0), t0, t1, solver=solver, rtol=rtol,
                                 atol=atol, saveat_ts=ts)
        return jax.vmap(lambda x: m.point_positions(m.all_positions(x))[k, 2])(sol.q)

    return jax.jit(jax.vmap(one))


class QuarterCarFit(NamedTuple):
    """Fitted constants ``p (P,)``, their standard errors relative to ``p`` (``sigma^2 (J^T J)^-1`` in log
    coordinates, ``nan`` without ``sigma``), RMS residual (m), Gauss–Newton steps and the history of costs."""

    p: np.ndarray
    rel_std: np.ndarray
    rms: float
    steps: int
    costs: list


def fit_quarter_car(trace, z_meas, p0, *, sigma: Optional[float] = None, max_steps: int = 12,
                    fd_step: float = 1e-5, xtol: float = 1e-10, verbose: bool = False) -> QuarterCarFit:
    """Gauss–Newton in ``log p`` from ``p0`` (module docstring); ``trace`` from :func:`chassis_trace_fn`.

    Stops when the relative step in every constant is below ``xtol`` or after ``max_steps``. ``sigma``: the
    measurement noise standard deviation (m) for the covariance.
    """
    z_meas = np.asarray(z_meas, dtype=float)
    logp = np.log(np.asarray(p0, dtype=float))
    npar = logp.size
    eye = np.eye(npar)

    def evaluate(lp):
        batch = np.exp(np.concatenate([lp[None], lp[None] + fd_step * eye]))
        z = np.asarray(trace(jnp.asarray(batch)))
        return z[0] - z_meas, (z[1:] - z[0]).T / fd_step

    r, jac = evaluate(logp)
    costs = [float(r @ r)]
    steps = 0
    for steps in range(1, max_steps + 1):
        scale = np.linalg.norm(jac, axis=0)
        delta = -np.linalg.lstsq(jac / scale, r, rcond=None)[0] / scale
        a = 1.0
        while True:
            r_new, jac_new = evaluate(logp + a * delta)
            if np.all(np.isfinite(r_new)) and r_new @ r_new <= costs[-1] or a < 1e-3:
                break
            a /= 4
        logp, r, jac = logp + a * delta, r_new, jac_new
        costs.append(float(r @ r))
        if verbose:
            print(f"  GN step {steps}: p = {np.exp(logp)}, RMS {np.sqrt(costs[-1] / r.size):.3e} m, a = {a}")
        if np.max(np.abs(a * delta)) < xtol:
            break
    rel_std = np.full(npar, np.nan)
    if sigma is not None:
        rel_std = sigma * np.sqrt(np.diag(np.linalg.inv(jac.T @ jac)))  # std of log p = relative std of p
    return QuarterCarFit(np.exp(logp), rel_std, float(np.sqrt(costs[-1] / r.size)), steps, costs)
