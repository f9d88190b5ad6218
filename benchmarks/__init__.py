"""Benchmarks: each module has ``main() -> dict`` and ``markdown(results) -> str``; ``run_all`` runs them all."""
