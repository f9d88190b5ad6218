"""XLA compiler options of particlesim's compiled entries on the CPU, set per executable (nothing global changes).

JAX accepts compiler options on a top-level ``jax.jit`` only; an entry called inside a user's trace is inlined into
the caller's program and compiled with the caller's options (:func:`top_level` tells the two apart).
"""

from __future__ import annotations

import functools
import threading

import jax

try:
    from jax._src.core import trace_state_clean as _trace_state_clean
except ImportError:  # a JAX without it: never claim top level, so entries compile with XLA's defaults
    def _trace_state_clean() -> bool:
        return False

__all__ = ["COMPILE_OPTIONS", "BATCH_OPTIONS", "WIDE_BATCH_OPTIONS", "cpu_options", "compiler_options", "top_level",
           "TopJit"]

#: XLA options for every compiled entry on the CPU (per executable: nothing global is changed), wide tree batches
#: excepted (:data:`WIDE_BATCH_OPTIONS`). Elementwise and loop
#: code is emitted by XLA's direct LLVM emitters rather than its MLIR fusion emitters, which compile about twice as
#: fast for programs like ours (hundreds of small fusions) and run as fast. Results agree to round-off (tested).
COMPILE_OPTIONS = {"xla_cpu_use_fusion_emitters": False}

#: Added for batch entries (and part of :data:`WIDE_BATCH_OPTIONS`): reductions go to the same YNNPACK kernels XLA
#: already uses for dots and elementwise loops:
#: the articulated-body sweeps of a batch, whose reductions run over the trailing batch axis, cost less per state;
#: one-state programs gain nothing, so only the batch entry uses them.
BATCH_OPTIONS = {"xla_cpu_experimental_ynn_fusion_type":
                 "LIBRARY_FUSION_TYPE_DOT,LIBRARY_FUSION_TYPE_ELTWISE,LIBRARY_FUSION_TYPE_REDUCE"}


#: Wide batches (``batch="wide"``: the tree batch entry for chunks of :data:`particlesim.tree.aba.WIDE_BATCH` states
#: or more, i.e. deep trees' batches; shallow trees run chunks of about 128 states,
#: :func:`~particlesim.tree.aba.batch_chunks`)
#: take XLA's fusion emitters (set explicitly, so that an ``XLA_FLAGS`` turning them off process-wide does not change
#: these programs) with :data:`BATCH_OPTIONS`: YNNPACK runs most of the sweeps there and the
#: operations left to XLA run faster from its fusion emitters, with no slower compile. Below about 700 states XLA
#: compiles more of the sweeps itself, where its fusion emitters compile slower, so narrower batches keep
#: :data:`COMPILE_OPTIONS`.
WIDE_BATCH_OPTIONS = {"xla_cpu_use_fusion_emitters": True, **BATCH_OPTIONS}
_GROUPS = {False: (COMPILE_OPTIONS,), True: (COMPILE_OPTIONS, BATCH_OPTIONS), "wide": (WIDE_BATCH_OPTIONS,)}


def cpu_options(batch: bool | str = False) -> dict:
    """The compiler options of our top-level programs: :data:`COMPILE_OPTIONS`, with :data:`BATCH_OPTIONS` for
    ``batch=True`` (the batched tree forward dynamics), :data:`WIDE_BATCH_OPTIONS` for ``batch="wide"`` (wide
    batches of it), each group kept only when the default backend is the CPU and this XLA knows it (checked once by
    compiling a trivial program with it), else ``{}``. A copy."""
    if batch not in _GROUPS:
        raise ValueError(f"cpu_options: batch must be False, True or 'wide', got {batch!r}")
    return dict(_cpu_options(batch if batch == "wide" else bool(batch)))


@functools.lru_cache(maxsize=None)
def _cpu_options(batch: bool | str) -> dict:
    if jax.default_backend() != "cpu":
        return {}
    groups = _GROUPS[batch]
    options = {}
    for group in groups:
        try:
            jax.jit(lambda x: x + 1.0, compiler_options={**options, **group}).lower(1.0).compile()
        except Exception:  # an XLA without these options: compile with its defaults
            continue
        options.update(group)
    return options


def compiler_options() -> dict:
    """XLA compiler options that particlesim's entries (``simulate``, ``simulate_mechanism``, the tree and mechanism
    functions) are compiled with at top level; ``{}`` off the CPU (a batch of tree states adds :data:`BATCH_OPTIONS`;
    a deep tree's batch in chunks of :data:`~particlesim.tree.aba.WIDE_BATCH` states or more takes
    :data:`WIDE_BATCH_OPTIONS` instead). For a
    user's own top-level ``jax.jit``: ``jax.jit(loss, compiler_options=particlesim.compiler_options())`` compiles about
    twice as fast on the CPU with the same run time (:data:`COMPILE_OPTIONS`). A copy: changing it changes nothing
    here."""
    return cpu_options()


def top_level() -> bool:
    """True when no trace is active (not inside a ``jit``, ``grad``, ``vmap``, ``scan``...): a call here starts a
    top-level program, which may take compiler options (JAX refuses them on a jit staged into another trace, where
    the entry is inlined into the caller's program). The trace context is JAX's ``trace_state_clean``."""
    return _trace_state_clean()


_TOP_LOCK = threading.Lock()


class TopJit:
    """``jax.jit(fn, **kwargs)``, compiled with :func:`cpu_options` (``batch``: True or "wide") when
    called or lowered at top level; inside a trace it is the plain ``jax.jit``, inlined into the caller's program.
    The top-level jit is built on first use, once the backend is up. Other attributes (``trace``, ``eval_shape``,
    ``clear_cache``...) are the plain jit's."""

    def __init__(self, fn, *, batch: bool | str = False, **kwargs):
        functools.update_wrapper(self, fn)
        self._options = kwargs.pop("compiler_options", None) or {}  # a caller's own, on top of ours
        self._fn, self._batch, self._kwargs = fn, batch, kwargs
        self._nested = jax.jit(fn, **kwargs)
        self._top = None
        #: The compiler options of the top-level program, once built (``None`` before the first top-level use).
        self.top_options = None

    def _pick(self):
        if not top_level():
            return self._nested
        if self._top is None:
            with _TOP_LOCK:  # threads running parts of one batch must share one jit (one compile)
                if self._top is None:
                    options = {**cpu_options(self._batch), **self._options}
                    self.top_options = options
                    self._top = jax.jit(self._fn, compiler_options=options or None, **self._kwargs)
        return self._top

    def __call__(self, *args, **kwargs):
        top = self._top  # the common call, once built: one check of the trace state before dispatch
        if top is not None and _trace_state_clean():
            return top(*args, **kwargs)
        return self._pick()(*args, **kwargs)

    def lower(self, *args, **kwargs):
        return self._pick().lower(*args, **kwargs)

    def _cache_size(self) -> int:
        """Programs compiled so far, top-level and nested together (compile-once tests read it)."""
        return self._nested._cache_size() + (0 if self._top is None else self._top._cache_size())

    def __getattr__(self, name):
        if name.startswith("_"):
            raise AttributeError(name)
        return getattr(self._nested, name)
