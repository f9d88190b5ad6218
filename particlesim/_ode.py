"""The one integration core behind :func:`particlesim.simulate.simulate` (trees, any second-order ODE) and
:func:`particlesim.mechanism.simulate_mechanism` (particle mechanisms): solvers and adjoints by name, the step-size
controller, the implicit solvers' root finder, an optional projection after every step, input checks with one set
of error types, the :class:`Solution` they return, and the compile cache.

Compile once per structure: each public entry point runs through :func:`cached`, an ``equinox.filter_jit`` whose
static part is the model's structure (its static fields, the callables it is given) and the :class:`Settings`;
parameter values, initial states, ``t0``/``t1``, tolerances, ``dt0`` and save times are traced arrays, so a second
call with new values reuses the compiled program. :data:`TRACES` counts traces per entry point (the tests read it).

Errors: :class:`~particlesim.errors.ModelError` (a ``ValueError``) for a bad model, state or parameter, plain
``ValueError`` for bad settings (unknown names, non-positive tolerances, ``t1 < t0``, ``max_steps < 1``). Concrete
values are checked eagerly; traced ones by a run-time check that raises under ``jit`` with the same message.
"""

from __future__ import annotations

import collections
import dataclasses
import functools
import weakref
from collections.abc import Callable
from typing import Any, Optional

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
from jaxtyping import Array, Bool, Float, Int

from .errors import ModelError
from ._esdirk import StructuredESDIRK
from ._xla import TopJit

try:  # the concrete (immutable) array type: the common leaf is told by one type comparison (isinstance is slower)
    from jax._src.array import ArrayImpl as _ArrayImpl
except ImportError:  # pragma: no cover - another JAX layout: nothing is remembered
    class _ArrayImpl:  # noqa: N801
        pass

__all__ = ["SOLVERS", "IMPLICIT_SOLVERS", "ADJOINTS", "Solution", "Settings", "settings", "integrate", "cached",
           "TRACES", "check_finite", "leaf_groups", "check_state", "check_times", "runtime_checks", "merge_checks",
           "as_time"]

#: Adaptive solvers by name. Explicit: Bogacki–Shampine 3(2), Tsitouras 5(4), Dormand–Prince 5(4) and 8(7).
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

#: Adjoints by name: "checkpoint" (reverse mode, recursive checkpointing; the default), "direct" (forward and
#: reverse), "forward" (forward mode, for ``jax.jvp``/``jacfwd``), "backsolve" (continuous adjoint, backwards).
ADJOINTS: dict[str, Callable[[], diffrax.AbstractAdjoint]] = {
    "checkpoint": diffrax.RecursiveCheckpointAdjoint,
    "direct": diffrax.DirectAdjoint,
    "forward": diffrax.ForwardMode,
    "backsolve": diffrax.BacksolveAdjoint,
}

# PID coefficients (pcoeff, icoeff, dcoeff). Explicit solvers: the plain integral controller (diffrax's own
# default), which met every work-against-precision target with fewer rejected steps than a PI controller
# (benchmarks/results/wp_*.json). Implicit solvers: a less sensitive PI controller, for the stiff problems they are
# used for (diffrax's guidance).
_PID_EXPLICIT = (0.0, 1.0, 0.0)
_PID_IMPLICIT = (0.3, 0.3, 0.0)

#: Number of traces of each cached entry point (a second call with new values must not add one).
TRACES: collections.Counter = collections.Counter()


class Solution(eqx.Module):
    """A saved trajectory.

    ``ts``: (T,) save times; ``q``, ``qd``: (T, n) coordinates and their rates (joint angles for trees, particle
    positions for mechanisms). ``steps``/``rejected``: accepted and rejected step counts. ``status``: diffrax
    ``RESULTS`` code, ``ok``: whether t1 was reached. When ``ok`` is false (only possible with ``throw=False``),
    ``q`` and ``qd`` are all NaN: a failed run never returns numbers that look valid. ``events``: the switches
    located by an evented rollout (:class:`Events`), else ``None``.
    """

    ts: Float[Array, " T"]
    q: Float[Array, "T n"]
    qd: Float[Array, "T n"]
    steps: Int[Array, ""]
    rejected: Int[Array, ""]
    status: diffrax.RESULTS
    ok: Bool[Array, ""]
    events: "Events | None" = None  # the located switches of an evented rollout


@dataclasses.dataclass(frozen=True)
class Settings:
    """Static solver settings (part of the compile-cache key). Build with :func:`settings`."""

    solver: str
    adjoint_key: Any  # the adjoint's name, or the identity of a user-given diffrax adjoint
    adjoint: diffrax.AbstractAdjoint = dataclasses.field(compare=False, hash=False)
    max_steps: int = dataclasses.field(default=16384)
    throw: bool = True
    progress: bool = False
    pid: tuple[float, float, float] = _PID_EXPLICIT
    save_ts: bool = False  # save at given times (else at t0 and t1)
    max_step: Optional[float] = None  # the largest step [s] (None: unbounded)


class _ByIdentity:
    """Hashes and compares a user object (a diffrax adjoint) by identity, for the compile-cache key."""

    __slots__ = ("obj",)

    def __init__(self, obj):
        self.obj = obj

    def __hash__(self):
        return id(self.obj)

    def __eq__(self, other):
        return isinstance(other, _ByIdentity) and other.obj is self.obj


_NAMED_ADJOINTS: dict[str, diffrax.AbstractAdjoint] = {}


def _adjoint(adjoint: str | diffrax.AbstractAdjoint | None) -> diffrax.AbstractAdjoint:
    if isinstance(adjoint, diffrax.AbstractAdjoint):
        return adjoint
    name = "checkpoint" if adjoint is None else adjoint
    if isinstance(name, str) and name in ADJOINTS:
        if name not in _NAMED_ADJOINTS:  # stateless: one instance per name
            _NAMED_ADJOINTS[name] = ADJOINTS[name]()
        return _NAMED_ADJOINTS[name]
    raise ValueError(f"unknown adjoint {adjoint!r}; choose one of {sorted(ADJOINTS)} or a diffrax adjoint")


def settings(*, solver: str, adjoint=None, max_steps: int, throw: bool, progress: bool, pid=None,
             save_ts: bool, max_step=None) -> Settings:
    """Validated :class:`Settings`; ``ValueError`` for unknown names, a non-positive step budget, a bad ``pid``.
    Remembered per argument values (typed: ``True`` is not ``1``) when they are hashable and the adjoint is given by
    name, so that a short rollout does not rebuild them on every call."""
    if adjoint is None or isinstance(adjoint, str):  # a user's adjoint object is keyed by identity: not cached
        try:
            return _settings_cached(solver, adjoint, max_steps, throw, progress, pid, save_ts, max_step)
        except TypeError as e:  # unhashable arguments (a pid given as a list): built each call
            if "unhashable" not in str(e):
                raise
    return _settings(solver, adjoint, max_steps, throw, progress, pid, save_ts, max_step)


def _settings(solver, adjoint, max_steps, throw, progress, pid, save_ts, max_step=None) -> Settings:
    name = solver.lower() if isinstance(solver, str) else solver
    if name not in SOLVERS:
        raise ValueError(f"unknown solver {solver!r}; choose one of {sorted(SOLVERS)}")
    if isinstance(max_steps, bool) or not isinstance(max_steps, (int, np.integer)) or max_steps < 1:
        raise ValueError(f"max_steps must be a positive integer, got {max_steps!r}")
    if pid is None:
        pid = _PID_IMPLICIT if name in IMPLICIT_SOLVERS else _PID_EXPLICIT
    pid = tuple(float(v) for v in pid)
    if len(pid) != 3 or not all(np.isfinite(pid)):
        raise ValueError(f"pid must be three finite numbers (pcoeff, icoeff, dcoeff), got {pid!r}")
    if max_step is not None:
        if isinstance(max_step, bool) or not isinstance(max_step, (int, float, np.integer, np.floating)) \
                or not np.isfinite(max_step) or max_step <= 0:
            raise ValueError(f"max_step must be a positive number of seconds (or None), got {max_step!r}")
        max_step = float(max_step)
    key = adjoint if adjoint is None or isinstance(adjoint, str) else _ByIdentity(adjoint)
    return Settings(name, key, _adjoint(adjoint), int(max_steps), bool(throw), bool(progress), pid, bool(save_ts),
                    max_step)


_settings_cached = functools.lru_cache(maxsize=256, typed=True)(_settings)


def as_time(name: str, value):
    """A scalar time or tolerance: a 0-d float64 NumPy array when concrete (cheap to check and to pass), the
    traced value itself under a transformation; ``ValueError`` for non-scalars."""
    v = value if isinstance(value, jax.core.Tracer) else np.asarray(value, dtype=np.float64)
    if np.shape(v) != ():
        raise ValueError(f"{name} must be a scalar, got shape {np.shape(v)}")
    return v


def _concrete(x) -> bool:
    return not isinstance(x, jax.core.Tracer)


def check_times(t0, t1, rtol, atol, dt0, ts):
    """Checks of times and tolerances: ``t1 > t0``; ``rtol > 0``, ``atol >= 0``; ``dt0 > 0``; save times inside
    ``[t0, t1]`` and non-decreasing. Concrete values raise ``ValueError`` now; returns a flag (an array when some
    value is traced, else ``False``) for the run-time error of traced ones."""
    values = [t0, t1, rtol, atol] + ([] if dt0 is None else [dt0]) + ([] if ts is None else [ts])
    if all(_concrete(v) for v in values):
        t0f, t1f = float(t0), float(t1)
        if not t1f > t0f:
            raise ValueError(f"t1 must be greater than t0 (integration runs forward in time), got t0 = {t0f}, "
                             f"t1 = {t1f}")
        if not float(rtol) > 0:
            raise ValueError(f"rtol must be positive, got {float(rtol)}")
        if not float(atol) >= 0:
            raise ValueError(f"atol must be non-negative, got {float(atol)}")
        if dt0 is not None and not float(dt0) > 0:
            raise ValueError(f"dt0 must be positive, got {float(dt0)}")
        if ts is not None:
            a = np.asarray(ts)
            if a.ndim != 1 or (a.size and (a.min() < t0f or a.max() > t1f or np.any(np.diff(a) < 0))):
                raise ValueError(f"saveat_ts must be non-decreasing times inside [t0, t1] = [{t0f}, {t1f}]")
        return np.asarray(False)
    bad = ~(t1 > t0) | ~(rtol > 0) | ~(atol >= 0)
    if dt0 is not None:
        bad = bad | ~(dt0 > 0)
    if ts is not None and jnp.size(ts):
        bad = bad | ~(jnp.all((ts >= t0) & (ts <= t1)) & jnp.all(jnp.diff(ts) >= 0))
    return bad


def times(t0, t1, rtol, atol, dt0, saveat_ts):
    """The time and tolerance arguments of a public rollout as float64 (tracers kept), checked by
    :func:`check_times`: ``(t0, t1, rtol, atol, dt0, ts, time_bad)``."""
    t0_, t1_ = as_time("t0", t0), as_time("t1", t1)
    rtol_, atol_ = as_time("rtol", rtol), as_time("atol", atol)
    dt0_ = None if dt0 is None else as_time("dt0", dt0)
    ts = None if saveat_ts is None else (saveat_ts if isinstance(saveat_ts, jax.core.Tracer)
                                         else np.asarray(saveat_ts, dtype=np.float64))
    return t0_, t1_, rtol_, atol_, dt0_, ts, check_times(t0_, t1_, rtol_, atol_, dt0_, ts)


def as_state(value):
    """An initial-state vector as float64: jax arrays (and tracers) stay on the device, anything else becomes a
    NumPy array (passed to the compiled code without an extra device transfer)."""
    if isinstance(value, jax.Array):
        return value if value.dtype == jnp.float64 else value.astype(jnp.float64)
    return np.asarray(value, dtype=np.float64)


def check_state(y0: tuple[Array, ...], names: tuple[str, ...]) -> None:
    """Eager finiteness check of concrete initial-state arrays (``ValueError`` naming the coordinates)."""
    for name, x in zip(names, y0):
        if _concrete(x):
            finite = np.isfinite(np.asarray(x))
            if not finite.all():
                raise ValueError(f"{name} is not finite at coordinates {np.flatnonzero(~finite).tolist()}")


def check_finite(entry: str, groups) -> tuple | None:
    """Refuse non-finite parameters (e.g. set after construction with ``with_params`` or ``eqx.tree_at``, which do
    not check). ``groups``: ``(label, array)`` pairs, where ``label`` is a string (the whole array) or a list of
    strings (one per entry along the leading axis). Concrete arrays: :class:`ModelError` now, naming the label
    and entry. Traced arrays: returns ``(bad flags, messages)`` for :func:`runtime_checks` (``None`` if none)."""
    groups = list(groups)
    if all(_concrete(arr) for _, arr in groups) and all(np.isfinite(np.asarray(arr)).all() for _, arr in groups):
        return None  # the common case, checked without building messages
    flags, msgs = [], []
    for label, arr in groups:
        per_row = not isinstance(label, str)
        if _concrete(arr):
            a = np.asarray(arr)
            if not np.all(np.isfinite(a)):
                where = tuple(int(i) for i in np.argwhere(~np.isfinite(a))[0]) if a.ndim else ()
                if per_row:
                    name, at = label[where[0]], f" at entry {where[1:]}" if len(where) > 1 else ""
                else:
                    name, at = label, f" at entry {where}" if where else ""
                raise ModelError(f"{entry}: parameter {name} is not finite (NaN or inf){at}")
        elif per_row:
            flags.append(~jnp.all(jnp.isfinite(arr.reshape(arr.shape[0], -1)), axis=1))
            msgs += [f"{entry}: parameter {name} is not finite (NaN or inf)" for name in label]
        else:
            flags.append(~jnp.all(jnp.isfinite(arr))[None])
            msgs.append(f"{entry}: parameter {label} is not finite (NaN or inf)")
    if not flags:
        return None
    return jnp.concatenate(flags), msgs


#: Models whose parameters passed :func:`check_finite_eager`: ``id -> (weak reference, leaves then)``.
_PASSED: dict = {}


def check_finite_eager(entry: str, model, groups: Callable[[], list], more: Callable[[], None] | None = None) -> bool:
    """The eager :func:`check_finite` of a public entry point, ``groups()`` giving the model's ``(label, array)``
    pairs, then ``more()`` (further eager checks that raise, or None) when every leaf is concrete; returns whether
    every leaf was concrete (so that ``more``'s checks were made and the program need not repeat them). A model whose
    array leaves are all concrete JAX arrays (immutable) is checked once and remembered while
    it lives, with its leaves: a later call with the same object and the very same leaves (a container inside it,
    such as a dict, may have been changed in place) skips the check. Labelling and checking every parameter costs a
    noticeable part of a short rollout's call. NumPy leaves (mutable in place) and traced ones are checked on every
    call."""
    leaves = jax.tree.leaves(model)
    if remembered(_PASSED, model, leaves):
        return True
    check_finite(entry, groups())
    concrete = all(_concrete(leaf) for leaf in leaves)
    if more is not None and concrete:
        more()
    remember(_PASSED, model, leaves)
    return concrete


def remembered(store: dict, obj, leaves: list) -> bool:
    """Whether ``obj``, with the very same ``leaves`` (``jax.tree.leaves(obj)``), passed a check kept in
    ``store`` (:func:`remember`)."""
    seen = store.get(id(obj))
    return seen is not None and seen[0]() is obj and len(seen[1]) == len(leaves) and all(
        a is b for a, b in zip(leaves, seen[1]))


def remember(store: dict, obj, leaves: list) -> None:
    """Keep in ``store`` that ``obj`` passed a check, while it lives, if its array leaves are immutable (concrete
    JAX arrays; other leaves static): NumPy or traced leaves, or an object that cannot be weakly referenced (a
    dict), are checked on every call."""
    if all(type(leaf) is _ArrayImpl or not isinstance(leaf, (np.ndarray, jax.Array, jax.core.Tracer))
           for leaf in leaves):
        key = id(obj)
        try:
            ref = weakref.ref(obj, lambda _, key=key: store.pop(key, None))
        except TypeError:  # not weakly referenceable
            return
        store[key] = (ref, tuple(leaves))


def leaf_groups(params: Any) -> list[tuple[str, Array]]:
    """``(label, leaf)`` for every floating leaf of a pytree, labelled by its path (``.inertia``, ``['w']``)."""
    return [(jax.tree_util.keystr(path) or "params", leaf)
            for path, leaf in jax.tree_util.tree_flatten_with_path(params)[0] if eqx.is_inexact_array(leaf)]


def merge_checks(*checks):
    """One ``(flags, messages)`` of several (``None`` entries skipped; the first flagged entry is reported)."""
    checks = [c for c in checks if c is not None]
    if not checks:
        return None
    return jnp.concatenate([c[0] for c in checks]), [m for c in checks for m in c[1]]


def runtime_checks(y0, time_bad: Array, param_bad, entry: str, names: str):
    """Attach run-time errors for traced bad times/tolerances, a non-finite initial state and non-finite
    parameters to ``y0`` (``eqx.error_if``: raised under ``jit`` too)."""
    leaves, tdef = jax.tree.flatten(y0)
    finite = jnp.all(jnp.stack([jnp.all(jnp.isfinite(v)) for v in leaves]))
    first = eqx.error_if(leaves[0], ~finite, f"{entry}: the initial state {names} is not finite")
    first = eqx.error_if(first, time_bad, f"{entry}: t1 <= t0, a non-positive tolerance or dt0, or save times "
                                          "outside [t0, t1]")
    if param_bad is not None:
        bad, msgs = param_bad
        first = eqx.branched_error_if(first, jnp.any(bad), jnp.argmax(bad), msgs)
    return jax.tree.unflatten(tdef, [first] + leaves[1:])


class _Projected(diffrax.AbstractAdaptiveSolver, diffrax.AbstractWrappedSolver):
    """Wraps a diffrax solver; after each step maps ``y1`` through ``projection(t1, y1, args)``."""

    solver: diffrax.AbstractSolver
    projection: Callable = eqx.field(static=True)

    @property
    def term_structure(self):
        return self.solver.term_structure

    @property
    def interpolation_cls(self):  # pyright: ignore
        return self.solver.interpolation_cls

    @property
    def term_compatible_contr_kwargs(self):
        return self.solver.term_compatible_contr_kwargs

    def order(self, terms):
        return self.solver.order(terms)

    def error_order(self, terms):
        return self.solver.error_order(terms)

    def strong_order(self, terms):
        return self.solver.strong_order(terms)

    @property
    def scan_kind(self):  # diffrax's adjoints ask Runge-Kutta solvers (and their wrappers) for it
        return getattr(self.solver, "scan_kind", None)

    @property
    def root_finder(self):  # diffrax asks implicit solvers (and their wrappers) for it
        return getattr(self.solver, "root_finder", None)

    def init(self, terms, t0, t1, y0, args):
        return self.solver.init(terms, t0, t1, y0, args)

    def step(self, terms, t0, t1, y0, args, solver_state, made_jump):
        y1, y_error, dense_info, solver_state, result = self.solver.step(
            terms, t0, t1, y0, args, solver_state, made_jump)
        return self.projection(t1, y1, args), y_error, dense_info, solver_state, result

    def func(self, terms, t0, y0, args):
        return self.solver.func(terms, t0, y0, args)


def _solver_and_controller(cfg: Settings, rtol, atol, projection, system=None):
    """The solver (wrapped with the projection, if any) and the PID controller of ``cfg``. An implicit solver
    given the system's structure (``system``, a :class:`~particlesim._esdirk.SecondOrderSystem`) is the
    structured ESDIRK of :mod:`particlesim._esdirk` with the same tableau; without it (or with the backsolve
    adjoint), diffrax's own."""
    implicit = cfg.solver in IMPLICIT_SOLVERS
    controller = diffrax.PIDController(rtol=rtol, atol=atol, pcoeff=cfg.pid[0], icoeff=cfg.pid[1],
                                       dcoeff=cfg.pid[2], dtmax=cfg.max_step)
    kw = {}
    # The Runge–Kutta stage loop: diffrax picks it from the adjoint for a bare solver; a wrapped (projected) one
    # is given it up front: forward mode needs "lax", DirectAdjoint "bounded"; the checkpointed adjoint keeps
    # diffrax's default, whose forward pass runs as a plain loop.
    if isinstance(cfg.adjoint, diffrax.ForwardMode):
        kw["scan_kind"] = "lax"
    elif isinstance(cfg.adjoint, diffrax.DirectAdjoint):
        kw["scan_kind"] = "bounded"
    # The structured solver integrates the forward system only: the continuous adjoint's backward solve (a
    # different system, in diffrax's own terms) keeps diffrax's Kvaerno.
    if implicit and system is not None and not isinstance(cfg.adjoint, diffrax.BacksolveAdjoint):
        solver = StructuredESDIRK(system, rtol, atol, method=cfg.solver)
    else:
        if implicit:  # chord-Newton stage solves at the controller's tolerances (diffrax's default, stated here)
            kw["root_finder"] = diffrax.VeryChord(rtol=rtol, atol=atol, norm=controller.norm)
        solver = SOLVERS[cfg.solver](**kw)
    if projection is not None:
        solver = _Projected(solver, projection)
    return solver, controller


class Events(eqx.Module):
    """The switches located in an evented rollout (:func:`integrate_events`), in order: ``ts`` (E,) their times
    (``inf`` where unused), ``element`` (E,) the index of the switching element (``-1`` unused), ``active`` (E,)
    whether the element's switched-on law (a tyre in contact, ...) holds after the switch. Elements switching
    together (within :data:`SIMULTANEOUS`) have a record each, at the same time."""

    ts: Float[Array, " E"]
    element: Int[Array, " E"]
    active: Bool[Array, " E"]


class SwitchCrossedWarning(UserWarning):
    """A switching force law (a tyre's contact, Coulomb friction's sign) changed inside a differentiated rollout
    run without events: the derivatives miss the jump at the switch."""


def warn_switches(changed, labels) -> None:
    """Host side of the switch check: warn naming every element whose law changed (``changed`` (..., S))."""
    import warnings

    changed = np.asarray(changed).reshape(-1, len(labels)).any(axis=0)
    hit = [n for n, c in zip(labels, changed) if c]
    if hit:
        warnings.warn(f"{', '.join(hit)} switched inside a differentiated rollout that steps across the switch "
                      "without locating it: the derivatives miss the jump at the switch and are biased. Pass "
                      "events=True to locate switches", SwitchCrossedWarning, stacklevel=2)


def differentiated(tree) -> bool:
    """Whether any array leaf carries a forward- or reverse-mode derivative (a JVP or linearize tracer, possibly
    under batching): decided when the entry point is called, outside its compiled program."""
    for leaf in jax.tree.leaves(tree):
        seen = 0
        while isinstance(leaf, jax.core.Tracer) and seen < 8:
            if type(leaf).__name__ in ("JVPTracer", "LinearizeTracer"):
                return True
            leaf = getattr(leaf, "val", getattr(leaf, "primal", None))
            seen += 1
    return False


def _who_throws(cfg: Settings) -> tuple[bool, bool]:
    """``(here, diffrax)``: whether a failed solve is raised here (:func:`_raise_failed`, with a hint) or by diffrax's
    ``throw``. Here whenever ``throw``, except under BacksolveAdjoint, whose backward solve takes its ``throw`` from
    the forward one."""
    backsolve = isinstance(cfg.adjoint, diffrax.BacksolveAdjoint)
    return cfg.throw and not backsolve, cfg.throw and backsolve


def _raise_failed(x, result, hint: str = ""):
    """``x`` (a pytree: pass every output, since JAX drops an error check whose output goes unused), raising
    diffrax's own error at run time when ``result`` is a failure, as ``diffeqsolve(throw=True)`` does, with ``hint``
    (what usually causes it in this kind of model, and what to do) after the max-steps message. Reads the message
    table of diffrax's RESULTS (an equinox enumeration: ``_index_to_message``, ``_value``; diffrax 0.7.2, equinox
    0.13.8, pinned in pyproject.toml)."""
    messages = list(diffrax.RESULTS._index_to_message)
    if hint:
        i = int(np.asarray(diffrax.RESULTS.max_steps_reached._value))
        messages[i] = f"{messages[i]} {hint}"
    return eqx.branched_error_if(x, result != diffrax.RESULTS.successful, result._value, messages)


#: Event times are located by bisection on the step's dense output to this tolerance [s] (absolute, plus this
#: fraction of the time).
EVENT_TOL = 1e-13
#: Switches located within this time of each other [s] (plus this fraction of the time) flip together.
SIMULTANEOUS = 1e3 * EVENT_TOL
#: A switching surface starting a segment below this (relative to 1 + the largest surface value, in the surfaces'
#: units: metres of gap for tyres and bump stops) starts at it instead (:func:`integrate_events`): far above
#: rounding, far below any gap that matters (it shifts that element's next crossing by this over its rate).
SURFACE_MARGIN = 1e3 * float(np.finfo(np.float64).eps)


class _EventBisection(optx.Bisection):
    """Bisection for the event time (diffrax brackets it by the step that crossed), ending when the bracket is
    below ``rtol |t| + atol``. Not optimistix's test, which also asks ``|f| < atol`` in the switching function's own
    units (out of reach at a steep crossing once the bracket reaches the time's resolution), nor its containment
    check, which stops a run: diffrax also root-finds event-free and zero-length steps (the members without an
    event of a vectorised batch where one has; the segments after a run ends) with a function that is zero at the
    upper end. Use with ``flip=True``: the event function decreases through its root (``direction=False``); with no
    sign change the bracket closes on the upper end, the step's end."""

    def terminate(self, fn, y, args, options, state, tags):
        return jnp.abs(state.upper - state.lower) < self.atol + self.rtol * jnp.abs(y), optx.RESULTS.successful


def integrate_events(field: Callable, y0, args, modes0, surfaces: Callable, n_surfaces: int, max_events: int, *,
                     t0: Array, t1: Array, rtol: Array, atol: Array, dt0, ts, cfg: Settings,
                     projection: Callable | None = None, hint: str = "", system=None):
    """:func:`integrate` of a switching system as smooth segments joined at located events.

    ``modes`` (S,) holds each switching element's law (1.0 on, 0.0 off) and stays fixed within a segment:
    ``field(t, y, (args, modes))`` is smooth there (each law extended across its surface). ``surfaces(t, y, args,
    modes)`` (S,) are the switching functions signed so that they are positive in the current mode and cross zero
    downwards at a switch. Each segment runs until the first crossing, located by a root-find on the step's
    dense output (so the event time is a differentiable function of parameters and state, by the implicit
    function theorem); the element's law flips there (with any other already across) and the next segment starts
    from the event state (projected, if ``projection`` is given). ``max_events + 1`` segments at most (one
    ``lax.scan``, so every adjoint differentiates it); a run with more switches fails. Returns ``(ts, ys, steps,
    rejected, result, ok, events)``.
    """
    solver, controller = _solver_and_controller(cfg, rtol, atol, projection, system)
    own, diffrax_throws = _who_throws(cfg)
    save = ts if cfg.save_ts else jnp.stack([t0, t1])
    # One event function, the least of the surfaces: it crosses zero (downwards) when the first of them does,
    # located by bisection within the step that crossed. Newton's method (with one function per surface) was not
    # robust: on a quarter car whose tyre lifts off and lands within tens of ms it reported a wrong time and then
    # failed to converge, for constants 1e-4 (relative) from ones where it had converged; and with two surfaces
    # crossing in one step a vector of functions has no common root. Bisection keeps the root inside the step
    # and halves the bracket to EVENT_TOL.
    root = _EventBisection(rtol=EVENT_TOL, atol=EVENT_TOL, flip=True)
    # args = (args, modes, lift): a surface that starts the segment below SURFACE_MARGIN (an element just switched
    # starts at its root, and the projection after an event may leave it a rounding error across) is measured from
    # that start, lifted to SURFACE_MARGIN; the others are not moved. The start must be strictly positive (a start
    # at zero would hide the next crossing of any other element within the first step), and by more than rounding:
    # diffrax evaluates the condition again inside its loop, where the surfaces may round differently, and a start
    # lifted to exactly zero can then read as crossed on the first step, even a rejected one.
    def condition(t, y, args, **kw):
        return jnp.min(surfaces(t, y, args[0], args[1]) + args[2])

    event = diffrax.Event(condition, root_finder=root, direction=False)
    term = diffrax.ODETerm(field)

    def segment(carry, _):
        t_s, y_s, modes, acc, steps, rejected, failed, n_ev, ev_t, ev_el, ev_on = carry
        # after a failed segment the rest are empty (start at t1), as after the last one of a run that finished
        t_s = jnp.where(failed == diffrax.RESULTS.successful, t_s, t1)
        s_0 = jax.lax.stop_gradient(surfaces(t_s, y_s, args, modes))
        margin = SURFACE_MARGIN * (1.0 + jnp.max(jnp.abs(s_0), initial=0.0))
        lift = jnp.where(s_0 < margin, margin - s_0, 0.0)
        sol = diffrax.diffeqsolve(
            term, solver, t0=t_s, t1=t1, dt0=dt0, y0=y_s, args=(args, modes, lift),
            saveat=diffrax.SaveAt(subs=[diffrax.SubSaveAt(ts=jnp.clip(save, t_s, t1)), diffrax.SubSaveAt(t1=True)]),
            stepsize_controller=controller, adjoint=cfg.adjoint, max_steps=cfg.max_steps, throw=diffrax_throws,
            event=event)
        hit = jnp.asarray(sol.event_mask)
        t_e = sol.ts[1][0]  # the event time (t1 without an event)
        y_e = jax.tree.map(lambda v: v[0], sol.ys[1])
        # The element whose surface the event's root is on (the least), and any other already across (switches
        # simultaneous to the tolerance flip together).
        # Simultaneous: across already, or reaching its surface within SIMULTANEOUS seconds at its present rate
        # (two symmetric wheels landing together): left for the next segment, such an element would start at its
        # root heading across, where no crossing can be seen.
        s_e, rate = jax.jvp(lambda tt, yy: surfaces(tt, yy, args, modes), (t_e, y_e),
                            (jnp.ones_like(t_e), field(t_e, y_e, (args, modes, lift))))
        soon = SIMULTANEOUS * (1.0 + jnp.abs(t_e))
        which = hit & ((jnp.arange(n_surfaces) == jnp.argmin(s_e)) | (s_e < 0.0) | (s_e + soon * rate < 0.0))
        if projection is not None:  # called as the solver calls it, with (args, modes, ...)
            y_e = projection(t_e, y_e, (args, modes, lift))
        ran = t_e > t_s  # the segments after the run's end are empty (t_s = t_e = t1): their outputs are not states
        y_e = jax.tree.map(lambda a, b: jnp.where(ran, a, b), y_e, y_s)
        seg = sol.ys[0]
        valid = (save >= t_s) & (save <= t_e) & ran
        acc = jax.tree.map(lambda a, v: jnp.where(valid.reshape((-1,) + (1,) * (v.ndim - 1)), v, a), acc, seg)
        new_modes = jnp.where(which, 1.0 - modes, modes)
        # every element that switched gets its own record (those switching together share the time), in element
        # order; records beyond the last slot are dropped
        slot = jnp.where(which, n_ev + jnp.cumsum(which) - 1, max_events)
        ev_t = ev_t.at[slot].set(t_e, mode="drop")
        ev_el = ev_el.at[slot].set(jnp.arange(n_surfaces), mode="drop")
        ev_on = ev_on.at[slot].set(new_modes > 0.5, mode="drop")
        bad = (sol.result != diffrax.RESULTS.successful) & (sol.result != diffrax.RESULTS.event_occurred)
        failed = diffrax.RESULTS.where(bad & (failed == diffrax.RESULTS.successful), sol.result, failed)
        return (t_e, y_e, new_modes, acc, steps + sol.stats["num_accepted_steps"],
                rejected + sol.stats["num_rejected_steps"], failed, n_ev + jnp.sum(which), ev_t, ev_el,
                ev_on), None

    acc0 = jax.tree.map(lambda v: jnp.full((save.shape[0],) + v.shape, jnp.nan, v.dtype), y0)
    zero = jnp.zeros((), dtype=int)
    init = (jnp.asarray(t0, dtype=float), y0, jnp.asarray(modes0, dtype=float), acc0, zero, zero,
            diffrax.RESULTS.successful, zero, jnp.full((max_events,), jnp.inf), jnp.full((max_events,), -1),
            jnp.zeros((max_events,), dtype=bool))
    out, _ = jax.lax.scan(segment, init, None, length=max_events + 1)
    if own:
        out = _raise_failed(out, out[6], hint)
    t_end, _, _, ys, steps, rejected, result, n_ev, ev_t, ev_el, ev_on = out
    too_many = t_end < t1
    result = diffrax.RESULTS.where(too_many & (result == diffrax.RESULTS.successful),
                                   diffrax.RESULTS.event_occurred, result)
    ok = result == diffrax.RESULTS.successful
    ys = jax.tree.map(lambda y: jnp.where(ok, y, jnp.nan), ys)
    outputs = (save, ys, steps, rejected, result, ok, Events(ts=ev_t, element=ev_el, active=ev_on))
    if cfg.throw:  # on every output: an error check whose output goes unused is dropped
        outputs = eqx.error_if(outputs, too_many, f"more switches than max_events = {max_events} before t1: "
                                                  "raise max_events (or a switching element chatters, e.g. a "
                                                  "contact at rest)")
    return outputs


def integrate(field: Callable, y0, args, *, t0: Array, t1: Array, rtol: Array, atol: Array, dt0, ts,
              cfg: Settings, projection: Callable | None = None, hint: str = "", system=None):
    """``diffrax.diffeqsolve`` of ``dy/dt = field(t, y, args)`` with the settings ``cfg``; ``projection(t, y, args)``
    is applied after every step when given; ``system``: the structure an implicit solver uses
    (:func:`_solver_and_controller`). Returns ``(ts, ys, steps, rejected, result, ok)``; ``ys`` are NaN
    when the run failed (``throw=False``). With ``throw`` a failure raises diffrax's error, followed by ``hint``
    when the step budget ran out."""
    solver, controller = _solver_and_controller(cfg, rtol, atol, projection, system)
    own, diffrax_throws = _who_throws(cfg)
    saveat = diffrax.SaveAt(ts=ts) if cfg.save_ts else diffrax.SaveAt(t0=True, t1=True)
    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(field), solver, t0=t0, t1=t1, dt0=dt0, y0=y0, args=args, saveat=saveat,
        stepsize_controller=controller, adjoint=cfg.adjoint, max_steps=cfg.max_steps, throw=diffrax_throws,
        progress_meter=diffrax.TqdmProgressMeter() if cfg.progress else diffrax.NoProgressMeter())
    if own:
        sol = _raise_failed(sol, sol.result, hint)
    ok = sol.result == diffrax.RESULTS.successful
    ys = jax.tree.map(lambda y: jnp.where(ok, y, jnp.nan), sol.ys)
    return sol.ts, ys, sol.stats["num_accepted_steps"], sol.stats["num_rejected_steps"], sol.result, ok


def cached(name: str):
    """Decorator: compile an entry point's traced body once per static structure, and count its traces in
    :data:`TRACES`.

    The arguments are flattened; array leaves (``jax.Array``, ``numpy.ndarray``) are traced, everything else
    (the tree structure with the models' static fields, Python numbers, strings, :class:`Settings`, functions) is
    the static cache key, hashed by value (functions by identity). This is ``equinox.filter_jit``'s rule with a
    dispatch lean enough for short rollouts (one ``jax.jit`` call with a hashable key).
    """

    def wrap(fn):
        def traced(key, *arrays):
            treedef, statics = key
            leaves = list(statics)
            it = iter(arrays)
            leaves = [next(it) if leaf is _ARRAY else leaf for leaf in leaves]
            args, kwargs = jax.tree.unflatten(treedef, leaves)
            TRACES[name] += 1
            return fn(*args, **kwargs)

        traced.__name__ = traced.__qualname__ = name
        compiled = TopJit(traced, static_argnums=0)

        def call(*args, **kwargs):
            leaves, treedef = jax.tree.flatten((args, kwargs))
            arrays, statics = [], []
            for leaf in leaves:  # one pass, the concrete array type tested first (the common leaf)
                if type(leaf) is _ArrayImpl or isinstance(leaf, (jax.Array, np.ndarray)):
                    arrays.append(leaf)
                    statics.append(_ARRAY)
                else:
                    statics.append(leaf)
            try:
                return compiled((treedef, tuple(statics)), *arrays)
            except TypeError as e:  # JAX's words for forward mode through a reverse-mode-only adjoint
                if "forward-mode autodiff" not in str(e) or "custom_vjp" not in str(e):
                    raise
                raise TypeError(f"{name}: forward-mode differentiation (jax.jvp, jax.jacfwd) of a rollout needs "
                                "adjoint='forward' (or 'direct'); the default 'checkpoint' (and 'backsolve') "
                                "differentiate in reverse mode only") from e

        call.__name__ = call.__qualname__ = name
        call.__wrapped__ = fn
        call.jit = compiled
        return call

    return wrap


class _ArraySlot:
    """Marks where a traced array sits among the static leaves of a cache key."""

    def __repr__(self):
        return "<array>"


_ARRAY = _ArraySlot()
