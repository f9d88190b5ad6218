"""Report: free response of the quarter-car double-wishbone suspension (Attia §3, Figs. 4–5).

The mechanism of :func:`particlesim.scenes.quarter_car.quarter_car` (its assumptions A1–A6 fill the reference's
gaps) is released from rest in its assembly configuration and simulated for ``DURATION`` seconds. Written: the
chassis-centre vertical displacement and acceleration against time (CSV and PNG, as the reference's Figs. 4–5)
and a JSON of the figures, including the largest constraint residual of the run.
"""

from __future__ import annotations

import csv
import json
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from .. import _xla

__all__ = ["quarter_car_report", "DURATION"]

DURATION = 3.0
N_SAVE = 601


def quarter_car_report(out_dir: Path, *, progress: bool = True, solver: str = "dopri5", rtol: float = 1e-10) -> dict:
    from ..mechanism import accelerations, mass_properties, residuals, simulate_mechanism
    from ..scenes.quarter_car import quarter_car

    out_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    mech, x0 = quarter_car()
    t_build = time.perf_counter() - t0
    ts = np.linspace(0.0, DURATION, N_SAVE)
    run = _xla.TopJit(lambda m, x: simulate_mechanism(m, x, jnp.zeros_like(x), 0.0, DURATION, solver=solver,
                                                      rtol=rtol, atol=rtol * 1e-2, saveat_ts=ts, progress=progress))
    t0 = time.perf_counter()
    compiled = run.lower(mech, jnp.asarray(x0)).compile()
    t_compile = time.perf_counter() - t0
    t0 = time.perf_counter()
    sol = jax.block_until_ready(compiled(mech, jnp.asarray(x0)))
    t_run = time.perf_counter() - t0

    k_centre = mech.point_index("centre")
    c_slice = mech.free_slice("C")  # a chassis particle: the chassis only translates

    @_xla.TopJit
    def observe(m, q, qd):
        props = mass_properties(m)

        def one(x, v):
            a = accelerations(m, 0.0, x, v, props=props)
            pos, vel = residuals(m, x, v)
            return (m.point_positions(m.all_positions(x))[k_centre, 2], a[c_slice][2],
                    jnp.max(jnp.abs(pos)), jnp.max(jnp.abs(vel)))

        return jax.vmap(one)(q, qd)

    z, acc, pos_res, vel_res = (np.asarray(v) for v in observe(mech, sol.q, sol.qd))
    disp = z - z[0]
    figures = {
        "scene": "quarter-car double wishbone (Attia 3), free response from rest; assumptions A1-A6 in "
                 "particlesim/scenes/quarter_car.py",
        "degrees_of_freedom": 3,
        "particles_free": mech.n_free,
        "constraints": int(residuals(mech, sol.q[0], sol.qd[0])[0].shape[0]),
        "solver": solver, "rtol": rtol, "accepted_steps": int(sol.steps), "rejected_steps": int(sol.rejected),
        "build_s": t_build, "compile_s": t_compile, "run_s": t_run,
        "final_displacement_m": float(disp[-1]), "min_displacement_m": float(disp.min()),
        "initial_acceleration_m_s2": float(acc[0]), "peak_acceleration_m_s2": float(acc[np.argmax(np.abs(acc))]),
        "max_position_constraint_residual": float(pos_res.max()),
        "max_velocity_constraint_residual": float(vel_res.max()),
    }
    with open(out_dir / "quarter_car.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["t_s", "chassis_displacement_m", "chassis_acceleration_m_s2", "constraint_residual"])
        for row in zip(ts, disp, acc, pos_res):
            w.writerow([f"{row[0]:.4f}", f"{row[1]:.12g}", f"{row[2]:.12g}", f"{row[3]:.3g}"])
    (out_dir / "quarter_car.json").write_text(json.dumps(figures, indent=2))
    _plot(out_dir / "quarter_car.png", ts, disp, acc)
    return figures


def _plot(path: Path, ts, disp, acc) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a1, a2) = plt.subplots(2, 1, figsize=(8, 7), sharex=True, constrained_layout=True)
    a1.plot(ts, disp)
    a1.set_ylabel("chassis vertical displacement [m]")
    a1.set_title("Quarter car, free response from rest (cf. Attia Fig. 4)")
    a2.plot(ts, acc)
    a2.set_ylabel("chassis vertical acceleration [m/s²]")
    a2.set_xlabel("t [s]")
    a2.set_title("(cf. Attia Fig. 5)")
    for a in (a1, a2):
        a.grid(alpha=0.3)
    fig.savefig(path, dpi=110)
    plt.close(fig)
