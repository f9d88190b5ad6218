"""The joint-torque regressor: ``tau = W(q, qd, qdd) pi``, linear in the dynamic parameters.

Parameter vector ``pi`` of an ``n``-joint tree, shape ``(13 n,)``:
``[inertia.ravel() (10 n, link 10-vectors about the link origins), I_a (n), Fv (n), Fc (n)]`` with the rotor
inertia ``I_a = N^2 J_m`` (Zafar eq. 18; column ``qdd_j``) and friction ``Fv qd + Fc tanh(qd / eps)`` (eq. 17 with a
smooth sign; columns ``qd_j``, ``tanh(qd_j / eps)``). The rigid-body block is built by automatic differentiation:
inverse dynamics is linear in the inertial parameters, so ``jax.jacfwd`` of
:func:`particlesim.tree.inverse_dynamics` w.r.t. ``inertia`` *is* the regressor (independent of where it is taken).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .. import _xla
from ..tree import TreeModel, inverse_dynamics

__all__ = ["N_PER_JOINT", "rigid_regressor", "actuator_columns", "regressor", "model_with_params", "params_of_model",
           "identifiable_basis", "ordinary_least_squares", "column_scale"]

#: Parameters per joint: 10 inertial + rotor inertia + viscous + Coulomb.
N_PER_JOINT = 13


def _rigid(model: TreeModel, q, qd, qdd):
    def tau(inertia):
        return inverse_dynamics(model.with_params(inertia=inertia), q, qd, qdd)
    return jax.jacfwd(tau)(model.inertia).reshape(model.nq, 10 * model.n_joints)


def rigid_regressor(model: TreeModel, q: Float[ArrayLike, "N n"], qd: Float[ArrayLike, "N n"],
                    qdd: Float[ArrayLike, "N n"], *, chunk: int = 1024) -> Float[Array, "N n 10n"]:
    """``d tau / d inertia`` per sample (rigid-body part only: friction and rotor terms do not depend on it)."""
    q, qd, qdd = (jnp.asarray(x, dtype=float) for x in (q, qd, qdd))
    bare = _strip(model)
    f = _xla.TopJit(jax.vmap(lambda a, b, c: _rigid(bare, a, b, c)))
    out = [f(q[i:i + chunk], qd[i:i + chunk], qdd[i:i + chunk]) for i in range(0, q.shape[0], chunk)]
    return jnp.concatenate(out, axis=0)


def _strip(model: TreeModel) -> TreeModel:
    return eqx.tree_at(lambda m: (m.viscous, m.coulomb, m.rotor_inertia), model, (None, None, None),
                       is_leaf=lambda x: x is None)


def actuator_columns(qd, qdd, eps: float) -> Float[Array, "N n 3n"]:
    """Columns of ``[I_a, Fv, Fc]``: ``diag(qdd)``, ``diag(qd)``, ``diag(tanh(qd / eps))``."""
    qd, qdd = jnp.asarray(qd), jnp.asarray(qdd)
    eye = jnp.eye(qd.shape[-1]).reshape((1,) * (qd.ndim - 1) + (qd.shape[-1], qd.shape[-1]))
    return jnp.concatenate([qdd[..., :, None] * eye, qd[..., :, None] * eye, jnp.tanh(qd / eps)[..., :, None] * eye],
                           axis=-1)


def regressor(model: TreeModel, q, qd, qdd, *, eps: float, rigid=None) -> Float[Array, "N n 13n"]:
    """Full regressor ``W`` with ``tau = W pi`` (layout in the module docstring). ``rigid``: a precomputed
    :func:`rigid_regressor` for the same ``(q, qd, qdd)`` (the friction columns are cheap to redo per ``eps``)."""
    if rigid is None:
        rigid = rigid_regressor(model, q, qd, qdd)
    return jnp.concatenate([rigid, actuator_columns(qd, qdd, eps)], axis=-1)


def model_with_params(model: TreeModel, pi: Float[ArrayLike, " 13n"]) -> TreeModel:
    """``model`` with inertia, rotor inertia and friction taken from ``pi`` (unchecked; traceable)."""
    n, nl = model.nq, model.n_joints
    pi = jnp.asarray(pi)
    r = 10 * nl
    return eqx.tree_at(lambda m: (m.inertia, m.rotor_inertia, m.viscous, m.coulomb), model,
                       (pi[:r].reshape(nl, 10), pi[r:r + n], pi[r + n:r + 2 * n], pi[r + 2 * n:]),
                       is_leaf=lambda x: x is None)


def params_of_model(model: TreeModel) -> Float[Array, " 13n"]:
    """``pi`` of a model (absent rotor inertia / friction -> zeros)."""
    n = model.nq
    z = jnp.zeros(n)
    pick = lambda x: z if x is None else x  # noqa: E731
    return jnp.concatenate([model.inertia.ravel(), pick(model.rotor_inertia), pick(model.viscous),
                            pick(model.coulomb)])


#: Columns whose norm is below this fraction of the largest are structurally zero (a parameter the data cannot
#: see at all, e.g. inertia about axes the first joint never turns) and hold only rounding residue.
ZERO_COLUMN_RTOL = 1e-12


def column_scale(w: Float[ArrayLike, "M p"]) -> np.ndarray:
    """Column norms of ``w`` for scaling, ``inf`` for structurally zero columns (so they scale to exactly 0
    instead of being blown up from rounding residue to unit norm)."""
    scale = np.linalg.norm(np.asarray(w), axis=0)
    return np.where(scale > ZERO_COLUMN_RTOL * scale.max(), scale, np.inf)


def identifiable_basis(w: Float[ArrayLike, "M p"], *, rtol: float = 1e-10) -> tuple[np.ndarray, int]:
    """Identifiable combinations of a stacked regressor ``w``: ``(E (p, r), r)`` with ``beta = E^T pi`` the base
    parameters in column-scaled units.

    With ``D = diag(column norms of w)`` and the SVD ``w D^-1 = U S V^T``, ``E = D V_r`` over the ``r`` singular
    values above ``rtol`` times the largest: ``w pi = U_r S_r E^T pi`` up to the dropped directions, so every
    combination ``E^T pi`` is determined by the data with a condition number ``<= 1 / rtol`` (relative to the
    scaled columns). ``E`` spans the row space of ``w``; its columns are orthonormal in the scaled metric
    ``D^-1 E``, not in the raw parameter units (whose scales differ by many orders of magnitude).
    """
    w = np.asarray(w).reshape(-1, np.shape(w)[-1])
    scale = column_scale(w)
    _, s, vt = np.linalg.svd(w / scale, full_matrices=False)
    r = int(np.sum(s > rtol * s[0]))
    # w = U S V^T D, so the row space of w is spanned by the columns of D V_r.
    return np.where(np.isfinite(scale), scale, 0.0)[:, None] * vt[:r].T, r


def ordinary_least_squares(w: Float[ArrayLike, "N n p"], tau: Float[ArrayLike, "N n"], mask=None) -> np.ndarray:
    """Unconstrained minimum-norm least squares ``argmin ||W pi - tau||`` over rows where ``mask`` (N, n) holds
    (column-scaled ``numpy.linalg.lstsq``; the non-identifiable part of ``pi`` is set to zero in scaled units)."""
    w, tau = np.asarray(w), np.asarray(tau)
    if mask is not None:
        m = np.asarray(mask, bool)
        a, b = w[m], tau[m]
    else:
        a, b = w.reshape(-1, w.shape[-1]), tau.ravel()
    scale = column_scale(a)
    x, *_ = np.linalg.lstsq(a / scale, b, rcond=None)
    return x / scale
