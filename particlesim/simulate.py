"""Time integration of second-order mechanical systems with diffrax.

The state is the pair y = (q, q̇) and the vector field is the first-order form of M(q) q̈ + h(q, q̇) = τ:

    d/dt (q, q̇) = (q̇, dynamics(params, q, q̇, τ(t, q, q̇, params)))

with ``dynamics`` any function returning q̈ (for a tree robot ``particlesim.tree.forward_dynamics``) and ``τ`` an
optional control law. Everything is a pure JAX function of ``(params, q0, qd0)``: it can be jitted, vmapped over
parameter sets and initial states, and differentiated (reverse mode through diffrax's checkpointed
``RecursiveCheckpointAdjoint`` by default; forward mode with ``adjoint="forward"``).

Solvers are chosen by name (:data:`SOLVERS`). Steps are adaptive with a PID controller on the mixed error norm
``atol + rtol·|y|``. Implicit solvers (Kvaerno) solve their stage equations with diffrax's default root finder, a
chord-Newton iteration (``VeryChord``) whose tolerances are taken from the step-size controller, with the Jacobian
of the vector field formed by automatic differentiation (dense, fine for tens of joints).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int, Bool

from .errors import ModelError

__all__ = ["SOLVERS", "IMPLICIT_SOLVERS", "Solution", "simulate"]

#: Adaptive solvers by name. Explicit: Tsitouras 5(4), Dormand–Prince 5(4) and 8(7).
#: Implicit (L-stable ESDIRK, for stiff friction or stiff springs): Kvaerno 3(2), 4(3), 5(4).
SOLVERS: dict[str, type[diffrax.AbstractSolver]] = {
    "bosh3": diffrax.Bosh3,
    "tsit5": diffrax.Tsit5,
    "dopri5": diffrax.Dopri5,
    "dopri8": diffrax.Dopri8,
    "kvaerno3": diffrax.Kvaerno3,
    "kvaerno4": diffrax.Kvaerno4,
    "kvaerno5": diffrax.Kvaerno5,
}
IMPLICIT_SOLVERS = frozenset({"kvaerno3", "kvaerno4", "kvaerno5"})

# PID coefficients (pcoeff, icoeff, dcoeff): a PI controller with full integral gain suits smooth non-stiff
# problems; a less sensitive one suits the stiff problems implicit solvers are used for (diffrax's guidance).
_PID_EXPLICIT = (0.4, 1.0, 0.0)
_PID_IMPLICIT = (0.3, 0.3, 0.0)

_ADJOINTS: dict[str, Callable[[], diffrax.AbstractAdjoint]] = {
    "checkpoint": diffrax.RecursiveCheckpointAdjoint,
    "direct": diffrax.DirectAdjoint,
    "forward": diffrax.ForwardMode,
    "backsolve": diffrax.BacksolveAdjoint,
}


class Solution(eqx.Module):
    """Saved trajectory of :func:`simulate`.

    ``ts``: (T,) save times; ``q``, ``qd``: (T, n). ``steps``/``rejected``: accepted and rejected step counts.
    ``status``: diffrax ``RESULTS`` code, ``ok``: whether t1 was reached. When ``ok`` is false (only possible with
    ``throw=False``), ``q`` and ``qd`` are all NaN: a failed run never returns numbers that look valid.
    """

    ts: Float[Array, " T"]
    q: Float[Array, "T n"]
    qd: Float[Array, "T n"]
    steps: Int[Array, ""]
    rejected: Int[Array, ""]
    status: diffrax.RESULTS
    ok: Bool[Array, ""]


def _solver(name: str) -> diffrax.AbstractSolver:
    try:
        return SOLVERS[name.lower()]()
    except (KeyError, AttributeError):
        raise ValueError(f"unknown solver {name!r}; choose one of {sorted(SOLVERS)}") from None


def _adjoint(adjoint: str | diffrax.AbstractAdjoint | None) -> diffrax.AbstractAdjoint:
    if adjoint is None:
        return diffrax.RecursiveCheckpointAdjoint()
    if isinstance(adjoint, diffrax.AbstractAdjoint):
        return adjoint
    if adjoint in _ADJOINTS:
        return _ADJOINTS[adjoint]()
    raise ValueError(f"unknown adjoint {adjoint!r}; choose one of {sorted(_ADJOINTS)} or a diffrax adjoint")


def _check_state(params: Any, q0: Array, qd0: Array) -> None:
    """Shape checks (static) and a NaN check (eager when the values are concrete, else a runtime check)."""
    if q0.ndim != 1 or qd0.shape != q0.shape:
        raise ModelError(
            f"initial state must be two vectors of the same length n, got q0 {q0.shape} and qd0 {qd0.shape} "
            "(batch with jax.vmap, not by stacking)"
        )
    nq = getattr(params, "nq", None)
    if isinstance(nq, (int, np.integer)) and q0.shape[0] != nq:
        raise ModelError(f"initial state has {q0.shape[0]} coordinates but the model has nq = {nq}")
    for name, x in (("q0", q0), ("qd0", qd0)):
        if not isinstance(x, jax.core.Tracer):
            bad = np.flatnonzero(~np.isfinite(np.asarray(x)))
            if bad.size:
                raise ValueError(f"{name} is not finite at coordinates {bad.tolist()}")


def _finite_params(params: Any, q0: Array) -> Array:
    """Refuse non-finite floating leaves of ``params`` (e.g. set with ``with_params``/``eqx.tree_at``, which do not
    check): eagerly, naming the leaf and entry, when the values are concrete; else by a run-time error."""
    flat = [(jax.tree_util.keystr(path), leaf) for path, leaf in jax.tree_util.tree_flatten_with_path(params)[0]
            if eqx.is_inexact_array(leaf)]
    if not flat:
        return q0
    if not any(isinstance(leaf, jax.core.Tracer) for _, leaf in flat):
        for name, leaf in flat:
            a = np.asarray(leaf)
            if not np.all(np.isfinite(a)):
                where = tuple(int(i) for i in np.argwhere(~np.isfinite(a))[0]) if a.ndim else ()
                raise ModelError(f"simulate: parameter {name or 'params'} is not finite (NaN or inf) at entry {where}")
        return q0
    bad = jnp.stack([~jnp.all(jnp.isfinite(leaf)) for _, leaf in flat])
    msgs = [f"simulate: parameter {name or 'params'} is not finite (NaN or inf)" for name, _ in flat]
    return eqx.branched_error_if(q0, jnp.any(bad), jnp.argmax(bad), msgs)


def simulate(
    dynamics: Callable[[Any, Array, Array, Array], Array],
    params: Any,
    q0: Float[Array, " n"],
    qd0: Float[Array, " n"],
    t0: float,
    t1: float,
    *,
    control: Callable[[Array, Array, Array, Any], Array] | None = None,
    solver: str = "tsit5",
    rtol: float = 1e-8,
    atol: float = 1e-10,
    dt0: float | None = None,
    saveat_ts: Float[Array, " T"] | None = None,
    max_steps: int = 16384,
    adjoint: str | diffrax.AbstractAdjoint | None = None,
    pid: tuple[float, float, float] | None = None,
    throw: bool = True,
    progress: bool = False,
) -> Solution:
    """Integrate q̈ = dynamics(params, q, q̇, τ) from (q0, qd0) at t0 to t1.

    Args:
        dynamics: ``(params, q (n,), qd (n,), tau (n,)) -> qdd (n,)``.
        params: pytree of parameters (e.g. a ``TreeModel``); its array leaves may be traced (vmap, grad).
            If it has an integer attribute ``nq``, the state length is checked against it.
        q0, qd0: initial generalised coordinates and velocities, shape (n,).
        t0, t1: time interval.
        control: ``(t, q, qd, params) -> tau (n,)``, evaluated at every solver stage (exact, not held per
            step); ``None`` means zero generalised force.
        solver: a name in :data:`SOLVERS`.
        rtol, atol: tolerances of the PID step-size controller (and of the implicit solvers' root finder).
        dt0: first step; ``None`` lets diffrax choose it from the tolerances.
        saveat_ts: (T,) times in [t0, t1] at which to save; ``None`` saves at t0 and t1.
        max_steps: step budget; reaching it is an error (see ``throw``).
        adjoint: ``None``/"checkpoint" (reverse mode, default), "forward" (forward mode, for ``jax.jvp``),
            "direct" (both, more memory), "backsolve", or any diffrax adjoint.
        pid: (pcoeff, icoeff, dcoeff) of the controller; defaults (0.4, 1, 0) explicit, (0.3, 0.3, 0) implicit.
        throw: if True (default) a failed integration raises at run time (also under jit); if False the
            returned :class:`Solution` has ``ok = False`` and NaN trajectories.
        progress: show a tqdm progress bar.

    Raises:
        ValueError: unknown solver or adjoint name; non-finite concrete initial state.
        ModelError: q0/qd0 shapes disagree with each other, with ``params.nq`` or with what ``dynamics`` returns;
            a floating parameter is NaN or inf (at run time when traced).
    """
    q0 = jnp.asarray(q0, dtype=float)
    qd0 = jnp.asarray(qd0, dtype=float)
    name = solver
    solver_ = _solver(solver)
    adjoint_ = _adjoint(adjoint)
    _check_state(params, q0, qd0)

    def tau_of(t, q, qd):
        if control is None:
            return jnp.zeros_like(q)
        return control(t, q, qd, params)

    out = jax.eval_shape(lambda q, qd: dynamics(params, q, qd, tau_of(t0, q, qd)), q0, qd0)
    if out.shape != q0.shape:
        raise ModelError(f"dynamics returned shape {out.shape} for a state of shape {q0.shape}")

    # Runtime guard for traced initial states (under jit/vmap the eager check above cannot see values).
    finite = jnp.all(jnp.isfinite(q0)) & jnp.all(jnp.isfinite(qd0))
    q0 = eqx.error_if(q0, ~finite, "simulate: initial state (q0, qd0) is not finite")
    q0 = _finite_params(params, q0)

    # The parameters reach diffrax through ``args`` (not a closure), so every adjoint, BacksolveAdjoint included,
    # differentiates them. They travel as their flat list of leaves: diffrax 0.7.2's backsolve fails on ``args``
    # holding empty tuples.
    p_leaves, p_def = jax.tree.flatten(params)

    def vector_field(t, y, leaves):
        p = jax.tree.unflatten(p_def, leaves)
        q, qd = y
        tau = jnp.zeros_like(q) if control is None else control(t, q, qd, p)
        return qd, dynamics(p, q, qd, tau)

    pcoeff, icoeff, dcoeff = pid or (_PID_IMPLICIT if name.lower() in IMPLICIT_SOLVERS else _PID_EXPLICIT)
    controller = diffrax.PIDController(rtol=rtol, atol=atol, pcoeff=pcoeff, icoeff=icoeff, dcoeff=dcoeff)
    saveat = diffrax.SaveAt(t0=True, t1=True) if saveat_ts is None else diffrax.SaveAt(ts=jnp.asarray(saveat_ts))
    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(vector_field),
        solver_,
        t0=t0,
        t1=t1,
        dt0=dt0,
        y0=(q0, qd0),
        args=p_leaves,
        saveat=saveat,
        stepsize_controller=controller,
        adjoint=adjoint_,
        max_steps=max_steps,
        throw=throw,
        progress_meter=diffrax.TqdmProgressMeter() if progress else diffrax.NoProgressMeter(),
    )
    ok = sol.result == diffrax.RESULTS.successful
    q, qd = (jnp.where(ok, y, jnp.nan) for y in sol.ys)
    return Solution(
        ts=sol.ts,
        q=q,
        qd=qd,
        steps=sol.stats["num_accepted_steps"],
        rejected=sol.stats["num_rejected_steps"],
        status=sol.result,
        ok=ok,
    )
