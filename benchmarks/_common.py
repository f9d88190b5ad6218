"""Shared benchmark harness: timing (median of repeats, blocking on results), machine and version records, the
results files (``results/<name>.{json,csv,png}``) and a module's ``main`` (run, write, print the table).

The scene benchmarks' sweeps, headlines and tables are in :mod:`benchmarks._wp`, on top of these."""

from __future__ import annotations

import csv
import datetime as _dt
import json
import platform
import statistics
import time
from collections.abc import Callable, Iterable, Sequence
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


def compile_and_time(fn: Callable[[], object], *, number: int = 1, repeat: int = 3,
                     block: Callable = lambda x: x) -> tuple[float, float, object]:
    """``(compile s, run s per call, first output)`` of a function whose first call compiles: the run time is the
    median over ``repeat`` runs of ``number`` calls after the first, the compile time the first call's less one
    run (never negative)."""
    t = time.perf_counter()
    out = block(fn())
    first = time.perf_counter() - t
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        for _ in range(number):
            last = fn()
        block(last)
        times.append((time.perf_counter() - t) / number)
    run = statistics.median(times)
    return max(first - run, 0.0), run, out


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


def machine(env: dict) -> str:
    """The machine a table was measured on, as the tables state it: CPU, cores, 1-minute load average, date."""
    return (f"{env['cpu']}, {env['cpu_count']} cores, load average {env['load_average_1_5_15min'][0]:.1f} (1 min), "
            f"{env['date']}")


def write_json(name: str, res: dict, *, indent: int = 2, newline: bool = True) -> None:
    """``results/<name>.json``: ``res`` indented by ``indent``, ending in a newline unless ``newline`` is False
    (each module keeps the layout its saved files have)."""
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / f"{name}.json").write_text(json.dumps(res, indent=indent) + ("\n" if newline else ""))


def write_csv(name: str, rows: list[dict], fieldnames: Sequence[str] | None = None) -> None:
    """``results/<name>.csv``: one line per row, the columns ``fieldnames`` (default: the first row's keys; a row
    without one of them leaves it empty)."""
    RESULTS.mkdir(exist_ok=True)
    with open(RESULTS / f"{name}.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]) if fieldnames is None else list(fieldnames), restval="")
        w.writeheader()
        w.writerows(rows)


def write_table(name: str, header: Sequence[str], lines: Iterable[Sequence]) -> None:
    """``results/<name>.csv`` from a header and lines of values (for results that are not one dict per row)."""
    RESULTS.mkdir(exist_ok=True)
    with open(RESULTS / f"{name}.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        w.writerows(lines)


def write_results(name: str, res: dict, rows: list[dict]) -> None:
    """``results/<name>.json`` (the whole ``res``) and ``results/<name>.csv`` (``rows``, one line each)."""
    write_json(name, res, indent=1, newline=False)
    write_csv(name, rows)


def pyplot():
    """``matplotlib.pyplot`` on the Agg backend: figures go to files, no display is needed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, name: str, *, dpi: int, tight: bool = False, title: str | None = None) -> None:
    """``results/<name>.png`` at ``dpi``, under the figure title ``title`` if given (small, it names the machine)
    and laid out by ``tight_layout`` first if ``tight``; the figure is closed."""
    if title is not None:
        fig.suptitle(title, fontsize=9)
    if tight:
        fig.tight_layout()
    fig.savefig(RESULTS / f"{name}.png", dpi=dpi)
    pyplot().close(fig)


def report(run: Callable[[], dict], write: Callable[[dict], None], markdown: Callable[[dict], str], *,
           devices: bool = False, elapsed: bool = False) -> dict:
    """A benchmark module's ``main``: ``run()``, ``write`` its results files, print its table and return the
    results; with ``devices`` the JAX devices are printed first, with ``elapsed`` the run's ``elapsed_s`` last."""
    if devices:
        import jax

        print(f"devices: {jax.devices()}")
    results = run()
    write(results)
    print(markdown(results))
    if elapsed:
        print(f"elapsed {results['elapsed_s']:.0f} s")
    return results
