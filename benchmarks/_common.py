"""Shared benchmark helpers: timing (median of repeats, blocking on results), machine and version records."""

from __future__ import annotations

import csv
import datetime as _dt
import json
import platform
import statistics
import time
from collections.abc import Callable
from importlib import metadata
from pathlib import Path

RESULTS = Path(__file__).resolve().parent / "results"


def median_time(fn: Callable[[], object], *, number: int, repeat: int = 7, block: Callable = lambda x: x) -> float:
    """Median over ``repeat`` runs of the time per call of ``fn`` (run ``number`` times, result blocked on)."""
    block(fn())  # warm-up
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        for _ in range(number):
            out = fn()
        block(out)
        times.append((time.perf_counter() - t) / number)
    return statistics.median(times)


def timed(fn: Callable[[], object]) -> tuple[float, object]:
    t = time.perf_counter()
    out = fn()
    return time.perf_counter() - t, out


def cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def environment() -> dict:
    import jax

    versions = {}
    for pkg in ("jax", "jaxlib", "diffrax", "equinox", "mujoco", "mujoco-mjx", "pin", "numpy"):
        try:
            versions[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            versions[pkg] = None
    import os

    return {
        "date": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
        "cpu": cpu_model(),
        "cpu_count": os.cpu_count(),
        "load_average_1_5_15min": list(os.getloadavg()),  # the machine is shared: read timings against this
        "jax_devices": [str(d) for d in jax.devices()],
        "x64": bool(jax.config.jax_enable_x64),
        "python": platform.python_version(),
        "versions": versions,
    }


def write_results(name: str, res: dict, rows: list[dict]) -> None:
    """``results/<name>.json`` (the whole ``res``) and ``results/<name>.csv`` (``rows``, one line each)."""
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / f"{name}.json").write_text(json.dumps(res, indent=1))
    with open(RESULTS / f"{name}.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
