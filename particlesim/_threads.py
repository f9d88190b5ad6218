"""Threads for batches passed from Python: XLA:CPU runs a batched program's small operations (and a rollout's
loop) on one core, so a second core is used only by a second program running beside the first. Batch entries
split a concrete batch into parts and run the same compiled program on each part, one per thread."""

from __future__ import annotations

import os
import threading
from collections.abc import Callable, Sequence

import jax
from concurrent.futures import ThreadPoolExecutor

__all__ = ["usable_cores", "pool", "run_parts", "threads_apply"]

_pools: dict[int, ThreadPoolExecutor] = {}
_lock = threading.Lock()


def usable_cores() -> int:
    """Cores this process may run on (its CPU affinity where the platform tells it, else ``os.cpu_count()``)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def pool(workers: int) -> ThreadPoolExecutor:
    """A pool of ``workers`` threads, made on first use and kept (a thread's start costs ~50 us)."""
    p = _pools.get(workers)
    if p is None:
        with _lock:
            p = _pools.setdefault(workers, ThreadPoolExecutor(workers, thread_name_prefix="particlesim-batch"))
    return p


def run_parts(fn: Callable, parts: Sequence[tuple]) -> list:
    """``[fn(*args) for args in parts]``, the first on this thread and the others on a kept pool's threads, handed
    over before this thread starts its own (a program dispatched asynchronously first held back those dispatched
    after it from other threads: two 0.25 s loops took 0.50-0.54 s that way, 0.25 s the other). Each part runs with
    its thread held to one of the usable cores (:func:`_on_core`; Krang's batch of 1024 in two parts, per state,
    three A/Bs: 3.85-4.49 us against 5.49-5.90 us with the threads free to move). A part the pool has not started by
    the time this thread is done is taken back and run here, so that a part whose program calls back into Python
    and starts another batch cannot wait on itself. Exceptions reach the caller."""
    cores = _cores()
    rest = [pool(len(parts) - 1).submit(_on_core, cores[(k + 1) % len(cores)], fn, args)
            for k, args in enumerate(parts[1:])]
    outs = [_on_core(cores[0], fn, parts[0])]
    for f, args in zip(rest, parts[1:]):
        outs.append(_on_core(cores[0], fn, args) if f.cancel() else f.result())
    return outs


#: Whether :func:`run_parts` holds each part's thread to one core (False: threads free to move).
PIN_THREADS = True


def _cores() -> list[int]:
    if not PIN_THREADS:
        return [-1]
    try:
        return sorted(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux: no pinning
        return [-1]


def _on_core(core: int, fn: Callable, args: tuple):
    """``fn(*args)`` with the calling thread held to ``core`` (its own affinity restored after; ``-1``: as it is).
    XLA:CPU runs a program waited for on this thread here: threads free to move let two parts share a core."""
    if core < 0:
        return fn(*args)
    before = os.sched_getaffinity(0)
    os.sched_setaffinity(0, {core})
    try:
        return fn(*args)
    finally:
        os.sched_setaffinity(0, before)


def threads_apply() -> bool:
    """Whether a batch may be split over threads here: JAX's default backend is the CPU (on a GPU the parts would
    run one after another) and ``jax.disable_jit`` is off (a thread-local setting the pool's threads would not
    see)."""
    return not jax.config.jax_disable_jit and jax.default_backend() == "cpu"
