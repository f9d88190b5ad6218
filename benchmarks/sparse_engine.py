"""The hub split (``solve="sparse"``, :mod:`particlesim.mechanism.sparse`) against the dense solve (float64, CPU).

* **Scaling**: a chassis carrying N = 1, 2, 4, 8 double-wishbone corners (the full vehicle's HMMWV corners, axles a
  wheelbase apart, left and right mirrored): build time, compile time and cost of one evaluation of the
  accelerations (the mean over 200 evaluations inside one compiled loop, median of 7 runs), dense and sparse, with
  the log-log slopes against N; the quarter car's evaluations (dense and split: its chassis shares the arms'
  pivot particles) beside them.
* **Ride**: the full vehicle's 3 s ride of ``wp_vehicle`` (the 5 cm bump under the front wheels, then ISO 8608
  class C) at the setting that benchmark found passing (Dopri8, rtol 5e-4, located events), dense and sparse
  interleaved in one process; the largest chassis-heave difference between the two.
* **Batch**: 16 vehicles whose spring and damper rates differ (±20 %), 1 s of the same ride: ``jax.vmap`` of one
  call against 16 single calls, dense and sparse.

Writes ``results/sparse_engine.{json,csv,png}``. Run: ``python -m benchmarks.sparse_engine``.
"""

from __future__ import annotations

import dataclasses
import time
import warnings

import jax
import jax.numpy as jnp
import numpy as np

from particlesim.mechanism import MechanismBuilder, body_com_positions, simulate_mechanism
from particlesim.mechanism.dynamics import _solve, prepare
from particlesim.scenes import quarter_car as qc
from particlesim.scenes import vehicle as sv

from ._common import environment, median_time, pyplot, save_figure, write_results

NAME = "sparse_engine"
CORNER_N = (1, 2, 4, 8)
EVALS = 200
RIDE = {"t_end": 3.0, "solver": "dopri8", "rtol": 5e-4, "laps": 7}  # wp_vehicle's passing setting at 1e-6 m
BATCH, BATCH_T = 16, 1.0


def corner_vehicle(n: int):
    """A chassis (500 kg per corner) on ``n`` HMMWV corners: pairs left and right on axles a wheelbase apart (one
    corner alone for n = 1). Returns ``(mech, q0)``."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", sv.InertiaWarning)
        corner = sv.load_double_wishbone(sv.hmmwv_front_path())
    mb = MechanismBuilder(gravity=(0.0, 0.0, -9.81))
    axles = (n + 1) // 2
    mass = 500.0 * n
    com = np.array([corner.bodies["spindle"].com[0] - (axles - 1) * sv.WHEELBASE / 2, 0.0, 0.6])
    moments = mass / 12 * np.array([1.0 + 0.25, axles**2 * 4.0 + 0.25, axles**2 * 4.0 + 1.0])
    sv._chassis(mb, mass, com, moments)
    for k in range(n):
        sy = 1.0 if k % 2 == 0 else -1.0
        sv._corner(mb, f"{k}", corner, -(k // 2) * sv.WHEELBASE, sy, sv._spring_values(corner), sv.TYRE, 0.0)
    return mb.build(dof=6 + n)


def _eval_cost(mech, q0, split: bool) -> tuple[float, float]:
    """(compile [s], one evaluation [us]) of the accelerations inside a compiled loop of :data:`EVALS`."""
    prep = prepare(mech, split)
    q0 = jnp.asarray(q0)
    qd = 1e-2 * jnp.asarray(np.random.default_rng(0).normal(size=q0.shape))

    @jax.jit
    def run(m, p, q, v):
        return jax.lax.fori_loop(0, EVALS, lambda i, a: _solve(m, p, 0.0, q + 1e-12 * a, v, 0.0, split=split)[0],
                                 jnp.zeros_like(q))

    t = time.perf_counter()
    run.lower(mech, prep, q0, qd).compile()
    compile_s = time.perf_counter() - t
    run(mech, prep, q0, qd).block_until_ready()
    per = median_time(lambda: run(mech, prep, q0, qd), number=1, block=lambda x: x.block_until_ready())
    return compile_s, per / EVALS * 1e6


def scaling() -> list[dict]:
    rows = []
    for n in CORNER_N:
        t = time.perf_counter()
        mech, q0 = corner_vehicle(n)
        build = time.perf_counter() - t
        for solve in ("dense", "sparse"):
            if solve == "sparse" and mech.topo.sparse is None:
                continue
            compile_s, us = _eval_cost(mech, q0, solve == "sparse")
            rows.append({"corners": n, "solve": solve, "rows": mech.n_constraints, "coords": mech.n_coords,
                         "build_s": build, "compile_s": compile_s, "eval_us": us})
            print(rows[-1], flush=True)
    mech, q0 = qc.quarter_car()
    for solve in ("dense", "sparse"):
        compile_s, us = _eval_cost(mech, q0, solve == "sparse")
        rows.append({"corners": 0, "solve": f"quarter car ({solve})", "rows": mech.n_constraints,
                     "coords": mech.n_coords, "build_s": float("nan"), "compile_s": compile_s, "eval_us": us})
        print(rows[-1], flush=True)
    return rows


def _rest_car():
    """The full vehicle on the ride's roads (:func:`benchmarks.wp_vehicle.ride`) at static rest."""
    from particlesim.reports.vehicle_ride import ride_car

    from .wp_vehicle import ride

    return ride_car(ride())


def _runner(mech, q, t_end, solve, saves=None, block=True):
    def run(m=mech):
        s = simulate_mechanism(m, q, jnp.zeros_like(q), 0.0, t_end, solver=RIDE["solver"], rtol=RIDE["rtol"],
                               atol=RIDE["rtol"] * 1e-2, events=True, saveat_ts=saves, solve=solve)
        return (s.q.block_until_ready() if block else s.q), s
    return run


def ride_rows() -> dict:
    """Dense and sparse on the 3 s ride, interleaved; compile times; their heave difference."""
    mech, q = _rest_car()
    b = mech.body_index("chassis")
    heave = jax.jit(jax.vmap(lambda x: body_com_positions(mech, x)[b, 2]))
    saves = jnp.linspace(0.0, RIDE["t_end"], 301)
    out = {"setting": RIDE}
    runs, traj = {}, {}
    for solve in ("dense", "sparse"):
        run = _runner(mech, q, RIDE["t_end"], solve)
        t = time.perf_counter()
        run()
        out[f"{solve}_first_s"] = time.perf_counter() - t
        runs[solve] = run
        sol = _runner(mech, q, RIDE["t_end"], solve, saves)()[1]
        traj[solve] = np.array(heave(sol.q), copy=True)
        out[f"{solve}_steps"], out[f"{solve}_rejected"] = int(sol.steps), int(sol.rejected)
    laps = {s: [] for s in runs}
    for _ in range(RIDE["laps"]):
        for s, run in runs.items():
            t = time.perf_counter()
            run()
            laps[s].append(time.perf_counter() - t)
    for s in runs:
        out[f"{s}_s"] = float(np.median(laps[s]))
        out[f"{s}_compile_s"] = out[f"{s}_first_s"] - out[f"{s}_s"]
    out["dense_over_sparse"] = out["dense_s"] / out["sparse_s"]
    out["heave_difference_m"] = float(np.abs(traj["sparse"] - traj["dense"]).max())
    ref = simulate_mechanism(mech, q, jnp.zeros_like(q), 0.0, RIDE["t_end"], solver="dopri8", rtol=1e-12,
                             atol=1e-14, events=True, saveat_ts=saves)
    ref = np.array(heave(ref.q), copy=True)
    for solve in runs:
        out[f"{solve}_max_error_m"] = float(np.abs(traj[solve] - ref).max())
    print(out, flush=True)
    return out


def batch_rows() -> dict:
    """16 spring-rate sets of the car, 1 s of the ride: one ``jax.vmap`` call against 16 single calls."""
    mech, q = _rest_car()
    scale = jnp.asarray(np.random.default_rng(0).uniform(0.8, 1.2, (BATCH, len(mech.spring_stiffness))))
    out = {"members": BATCH, "t_end": BATCH_T}
    for solve in ("dense", "sparse"):
        run = _runner(mech, q, BATCH_T, solve, block=False)

        def member(k):
            return run(dataclasses.replace(mech, spring_stiffness=mech.spring_stiffness * k))[1].q

        batched = jax.jit(jax.vmap(member))
        t = time.perf_counter()
        batched(scale).block_until_ready()
        first = time.perf_counter() - t
        b_s = median_time(lambda: batched(scale), number=1, repeat=3, block=lambda x: x.block_until_ready())
        member(scale[0])
        singles = median_time(lambda: [member(k) for k in scale], number=1, repeat=3,
                              block=lambda x: x[-1].block_until_ready())
        out[solve] = {"batch_s": b_s, "batch_compile_s": first - b_s, "singles_s": singles,
                      "throughput_ratio": singles / b_s}
        print(solve, out[solve], flush=True)
    return out


def slope(rows, solve) -> float:
    pts = [(r["corners"], r["eval_us"]) for r in rows if r["solve"] == solve and r["corners"] > 0]
    n, y = np.log([p[0] for p in pts]), np.log([p[1] for p in pts])
    return float(np.polyfit(n, y, 1)[0])


def plot(res: dict) -> None:
    fig, ax = pyplot().subplots(figsize=(5.5, 4))
    for solve, marker in (("dense", "o"), ("sparse", "s")):
        pts = [(r["corners"], r["eval_us"]) for r in res["scaling"] if r["solve"] == solve]
        ax.loglog(*zip(*pts), marker=marker, label=f"{solve} (slope {res['slopes'][solve]:.2f})")
    qc_us = next(r["eval_us"] for r in res["scaling"] if r["solve"] == "quarter car (dense)")
    ax.axhline(qc_us, color="grey", ls=":", label="quarter car (dense)")
    ax.set_xlabel("corners on the chassis")
    ax.set_ylabel("one evaluation of the accelerations [us]")
    ax.set_xticks(CORNER_N, [str(n) for n in CORNER_N])
    ax.legend()
    ax.set_title("Hub split against the dense solve")
    save_figure(fig, NAME, dpi=120, tight=True)


def main() -> dict:
    res = {"environment": environment(), "scaling": scaling(), "ride": ride_rows(), "batch": batch_rows()}
    res["slopes"] = {s: slope(res["scaling"], s) for s in ("dense", "sparse")}
    qc_us = next(r["eval_us"] for r in res["scaling"] if r["solve"] == "quarter car (dense)")
    res["four_corners_over_quarter_car"] = {r["solve"]: r["eval_us"] / qc_us for r in res["scaling"]
                                            if r["corners"] == 4}
    print(res["slopes"], res["four_corners_over_quarter_car"])
    write_results(NAME, res, res["scaling"])
    plot(res)
    return res


if __name__ == "__main__":
    main()
