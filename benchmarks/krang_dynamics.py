"""Forward dynamics and rollouts of the 18-joint fixed-wheel Krang, float64, CPU: ours vs Pinocchio, MuJoCo, MJX.

Run: ``python -m benchmarks.krang_dynamics``. Writes ``benchmarks/results/krang_dynamics.{json,csv,png}``.

Rows (per state for batched rows, per step for fixed-step rollouts, per simulated second for ours):
  ours forward_dynamics, one jitted call; ours vmapped over 1024 states; Pinocchio ABA per call from Python and
  Pinocchio's batched C++ ``abaInParallel`` over the 1024 states on 1 and 2 threads; MJX ``forward`` vmapped over
  1024 states; MuJoCo C RK4 per step (dt 1e-4, ``mujoco.rollout``); MJX jitted RK4 rollout (scan) per
  step; our jitted diffrax rollout per simulated second (Tsit5 at the default tolerances, Dopri8 at tight ones).
Compile times are measured separately (``jit(...).lower(...).compile()``); run times are medians of repeats with
``block_until_ready`` on the results. Goals: batched ≤ 1.0× ABA per state, single call ≤ 3× ABA,
compile ≤ 5 s.
"""

from __future__ import annotations

import json
import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from particlesim import compiler_options
from particlesim.data import data_dir
from particlesim.tree import dynamics as tree_dynamics, forward_dynamics
from particlesim.io import load_urdf
from particlesim.twins.urdf import JointMap, mjx_model, mujoco_model, urdf_for_mujoco
from particlesim.simulate import simulate

from ._common import environment, median_time, pyplot, report, save_figure, timed, write_csv, write_json

NAME = "krang_dynamics"
URDF = "krang/urdf/krang_fixed_wheel_2018-04.urdf"
GRAVITY = (0.0, -9.81, 0.0)
BATCH = 1024
#: Small batches timed per call through the public function and through its batch entry made to take the sweeps,
#: each with its compile time (Krang has 18 links: up to 18 states, one per link, run state by state).
SMALL_BATCHES = (1, 8, 18, 32)
INTERLEAVED_LAPS = 15
DT = 1e-4


def _compile(fn, *args):
    t, compiled = timed(lambda: jax.jit(fn, compiler_options=compiler_options()).lower(*args).compile())
    return compiled, t


def _row(name, seconds, unit, compile_s=None, note=""):
    return {"name": name, "time_us": seconds * 1e6, "unit": unit, "compile_s": compile_s, "note": note}


_SYNC_SCRIPT = """
import json, statistics, time, sys
import jax
jax.config.update("jax_cpu_enable_async_dispatch", False)
import particlesim, numpy as np, jax.numpy as jnp
from particlesim.data import data_dir
from particlesim.io import load_urdf
from particlesim.tree import forward_dynamics
model = load_urdf(data_dir() / sys.argv[1], gravity=tuple(json.loads(sys.argv[2])), limits="ignore")
rng = np.random.default_rng(0)
q, qd, tau = (jnp.asarray(rng.uniform(-1.0, 1.0, model.nq)) for _ in range(3))
t0 = time.perf_counter()
call = jax.jit(forward_dynamics).lower(model, q, qd, tau).compile()
compile_s = time.perf_counter() - t0
floor = jax.jit(lambda q: q + 1.0).lower(q).compile()
floor_args = jax.jit(lambda m, q, qd, tau: q + 1.0).lower(model, q, qd, tau).compile()
def med(fn, n=200, laps=15):
    fn()
    out = []
    for _ in range(laps):
        t = time.perf_counter()
        for _ in range(n):
            fn().block_until_ready()
        out.append((time.perf_counter() - t) / n)
    return statistics.median(out)
forward_dynamics(model, q, qd, tau)  # the public entry's own compile
print(json.dumps({"call_s": med(lambda: call(model, q, qd, tau)), "floor_s": med(lambda: floor(q)),
                  "public_s": med(lambda: forward_dynamics(model, q, qd, tau)),
                  "floor_args_s": med(lambda: floor_args(model, q, qd, tau)), "compile_s": compile_s}))
"""


_ONE_CORE_SCRIPT = """
import json, os, sys, time
os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # this process, and every thread it starts, on one core
import numpy as np, jax, jax.numpy as jnp, mujoco, pinocchio as pin
import particlesim
from mujoco.batch import Batch
from particlesim.data import data_dir
from particlesim.io import load_urdf
from particlesim.tree import forward_dynamics
from particlesim.twins.urdf import JointMap, mujoco_model, urdf_for_mujoco
urdf, gravity, batch, laps = sys.argv[1], tuple(json.loads(sys.argv[2])), int(sys.argv[3]), int(sys.argv[4])
path = data_dir() / urdf
model = load_urdf(path, gravity=gravity)
rng = np.random.default_rng(0)
n = model.nq
qs, qds = rng.uniform(-np.pi, np.pi, (batch, n)), rng.normal(0.0, 1.0, (batch, n))
taus = rng.normal(0.0, 10.0, (batch, n))
jq, jqd, jtau = (jnp.asarray(x) for x in (qs, qds, taus))
pm = pin.buildModelFromXML(urdf_for_mujoco(path))
pm.gravity.linear = np.asarray(gravity)
pool = pin.ModelPool(pm, 1)
qT, qdT, tauT = (np.asfortranarray(a.T) for a in (qs, qds, taus))
aT = np.zeros_like(qdT, order="F")
m = mujoco_model(path, timestep=1e-4, integrator="rk4")
jm = JointMap(m, model.joint_names)
mb = Batch(m, nsim=batch, nthread=1)
mb.qpos, mb.qvel, mb.qfrc_applied = (np.asarray(jm.to_mujoco(x)) for x in (qs, qds, taus))
t0 = time.perf_counter()
ours = np.asarray(forward_dynamics(model, jq, jqd, jtau))
compile_s = time.perf_counter() - t0
pin.abaInParallel(1, pool, qT, qdT, tauT, aT)
err = float(np.max(np.abs(ours.T - aT)) / np.max(np.abs(aT)))
fns = {"ours": lambda: jax.block_until_ready(forward_dynamics(model, jq, jqd, jtau)),
       "pin": lambda: pin.abaInParallel(1, pool, qT, qdT, tauT, aT), "mujoco": mb.forward}
times = {k: [] for k in fns}
for _ in range(laps):
    for k, fn in fns.items():
        t = time.perf_counter()
        for _ in range(3):
            fn()
        times[k].append((time.perf_counter() - t) / 3 / batch)
print(json.dumps({"times": times, "compile_s": compile_s, "err_vs_abaInParallel": err,
                  "cores": sorted(os.sched_getaffinity(0))}))
"""


def _one_core_batch() -> dict:
    """The batched comparison at equal cores, one: a fresh process pinned to one core (XLA's thread pool, which
    otherwise runs independent kernels of our batch on both cores, included) runs ours, Pinocchio's
    ``abaInParallel`` on 1 thread and MuJoCo C's ``Batch.forward`` on 1 thread, interleaved lap by lap."""
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", _ONE_CORE_SCRIPT, URDF, json.dumps(list(GRAVITY)), str(BATCH),
                          str(INTERLEAVED_LAPS)], check=True, capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def _synchronous_single_calls() -> dict:
    """Median time of one jitted forward-dynamics call and of the dispatch floor with asynchronous CPU dispatch
    off, measured in a fresh process (``jax_cpu_enable_async_dispatch`` is read when the CPU client starts)."""
    import subprocess
    import sys

    out = subprocess.run([sys.executable, "-c", _SYNC_SCRIPT, URDF, json.dumps(list(GRAVITY))], check=True,
                         capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def run() -> dict:
    path = data_dir() / URDF
    model = load_urdf(path, gravity=GRAVITY)
    n = model.nq
    rng = np.random.default_rng(0)
    qs, qds = rng.uniform(-np.pi, np.pi, (BATCH, n)), rng.normal(0.0, 1.0, (BATCH, n))
    taus = rng.normal(0.0, 10.0, (BATCH, n))
    jq, jqd, jtau = (jnp.asarray(x) for x in (qs, qds, taus))
    rows = []

    # Ours: one call, then 1024 states in one vmapped call.
    q1, qd1, tau1 = jq[0], jqd[0], jtau[0]  # sliced once: an eager jq[0] per call costs more than the call
    single, c1 = _compile(forward_dynamics, model, q1, qd1, tau1)
    # Single calls are waited for one by one (a Python loop that uses each result).
    t = median_time(lambda: single(model, q1, qd1, tau1).block_until_ready(), number=200)
    rows.append(_row("ours forward_dynamics (1 call, jit, model as argument)", t, "per call", c1))
    # The same with the model closed over (a constant of the compiled function): no pytree flattening per call.
    closed, c1b = _compile(lambda q, qd, tau: forward_dynamics(model, q, qd, tau), jq[0], jqd[0], jtau[0])
    t = median_time(lambda: closed(q1, qd1, tau1).block_until_ready(), number=200)
    rows.append(_row("ours forward_dynamics (1 call, jit, model closed over)", t, "per call", c1b))
    # Compute cost without per-call dispatch: 1000 dependent evaluations inside one compiled scan.
    def chain(q, qd, tau):
        step = lambda q, _: (q + 1e-9 * forward_dynamics(model, q, qd, tau), None)  # noqa: E731
        return jax.lax.scan(step, q, None, length=1000)[0]

    chained, _ = _compile(chain, jq[0], jqd[0], jtau[0])
    t = median_time(lambda: chained(q1, qd1, tau1), number=1, block=jax.block_until_ready) / 1000
    rows.append(_row("ours forward_dynamics (in a compiled scan, no dispatch)", t, "per call"))
    floor, _ = _compile(lambda q: q + 1.0, jq[0])
    t = median_time(lambda: floor(q1).block_until_ready(), number=200)
    rows.append(_row("jit dispatch floor (q + 1, for reference)", t, "per call"))
    # What a user writes: the public function called directly (its compiled entry, no jit of ours around it), and
    # the floor of any jitted call with the same arguments (the model's leaves and static structure included).
    t0 = time.perf_counter()
    forward_dynamics(model, q1, qd1, tau1).block_until_ready()
    c_pub = time.perf_counter() - t0
    t = median_time(lambda: forward_dynamics(model, q1, qd1, tau1).block_until_ready(), number=200)
    rows.append(_row("ours forward_dynamics (public call as written, no jit around it)", t, "per call", c_pub))
    floor_args, _ = _compile(lambda m, q, qd, tau: q + 1.0, model, q1, qd1, tau1)
    t = median_time(lambda: floor_args(model, q1, qd1, tau1).block_until_ready(), number=200)
    rows.append(_row("jit dispatch floor (same arguments: model, q, qd, tau)", t, "per call"))
    # The same two single calls with JAX's asynchronous CPU dispatch off (a fresh process: the setting is read when
    # the CPU client starts). An execution above XLA's "cheap" threshold is otherwise handed to a worker thread.
    sync = _synchronous_single_calls()
    rows.append(_row("ours forward_dynamics (1 call, jit, synchronous CPU dispatch)", sync["call_s"], "per call",
                     sync["compile_s"], note="jax_cpu_enable_async_dispatch=False, fresh process"))
    rows.append(_row("jit dispatch floor (q + 1, synchronous CPU dispatch)", sync["floor_s"], "per call",
                     note="same process"))
    rows.append(_row("ours forward_dynamics (public call as written, synchronous CPU dispatch)", sync["public_s"],
                     "per call", note="same process"))
    rows.append(_row("jit dispatch floor (same arguments, synchronous CPU dispatch)", sync["floor_args_s"],
                     "per call", note="same process"))
    batched, c2 = _compile(jax.vmap(forward_dynamics, in_axes=(None, 0, 0, 0)), model, jq, jqd, jtau)
    t = median_time(lambda: batched(model, jq, jqd, jtau), number=5, block=jax.block_until_ready)
    rows.append(_row(f"ours forward_dynamics (vmap {BATCH}, one-state path vectorised)", t / BATCH, "per state", c2))
    # The batch passed directly to the public function (its own compiled entry, with the XLA options of
    # particlesim._xla.BATCH_OPTIONS): articulated-body sweeps with the batch innermost (particlesim.tree.aba).
    swept = forward_dynamics
    t0 = time.perf_counter()
    jax.block_until_ready(swept(model, jq, jqd, jtau))
    c2b = time.perf_counter() - t0
    t = median_time(lambda: swept(model, jq, jqd, jtau), number=5, block=jax.block_until_ready)
    rows.append(_row(f"ours forward_dynamics (batch of {BATCH}, articulated-body sweeps)", t / BATCH, "per state",
                     c2b))
    # Small batches (particlesim.tree.aba.state_by_state: at most one state per link runs state by state): the public
    # call per call, beside the same batch entry made to take the written-out sweeps (the same Python before dispatch
    # but forward_dynamics' own checks), each with its compile time (its first call, tracing included), interleaved.
    err_small = 0.0
    for size in SMALL_BATCHES:
        args = (model, jq[:size], jqd[:size], jtau[:size])
        c_pub, a = timed(lambda: np.asarray(forward_dynamics(*args)))
        c_sw, b = timed(lambda: np.asarray(tree_dynamics._batched(*args, None, False)))
        err_small = max(err_small, float(np.max(np.abs(a - b)) / np.max(np.abs(b))))
        pub, swp = [], []
        for _ in range(5):
            pub.append(median_time(lambda: jax.block_until_ready(forward_dynamics(*args)), number=20))
            swp.append(median_time(lambda: jax.block_until_ready(tree_dynamics._batched(*args, None, False)),
                                   number=20))
        rows.append(_row(f"ours forward_dynamics (batch of {size}, public call)", float(np.median(pub)), "per call",
                         c_pub))
        rows.append(_row(f"ours batch entry on the sweeps (batch of {size})", float(np.median(swp)), "per call",
                         c_sw))

    # Order: everything single-threaded first (ours, Pinocchio and MuJoCo C on one thread, their interleaved
    # comparison, our rollouts), then the two-thread runs and MJX, whose thread pools and large programs left
    # later measurements of this process slower than a fresh one's.
    # Ours: diffrax rollouts of 1 s (falling from a random pose, no input).
    q0, qd0 = jnp.asarray(0.5 * rng.uniform(-1, 1, n)), jnp.zeros(n)
    dyn = lambda p, q, qd, tau: forward_dynamics(p, q, qd, tau)  # noqa: E731
    for solver, rtol, atol in (("tsit5", 1e-8, 1e-10), ("dopri8", 1e-12, 1e-12)):
        def ours_roll(q0, qd0, solver=solver, rtol=rtol, atol=atol):
            s = simulate(dyn, model, q0, qd0, 0.0, 1.0, solver=solver, rtol=rtol, atol=atol)
            return s.q[-1], s.steps

        roll_o, c5 = _compile(ours_roll, q0, qd0)
        t = median_time(lambda: roll_o(q0, qd0), number=1, repeat=3, block=jax.block_until_ready)
        nsteps = int(roll_o(q0, qd0)[1])
        rows.append(_row(f"ours rollout {solver} rtol {rtol:g}", t, "per simulated s", c5, f"{nsteps} steps"))

    # Pinocchio ABA.
    import pinocchio as pin

    pm = pin.buildModelFromXML(urdf_for_mujoco(path))
    pm.gravity.linear = np.asarray(GRAVITY)
    pdata = pm.createData()
    assert list(pm.names[1:]) == list(model.joint_names)

    def aba_all():
        for k in range(BATCH):
            pin.aba(pm, pdata, qs[k], qds[k], taus[k])

    t_aba = median_time(aba_all, number=1) / BATCH
    rows.append(_row("Pinocchio ABA (C++, one call per state from Python)", t_aba, "per call"))
    # One state inside a compiled scan against pin.aba, interleaved lap by lap (the two rows above are measured
    # minutes apart, with other programs run between them, while the shared machine drifts by 10 % and more): per lap,
    # 1000 scan steps, then 1024 pin.aba. pin.aba's time includes its Python call (it costs more per state than
    # abaInParallel on one thread, which has none): the goal's measure, not the C++ ABA alone.
    scan_laps = []
    for _ in range(INTERLEAVED_LAPS):
        t0 = time.perf_counter()
        jax.block_until_ready(chained(q1, qd1, tau1))
        t_scan = (time.perf_counter() - t0) / 1000
        t0 = time.perf_counter()
        aba_all()
        scan_laps.append(t_scan / ((time.perf_counter() - t0) / BATCH))
    # Pinocchio's own batched C++ path: columns are states.
    pool = pin.ModelPool(pm, 2)
    qT, qdT, tauT = (np.asfortranarray(a.T) for a in (qs, qds, taus))
    aT = np.zeros_like(qdT, order="F")
    t = median_time(lambda: pin.abaInParallel(1, pool, qT, qdT, tauT, aT), number=3) / BATCH
    rows.append(_row(f"Pinocchio abaInParallel (C++, {BATCH} states, 1 thread)", t, "per state"))
    np.testing.assert_allclose(aT[:, 0], pin.aba(pm, pdata, qs[0], qds[0], taus[0]), rtol=1e-12, atol=1e-9)
    def rel_err(k):
        ref = pin.aba(pm, pdata, qs[k], qds[k], taus[k])
        return float(np.max(np.abs(ref - np.asarray(single(model, jq[k], jqd[k], jtau[k])))) / np.max(np.abs(ref)))

    err = max(rel_err(k) for k in range(16))
    batch_out = np.asarray(swept(model, jq, jqd, jtau))
    err_batch = max(float(np.max(np.abs(aT[:, k] - batch_out[k])) / np.max(np.abs(aT[:, k]))) for k in range(BATCH))

    # The MuJoCo twin (MuJoCo C's Batch and MJX), its joint map and the states in its order.
    from mujoco import mjx

    m = mujoco_model(path, timestep=DT, integrator="rk4")
    jm = JointMap(m, model.joint_names)
    mx = mjx_model(m)
    d0 = mjx.put_data(m, mujoco.MjData(m))
    mq, mqd, mtau = (jnp.asarray(jm.to_mujoco(x)) for x in (qs, qds, taus))

    # MuJoCo C's own batch (mujoco.batch.Batch.forward: mj_forward per simulation on a thread pool).
    from mujoco.batch import Batch

    def mujoco_batch(threads, row=True):
        """A Batch of the states on ``threads`` threads (and its Batch.forward row), and its qacc error."""
        batch = Batch(m, nsim=BATCH, nthread=threads)
        batch.qpos, batch.qvel, batch.qfrc_applied = (np.asarray(x) for x in (mq, mqd, mtau))
        bound = batch.bind("qacc")  # a derived field is refreshed by the calls after it is bound
        t = median_time(batch.forward, number=3)
        if row:
            rows.append(_row(f"MuJoCo C Batch.forward ({BATCH} states, {threads} thread{'s' * (threads > 1)})",
                             t / BATCH, "per state"))
        qacc = jm.from_mujoco(np.asarray(bound))
        return batch, max(float(np.max(np.abs(qacc[k] - aT[:, k])) / np.max(np.abs(aT[:, k]))) for k in range(BATCH))

    mj_batch1, err_mj = mujoco_batch(1)

    # Equal cores. One core: a fresh process pinned to one core (ours, abaInParallel 1 thread, Batch.forward 1
    # thread, interleaved). The rows above ran unpinned, where XLA spreads independent kernels of our batch over both
    # cores: they are relabelled and the one-core rows added.
    one = _one_core_batch()
    lap = {k: np.asarray(v) for k, v in one["times"].items()}
    for r in rows:
        if r["name"].startswith(f"ours forward_dynamics (batch of {BATCH}"):
            r["name"] = f"ours forward_dynamics (batch of {BATCH}, articulated-body sweeps, process unpinned)"
        if r["name"].endswith("1 thread)"):
            r["name"] = r["name"][:-1] + ", process unpinned)"
    note = f"fresh process pinned to core {one['cores']}, median of {INTERLEAVED_LAPS} interleaved laps"
    rows.append(_row(f"ours forward_dynamics (batch of {BATCH}, one core)", float(np.median(lap["ours"])),
                     "per state", one["compile_s"], note))
    rows.append(_row(f"Pinocchio abaInParallel (C++, {BATCH} states, 1 thread, one core)",
                     float(np.median(lap["pin"])), "per state", note=note))
    rows.append(_row(f"MuJoCo C Batch.forward ({BATCH} states, 1 thread, one core)", float(np.median(lap["mujoco"])),
                     "per state", note=note))

    # Two cores: ours unpinned against the two-thread runs, interleaved in this process.
    mj_batch2, err2 = mujoco_batch(2, row=False)
    err_mj = max(err_mj, err2)
    contenders = {
        "ours": lambda: jax.block_until_ready(swept(model, jq, jqd, jtau)),
        "pin": lambda: pin.abaInParallel(2, pool, qT, qdT, tauT, aT),
        "mujoco": mj_batch2.forward,
    }
    # Each lap: every contender once more untimed, then 3 timed calls, the order rotated from lap to lap. A call
    # right after another contender's two threads runs slow (abaInParallel's OpenMP threads keep spinning after a
    # call: ours right after it took 6.2-6.5 us per state against about 4 us otherwise), so no one's timed calls
    # start on another's threads, and each follows each other contender equally often.
    two = {k: [] for k in contenders}
    names = list(contenders)
    for lap_no in range(INTERLEAVED_LAPS):
        for name in names[lap_no % 3:] + names[:lap_no % 3]:
            fn = contenders[name]
            fn()
            t0 = time.perf_counter()
            for _ in range(3):
                fn()
            two[name].append((time.perf_counter() - t0) / 3 / BATCH)
    two = {k: np.asarray(v) for k, v in two.items()}
    note2 = f"this process, median of {INTERLEAVED_LAPS} interleaved laps, order rotated, one untimed call each"
    rows.append(_row(f"ours forward_dynamics (batch of {BATCH}, two cores)", float(np.median(two["ours"])),
                     "per state", note=note2))
    rows.append(_row(f"Pinocchio abaInParallel (C++, {BATCH} states, 2 threads)", float(np.median(two["pin"])),
                     "per state", note=note2))
    rows.append(_row(f"MuJoCo C Batch.forward ({BATCH} states, 2 threads)", float(np.median(two["mujoco"])),
                     "per state", note=note2))

    def quartiles(x):
        return [float(np.percentile(x, p)) for p in (25, 50, 75)]

    lap_ratios = {"one_core_vs_abaInParallel": quartiles(lap["ours"] / lap["pin"]),
                  "one_core_vs_Batch_forward": quartiles(lap["ours"] / lap["mujoco"]),
                  "two_cores_vs_abaInParallel": quartiles(two["ours"] / two["pin"]),
                  "two_cores_vs_Batch_forward": quartiles(two["ours"] / two["mujoco"])}
    err_one_core = one["err_vs_abaInParallel"]

    # MJX forward, vmapped.
    def mjx_fd(q, qd, tau):
        return mjx.forward(mx, d0.replace(qpos=q, qvel=qd, qfrc_applied=tau)).qacc

    mjx_b, c3 = _compile(jax.vmap(mjx_fd), mq, mqd, mtau)
    t = median_time(lambda: mjx_b(mq, mqd, mtau), number=2, block=jax.block_until_ready)
    rows.append(_row(f"MJX forward (vmap {BATCH})", t / BATCH, "per state", c3))

    # MuJoCo C, RK4 steps in its native loop.
    from ._native import Rollout, initial_state

    d = mujoco.MjData(m)
    d.qpos[:], d.qvel[:] = mq[0], mqd[0]
    _, t = Rollout(m, initial_state(m, d), 1000).timed(5)
    rows.append(_row(f"MuJoCo C RK4 step (dt {DT:g}, mujoco.rollout)", t / 1000, "per step"))

    # MJX jitted RK4 rollout (scan); one forward first (x64 field types settle).
    steps = 1000
    dstart = mjx.forward(mx, d0.replace(qpos=mq[0], qvel=mqd[0]))

    def mjx_roll(dd):
        return jax.lax.scan(lambda c, _: (mjx.step(mx, c), None), dd, None, length=steps)[0].qpos

    roll, c4 = _compile(mjx_roll, dstart)
    t = median_time(lambda: roll(dstart), number=1, repeat=3, block=jax.block_until_ready) / steps
    rows.append(_row("MJX RK4 rollout (jit scan)", t, "per step", c4))

    for r in rows:
        r["ratio_vs_aba"] = r["time_us"] / (t_aba * 1e6) if r["unit"] in ("per call", "per state") else None
    return {
        "benchmark": NAME,
        "model": f"{URDF} ({n} joints), float64",
        "n_links": model.n_joints,
        "environment": environment(),
        "rows": rows,
        "checks": {"max_rel_qdd_diff_ours_vs_pinocchio": err,
                   "max_rel_qdd_diff_ours_batch_vs_abaInParallel_all_states": err_batch,
                   "max_rel_qdd_diff_mujoco_batch_vs_abaInParallel_all_states": err_mj,
                   "max_rel_qdd_diff_small_batches_public_vs_sweeps": err_small},
        "batched_lap_ratios_quartiles": lap_ratios,
        "scan_vs_pin_aba_lap_ratios_quartiles": [float(np.percentile(scan_laps, p)) for p in (25, 50, 75)],
        "max_rel_qdd_diff_ours_one_core_vs_abaInParallel": err_one_core,
        "targets": {"batched_vs_abaInParallel": 1.0, "scan_vs_pin_aba": 1.5, "single_call_vs_floor": 1.5,
                    "compile_s": 5.0},
    }


def write(results: dict) -> None:
    write_json(NAME, results)
    write_csv(NAME, results["rows"], ["name", "time_us", "unit", "ratio_vs_aba", "compile_s", "note"])
    rows = results["rows"]
    fig, ax = pyplot().subplots(figsize=(9, 4.5))
    ax.barh([f"{r['name']}\n({r['unit']})" for r in rows], [r["time_us"] for r in rows], color="tab:blue")
    ax.set_xscale("log")
    ax.set_xlabel("time [µs] (log)")
    ax.invert_yaxis()
    ax.set_title(f"Krang fixed-wheel, float64, {results['environment']['cpu']}", fontsize=9)
    save_figure(fig, NAME, dpi=120, tight=True)


def markdown(results: dict) -> str:
    env = results["environment"]
    v = env["versions"]
    lines = [
        f"### Krang dynamics ({results['model']})",
        "",
        f"{env['cpu']}, {env['cpu_count']} cores, {env['date']}; jax {v['jax']}, mujoco {v['mujoco']}, "
        f"mjx {v['mujoco-mjx']}, pinocchio {v['pin']}, numpy {v['numpy']}.",
        "",
        "| what | time | unit | × Pinocchio ABA | compile |",
        "|---|---:|---|---:|---:|",
    ]
    for r in results["rows"]:
        ratio = "" if r["ratio_vs_aba"] is None else f"{r['ratio_vs_aba']:.2f}"
        comp = "" if r["compile_s"] is None else f"{r['compile_s']:.1f} s"
        t = f"{r['time_us']:.2f} µs" if r["time_us"] < 1e4 else f"{r['time_us'] / 1e3:.1f} ms"
        note = f" ({r['note']})" if r["note"] else ""
        lines.append(f"| {r['name']}{note} | {t} | {r['unit']} | {ratio} | {comp} |")
    by = {r["name"]: r["time_us"] for r in results["rows"]}
    chk = results["checks"]
    lr = results.get("batched_lap_ratios_quartiles", {})
    vm = next(v for k, v in by.items() if k.startswith("ours forward_dynamics (vmap"))
    mj = next(v for k, v in by.items() if k.startswith("MJX forward"))
    one_core = {k: v for k, v in by.items() if k.endswith("one core)")}
    if one_core and "one_core_vs_abaInParallel" in lr:
        ours1 = next(v for k, v in one_core.items() if k.startswith("ours"))
        pin1 = next(v for k, v in one_core.items() if "abaInParallel" in k)
        mj1 = next(v for k, v in one_core.items() if "Batch.forward" in k)
        ours2 = next(v for k, v in by.items() if k.startswith("ours") and k.endswith("two cores)"))
        pin2 = next(v for k, v in by.items() if "abaInParallel" in k and "2 threads" in k)
        mj2 = next(v for k, v in by.items() if "Batch.forward" in k and "2 threads" in k)
        a, b, c, d = (lr[k] for k in ("one_core_vs_abaInParallel", "one_core_vs_Batch_forward",
                                      "two_cores_vs_abaInParallel", "two_cores_vs_Batch_forward"))
        lines += ["", f"Batched forward dynamics per state at equal cores (goal ≤ 1.0× `abaInParallel`). One core (a "
                  f"fresh process pinned to one core): ours {ours1:.2f} µs, Pinocchio `abaInParallel` {pin1:.2f} µs, "
                  f"MuJoCo C `Batch.forward` {mj1:.2f} µs; per interleaved lap ours / `abaInParallel` median "
                  f"{a[1]:.2f} (quartiles {a[0]:.2f}–{a[2]:.2f}), ours / `Batch.forward` {b[1]:.2f} ({b[0]:.2f}–"
                  f"{b[2]:.2f}). Two cores: ours {ours2:.2f} µs, `abaInParallel` {pin2:.2f} µs, `Batch.forward` "
                  f"{mj2:.2f} µs; per lap {c[1]:.2f} ({c[0]:.2f}–{c[2]:.2f}) and {d[1]:.2f} ({d[0]:.2f}–{d[2]:.2f}). "
                  f"Unpinned, XLA runs independent kernels of our batch on both cores: the rows marked \"process "
                  f"unpinned\" are not one-thread figures. The vmapped one-state path {vm:.2f} µs; MJX {mj:.2f} µs. "
                  f"Max |q̈ ours − ABA| / max |q̈|: {chk['max_rel_qdd_diff_ours_vs_pinocchio']:.1e} over 16 single "
                  f"states, {chk.get('max_rel_qdd_diff_ours_batch_vs_abaInParallel_all_states', float('nan')):.1e} "
                  f"over the whole batch.", ""]
    else:  # results saved before the one-core rows existed
        swept = next(v for k, v in by.items() if "articulated-body sweeps" in k)
        par1 = next(v for k, v in by.items() if "abaInParallel" in k and "1 thread" in k)
        lines += ["", f"Batched forward dynamics per state: ours (batch passed directly) {swept:.2f} µs = "
                  f"{swept / par1:.2f}× Pinocchio `abaInParallel` on 1 thread ({par1:.2f} µs; goal ≤ 1.0×; ours ran "
                  f"unpinned, where XLA may use both cores); the vmapped one-state path {vm:.2f} µs; MJX {mj:.2f} µs.",
                  ""]
    one = by.get("ours forward_dynamics (1 call, jit, model as argument)")
    one_sync = by.get("ours forward_dynamics (1 call, jit, synchronous CPU dispatch)")
    if one is not None and one_sync is not None:
        scan = next(v for k, v in by.items() if "in a compiled scan" in k)
        floor = by["jit dispatch floor (q + 1, for reference)"]
        floor_sync = by["jit dispatch floor (q + 1, synchronous CPU dispatch)"]
        lines += [f"One state from Python: one jitted call {one:.0f} µs against a {floor:.1f} µs dispatch floor with "
                  f"JAX's default asynchronous CPU dispatch, {one_sync:.0f} µs against {floor_sync:.1f} µs with it off "
                  f"(`jax_cpu_enable_async_dispatch=False`; XLA hands a program above its 'cheap' threshold to a "
                  f"worker thread); {scan:.1f} µs inside a compiled scan."]
        sq = results.get("scan_vs_pin_aba_lap_ratios_quartiles")
        if sq is not None:
            lines[-1] += (f" Inside a compiled scan against `pin.aba` from Python, interleaved lap by lap "
                          f"({INTERLEAVED_LAPS} laps): median {sq[1]:.2f}× (quartiles {sq[0]:.2f}–{sq[2]:.2f}; goal "
                          "≤ 1.5×).")
        pub = by.get("ours forward_dynamics (public call as written, no jit around it)")
        fa = by.get("jit dispatch floor (same arguments: model, q, qd, tau)")
        pub_s = by.get("ours forward_dynamics (public call as written, synchronous CPU dispatch)")
        fa_s = by.get("jit dispatch floor (same arguments, synchronous CPU dispatch)")
        if None not in (pub, fa, pub_s, fa_s):
            lines[-1] += (f" The public function called as written (its own compiled entry) costs {pub:.0f} µs "
                          f"({pub_s:.0f} µs with synchronous dispatch) against {fa:.0f} µs ({fa_s:.0f} µs) for any "
                          f"jitted call with the same arguments: {pub / fa:.1f}× ({pub_s / fa_s:.1f}×) that floor "
                          "(goal ≤ 1.5×).")
        lines.append("")
    small = [(k, by.get(f"ours forward_dynamics (batch of {k}, public call)"),
              by.get(f"ours batch entry on the sweeps (batch of {k})")) for k in SMALL_BATCHES]
    small = [x for x in small if None not in x]
    if small:
        comp = {r["name"]: r.get("compile_s") for r in results["rows"]}

        def cs(name):
            c = comp.get(name)
            return "" if c is None else f" (compile {c:.1f} s)"

        lines += ["Small batches, per call (this process, unpinned, the two interleaved): "
                  + "; ".join(f"{k} states {a:.0f} µs through the public function"
                              f"{cs(f'ours forward_dynamics (batch of {k}, public call)')} against {b:.0f} µs for the "
                              f"batch entry on the sweeps{cs(f'ours batch entry on the sweeps (batch of {k})')}"
                              for k, a, b in small)
                  + f" (up to {results.get('n_links', 18)} states, one per link, run state by state; the "
                  "two agree to "
                  f"{chk.get('max_rel_qdd_diff_small_batches_public_vs_sweeps', float('nan')):.0e} relative).", ""]
    return "\n".join(lines)


def main() -> dict:
    return report(run, write, markdown, devices=True)


if __name__ == "__main__":
    main()
