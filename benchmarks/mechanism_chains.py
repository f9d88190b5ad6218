"""Cost of the particle-coordinate pendulum chains, N = 2 .. 64 links (revolute and spherical), float64, CPU: ours
(dense saddle-point solve) against MuJoCo C and MJX on the same chains (:func:`particlesim.scenes.chains.chain_mjcf`).

Rows per (joint, N):
  ours ``accelerations`` inside a compiled ``lax.fori_loop`` of ``LOOP`` dependent evaluations (no dispatch) and as
  one jitted call (with dispatch); MuJoCo C ``mj_forward`` per call; MJX ``forward`` in a compiled loop and as one
  jitted call; ours one simulated second (Tsit5, rtol 1e-8, atol 1e-10, projected) from the assembly pose at rest.
Compile times are measured separately (``lower().compile()``); run times are medians of repeats, blocked on.
Log-log slopes of cost against N are fitted over N >= ``SLOPE_FROM``. :func:`particlesim.mechanism.accelerations`
solves the dense KKT system of ~(3F + C) unknowns, so its cost grows like N^2..N^3; the O(N) recursion
(``chain_accelerations``) is benchmarked in ``mechanism_recursive``. Run: ``python -m benchmarks.mechanism_chains``.
"""

from __future__ import annotations

import csv
import json
import time

import particlesim  # noqa: F401  (float64)
import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from particlesim.mechanism import accelerations, mass_properties, project, simulate_mechanism
from particlesim.scenes.chains import chain_geometry, chain_mechanism, chain_mjcf

from ._common import RESULTS, environment, median_time, timed

NAME = "mechanism_chains"
SIZES = (2, 4, 8, 16, 32, 64)
MJX_MAX_N = 4  # MJX 3.17 on deeper chains: N = 8 revolute took 12 ms per forward in a loop, 1.1 s per call and
# ~3 min in all (measured once, load ~4); N = 64 had not compiled after 3 min
SIM_MAX_N = 8  # one simulated second: revolute N = 16 took 21 s, spherical N = 16 over 2 min (dense solve)
LOOP = 100  # evaluations per compiled loop (fewer for N > 8: see _loop_len)
SLOPE_FROM = 8
SERIES = ("ours accelerations (loop)", "ours accelerations (1 call)", "MuJoCo C mj_forward",
          "MJX forward (loop)", "MJX forward (1 call)", "ours 1 simulated s (tsit5 1e-8)")


def _loop_len(n: int) -> int:
    return LOOP if n <= 8 else 10


def _reps(n: int) -> dict:
    return {"number": 3, "repeat": 5} if n <= 16 else {"number": 1, "repeat": 3}


def _compile(fn, *args):
    t, compiled = timed(lambda: jax.jit(fn).lower(*args).compile())
    return compiled, t


def _ours(mech, x, xd, n):
    props = mass_properties(mech)
    out = {}

    k = _loop_len(n)

    def loop(mech, x, xd):
        return jax.lax.fori_loop(0, k, lambda i, a: a + accelerations(mech, 0.0, x, xd + 1e-12 * a, props=props),
                                 jnp.zeros_like(x))

    f, c = _compile(loop, mech, x, xd)
    out[SERIES[0]] = (median_time(lambda: f(mech, x, xd), **_reps(n), block=jax.block_until_ready) / k, c)
    g, c = _compile(lambda mech, x, xd: accelerations(mech, 0.0, x, xd, props=props), mech, x, xd)
    out[SERIES[1]] = (median_time(lambda: g(mech, x, xd), number=20, repeat=5, block=jax.block_until_ready), c)
    if n <= SIM_MAX_N:
        def sim(mech, x):
            s = simulate_mechanism(mech, x, jnp.zeros_like(x), 0.0, 1.0, solver="tsit5", rtol=1e-8, atol=1e-10)
            return s.q[-1], s.steps

        h, c = _compile(sim, mech, x)
        t = median_time(lambda: h(mech, x), number=1, repeat=3, block=jax.block_until_ready)
        out[SERIES[5]] = (t, c, int(h(mech, x)[1]))
    return out


def _mujoco(geom, qvel_seed):
    k = _loop_len(geom.n)
    from mujoco import mjx

    xml, _ = chain_mjcf(geom, timestep=1e-3)
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    d.qvel[:] = np.random.default_rng(qvel_seed).normal(size=m.nv)
    out = {SERIES[2]: (median_time(lambda: mujoco.mj_forward(m, d), number=200, repeat=5), None)}
    if geom.n > MJX_MAX_N:
        return out
    mx = mjx.put_model(m)
    with jax.numpy_rank_promotion("allow"):
        dx = mjx.put_data(m, d)

        def loop(mx, dx):
            def body(i, acc):
                return acc + mjx.forward(mx, dx.replace(qvel=dx.qvel + 1e-12 * acc)).qacc
            return jax.lax.fori_loop(0, k, body, jnp.zeros_like(dx.qvel))

        f, c = _compile(loop, mx, dx)
        out[SERIES[3]] = (median_time(lambda: f(mx, dx), **_reps(geom.n), block=jax.block_until_ready) / k, c)
        g, c = _compile(lambda mx, dx: mjx.forward(mx, dx).qacc, mx, dx)
        out[SERIES[4]] = (median_time(lambda: g(mx, dx), number=20, repeat=5, block=jax.block_until_ready), c)
    return out


def run(sizes=SIZES) -> dict:
    rows = []
    for joint in ("revolute", "spherical"):
        for n in sizes:
            t0 = time.perf_counter()
            geom = chain_geometry(n, joint, seed=n)
            mech, x0 = chain_mechanism(geom)
            x, xd = project(mech, jnp.asarray(x0), jnp.asarray(np.random.default_rng(n).normal(size=x0.shape)))
            res = {**_ours(mech, x, xd, n), **_mujoco(geom, n)}
            for series, val in res.items():
                rows.append({"joint": joint, "n": n, "coords": int(x.shape[0]), "series": series,
                             "time_us": val[0] * 1e6, "compile_s": val[1],
                             "steps": val[2] if len(val) > 2 else None})
            print(f"{joint:9s} N={n:3d} " + "  ".join(f"{k}: {v[0] * 1e6:.1f} us" for k, v in res.items())
                  + f"  [{time.perf_counter() - t0:.0f} s]", flush=True)
    slopes = {}
    for joint in ("revolute", "spherical"):
        for series in SERIES:
            sel = [r for r in rows if r["joint"] == joint and r["series"] == series and r["n"] >= SLOPE_FROM]
            if len(sel) >= 2:
                slopes[f"{joint} / {series}"] = float(np.polyfit(np.log([r["n"] for r in sel]),
                                                                 np.log([r["time_us"] for r in sel]), 1)[0])
    return {"benchmark": NAME, "environment": environment(), "rows": rows, "loglog_slopes": slopes,
            "slope_from_n": SLOPE_FROM, "loop": LOOP, "sim_max_n": SIM_MAX_N, "mjx_max_n": MJX_MAX_N}


def write(results: dict) -> None:
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / f"{NAME}.json").write_text(json.dumps(results, indent=2) + "\n")
    with open(RESULTS / f"{NAME}.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=["joint", "n", "coords", "series", "time_us", "compile_s", "steps"])
        w.writeheader()
        w.writerows(results["rows"])
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5), sharey=True, constrained_layout=True)
    for ax, joint in zip(axes, ("revolute", "spherical")):
        for series in SERIES:
            sel = [r for r in results["rows"] if r["joint"] == joint and r["series"] == series]
            if sel:
                ax.loglog([r["n"] for r in sel], [r["time_us"] for r in sel], marker="o", label=series)
        ax.set_xlabel("links N")
        ax.set_title(f"{joint} chains")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel("µs (per evaluation; per simulated s for the rollout)")
    axes[1].legend(fontsize=7)
    fig.savefig(RESULTS / f"{NAME}.png", dpi=110)
    plt.close(fig)


def markdown(results: dict) -> str:
    env = results["environment"]
    rows = results["rows"]

    def cell(joint, n, series):
        r = [x for x in rows if x["joint"] == joint and x["n"] == n and x["series"] == series]
        if not r:
            return "—"
        t = r[0]["time_us"]
        s = f"{t:.1f} µs" if t < 1e4 else f"{t / 1e3:.0f} ms"
        return s + (f" ({r[0]['steps']} steps)" if r[0]["steps"] else "")

    short = ["ours, loop", "ours, 1 call", "MuJoCo C", "MJX, loop", "MJX, 1 call", "ours, 1 s sim"]
    lines = [f"### Pendulum chains: cost against N (dense KKT solve vs MuJoCo C / MJX)", "",
             f"{env['cpu']}, {env['cpu_count']} cores, load average {env['load_average_1_5_15min'][0]:.1f} "
             f"(1 min), {env['date']}. Per acceleration evaluation (loop = {results['loop']} evaluations (10 for N > 8) in one "
             "compiled loop, no dispatch; 1 call = one jitted call with dispatch); MuJoCo C = `mj_forward` per call; "
             f"1 s sim = Tsit5 rtol 1e-8 wall time per simulated second (N ≤ {results['sim_max_n']} only: beyond, "
             f"one simulated second took 21 s for revolute N = 16 and over 2 min for spherical N = 16); MJX for N ≤ {results['mjx_max_n']} only (MJX 3.17 "
             "degrades sharply with depth here: N = 8 revolute measured once at 12 ms per forward in a loop and 1.1 s "
             "per call, ~3 min with compiles; N = 64 had not compiled after 3 min).", "",
             "| joint | N | " + " | ".join(short) + " |", "|---|---:|" + "---:|" * len(short)]
    for joint in ("revolute", "spherical"):
        for n in sorted({r["n"] for r in rows}):
            lines.append(f"| {joint} | {n} | " + " | ".join(cell(joint, n, s) for s in SERIES) + " |")
    lines += ["", f"Log-log slope of cost against N (N ≥ {results['slope_from_n']}):", "",
              "| series | revolute | spherical |", "|---|---:|---:|"]
    sl = results["loglog_slopes"]
    for s in SERIES:
        lines.append(f"| {s} | {sl.get(f'revolute / {s}', float('nan')):.2f} | "
                     f"{sl.get(f'spherical / {s}', float('nan')):.2f} |")
    comp = {s: max((r["compile_s"] or 0.0) for r in rows if r["series"] == s) for s in SERIES if s != SERIES[2]}
    lines += ["", "Largest compile times: " + ", ".join(f"{k} {v:.1f} s" for k, v in comp.items()) + ". "
              "`accelerations` solves the dense saddle-point system, so its slope is 2–3; the O(N) recursion is in "
              "the `mechanism_recursive` table.", ""]
    return "\n".join(lines)


def main(sizes=SIZES) -> dict:
    print(f"devices: {jax.devices()}")
    results = run(sizes)
    write(results)
    print(markdown(results))
    return results


if __name__ == "__main__":
    import sys

    main(tuple(int(a) for a in sys.argv[1:]) or SIZES)
