"""Cost of one acceleration evaluation along serial chains: the O(N) tip-to-base recursion against the dense
saddle-point solve, N = 2 .. 64, spherical and revolute joints, side by side with MuJoCo C's ``mj_forward`` on the
same chain (:func:`particlesim.twins.chains.chain_mjcf`; one call from Python, which includes MuJoCo's own
dispatch of a few hundred ns). Log-log slopes over the larger N.

Each evaluation is timed inside a compiled ``lax.fori_loop`` of ``REPEATS`` evaluations (no dispatch), median of
repeats; compile time separately. Run: ``python -m benchmarks.mechanism_recursive``.
"""

from __future__ import annotations

import time

import jax
import mujoco
import jax.numpy as jnp
import numpy as np

from particlesim.mechanism import accelerations, chain_accelerations, chain_plan, mass_properties, project
from particlesim.scenes.chains import chain_geometry, chain_mechanism
from particlesim.twins.chains import chain_mjcf

from ._common import environment, median_time, pyplot, report, save_figure, timed, write_csv, write_json

NAME = "mechanism_recursive"
SIZES = (2, 4, 8, 16, 32, 64)
REPEATS = 20
SLOPE_FROM = 8  # fit the slope over N >= this


def _loop(step):
    def run(mech, x, xd):
        def body(_, acc):
            return acc + step(mech, x, xd + 1e-12 * acc)

        return jax.lax.fori_loop(0, REPEATS, body, jnp.zeros_like(x))

    return jax.jit(run)


def run() -> dict:
    started = time.perf_counter()
    rows = []
    for joint in ("spherical", "revolute"):
        for n in SIZES:
            geom = chain_geometry(n, joint, seed=n)
            mech, x0 = chain_mechanism(geom)
            m = mujoco.MjModel.from_xml_string(chain_mjcf(geom)[0])
            d = mujoco.MjData(m)
            d.qvel[:] = np.random.default_rng(n).normal(size=m.nv)
            per = median_time(lambda: mujoco.mj_forward(m, d), number=200, repeat=5)
            rows.append({"joint": joint, "n": n, "solve": "MuJoCo C", "coords": int(m.nq),
                         "us_per_eval": per * 1e6, "compile_s": None})
            x, xd = project(mech, jnp.asarray(x0), jnp.asarray(np.random.default_rng(n).normal(size=x0.shape)))
            plan = chain_plan(mech)
            props = mass_properties(mech)
            for name, step in (
                ("recursive", lambda m, a, b: chain_accelerations(m, plan, 0.0, a, b)),
                ("dense", lambda m, a, b: accelerations(m, 0.0, a, b, props=props)),
            ):
                f = _loop(step)
                t_compile, _ = timed(lambda: f.lower(mech, x, xd).compile())
                per = median_time(lambda: f(mech, x, xd), number=3, repeat=5, block=jax.block_until_ready) / REPEATS
                rows.append({"joint": joint, "n": n, "solve": name, "coords": int(x.shape[0]),
                             "us_per_eval": per * 1e6, "compile_s": t_compile})
                print(f"{joint:9s} N={n:3d} {name:9s} {per * 1e6:10.1f} us/eval  compile {t_compile:.1f} s")
    slopes = {}
    for joint in ("spherical", "revolute"):
        for name in ("recursive", "dense", "MuJoCo C"):
            sel = [r for r in rows if r["joint"] == joint and r["solve"] == name and r["n"] >= SLOPE_FROM]
            slopes[f"{joint}/{name}"] = float(np.polyfit(np.log([r["n"] for r in sel]),
                                                         np.log([r["us_per_eval"] for r in sel]), 1)[0])
    return {"environment": environment(), "rows": rows, "loglog_slope_n_ge_8": slopes,
            "elapsed_s": time.perf_counter() - started}


def write(out: dict) -> None:
    write_json(NAME, out, newline=False)
    write_csv(NAME, out["rows"])
    _plot(out["rows"])


def _plot(rows) -> None:
    fig, ax = pyplot().subplots(figsize=(6, 4.5), constrained_layout=True)
    for joint, style in (("spherical", "-"), ("revolute", "--")):
        for name, marker in (("recursive", "o"), ("dense", "s"), ("MuJoCo C", "^")):
            sel = [r for r in rows if r["joint"] == joint and r["solve"] == name]
            ax.loglog([r["n"] for r in sel], [r["us_per_eval"] for r in sel], style, marker=marker,
                      label=f"{joint}, {name}")
    ax.set_xlabel("bodies N")
    ax.set_ylabel("µs per acceleration evaluation")
    ax.set_title("Serial chains: recursion vs dense solve vs MuJoCo C mj_forward")
    ax.legend()
    save_figure(fig, NAME, dpi=110)


def markdown(results: dict) -> str:
    rows = results["rows"]
    env = results["environment"]
    lines = ["### Serial chains: acceleration cost against N, O(N) recursion vs dense solve vs MuJoCo C", "",
             f"{env['cpu']}, load average {env['load_average_1_5_15min'][0]:.1f}, {env['date']}. "
             "Ours: µs per evaluation inside a compiled loop (compile time in brackets). MuJoCo C: `mj_forward` per "
             "call (positions, velocities and accelerations of the same chain in joint coordinates).", "",
             "| joint | N | recursive | dense | dense / recursive | MuJoCo C | recursive / MuJoCo C |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    for joint in ("spherical", "revolute"):
        for n in SIZES:
            r = {x["solve"]: x for x in rows if x["joint"] == joint and x["n"] == n}
            lines.append(f"| {joint} | {n} | {r['recursive']['us_per_eval']:.1f} ({r['recursive']['compile_s']:.1f} s) "
                         f"| {r['dense']['us_per_eval']:.1f} ({r['dense']['compile_s']:.1f} s) "
                         f"| {r['dense']['us_per_eval'] / r['recursive']['us_per_eval']:.1f} "
                         f"| {r['MuJoCo C']['us_per_eval']:.1f} "
                         f"| {r['recursive']['us_per_eval'] / r['MuJoCo C']['us_per_eval']:.1f} |")
    s = results["loglog_slope_n_ge_8"]
    lines += ["", "Log-log slope of cost against N (N ≥ 8): " + ", ".join(f"{k} {v:.2f}" for k, v in s.items())
              + " (goal for the recursion: ≤ 1.2)."]
    return "\n".join(lines) + "\n"


def main() -> dict:
    return report(run, write, markdown)


if __name__ == "__main__":
    main()
