"""Batches split over threads: the core count (affinity and control-group quota), the parts' runner, its watch over
stalled parts, and the LAPACK batches that keep a program from running beside its copies."""

import os
import threading
import time

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from particlesim import _threads


def test_cpu_quota_is_read_from_either_cgroup_version(tmp_path):
    """cgroup v2 ``cpu.max`` (quota and period, or ``max``) and v1 ``cpu.cfs_quota_us``/``cpu.cfs_period_us``
    (``-1``: unlimited), rounded up to whole cores; nothing readable: no quota."""
    v2 = tmp_path / "v2"
    v2.mkdir()
    (v2 / "cpu.max").write_text("150000 100000\n")
    assert _threads._read_quota(str(v2)) == 2
    (v2 / "cpu.max").write_text("max 100000\n")
    assert _threads._read_quota(str(v2)) is None
    v1 = tmp_path / "v1"
    (v1 / "cpu").mkdir(parents=True)
    (v1 / "cpu" / "cpu.cfs_quota_us").write_text("300000\n")
    (v1 / "cpu" / "cpu.cfs_period_us").write_text("100000\n")
    assert _threads._read_quota(str(v1)) == 3
    (v1 / "cpu" / "cpu.cfs_quota_us").write_text("-1\n")
    assert _threads._read_quota(str(v1)) is None
    assert _threads._read_quota(str(tmp_path / "missing")) is None


def test_usable_cores_are_bounded_by_the_quota(monkeypatch):
    affinity = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    monkeypatch.setattr(_threads, "_QUOTA", [None])
    assert _threads.usable_cores() == affinity
    monkeypatch.setattr(_threads, "_QUOTA", [1])
    assert _threads.usable_cores() == 1


def test_run_parts_returns_in_order_and_raises_a_parts_error():
    assert _threads.run_parts(lambda k: k * k, [(k,) for k in range(5)]) == [0, 1, 4, 9, 16]

    def part(k):
        if k == 3:
            raise ValueError("part 3 failed")
        return k

    with pytest.raises(ValueError, match="part 3 failed"):
        _threads.run_parts(part, [(k,) for k in range(4)])


def test_pool_parts_run_under_the_callers_local_settings():
    """Settings made for the calling thread (JAX's context managers) reach the parts run on the pool's threads, and
    leave them afterwards: a batch split under ``jax.debug_nans`` checks every part, not only the caller's own."""
    n = 3
    barrier = threading.Barrier(n, timeout=30)  # every part on its own thread: the pool runs n - 1 of them

    def seen(_):
        barrier.wait()
        return threading.current_thread().name, jax.config.jax_debug_nans, jax.config.jax_numpy_rank_promotion

    before = (jax.config.jax_debug_nans, jax.config.jax_numpy_rank_promotion)
    other = "raise" if before[1] != "raise" else "warn"
    with jax.debug_nans(not before[0]), jax.numpy_rank_promotion(other):
        outs = _threads.run_parts(seen, [(k,) for k in range(n)])
    assert len({name for name, *_ in outs}) == n  # three threads, two of them the pool's
    assert all(tuple(v) == (not before[0], other) for _, *v in outs)
    barrier.reset()
    outs = _threads.run_parts(seen, [(k,) for k in range(n)])
    assert all(tuple(v) == before for _, *v in outs)  # the pool's threads back to the process's settings


def _context():
    """JAX's trace context (what its jit keys on) without the per-thread axis environment object."""
    from jax._src import config as jax_config

    return tuple(v for n, v in zip(jax_config.trace_context_names(), jax_config.trace_context())
                 if n != "axis_env_state")


def test_pool_parts_see_the_callers_mesh_and_keep_the_thread_guard_to_the_caller():
    """A mesh set with ``jax.set_mesh`` (a context manager's own setting, not a config option) reaches the pool's
    parts: they trace under the caller's context. ``jax.thread_guard`` is not carried (on a second thread JAX refuses
    it): a batch split under it runs, and the caller's guard is still set afterwards."""
    barrier = threading.Barrier(2, timeout=30)

    def part(_):
        barrier.wait()
        return threading.current_thread().name, _context()

    with jax.set_mesh(jax.make_mesh((1,), ("x",))):
        mine = _context()
        outs = _threads.run_parts(part, [(0,), (1,)])
    assert len({name for name, _ in outs}) == 2
    assert all(ctx == mine for _, ctx in outs)
    barrier.reset()
    guard = jax.config.jax_thread_guard
    with jax.thread_guard(True):
        outs = _threads.run_parts(lambda k: (barrier.wait(), k)[1], [(0,), (1,)])
        assert outs == [0, 1] and jax.config.jax_thread_guard
    assert jax.config.jax_thread_guard == guard


def test_settings_are_all_restored_when_one_fails_to():
    """``settings_applied`` restores every setting on a reused pool thread even when one of them fails to, and raises
    that failure after."""

    class Setting:
        def __init__(self, fail=False):
            self.value, self.fail = "process", fail

        def swap_local(self, v):
            old, self.value = self.value, v
            return old

        def set_local(self, v):
            if self.fail:
                raise RuntimeError("cannot restore")
            self.value = v

    good, bad, other = Setting(), Setting(fail=True), Setting()
    with pytest.raises(RuntimeError, match="cannot restore"):
        with _threads.settings_applied(((good, "caller's"), (bad, "caller's"), (other, "caller's"))):
            assert good.value == bad.value == other.value == "caller's"
    assert good.value == other.value == "process"


def test_lapack_batches_spread_over_the_pool_are_found_in_a_lowered_program():
    """A batched factorisation whose work reaches jaxlib's bound (``LAPACK_INLINE_WORK`` flops, counted as
    ``m n max(m, n)`` per matrix) is spread over XLA's intra-op pool; one matrix, or a small batch, runs on its own
    thread. ``inline_batch`` gives the largest batch under the bound."""
    def lowered(shape):
        return jax.jit(jnp.linalg.cholesky).lower(jnp.zeros(shape)).as_text()

    assert _threads.fanning_kernels(lowered((200, 200))) == []  # one matrix: never spread
    assert _threads.fanning_kernels(lowered((2, 36, 36))) == []  # 2 x 36^3 = 93312 < 2e5
    found = _threads.fanning_kernels(lowered((5, 36, 36)))  # 233280
    assert len(found) == 1 and found[0].startswith("lapack_dpotrf") and "5x36x36" in found[0]
    assert _threads.fanning_kernels(lowered((2, 8, 3, 3))) == []  # batch axes multiply: 16 x 27
    for n in (3, 18, 36, 59, 60, 122):
        k = _threads.inline_batch(n)
        assert _threads.fanning_kernels(lowered((k, n, n))) == []
        assert _threads.fanning_kernels(lowered((k + 1, n, n))) != [] or k == 1


def test_a_vmapped_factorisation_runs_unsplit_and_a_member_loop_splits(monkeypatch):
    """``sharded_vmap`` over members each factorising a matrix: vectorised, the part program has one batched
    factorisation that would spread over the pool, so the batch runs as one program; member by member (``chunk=1``)
    it is split. Both equal NumPy's factors."""
    from particlesim import batch as batch_module
    from particlesim.batch import sharded_vmap

    rng = np.random.default_rng(3)
    a = rng.normal(size=(16, 40, 40))
    spd = jnp.asarray(a @ np.swapaxes(a, 1, 2) + 40 * np.eye(40))
    calls = []
    real = batch_module.run_parts
    monkeypatch.setattr(batch_module, "run_parts", lambda *a, **k: calls.append(1) or real(*a, **k))
    ref = np.linalg.cholesky(np.asarray(spd))
    out = sharded_vmap(jnp.linalg.cholesky, threads=2)(spd)
    assert calls == [] and np.allclose(out, ref, rtol=1e-12, atol=0)
    out = sharded_vmap(jnp.linalg.cholesky, chunk=1, threads=2)(spd)
    assert calls == [1] and np.allclose(out, ref, rtol=1e-12, atol=0)


def test_a_stalled_part_raises_naming_the_batch_part_and_thread(monkeypatch):
    """A part that waits and never finishes (here: on an event; a deadlock looks alike, the process idle) raises
    ``BatchStalledError`` after ``STALL_SECONDS``, naming the batch, the part and its thread; a part busy for longer
    than that is not stalled; ``TIMEOUT_SECONDS`` bounds even a busy one."""
    from particlesim.errors import BatchStalledError

    monkeypatch.setattr(_threads, "STALL_SECONDS", 1.0)
    monkeypatch.setattr(_threads, "_TICK", 0.1)
    release = threading.Event()

    def part(k):
        if k == 1:
            release.wait(60)
        return k

    try:
        with pytest.raises(BatchStalledError, match=r"my batch: part 2 of 3, on thread 'particlesim-part-\d+', no "
                                                    r"part finished in the last \d s"):
            _threads.run_parts(part, [(0,), (1,), (2,)], what="my batch")
    finally:
        release.set()

    def busy(k, seconds=2.5):  # the second part keeps a core busy (the first, on the calling thread, returns)
        end = time.monotonic() + (seconds if k else 0.0)
        while time.monotonic() < end:
            pass
        return k

    assert _threads.run_parts(busy, [(0,), (1,)]) == [0, 1]  # busy for 2.5 s: not stalled
    monkeypatch.setattr(_threads, "TIMEOUT_SECONDS", 0.5)
    with pytest.raises(BatchStalledError, match=r"b: members 10\.\.19, on thread 'particlesim-part-\d+', not "
                                                r"finished after"):
        _threads.run_parts(busy, [(0,), (1,)], what="b", describe=lambda k: f"members {10 * k}..{10 * k + 9}")
