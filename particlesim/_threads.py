"""Threads for batches passed from Python: one batched program gains little from a second core (XLA:CPU hands its
small operations, and a rollout's loop, between the threads of its pool without running faster), so a second core
is used by a second program running beside the first. Batch entries split a concrete batch into parts and run the
same compiled program on each part, one per thread; the parts run under the calling thread's JAX settings.

Programs that run side by side share XLA's intra-op thread pool (one thread per core). jaxlib's LAPACK kernels
(Cholesky, LU, triangular solves, QR, eigen- and singular-value decompositions) split a *batch* of matrices whose
estimated work reaches :data:`LAPACK_INLINE_WORK` flops into pieces on that pool and block the pool thread they run on
until the pieces are done. Two such kernels running at once from two programs on a two-thread pool each hold one
thread and wait for pieces that only the other thread could run: neither returns. A program is therefore split
only when it has no such kernel (:func:`splits_safely`, read off its lowered text); particlesim's own batch programs
keep their batched factorisations under the bound (:func:`inline_batch`), and a program that has one runs unsplit
(its kernels then use the pool themselves). A part that still does not finish is reported, not waited for without
bound (:func:`run_parts`: :data:`STALL_SECONDS`, :data:`TIMEOUT_SECONDS`)."""

from __future__ import annotations

import collections
import concurrent.futures as cf
import contextlib
import math
import os
import queue
import re
import threading
import time
import weakref
from collections.abc import Callable, Sequence

import jax

from .errors import BatchStalledError

__all__ = ["usable_cores", "run_parts", "threads_apply", "splits_safely", "inline_batch", "fanning_kernels",
           "LAPACK_INLINE_WORK", "STALL_SECONDS", "TIMEOUT_SECONDS"]

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


# --- LAPACK kernels that spread a batch over XLA's intra-op pool -------------------------------------------------

#: The estimated work (flops) of one batched LAPACK call from which jaxlib spreads its matrices over XLA's intra-op
#: pool and blocks the calling pool thread until they are done (jaxlib's ``kMinWorkPerTask``, 2e5 in jaxlib 0.10.2);
#: below it the call runs on its own thread. Work per matrix is counted here as ``m n max(m, n)``, at least
#: jaxlib's own estimate for every kernel, so a program judged safe is safe.
LAPACK_INLINE_WORK = 200_000

_CUSTOM_CALL = re.compile(r"custom_call @(lapack_\w+)\(.*?\)[^\n]*?: \((tensor<[^>]*>)")
_TENSOR = re.compile(r"tensor<((?:\d+x)*)\w+>")


def fanning_kernels(text: str) -> list[str]:
    """The LAPACK calls of a lowered program (its StableHLO text) that take a batch of matrices large enough to be
    spread over XLA's intra-op pool (:data:`LAPACK_INLINE_WORK`), as ``"target (shape)"``."""
    found = []
    for target, tensor in _CUSTOM_CALL.findall(text):
        dims = [int(d) for d in _TENSOR.match(tensor).group(1).split("x") if d]
        if len(dims) < 3:
            continue  # one matrix: always run on the calling thread
        batch, (m, n) = math.prod(dims[:-2]), dims[-2:]
        if batch >= 2 and batch * m * n * max(m, n) >= LAPACK_INLINE_WORK:
            found.append(f"{target} ({'x'.join(map(str, dims))})")
    return found


def inline_batch(n: int, m: int | None = None) -> int:
    """How many ``m x n`` (default square) matrices one batched LAPACK call may take and still run on the calling
    thread (:data:`LAPACK_INLINE_WORK`): the block size for factorisations of a batch inside a program that may run
    beside another (``jax.lax.map(..., batch_size=inline_batch(n))``)."""
    m = n if m is None else m
    return max(1, (LAPACK_INLINE_WORK - 1) // max(1, m * n * max(m, n)))


_SAFE: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()  # jitted -> {key: verdict}


def splits_safely(jitted, args: tuple, key) -> bool:
    """Whether the program ``jitted(*args)`` may run beside copies of itself on other threads: it has no LAPACK call
    that spreads a batch over XLA's intra-op pool (:func:`fanning_kernels`). Lowered once per ``jitted`` and ``key``
    (the program's structure and argument shapes, which the caller knows); a program that cannot be lowered here
    counts as unsafe (run unsplit, it raises its own error)."""
    try:
        known = _SAFE.setdefault(jitted, {})
    except TypeError:  # not weakly referable: look it up every time
        known = {}
    ok = known.get(key)
    if ok is None:
        try:
            ok = not fanning_kernels(jitted.lower(*args).as_text())
        except Exception:
            ok = False
        known[key] = ok
    return ok


# --- The parts' threads and the watch over them -----------------------------------------------------------------

#: A split batch none of whose unfinished parts has advanced for this many seconds, while the process used less than
#: :data:`_IDLE_SHARE` of one core, raises :class:`~particlesim.errors.BatchStalledError`: running parts keep a
#: core busy; deadlocked ones keep none. ``None``: never.
STALL_SECONDS: float | None = 60.0

#: A split batch not finished after this many seconds raises :class:`~particlesim.errors.BatchStalledError`, busy or
#: not. ``None`` (default): no bound beyond :data:`STALL_SECONDS`.
TIMEOUT_SECONDS: float | None = None

_IDLE_SHARE = 0.05  # of one core: below this the process is idle (its waiting threads cost nothing)
_TICK = 0.5  # seconds between looks at a stalled batch


class _Worker(threading.Thread):
    """A daemon thread that runs one part at a time and goes back to the idle list: a part that never returns keeps
    its thread (not the caller, nor the interpreter's exit)."""

    def __init__(self):
        super().__init__(name=f"particlesim-part-{next(_names)}", daemon=True)
        self.tasks: queue.SimpleQueue = queue.SimpleQueue()

    def run(self):
        while True:
            future, fn, args = self.tasks.get()
            if not future.set_running_or_notify_cancel():
                self._back()
                continue
            try:
                out, error = fn(*args), None
            except BaseException as e:  # to the caller
                out, error = None, e
            self._back()  # idle again before the caller hears: its next batch reuses this thread
            if error is None:
                future.set_result(out)
            else:
                future.set_exception(error)
            future = fn = args = out = error = None

    def _back(self):
        with _lock:
            _idle.append(self)


_idle: list[_Worker] = []
_names = iter(range(1 << 62))


def _submit(fn: Callable, *args) -> tuple[cf.Future, str]:
    """``fn(*args)`` on an idle worker (a new one if none is idle: a batch started from inside a part gets threads of
    its own rather than waiting for its parent's); its future and the thread's name."""
    with _lock:
        worker = _idle.pop() if _idle else None
    if worker is None:
        worker = _Worker()
        worker.start()
    future: cf.Future = cf.Future()
    worker.tasks.put((future, fn, args))
    return future, worker.name


def run_parts(fn: Callable, parts: Sequence[tuple], *, what: str = "a batch",
              describe: Callable[[int], str] | None = None) -> list:
    """``[fn(*args) for args in parts]`` with every output ready: the first part dispatched on this thread, the
    others each on a worker thread of its own (dispatched and waited for there) under the JAX settings this thread
    has set locally (``jax.default_device``, ``jax.debug_nans``... as context managers: :func:`local_settings`).
    Exceptions reach the caller. The caller waits with a bound: a part that stalls (:data:`STALL_SECONDS`) or
    outlasts :data:`TIMEOUT_SECONDS` raises :class:`~particlesim.errors.BatchStalledError` naming ``what`` (the
    batch), the part (``describe(k)``, e.g. its members) and its thread."""
    if len(parts) <= 1:
        return [jax.block_until_ready(fn(*args)) for args in parts]
    settings = local_settings()
    submitted = [_submit(_part, settings, fn, args) for args in parts[1:]]
    futures = [f for f, _ in submitted]
    watch = _Watch(what, len(parts), describe, [threading.current_thread().name] + [n for _, n in submitted])
    try:
        own = fn(*parts[0])  # dispatched here (asynchronously, for a compiled program) while the others start
        outs = [None] + [watch.result(k, f) for k, f in enumerate(futures, 1)]
        outs[0] = watch.ready(0, own)
        return outs
    except BaseException:
        for f in futures:  # parts not started yet are dropped; running ones finish on their own
            f.cancel()
        raise


def _part(settings: tuple, fn: Callable, args: tuple):
    if not settings:
        return jax.block_until_ready(fn(*args))
    with settings_applied(settings):
        return jax.block_until_ready(fn(*args))


class _Watch:
    """The caller's bounded wait for a split batch's parts: :class:`BatchStalledError` when no part has finished for
    :data:`STALL_SECONDS` while the process stayed idle (running parts keep a core busy, deadlocked ones none), or
    past :data:`TIMEOUT_SECONDS`."""

    def __init__(self, what: str, n: int, describe, threads: list[str]):
        self.what, self.n, self.describe, self.threads = what, n, describe, threads
        self.start = time.monotonic()
        self.marks = collections.deque([(self.start, time.process_time())])  # since the last part finished
        self.done = 0

    def result(self, k: int, future: cf.Future):
        """Part ``k``'s result (its exception raised)."""
        while True:
            bounded = STALL_SECONDS is not None or TIMEOUT_SECONDS is not None
            try:
                out = future.result(timeout=_TICK if bounded else None)
            except cf.TimeoutError:
                self._check(k)
                continue
            self._finished()
            return out

    def ready(self, k: int, out):
        """Part ``k``'s outputs once ready (arrays dispatched on this thread; other values are)."""
        pending = [x for x in jax.tree.leaves(out) if hasattr(x, "is_ready")]
        pause = 2e-5
        while pending:
            pending = [x for x in pending if not x.is_ready()]
            if pending:
                time.sleep(pause)
                pause = min(2 * pause, 1e-3)
                if time.monotonic() - self.marks[-1][0] >= _TICK:
                    self._check(k)
        self._finished()
        return out

    def _finished(self):
        self.done += 1
        self.marks = collections.deque([(time.monotonic(), time.process_time())])

    def _check(self, k: int):
        stall, timeout = STALL_SECONDS, TIMEOUT_SECONDS
        now, cpu = time.monotonic(), time.process_time()
        self.marks.append((now, cpu))
        if stall is not None:  # the oldest mark kept is the newest at least `stall` seconds old
            while len(self.marks) > 1 and now - self.marks[1][0] >= stall:
                self.marks.popleft()
        t0, c0 = self.marks[0]
        busy = (cpu - c0) / max(now - t0, 1e-9)
        stalled = stall is not None and now - t0 >= stall and busy < _IDLE_SHARE
        late = timeout is not None and now - self.start >= timeout
        if not (stalled or late):
            return
        part = self.describe(k) if self.describe else f"part {k + 1} of {self.n}"
        why = (f"no part finished in the last {now - t0:.0f} s, while the process used {100 * busy:.1f} % of a "
               f"core (particlesim._threads.STALL_SECONDS = {stall})" if stalled else
               f"not finished after {now - self.start:.0f} s (particlesim._threads.TIMEOUT_SECONDS = {timeout})")
        raise BatchStalledError(
            f"{self.what}: {part}, on thread {self.threads[k]!r}, {why}; {self.n - self.done} of {self.n} parts are "
            "unfinished. Run the batch unsplit (threads=1; for tree batches particlesim.tree.aba.BATCH_THREADS = 1): "
            "its parts wait on each other")


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


def threads_apply(platform: str | None = None) -> bool:
    """Whether a batch may be split over threads here: its devices' ``platform`` (default: JAX's default backend)
    is the CPU (on a GPU the parts would run one after another) and ``jax.disable_jit`` is off (a thread-local
    setting the pool's threads would not see)."""
    return not jax.config.jax_disable_jit and (platform or jax.default_backend()) == "cpu"
