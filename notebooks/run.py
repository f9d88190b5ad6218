"""Rebuild the notebooks from their ``build_*.py`` scripts and execute them in place, saving their outputs (plots
included) so that they read on a code host without running. Run: ``make notebooks`` (or ``python notebooks/run.py
[name ...]``). ``tests/test_notebooks.py`` executes the committed notebooks again in CI."""

from __future__ import annotations

import os
import runpy
import sys
from pathlib import Path

import nbclient
import nbformat

HERE = Path(__file__).resolve().parent


def execute(path: Path) -> None:
    """Execute ``path`` top to bottom with this interpreter's kernel and write it back with its outputs."""
    nb = nbformat.read(path, as_version=4)
    client = nbclient.NotebookClient(nb, timeout=1800, kernel_name="python3",
                                     resources={"metadata": {"path": str(path.parent)}})
    km = client.create_kernel_manager()
    km.kernel_spec.argv = [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"]
    client.km = km
    client.execute()
    nbformat.write(nb, path)


def main(names: list[str]) -> None:
    os.environ["PYTHONPATH"] = os.pathsep.join(filter(None, [str(HERE.parent), os.environ.get("PYTHONPATH")]))
    os.environ.pop("MPLBACKEND", None)  # the kernel's inline backend, so that figures are saved as outputs
    for build in sorted(HERE.glob("build_*.py")):
        name = build.stem.removeprefix("build_")
        if names and name not in names:
            continue
        runpy.run_path(str(build), run_name="__main__")
        print(f"executing {name}.ipynb", flush=True)
        execute(HERE / f"{name}.ipynb")


if __name__ == "__main__":
    main(sys.argv[1:])
