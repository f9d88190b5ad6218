"""Public functions of one model and one state as compiled entries.

A function such as :func:`particlesim.tree.mass_matrix` is a few hundred small array operations. Called eagerly
(from a notebook, a control loop, a script) JAX would dispatch them one by one, at a cost far above their
arithmetic's. :func:`compiled` turns such a function into one compiled entry
(:func:`particlesim._ode.cached`): compiled once per model structure (static fields: topology, joint kinds, names,
force-law callables), argument shapes and static settings (a link name, a frame, ``smooth_friction``); new
parameter values and states reuse the compiled program, and under an outer ``jit``, ``vmap`` or ``grad`` the entry
is traced inline like any jitted function. :data:`particlesim._ode.TRACES` counts the traces of every entry (the
tests read it).

The state arguments are converted to float64 arrays before dispatch, so that a Python list or number is traced
like an array rather than keyed as a static value; checks that need concrete values (shapes, a zero quaternion)
run before dispatch via ``check``.
"""

from __future__ import annotations

import functools
import inspect
from collections.abc import Callable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from ._ode import TRACES, _ArrayImpl, cached  # _ArrayImpl: the concrete array type, told by one type comparison
from ._xla import TopJit

__all__ = ["compiled"]


def _as_array(x):
    if type(x) is _ArrayImpl or x is None or isinstance(x, (jax.Array, jax.core.Tracer)):
        return x
    return jnp.asarray(np.asarray(x, dtype=np.float64))


def compiled(name: str, *, static: Sequence[str] = (), check: Callable | None = None, arrays_only: bool = False,
             batch: bool | str = False):
    """Decorator: ``fn(model, *state, **settings)`` as one compiled entry (module docstring).

    Every parameter after the model, except those named in ``static`` (settings: strings, numbers, ``None``, part of
    the cache key) and ``props`` (a pytree of arrays), is an array and is converted before dispatch. ``check(model,
    arrays)`` runs before dispatch with the converted arrays by parameter name. ``arrays_only``: every leaf of the
    model is an array (a :class:`~particlesim.tree.TreeModel`), so the entry jits the function itself (its dispatch
    is a few microseconds cheaper than sorting leaves into arrays and static values, which a mechanism's force-law
    callables need). Called at top level, every entry is compiled with :func:`particlesim._xla.cpu_options` (with
    the batch options for ``batch``, True or "wide", which needs ``arrays_only``; :class:`particlesim._xla.TopJit`);
    inside a caller's trace it is inlined. The undecorated function stays available as ``.raw`` for callers already
    inside a trace."""
    if batch and not arrays_only:
        raise TypeError(f"compiled({name!r}): batch={batch!r} needs arrays_only=True (the batch options are the "
                        "tree batch entry's)")

    def wrap(fn):
        sig = inspect.signature(fn)
        names = list(sig.parameters)
        arrays = [n for n in names[1:] if n not in static and n != "props"]
        if arrays_only:
            @functools.wraps(fn)
            def counted(*args, **kwargs):
                TRACES[name] += 1
                return fn(*args, **kwargs)

            entry = TopJit(counted, static_argnames=tuple(static), batch=batch)
        else:
            entry = cached(name)(fn)

        positions = [i for i, n in enumerate(names) if n in arrays]
        named_positions = [(names[i], i) for i in positions]
        # Positional calls that leave only defaulted parameters out (``forward_dynamics(model, q, qd, tau)``) take
        # the fast path too: binding the signature costs more than a small compiled call's own dispatch.
        required = sum(p.default is inspect.Parameter.empty and p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD)
                       for p in sig.parameters.values())
        positional_ok = all(p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD) for p in sig.parameters.values())

        @functools.wraps(fn)
        def call(*args, **kwargs):
            if kwargs or not (positional_ok and required <= len(args) <= len(names)):  # keywords: bind by name
                bound = sig.bind(*args, **kwargs)
                for n in arrays:
                    if n in bound.arguments:
                        bound.arguments[n] = _as_array(bound.arguments[n])
                args, kwargs, given = bound.args, bound.kwargs, bound.arguments
            else:  # all positional (the common call): convert by position
                args = list(args)
                for i in positions:
                    if i < len(args):
                        args[i] = _as_array(args[i])
                if check is not None:
                    check(args[0], {n: args[i] for n, i in named_positions if i < len(args)})
                return entry(*args)
            if check is not None:
                check(given[names[0]], {n: given[n] for n in arrays if n in given})
            return entry(*args, **kwargs)

        call.raw = fn
        call.jit = entry if arrays_only else entry.jit  # the TopJit (tests read its top_options)
        return call

    return wrap
