"""Threads for batches passed from Python: one batched program gains little from a second core (XLA:CPU hands its
small operations, and a rollout's loop, between the threads of its pool without running faster), so a second core
is used by a second program running beside the first. Batch entries split a concrete batch into parts and run the
same compiled program on each part, one per thread; the parts run under the calling thread's JAX settings."""

from __future__ import annotations

import contextlib
import functools
import os
import threading
from collections.abc import Callable, Sequence

import jax
from concurrent.futures import ThreadPoolExecutor

__all__ = ["usable_cores", "pool", "run_parts", "threads_apply"]

_pools: dict[int, ThreadPoolExecutor] = {}
_lock = threading.Lock()


def usable_cores() -> int:
    """Cores this process may run on: its CPU affinity where the platform tells it (else ``os.cpu_count()``), at
    most a container's CPU quota rounded up (one started with ``--cpus 2`` on a larger machine; :func:`_cpu_quota`)."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cores = os.cpu_count() or 1
    quota = _cpu_quota()
    return max(1, min(cores, quota)) if quota else cores


_QUOTA: list = []


def _cpu_quota() -> int | None:
    """The CPU quota at the root of the control-group file system as a container sees it (its own group), in whole
    cores rounded up (cgroup v2 ``cpu.max``, v1 ``cpu.cfs_quota_us`` / ``cpu.cfs_period_us``); ``None`` when
    unlimited or unknown (a process in a quota'd group of the host's own hierarchy is not looked up). Read once."""
    if not _QUOTA:
        _QUOTA.append(_read_quota())
    return _QUOTA[0]


def _read_quota(root: str = "/sys/fs/cgroup") -> int | None:
    try:
        with open(f"{root}/cpu.max") as f:
            quota, period = f.read().split()[:2]
        if quota != "max":
            return -(-int(quota) // int(period))
        return None
    except (OSError, ValueError):
        pass
    try:
        with open(f"{root}/cpu/cpu.cfs_quota_us") as f:
            quota = int(f.read())
        with open(f"{root}/cpu/cpu.cfs_period_us") as f:
            period = int(f.read())
        return -(-quota // period) if quota > 0 and period > 0 else None
    except (OSError, ValueError):
        return None


def pool(workers: int) -> ThreadPoolExecutor:
    """A pool of ``workers`` threads, made on first use and kept (a thread's start costs ~50 us)."""
    p = _pools.get(workers)
    if p is None:
        with _lock:
            p = _pools.setdefault(workers, ThreadPoolExecutor(workers, thread_name_prefix="particlesim-batch"))
    return p


def run_parts(fn: Callable, parts: Sequence[tuple]) -> list:
    """``[fn(*args) for args in parts]``, the first on this thread and the others on a kept pool's threads, handed
    over before this thread starts its own (an earlier measurement found a program dispatched asynchronously first
    holding back those dispatched after it from other threads, two 0.25 s loops taking 0.50-0.54 s; not reproduced on
    2026-12-06, jaxlib 0.10.2: either order 0.24-0.26 s; the order is kept, harmless either way). A part the pool has
    not started by the time this thread is done is taken back and run here, so that a part whose program calls back
    into Python and starts another batch cannot wait on itself. The pool's threads run their parts under the JAX
    settings this thread has set locally (``jax.default_device``, ``jax.debug_nans``... as context managers:
    :func:`local_settings`). Exceptions reach the caller."""
    if len(parts) <= 1:
        return [fn(*args) for args in parts]
    settings = local_settings()
    call = functools.partial(_under, settings, fn) if settings else fn
    rest = [pool(len(parts) - 1).submit(call, *args) for args in parts[1:]]
    try:
        outs = [fn(*parts[0])]
        for f, args in zip(rest, parts[1:]):
            outs.append(fn(*args) if f.cancel() else f.result())
    except BaseException:
        for f in rest:  # parts not started yet are dropped; running ones finish on their own
            f.cancel()
        raise
    return outs


#: Thread-local JAX settings never carried to the pool's threads: the thread guard marks the one thread allowed to
#: run JAX work (set on a second thread, JAX refuses it, and clearing it there would clear the caller's).
NOT_CARRIED = frozenset({"jax_thread_guard"})

_SETTINGS: list = []  # [(number of JAX's config states when collected, the settings)]


def _all_settings() -> tuple:
    """Every JAX setting that can hold a thread-local value: the options of ``jax._src.config.config_states`` and the
    context managers' own ``config_ext.Config`` objects of that module (mesh, compute_on, xla_metadata...), those
    in :data:`NOT_CARRIED` left out. Collected once, again when JAX defines new options."""
    from jax._src import config as jax_config

    states = jax_config.config_states
    if not _SETTINGS or _SETTINGS[0][0] != len(states):
        found = {id(c): c for c in vars(jax_config).values() if isinstance(c, jax_config.config_ext.Config)}
        found.update((id(c), c) for c in states.values())
        carried = tuple(c for c in found.values() if getattr(c, "name", None) not in NOT_CARRIED)
        _SETTINGS[:] = [(len(states), carried)]
    return _SETTINGS[0][1]


def local_settings() -> tuple:
    """The JAX settings this thread has set for itself (the context managers ``jax.default_device``,
    ``jax.debug_nans``, ``jax.numpy_rank_promotion``, ``jax.set_mesh``...), as ``(setting, value)`` pairs for
    :func:`settings_applied`. Not found: a user's own ``make_user_context`` contexts (JAX keeps no list of them), and
    :data:`NOT_CARRIED`. Empty when none is set, or when this JAX does not keep its settings as the code expects
    (``jax._src.config``): then the pool's threads run under the process's settings."""
    try:
        from jax._src import config as jax_config

        unset = jax_config.config_ext.unset
        return tuple((c, value) for c in _all_settings() if (value := c.get_local()) is not unset)
    except Exception:  # another JAX's internals
        return ()


@contextlib.contextmanager
def settings_applied(settings: tuple):
    """Set :func:`local_settings`' pairs on this thread for the block, as JAX's own context managers set them (the
    thread-local value, then its hook if it has one), and restore what was there after, every pair even when one
    fails to (the first error is raised after): the pool's threads are reused."""
    from jax._src import config as jax_config

    unset = jax_config.config_ext.unset
    entered = []
    try:
        for c, value in settings:
            entered.append((c, c.swap_local(value)))
            hook = getattr(c, "_update_thread_local_hook", None)
            if hook:
                hook(value)
        yield
    finally:
        error = None
        for c, prev in reversed(entered):
            try:
                c.set_local(prev)
                hook = getattr(c, "_update_thread_local_hook", None)
                if hook:
                    hook(None if prev is unset else prev)
            except Exception as e:  # restore the others first
                error = error or e
        if error is not None:
            raise error


def _under(settings: tuple, fn: Callable, *args):
    with settings_applied(settings):
        return fn(*args)


def threads_apply(platform: str | None = None) -> bool:
    """Whether a batch may be split over threads here: its devices' ``platform`` (default: JAX's default backend)
    is the CPU (on a GPU the parts would run one after another) and ``jax.disable_jit`` is off (a thread-local
    setting the pool's threads would not see)."""
    return not jax.config.jax_disable_jit and (platform or jax.default_backend()) == "cpu"
