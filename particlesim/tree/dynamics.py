"""Joint-space dynamics ``A(q) qdd + C(q, qd) qd + Q(q) + Gamma_f(qd) = tau`` (Zafar eqs. 3, 17, 18).

Fast path, vectorised over links with the static support mask (no per-link Python work beyond the pose loop):

* ``A = sum_j J_j^T M_j J_j + diag(I_a)`` with the link Jacobians ``J_j`` (world axes, about ``O_j``) and the
  6 x 6 matrix ``M_j = [[m E, [MS]x^T], [[MS]x, J]]`` of the quadratic form eq. (11); this *is* the Hessian of the
  kinetic energy w.r.t. ``qd`` (tested against ``jax.hessian``).
* ``C qd + Q``: Newton–Euler wrenches about each link origin with the bias accelerations ``Jdot_j qd`` and
  gravity as a base acceleration, mapped to joints by ``sum_j J_j^T w_j`` (a Jacobian-transpose RNEA, O(n^2)).
  This equals ``d/dt dE/dqd - dE/dq + dU/dq`` at ``qdd = 0`` (tested against autodiff of the energies).
"""

from __future__ import annotations

from typing import NamedTuple, Optional

import jax.numpy as jnp
from jax.scipy.linalg import cho_factor, cho_solve
from jaxtyping import Array, ArrayLike, Float

from ..spatial import skew
from .energy import split_params
from .kinematics import link_jacobians, link_poses, world_axes
from .model import TreeModel

__all__ = [
    "mass_matrix",
    "bias_forces",
    "coriolis_times_qdot",
    "gravity_torques",
    "friction_torques",
    "inverse_dynamics",
    "forward_dynamics",
]


class _Kin(NamedTuple):
    rot: Array  # (n, 3, 3) link axes -> world
    pos: Array  # (n, 3) link origins
    jac: Array  # (n, 6, n) [v_O; w] Jacobians, world axes
    m: Array  # (n,)
    ms: Array  # (n, 3) first moments, world axes
    j: Array  # (n, 3, 3) inertia about the origin, world axes


def _kinematics(model: TreeModel, q) -> _Kin:
    rot, pos = link_poses(model, q)
    jac = link_jacobians(model, rot, pos)
    m, ms, j = split_params(model.inertia)
    ms_w = (rot @ ms[..., None])[..., 0]
    j_w = rot @ j @ jnp.swapaxes(rot, -1, -2)
    return _Kin(rot, pos, jac, m, ms_w, j_w)


def _mass_matrix(model: TreeModel, k: _Kin) -> Array:
    hx = skew(k.ms)  # (n, 3, 3)
    jv, jw = k.jac[:, :3, :], k.jac[:, 3:, :]
    f = k.m[:, None, None] * jv + jnp.swapaxes(hx, -1, -2) @ jw  # force rows of M_j J_j
    t = hx @ jv + k.j @ jw  # moment rows
    a = jnp.einsum("jak,jal->kl", jv, f) + jnp.einsum("jak,jal->kl", jw, t)
    a = 0.5 * (a + a.T)
    if model.rotor_inertia is not None:
        a = a + jnp.diag(model.rotor_inertia)
    return a


def _wrench_torques(model: TreeModel, k: _Kin, qd, qdd, gravity) -> Array:
    """``sum_j J_j^T [F_j; N_j]`` with the Newton–Euler wrench about ``O_j`` needed for accelerations ``qdd``."""
    rev = model.is_revolute
    jv, jw = k.jac[:, :3, :], k.jac[:, 3:, :]
    acc_lin = jnp.zeros_like(k.pos) if gravity is None else jnp.broadcast_to(-gravity, k.pos.shape)
    acc_ang = jnp.zeros_like(k.pos)
    if qd is not None:
        w = jw @ qd  # (n, 3) link angular velocities
        v = jv @ qd  # (n, 3) origin velocities
        a = world_axes(model, k.rot)  # (n, 3)
        adot = jnp.cross(w, a)  # axis k fixed in link k
        mask = jnp.asarray(model.support, dtype=k.pos.dtype)  # (j, k)
        r = k.pos[:, None, :] - k.pos[None, :, :]  # (j, k, 3)
        rv = jnp.asarray(rev, dtype=k.pos.dtype)
        # Jdot_j qd: angular part sum_k rev_k adot_k qd_k; linear part per column (see module docstring).
        col_ang = (rv * qd)[:, None] * adot  # (k, 3)
        dv = v[:, None, :] - v[None, :, :]  # (j, k, 3): v_j - v_k
        adot_b = jnp.broadcast_to(adot[None], r.shape)
        a_b = jnp.broadcast_to(a[None], r.shape)
        col_lin_rev = jnp.cross(adot_b, r) + jnp.cross(a_b, dv)
        if rev.all():
            col_lin = col_lin_rev
        else:
            col_lin = rv[None, :, None] * col_lin_rev + (1.0 - rv)[None, :, None] * adot_b
        acc_ang = acc_ang + mask @ col_ang
        acc_lin = acc_lin + jnp.einsum("jk,jka,k->ja", mask, col_lin, qd)
    if qdd is not None:
        acc_lin = acc_lin + jv @ qdd
        acc_ang = acc_ang + jw @ qdd
    force = k.m[:, None] * acc_lin + jnp.cross(acc_ang, k.ms)
    moment = (k.j @ acc_ang[..., None])[..., 0] + jnp.cross(k.ms, acc_lin)
    if qd is not None:
        force = force + jnp.cross(w, jnp.cross(w, k.ms))
        moment = moment + jnp.cross(w, (k.j @ w[..., None])[..., 0])
    return jnp.einsum("jak,ja->k", jv, force) + jnp.einsum("jak,ja->k", jw, moment)


def mass_matrix(model: TreeModel, q: Float[ArrayLike, " n"]) -> Float[Array, "n n"]:
    """The inertia matrix ``A(q)`` of eq. (2), including rotor inertia ``I_a`` on the diagonal (eq. 18)."""
    return _mass_matrix(model, _kinematics(model, jnp.asarray(q)))


def bias_forces(model: TreeModel, q: Float[ArrayLike, " n"], qd: Float[ArrayLike, " n"]) -> Float[Array, " n"]:
    """``C(q, qd) qd + Q(q)`` (Coriolis, centrifugal and gravity torques; no friction)."""
    return _wrench_torques(model, _kinematics(model, jnp.asarray(q)), jnp.asarray(qd), None, model.gravity)


def coriolis_times_qdot(model: TreeModel, q: Float[ArrayLike, " n"], qd: Float[ArrayLike, " n"]) -> Float[Array, " n"]:
    """``C(q, qd) qd`` alone (no gravity); equals ``coriolis_matrix(model, q, qd) @ qd``."""
    return _wrench_torques(model, _kinematics(model, jnp.asarray(q)), jnp.asarray(qd), None, None)


def gravity_torques(model: TreeModel, q: Float[ArrayLike, " n"]) -> Float[Array, " n"]:
    """``Q(q) = dU/dq`` (eq. 5) as ``-sum_j J_Gj^T m_j g``."""
    return _wrench_torques(model, _kinematics(model, jnp.asarray(q)), None, None, model.gravity)


def friction_torques(model: TreeModel, qd: Float[ArrayLike, " n"], *,
                     smooth_friction: Optional[float] = None) -> Float[Array, " n"]:
    """``Gamma_f = Fv qd + Fc sign(qd)`` (eq. 17); with ``smooth_friction=eps``, ``sign`` -> ``tanh(qd / eps)``.

    Zero (and free) when the model has no friction parameters.
    """
    qd = jnp.asarray(qd)
    out = jnp.zeros_like(qd)
    if model.viscous is not None:
        out = out + model.viscous * qd
    if model.coulomb is not None:
        s = jnp.sign(qd) if smooth_friction is None else jnp.tanh(qd / smooth_friction)
        out = out + model.coulomb * s
    return out


def inverse_dynamics(model: TreeModel, q: Float[ArrayLike, " n"], qd: Float[ArrayLike, " n"],
                     qdd: Float[ArrayLike, " n"], *, smooth_friction: Optional[float] = None) -> Float[Array, " n"]:
    """``tau = A qdd + C qd + Q + Gamma_f`` (eqs. 3, 17, 18)."""
    qd, qdd = jnp.asarray(qd), jnp.asarray(qdd)
    tau = _wrench_torques(model, _kinematics(model, jnp.asarray(q)), qd, qdd, model.gravity)
    if model.rotor_inertia is not None:
        tau = tau + model.rotor_inertia * qdd
    if model.viscous is not None or model.coulomb is not None:
        tau = tau + friction_torques(model, qd, smooth_friction=smooth_friction)
    return tau


def forward_dynamics(model: TreeModel, q: Float[ArrayLike, " n"], qd: Float[ArrayLike, " n"],
                     tau: Float[ArrayLike, " n"], *, smooth_friction: Optional[float] = None) -> Float[Array, " n"]:
    """``qdd = A^-1 (tau - C qd - Q - Gamma_f)`` by a Cholesky factorisation of ``A``.

    External wrenches enter through ``tau``: add :func:`~.kinematics.wrench_torques` (``J^T f``, eq. 16).
    ``smooth_friction=eps`` replaces ``sign(qd)`` by ``tanh(qd / eps)`` (differentiable at ``qd = 0``).
    """
    qd, tau = jnp.asarray(qd), jnp.asarray(tau)
    k = _kinematics(model, jnp.asarray(q))
    rhs = tau - _wrench_torques(model, k, qd, None, model.gravity)
    if model.viscous is not None or model.coulomb is not None:
        rhs = rhs - friction_torques(model, qd, smooth_friction=smooth_friction)
    return cho_solve(cho_factor(_mass_matrix(model, k)), rhs)
