"""How well the data determine the identified parameters: Gauss–Newton standard errors of the base parameters,
checked against bootstrap resamples of the training data.

Only the base parameters ``beta = E^T pi`` (:func:`._regressor.identifiable_basis`, column-scaled units) are
determined by the data. At a fit ``theta`` (log-Cholesky coordinates, :func:`._fit.params_from_theta`) of the
residual ``r(theta) = W pi(theta) - tau`` the Gauss–Newton approximation of the Hessian is ``J^T J`` with
``J = W dpi/dtheta``; for residuals with independent noise of variance ``sigma^2`` (estimated as
``RSS / (M - rank)``) the parameter covariance is ``sigma^2 (J^T J)^+`` and, pushed through ``G = E^T dpi/dtheta``,

    ``cov(beta) = sigma^2 G (J^T J)^+ G^T``.

When the fit is interior (no body at the edge of physical consistency) this is the least-squares covariance
``sigma^2 S_r^-2`` in the basis of the regressor's singular vectors; when a consistency bound is active, the
directions in which ``pi(theta)`` flattens carry less variance (the bound holds them).

This assumes residuals of equal variance, independent of each other. Real data break both: joints have different
residual levels and model error is smooth in time. :func:`robust_base_uncertainty` keeps the Gauss–Newton Hessian
``H = J^T J`` and replaces ``sigma^2 H`` by the spread of the residual's own scores (a sandwich estimate),

    ``cov(beta) = G H^+ (sum_b s_b s_b^T) H^+ G^T``,  ``s_b = sum over the samples t of block b of J_t^T e_t``,

over single samples (``block = 1``: any variance per joint and sample, joints of one sample correlated) or over
contiguous blocks of samples (correlation in time shorter than a block). :func:`bootstrap_base` resamples samples
or the same contiguous blocks, an independent check of each.
"""

from __future__ import annotations

from typing import NamedTuple, Optional

import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
from jaxtyping import ArrayLike, Float

from .. import _xla
from ._fit import CompressedLSQ, check_start, compress, params_from_theta
from ._regressor import column_scale, identifiable_basis

__all__ = ["BaseUncertainty", "base_uncertainty", "bootstrap_base", "robust_base_uncertainty"]


class BaseUncertainty(NamedTuple):
    """Base parameters ``beta = basis^T pi (r,)`` at the fit, their Gauss–Newton covariance ``cov (r, r)`` and
    standard errors ``std (r,)``; ``sigma`` the residual standard deviation estimate, ``dof = M - r``."""

    basis: np.ndarray
    beta: np.ndarray
    cov: np.ndarray
    std: np.ndarray
    sigma: float
    dof: int

    @property
    def rel_std(self) -> np.ndarray:
        """``std / |beta|`` (``inf`` where ``beta = 0``)."""
        with np.errstate(divide="ignore"):
            return np.where(self.beta != 0, self.std / np.abs(self.beta), np.inf)


def base_uncertainty(lsq: CompressedLSQ, theta: Float[ArrayLike, " p"], *, basis: Optional[np.ndarray] = None,
                     rtol: float = 1e-6, sigma: Optional[float] = None, pinv_rtol: float = 1e-12
                     ) -> BaseUncertainty:
    """Gauss–Newton standard errors of the base parameters at the fit ``theta`` (module docstring).

    ``basis``: the identifiable combinations (default ``identifiable_basis(lsq.r, rtol=rtol)``); ``sigma``: the
    noise standard deviation if known (default: estimated from the residual); ``pinv_rtol``: singular values of
    ``J^T J`` below this times the largest are treated as unidentifiable (pseudo-inverse).
    """
    check_start(theta)
    theta = jnp.asarray(theta, dtype=float)
    r_mat = np.asarray(lsq.r)
    if theta.shape != (r_mat.shape[1],):
        raise ValueError(f"theta has shape {theta.shape}; the regressor has {r_mat.shape[1]} parameters")
    if basis is None:
        basis, _ = identifiable_basis(r_mat, rtol=rtol)
    rank = basis.shape[1]
    dpi = np.asarray(jax.jacfwd(params_from_theta)(theta))
    pi = np.asarray(params_from_theta(theta))
    jac = r_mat @ dpi
    if sigma is None:
        rss = float(np.sum((r_mat @ pi - np.asarray(lsq.y)) ** 2) + lsq.rest)
        dof = lsq.count - rank
        if dof <= 0:
            raise ValueError(f"{lsq.count} residuals do not exceed the {rank} base parameters: no noise estimate")
        sigma = float(np.sqrt(rss / dof))
    g = basis.T @ dpi
    cov = sigma ** 2 * g @ np.linalg.pinv(jac.T @ jac, rcond=pinv_rtol, hermitian=True) @ g.T
    cov = 0.5 * (cov + cov.T)
    return BaseUncertainty(basis, basis.T @ pi, cov, np.sqrt(np.clip(np.diag(cov), 0.0, None)), float(sigma),
                           lsq.count - rank)


def robust_base_uncertainty(w: Float[ArrayLike, "N n p"], tau: Float[ArrayLike, "N n"],
                            theta: Float[ArrayLike, " p"], basis: np.ndarray, *, mask=None, block: int = 1,
                            pinv_rtol: float = 1e-12) -> BaseUncertainty:
    """Sandwich standard errors of the base parameters at the fit ``theta`` (module docstring) from the rows of
    the regressor ``w`` and torques ``tau`` (``mask``: the fitted entries, default all): scores summed over each
    sample (``block = 1``) or over contiguous blocks of ``block`` samples, as :func:`bootstrap_base` resamples
    them. ``sigma`` is the residual RMS; ``pinv_rtol`` as in :func:`base_uncertainty`."""
    check_start(theta)
    w, tau = np.asarray(w, dtype=float), np.asarray(tau, dtype=float)
    if w.ndim != 3 or tau.shape != w.shape[:2]:
        raise ValueError(f"w must be (N, n, p) and tau (N, n); got {w.shape} and {tau.shape}")
    theta = jnp.asarray(theta, dtype=float)
    if theta.shape != (w.shape[2],):
        raise ValueError(f"theta has shape {theta.shape}; the regressor has {w.shape[2]} parameters")
    if not 1 <= block <= tau.shape[0]:
        raise ValueError(f"block must be between 1 and the number of samples ({tau.shape[0]}), got {block}")
    mask = np.ones(tau.shape, bool) if mask is None else np.broadcast_to(np.asarray(mask, bool), tau.shape)
    dpi = np.asarray(jax.jacfwd(params_from_theta)(theta))
    pi = np.asarray(params_from_theta(theta))
    jac = np.where(mask[..., None], w @ dpi, 0.0)  # (N, n, q)
    e = np.where(mask, w @ pi - tau, 0.0)
    hinv = np.linalg.pinv(np.einsum("tjp,tjq->pq", jac, jac), rcond=pinv_rtol, hermitian=True)
    scores = np.einsum("tjp,tj->tp", jac, e)
    n_blocks = -(-scores.shape[0] // block)
    pad = np.zeros((n_blocks * block - scores.shape[0], scores.shape[1]))
    sums = np.concatenate([scores, pad]).reshape(n_blocks, block, -1).sum(axis=1)
    g = basis.T @ dpi
    cov = g @ hinv @ (sums.T @ sums) @ hinv @ g.T
    cov = 0.5 * (cov + cov.T)
    count, rank = int(mask.sum()), basis.shape[1]
    return BaseUncertainty(basis, basis.T @ pi, cov, np.sqrt(np.clip(np.diag(cov), 0.0, None)),
                           float(np.sqrt(np.sum(e ** 2) / count)), count - rank)


def _resample(n: int, rng: np.random.Generator, block: int) -> np.ndarray:
    if block <= 1:
        return rng.integers(0, n, n)
    starts = rng.integers(0, n - block + 1, -(-n // block))
    return (starts[:, None] + np.arange(block)[None]).ravel()[:n]


def bootstrap_base(w: Float[ArrayLike, "N n p"], tau: Float[ArrayLike, "N n"], theta0: Float[ArrayLike, " p"],
                   basis: np.ndarray, *, mask=None, count: int = 50, block: int = 1, seed: int = 0,
                   project: bool = False, max_steps: int = 3000, tol: float = 1e-14) -> np.ndarray:
    """Base parameters ``(count, r)`` fitted to ``count`` resamples of the rows (samples) of ``(w, tau)``:
    independent rows (``block = 1``) or contiguous blocks of ``block`` samples (for data correlated in time).

    Each resample's least-squares base parameters ``E^T pi_ls`` (``E = basis``, fixed from the full data; a linear
    solve). They are what a consistent fit of the resample returns whenever its optimum is interior, the case the
    Gauss–Newton errors of :func:`base_uncertainty` describe. ``project=True`` also projects each onto the
    consistent set as :func:`._base.fit_base_consistent` does (Levenberg–Marquardt on ``E^T pi(theta) - E^T
    pi_ls`` from ``theta0``, all resamples vmapped; ``max_steps``, ``tol``), for fits where a consistency bound
    is active."""
    w, tau = np.asarray(w), np.asarray(tau)
    if not 1 <= block <= tau.shape[0]:
        raise ValueError(f"block must be between 1 and the number of samples ({tau.shape[0]}), got {block}")
    mask = np.ones(tau.shape, bool) if mask is None else np.broadcast_to(np.asarray(mask, bool), tau.shape)
    rng = np.random.default_rng(seed)
    targets = []
    for _ in range(count):
        idx = _resample(tau.shape[0], rng, block)
        lsq = compress(w[idx], tau[idx], mask[idx])
        r = np.asarray(lsq.r)
        scale = column_scale(r)
        pi_ls = np.linalg.lstsq(r / scale, np.asarray(lsq.y), rcond=None)[0] / scale
        targets.append(basis.T @ pi_ls)
    targets = np.stack(targets)
    if not project:
        return targets
    solver = optx.LevenbergMarquardt(rtol=tol, atol=tol, linear_solver=lx.QR())
    e_mat = jnp.asarray(basis.T)

    def residual(theta, target):
        return e_mat @ params_from_theta(theta) - target

    @_xla.TopJit
    @jax.vmap
    def run(target):
        sol = optx.least_squares(residual, solver, jnp.asarray(theta0, dtype=float), args=target,
                                 max_steps=max_steps, throw=False)
        return e_mat @ params_from_theta(sol.value)

    return np.asarray(run(jnp.asarray(targets)))
