"""Benchmarks: each module has ``main() -> dict`` and ``markdown(results) -> str``; ``run_all`` runs them all.

Importing the package imports :mod:`particlesim` first, which turns on float64 (``jax_enable_x64``) before any
benchmark module, or a library it imports, creates an array.
"""

import importlib

importlib.import_module("particlesim")
