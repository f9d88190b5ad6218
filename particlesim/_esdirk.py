"""An ESDIRK solver for constrained second-order systems, with a Newton matrix built from the system's structure.

The system is ``M(q) a + J(q)^T lam = Q(t, q, v)``, ``J(q) a = gamma(t, q, v)`` with ``q' = v``, ``v' = a``
(``J`` empty for an unconstrained system). An explicit-first-stage, singly diagonally implicit Runge–Kutta method
(the Kvaerno tableaux of diffrax, L-stable, stiffly accurate) takes each implicit stage as one unknown pair: the
stage velocity ``V`` and the scaled multipliers ``L = g lam`` (``g = h gamma_ii``). With ``zq``, ``zv`` the explicit
parts of the stage, ``Q_s = zq + g V`` and the stage acceleration ``(V - zv) / g``, the stage equations are

    F1 = M (V - zv) + J(Q_s)^T L - g Q(t, Q_s, V) = 0,      F2 = J(Q_s) (V - zv) - g gamma(t, Q_s, V) = 0

— no constraint solve inside the residual. Their Newton matrix, with ``K = -dQ/dq`` and ``C = -dQ/dv`` (the
constraint forces' own stiffness ``d(J^T lam)/dq`` included in ``K``), is the saddle-point matrix

    [[M + g C + g^2 K, J^T], [J, 0]]

whose parts the system gives locally (the force elements' derivatives alone, never the whole first-order field).
It is formed at a step's start and inverted (each iteration is then one matrix-vector product), used by every stage
of the step (modified Newton), and kept for the next step while its iterations contracted fast and the step size
stayed near the one it was formed for (:data:`REUSE_RATE`, :data:`REUSE_SPAN`; under ``vmap`` the choice becomes a
select and a new matrix is formed every step). A stage solve takes at least two iterations (the second measures
the contraction ``theta``) and stops when the estimated remaining error ``theta / (1 - theta) |dx|`` is below
``kappa`` of the step's tolerance (Hairer & Wanner, Solving ODEs II, §IV.8; ``kappa = max(10 eps / rtol,
min(0.03, sqrt(rtol)))``, RADAU5's rule), or when a correction below ``kappa`` stops shrinking (the rounding
floor); it fails only on divergence (``theta > DIVERGENCE`` from the third iterate on), a non-finite iterate, or at
``MAX_ITERATIONS``, and then the step is rejected (an infinite error estimate: the controller shrinks it).

Derivatives of each stage solve come from the implicit function theorem (``jax.lax.custom_root``), with the exact
Jacobian of the stage equations, so reverse and forward mode through the solver are those of the converged stages.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, ClassVar

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import jax.scipy.linalg
import numpy as np

__all__ = ["SecondOrderSystem", "StructuredESDIRK", "field_system", "METHODS", "MAX_ITERATIONS", "DIVERGENCE"]

#: The tableaux by solver name (diffrax's Kvaerno 3(2), 4(3), 5(4): explicit first stage, stiffly accurate).
METHODS: dict[str, type] = {"kvaerno3": diffrax.Kvaerno3, "kvaerno4": diffrax.Kvaerno4,
                            "kvaerno5": diffrax.Kvaerno5}
#: Diagnostics: a list here when a rollout is traced makes every attempted step of it append
#: ``(h, newton_iterations, converged, matrix_reused)`` (host callback; single rollouts, not under ``vmap``; for
#: benchmarks, off by default).
STEP_LOG: list | None = None
#: A stage solve that has not converged after this many iterations fails (the step is rejected).
MAX_ITERATIONS = 10
#: A stage solve whose iterates grow by more than this factor per iteration fails (diverging).
DIVERGENCE = 2.0
#: The Newton matrix of the previous step is used again while its iterations contracted by at most this factor
#: and the step size is within a factor REUSE_SPAN of the one it was formed for; else a new one is formed.
REUSE_RATE = 0.05
REUSE_SPAN = 1.1
#: A correction below this fraction of the stage tolerance ends the solve (its size is then at the rounding floor).
FLOOR = 1e-3


class SecondOrderSystem(eqx.Module):
    """What :class:`StructuredESDIRK` needs of a system (every callable takes the solve's ``args`` last).

    ``accelerations(t, q, v, args) -> (a (n,), lam (m,))``: the explicit solve (first stage).
    ``residual(t, q, v, L, zv, g, args, modes) -> (n + m,)``: the stage equations ``(F1, F2)`` above.
    ``matrix(t, q, v, lam, g, args, modes) -> (n + m, n + m)``: their Newton matrix at ``(q, v)``.
    ``modes(t, q, v, args)``: the law of each switching element (a tyre in contact or not, ...) at a state, or
    None: each stage solve holds the laws read at its starting value, so that its equations are smooth (Newton's
    method does not converge across a jump of the force). Stages on both sides of a switch see different laws,
    which the error estimate shows; a stage whose solution lies just across a surface from its starting value keeps
    the starting law (an error of the order of the step's, as an explicit solver stepping across the switch).
    ``n_mult``: ``m``, the number of multipliers (0 without constraints).
    """

    accelerations: Callable = eqx.field(static=True)
    residual: Callable = eqx.field(static=True)
    matrix: Callable = eqx.field(static=True)
    n_mult: int = eqx.field(static=True)
    modes: Callable | None = eqx.field(static=True, default=None)


def _predictor(c):
    """Starting values of each stage's acceleration: the previous stage at the same abscissa where there is one,
    else the polynomial through the (up to three) previous stages nearest in ``c``, extrapolated to ``c_i``."""
    s = c.shape[0]
    p = np.zeros((s, s))
    for i in range(1, s):
        same = [j for j in range(i) if c[j] == c[i]]
        if same:
            p[i, same[-1]] = 1.0
            continue
        near = sorted({float(c[j]): j for j in range(i)}.items(), key=lambda cj: abs(cj[0] - c[i]))[:3]
        for k, (ck, jk) in enumerate(near):
            others = [cm for m_, (cm, _) in enumerate(near) if m_ != k]
            p[i, jk] = np.prod([(c[i] - cm) / (ck - cm) for cm in others])
    return p


def _tableau(method: str):
    tab = METHODS[method].tableau
    s = tab.b_sol.shape[0]
    a = np.zeros((s, s))
    for i, row in enumerate(tab.a_lower, start=1):
        a[i, :i] = row
    c = np.concatenate([[0.0], tab.c])
    p = _predictor(c)
    diag = np.asarray(tab.a_diagonal, dtype=float)
    assert diag[0] == 0.0 and np.all(diag[1:] == diag[1]), "an ESDIRK tableau (explicit first stage, one gamma)"
    return a, p, c, np.asarray(tab.b_sol, float), np.asarray(tab.b_error, float), float(diag[1])


class _State(eqx.Module):
    """Carried from one accepted step to the next: the inverse Newton matrix ``inv`` formed with ``g``, the largest
    over the last step's stage solves of their final contraction (``rate``), and whether it may be reused
    (``valid``)."""

    inv: Any
    g: Any
    rate: Any
    valid: Any


class StructuredESDIRK(diffrax.AbstractAdaptiveSolver):
    """Kvaerno ESDIRK on the structured Newton matrix of a :class:`SecondOrderSystem` (module docstring).

    ``rtol``/``atol`` are the step-size controller's (the stage solves stop at a fraction of them); ``method``
    one of :data:`METHODS`. Dense output: cubic Hermite on the step's ends (as diffrax's Kvaerno solvers)."""

    system: SecondOrderSystem
    rtol: Any
    atol: Any
    method: str = eqx.field(static=True, default="kvaerno5")

    term_structure: ClassVar = diffrax.AbstractTerm
    interpolation_cls: ClassVar = diffrax.ThirdOrderHermitePolynomialInterpolation.from_k

    def order(self, terms):
        return METHODS[self.method]().order(terms)

    def error_order(self, terms):
        return METHODS[self.method]().error_order(terms)

    def init(self, terms, t0, t1, y0, args):
        q0 = y0[0]
        size = q0.shape[0] + self.system.n_mult
        zero = jnp.zeros((), q0.dtype)
        return _State(inv=jnp.zeros((size, size), q0.dtype), g=zero, rate=zero, valid=jnp.asarray(False))

    def func(self, terms, t0, y0, args):
        return terms.vf(t0, y0, args)

    def step(self, terms, t0, t1, y0, args, solver_state, made_jump):
        a_tab, p_tab, c_tab, b_sol, b_err, gam = _tableau(self.method)
        sys_ = self.system
        q0, v0 = y0
        n, m = q0.shape[0], sys_.n_mult
        dtype = q0.dtype
        h = t1 - t0
        g = h * gam
        rtol = jnp.asarray(self.rtol, dtype)
        atol = jnp.asarray(self.atol, dtype)
        eps = jnp.finfo(dtype).eps
        # Stage solves stop at kappa of the step's tolerance (RADAU5's rule: tighter for tighter rtol).
        kappa = jnp.maximum(10.0 * eps / rtol, jnp.minimum(0.03, jnp.sqrt(rtol)))
        sq = atol + rtol * jnp.abs(q0)
        sv = atol + rtol * jnp.abs(v0)
        st = solver_state

        def modes_at(t, q, v):
            return None if sys_.modes is None else sys_.modes(t, q, v, args)

        a0, lam0 = sys_.accelerations(t0, q0, v0, args)

        # The Newton matrix's inverse: each iteration is then one matrix-vector product (a pair of triangular solves
        # costs several times more at these sizes). Kept from the previous step while that step's iterations
        # contracted fast and the step size is near the one it was formed for; an iteration device only, so no
        # derivative flows through it (the stages' derivatives come from their own equations).
        def fresh():
            mat = sys_.matrix(t0, q0, v0, lam0, g, args, modes_at(t0, q0, v0))
            return jax.lax.stop_gradient(jnp.linalg.inv(mat)), jax.lax.stop_gradient(g)

        ratio = g / jnp.where(st.valid, st.g, 1.0)
        reuse = (st.valid & (st.rate <= REUSE_RATE) & (ratio <= REUSE_SPAN) & (ratio >= 1.0 / REUSE_SPAN)
                 & ~jnp.asarray(made_jump))
        inv, g_inv = jax.lax.cond(reuse, lambda: (st.inv, st.g), fresh)

        def norm(dv):  # RMS of the velocity correction and the position correction it implies, scaled
            return jnp.sqrt(0.5 * (jnp.mean((dv / sv) ** 2) + jnp.mean((g * dv / sq) ** 2)))

        def newton(f, x0):
            def cond(c):
                _, k, _, _, _, done, fail = c
                return ~done & ~fail & (k < MAX_ITERATIONS)

            def body(c):
                x, k, prev, eta, _, _, _ = c
                dx = -(inv @ f(x))
                x = x + dx
                size = norm(dx[:n])
                theta = size / prev
                eta = jnp.where(k > 0, theta / jnp.maximum(1.0 - theta, eps), eta)
                contracting = (k > 0) & (theta < 1.0)
                # Converged: the remaining error estimated below kappa; or a correction already below kappa that
                # no longer shrinks (the rounding floor, where ratios of corrections measure noise, not
                # contraction: at tight tolerances it lies above kappa's own rounding term); or a correction so far
                # below kappa that it is at that floor.
                floor = (k > 0) & ~contracting & (size <= kappa)
                done = (size <= FLOOR * kappa) | (contracting & (eta * size <= kappa)) | floor
                # Diverging: judged from the third iterate on; the first correction starts from predicted
                # multipliers, and the second may exceed it while the iteration converges.
                fail = ~jnp.isfinite(size) | ((k > 1) & (theta > DIVERGENCE) & ~done)
                rate = jnp.where((k > 0) & (size > FLOOR * kappa), theta, 0.0)
                return x, k + 1, size, eta, rate, done, fail

            start = (x0, 0, jnp.asarray(jnp.inf, dtype), jnp.ones((), dtype), jnp.zeros((), dtype), False, False)
            x, k, _, _, rate, done, _ = jax.lax.while_loop(cond, body, start)
            # A failed solve returns its starting value (finite: the step is rejected, and the derivative pass
            # then solves a finite tangent system instead of one at a diverged iterate). Aux values as floats:
            # custom_root gives its auxiliary outputs tangents of their own dtype.
            x = jnp.where(done, x, x0)
            return x, jax.lax.stop_gradient((done.astype(dtype), rate, k.astype(dtype)))

        def tangent_solve(lin, y):  # the exact Jacobian of the stage equations, for derivatives only
            return jnp.linalg.solve(jax.jacfwd(lin)(y), y)

        s_ = a_tab.shape[0]
        kv0 = jnp.zeros((s_, n), dtype).at[0].set(v0)
        ka0 = jnp.zeros((s_, n), dtype).at[0].set(a0)
        kl0 = jnp.zeros((s_, m), dtype).at[0].set(lam0)

        def stage(carry, row):
            kv, ka, kl, rate, ok, iters = carry
            a_i, p_i, c_i, i = row
            zq = q0 + h * (a_i @ kv)
            zv = v0 + h * (a_i @ ka)
            t_i = t0 + c_i * h
            # the stage's acceleration and multipliers extrapolated from the previous stages'
            x0 = jnp.concatenate([zv + g * (p_i @ ka), g * (p_i @ kl)])
            modes = modes_at(t_i, zq + g * x0[:n], x0[:n])

            def f(x):
                return sys_.residual(t_i, zq + g * x[:n], x[:n], x[n:], zv, g, args, modes)

            x, (done, rate_i, k) = jax.lax.custom_root(f, x0, newton, tangent_solve, has_aux=True)
            done, k = done > 0.5, k.astype(iters.dtype)
            v = x[:n]
            kv = kv.at[i].set(v)
            ka = ka.at[i].set((v - zv) / g)
            kl = kl.at[i].set(x[n:] / g)
            return (kv, ka, kl, jnp.maximum(rate, rate_i), ok & done, iters + k), None

        rows = (jnp.asarray(a_tab[1:], dtype), jnp.asarray(p_tab[1:], dtype), jnp.asarray(c_tab[1:], dtype),
                jnp.arange(1, s_))
        init = (kv0, ka0, kl0, jnp.zeros((), dtype), jnp.asarray(True), jnp.asarray(0))
        (kv, ka, _, rate, ok, iters), _ = jax.lax.scan(stage, init, rows)
        if STEP_LOG is not None:
            jax.debug.callback(lambda *a: STEP_LOG.append(tuple(np.asarray(x).item() for x in a)), h, iters, ok,
                               reuse)
        bs, be = jnp.asarray(b_sol, dtype), jnp.asarray(b_err, dtype)
        y1 = (q0 + h * (bs @ kv), v0 + h * (bs @ ka))
        y_error = (h * (be @ kv), h * (be @ ka))
        y_error = jax.tree.map(lambda e: jnp.where(ok, e, jnp.inf), y_error)
        dense_info = dict(y0=y0, y1=y1, k=(h * kv, h * ka))
        state = _State(inv=inv, g=g_inv, rate=rate, valid=ok)
        return y1, y_error, dense_info, state, diffrax.RESULTS.successful


def field_system(field: Callable) -> SecondOrderSystem:
    """The :class:`SecondOrderSystem` of any first-order field ``field(t, (q, v), args) -> (v, a)`` with ``q' = v``
    (no multipliers): stage equations ``V - zv - g a(t, Q, V) = 0``, Newton matrix ``I - g da/dv - g^2 da/dq``
    from one forward-mode Jacobian of the accelerations at the step's start (``2 n`` columns)."""
    def accel(t, q, v, args):
        return field(t, (q, v), args)[1]

    def accelerations(t, q, v, args):
        return accel(t, q, v, args), jnp.zeros((0,), q.dtype)

    def residual(t, q, v, lam, zv, g, args, modes):
        return v - zv - g * accel(t, q, v, args)

    def matrix(t, q, v, lam, g, args, modes):
        dq, dv = jax.jacfwd(accel, argnums=(1, 2))(t, q, v, args)
        return jnp.eye(q.shape[0], dtype=q.dtype) - g * dv - g * g * dq

    return SecondOrderSystem(accelerations, residual, matrix, 0)
