"""Every notebook in ``notebooks/`` executes top to bottom without error (kernel: this interpreter's ipykernel)."""

import os
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))


def _execute(path, monkeypatch):
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    pytest.importorskip("ipykernel")
    # The kernel is a child process: make the project importable there whether or not it is installed, and
    # run it with this interpreter (the venv's), whatever kernels are registered on the machine.
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])))
    monkeypatch.setenv("MPLBACKEND", "Agg")
    nb = nbformat.read(path, as_version=4)
    client = nbclient.NotebookClient(
        nb,
        timeout=900,
        kernel_name="python3",
        resources={"metadata": {"path": str(path.parent)}},
    )
    # Launch the kernel with this interpreter (the venv's), whatever python3 kernel is registered on the machine.
    km = client.create_kernel_manager()
    km.kernel_spec.argv = [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"]
    client.km = km
    client.execute()
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", []) if o.output_type == "error"]
    assert not errors


# One class per notebook: under ``--dist loadscope`` each class is its own scope, so the notebooks run on whichever
# worker is free rather than all on one.
for _path in NOTEBOOKS:
    _name = "TestNotebook_" + _path.stem

    def _test(self, monkeypatch, _path=_path):
        _execute(_path, monkeypatch)

    _test.__name__ = "test_executes"
    globals()[_name] = pytest.mark.slow(type(_name, (), {"test_executes": _test}))
