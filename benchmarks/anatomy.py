"""Where the time of short programs goes on the CPU: sampled profiles of four workloads while they loop (Linux
``perf``, when the machine has it), and three timing decompositions without a profiler.

Workloads, each in a fresh process, warmed up (compiled, a few calls), then sampled for :data:`SAMPLE_S` seconds:

* ``chain``: the 4-link revolute chain's 2 s rollout at its headline setting (``wp_chains``: Dopri8, rtol 5e-5);
* ``krang batch, 1 thread`` / ``2 threads``: ``forward_dynamics`` on 1024 Krang states
  (``particlesim.tree.aba.BATCH_THREADS`` 1, and the default: one part per core);
* ``quarter cars``: 256 quarter-car rollouts one after another on one thread (``mechanism_engine``'s batch member:
  Tsit5 with the PI(0.2, 0.4) controller, rtol 4e-3).

Samples are grouped by where the sampled instruction lies: compiled kernels (XLA's generated code), YNNPACK kernels
(``ynn::``/``slinky::`` in jaxlib), BLAS/LAPACK (OpenBLAS, called by JAX's LAPACK kernels for Cholesky factors and
triangular solves), XLA's runtime (the rest of jaxlib: the thunk executor, its thread pool, buffers, dispatch), the
OS kernel (thread switches), libc (malloc/free, memset, memcpy) and Python; "cores busy" is samples / (rate x
seconds).

Decompositions (medians of laps; the first two interleave their variants' laps):

* ``chain``: run time against accepted + rejected steps (t1 from 1e-3 to 2 s), fitted as fixed + per step by least
  squares; the Python before dispatch alone (the compiled call replaced by a no-op).
* ``krang parts``: one part of 512 states alone, and two such parts run at once on two threads (as
  ``forward_dynamics`` splits 1024 states on two cores); efficiency = alone / together (1.0: the second core
  doubles the throughput), with the cores each keeps busy (the process's CPU time over wall time).
* ``quarter-car evaluation``: the quarter car's acceleration solve (39 coordinates, 36 constraint rows) as a
  rollout evaluates it (the mechanism and its prepared quantities passed in as arrays, not baked in), each variant
  in a compiled loop of :data:`QC_LOOP` calls, timed one after another: as it is; with the multipliers' solve
  replaced by a division by ``S``'s diagonal (an accounting variant, not valid dynamics: no factorisation and no
  triangular solves, and only ``S``'s diagonal is used); the projection between steps; and a 36 x 36
  symmetric positive-definite solve alone through JAX's LAPACK calls (``cho_factor`` + ``cho_solve``, and the
  factorisation alone; also 64 per call, per matrix). Beside them one batch member's accepted and rejected steps
  at the batch's setting, so that the evaluations per member can be counted, and the largest eigenvalues of the
  linearised field along the run (:data:`EIG_TIMES`), which bound an explicit solver's step.

Run: ``python -m benchmarks.anatomy``.
"""

from __future__ import annotations

import json
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time

import jax
import jax.numpy as jnp
import numpy as np

from ._common import RESULTS, environment, machine, pyplot, report, save_figure, write_json, write_table

NAME = "anatomy"
SAMPLE_S = 8.0
RATE_HZ = 999
LAPS = 15
START_TIMEOUT_S = 600.0
CHAIN_T1 = (1e-3, 0.05, 0.3, 1.0, 2.0)
CHAIN_SETTING = {"solver": "dopri8", "rtol": 5e-5, "atol": 5e-7}
KRANG_URDF = "krang/urdf/krang_fixed_wheel_2018-04.urdf"
QC_MEMBERS, QC_RTOL, QC_PID = 256, 4e-3, (0.2, 0.4, 0.0)  # mechanism_engine's batch setting
GROUPS = ("compiled kernels", "YNNPACK kernels", "BLAS/LAPACK", "XLA runtime", "OS kernel", "libc", "Python",
          "other")

_WORKLOAD = r"""
import sys, time
import particlesim
import jax, jax.numpy as jnp, numpy as np
which = sys.argv[1]
if which == "chain":
    from particlesim.mechanism import simulate_mechanism
    from particlesim.scenes.chains import chain_geometry, chain_mechanism
    mech, x0 = chain_mechanism(chain_geometry(4, "revolute", seed=4))
    solver, rtol, atol = sys.argv[6], float(sys.argv[7]), float(sys.argv[8])
    def call():
        s = simulate_mechanism(mech, x0, 0 * x0, 0.0, 2.0, solver=solver, rtol=rtol, atol=atol, max_steps=200_000)
        jax.block_until_ready(s.q)
elif which.startswith("krang"):
    import particlesim.tree.aba as aba
    from particlesim.data import data_dir
    from particlesim.io import load_urdf
    from particlesim.tree import forward_dynamics
    model = load_urdf(data_dir() / sys.argv[2], gravity=(0.0, -9.81, 0.0), limits="ignore")
    aba.BATCH_THREADS = 1 if which == "krang1" else None
    rng = np.random.default_rng(0)
    q, qd, tau = (jnp.asarray(rng.uniform(-1, 1, (1024, model.nv))) for _ in range(3))
    def call():
        jax.block_until_ready(forward_dynamics(model, q, qd, tau))
else:
    sys.path.insert(0, sys.argv[3])
    from particlesim.batch import sharded_vmap
    from benchmarks.mechanism_engine import _batch_member, qc
    mech, x0 = qc.quarter_car()
    member = _batch_member(mech, jnp.asarray(x0))
    th = jnp.asarray(np.random.default_rng(0).uniform(0.8, 1.2, size=(int(sys.argv[4]), 9)))
    fn = sharded_vmap(lambda t: member(t, float(sys.argv[5]), "tsit5", (0.2, 0.4, 0.0)), chunk=1, threads=1)
    def call():
        jax.block_until_ready(fn(th))
for _ in range(3):
    call()
print("READY", flush=True)
while True:
    call()
"""

WORKLOADS = {"chain": "the 4-link chain's 2 s rollout (Dopri8, rtol 5e-5)",
             "krang1": "Krang forward dynamics, 1024 states, one program",
             "krang2": "Krang forward dynamics, 1024 states, two parts on two threads",
             "quarter": f"{QC_MEMBERS} quarter-car rollouts one after another, 1 thread (Tsit5 PI(0.2, 0.4), "
                        f"rtol {QC_RTOL:g})"}


def _group(dso: str, sym: str) -> str:
    if dso.startswith("[JIT]"):
        return "compiled kernels"
    if "libjax_common" in dso:
        return "YNNPACK kernels" if sym.startswith(("ynn::", "slinky::", "ynn_")) else "XLA runtime"
    if "openblas" in dso or "_lapack" in dso or "cython_blas" in dso or "cython_lapack" in dso:
        return "BLAS/LAPACK"
    if dso.startswith("[kernel"):
        return "OS kernel"
    if dso.startswith("libc.") or dso.startswith("libc-"):
        return "libc"
    if "libpython" in dso or dso.startswith("python"):
        return "Python"
    return "other"


def _profile(which: str, perf: str) -> dict:
    """Sample one workload's process while it loops; returns the groups' shares and the cores it kept busy."""
    args = [sys.executable, "-c", _WORKLOAD, which, KRANG_URDF, str(RESULTS.parent.parent), str(QC_MEMBERS),
            str(QC_RTOL), CHAIN_SETTING["solver"], str(CHAIN_SETTING["rtol"]), str(CHAIN_SETTING["atol"])]
    proc = subprocess.Popen(args, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    try:
        ready = []
        reader = threading.Thread(target=lambda: ready.append(proc.stdout.readline()), daemon=True)
        reader.start()
        reader.join(START_TIMEOUT_S)
        if not ready or not ready[0].startswith("READY"):
            raise RuntimeError(f"anatomy: workload {which} did not start within {START_TIMEOUT_S:g} s "
                               f"({ready[0] if ready else 'no output'!r})")
        with tempfile.TemporaryDirectory() as tmp:
            data = os.path.join(tmp, "perf.data")
            subprocess.run([perf, "record", "-F", str(RATE_HZ), "-p", str(proc.pid), "-o", data, "--", "sleep",
                            str(SAMPLE_S)], check=True, capture_output=True)
            report = subprocess.run([perf, "report", "-i", data, "--stdio", "--no-children", "-n", "-g", "none",
                                     "--sort", "dso,sym", "--field-separator=;"], check=True, capture_output=True,
                                    text=True).stdout
    finally:
        proc.kill()
        proc.wait()
    groups = dict.fromkeys(GROUPS, 0)
    top = []
    total = 0
    for row in report.splitlines():
        if not row.strip() or row.lstrip().startswith("#"):
            continue
        parts = row.split(";")
        if len(parts) < 4:
            continue
        try:
            n = int(parts[1])
        except ValueError:
            continue
        dso, sym = parts[2].strip(), parts[3].strip()
        sym = sym[4:] if sym[:1] == "[" and sym[2:4] == "] " else sym
        groups[_group(dso, sym)] += n
        total += n
        top.append((n, dso, sym))
    if not total:
        raise RuntimeError(f"anatomy: perf recorded no samples of workload {which}")
    top.sort(reverse=True)
    return {"samples": total, "cores_busy": total / (RATE_HZ * SAMPLE_S),
            "share": {g: groups[g] / total for g in GROUPS},
            "top": [{"share": n / total, "dso": d, "symbol": s[:90]} for n, d, s in top[:12]]}


#: Variants of the chain's run whose fixed cost is compared with the headline setting's (two-point fits: t1 = 1e-3
#: and 2 s): another solver, no projection, the initial step given (no initial step selection).
CHAIN_VARIANTS = {"tsit5": {"solver": "tsit5"}, "no projection": {"stabilise": False}, "dt0 given": {"dt0": 1e-3}}


def _chain_decomposition() -> dict:
    import particlesim._xla as xla
    from particlesim.mechanism import simulate_mechanism
    from particlesim.scenes.chains import chain_geometry, chain_mechanism

    mech, x0 = chain_mechanism(chain_geometry(4, "revolute", seed=4))
    xd0 = jnp.zeros_like(x0)

    def run(t1, **change):
        s = simulate_mechanism(mech, x0, xd0, 0.0, t1, max_steps=200_000, **{**CHAIN_SETTING, **change})
        jax.block_until_ready(s.q)
        return s

    def count(s):
        return int(s.steps) + int(s.rejected)

    steps = [count(run(t1)) for t1 in CHAIN_T1]
    variant_steps = {k: [count(run(t1, **v)) for t1 in (CHAIN_T1[0], CHAIN_T1[-1])] for k, v in CHAIN_VARIANTS.items()}
    real_call = xla.TopJit.__call__

    def python_only():  # everything up to JAX's dispatch of the compiled rollout (its jit call made a no-op)
        xla.TopJit.__call__ = lambda self, *a, **k: None
        try:
            simulate_mechanism(mech, x0, xd0, 0.0, 2.0, max_steps=200_000, **CHAIN_SETTING)
        finally:
            xla.TopJit.__call__ = real_call

    def timed(fn):
        t = time.perf_counter()
        fn()
        return time.perf_counter() - t

    times = {t1: [] for t1 in CHAIN_T1}
    vtimes = {(k, t1): [] for k in CHAIN_VARIANTS for t1 in (CHAIN_T1[0], CHAIN_T1[-1])}
    pre = []
    for _ in range(LAPS):
        for t1 in CHAIN_T1:
            times[t1] += [timed(lambda: run(t1)) for _ in range(3)]
        for (k, t1), ts in vtimes.items():
            ts += [timed(lambda: run(t1, **CHAIN_VARIANTS[k])) for _ in range(3)]
        pre += [timed(python_only) for _ in range(3)]
    med = [statistics.median(times[t1]) for t1 in CHAIN_T1]
    fixed, per_step = np.linalg.lstsq(np.vstack([np.ones(len(steps)), steps]).T, np.asarray(med), rcond=None)[0]
    variants = {}
    for k, (n1, n2) in variant_steps.items():
        a, b = (statistics.median(vtimes[(k, t1)]) for t1 in (CHAIN_T1[0], CHAIN_T1[-1]))
        per = (b - a) / (n2 - n1)
        variants[k] = {"steps": [n1, n2], "median_s": [a, b], "fixed_s": a - n1 * per, "per_step_s": per}
    two_point = (med[-1] - med[0]) / (steps[-1] - steps[0])
    return {"t1_s": list(CHAIN_T1), "steps": steps, "median_s": med, "fixed_s": float(fixed),
            "per_step_s": float(per_step), "two_point_fixed_s": med[0] - steps[0] * two_point,
            "variants": variants, "python_before_dispatch_s": statistics.median(pre),
            "constraints": mech.n_constraints, "coords": mech.n_coords}


#: Calls per compiled loop in the quarter-car evaluation decomposition.
QC_LOOP = 2000
#: Times [s] at which the quarter car's linearised field is decomposed (its stiffest modes set the step).
EIG_TIMES = (0.0, 0.2, 1.0)


def _timed_loop(fn, *args, consts=None, calls: int = QC_LOOP) -> float:
    """Median seconds per call of ``fn(consts, *args)`` (``fn(*args)`` without ``consts``) in a compiled
    ``fori_loop`` (each call's array inputs nudged by the last output, so that nothing is hoisted; ``consts``, a
    pytree such as a mechanism, passed to the program as arguments, as a rollout passes them), over LAPS laps."""
    import equinox as eqx

    @eqx.filter_jit
    def loop(c, *a):
        def body(i, carry):
            nudged = [x + 1e-300 * carry for x in a]
            out = fn(*nudged) if c is None else fn(c, *nudged)
            return jnp.ravel(out)[0] * 0.0

        return jax.lax.fori_loop(0, calls, body, jnp.zeros((), a[0].dtype))

    jax.block_until_ready(loop(consts, *args))
    laps = []
    for _ in range(LAPS):
        t = time.perf_counter()
        jax.block_until_ready(loop(consts, *args))
        laps.append((time.perf_counter() - t) / calls)
    return statistics.median(laps)


def _quarter_car_evaluation() -> dict:
    from jax.scipy.linalg import cho_factor, cho_solve

    from particlesim.mechanism import dynamics, simulate_mechanism
    from particlesim.mechanism._algebra import BETWEEN_STEPS, prepare, rows, schur
    from particlesim.mechanism.integrate import project_prepared
    from particlesim.scenes import quarter_car as qc

    mech, x0 = qc.quarter_car()
    x0 = jnp.asarray(x0)
    prep = prepare(mech)
    xd0 = jnp.asarray(np.random.default_rng(0).normal(size=x0.shape)) * 1e-2
    out = {"coords": mech.n_coords, "constraints": mech.n_constraints}
    consts = (mech, prep)

    def evaluation(c, q, qd):
        return dynamics._solve(c[0], c[1], 0.0, q, qd, 0.0)[0]

    out["evaluation_s"] = _timed_loop(evaluation, x0, xd0, consts=consts)
    real = dynamics.schur_solve
    dynamics.schur_solve = lambda p, r, s_, rhs: rhs / jnp.diag(s_)  # traced once, below, then put back
    try:
        out["evaluation_without_solve_s"] = _timed_loop(evaluation, x0, xd0, consts=consts)
    finally:
        dynamics.schur_solve = real
    out["projection_s"] = _timed_loop(lambda c, q, qd: project_prepared(c[0], c[1], q, qd, 0.0, BETWEEN_STEPS)[0],
                                      x0, xd0, consts=consts)
    s_mat = schur(prep, rows(prep, x0))
    rhs = jnp.asarray(np.random.default_rng(1).normal(size=s_mat.shape[0]))
    out["spd_solve_s"] = _timed_loop(lambda s_, b: cho_solve(cho_factor(s_), b), s_mat, rhs)
    out["factorisation_s"] = _timed_loop(lambda s_: cho_factor(s_)[0], s_mat)
    batch = 64
    sb, bb = jnp.broadcast_to(s_mat, (batch,) + s_mat.shape) + 0.0, jnp.broadcast_to(rhs, (batch,) + rhs.shape) + 0.0
    out["spd_solve_batched_s"] = _timed_loop(
        jax.vmap(lambda s_, b: cho_solve(cho_factor(s_), b)), sb, bb, calls=QC_LOOP // batch) / batch
    out["factorisation_batched_s"] = _timed_loop(
        jax.vmap(lambda s_: cho_factor(s_)[0]), sb, calls=QC_LOOP // batch) / batch
    member = simulate_mechanism(mech, x0, jnp.zeros_like(x0), 0.0, 1.0, solver="tsit5", rtol=QC_RTOL,
                                atol=QC_RTOL * 1e-2, pid=QC_PID)
    out["member_steps"] = [int(member.steps), int(member.rejected)]
    # What sets the step count: the largest eigenvalues of the linearised first-order field (q, qd) along the
    # unperturbed run (the constraint directions add zeros), at the start, mid-settle and the end.
    ref = simulate_mechanism(mech, x0, jnp.zeros_like(x0), 0.0, 1.0, solver="dopri8", rtol=1e-10, atol=1e-12,
                             saveat_ts=EIG_TIMES)
    n = x0.shape[0]

    def field(y):
        return jnp.concatenate([y[n:], dynamics.accelerations(mech, 0.0, y[:n], y[n:])])

    out["eigenvalues"] = {}
    for t, q, qd in zip(EIG_TIMES, ref.q, ref.qd):
        ev = np.linalg.eigvals(np.asarray(jax.jacfwd(field)(jnp.concatenate([q, qd]))))
        ev = ev[np.argsort(-np.abs(ev))][:3]
        out["eigenvalues"][f"{t:g}"] = [[float(v.real), float(v.imag)] for v in ev]
    return out


_PINNED_PART = r"""
import json, os, statistics, sys, time
os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})
import particlesim
import jax, jax.numpy as jnp, numpy as np
from particlesim.data import data_dir
from particlesim.io import load_urdf
from particlesim.tree import dynamics
model = load_urdf(data_dir() / sys.argv[1], gravity=(0.0, -9.81, 0.0), limits="ignore")
rng = np.random.default_rng(0)
q, qd, tau = (jnp.asarray(rng.uniform(-1, 1, (1024, model.nv))) for _ in range(3))
s0 = jnp.asarray(0, jnp.int32)
def part():
    return jax.block_until_ready(dynamics._batched_part(model, q, qd, tau, s0, False, 512))
part(); part()
laps = []
for _ in range(int(sys.argv[2])):
    t = time.perf_counter()
    for _ in range(3):
        part()
    laps.append((time.perf_counter() - t) / 3)
print(json.dumps({"alone_s": statistics.median(laps), "cores": sorted(os.sched_getaffinity(0))}))
"""


def _pinned_part() -> dict | None:
    """One part of 512 Krang states timed in a fresh process held to one core (XLA's pool threads included)."""
    if not hasattr(os, "sched_setaffinity"):
        return None
    out = subprocess.run([sys.executable, "-c", _PINNED_PART, KRANG_URDF, str(LAPS)], check=True,
                         capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def _krang_parts() -> dict:
    import resource

    from particlesim._threads import run_parts
    from particlesim.data import data_dir
    from particlesim.io import load_urdf
    from particlesim.tree import dynamics

    model = load_urdf(data_dir() / KRANG_URDF, gravity=(0.0, -9.81, 0.0), limits="ignore")
    rng = np.random.default_rng(0)
    q, qd, tau = (jnp.asarray(rng.uniform(-1, 1, (1024, model.nv))) for _ in range(3))
    starts = [jnp.asarray(0, jnp.int32), jnp.asarray(512, jnp.int32)]

    def part(s):
        return jax.block_until_ready(dynamics._batched_part(model, q, qd, tau, s, False, 512))

    runs = {"alone": lambda: part(starts[0]), "together": lambda: run_parts(part, [(s,) for s in starts])}
    for fn in runs.values():
        fn()
        fn()
    laps = {k: [] for k in runs}
    busy = {k: [] for k in runs}
    names = list(runs)
    for lap in range(LAPS):
        for name in names[lap % 2:] + names[:lap % 2]:
            r0, t = resource.getrusage(resource.RUSAGE_SELF), time.perf_counter()
            for _ in range(3):
                runs[name]()
            wall, r1 = time.perf_counter() - t, resource.getrusage(resource.RUSAGE_SELF)
            laps[name].append(wall / 3)
            busy[name].append((r1.ru_utime - r0.ru_utime + r1.ru_stime - r0.ru_stime) / wall)
    alone, together = statistics.median(laps["alone"]), statistics.median(laps["together"])
    return {"alone_s": alone, "together_s": together, "efficiency": alone / together,
            "cores_busy_alone": statistics.median(busy["alone"]),
            "cores_busy_together": statistics.median(busy["together"]),
            "efficiency_quartiles": [float(x) for x in np.percentile(
                np.asarray(laps["alone"]) / np.asarray(laps["together"]), [25, 75])]}


def run() -> dict:
    t0 = time.perf_counter()
    perf = shutil.which("perf")
    profiles, why = {}, None
    if perf is None:
        why = "no `perf` on this machine"
    else:
        try:
            for which in WORKLOADS:
                print("profiling", which, flush=True)
                profiles[which] = _profile(which, perf)
        except (subprocess.CalledProcessError, RuntimeError, OSError) as e:
            profiles, why = {}, f"perf failed: {e}"
    print("chain decomposition", flush=True)
    chain = _chain_decomposition()
    print("krang parts", flush=True)
    pinned = [_pinned_part()]  # before and after the unpinned laps: the machine drifts between processes
    parts = _krang_parts()
    pinned.append(_pinned_part())
    if pinned[0] is not None:
        parts["pinned_alone_s"] = [p["alone_s"] for p in pinned]
    print("quarter-car evaluation", flush=True)
    evaluation = _quarter_car_evaluation()
    return {"benchmark": NAME, "environment": environment(), "workloads": WORKLOADS, "profiles": profiles,
            "profiles_missing": why, "sample_s": SAMPLE_S, "rate_hz": RATE_HZ, "chain": chain, "krang_parts": parts,
            "quarter_car_evaluation": evaluation, "wall_s": time.perf_counter() - t0}


def write(results: dict) -> None:
    write_json(NAME, results)
    write_table(NAME, ["workload", "group", "share", "cores_busy"],
                ([which, g, s, p["cores_busy"]] for which, p in results["profiles"].items()
                 for g, s in p["share"].items()))
    fig, (a1, a2) = pyplot().subplots(1, 2, figsize=(12, 3.8), gridspec_kw={"width_ratios": [3, 2]})
    names = list(results["profiles"])
    left = np.zeros(len(names))
    for g in GROUPS:
        vals = np.asarray([results["profiles"][n]["share"][g] * 100 for n in names])
        a1.barh(names, vals, left=left, label=g)
        left += vals
    a1.set_xlabel("% of samples")
    a1.legend(fontsize=7, ncol=4, loc="upper center", bbox_to_anchor=(0.5, -0.22))
    a1.set_title(f"perf samples by where they fall ({results['environment']['cpu']})", fontsize=9)
    c = results["chain"]
    a2.plot(c["steps"], np.asarray(c["median_s"]) * 1e3, "o", label="4-link chain, median run")
    xs = np.asarray([0, max(c["steps"])])
    a2.plot(xs, (c["fixed_s"] + c["per_step_s"] * xs) * 1e3, "-",
            label=f"fit: {c['fixed_s'] * 1e6:.0f} µs + {c['per_step_s'] * 1e6:.0f} µs/step")
    a2.axhline(c["python_before_dispatch_s"] * 1e3, ls=":", color="k", label="Python up to the jit call")
    a2.set_xlabel("steps (accepted + rejected)")
    a2.set_ylabel("ms")
    a2.legend(fontsize=7)
    save_figure(fig, NAME, dpi=120, tight=True)


def markdown(results: dict) -> str:
    env = results["environment"]
    lines = ["### Where the time goes: profiles of short programs", "",
             f"{machine(env)}; jax {env['versions'].get('jax')}; took {results['wall_s'] / 60:.1f} min."]
    if results["profiles"]:
        lines += [f"`perf` samples at {results['rate_hz']} Hz over {results['sample_s']:g} s of each workload looping "
                  "(a fresh process each, compiled and warmed first); shares of all samples, and the cores kept busy "
                  "(thread pools spinning for work count as busy: XLA's runtime column).",
                  "", "| workload | cores busy | " + " | ".join(GROUPS) + " |",
                  "|---|---:|" + "---:|" * len(GROUPS)]
        for which, p in results["profiles"].items():
            lines.append(f"| {results['workloads'][which]} | {p['cores_busy']:.2f} | "
                         + " | ".join(f"{100 * p['share'][g]:.0f} %" for g in GROUPS) + " |")
    else:
        lines += ["", f"No profiles: {results['profiles_missing']}."]
    c, k = results["chain"], results["krang_parts"]
    us = 1e6
    variants = "; ".join(f"{name} {v['fixed_s'] * us:.0f} µs fixed + {v['per_step_s'] * us:.0f} µs per step"
                         for name, v in c.get("variants", {}).items())
    lines += ["", f"4-link chain ({c.get('coords', 24)} coordinates, {c.get('constraints', 20)} constraint rows), run "
              f"time against steps (t1 = {', '.join(f'{t:g}' for t in c['t1_s'])} s: "
              f"{', '.join(str(s) for s in c['steps'])} steps; medians "
              f"{', '.join(f'{m * us:.0f}' for m in c['median_s'])} µs): **{c['fixed_s'] * us:.0f} µs fixed + "
              f"{c['per_step_s'] * us:.0f} µs per Dopri8 step** (least squares; "
              f"{c.get('two_point_fixed_s', c['fixed_s']) * us:.0f} µs fixed from the first and last alone), of the "
              f"fixed part {c['python_before_dispatch_s'] * us:.0f} µs of Python up to the compiled rollout's jit "
              "call."
              + (f" Two-point fits of variants, same laps: {variants}." if variants else ""), "",
              f"Krang's batch in parts: one part of 512 states alone {k['alone_s'] * 1e3:.2f} ms keeping "
              f"{k['cores_busy_alone']:.2f} cores busy"
              + (f" (in a fresh process held to one core: {' and '.join(f'{t * 1e3:.2f}' for t in k['pinned_alone_s'])}"
                 " ms, before and after)" if k.get("pinned_alone_s") else "")
              + f"; two parts at once on two threads {k['together_s'] * 1e3:.2f} ms "
              f"({k['cores_busy_together']:.2f} cores): **efficiency {k['efficiency']:.2f}** (lap quartiles "
              f"{k['efficiency_quartiles'][0]:.2f}–{k['efficiency_quartiles'][1]:.2f}; 1.0 would double the "
              "throughput).", ""]
    e = results.get("quarter_car_evaluation")
    if e:
        steps = sum(e["member_steps"])
        lines += [f"Quarter car ({e['coords']} coordinates, {e['constraints']} constraint rows), medians per call in "
                  f"compiled loops of {QC_LOOP}: the acceleration solve **{e['evaluation_s'] * us:.1f} µs**, "
                  f"{e['evaluation_without_solve_s'] * us:.1f} µs with the multipliers' solve replaced by a division "
                  f"by S's diagonal (no factorisation, no triangular solves, only S's diagonal used); the "
                  f"projection between steps {e['projection_s'] * us:.1f} µs; a {e['constraints']} x "
                  f"{e['constraints']} positive-definite solve alone through JAX's LAPACK calls "
                  f"{e['spd_solve_s'] * us:.2f} µs, its factorisation {e['factorisation_s'] * us:.2f} µs (64 per call: "
                  f"{e['spd_solve_batched_s'] * us:.2f} and {e['factorisation_batched_s'] * us:.2f} µs per matrix). "
                  f"One batch member (Tsit5 PI(0.2, 0.4), rtol {QC_RTOL:g}, 1 s) takes {e['member_steps'][0]} "
                  f"accepted and {e['member_steps'][1]} rejected steps: {6 * steps + 3} evaluations (six a step "
                  f"attempt, the first stage reused from the last, and three before the first step: the initial step "
                  f"selection's two and the first stage's) and {steps} "
                  "projections."
                  + (" The stiffest modes of the linearised field (1/s), which bound an explicit solver's step: "
                     + "; ".join(f"t = {t} s: " + ", ".join(_complex(v) for v in [v for v in evs if v[1] >= 0][:2])
                                 for t, evs in e["eigenvalues"].items()) + "." if e.get("eigenvalues") else ""),
                  ""]
    return "\n".join(lines)


def _complex(v) -> str:
    re_, im = v
    return f"{re_:.0f}" if abs(im) < 0.5 else f"{re_:.0f} ± {abs(im):.0f}i"


def main() -> dict:
    return report(run, write, markdown)


if __name__ == "__main__":
    main()
