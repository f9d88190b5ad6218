"""Forward dynamics of serial chains against their size, N = 7..200 links (float64, CPU): compile time, cost per call
and per batched state, ours beside Pinocchio's ABA and ``abaInParallel``.

Chains: seeded random revolute chains (random axes, joint origins and inertias), written as URDF and loaded by both
libraries. Ours: ``forward_dynamics`` jitted for one state (composite inertias and Cholesky up to
``particlesim.tree.aba.UNROLL_LINKS`` links unless the tree is deep, articulated-body sweeps laid out for one state
beyond and for deep trees: chains of 16 links or more), timed per call
from Python and per evaluation inside a compiled scan (no dispatch); and for a batch of states passed directly
(articulated-body sweeps with the batch innermost). Pinocchio: ``pin.aba`` per call from Python, and its batched C++
``abaInParallel`` on 1 thread, the whole process pinned to one core. Compile times are
``jit(...).lower(...).compile()``; run times least of repeats.
Run: ``python -m benchmarks.tree_scaling``.
"""

from __future__ import annotations

import os
import time

import jax
import jax.numpy as jnp
import numpy as np

from particlesim import compiler_options
from particlesim._xla import cpu_options
from particlesim.tree import forward_dynamics
from particlesim.io import load_urdf
from particlesim.tree.aba import ONE_STATE_SWEEPS_DEPTH, UNROLL_LINKS, one_state_sweeps

from ._common import environment, pyplot, report, save_figure, timed, write_csv, write_json

NAME = "tree_scaling"
SIZES = (7, 25, 50, 100, 200)
BATCH = 256
SCAN = 200
SLOPE_FROM = 25


def chain_urdf(n: int, seed: int = 0) -> str:
    rng = np.random.default_rng(seed)

    def fmt(v):
        return " ".join(f"{x:.17g}" for x in v)

    links, joints = ['<link name="base"/>'], []
    for i in range(n):
        m = rng.uniform(0.5, 2.0)
        a, b = rng.uniform(0.01, 0.05, 2)
        c = rng.uniform(abs(a - b) + 0.005, a + b - 0.005)
        links.append(f'<link name="l{i}"><inertial><mass value="{m:.17g}"/><origin xyz="{fmt(rng.uniform(-0.1, 0.1, 3))}"'
                     f' rpy="{fmt(rng.uniform(-1, 1, 3))}"/><inertia ixx="{a:.17g}" ixy="0" ixz="0" iyy="{b:.17g}" '
                     f'iyz="0" izz="{c:.17g}"/></inertial></link>')
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        parent = "base" if i == 0 else f"l{i - 1}"
        joints.append(f'<joint name="j{i}" type="continuous"><parent link="{parent}"/><child link="l{i}"/>'
                      f'<origin xyz="{fmt(rng.uniform(-0.2, 0.2, 3))}" rpy="{fmt(rng.uniform(-3, 3, 3))}"/>'
                      f'<axis xyz="{fmt(axis)}"/></joint>')
    return '<robot name="chain">' + "".join(links) + "".join(joints) + "</robot>"


def _least(fn, repeat=5):
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def run_size(n: int) -> dict:
    import pinocchio as pin

    urdf = chain_urdf(n)
    model = load_urdf(urdf)
    rng = np.random.default_rng(1)
    qs, qds, taus = rng.uniform(-2, 2, (BATCH, n)), rng.normal(size=(BATCH, n)), rng.normal(size=(BATCH, n))
    jq, jqd, jtau = (jnp.asarray(x) for x in (qs, qds, taus))
    row = {"n": n, "one_state_path": "articulated-body sweeps" if one_state_sweeps(model) else "composite inertias + Cholesky"}

    q1, qd1, tau1 = jq[0], jqd[0], jtau[0]  # sliced once (an eager slice per call would cost more than the call)
    c, single = timed(lambda: jax.jit(forward_dynamics, compiler_options=compiler_options())
                      .lower(model, q1, qd1, tau1).compile())
    row["compile_single_s"] = c
    single(model, q1, qd1, tau1).block_until_ready()
    calls = 50
    row["single_call_us"] = _least(lambda: [single(model, q1, qd1, tau1).block_until_ready()
                                            for _ in range(calls)]) / calls * 1e6

    def chain(q, qd, tau):
        return jax.lax.scan(lambda q, _: (q + 1e-9 * forward_dynamics(model, q, qd, tau), None), q, None,
                            length=SCAN)[0]

    c, scanned = timed(lambda: jax.jit(chain, compiler_options=compiler_options()).lower(q1, qd1, tau1).compile())
    row["compile_scan_s"] = c
    scanned(q1, qd1, tau1).block_until_ready()
    row["in_scan_us"] = _least(lambda: scanned(q1, qd1, tau1).block_until_ready()) / SCAN * 1e6

    c, batched = timed(lambda: jax.jit(forward_dynamics, compiler_options=cpu_options(batch=True))
                       .lower(model, jq, jqd, jtau).compile())
    row["compile_batch_s"] = c
    out = np.asarray(batched(model, jq, jqd, jtau))
    row["batch_per_state_us"] = _least(lambda: batched(model, jq, jqd, jtau).block_until_ready()) / BATCH * 1e6

    pm = pin.buildModelFromXML(urdf)
    pm.gravity.linear = np.asarray(model.gravity)
    pdata = pm.createData()
    assert list(pm.names[1:]) == list(model.joint_names)

    def pin_q(q):  # continuous joints: (cos, sin) per joint in Pinocchio's configuration
        return np.stack([np.cos(q), np.sin(q)], axis=-1).reshape(-1)

    pq = np.stack([pin_q(q) for q in qs])
    row["pin_aba_call_us"] = _least(lambda: [pin.aba(pm, pdata, pq[k], qds[k], taus[k]) for k in range(BATCH)]
                                    ) / BATCH * 1e6
    pool = pin.ModelPool(pm, 1)
    qT, qdT, tauT = (np.asfortranarray(a.T) for a in (pq, qds, taus))
    aT = np.zeros_like(qdT, order="F")
    row["pin_parallel_1thread_us"] = _least(lambda: pin.abaInParallel(1, pool, qT, qdT, tauT, aT)) / BATCH * 1e6
    ref = aT.T
    row["max_rel_err_batch_vs_pinocchio"] = float(np.max(np.abs(out - ref)) / np.max(np.abs(ref)))
    one = np.asarray(single(model, q1, qd1, tau1))
    row["max_rel_err_single_vs_pinocchio"] = float(np.max(np.abs(one - ref[0])) / np.max(np.abs(ref[0])))
    print(row, flush=True)
    return row


def _slope(rows, key):
    pts = [(r["n"], r[key]) for r in rows if r["n"] >= SLOPE_FROM]
    x, y = np.log([p[0] for p in pts]), np.log([p[1] for p in pts])
    return float(np.polyfit(x, y, 1)[0])


def _pin_to_one_core() -> list[int]:
    """Every thread of this process (and so every thread it starts later: XLA's pool included) on one core, so that
    ours and ``abaInParallel`` on 1 thread compare at equal cores (unpinned, XLA runs independent kernels of our
    batch on a second core: 50 / 100 / 200 links 14.9 / 24.2 / 58.2 us per state unpinned against 20.9 / 31.4 /
    76.8 pinned in a side test)."""
    core = min(os.sched_getaffinity(0))
    for tid in os.listdir("/proc/self/task"):
        os.sched_setaffinity(int(tid), {core})
    return sorted(os.sched_getaffinity(0))


def run() -> dict:
    cores = _pin_to_one_core()
    t0 = time.perf_counter()
    rows = [run_size(n) for n in SIZES]
    slopes = {k: _slope(rows, k) for k in ("single_call_us", "in_scan_us", "batch_per_state_us", "pin_aba_call_us",
                                           "pin_parallel_1thread_us", "compile_single_s")}
    return {"benchmark": NAME, "environment": environment(), "rows": rows, "slopes": slopes, "batch": BATCH,
            "wall_s": time.perf_counter() - t0, "cores": cores}


def write(results: dict) -> None:
    write_json(NAME, results)
    write_csv(NAME, results["rows"], list(results["rows"][0]))
    rows = results["rows"]
    ns = [r["n"] for r in rows]
    fig, (a1, a2) = pyplot().subplots(1, 2, figsize=(10, 4))
    for key, label in (("single_call_us", "ours, one jitted call"), ("in_scan_us", "ours, in a compiled scan"),
                       ("batch_per_state_us", f"ours, batch of {BATCH} (per state)"),
                       ("pin_aba_call_us", "Pinocchio aba (per call)"),
                       ("pin_parallel_1thread_us", "Pinocchio abaInParallel, 1 thread (per state)")):
        a1.loglog(ns, [r[key] for r in rows], "o-", label=label)
    a1.set_xlabel("links N")
    a1.set_ylabel("µs")
    a1.legend(fontsize=7)
    for key, label in (("compile_single_s", "one state"), ("compile_scan_s", "in a scan"),
                       ("compile_batch_s", "batch")):
        a2.plot(ns, [r[key] for r in rows], "o-", label=label)
    a2.set_xlabel("links N")
    a2.set_ylabel("compile [s]")
    a2.legend(fontsize=7)
    save_figure(fig, NAME, dpi=120, tight=True,
                title=f"Serial chains, forward dynamics, float64, {results['environment']['cpu']}")


def markdown(results: dict) -> str:
    env = results["environment"]
    s = results["slopes"]
    lines = [f"### Serial chains: forward dynamics against size (N = {SIZES[0]}..{SIZES[-1]})", "",
             f"{env['cpu']}, {env['cpu_count']} cores, {env['date']}; took {results['wall_s'] / 60:.1f} min. "
             f"Ours one state: articulated-body sweeps beyond {UNROLL_LINKS} links and for trees of mean link depth above "
             f"{ONE_STATE_SWEEPS_DEPTH:g} (chains of 16 links or more), composite inertias + Cholesky otherwise; "
             f"batch of {results['batch']} passed directly (articulated-body sweeps, batch innermost). "
             f"{'Process pinned to one core: ' if results.get('cores') and len(results['cores']) == 1 else ''}"
             "ours and abaInParallel at equal cores.", "",
             "| N | compile one / scan / batch | one call | in scan | batch, per state | Pinocchio aba | "
             "abaInParallel 1 thread | error vs Pinocchio |",
             "|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in results["rows"]:
        lines.append(f"| {r['n']} | {r['compile_single_s']:.1f} / {r['compile_scan_s']:.1f} / "
                     f"{r['compile_batch_s']:.1f} s | {r['single_call_us']:.0f} µs | {r['in_scan_us']:.1f} µs | "
                     f"{r['batch_per_state_us']:.1f} µs | {r['pin_aba_call_us']:.1f} µs | "
                     f"{r['pin_parallel_1thread_us']:.1f} µs | "
                     f"{max(r['max_rel_err_batch_vs_pinocchio'], r['max_rel_err_single_vs_pinocchio']):.1e} |")
    lines += ["", f"Log-log slopes over N = {SLOPE_FROM}..{SIZES[-1]} (goal ≤ 1.2 for ours): one call "
              f"{s['single_call_us']:.2f}, in scan {s['in_scan_us']:.2f}, batch per state "
              f"{s['batch_per_state_us']:.2f}; Pinocchio aba {s['pin_aba_call_us']:.2f}, abaInParallel "
              f"{s['pin_parallel_1thread_us']:.2f}.", ""]
    return "\n".join(lines)


def main() -> dict:
    return report(run, write, markdown)


if __name__ == "__main__":
    main()
