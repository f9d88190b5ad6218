"""What one step of the structured implicit solver (:mod:`particlesim._esdirk`, ``solver="kvaerno5"``) costs, in
vector-field evaluations, and where its steps go (float64, CPU).

For each scene: a rollout through the public entry point (compile timed on its first call, then the least of
:data:`REPEAT` calls), its attempted steps (accepted + rejected), and the cost of one evaluation of the same
scene's first-order vector field (the constraint solve included) timed inside a compiled loop of
:data:`EVALS` evaluations with the model passed as an argument, as the rollout sees it. The cost of a step in
evaluations is ``(wall / attempts) / field``. From :data:`particlesim._esdirk.STEP_LOG` (a diagnostic run, not
timed): Newton iterations per attempted step, the share of steps that reused the previous Newton matrix, and the
attempts whose stage solves failed (Newton rejections; the rest of the rejections are the error estimate's).

Scenes: the flyball governor (IFToMM A05) for 10 s at rtol 1e-8 (its 1e-6 target); the quarter car's free
response for 3 s, stock (rtol 1e-6) and with the tyre 100x and spring 10x stiffer (rtol 1e-4); Krang with joint
damping 100 N m s/rad for 2 s (rtol 1e-6, trees: the Newton matrix from the accelerations' forward-mode Jacobian).

Run: ``python -m benchmarks.implicit_cost`` (about 2 min).
"""

from __future__ import annotations

import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from particlesim import _esdirk
from particlesim.mechanism import simulate_mechanism
from particlesim.mechanism._algebra import prepare
from particlesim.mechanism.dynamics import _solve
from particlesim.scenes import quarter_car as qc
from particlesim.scenes.iftomm import a05_flyball
from particlesim.simulate import simulate
from particlesim.tree import forward_dynamics

from ._common import environment, report, write_results

NAME = "implicit_cost"
REPEAT = 5
EVALS = 2000


def _mechanism_field_cost(mech, q, v) -> float:
    """Seconds per evaluation of the mechanism's vector field inside a compiled loop (model as an argument)."""
    @eqx.filter_jit
    def loop(mech, q, v):
        prep = prepare(mech)

        def body(i, x):
            return x + 1e-12 * _solve(mech, prep, 0.0, q + x, v + x, 0.0)[0]

        return jax.lax.fori_loop(0, EVALS, body, jnp.zeros_like(q))

    loop(mech, q, v).block_until_ready()
    t = time.perf_counter()
    loop(mech, q, v).block_until_ready()
    return (time.perf_counter() - t) / EVALS


def _tree_field_cost(model, q, v, control) -> float:
    @eqx.filter_jit
    def loop(model, q, v):
        def body(i, x):
            return x + 1e-12 * forward_dynamics(model, q + x, v + x, control(0.0, q + x, v + x, model))

        return jax.lax.fori_loop(0, EVALS, body, jnp.zeros_like(q))

    loop(model, q, v).block_until_ready()
    t = time.perf_counter()
    loop(model, q, v).block_until_ready()
    return (time.perf_counter() - t) / EVALS


def _measure(name: str, run, field_s: float, setting: str) -> dict:
    t = time.perf_counter()
    sol = run()
    first = time.perf_counter() - t
    walls = []
    for _ in range(REPEAT):
        t = time.perf_counter()
        sol = run()
        walls.append(time.perf_counter() - t)
    wall = min(walls)
    attempts = int(sol.steps) + int(sol.rejected)
    # the diagnostic run: a separate trace with the step log on (not timed)
    _esdirk.STEP_LOG = log = []
    try:
        jax.clear_caches()
        run()
        jax.effects_barrier()
    finally:
        _esdirk.STEP_LOG = None
        jax.clear_caches()
    its = np.asarray([r[1] for r in log], dtype=float)
    converged = np.asarray([bool(r[2]) for r in log])
    reused = np.asarray([bool(r[3]) for r in log])
    step_s = wall / attempts
    row = {"scene": name, "setting": setting, "wall_s": wall, "first_call_s": first,
           "compile_s": max(first - wall, 0.0), "steps": int(sol.steps), "rejected": int(sol.rejected),
           "field_eval_s": field_s, "step_s": step_s, "evals_per_step": step_s / field_s,
           "newton_iterations_per_step": float(its.mean()) if its.size else None,
           "matrix_reused_share": float(reused.mean()) if reused.size else None,
           "newton_rejections": int((~converged).sum())}
    print(row, flush=True)
    return row


def run() -> dict:
    started = time.perf_counter()
    rows = []
    mech, x0, xd0 = a05_flyball()
    x0, xd0 = jnp.asarray(x0), jnp.asarray(xd0)
    rows.append(_measure("flyball governor (A05), 10 s", lambda: simulate_mechanism(
        mech, x0, xd0, 0.0, 10.0, solver="kvaerno5", rtol=1e-8, atol=1e-8, max_steps=100_000),
        _mechanism_field_cost(mech, x0, xd0), "rtol = atol = 1e-8"))
    for label, kw, rtol in (("quarter car, 3 s", {}, 1e-6),
                            ("quarter car, tyre 100x, spring 10x, 3 s",
                             {"spring": {"stiffness": 10 * qc.SPRING["stiffness"]},
                              "tyre": {"stiffness": 100 * qc.TYRE["stiffness"]}}, 1e-4)):
        m, q = qc.quarter_car(**kw)
        q = jnp.asarray(q)
        rows.append(_measure(label, lambda m=m, q=q, rtol=rtol: simulate_mechanism(
            m, q, jnp.zeros_like(q), 0.0, 3.0, solver="kvaerno5", rtol=rtol, atol=rtol * 1e-2, max_steps=100_000),
            _mechanism_field_cost(m, q, jnp.zeros_like(q) + 1e-3), f"rtol {rtol:g}, atol {rtol * 1e-2:g}"))
    from . import wp_krang as wk
    from particlesim.data import data_dir
    from particlesim.io import load_urdf

    model = load_urdf(data_dir() / wk.URDF, gravity=wk.GRAVITY, viscous=100.0, limits="ignore")
    _, q0, qd0, targs = wk.scene()
    amp, omega, phase = (jnp.asarray(a) for a in targs)

    def control(t, q, qd, p):
        return wk.torque(t, amp, omega, phase, jnp)

    q0, qd0 = jnp.asarray(q0), jnp.asarray(qd0)
    rows.append(_measure("Krang, joint damping 100 N m s/rad, 2 s", lambda: simulate(
        forward_dynamics, model, q0, qd0, 0.0, wk.T_END, solver="kvaerno5", rtol=1e-6, atol=1e-6, control=control,
        max_steps=100_000), _tree_field_cost(model, q0, qd0, control), "rtol = atol = 1e-6"))
    return {"benchmark": NAME, "environment": environment(), "rows": rows,
            "notes": ["evals_per_step: wall time per attempted step over one vector-field evaluation's time in a "
                      "compiled loop; newton_rejections: attempts whose stage solves did not converge (from the "
                      "diagnostic run's step log)."],
            "elapsed_s": time.perf_counter() - started}


def markdown(results: dict) -> str:
    lines = ["### Cost of an implicit step (Kvaerno5, structured Newton matrix)", "",
             "| scene | setting | wall | steps + rejected (Newton) | field eval | per step | evaluations per step | "
             "Newton iterations per step | matrix reused | compile |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in results["rows"]:
        lines.append(f"| {r['scene']} | {r['setting']} | {1e3 * r['wall_s']:.0f} ms | {r['steps']} + "
                     f"{r['rejected']} ({r['newton_rejections']}) | {1e6 * r['field_eval_s']:.1f} us | "
                     f"{1e6 * r['step_s']:.0f} us | {r['evals_per_step']:.1f} | "
                     f"{r['newton_iterations_per_step']:.1f} | {100 * r['matrix_reused_share']:.0f} % | "
                     f"{r['compile_s']:.1f} s |")
    return "\n".join(lines + [""] + results["notes"] + [""])


def main() -> dict:
    return report(run, lambda res: write_results(NAME, res, res["rows"]), markdown)


if __name__ == "__main__":
    main()
