"""Run every benchmark module and rewrite the generated tables of ``benchmarks/README.md``.

Run: ``python -m benchmarks.run_all`` (all), ``python -m benchmarks.run_all NAME ...`` to rerun only those modules
and rebuild the other tables from their last ``results/<name>.json``, or ``python -m benchmarks.run_all --tables``
to rebuild every table from the saved JSON without running anything. A benchmark module is any
``benchmarks/<name>.py`` not starting with ``_`` (other than this one) that defines ``main() -> dict`` (which
writes its own JSON/CSV/PNG) and ``markdown(results) -> str``.

The tables go between the ``<!-- BENCHMARKS:START -->`` and ``<!-- BENCHMARKS:END -->`` markers of
``benchmarks/README.md``; the hand-written text around them is kept.

Each module runs in a fresh Python process (``python -m benchmarks.<name>``), so that no benchmark inherits the
state another left behind: in the process that has just run ``krang_dynamics`` (its MJX programs, MuJoCo's and
Pinocchio's thread pools) Krang's rollout runs more than twice as slow as in a fresh one.
"""

from __future__ import annotations

import importlib
import json
import pkgutil
import subprocess
import sys
from pathlib import Path

from ._common import RESULTS

HERE = Path(__file__).resolve().parent
README = HERE / "README.md"
START, END = "<!-- BENCHMARKS:START -->", "<!-- BENCHMARKS:END -->"


def modules() -> list[str]:
    return sorted(
        m.name for m in pkgutil.iter_modules([str(HERE)]) if not m.name.startswith("_") and m.name != "run_all"
    )


def tables(only: list[str] | None = None, *, run: bool = True) -> str:
    """Every module's table, rerun or from its saved JSON: with ``run``, the modules in ``only`` (all if None) and
    any module without a saved JSON are rerun; without it nothing runs (a module without JSON is left out)."""
    sections = []
    for name in modules():
        mod = importlib.import_module(f"benchmarks.{name}")
        if not (hasattr(mod, "main") and hasattr(mod, "markdown")):
            continue
        saved = RESULTS / f"{name}.json"
        rerun = run and (not only or name in only or not saved.exists())
        if not rerun:
            if not saved.exists():
                print(f"== {name}: no {saved.name}, left out (run `python -m benchmarks.run_all {name}`)")
                continue
            print(f"== {name} (table from {saved.name})")
            sections.append(mod.markdown(json.loads(saved.read_text())))
            continue
        print(f"== {name} (fresh process)", flush=True)
        subprocess.run([sys.executable, "-m", f"benchmarks.{name}"], cwd=HERE.parent, check=True)
        sections.append(mod.markdown(json.loads(saved.read_text())))
    return "\n".join(sections)


def update_readme(block: str, readme: Path = README) -> None:
    """Replace the block between the BENCHMARKS markers of ``readme`` by ``block``."""
    text = readme.read_text()
    if START not in text or END not in text:
        raise SystemExit(f"{readme} has no {START} ... {END} block: not updated")
    head, rest = text.split(START, 1)
    _, tail = rest.split(END, 1)
    readme.write_text(f"{head}{START}\n{block.strip()}\n{END}{tail}")
    print(f"updated {readme}")


def main(argv: list[str] | None = None) -> None:
    args = list(sys.argv[1:] if argv is None else argv)
    only_tables = "--tables" in args
    names = [a for a in args if a != "--tables"]
    if only_tables and names:
        raise SystemExit("--tables rebuilds every table from the saved JSON; it takes no module names")
    unknown = sorted(set(names) - set(modules()))
    if unknown:
        raise SystemExit(f"unknown benchmark module(s) {unknown}; known: {modules()}")
    if not only_tables:
        RESULTS.mkdir(exist_ok=True)
    update_readme(tables(names or None, run=not only_tables))


if __name__ == "__main__":
    main()
