"""Physically consistent identification through inverse dynamics (torque residuals), multi-start LM.

Unconstrained coordinates ``theta`` ``(13 n,)``: ``[log-Cholesky (n x 10), softplus^-1 I_a (n),
softplus^-1 Fv (n), softplus^-1 Fc (n)]`` (see :mod:`._params`); :func:`params_from_theta` maps them to the
regressor layout ``pi`` of :mod:`._regressor`. Every ``theta`` gives positive-definite pseudo-inertias (each body
physically consistent) and positive rotor inertias and friction coefficients.

The residual is ``W pi(theta) - tau`` over the fitted samples. Because ``W`` does not depend on ``theta``, the
stacked ``(M, p)`` regressor is compressed once by a QR factorisation ``W = Q R``: ``||W pi - tau||^2 =
||R pi - Q^T tau||^2 + const``, the same minimiser, gradient and Gauss–Newton steps at ``p x p`` cost per
iteration. :func:`torque_residuals` is the uncompressed form through :func:`particlesim.tree.inverse_dynamics`
(used for gradient checks and as the definition).
"""

from __future__ import annotations

import dataclasses
import functools
from typing import NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np
import lineax as lx
import optimistix as optx
from jaxtyping import Array, ArrayLike, Float

from .. import _ode, _xla
from ..tree import TreeModel, inverse_dynamics
from ._params import inertia_from_log_cholesky, inv_softplus, log_cholesky_from_inertia, softplus
from ._regressor import model_with_params

__all__ = ["params_from_theta", "theta_from_params", "torque_residuals", "CompressedLSQ", "compress",
           "FitResult", "fit_consistent"]


def params_from_theta(theta: Float[ArrayLike, " 13n"]) -> Float[Array, " 13n"]:
    """Unconstrained ``theta`` -> physical ``pi`` (consistent inertias, positive ``I_a, Fv, Fc``)."""
    theta = jnp.asarray(theta)
    n = theta.shape[-1] // 13
    inertia = inertia_from_log_cholesky(theta[..., :10 * n].reshape(*theta.shape[:-1], n, 10))
    return jnp.concatenate([inertia.reshape(*theta.shape[:-1], 10 * n), softplus(theta[..., 10 * n:])], -1)


def theta_from_params(pi: Float[ArrayLike, " 13n"]) -> Float[Array, " 13n"]:
    """Inverse of :func:`params_from_theta`; NaN where ``pi`` is not strictly consistent / positive."""
    pi = jnp.asarray(pi)
    n = pi.shape[-1] // 13
    lc = log_cholesky_from_inertia(pi[..., :10 * n].reshape(*pi.shape[:-1], n, 10))
    return jnp.concatenate([lc.reshape(*pi.shape[:-1], 10 * n), inv_softplus(pi[..., 10 * n:])], -1)


def torque_residuals(theta, model: TreeModel, q, qd, qdd, tau, *, eps: float) -> Float[Array, " N*n"]:
    """``inverse_dynamics(model(theta), q, qd, qdd; smooth_friction=eps) - tau`` over samples, flattened."""
    m = model_with_params(model, params_from_theta(theta))
    pred = jax.vmap(lambda a, b, c: inverse_dynamics(m, a, b, c, smooth_friction=eps))(q, qd, qdd)
    return (pred - tau).ravel()


class CompressedLSQ(NamedTuple):
    """``||W pi - tau||^2 = ||r pi - y||^2 + rest`` over ``count`` scalar residuals."""

    r: Array
    y: Array
    rest: Array
    count: int


def compress(w: Float[ArrayLike, "N n p"], tau: Float[ArrayLike, "N n"], mask=None) -> CompressedLSQ:
    """QR-compress the stacked regressor over the rows (sample, joint) where ``mask`` holds (default: all)."""
    w, tau = np.asarray(w), np.asarray(tau)
    if mask is None:
        a, b = w.reshape(-1, w.shape[-1]), tau.ravel()
    else:
        m = np.asarray(mask, bool)
        a, b = w[m], tau[m]
    qm, r = np.linalg.qr(a)
    y = qm.T @ b
    rest = max(float(b @ b - y @ y), 0.0)
    return CompressedLSQ(jnp.asarray(r), jnp.asarray(y), jnp.asarray(rest), int(b.size))


class MultiStart:
    """Results of one fit per start (abstract): ``theta``, ``pi`` rows per start and the index ``best``."""

    @property
    def best_pi(self) -> np.ndarray:
        return self.pi[self.best]

    @property
    def best_theta(self) -> np.ndarray:
        return self.theta[self.best]


@dataclasses.dataclass(frozen=True)
class FitResult(MultiStart):
    """Multi-start result: per start ``theta (S, 13n)``, ``pi (S, 13n)``, fitted RMSE ``(S,)``, ``steps``;
    ``best`` is the index of the lowest RMSE."""

    theta: np.ndarray
    pi: np.ndarray
    rmse: np.ndarray
    steps: np.ndarray
    best: int


def _entry(i: int, n: int) -> str:
    kinds = ("rotor inertia", "viscous friction", "Coulomb friction")
    return f"link {i // 10} inertia entry {i % 10}" if i < 10 * n else f"joint {(i - 10 * n) % n} {kinds[(i - 10 * n) // n]}"


def check_start(theta0) -> None:
    """Refuse starts with non-finite coordinates, naming the entry (``theta_from_params`` gives NaN where a body is
    not strictly consistent or a rotor inertia / friction coefficient is not positive, e.g. the zeros of
    ``params_of_model`` for a model without them)."""
    theta0 = np.atleast_2d(np.asarray(theta0, dtype=float))
    bad = np.argwhere(~np.isfinite(theta0))
    if bad.size:
        n = theta0.shape[-1] // 13
        where = ", ".join(f"start {s}: {_entry(int(i), n)}" for s, i in bad[:4]) + (" ..." if len(bad) > 4 else "")
        raise ValueError(f"non-finite start coordinates ({where}): every body must be strictly physically "
                         "consistent and every rotor inertia and friction coefficient positive in the start "
                         "(theta_from_params of a zero gives -inf; start actuator parameters at e.g. 1.0)")


@functools.partial(_xla.TopJit, static_argnames=("rtol", "atol", "max_steps", "has_prior"))
def _lm_starts(theta0, r, y, ref, weight, *, rtol, atol, max_steps, has_prior):
    """Levenberg–Marquardt from every row of ``theta0``, vmapped; compiled once per shapes and settings (new data
    and starts reuse it)."""
    _ode.TRACES["fit_consistent"] += 1  # counts traces (the tests read it)

    def residual(theta, args):
        res = args[0] @ params_from_theta(theta) - args[1]
        if has_prior:
            res = jnp.concatenate([res, weight * (theta - ref)])
        return res

    solver = optx.LevenbergMarquardt(rtol=rtol, atol=atol, linear_solver=lx.QR())

    def run(t0):
        sol = optx.least_squares(residual, solver, t0, args=(r, y), max_steps=max_steps, throw=False)
        return sol.value, sol.stats["num_steps"]

    return jax.vmap(run)(theta0)


def fit_consistent(lsq: CompressedLSQ, theta0: Float[ArrayLike, "S 13n"], *, rtol: float = 1e-10,
                   atol: float = 1e-10, max_steps: int = 500, prior: Optional[tuple] = None,
                   verbose: bool = True) -> FitResult:
    """Levenberg–Marquardt (``optimistix.least_squares``) from each row of ``theta0``, vmapped over starts.

    ``prior=(theta_ref, weight)`` adds ``weight (theta - theta_ref)`` to the residuals (a small Tikhonov term that
    pins the directions the data cannot see; ``None``: pure data fit). Progress: one line per start. Compiled once
    per problem size, number of starts and settings: new data, starts and prior values reuse it.
    """
    theta0 = jnp.atleast_2d(jnp.asarray(theta0, dtype=float))
    check_start(theta0)
    ref, weight = (jnp.zeros(theta0.shape[-1]), 0.0) if prior is None else (jnp.asarray(prior[0], float), prior[1])
    theta, steps = _lm_starts(theta0, lsq.r, lsq.y, ref, jnp.asarray(weight, float), rtol=float(rtol),
                              atol=float(atol), max_steps=int(max_steps), has_prior=prior is not None)
    pi = params_from_theta(theta)
    ss = jnp.sum((pi @ lsq.r.T - lsq.y[None]) ** 2, axis=-1) + lsq.rest
    rmse = np.sqrt(np.asarray(ss) / lsq.count)
    rmse = np.where(np.isfinite(rmse), rmse, np.inf)
    best = int(np.argmin(rmse))
    if verbose:
        for s in range(theta0.shape[0]):
            print(f"  start {s:2d}: {int(steps[s]):4d} LM steps, fitted RMSE {rmse[s]:.4f} N m"
                  + ("  <- best" if s == best else ""))
    return FitResult(np.asarray(theta), np.asarray(pi), rmse, np.asarray(steps), best)
