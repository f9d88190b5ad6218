"""Command line: ``python -m particlesim.cli main`` runs the main job; ``particles`` the particle report alone."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

__all__ = ["main"]


def _particles(out: Path) -> None:
    from .reports.particles import format_particles, particle_report

    t0 = time.perf_counter()
    summary = particle_report(out)
    print("Equivalent particle systems of the quarter-car bodies (Attia Table 1; layout assumptions in")
    print("particlesim/scenes/quarter_car.py). Positions in each body's frame [m], masses [kg].\n")
    print(format_particles(out))
    print("\nReproduction residuals (relative) and physical consistency:\n")
    print((out / "particles_summary.md").read_text())
    for s in summary:
        for w in s["warnings"]:
            print(f"note: {w}")
    print(f"\nwrote {out / 'particles.csv'}, {out / 'particles_summary.json'}, {out / 'particles_summary.md'} "
          f"in {time.perf_counter() - t0:.1f} s")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="particlesim", description=__doc__)
    parser.add_argument("job", nargs="?", default="main", choices=["main", "particles"])
    parser.add_argument("--out", type=Path, default=Path("out"), help="output folder (default: out/)")
    args = parser.parse_args(argv)
    if args.job in ("main", "particles"):
        _particles(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
