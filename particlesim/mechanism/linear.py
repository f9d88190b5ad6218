"""Linearisation of a constrained mechanism about a rest state, and its modes of vibration.

At rest (``qd = 0``, ``qdd = 0``) a small motion ``q = q* + dq`` of the constrained equations
``M qdd + J^T lam = Q(t, q, qd)``, ``J qdd = gamma(q, qd)`` stays on the tangent space ``J dq = 0`` to first order,
and so does its acceleration: differentiating ``J qdd = gamma``, ``J d(qdd) = -(dJ) qdd + d(gamma) = 0`` at rest,
since ``qdd = 0`` there and ``gamma`` is quadratic in ``qd``. With ``Z`` (3F x n) an orthonormal basis of the null
space of ``J(q*)`` and ``dq = Z z``, the linear equations are

    M_r z'' + C_r z' + K_r z = 0,   M_r = Z^T M Z,   K_r = -Z^T M (d qdd / d q) Z,   C_r = -Z^T M (d qdd / d qd) Z

where ``qdd(q, qd)`` is the constrained acceleration (:func:`~.dynamics.accelerations`), differentiated along the
columns of ``Z`` (``n`` forward-mode directions). Its derivative in ``q`` carries the change of the constraint
forces ``lam`` with the position, so ``K_r`` includes the geometric stiffness ``d(J^T lam)/dq`` (a hanging pendulum's
``m g / L``). ``K_r`` is symmetric for conservative loads (springs, tyres, gravity), ``C_r`` for dampers.

Modes: the undamped natural frequencies solve ``K_r v = w^2 M_r v`` (symmetric part of ``K_r``; ``eigh`` after a
Cholesky factor of ``M_r``); the damped ones are the eigenvalues ``s`` of the first-order matrix ``A`` (2n x 2n) of
``d/dt [z, z'] = A [z, z']``, paired with the undamped mode whose shape their eigenvector's position part resembles
most (mass-weighted); for a pair ``s1, s2``: ``w_n = sqrt(s1 s2)``, damping ratio ``-(s1 + s2) / (2 w_n)``, damped
frequency ``|Im s|``.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
import numpy as np
from jaxtyping import Array, Complex, Float

from .. import _ode
from .._jit import compiled
from ..errors import ModelError
from ._algebra import prepare
from ._build import RANK_RTOL
from .constraints import constraint_jacobian, constraints
from .dynamics import _solve
from .forces import one_sided_gaps, one_sided_names
from .model import Mechanism

__all__ = ["Linearization", "Modes", "linearize", "modes"]

#: A state is at rest when no acceleration at zero velocity exceeds this fraction of ``|g|`` (of 1 m/s^2 without
#: gravity).
REST_RTOL = 1e-6
#: The largest constraint residual accepted at the rest state.
PHI_TOL = 1e-8
#: Undamped ``w^2`` below this fraction of the largest are zero: free motions (a car's horizontal position and
#: heading on vertical tyres).
ZERO_RTOL = 1e-9


class Linearization(NamedTuple):
    """The linear equations about a rest state (module docstring): ``basis`` ``Z`` (3F x n, orthonormal, the
    admissible motions ``dq = Z z``), the reduced ``mass``, ``stiffness`` and ``damping`` (n x n), and ``A`` (2n x 2n)
    with ``d/dt [z, z'] = A [z, z']``: ``A = [[0, I], [-M_r^-1 K_r, -M_r^-1 C_r]]``."""

    basis: Float[Array, "3F n"]
    mass: Float[Array, "n n"]
    stiffness: Float[Array, "n n"]
    damping: Float[Array, "n n"]
    A: Float[Array, "2n 2n"]


class Modes(NamedTuple):
    """Modes about a rest state, in order of undamped frequency. ``frequency`` [Hz]: undamped natural frequencies
    (0 for a free motion; negative, ``-sqrt(-w^2)/2 pi``, for a divergent one: the rest state is unstable);
    ``damped_frequency`` [Hz] and ``damping_ratio`` of the pair of eigenvalues of ``A`` (``poles`` [1/s], n x 2) paired
    with each mode (NaN ratio for a mode of zero or negative frequency); ``shapes`` (3F x n): the undamped mode shapes
    in particle coordinates, mass-normalised (``shapes^T M shapes = I``), each signed so that its largest entry is
    positive."""

    frequency: Float[Array, " n"]
    damped_frequency: Float[Array, " n"]
    damping_ratio: Float[Array, " n"]
    shapes: Float[Array, "3F n"]
    poles: Complex[Array, "n 2"]


def _basis(j: Float[Array, "C 3F"], n_coords: int, dof: int):
    """``(Z, singular values of J)``. ``Z`` is the null space from the SVD; its derivative is taken through
    ``Z0 - J^+ J Z0`` (``Z0`` the SVD's basis, held constant), which needs no distinct singular values (the
    SVD's derivative does, and a null space's are all zero)."""
    if j.shape[0] == 0:
        return jnp.eye(n_coords, dtype=j.dtype), jnp.zeros(0, j.dtype)
    _, sv, vt = jnp.linalg.svd(jax.lax.stop_gradient(j), full_matrices=True)
    z0 = vt[n_coords - dof:].T
    return z0 - jnp.linalg.pinv(j, rtol=RANK_RTOL) @ (j @ z0), sv


def _apply_mass(prep, y: Float[Array, "3F n"]) -> Float[Array, "3F n"]:
    """``M y`` with ``M = M_s (x) I_3`` (:mod:`.dynamics`)."""
    f, n = prep.ms.shape[0], y.shape[1]
    return jnp.einsum("fg,gin->fin", prep.ms, y.reshape(f, 3, n)).reshape(3 * f, n)


@compiled("linearize", static=("dof",))
def _linearize(mech: Mechanism, t, q, contact, *, dof: int):
    """``(Linearization, qdd at rest, singular values of J, constraint residuals)``."""
    prep = prepare(mech)
    if contact is None:  # each one-sided element's law as it is at q
        contact = one_sided_gaps(mech, mech.point_positions(mech.all_positions(q)), t) < 0.0
    z, sv = _basis(constraint_jacobian.raw(mech, q, t=t), q.shape[0], dof)
    qd0 = jnp.zeros_like(q)
    a0, tangent = jax.linearize(lambda x, v: _solve(mech, prep, t, x, v, 0.0, contact=contact.astype(bool))[0], q, qd0)
    zero = jnp.zeros_like(z)
    a_q = jax.vmap(tangent, in_axes=(1, 1), out_axes=1)(z, zero)  # (d qdd / d q) Z
    a_v = jax.vmap(tangent, in_axes=(1, 1), out_axes=1)(zero, z)  # (d qdd / d qd) Z
    mz = _apply_mass(prep, z)
    m_r, k_r, c_r = z.T @ mz, -mz.T @ a_q, -mz.T @ a_v
    cho = jsl.cho_factor(m_r, lower=True)
    eye = jnp.eye(dof, dtype=q.dtype)
    a = jnp.block([[jnp.zeros_like(eye), eye], [-jsl.cho_solve(cho, k_r), -jsl.cho_solve(cho, c_r)]])
    lin = Linearization(basis=z, mass=m_r, stiffness=k_r, damping=c_r, A=a)
    return lin, a0, sv, constraints.raw(mech, q, t=t)


def _pair(vr: Complex[Array, "2n 2n"], n: int) -> Array:
    """``(n, 2)`` indices of the eigenvalues each mode takes: greedily, the largest share of an eigenvector's
    position part (modal coordinates, so mass-weighted) on one mode, two eigenvalues per mode."""
    share = jnp.abs(vr[:n]) ** 2
    share = share / jnp.sum(share, axis=0, keepdims=True)

    def step(_, state):
        taken, count, pick = state
        score = jnp.where(taken[None, :] | (count[:, None] >= 2), -1.0, share)
        i, k = jnp.divmod(jnp.argmax(score), 2 * n)
        return taken.at[k].set(True), count.at[i].add(1), pick.at[i, count[i]].set(k)

    init = (jnp.zeros(2 * n, bool), jnp.zeros(n, int), jnp.zeros((n, 2), int))
    return jax.lax.fori_loop(0, 2 * n, step, init)[2]


def _eigenvalues(am: Float[Array, "2n 2n"]):
    """Eigenvalues of ``am`` and its right eigenvectors (held constant); the eigenvalues differentiate by first-order
    perturbation, ``ds = u^H dA v / u^H v`` (simple eigenvalues; ``u``, ``v`` left and right eigenvectors)."""
    fixed = jax.lax.stop_gradient(am)
    s, ul, vr = jax.lax.linalg.eig(fixed)
    da = (am - fixed).astype(s.dtype)
    ds = jnp.einsum("ik,ij,jk->k", jnp.conj(ul), da, vr) / jnp.einsum("ik,ik->k", jnp.conj(ul), vr)
    return s + ds, vr


@compiled("modes", static=("dof",))
def _modes(mech: Mechanism, t, q, contact, *, dof: int):
    lin, a0, sv, phi = _linearize.raw(mech, t, q, contact, dof=dof)
    # K_r v = w^2 M_r v by eigh of L^-1 K L^-T (M_r = L L^T), the symmetric part of K_r
    low = jnp.linalg.cholesky(lin.mass)
    k_sym = 0.5 * (lin.stiffness + lin.stiffness.T)
    half = jsl.solve_triangular(low, k_sym, lower=True)
    kt = jsl.solve_triangular(low, half.T, lower=True)
    w2, u = jnp.linalg.eigh(0.5 * (kt + kt.T))
    v = jsl.solve_triangular(low.T, u, lower=False)  # mass-normalised: v^T M_r v = I
    shapes = lin.basis @ v
    big = jnp.take_along_axis(shapes, jnp.argmax(jnp.abs(shapes), axis=0)[None, :], axis=0)[0]
    sign = jnp.where(big < 0.0, -1.0, 1.0)
    v, shapes = v * sign[None, :], shapes * sign[None, :]
    zero = jnp.abs(w2) <= ZERO_RTOL * jnp.max(jnp.abs(w2))
    omega = jnp.where(zero, 0.0, jnp.sign(w2) * jnp.sqrt(jnp.where(zero, 1.0, jnp.abs(w2))))
    # the damped problem in modal coordinates z = v eta: similar to A
    eye = jnp.eye(dof, dtype=q.dtype)
    am = jnp.block([[jnp.zeros_like(eye), eye], [-v.T @ lin.stiffness @ v, -v.T @ lin.damping @ v]])
    s, vr = _eigenvalues(am)
    pick = _pair(jax.lax.stop_gradient(vr), dof)
    p1, p2 = s[pick[:, 0]], s[pick[:, 1]]
    wn2 = jnp.real(p1 * p2)
    ok = ~zero & (omega > 0.0) & (wn2 > 0.0)
    wn = jnp.sqrt(jnp.where(ok, wn2, 1.0))
    ratio = jnp.where(ok, -jnp.real(p1 + p2) / (2.0 * wn), jnp.nan)
    damped = jnp.where(zero, 0.0, 0.5 * (jnp.abs(jnp.imag(p1)) + jnp.abs(jnp.imag(p2))))
    modes_ = Modes(frequency=omega / (2 * np.pi), damped_frequency=damped / (2 * np.pi), damping_ratio=ratio,
                   shapes=shapes, poles=jnp.stack([p1, p2], axis=1))
    return modes_, a0, sv, phi


def _inputs(entry: str, mech: Mechanism, q, t, contact, dof):
    """Checked ``(q, t, contact, dof)``; ``dof`` from the rank of ``J(q)`` when not given (needs a concrete ``q``)."""
    q = jnp.asarray(q, dtype=jnp.float64)
    n = mech.n_coords
    if q.shape != (n,):
        raise ModelError(f"{entry}: q must have shape ({n},) (3 coordinates per free particle), got {q.shape}")
    concrete = _ode._concrete(q)
    if concrete and not np.all(np.isfinite(np.asarray(q))):
        raise ModelError(f"{entry}: q has non-finite entries")
    if contact is not None:
        names = one_sided_names(mech)
        contact = jnp.asarray(contact, bool)
        if contact.shape != (len(names),):
            raise ModelError(f"{entry}: contact must have one entry per one-sided element (tyres, then bump stops): "
                             f"{list(names)}, got shape {contact.shape}")
    if dof is not None and (isinstance(dof, bool) or not isinstance(dof, (int, np.integer)) or not 0 < dof <= n):
        raise ModelError(f"{entry}: dof must be an integer in [1, {n}], got {dof!r}")
    if concrete:  # the freedoms at q, from the rank of J as the builder counts it
        j = np.asarray(constraint_jacobian(mech, q, t=t)).reshape(-1, n)
        free = n - _rank(np.linalg.svd(j, compute_uv=False) if j.shape[0] else np.zeros(0))
        if free == 0:
            raise ModelError(f"{entry}: the mechanism has no degree of freedom at q: nothing to linearise")
        if dof is not None and dof != free:
            raise ModelError(f"{entry}: dof={dof}, but the constraint Jacobian at q leaves {free} degrees of freedom")
        dof = free
    elif dof is None:
        raise ModelError(f"{entry}: q is traced (under jit, grad or vmap): pass dof= (the degrees of freedom)")
    return q, jnp.asarray(t, jnp.float64), contact, int(dof)


def _rank(sv) -> int:
    return int(np.sum(sv > RANK_RTOL * sv[0])) if sv.size else 0


def _checked(entry: str, mech: Mechanism, out, a0, sv, phi, dof: int, rest_tol: float):
    """Refuse a state that is not at rest or off the constraints; traced, also one whose freedoms are not ``dof``
    (concrete, :func:`_inputs` counted them)."""
    limit = rest_tol * max(float(np.linalg.norm(np.asarray(mech.gravity))), 1.0) \
        if _ode._concrete(mech.gravity) else rest_tol * 9.81
    if all(_ode._concrete(x) for x in (a0, phi)):
        amax = float(jnp.max(jnp.abs(a0)))
        if not amax <= limit:
            raise ModelError(f"{entry}: not an equilibrium: max acceleration {amax:.3g} m/s² (pass "
                             "static_equilibrium(mech, q).q)")
        pmax = float(jnp.max(jnp.abs(phi), initial=0.0))
        if not pmax <= PHI_TOL:
            raise ModelError(f"{entry}: q violates the constraints: max residual {pmax:.3g} (pass "
                             "static_equilibrium(mech, q).q)")
        if not np.all(np.isfinite(np.asarray(out.frequency if isinstance(out, Modes) else out.A))):
            raise ModelError(f"{entry}: the reduced mass matrix is not positive definite at q: an admissible motion "
                             "moves no mass (a massless particle's freedom)")
        return out
    out = eqx.error_if(out, jnp.max(jnp.abs(a0)) > limit,
                       f"{entry}: not an equilibrium: an acceleration at zero velocity exceeds {limit:.3g} m/s² "
                       "(pass static_equilibrium(mech, q).q)")
    out = eqx.error_if(out, jnp.max(jnp.abs(phi), initial=0.0) > PHI_TOL,
                       f"{entry}: q violates the constraints (pass static_equilibrium(mech, q).q)")
    rank, tol = mech.n_coords - dof, RANK_RTOL * sv[0] if sv.shape[0] else 0.0
    wrong = rank > sv.shape[0] or (rank >= 1 and sv[rank - 1] <= tol)
    if rank < sv.shape[0]:
        wrong = wrong | (sv[rank] > tol)
    out = eqx.error_if(out, wrong, f"{entry}: dof={dof} is not the degrees of freedom at q")
    return out


def linearize(mech: Mechanism, q, *, t=0.0, contact=None, dof: int | None = None,
              rest_tol: float = REST_RTOL) -> Linearization:
    """The linear equations of motion about the rest state ``q`` (3F,) at time ``t`` (module docstring); ``q``
    typically ``static_equilibrium(mech, q0).q``.

    ``contact``: each one-sided element's law (tyres, then bump stops, :func:`~.forces.one_sided_names`; engaged or
    not), default as at ``q``. ``dof``: the degrees of freedom, read from the rank of the constraint Jacobian at ``q``
    when not given; needed when ``q`` is traced. Refuses (``ModelError``) a ``q`` of the wrong shape, off the
    constraints, or not at rest (an acceleration at zero velocity above ``rest_tol`` times ``|g|``). Compiled once per
    mechanism structure and ``dof``; differentiable in the mechanism's parameters and ``q``."""
    q, t, contact, dof = _inputs("linearize", mech, q, t, contact, dof)
    lin, a0, sv, phi = _linearize(mech, t, q, contact, dof=dof)
    return _checked("linearize", mech, lin, a0, sv, phi, dof, rest_tol)


def modes(mech: Mechanism, q, *, t=0.0, contact=None, dof: int | None = None, rest_tol: float = REST_RTOL) -> Modes:
    """The modes of vibration about the rest state ``q`` (:class:`Modes`; arguments and checks as
    :func:`linearize`). Compiled once per mechanism structure and ``dof``. Differentiable in the parameters for
    distinct frequencies (``eigh``'s derivative, and the poles' first-order perturbation, need simple eigenvalues);
    the pairing of poles with modes is held constant."""
    q, t, contact, dof = _inputs("modes", mech, q, t, contact, dof)
    out, a0, sv, phi = _modes(mech, t, q, contact, dof=dof)
    return _checked("modes", mech, out, a0, sv, phi, dof, rest_tol)
