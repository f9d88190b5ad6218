"""Batches split over threads, called again and again under a watchdog: they must return, equal to the unsplit batch.

Two programs running side by side share XLA's intra-op pool; jaxlib's LAPACK kernels spread a large batch of matrices
over that pool and block the thread they run on until it is done, so two parts each in such a kernel wait on each
other forever (particlesim._threads). Each case below hung within its first calls before the batch programs kept
their factorisations on their own thread and the split checked its part program:

* floating base: ``forward_dynamics`` on 1024 Solo-12 states (example-robot-data), the documented batch call;
* mimic joints: the same on a random 20-link tree with two mimic joints (18 coordinates);
* mechanism rollouts one member at a time (``sharded_vmap(chunk=1)``): the full vehicle's two end projections;
* mechanism rollouts vectorised (``sharded_vmap`` with no chunk): each member's factorisation batched over the part,
  which the split now detects and runs as one program.

Everything runs in a child process with a time limit, so a hang fails this test instead of CI; the child also bounds
its own waits (``particlesim._threads.STALL_SECONDS``) and dumps its threads' stacks before the limit.
"""

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

CALLS = 20  # calls per case and thread count
THREADS = (1, 2, 4)
SAME_RTOL = 1e-12  # a split batch against the unsplit one (the same per-state or per-member operations)
WATCHDOG_SECONDS = 420  # the child's whole run; it takes ~60-90 s
STALL_SECONDS = 30  # the child's own bound on a stalled batch

SCRIPT = textwrap.dedent("""
    import faulthandler, json, sys, time, warnings
    faulthandler.dump_traceback_later(%(dump)d, exit=True)
    import jax, jax.numpy as jnp, numpy as np
    import particlesim
    from particlesim import _threads
    from particlesim.batch import sharded_vmap
    from particlesim.io import load_urdf
    from particlesim.mechanism import simulate_mechanism
    from particlesim.tree import aba, forward_dynamics
    sys.path[:0] = [%(tests)r, %(tests)r + "/tree"]
    from tree_helpers import random_tree_urdf
    from test_mimic import with_mimics

    _threads.STALL_SECONDS = %(stall)d
    CALLS, THREADS = %(calls)d, %(threads)r
    out = {}

    def rel(a, b):
        a, b = np.asarray(a), np.asarray(b)
        return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300))

    def tree_case(name, model, free):
        rng = np.random.default_rng(0)
        b = 1024
        q = rng.uniform(-3, 3, (b, model.nq))
        if free:
            quat = rng.normal(size=(b, 4))
            q[:, :3] = rng.uniform(-1, 1, (b, 3))
            q[:, 3:7] = quat / np.linalg.norm(quat, axis=1, keepdims=True)
        qd = rng.uniform(-2, 2, (b, model.nv))
        tau = rng.uniform(-5, 5, (b, model.nv))
        if free:
            tau[:, :6] = 0.0
        q, qd, tau = map(jnp.asarray, (q, qd, tau))
        aba.BATCH_THREADS = 1
        whole = forward_dynamics(model, q, qd, tau)
        worst, t0 = 0.0, time.perf_counter()
        for threads in THREADS:
            aba.BATCH_THREADS = threads
            for _ in range(CALLS):
                worst = max(worst, rel(jax.block_until_ready(forward_dynamics(model, q, qd, tau)), whole))
        out[name] = {"calls": CALLS * len(THREADS), "rel": worst, "seconds": time.perf_counter() - t0}
        aba.BATCH_THREADS = None
        print(name, out[name], flush=True)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        solo = load_urdf(%(solo)r, floating_base=True, limits="ignore")
    tree_case("floating base (Solo-12)", solo, True)
    mimic_urdf = with_mimics(random_tree_urdf(5, n=20, prismatic=0.3), {"j7": ("j3", -0.7, 0.2),
                                                                          "j12": ("j9", 1.3, 0.0)})
    tree_case("mimic (20 links, 18 coordinates)", load_urdf(mimic_urdf, limits="ignore"), False)

    def mechanism_case(name, mech, q0, spring, k0, t1, members, chunk):
        def rollout(k):
            m = mech.with_params(spring={spring: {"stiffness": k}})
            return simulate_mechanism(m, q0, 0 * q0, 0.0, t1).q[-1]

        ks = jnp.linspace(0.8, 1.2, members) * k0
        whole = sharded_vmap(rollout, chunk=chunk, threads=1)(ks)
        worst, t0 = 0.0, time.perf_counter()
        for threads in THREADS:
            f = sharded_vmap(rollout, chunk=chunk, threads=threads)
            for _ in range(CALLS):
                worst = max(worst, rel(jax.block_until_ready(f(ks)), whole))
        out[name] = {"calls": CALLS * len(THREADS), "rel": worst, "seconds": time.perf_counter() - t0}
        print(name, out[name], flush=True)

    %(mechanisms)s
    print("RESULT " + json.dumps(out), flush=True)
""")

MECHANISMS = """
from particlesim.scenes.vehicle import SPRING, full_vehicle
from particlesim.scenes.quarter_car import quarter_car
vehicle, vq0 = full_vehicle()
mechanism_case("vehicle, one member at a time", vehicle, vq0, "spring FL", SPRING["stiffness"], 0.02, 4, 1)
car, cq0 = quarter_car()
mechanism_case("quarter cars vectorised", car, cq0, "suspension", 5.11e4, 0.05, 32, None)
"""


def _solo12() -> Path:
    from importlib import metadata

    for f in metadata.files("example-robot-data") or ():
        if str(f).endswith("solo_description/robots/solo12.urdf"):
            return Path(f.locate())
    pytest.skip("example-robot-data has no solo12.urdf")


@pytest.mark.slow
def test_split_batches_return_and_equal_the_unsplit_batch():
    tests = str(Path(__file__).parent)
    script = SCRIPT % {"dump": WATCHDOG_SECONDS - 20, "tests": tests, "stall": STALL_SECONDS, "calls": CALLS,
                       "threads": THREADS, "solo": str(_solo12()),
                       "mechanisms": MECHANISMS.strip()}
    env = {**os.environ, "PYTHONFAULTHANDLER": "1"}
    try:
        run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                             timeout=WATCHDOG_SECONDS, env=env)
    except subprocess.TimeoutExpired as e:
        pytest.fail(f"the split batches hung (no result in {WATCHDOG_SECONDS} s):\n{e.stdout}\n{e.stderr}")
    assert run.returncode == 0, f"the child failed:\n{run.stdout}\n{run.stderr[-6000:]}"
    line = next(x for x in run.stdout.splitlines() if x.startswith("RESULT "))
    results = json.loads(line[len("RESULT "):])
    print("\n" + "\n".join(f"  {k}: {v}" for k, v in results.items()))
    assert len(results) == 4
    for name, r in results.items():
        assert r["calls"] == CALLS * len(THREADS)
        assert r["rel"] <= SAME_RTOL, name
