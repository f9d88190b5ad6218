"""The mechanism engine's costs: compile times, gradients through rollouts, a batch of quarter cars against MuJoCo
C's native batched rollout, and chain scaling (float64, CPU).

* **Compile** of a forward rollout through the public entry point (first call minus a cached call; 301 saves), for
  the quarter car and the Nikravesh AA with Dopri8 and Tsit5; and for revolute chains N = 4..64 (dense and O(N)
  chain solve), with the log-log slope of compile time against N.
* **Gradients** of a quarter-car rollout loss (chassis displacement over 0.5 s, 51 samples) with respect to the
  spring, damper, tyre and body masses (9 parameters): reverse mode (checkpointed adjoint) and forward mode
  (``jax.jacfwd``, ForwardMode), compile and run, against the forward rollout.
* **Batch**: 1024 quarter cars whose spring, damper, tyre stiffness and damping and body masses differ (±20 %),
  1 s from rest. Ours: ``jax.vmap`` of ``simulate_mechanism`` and the chunked :func:`particlesim.batch.sharded_vmap`;
  MuJoCo C: ``mujoco.rollout`` over one model per member (tyre per model through the compiled callback) on 1 and 2
  threads. Every method is run at the loosest setting whose final chassis height is within 1e-6 m of a tight
  reference on 16 members (checked, listed).
* **Chains**: build time and cost per projected step (accepted + rejected) of the O(N) chain path and of the dense
  path for revolute chains N = 8..128, with log-log slopes.

Writes ``results/mechanism_engine.{json,csv,png}``. Run: ``python -m benchmarks.mechanism_engine``.
"""

from __future__ import annotations

import copy
import json
import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from particlesim import compiler_options
from particlesim.batch import sharded_vmap
from particlesim.twins import callbacks as mjcb
from particlesim.mechanism import simulate_mechanism
from particlesim.scenes import quarter_car as qc
from particlesim.scenes.chains import chain_geometry, chain_mechanism
from particlesim.scenes.nikravesh import aa_mechanism
from particlesim.twins.quarter_car import twin_xml

from ._common import RESULTS, environment, pyplot, report, save_figure, write_json, write_table
from ._native import Rollout, initial_state
from ._wp import _time

NAME = "mechanism_engine"
TARGET = 1e-6
BATCH = 1024
BATCH_T = 1.0
CHECKED = 16
CHAIN_COMPILE_N = (4, 8, 16, 32, 64)
CHAIN_STEP_N = (8, 16, 32, 64, 128)
#: long enough for tens of steps, so the fixed cost of a call does not flatten the slope
CHAIN_STEP_T = 0.5


def _first_and_cached(call) -> tuple[float, float]:
    t = time.perf_counter()
    call()
    first = time.perf_counter() - t
    _, run = _time(call, 3, lambda o: o)
    return max(first - run, 0.0), run


def _revolute_chain(n: int) -> tuple[float, object, jnp.ndarray]:
    """``(build_s, mech, x0)``: the revolute chain of ``n`` links (seed ``n``) and the time building it took."""
    t = time.perf_counter()
    mech, x0 = chain_mechanism(chain_geometry(n, "revolute", seed=n))
    build = time.perf_counter() - t
    return build, mech, jnp.asarray(x0)


def compile_times() -> list[dict]:
    rows = []
    for name, make, t1 in (("quarter car", qc.quarter_car, 3.0), ("Nikravesh AA", aa_mechanism, 2.0)):
        mech, x0 = make()
        x0 = jnp.asarray(x0)
        for solver in ("dopri8", "tsit5"):
            comp, run = _first_and_cached(lambda: simulate_mechanism(
                mech, x0, jnp.zeros_like(x0), 0.0, t1, solver=solver, rtol=1e-6, atol=1e-8,
                saveat_ts=np.linspace(0.0, t1, 301)).q.block_until_ready())
            rows.append({"scene": name, "solver": solver, "compile_s": comp, "run_s": run})
            print(rows[-1], flush=True)
    for n in CHAIN_COMPILE_N:
        build, mech, x0 = _revolute_chain(n)
        for solve in ("dense", "chain"):
            comp, run = _first_and_cached(lambda: simulate_mechanism(
                mech, x0, jnp.zeros_like(x0), 0.0, 0.5, solver="tsit5", rtol=1e-6, atol=1e-8,
                saveat_ts=np.linspace(0.0, 0.5, 301), solve=solve).q.block_until_ready())
            rows.append({"scene": f"revolute chain N={n}", "solver": "tsit5", "solve": solve, "n": n,
                         "build_s": build, "compile_s": comp, "run_s": run})
            print(rows[-1], flush=True)
    return rows


def _slope(ns, ys) -> float:
    return float(np.polyfit(np.log(ns), np.log(ys), 1)[0])


def _qc_params(mech, theta):
    """theta (9,): relative spring k, c, tyre k, c and the five body masses."""
    return mech.with_params(
        spring={"suspension": {"stiffness": theta[0] * qc.SPRING["stiffness"],
                               "damping": theta[1] * qc.SPRING["damping"]}},
        tyre={"tyre": {"stiffness": theta[2] * qc.TYRE["stiffness"], "damping": theta[3] * qc.TYRE["damping"]}},
        body={name: {"mass": theta[4 + i] * qc.TABLE1[name][0],
                     "inertia": theta[4 + i] * mech.body_inertia[mech.body_index(name)]}
              for i, name in enumerate(qc.TABLE1)})


def gradients() -> dict:
    mech, x0 = qc.quarter_car()
    x0 = jnp.asarray(x0)
    k = mech.point_index("centre")
    ts = np.linspace(0.0, 0.5, 51)

    def loss(theta, adjoint=None):
        m = _qc_params(mech, theta)
        s = simulate_mechanism(m, x0, jnp.zeros_like(x0), 0.0, 0.5, solver="tsit5", rtol=1e-8, atol=1e-10,
                               saveat_ts=ts, adjoint=adjoint)
        z = jax.vmap(lambda x: m.point_positions(m.all_positions(x))[k, 2])(s.q)
        return jnp.sum((z - z[0]) ** 2)

    theta = jnp.ones(9)
    fwd = jax.jit(loss, compiler_options=compiler_options())
    rev = jax.jit(jax.grad(loss), compiler_options=compiler_options())
    jf = jax.jit(jax.jacfwd(lambda th: loss(th, "forward")), compiler_options=compiler_options())
    out = {}
    for label, fn in (("rollout", fwd), ("reverse (checkpoint)", rev), ("forward (jacfwd)", jf)):
        comp, run = _first_and_cached(lambda: jax.block_until_ready(fn(theta)))
        out[label] = {"compile_s": comp, "run_s": run}
        print(label, out[label], flush=True)
    g_rev, g_fwd = np.asarray(rev(theta)), np.asarray(jf(theta))
    h = 1e-6
    fd = np.array([(float(fwd(theta.at[i].add(h))) - float(fwd(theta.at[i].add(-h)))) / (2 * h) for i in range(9)])
    out["rev_vs_fwd"] = float(np.abs(g_rev - g_fwd).max() / np.abs(g_fwd).max())
    out["rev_vs_central_differences"] = float(np.abs(g_rev - fd).max() / np.abs(fd).max())
    for label in ("reverse (checkpoint)", "forward (jacfwd)"):
        out[label]["cost_vs_rollout"] = out[label]["run_s"] / out["rollout"]["run_s"]
    return out


def _thetas(rng) -> np.ndarray:
    return rng.uniform(0.8, 1.2, size=(BATCH, 9))


#: The settings swept, loosest first, each side at the first that meets TARGET on the checked members (steps in
#: between so that neither stops far below the target: MuJoCo's error here falls as dt^2, the tyre's switch bounds
#: RK4's order): our rtol, and MuJoCo's step count over BATCH_T (dt = BATCH_T / n). Near the target ours steps by
#: about 26 % (ten per decade from 1e-2 to 1e-3), MuJoCo's dt by 10-14 % (1/100 to 1/250 s); both coarser beyond.
BATCH_RTOLS = tuple(float(f"{10 ** (-2 - k / 10):.2g}") for k in range(11)) + (5e-4, 2e-4, 1e-4, 1e-5)
BATCH_MUJOCO_STEPS = (100, 110, 125, 140, 160, 180, 200, 250, 500, 1000, 2000)
#: Ours in the batch: (solver, pid) - the default controller, and the less sensitive one that suits this
#: stability-bound scene (see ``benchmarks/quarter_car.py``; ``simulate_mechanism``'s docstring recommends it), with
#: the two solvers the single quarter car's sweep found fastest.
BATCH_SOLVERS = (("tsit5", None), ("tsit5", (0.2, 0.4, 0.0)), ("bosh3", (0.2, 0.4, 0.0)))
#: How the batch is run on one device: vectorised, chunks of 8 vectorised members, or members one after another.
BATCH_CHUNKS = (None, 8, 1)


def _batch_member(mech, x0):
    k = mech.point_index("centre")

    def member(theta, rtol, solver, pid=None):
        m = _qc_params(mech, theta)
        s = simulate_mechanism(m, x0, jnp.zeros_like(x0), 0.0, BATCH_T, solver=solver, rtol=rtol, atol=rtol * 1e-2,
                               max_steps=100_000, pid=pid)
        return m.point_positions(m.all_positions(s.q[-1]))[k, 2]

    return member


def _label(solver, pid, chunk, ndev=1):
    how = {None: "vmap", 1: "lax.map one at a time"}.get(chunk, f"lax.map chunks of {chunk}")
    ctl = "" if pid is None else f" PI({pid[0]:g}, {pid[1]:g})"
    return f"ours {solver}{ctl} {how}" + (f", {ndev} host devices" if ndev > 1 else "")


def _ours_batch_rows(thetas, ref, solvers=BATCH_SOLVERS, chunks=BATCH_CHUNKS, threads=1) -> list[dict]:
    """Ours on every device JAX sees (``sharded_vmap``; on one device in ``threads`` parts, one per thread): the
    loosest rtol meeting the target on the checked members, then the whole batch per chunking."""
    mech, x0 = qc.quarter_car()
    member = _batch_member(mech, jnp.asarray(x0))
    ndev = jax.device_count()
    rows = []
    for solver, pid in solvers:
        # rtol is traced: one compile serves the whole sweep
        f = jax.jit(jax.vmap(lambda th, r: member(th, r, solver, pid), in_axes=(0, None)),
                    compiler_options=compiler_options())
        sweep = []
        for rtol in BATCH_RTOLS:
            err = float(np.abs(np.asarray(f(jnp.asarray(thetas[:CHECKED]), rtol)) - ref).max())
            sweep.append([rtol, err])
            if err <= TARGET:
                break
        for chunk in chunks:
            fn = sharded_vmap(lambda th: member(th, rtol, solver, pid), chunk=chunk, threads=threads)
            comp, run = _first_and_cached(lambda: jax.block_until_ready(fn(jnp.asarray(thetas))))
            label = _label(solver, pid, chunk, ndev) + (f", {threads} threads (one device)" if threads > 1 else "")
            rows.append({"method": label, "setting": f"rtol {rtol:g}",
                         "checked_error_m": err, "wall_s": run, "compile_s": comp, "per_s": BATCH / run,
                         "sweep": sweep})
            print(rows[-1], flush=True)
    return rows


def _two_device_rows(thetas, ref) -> list[dict]:
    """The members-one-after-another rows again in a fresh process whose CPU is split into two host devices
    (``XLA_FLAGS`` must be set before JAX starts): ours on two cores, beside MuJoCo C on two threads."""
    import os
    import subprocess
    import sys
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        np.save(f"{tmp}/thetas.npy", thetas)
        np.save(f"{tmp}/ref.npy", ref)
        env = {**os.environ, "XLA_FLAGS": "--xla_force_host_platform_device_count=2"}
        subprocess.run([sys.executable, "-m", "benchmarks.mechanism_engine", "batch-worker", tmp], env=env,
                       check=True)
        return json.loads(open(f"{tmp}/rows.json").read())


def _batch_worker(tmp: str) -> None:
    rows = _ours_batch_rows(np.load(f"{tmp}/thetas.npy"), np.load(f"{tmp}/ref.npy"), chunks=(1,))
    open(f"{tmp}/rows.json", "w").write(json.dumps(rows))


def batch() -> dict:
    rng = np.random.default_rng(0)
    thetas = _thetas(rng)
    mech, x0 = qc.quarter_car()
    x0 = jnp.asarray(x0)
    member = _batch_member(mech, x0)
    ref_fn = jax.jit(jax.vmap(lambda th: member(th, 1e-12, "dopri8")))
    ref = np.asarray(ref_fn(jnp.asarray(thetas[:CHECKED])))
    rows = _ours_batch_rows(thetas, ref) + _ours_batch_rows(thetas, ref, chunks=(1,), threads=2)
    rows += _two_device_rows(thetas, ref)
    # MuJoCo C: one model per member, the tyre per model through the compiled callback
    base_xml = mjcb.tyre_numeric(twin_xml(1e-3), qc.TYRE["stiffness"], qc.TYRE["damping"])

    def models(dt, thetas_):
        m0 = mujoco.MjModel.from_xml_string(base_xml.replace('timestep="0.001"', f'timestep="{dt!r}"'))
        spring = mujoco.mj_name2id(m0, mujoco.mjtObj.mjOBJ_TENDON, "spring")
        out = []
        for th in thetas_:
            m = copy.copy(m0)
            m.tendon_stiffness[spring] = th[0] * qc.SPRING["stiffness"]
            m.tendon_damping[spring] = th[1] * qc.SPRING["damping"]
            m.numeric_data[0:2] = (th[2] * qc.TYRE["stiffness"], th[3] * qc.TYRE["damping"])
            for i, name in enumerate(qc.TABLE1):
                b = mujoco.mj_name2id(m0, mujoco.mjtObj.mjOBJ_BODY, name)
                m.body_mass[b] = m0.body_mass[b] * th[4 + i]
                m.body_inertia[b] = m0.body_inertia[b] * th[4 + i]
            out.append(m)
        return out, m0

    site_body = None
    sweep = []
    for nsteps in BATCH_MUJOCO_STEPS:
        dt = BATCH_T / nsteps
        ms, m0 = models(dt, thetas[:CHECKED])
        site = mujoco.mj_name2id(m0, mujoco.mjtObj.mjOBJ_SITE, "centre")
        site_body = mujoco.mj_name2id(m0, mujoco.mjtObj.mjOBJ_BODY, "chassis")
        mjcb.install_tyres([(site, (0, 0, 1), float(qc._p(10)[2]) - qc.TYRE["radius"], qc.TYRE["radius"],
                             qc.TYRE["stiffness"], qc.TYRE["damping"])])
        s0 = np.stack([initial_state(m) for m in ms])
        nstep = int(round(BATCH_T / dt))
        ro = Rollout(ms, s0, nstep)
        states = ro()
        z = np.array([ro.trajectory(states, lambda mm, dd: dd.xpos[site_body, 2], nstep, member=i)[-1, 0]
                      for i in range(CHECKED)])
        err = float(np.abs(z - ref).max()) if np.all(np.isfinite(z)) else float("inf")
        print(f"MuJoCo C dt {dt:g}: checked error {err:.2e}", flush=True)
        sweep.append([dt, err])
        if err <= TARGET:
            break
    ms, _ = models(dt, thetas)
    s0 = np.stack([initial_state(m) for m in ms])
    for nthread in (0, 2):
        ro = Rollout(ms, s0, int(round(BATCH_T / dt)), nthread=nthread)
        _, wall = ro.timed(3)
        rows.append({"method": f"MuJoCo C mujoco.rollout nthread {max(nthread, 1)}", "setting": f"dt {dt:g}",
                     "checked_error_m": err, "wall_s": wall, "compile_s": None, "per_s": BATCH / wall,
                     "sweep": sweep})
        print(rows[-1], flush=True)
    mjcb.uninstall()
    return {"rows": rows, "batch": BATCH, "t_end_s": BATCH_T, "checked_members": CHECKED}


def chain_steps() -> list[dict]:
    rows = []
    for n in CHAIN_STEP_N:
        build, mech, x0 = _revolute_chain(n)
        for solve in ("chain", "dense"):
            if solve == "dense" and n > 64:
                continue
            call = lambda: simulate_mechanism(mech, x0, jnp.zeros_like(x0), 0.0, CHAIN_STEP_T, solver="tsit5",  # noqa: E731
                                              rtol=1e-8, atol=1e-10, solve=solve)
            sol = call()
            _, wall = _time(lambda: call().q.block_until_ready(), 3, lambda o: o)
            steps = int(sol.steps) + int(sol.rejected)
            rows.append({"n": n, "solve": solve, "build_s": build, "steps": steps, "wall_s": wall,
                         "per_step_s": wall / steps})
            print(rows[-1], flush=True)
    return rows


def run() -> dict:
    started = time.perf_counter()
    res = {"benchmark": NAME, "environment": environment()}
    res["compile"] = compile_times()
    chain_rows = [r for r in res["compile"] if r.get("n")]
    res["compile_slope_chain_dense"] = _slope([r["n"] for r in chain_rows if r["solve"] == "dense"],
                                              [r["compile_s"] for r in chain_rows if r["solve"] == "dense"])
    res["compile_slope_chain_chain"] = _slope([r["n"] for r in chain_rows if r["solve"] == "chain"],
                                              [r["compile_s"] for r in chain_rows if r["solve"] == "chain"])
    res["gradients"] = gradients()
    res["batch"] = batch()
    res["chain_steps"] = chain_steps()
    ch = [r for r in res["chain_steps"] if r["solve"] == "chain"]
    res["step_slope_chain"] = _slope([r["n"] for r in ch], [r["per_step_s"] for r in ch])
    res["elapsed_s"] = time.perf_counter() - started
    return res


def write(res: dict) -> None:
    write_json(NAME, res)
    write_table(NAME, ["part", "what", "setting", "wall_s", "compile_s", "extra"],
                [["compile", r["scene"], f"{r['solver']} {r.get('solve', 'dense')}", r["run_s"], r["compile_s"],
                  r.get("build_s", "")] for r in res["compile"]]
                + [["gradient", k, "", v["run_s"], v["compile_s"], v.get("cost_vs_rollout", "")]
                   for k, v in res["gradients"].items() if isinstance(v, dict)]
                + [["batch", r["method"], r["setting"], r["wall_s"], r["compile_s"], r["per_s"]]
                   for r in res["batch"]["rows"]]
                + [["chain step", f"N={r['n']}", r["solve"], r["per_step_s"], "", r["build_s"]]
                   for r in res["chain_steps"]])
    fig, (a1, a2) = pyplot().subplots(1, 2, figsize=(11, 4.4), constrained_layout=True)
    for solve in ("dense", "chain"):
        sel = [r for r in res["compile"] if r.get("solve") == solve]
        a1.loglog([r["n"] for r in sel], [r["compile_s"] for r in sel], marker="o", label=f"compile, {solve}")
        sel = [r for r in res["chain_steps"] if r["solve"] == solve]
        a2.loglog([r["n"] for r in sel], [r["per_step_s"] for r in sel], marker="o", label=f"per step, {solve}")
    a1.set_xlabel("links N")
    a1.set_ylabel("compile [s]")
    a2.set_xlabel("links N")
    a2.set_ylabel("wall time per projected Tsit5 step [s]")
    for a in (a1, a2):
        a.grid(True, which="both", alpha=0.3)
        a.legend(fontsize=8)
    save_figure(fig, NAME, dpi=110,
                title=f"Revolute chains: compile and step cost against N ({res['environment']['cpu']})")


def _fmt(x: float) -> str:
    return f"{round(x, 2) + 0.0:.2f}"  # no "-0.00"


def markdown(res: dict) -> str:
    env = res["environment"]
    lines = ["### Mechanism engine: compile, gradients, batch, chain scaling", "",
             f"{env['cpu']}, {env['cpu_count']} cores, load {env['load_average_1_5_15min'][0]:.1f}, {env['date']}; "
             f"least of repeats, compile separate. Took {res['elapsed_s'] / 60:.1f} min.", "",
             "| compile of a forward rollout (301 saves) | solver | compile | run |", "|---|---|---:|---:|"]
    for r in res["compile"]:
        if not r.get("n"):
            lines.append(f"| {r['scene']} | {r['solver']} | {r['compile_s']:.1f} s | {r['run_s'] * 1e3:.1f} ms |")
    lines += ["", "| revolute chain | build | compile dense | compile chain |", "|---|---:|---:|---:|"]
    for n in CHAIN_COMPILE_N:
        d = next(r for r in res["compile"] if r.get("n") == n and r["solve"] == "dense")
        c = next(r for r in res["compile"] if r.get("n") == n and r["solve"] == "chain")
        lines.append(f"| N = {n} | {d['build_s']:.2f} s | {d['compile_s']:.1f} s | {c['compile_s']:.1f} s |")
    lines += ["", f"Compile-time slope (log-log, N = {CHAIN_COMPILE_N[0]}..{CHAIN_COMPILE_N[-1]}): dense "
              f"{_fmt(res['compile_slope_chain_dense'])}, chain {_fmt(res['compile_slope_chain_chain'])}.", ""]
    g = res["gradients"]
    lines += ["| quarter-car loss (9 parameters, 0.5 s) | compile | run | × rollout |", "|---|---:|---:|---:|"]
    for k in ("rollout", "reverse (checkpoint)", "forward (jacfwd)"):
        v = g[k]
        lines.append(f"| {k} | {v['compile_s']:.1f} s | {v['run_s'] * 1e3:.1f} ms | "
                     f"{v.get('cost_vs_rollout', 1.0):.1f} |")
    lines += ["", f"Reverse vs forward gradient: {g['rev_vs_fwd']:.1e}; vs central differences "
              f"{g['rev_vs_central_differences']:.1e} (relative to the largest entry).", ""]
    b = res["batch"]
    lines += [f"| {b['batch']} quarter cars, {b['t_end_s']:g} s | setting | error on {b['checked_members']} "
              f"checked | wall | rollouts/s | compile |", "|---|---|---:|---:|---:|---:|"]
    for r in b["rows"]:
        comp = "" if r["compile_s"] is None else f"{r['compile_s']:.1f} s"
        lines.append(f"| {r['method']} | {r['setting']} | {r['checked_error_m']:.1e} | {r['wall_s']:.2f} s | "
                     f"{r['per_s']:.0f} | {comp} |")
    sweeps = [(r["method"], r["sweep"]) for r in b["rows"] if r.get("sweep")]
    if sweeps:
        lines += ["", "Settings swept (loosest first, up to the first meeting the target; setting: checked error): " +
                  "; ".join(f"{m.split(' lax.map')[0]}: " + ", ".join(f"{v:.3g}: {e:.1e}" for v, e in sw)
                            for m, sw in sweeps if m.endswith("one at a time") or m.endswith("nthread 1")) + "."]
    if b.get("rerun"):
        rr = b["rerun"]
        load = (f"load {rr['load_before']:.1f} before it, {rr['load']:.1f} after" if "load_before" in rr
                else f"load {rr.get('load', float('nan')):.1f}")
        lines += ["", f"Batch rows rerun {rr['date']} ({load}). "
                  "Ours runs each member's adaptive loop alone ('one at a time') or vectorised; vectorised members "
                  "step together and every step carries the whole slice, which costs more per member here."]
    if res.get("chain_steps_rerun"):
        rr = res["chain_steps_rerun"]
        load = (f"load {rr['load_before']:.1f} before it, {rr['load']:.1f} after" if "load_before" in rr
                else f"load {rr.get('load', float('nan')):.1f}")
        lines += ["", f"Chain rows rerun {rr['date']} ({load})."]
    lines += ["", "| revolute chain | solve | build | steps | per projected step |", "|---|---|---:|---:|---:|"]
    for r in res["chain_steps"]:
        lines.append(f"| N = {r['n']} | {r['solve']} | {r['build_s']:.2f} s | {r['steps']} | "
                     f"{r['per_step_s'] * 1e6:.0f} µs |")
    lines += ["", f"Step-cost slope of the chain path (log-log, N = {CHAIN_STEP_N[0]}..{CHAIN_STEP_N[-1]}): "
              f"{_fmt(res['step_slope_chain'])}.", ""]
    return "\n".join(lines)


def _rerun_stamp(before: dict, after: dict) -> dict:
    """Date and 1-minute load averages before and after a partial rerun (stored with its rows)."""
    return {"date": after["date"], "load_before": before["load_average_1_5_15min"][0],
            "load": after["load_average_1_5_15min"][0]}


def rerun_batch() -> dict:
    """Redo only the batch part of the saved results (``python -m benchmarks.mechanism_engine batch``)."""
    res = json.loads((RESULTS / f"{NAME}.json").read_text())
    before = environment()  # the load before the run (afterwards it counts the run itself)
    started = time.perf_counter()
    res["batch"] = batch()
    env = environment()
    res["batch"]["rerun"] = {**_rerun_stamp(before, env), "took_s": time.perf_counter() - started}
    return res


def rerun_chain_steps() -> dict:
    """Redo only the chain-step part of the saved results (``python -m benchmarks.mechanism_engine chains``)."""
    res = json.loads((RESULTS / f"{NAME}.json").read_text())
    before = environment()
    res["chain_steps"] = chain_steps()
    ch = [r for r in res["chain_steps"] if r["solve"] == "chain"]
    res["step_slope_chain"] = _slope([r["n"] for r in ch], [r["per_step_s"] for r in ch])
    res["chain_steps_rerun"] = _rerun_stamp(before, environment())
    return res


def main() -> dict:
    return report(run, write, markdown)


if __name__ == "__main__":
    import sys

    if sys.argv[1:2] == ["batch-worker"]:
        _batch_worker(sys.argv[2])
    elif sys.argv[1:] == ["batch"]:
        report(rerun_batch, write, markdown)
    elif sys.argv[1:] == ["chains"]:
        report(rerun_chain_steps, write, markdown)
    else:
        main()
