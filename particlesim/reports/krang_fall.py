"""Report: Golem Krang on fixed wheels falling under gravity, against its MuJoCo C twin.

Scene: ``krang_fixed_wheel_2018-04.urdf`` (18 joints: base pitch, waist, torso, Kinect, two 7-joint arms), gravity
(0, -9.81, 0) as in the DART data, released at rest from the first DART sample's pose. Every joint carries the
same viscous friction ``FV`` (a round illustrative value, not identified: it keeps the fall tame), which MuJoCo
models exactly as joint damping, so the twin is the same system. Ours: Dopri5 with tight tolerances. MuJoCo C: RK4
at a fixed step. Written: a CSV of both trajectories, a PNG of the joint angles, a JSON of the figures.
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
from ..data import data_dir

__all__ = ["krang_fall", "FV", "DURATION", "MJ_DT"]

FV = 5.0  # N m s / rad, every joint
DURATION = 2.0  # s
MJ_DT = 1e-4  # MuJoCo RK4 step
N_SAVE = 201


def _initial_pose(n: int) -> np.ndarray:
    rows = np.loadtxt(data_dir() / "krang" / "dart_fixed_wheel" / "dataQ.txt", skiprows=1, max_rows=1)
    q0 = np.asarray(rows, dtype=float)
    if q0.shape != (n,):
        raise ValueError(f"first DART pose has {q0.shape} entries, the model {n} joints")
    return q0


def _mujoco_rollout(urdf: Path, names, q0, ts):
    import mujoco

    from ..twins.urdf import JointMap, mujoco_model

    m = mujoco_model(urdf, gravity=(0.0, -9.81, 0.0), timestep=MJ_DT, integrator="rk4", damping=FV)
    jmap = JointMap(m, names)
    d = mujoco.MjData(m)
    d.qpos[:] = jmap.to_mujoco(q0)
    d.qvel[:] = 0.0
    mujoco.mj_forward(m, d)
    out = np.empty((len(ts), len(names)))
    steps_per_save = int(round((ts[1] - ts[0]) / MJ_DT))
    t0 = time.perf_counter()
    for k in range(len(ts)):
        out[k] = jmap.from_mujoco(d.qpos.copy())
        if k + 1 < len(ts):
            for _ in range(steps_per_save):
                mujoco.mj_step(m, d)
    return out, time.perf_counter() - t0


def krang_fall(out_dir: Path, *, progress: bool = True) -> dict:
    """Simulate, compare, write ``krang_fall.{csv,png,json}`` under ``out_dir``; return the figures."""
    from ..simulate import simulate
    from ..tree import forward_dynamics, kinetic_energy, potential_energy
    from ..io import load_urdf

    out_dir.mkdir(parents=True, exist_ok=True)
    urdf = data_dir() / "krang" / "urdf" / "krang_fixed_wheel_2018-04.urdf"
    model = load_urdf(urdf, gravity=(0.0, -9.81, 0.0), viscous=FV)
    n = model.nq
    q0 = _initial_pose(n)
    ts = np.linspace(0.0, DURATION, N_SAVE)

    run = _xla.TopJit(lambda mdl, q: simulate(forward_dynamics, mdl, q, jnp.zeros(n), 0.0, DURATION,
                                              solver="dopri5", rtol=1e-10, atol=1e-12, saveat_ts=ts,
                                              progress=progress))
    t0 = time.perf_counter()
    sol = jax.block_until_ready(run(model, q0))  # first call: compile + run
    t_first = time.perf_counter() - t0
    t0 = time.perf_counter()
    sol = jax.block_until_ready(run(model, q0))
    t_run = time.perf_counter() - t0
    q = np.asarray(sol.q)
    qd = np.asarray(sol.qd)

    energy = np.asarray(jax.vmap(lambda a, b: kinetic_energy(model, a, b) + potential_energy(model, a))(sol.q, sol.qd))
    q_mj, t_mj = _mujoco_rollout(urdf, model.joint_names, q0, ts)
    dev = np.abs(q - q_mj)
    figures = {
        "scene": "Krang fixed-wheel URDF, released at rest from DART sample 1, viscous friction on every joint",
        "viscous_friction_Nms_per_rad": FV,
        "duration_s": DURATION,
        "ours": {"solver": "dopri5", "rtol": 1e-10, "atol": 1e-12, "accepted_steps": int(sol.steps),
                 "rejected_steps": int(sol.rejected), "compile_plus_first_run_s": t_first, "run_s": t_run},
        "mujoco_c": {"integrator": "RK4", "dt": MJ_DT, "run_s": t_mj},
        "max_abs_joint_deviation_rad": float(dev.max()),
        "joint_with_max_deviation": model.joint_names[int(np.argmax(dev.max(axis=0)))],
        "energy_start_J": float(energy[0]),
        "energy_end_J": float(energy[-1]),
        "energy_non_increasing": bool(np.all(np.diff(energy) <= 1e-9 * abs(energy[0]))),
        "final_q": dict(zip(model.joint_names, q[-1].round(6).tolist())),
    }
    with open(out_dir / "krang_fall.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["t"] + [f"q_{j}" for j in model.joint_names] + [f"mujoco_q_{j}" for j in model.joint_names]
                   + ["energy_J"])
        for k in range(len(ts)):
            w.writerow([f"{ts[k]:.4f}"] + [f"{x:.10g}" for x in q[k]] + [f"{x:.10g}" for x in q_mj[k]]
                       + [f"{energy[k]:.10g}"])
    (out_dir / "krang_fall.json").write_text(json.dumps(figures, indent=2))
    _plot(out_dir / "krang_fall.png", ts, q, q_mj, qd, energy, model.joint_names)
    return figures


def _plot(path: Path, ts, q, q_mj, qd, energy, names) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 2, figsize=(12, 8), constrained_layout=True)
    groups = [("base, waist, torso, Kinect", range(0, 4)), ("left arm", range(4, 11)), ("right arm", range(11, 18))]
    for ax, (title, idx) in zip(axes.flat[:3], groups):
        for i in idx:
            (line,) = ax.plot(ts, q[:, i], label=names[i])
            ax.plot(ts[::10], q_mj[::10, i], "o", ms=3, color=line.get_color())
        ax.set_title(f"{title} (lines: particlesim, dots: MuJoCo C RK4)")
        ax.set_xlabel("t [s]")
        ax.set_ylabel("q [rad]")
        ax.legend(fontsize=7, ncol=2)
    ax = axes.flat[3]
    ax.plot(ts, energy - energy[0])
    ax.set_title("total energy change (viscous friction dissipates)")
    ax.set_xlabel("t [s]")
    ax.set_ylabel("E(t) - E(0) [J]")
    fig.suptitle("Krang on fixed wheels falling under gravity")
    fig.savefig(path, dpi=110)
    plt.close(fig)
