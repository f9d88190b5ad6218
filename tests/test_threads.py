"""Batches split over threads: the core count (affinity and control-group quota) and the parts' runner."""

import os
import threading

import jax
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
