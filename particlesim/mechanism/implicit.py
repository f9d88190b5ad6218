"""A mechanism's stage equations and Newton matrix for the structured implicit solver (:mod:`particlesim._esdirk`).

In particle coordinates the mass matrix ``M = M_s (x) I_3`` is constant, the constraint Jacobian ``J`` comes in
closed form per row kind (:mod:`._algebra`), and the generalised forces ``Q`` are gravity (constant) plus the force
elements, each reading a few points. The Newton matrix ``[[M + g C + g^2 K, J^T], [J, 0]]`` needs
``K = -d(Q - J^T lam)/dq`` and ``C = -dQ/dv``: forward-mode derivatives of the force elements and of ``J^T lam`` at
fixed multipliers (the constraint forces' geometric stiffness, which matters where they are large: a spinning
governor's arms, a loaded suspension), never of the constraint solve. Singular mass matrices need nothing else
(the saddle-point matrix stays regular). Mechanisms with redundant rows (``multipliers='least_squares'``) keep
diffrax's Kvaerno (:mod:`.integrate`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from .._esdirk import SecondOrderSystem
from ._algebra import _partner, Prepared, apply_j, drive_at, gamma, jacobian, residual, rows, velocity_target
from .dynamics import _forces, _solve
from .forces import generalized_point_forces, one_sided_gaps
from .model import Mechanism

__all__ = ["stage_system"]


def _generalized(mech: Mechanism, prep: Prepared, t, q, v, contact):
    """``Q(t, q, v)`` on the free coordinates (gravity, force elements, torques)."""
    terms, q_torque = _forces(mech, prep, t, q, v, contact)
    out = prep.qg.reshape(-1)
    if terms is not None:
        out = out + generalized_point_forces(prep.wk[terms[0]], terms[1])
    if q_torque is not None:
        out = out + q_torque
    return out


def _gamma(mech: Mechanism, prep: Prepared, r, q, v, baumgarte: float):
    g = gamma(prep, r)
    if baumgarte:
        g = g - 2.0 * baumgarte * (apply_j(prep, r, v.reshape(-1, 3)) - velocity_target(prep, r)) - \
            baumgarte**2 * residual(prep, mech.dot_kappa, r, q)
    return g


def _jmat(prep: Prepared, r):
    j = jacobian(prep, r)
    return j.reshape(j.shape[0], -1)


def _jt(prep: Prepared, vu, lam, drive_n=None):
    """``J^T lam`` (3F,) from the dot rows' vectors ``vu`` (2D, 3), as products with the rows' constant matrices
    (:func:`~._algebra.apply_minv_jt` without ``M^-1``); ``drive_n``: the driving rows' directions, if any."""
    n, nl = prep.scale.shape[0], prep.c_lin.shape[0]
    ls = jnp.tile(lam[:n] * prep.scale, 2)[:, None] * _partner(vu, prep.turn)
    out = prep.d.T @ ls + jnp.sum(prep.j_lin * lam[n:n + nl, None, None], axis=0)
    if drive_n is not None:
        out = out + prep.drv_d.T @ (lam[n + nl:, None] * drive_n)
    return out.reshape(-1)


def _drive_n(r):
    return None if r.drive is None else r.drive.n


def stage_residual(mech: Mechanism, prep: Prepared, t, q, v, lam_g, zv, g, baumgarte: float = 0.0, contact=None):
    """``(M (v - zv) + J^T lam_g - g Q, J (v - zv) - g gamma)`` at the stage position ``q``."""
    dv = v - zv
    f1 = (prep.ms @ dv.reshape(-1, 3)).reshape(-1) - g * _generalized(mech, prep, t, q, v, contact)
    if mech.n_constraints == 0:
        return f1
    r = rows(prep, q, v, drive_at(mech, t))
    return jnp.concatenate([f1 + _jt(prep, r.vu, lam_g, _drive_n(r)),
                            apply_j(prep, r, dv.reshape(-1, 3)) - g * _gamma(mech, prep, r, q, v, baumgarte)])


def newton_matrix(mech: Mechanism, prep: Prepared, t, q, v, lam, g, contact=None, baumgarte: float = 0.0):
    """``[[M + g C + g^2 K, J^T], [J, 0]]`` at ``(q, v)`` with multipliers ``lam`` (module docstring); with Baumgarte
    terms (rate ``b``) the constraint rows of the stage equations are ``(1 + b g)^2 J``."""
    drive = drive_at(mech, t)
    n_c = mech.n_constraints

    def load(q_, v_):  # the forces on the particles at fixed multipliers
        f = _generalized(mech, prep, t, q_, v_, contact)
        if n_c == 0:
            return f
        # the dot rows' vectors by a plain product: its derivative is one small product per column
        return f - _jt(prep, prep.d @ q_.reshape(-1, 3) + prep.c, lam, None if drive is None else drive.n)

    dq, dv = jax.jacfwd(load, argnums=(0, 1))(q, v)
    m = jnp.kron(prep.ms, jnp.eye(3, dtype=prep.ms.dtype))
    top = m - g * dv - g * g * dq
    if n_c == 0:
        return top
    j = _jmat(prep, rows(prep, q, None, drive))
    left = j * (1.0 + baumgarte * g) ** 2 if baumgarte else j
    low = jnp.zeros((n_c, n_c), dtype=top.dtype)
    return jnp.block([[top, j.T], [left, low]])


def stage_system(unpack, baumgarte: float, split: bool, contact_of=None, n_mult: int = 0,
                 switching: bool = False) -> SecondOrderSystem:
    """The :class:`~particlesim._esdirk.SecondOrderSystem` of a rollout: ``unpack(args) -> (mech, prep, _)`` reads
    the mechanism from the solve's ``args``; ``contact_of(args)`` (or None) the one-sided elements' fixed laws of an
    evented segment; ``switching``: the mechanism has one-sided elements (tyres, bump stops), whose laws each stage
    solve holds fixed (:class:`~particlesim._esdirk.SecondOrderSystem`)."""
    def parts(args):
        if contact_of is None:
            return unpack(args)[:2], None
        return unpack(args[0])[:2], contact_of(args)

    def accelerations(t, q, v, args):
        (m, p), contact = parts(args)
        return _solve(m, p, t, q, v, baumgarte, contact=contact, split=split)

    def residual_(t, q, v, lam_g, zv, g, args, modes):
        (m, p), _ = parts(args)
        return stage_residual(m, p, t, q, v, lam_g, zv, g, baumgarte, modes)

    def matrix(t, q, v, lam, g, args, modes):
        (m, p), _ = parts(args)
        return newton_matrix(m, p, t, q, v, lam, g, modes, baumgarte)

    def modes(t, q, v, args):  # the segment's laws (evented), else each element's law read from its gap's sign
        (m, p), contact = parts(args)
        if contact is not None:
            return contact
        return one_sided_gaps(m, p.wk @ q.reshape(-1, 3) + p.p0, t) < 0.0

    return SecondOrderSystem(accelerations, residual_, matrix, n_mult, modes if switching else None)
