"""Threads for batches passed from Python: XLA:CPU runs a batched program's small operations (and a rollout's
loop) on one core, so a second core is used only by a second program running beside the first. Batch entries
split a concrete batch into parts and run the same compiled program on each part, one per thread."""

from __future__ import annotations

import os
import threading
from concurrent.futures import ThreadPoolExecutor

__all__ = ["usable_cores", "pool"]

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
