"""Identification through simulation: trajectory error of short rollouts from measured initial states.

Each window starts at a measured state ``(q(t_0), qd(t_0))`` and integrates the forward dynamics
``qdd = A^-1 (tau - C qd - Q - Fv qd - Fc tanh(qd / eps))`` of the model at ``theta`` with the measured torque as a
linearly interpolated control input (:func:`particlesim.simulate.simulate`, diffrax). The residual is the
position error ``q_sim(t_k) - q_meas(t_k)`` at the window's sample times, all windows stacked (vmapped). Its
Jacobian w.r.t. ``theta`` is taken through the ODE solver (forward mode for Levenberg–Marquardt).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, Float

from .. import _xla
from ..simulate import simulate
from ..tree import TreeModel, forward_dynamics
from ._fit import params_from_theta
from ._regressor import model_with_params

__all__ = ["Windows", "make_windows", "rollout_residuals", "fit_rollout"]


class Windows(NamedTuple):
    """``W`` windows of ``T`` samples: times ``ts (W, T)``, positions ``q (W, T, n)``, initial velocities
    ``qd0 (W, n)``, applied torques ``tau (W, T, n)``."""

    ts: Float[Array, "W T"]
    q: Float[Array, "W T n"]
    qd0: Float[Array, "W n"]
    tau: Float[Array, "W T n"]


def make_windows(t, q, qd, tau, *, length: int, starts) -> Windows:
    """Cut windows of ``length`` samples beginning at the row indices ``starts`` of aligned ``(N, ...)`` arrays."""
    t, q, qd, tau = (np.asarray(x) for x in (t, q, qd, tau))
    idx = np.asarray(starts)[:, None] + np.arange(length)[None, :]
    if idx.max() >= len(t):
        raise ValueError(f"window ending at row {idx.max()} exceeds the {len(t)} samples")
    return Windows(jnp.asarray(t[idx]), jnp.asarray(q[idx]), jnp.asarray(qd[idx[:, 0]]), jnp.asarray(tau[idx]))


def _one(model: TreeModel, eps, ts, q, qd0, tau, rtol, atol, solver, adjoint):
    def dynamics(m, q_, qd_, u):
        return forward_dynamics(m, q_, qd_, u, smooth_friction=eps)

    def control(t, q_, qd_, m):
        return jax.vmap(lambda col: jnp.interp(t, ts, col), in_axes=1)(tau)

    sol = simulate(dynamics, model, q[0], qd0, ts[0], ts[-1], control=control, saveat_ts=ts, rtol=rtol, atol=atol,
                   solver=solver, adjoint=adjoint, max_steps=4096)
    return sol.q[1:] - q[1:]


def rollout_residuals(theta, model: TreeModel, windows: Windows, *, eps: float, rtol: float = 1e-7,
                      atol: float = 1e-9, solver: str = "tsit5", adjoint: str = "forward") -> Float[Array, " K"]:
    """Stacked position errors (rad) of all windows for the model at unconstrained ``theta``."""
    m = model_with_params(model, params_from_theta(theta))
    err = jax.vmap(lambda ts, q, qd0, tau: _one(m, eps, ts, q, qd0, tau, rtol, atol, solver, adjoint))(*windows)
    return err.ravel()


def _show(**kwargs):
    # optimistix passes name=(label, traced value); print from inside the compiled solve.
    items = [v for k, v in kwargs.items() if k != "y" and isinstance(v, tuple) and len(v) == 2]
    jax.debug.print("  rollout LM " + " ".join(f"{label}={{}}" for label, _ in items), *[v for _, v in items])


def fit_rollout(theta0, model: TreeModel, windows: Windows, *, eps: float, max_steps: int = 20,
                rtol: float = 1e-6, atol: float = 1e-8, ode_rtol: float = 1e-7, ode_atol: float = 1e-9,
                free=None, verbose: bool = True):
    """Levenberg–Marquardt on :func:`rollout_residuals` from ``theta0``; returns ``(theta, rms_before, rms_after)``
    (RMS position error in rad). Jacobians by forward-mode differentiation through diffrax.

    ``free``: indices of the entries of ``theta`` to fit (default: all); the others stay at ``theta0``.
    """
    theta0 = jnp.asarray(theta0, dtype=float)
    idx = jnp.arange(theta0.size) if free is None else jnp.asarray(np.asarray(free, dtype=int))

    def full(x):
        return theta0.at[idx].set(x)

    def residual(x, _):
        return rollout_residuals(full(x), model, windows, eps=eps, rtol=ode_rtol, atol=ode_atol, adjoint="forward")

    solver = optx.LevenbergMarquardt(rtol=rtol, atol=atol, verbose=_show if verbose else False)
    x0 = theta0[idx]
    rms = _xla.TopJit(lambda x: jnp.sqrt(jnp.mean(residual(x, None) ** 2)))
    before = float(rms(x0))
    sol = optx.least_squares(residual, solver, x0, max_steps=max_steps, throw=False)
    after = float(rms(sol.value))
    if verbose:
        print(f"  rollout fit: RMS position error {before:.3e} -> {after:.3e} rad "
              f"in {int(sol.stats['num_steps'])} LM steps")
    return np.asarray(full(sol.value)), before, after
