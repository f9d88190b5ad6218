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

import inspect
import types
from collections.abc import Callable
from typing import Any

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from . import _ode
from ._esdirk import field_system
from ._ode import ADJOINTS, IMPLICIT_SOLVERS, SOLVERS, Solution
from ._xla import top_level
from .errors import ModelError
from .tree.checks import physical_checks, physical_checks_eager
from .tree.kinematics import _parameter_groups as _tree_groups
from .tree.model import TreeModel

__all__ = ["SOLVERS", "IMPLICIT_SOLVERS", "ADJOINTS", "Solution", "simulate"]


def _check_state(params: Any, q0: Array, qd0: Array) -> None:
    """Shape checks (static) and a NaN check (eager when the values are concrete)."""
    nq, nv = getattr(params, "nq", None), getattr(params, "nv", None)
    if not isinstance(nv, (int, np.integer)):
        nv = nq
    if q0.ndim != 1 or qd0.ndim != 1 or (nq == nv and qd0.shape != q0.shape):
        raise ModelError(
            f"initial state must be two vectors of the same length n, got q0 {q0.shape} and qd0 {qd0.shape} "
            "(batch with jax.vmap, not by stacking)"
        )
    if isinstance(nq, (int, np.integer)) and (q0.shape[0], qd0.shape[0]) != (nq, nv):
        raise ModelError(f"initial state has {q0.shape[0]} configuration entries and {qd0.shape[0]} velocities but "
                         f"the model has nq = {nq}, nv = {nv}")
    _ode.check_state((q0, qd0), ("q0", "qd0"))
    # A plain method is called through the class: an equinox module wraps a bound method it hands out in a new
    # module (a cost on every call). Anything else (a static or class method, a field, a property) as the instance
    # has it.
    if isinstance(inspect.getattr_static(type(params), "check_configuration", None), types.FunctionType):
        type(params).check_configuration(params, q0)
    elif (check := getattr(params, "check_configuration", None)) is not None:
        check(q0)


#: Structures whose ``dynamics``/``control`` output shapes passed :func:`_check_output_shapes` at top level
#: (bounded; under a caller's trace the check runs once per trace anyway, and nothing traced is kept).
_SHAPES_PASSED: dict = {}
_SHAPES_PASSED_MAX = 256


def _check_output_shapes(dynamics, control, params, q0, qd0, t0) -> None:
    """``ModelError`` unless ``control`` and ``dynamics`` return one entry per velocity coordinate, found by
    tracing them (``jax.eval_shape``). Shapes depend on the structure alone (the functions, the parameters' tree and
    leaf shapes, the state's shapes), so a structure that passed is remembered: tracing the dynamics costs a large
    part of a short rollout's call."""
    key = None
    if top_level():
        leaves, treedef = jax.tree.flatten((dynamics, control, params))
        key = (treedef, tuple((v.shape, v.dtype) if isinstance(v, (jax.Array, np.ndarray)) else v for v in leaves),
               q0.shape, qd0.shape)
        try:
            if key in _SHAPES_PASSED:
                return
        except TypeError:  # an unhashable static leaf: checked every call
            key = None

    def tau_of(q, qd):
        return jnp.zeros_like(qd) if control is None else control(t0, q, qd, params)

    if control is not None:
        tau_shape = jax.eval_shape(tau_of, q0, qd0).shape
        if tau_shape != qd0.shape:
            raise ModelError(f"control returned shape {tau_shape} for a velocity of shape {qd0.shape}: it must "
                             "return one generalised force per velocity coordinate (no broadcasting of scalars)")
    out = jax.eval_shape(lambda q, qd: dynamics(params, q, qd, tau_of(q, qd)), q0, qd0)
    if out.shape != qd0.shape:
        raise ModelError(f"dynamics returned shape {out.shape} for a velocity of shape {qd0.shape}")
    if key is not None:
        if len(_SHAPES_PASSED) >= _SHAPES_PASSED_MAX:
            _SHAPES_PASSED.clear()
        _SHAPES_PASSED[key] = True


def _is_tree(x) -> bool:
    return isinstance(x, TreeModel)


def _trees(params) -> list[tuple[str, TreeModel]]:
    """The tree models in ``params`` (itself one, or inside a tuple, dict, module...) with their paths."""
    if isinstance(params, TreeModel):
        return [("", params)]
    flat = jax.tree_util.tree_flatten_with_path(params, is_leaf=_is_tree)[0]
    return [(jax.tree_util.keystr(path), leaf) for path, leaf in flat if isinstance(leaf, TreeModel)]


def _parameter_groups(params) -> list:
    """``(label, array)`` of the parameters' floating leaves by path; a tree's (``params`` itself or inside it) as its
    own entries label them (link by link; soft limits' infinite bounds allowed)."""
    if isinstance(params, TreeModel):
        return _tree_groups(params)
    groups = []
    for path, leaf in jax.tree_util.tree_flatten_with_path(params, is_leaf=_is_tree)[0]:
        where = jax.tree_util.keystr(path)
        if isinstance(leaf, TreeModel):
            groups += [(_joined(where, label) if isinstance(label, str) else [_joined(where, x) for x in label], arr)
                       for label, arr in _tree_groups(leaf)]
        elif eqx.is_inexact_array(leaf):
            groups.append((where or "params", leaf))
    return groups


def _joined(where: str, label: str) -> str:
    """A tree's own label under its path: ``['robot'].limits``, ``['robot'] inertia of link 'b'``."""
    return where + label if label[:1] in ".[" else f"{where} {label}"


def _physical_checks(params):
    """:func:`~particlesim.tree.checks.physical_checks` of every tree in ``params`` (run-time flags), or None."""
    return _ode.merge_checks(*(physical_checks(t, f"simulate{' ' + w if w else ''}") for w, t in _trees(params)))


#: Trees that passed :func:`_physical_checks_eager`: ``id -> (weak reference, leaves then)`` (a tree inside a dict
#: of parameters, which cannot be remembered as a whole, is checked once while it lives).
_TREES_PASSED: dict = {}


def _physical_checks_eager(params) -> None:
    for w, t in _trees(params):
        leaves = jax.tree.leaves(t)
        if not _ode.remembered(_TREES_PASSED, t, leaves):
            physical_checks_eager(t, f"simulate{' ' + w if w else ''}")
            _ode.remember(_TREES_PASSED, t, leaves)


@_ode.cached("simulate")
def _simulate(dynamics, control, params, q0, qd0, t0, t1, rtol, atol, dt0, ts, time_bad, cfg, switch=(),
              max_events=0, warn=(), check_physical=False) -> Solution:
    # A tree's non-physical values are looked for here only when the eager check could not see them (traced leaves).
    param_bad = _ode.merge_checks(_ode.check_finite("simulate", _parameter_groups(params)),
                                  _physical_checks(params) if check_physical else None)
    q0, qd0 = _ode.runtime_checks((q0, qd0), time_bad, param_bad, "simulate", "(q0, qd0)")

    rate = getattr(params, "configuration_rate", None)
    # Implicit solvers: the structured ESDIRK (one Newton matrix per step at most, from the accelerations'
    # Jacobian; particlesim._esdirk) wherever q' = q̇; diffrax's own where a configuration rate maps them.
    identity_rate = rate is None or not getattr(params, "multi_dof", True)  # no free or ball joint: q' = q̇
    structured = cfg.solver in IMPLICIT_SOLVERS and identity_rate
    rate = (lambda p, q, qd: qd) if rate is None else (lambda p, q, qd: p.configuration_rate(q, qd))

    def controlled(t, q, qd, p):
        if control is None:
            return jnp.zeros_like(qd)
        tau = control(t, q, qd, p)
        return eqx.error_if(tau, ~jnp.all(jnp.isfinite(tau)), "simulate: the control returned a non-finite "
                                                                "generalised force")

    def vector_field(t, y, p):
        q, qd = y
        return rate(p, q, qd), dynamics(p, q, qd, controlled(t, q, qd, p))

    events = None
    if switch:  # Coulomb friction of the listed joints at located events: each segment keeps every sign fixed
        idx = np.asarray(switch, dtype=int)

        def field_modes(t, y, args):
            p, modes = args[:2]  # (params, modes, the event's lift)
            q, qd = y
            tau = controlled(t, q, qd, p)
            sign = jnp.sign(qd).at[idx].set(2.0 * modes - 1.0)
            # the friction law of this segment as a generalised force; the model's own Coulomb term is zeroed
            smooth = eqx.tree_at(lambda m: m.coulomb, p, jnp.zeros_like(p.coulomb))
            return rate(p, q, qd), dynamics(smooth, q, qd, tau - p.coulomb * sign)

        def surfaces(t, y, p, modes):
            return (2.0 * modes - 1.0) * y[1][idx]  # the velocity along the segment's sign: crosses zero downwards

        # starting at rest, a joint moves the way it accelerates without its Coulomb friction
        free = eqx.tree_at(lambda m: m.coulomb, params, jnp.zeros_like(params.coulomb))
        tau0 = jnp.zeros_like(qd0) if control is None else control(t0, q0, qd0, params)
        start = jnp.where(qd0 != 0.0, qd0, dynamics(free, q0, qd0, tau0))
        modes0 = (start[idx] >= 0.0).astype(qd0.dtype)
        ts_, (q, qd), steps, rejected, result, ok, ev = _ode.integrate_events(
            field_modes, (q0, qd0), params, modes0, surfaces, len(idx), max_events, t0=t0, t1=t1, rtol=rtol,
            atol=atol, dt0=dt0, ts=ts, cfg=cfg, system=field_system(field_modes) if structured else None)
        joint = jnp.where(ev.element >= 0, jnp.asarray(idx)[jnp.maximum(ev.element, 0)], -1)
        events = _ode.Events(ts=ev.ts, element=joint, active=ev.active)
    else:
        # The parameters reach diffrax through ``args`` (not a closure), so every adjoint, BacksolveAdjoint
        # included, differentiates them.
        ts_, (q, qd), steps, rejected, result, ok = _ode.integrate(
            vector_field, (q0, qd0), params, t0=t0, t1=t1, rtol=rtol, atol=atol, dt0=dt0, ts=ts, cfg=cfg,
            system=field_system(vector_field) if structured else None)
    if warn:  # a differentiated rollout stepping across a Coulomb switch: say so
        w = np.asarray([j for j, _ in warn], dtype=int)
        v = jnp.concatenate([qd0[None], qd])[:, w]
        jax.debug.callback(_ode.warn_switches, jnp.any(jnp.sign(v[1:]) != jnp.sign(v[:-1]), axis=0),
                           labels=[f"Coulomb friction of joint '{n}'" for _, n in warn])
    return Solution(ts=ts_, q=q, qd=qd, steps=steps, rejected=rejected, status=result, ok=ok, events=events)


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
    events: bool = False,
    max_events: int = 16,
    max_step: float | None = None,
) -> Solution:
    """Integrate q̈ = dynamics(params, q, q̇, τ) from (q0, qd0) at t0 to t1.

    Compiles once per ``dynamics``/``control`` function, parameter structure and solver settings: a second call
    with new parameter values, initial state, ``t0``/``t1``, tolerances or save times (of the same count) reuses
    the compiled program. A control with parameters of its own (gains, a torque table) should be an
    ``equinox.Module`` whose arrays are fields, so new values are traced, not baked in (a new lambda per call
    compiles anew).

    Args:
        dynamics: ``(params, q (n,), qd (n,), tau (n,)) -> qdd (n,)``.
        params: pytree of parameters (e.g. a ``TreeModel``); its array leaves may be traced (vmap, grad).
            If it has an integer attribute ``nq``, the state length is checked against it.
        q0, qd0: initial generalised coordinates and velocities, shape (n,).
        t0, t1: time interval, ``t1 > t0``.
        control: ``(t, q, qd, params) -> tau (n,)``, evaluated at every solver stage (exact, not held per
            step); ``None`` means zero generalised force.
        solver: a name in :data:`SOLVERS`.
        rtol, atol: tolerances of the PID step-size controller (and of the implicit solvers' root finder);
            ``rtol > 0``, ``atol >= 0``.
        dt0: first step; ``None`` lets diffrax choose it from the tolerances.
        saveat_ts: (T,) non-decreasing times in [t0, t1] at which to save; ``None`` saves at t0 and t1.
        max_steps: step budget (a positive integer; with ``events``, of each smooth segment: a segment that
            exhausts it ends the run); reaching it is an error (see ``throw``).
        adjoint: ``None``/"checkpoint" (reverse mode, default), "forward" (forward mode, for ``jax.jvp``),
            "direct" (both, more memory), "backsolve", or any diffrax adjoint.
        pid: (pcoeff, icoeff, dcoeff) of the controller; defaults (0, 1, 0) explicit (integral control),
            (0.3, 0.3, 0) implicit.
        max_step: the largest step [s] (``None``: unbounded), e.g. shorter than a brief input the solver could
            otherwise stride over.
        throw: if True (default) a failed integration raises at run time (also under jit); if False the
            returned :class:`Solution` has ``ok = False`` and NaN trajectories.
        progress: show a tqdm progress bar.
        events: locate every sign change of the joint velocities that carry Coulomb friction (``params`` a
            model with a ``coulomb`` field, e.g. a ``TreeModel``, and ``dynamics`` that applies it as
            ``friction_torques`` does, like :func:`~particlesim.tree.forward_dynamics`): the run is split into
            segments with each friction sign fixed, ending where a velocity crosses zero (root-found on the step's
            dense output), so that derivatives carry the jump of the friction torque. At most ``max_events``
            switches; they are reported in ``Solution.events`` (``element``: the joint index; ``active``: the
            joint moves in the positive direction after it). A joint that sticks (its velocity returning to zero
            at once) exhausts ``max_events`` with an error: the sign law has no stiction; use ``smooth_friction``
            there. Without events, a differentiated rollout whose Coulomb joints reverse warns
            (:class:`~particlesim._ode.SwitchCrossedWarning`).

    Raises:
        ValueError: unknown solver or adjoint name; non-positive tolerances or step budget; ``t1 <= t0``;
            non-finite concrete initial state.
        ModelError: q0/qd0 shapes disagree with each other, with ``params.nq`` or with what ``dynamics`` returns;
            a floating parameter is NaN or inf (at run time when traced); for a
            :class:`~particlesim.tree.TreeModel` (``params``, or inside it: its checks and labels only; events,
            ``configuration_rate`` and quaternion checks need ``params`` to be the model), a negative friction
            level, rotor inertia or joint stiffness, or a soft limit with negative stiffness or damping or crossed
            bounds (:mod:`particlesim.tree.checks`; at run time, by JAX's run-time error, when traced).
        InertiaError: for a ``TreeModel``, a link that is neither massless nor a physical body (a positive mass, an
            inertia about its centre of mass symmetric, positive semi-definite and within the triangle
            inequalities), or a joint that moves no mass (at run time when traced; a model loaded with
            ``inertia="warn"`` keeps its links unchecked).
    """
    q0 = _ode.as_state(q0)
    qd0 = _ode.as_state(qd0)
    cfg = _ode.settings(solver=solver, adjoint=adjoint, max_steps=max_steps, throw=throw, progress=progress,
                        pid=pid, save_ts=saveat_ts is not None, max_step=max_step)
    _check_state(params, q0, qd0)
    t0_, t1_, rtol_, atol_, dt0_, ts, time_bad = _ode.times(t0, t1, rtol, atol, dt0, saveat_ts)

    concrete = _ode.check_finite_eager("simulate", params, lambda: _parameter_groups(params),  # concrete values, now
                                       lambda: _physical_checks_eager(params))
    check_physical = not concrete and bool(_trees(params))  # traced leaves: the trees' checks in the program
    _check_output_shapes(dynamics, control, params, q0, qd0, t0_)
    if isinstance(max_events, bool) or not isinstance(max_events, (int, np.integer)) or max_events < 1:
        raise ValueError(f"max_events must be a positive integer, got {max_events!r}")
    coulomb = getattr(params, "coulomb", None)
    names = (getattr(params, "velocity_names", None) or getattr(params, "joint_names", None)
             or tuple(f"joint{i}" for i in range(qd0.shape[0])))
    switch: tuple = ()
    if coulomb is not None:
        # the joints whose friction switches: those with a non-zero Coulomb level (all of them when traced)
        c = np.asarray(coulomb) if _ode._concrete(coulomb) else np.ones(qd0.shape[0])
        switch = tuple(int(i) for i in np.flatnonzero(c))
    if events:
        if coulomb is None:
            raise ValueError("events=True: the model has no switching element (Coulomb friction, params.coulomb)")
        if isinstance(cfg.adjoint, diffrax.BacksolveAdjoint):
            raise ValueError("events=True needs a discrete adjoint ('checkpoint', 'direct', 'forward')")
        return _simulate(dynamics, control, params, q0, qd0, t0_, t1_, rtol_, atol_, dt0_, ts, time_bad, cfg,
                         switch, int(max_events) if switch else 0, check_physical=check_physical)
    warn = tuple((j, names[j]) for j in switch) if switch and _ode.differentiated((params, q0, qd0)) else ()
    return _simulate(dynamics, control, params, q0, qd0, t0_, t1_, rtol_, atol_, dt0_, ts, time_bad, cfg,
                     warn=warn, check_physical=check_physical)
