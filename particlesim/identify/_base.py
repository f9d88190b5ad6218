"""Consistent parameters that reproduce the least-squares base parameters: Gauss–Newton with continuation.

The torque model is linear, ``tau = W pi``, but rank-deficient: only the base parameters ``beta = E^T pi``
(:func:`._regressor.identifiable_basis`, column-scaled) are determined by data. Their least-squares estimate is
a well-conditioned linear problem: with the SVD ``W D^-1 = U S V^T`` of the column-scaled regressor,
``beta_hat = S_r^-1 U_r^T tau`` (condition ``<= 1 / rtol``). What remains is to find a physically consistent
``pi(theta)`` (log-Cholesky coordinates, :func:`._fit.params_from_theta`) with ``E^T pi(theta) = beta_hat``:
``r`` equations in ``13 n > r`` unknowns, solved by Levenberg–Marquardt on the *whitened* base residual
``e(theta) = E^T pi(theta) - beta_hat``.

Why whitened: the torque residual ``W pi - tau`` equals ``U_r S_r e`` (plus the dropped directions), so both
have the same zero set, but the singular values ``S_r`` span ``1 / rtol``; the Gauss–Newton matrix of the torque
residual has their squares (``~1e12``) and its small directions stall LM (measured: 5.5e-2 relative error on the
base parameters after 1500 steps), while ``e`` weights every identifiable combination alike. Structurally zero
regressor columns are dropped before scaling (:func:`._regressor.column_scale`). The consistent set is convex in
``pi`` and so is its image in ``beta``; when ``beta_hat`` lies in it (noise-free data, or noise small against the
margin of every body) the fit reproduces ``beta_hat`` to rounding; otherwise it returns the closest consistent
point in the whitened metric and :func:`._fit.fit_consistent` gives the least-squares one.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike, Float

from ._fit import CompressedLSQ, MultiStart, _lm_starts, check_start, params_from_theta
from ._regressor import column_scale, identifiable_basis

__all__ = ["BaseParameters", "base_parameters", "BaseFit", "fit_base_consistent"]


class BaseParameters(NamedTuple):
    """``beta = basis^T pi`` (``basis (p, r)``) and its least-squares estimate ``beta_hat (r,)``; singular values
    ``sv (r,)`` of the column-scaled regressor."""

    basis: np.ndarray
    beta_hat: np.ndarray
    sv: np.ndarray


def base_parameters(lsq: CompressedLSQ, *, rtol: float = 1e-6) -> BaseParameters:
    """Least-squares base parameters from a compressed regressor (``r`` is ``W``'s triangular factor, so it has
    the same column norms, singular values and right singular vectors)."""
    r, y = np.asarray(lsq.r), np.asarray(lsq.y)
    basis, rank = identifiable_basis(r, rtol=rtol)
    scale = column_scale(r)
    u, s, _ = np.linalg.svd(r / scale, full_matrices=False)
    # Same SVD as inside identifiable_basis (deterministic LAPACK call on the same matrix).
    return BaseParameters(basis, (u[:, :rank].T @ y) / s[:rank], s[:rank])


@dataclasses.dataclass(frozen=True)
class BaseFit(MultiStart):
    """Per start: ``theta (S, p)``, ``pi (S, p)``, ``rel_residual (S,) = ||E^T pi - beta_hat|| / ||beta_hat||``,
    LM ``steps (S,)``; ``best`` is the start with the smallest residual."""

    theta: np.ndarray
    pi: np.ndarray
    rel_residual: np.ndarray
    steps: np.ndarray
    best: int


def fit_base_consistent(lsq: CompressedLSQ, theta0: Float[ArrayLike, "S p"], *, rtol: float = 1e-6,
                        tol: float = 1e-14, max_steps: int = 3000) -> BaseFit:
    """Consistent ``theta`` with ``E^T pi(theta) = beta_hat`` (module docstring), LM from each row of ``theta0``.

    ``rtol``: singular-value cut of the base parameters; ``tol``: LM's relative and absolute tolerances.
    """
    check_start(theta0)
    base = base_parameters(lsq, rtol=rtol)
    theta0 = jnp.atleast_2d(jnp.asarray(theta0, dtype=float))
    # The residual E^T pi(theta) - beta_hat is fit_consistent's with (E^T, beta_hat) for (R, y): one compiled
    # solver per shapes and settings serves both.
    theta, steps = _lm_starts(theta0, jnp.asarray(base.basis.T), jnp.asarray(base.beta_hat),
                              jnp.zeros(theta0.shape[-1]), jnp.asarray(0.0), rtol=float(tol), atol=float(tol),
                              max_steps=int(max_steps), has_prior=False)
    pi = np.asarray(params_from_theta(theta))
    rel = np.linalg.norm(pi @ base.basis - base.beta_hat[None], axis=-1) / np.linalg.norm(base.beta_hat)
    rel = np.where(np.isfinite(rel), rel, np.inf)
    return BaseFit(np.asarray(theta), pi, rel, np.asarray(steps), int(np.argmin(rel)))
