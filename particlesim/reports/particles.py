"""Report: the equivalent particle systems of the quarter-car bodies (Attia Table 1), with reproduction residuals."""

from __future__ import annotations

import csv
import json
import warnings
from pathlib import Path

import numpy as np

from ..errors import NegativeMassWarning
from ..particles import balanced_primaries, equivalent_particles
from ..scenes import quarter_car

__all__ = ["particle_report"]

KIND = {"chassis": "spatial", "lower_arm": "planar", "upper_arm": "planar", "knuckle": "spatial", "wheel": "spatial"}


def _residuals(ps, body):
    m = float(body.mass)
    size = float(np.max(np.linalg.norm(np.asarray(ps.positions), axis=1))) or 1.0
    i_o = np.asarray(body.about(np.zeros(3)))
    return {
        "mass_rel": abs(float(ps.total_mass()) - m) / m,
        "com_rel": float(np.linalg.norm(np.asarray(ps.first_moment() - body.mass * body.com))) / (m * size),
        "inertia_rel": float(np.max(np.abs(np.asarray(ps.inertia_about_origin()) - i_o)) / np.max(np.abs(i_o))),
    }


def particle_report(out_dir: Path) -> list[dict]:
    """Build both layouts (joint-based, balanced) for every body; write CSV + JSON + markdown; return the rows."""
    out_dir.mkdir(parents=True, exist_ok=True)
    bodies = quarter_car.bodies()
    joint = quarter_car.joint_primaries()
    rows, summary = [], []
    for name, body in bodies.items():
        for layout in ("joint", "balanced"):
            prim = joint[name] if layout == "joint" else balanced_primaries(body, KIND[name], name=name)
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always", NegativeMassWarning)
                ps = equivalent_particles(body, prim, name=name, on_negative="warn")
            res = _residuals(ps, body)
            masses = np.asarray(ps.masses)
            summary.append({"body": name, "layout": layout, "kind": ps.kind, "n_particles": int(masses.size),
                            "min_mass": float(masses.min()), "consistent": bool(masses.min() >= 0),
                            "warnings": [str(w.message) for w in caught], **res})
            for i, (pos, mass) in enumerate(zip(np.asarray(ps.positions), masses), start=1):
                rows.append({"body": name, "layout": layout, "kind": ps.kind, "particle": i,
                             "role": "primary" if i <= ps.primaries.shape[0] else "secondary",
                             "x": pos[0], "y": pos[1], "z": pos[2], "mass": float(mass)})
    with open(out_dir / "particles.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    (out_dir / "particles_summary.json").write_text(json.dumps(summary, indent=2))
    md = ["| body | layout | kind | particles | min mass [kg] | consistent | mass rel. | CoM rel. | inertia rel. |",
          "|---|---|---|---|---|---|---|---|---|"]
    for s in summary:
        md.append(f"| {s['body']} | {s['layout']} | {s['kind']} | {s['n_particles']} | {s['min_mass']:.4g} | "
                  f"{'yes' if s['consistent'] else 'no'} | {s['mass_rel']:.1e} | {s['com_rel']:.1e} | "
                  f"{s['inertia_rel']:.1e} |")
    (out_dir / "particles_summary.md").write_text("\n".join(md) + "\n")
    return summary


def format_particles(out_dir: Path) -> str:
    """The per-particle table as fixed-width text (body frame positions, masses)."""
    lines = [f"{'body':<10} {'layout':<9} {'#':>2} {'role':<9} {'x':>8} {'y':>8} {'z':>8} {'mass':>11}"]
    with open(out_dir / "particles.csv") as f:
        for r in csv.DictReader(f):
            lines.append(f"{r['body']:<10} {r['layout']:<9} {int(r['particle']):>2} {r['role']:<9} "
                         f"{float(r['x']):8.4f} {float(r['y']):8.4f} {float(r['z']):8.4f} {float(r['mass']):11.5f}")
    return "\n".join(lines)
