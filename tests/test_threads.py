"""Batches split over threads: the core count (affinity and control-group quota) and the parts' runner."""

import os

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
