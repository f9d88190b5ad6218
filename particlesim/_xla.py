"""XLA compiler options of particlesim's compiled entries on the CPU, set per executable (nothing global changes).

JAX accepts compiler options on a top-level ``jax.jit`` only; an entry called inside a user's trace is inlined into
the caller's program and compiled with the caller's options (:func:`top_level` tells the two apart).
"""

from __future__ import annotations

import functools

import jax

__all__ = ["COMPILE_OPTIONS", "BATCH_OPTIONS", "cpu_options", "compiler_options", "jit", "top_level"]

#: XLA options for every compiled entry on the CPU (per executable: nothing global is changed). Elementwise and loop
#: code is emitted by XLA's direct LLVM emitters rather than its MLIR fusion emitters, which compile about twice as
#: fast for programs like ours (hundreds of small fusions): Krang's 2 s rollout 3.2 -> 1.4 s, the quarter car's
#: 4.3 -> 2.4 s, Krang's batched forward dynamics 1.9 -> 1.1 s, a 100-link chain 1.3 -> 0.6 s; run times equal within
#: the machine's noise in interleaved runs (median ratios 0.92-1.04). Results agree to round-off (tested).
COMPILE_OPTIONS = {"xla_cpu_use_fusion_emitters": False}

#: Added for batch entries: reductions go to the same YNNPACK kernels XLA already uses for dots and elementwise loops:
#: the articulated-body sweeps of a batch, whose reductions run over the trailing batch axis, cost 5-20 % less per
#: state in interleaved runs (Krang, 1024 states); one-state programs gain nothing, so only the batch entry uses them.
BATCH_OPTIONS = {"xla_cpu_experimental_ynn_fusion_type":
                 "LIBRARY_FUSION_TYPE_DOT,LIBRARY_FUSION_TYPE_ELTWISE,LIBRARY_FUSION_TYPE_REDUCE"}

@functools.lru_cache(maxsize=2)
def cpu_options(batch: bool = False) -> dict:
    """The compiler options of our entries: :data:`COMPILE_OPTIONS`, with :data:`BATCH_OPTIONS` for ``batch``, each
    group kept only when the default backend is the CPU and this XLA knows it (checked once by compiling a trivial
    program with it), else ``{}``.

    Pass them to your own top-level ``jax.jit`` around particlesim functions (a loss, an identification step) to
    compile it as our entries are: ``jax.jit(loss, compiler_options=particlesim.compiler_options())``."""
    if jax.default_backend() != "cpu":
        return {}
    groups = (COMPILE_OPTIONS, BATCH_OPTIONS) if batch else (COMPILE_OPTIONS,)
    options = {}
    for group in groups:
        try:
            jax.jit(lambda x: x + 1.0, compiler_options={**options, **group}).lower(1.0).compile()
        except Exception:  # an XLA without these options: compile with its defaults
            continue
        options.update(group)
    return options


def compiler_options() -> dict:
    """XLA compiler options that particlesim's own entries (``simulate``, ``simulate_mechanism``, the tree and
    mechanism functions) are compiled with; ``{}`` off the CPU. For a user's own top-level ``jax.jit``:
    ``jax.jit(loss, compiler_options=particlesim.compiler_options())`` compiles about twice as fast on the CPU
    with the same run time (:data:`COMPILE_OPTIONS`). A copy: changing it changes nothing here."""
    return dict(cpu_options())


def top_level() -> bool:
    """True when no trace is active (not inside a ``jit``, ``grad``, ``vmap``, ``scan``...): a call here starts a
    top-level program, which may take compiler options (JAX refuses them on a jit staged into another trace, where
    the entry is inlined into the caller's program). The trace context is JAX's ``trace_state_clean``."""
    return _trace_state_clean()


try:
    from jax._src.core import trace_state_clean as _trace_state_clean
except ImportError:  # a JAX without it: never claim top level, so entries compile with XLA's defaults
    def _trace_state_clean() -> bool:
        return False


class jit:
    """``jax.jit(fn, **kwargs)`` compiled with :func:`cpu_options` when called (or lowered) at top level; inside a
    trace it is a plain ``jax.jit``, inlined into the caller's program. The options are probed on first top-level
    use, once the backend is up."""

    def __init__(self, fn, **kwargs):
        functools.update_wrapper(self, fn)
        self._fn, self._kwargs = fn, kwargs
        self._nested = jax.jit(fn, **kwargs)
        self._top = None

    def _top_level(self):
        if self._top is None:
            self._top = jax.jit(self._fn, compiler_options=cpu_options(), **self._kwargs)
        return self._top

    def __call__(self, *args, **kwargs):
        return (self._top_level() if top_level() else self._nested)(*args, **kwargs)

    def lower(self, *args, **kwargs):
        return (self._top_level() if top_level() else self._nested).lower(*args, **kwargs)
