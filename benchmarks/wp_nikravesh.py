"""Work against precision for 2 s of Nikravesh's planar double A-arm (float64, CPU): ours against its MuJoCo C and
MJX twins (:mod:`particlesim.scenes.nikravesh_twin`).

Error = the wheel-assembly CoM height y2 (the quantity of ``AA_results.csv``) against ours (Dopri8, rtol 1e-12,
atol 1e-14), sampled every 10 ms: at 2 s (final state) and the largest over the run. The AA settles well before
2 s, so the final-state error measures the static equilibrium only (a first-order integrator reaches it too); the
largest error over the run is the one that tells the methods apart, and it gets its own headline.

* ours: Tsit5, Dopri5, Dopri8 and Kvaerno5 over a sweep of rtol (atol = rtol / 100), one compile per solver
  (tolerances are traced); the reference is the Dopri8 program, compiled once for both. Bosh3 is left out to keep
  the module within its time budget (another 18-26 s of compile; it was never the cheapest at 1e-6 m);
* MuJoCo C twin: RK4 over a sweep of fixed steps (tyre in a Python passive callback at every stage, loop
  ``solref`` time constant 2 dt), Euler and implicitfast over short sweeps (first order);
* MJX twin: our RK4 loop around MJX's forward stages (tyre per stage), one compile, a few steps.

Run: ``python -m benchmarks.wp_nikravesh``.
"""

from __future__ import annotations

import time

import particlesim  # noqa: F401  (float64)
import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from particlesim.mechanism import simulate_mechanism
from particlesim.scenes import nikravesh as nk
from particlesim.scenes.nikravesh_twin import mjx_rollout, solref_tc, twin_rollout, twin_xml

from . import _wp
from ._common import median_time, timed

NAME = "wp_nikravesh"
T_END = 2.0
TARGET = 1e-6  # m, wheel height
TS = np.linspace(0.0, T_END, 201)  # every 10 ms (AA_results.csv rows 0, 10, 20, ...)
RTOLS = (1e-3, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10)
EXPLICIT = {"tsit5": RTOLS, "dopri5": RTOLS, "dopri8": RTOLS}
IMPLICIT = {"kvaerno5": RTOLS[:4]}  # 1.2 s per run at rtol 1e-6; compiles in 40-70 s
REF_RTOL, REF_ATOL = 1e-12, 1e-14
C_RK4_STEPS = (1e-2, 5e-3, 2e-3, 1e-3, 5e-4, 2e-4)
C_FIRST_ORDER_STEPS = (1e-3, 1e-4)
MJX_STEPS = (5e-3, 2e-3, 1e-3, 5e-4)
COST_STEPS = 2000  # RK4 steps timed with and without the Python tyre callback


def _wheel_fn(solver: str):
    """``fn(mech, x0, rtol, atol) -> (y2 at TS, steps, rejected)`` for one of our solvers."""
    def fn(mech, x0, rtol, atol):
        k = mech.point_index(nk.WHEEL_COM)
        s = simulate_mechanism(mech, x0, jnp.zeros_like(x0), 0.0, T_END, solver=solver, rtol=rtol, atol=atol,
                               max_steps=1_000_000, saveat_ts=TS)
        return jax.vmap(lambda x: mech.point_position(k, mech.all_positions(x))[1])(s.q), s.steps, s.rejected

    return fn


def _setting(kind: str):
    return lambda dt: f"dt {dt:g} (solref {solref_tc(dt):g} s)" if kind == "RK4" else f"dt {dt:g}"


def _c_rows(errors) -> list[dict]:
    rows = []
    for kind, dts in (("RK4", C_RK4_STEPS), ("Euler", C_FIRST_ORDER_STEPS), ("implicitfast", C_FIRST_ORDER_STEPS)):
        def run(dt, kind=kind):
            out = twin_rollout(TS, dt, kind)
            return {"traj": out["wheel_y"], "loop": out["loop_residual"]}

        rows += _wp.sweep_fixed(f"MuJoCo C twin {kind}", dts, run, errors, T_END, setting=_setting(kind),
                                extra=lambda out: {"loop_residual_m": float(np.max(out["loop"]))},
                                log=lambda r: print(r, flush=True))
    return rows


def _mjx_rows(errors) -> list[dict]:
    from mujoco import mjx

    fn, mx, d0 = mjx_rollout(mujoco.MjModel.from_xml_string(twin_xml(MJX_STEPS[0])), len(TS))
    per0 = int(round((TS[1] - TS[0]) / MJX_STEPS[0]))
    with jax.numpy_rank_promotion("allow"):
        comp, compiled = timed(lambda: fn.lower(mx, d0, per0).compile())
    models = {dt: mjx.put_model(mujoco.MjModel.from_xml_string(twin_xml(dt))) for dt in MJX_STEPS}

    def run(dt):
        y, loop = compiled(models[dt], d0, int(round((TS[1] - TS[0]) / dt)))
        return {"traj": y, "loop": loop}

    return _wp.sweep_fixed("MJX twin RK4 (jit)", MJX_STEPS, run, errors, T_END, compile_s=comp,
                           block=jax.block_until_ready, setting=_setting("RK4"),
                           extra=lambda out: {"loop_residual_m": float(np.max(out["loop"]))},
                           log=lambda r: print(r, flush=True))


def _callback_cost() -> dict:
    """µs per MuJoCo C RK4 step with the Python tyre callback and without any (other physics; cost only)."""
    from particlesim.scenes import nikravesh_twin as tw

    m = mujoco.MjModel.from_xml_string(twin_xml(1e-3))
    site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "G2")
    out = {}
    for label, cb in (("with_callback_us", tw._tyre_callback(site)), ("without_callback_us", None)):
        d = mujoco.MjData(m)
        mujoco.set_mjcb_passive(cb)
        try:
            out[label] = median_time(lambda: mujoco.mj_step(m, d, nstep=COST_STEPS), number=1, repeat=5) \
                / COST_STEPS * 1e6
        finally:
            mujoco.set_mjcb_passive(None)
    return out


def run() -> dict:
    started = time.perf_counter()
    mech, x0 = nk.aa_mechanism()
    x0 = jnp.asarray(x0)
    args, cache = (mech, x0), {}
    ref_c, ref_fn = _wp.compile_ours(_wheel_fn, args, "dopri8", cache)
    y_ref, ref_steps, _ = ref_fn(mech, x0, jnp.asarray(REF_RTOL), jnp.asarray(REF_ATOL))
    y_ref = np.asarray(y_ref)
    aa = nk.load_reference()[: len(TS) * 10 - 9 : 10]
    assert np.allclose(aa[:, 0], TS, atol=1e-12, rtol=0)
    file_dist = float(np.abs(y_ref - aa[:, 5]).max())
    print(f"reference: y2(2 s) = {y_ref[-1]:.12f} m, {int(ref_steps)} steps; vs AA_results.csv {file_dist:.2e} m",
          flush=True)
    errors = _wp.Errors(y_ref)
    rows = []
    for sweep, repeat in ((EXPLICIT, 5), (IMPLICIT, 3)):  # the load is shared: more repeats where runs are short
        rows += _wp.sweep_ours(_wheel_fn, args, list(sweep), sweep, errors, compiled=cache, repeat=repeat,
                               log=lambda r: print(r, flush=True))
    rows += _c_rows(errors)
    rows += _mjx_rows(errors)
    cost = _callback_cost()
    print(cost, flush=True)
    loop = {r["method"]: r["loop_residual_m"] for r in rows if r["setting"].startswith("dt 0.001 ")}
    loop_ratio = loop["MJX twin RK4 (jit)"] / loop["MuJoCo C twin RK4"]
    notes = [
        f"The AA settles before {T_END:g} s, so the final-state error measures the static equilibrium only (the "
        "first-order Euler and implicitfast runs reach it as well); the largest error over the run, sampled every "
        "10 ms, separates the methods and has its own headline below.",
        f"Reference: ours Dopri8 rtol {REF_RTOL:g} atol {REF_ATOL:g} ({int(ref_steps)} steps); it lies "
        f"{file_dist:.1e} m from `AA_results.csv` (MATLAB ode45, RelTol 1e-6) at the same samples.",
        f"MuJoCo C RK4 costs {cost['with_callback_us']:.0f} µs per step with the tyre as a Python `mjcb_passive` "
        f"callback (4 calls per step) and {cost['without_callback_us']:.0f} µs without any callback (other physics, "
        "cost only): the difference is the Python callback, which a callback written in C would mostly remove.",
        "The twins' loop is soft (`solref` time constant 2 dt, the smallest MuJoCo accepts); MJX 3.17 also omits "
        f"J̇v in `connect` rows, so its loop opens {loop_ratio:.0f}× further than MuJoCo C's at dt 1e-3 "
        "(MUJOCO-TWINS.md).",
    ]
    res = _wp.finish(NAME, "Nikravesh planar double A-arm", T_END, TARGET, "m", "wheel-assembly CoM height y2",
                     {"what": f"ours Dopri8 rtol {REF_RTOL:g}", "y2_final_m": float(y_ref[-1]),
                      "steps": int(ref_steps), "compile_s": ref_c, "distance_to_AA_results_m": file_dist},
                     rows, started, notes)
    res["notes"] += _wp.headline_notes(res)
    res["trajectory_headline"] = _wp.headline(rows, TARGET, key="max_error")
    res["notes"] += ["On the largest error over the run: " + n[0].lower() + n[1:]
                     for n in _wp.headline_notes({**res, **res["trajectory_headline"]})]
    res["callback_cost"] = cost
    res["elapsed_s"] = time.perf_counter() - started
    return res


def markdown(results: dict) -> str:
    text = _wp.markdown(results, all_rows=True)
    th = results["trajectory_headline"]
    best = th["ours_best"]
    lines = [f"On the largest error over the run (≤ {results['target_error']:g} {results['unit']}):", ""]
    if best:
        parts = []
        for peer, x in th["speedup_vs"].items():
            if x is None:
                parts.append(f"{peer}: no run reached the target")
            else:
                parts.append(f"{x:.2f}× faster than {peer}" if x >= 1 else f"{1 / x:.2f}× slower than {peer}")
        lines += [f"**{best['method']}, {best['setting']}: {_wp.fmt_time(best['wall_s'])}; "
                  + "; ".join(parts) + ".**", ""]
    lines += ["| method | setting | wall time | final error | max error | steps | compile |",
              "|---|---|---:|---:|---:|---:|---:|"]
    for method, r in th["headline"].items():
        lines.append(_wp._fmt(r, results["unit"]) if r else f"| {method} | none of the settings tried | | | | | |")
    marker = "All runs:"
    return text.replace(marker, "\n".join(lines) + "\n\n" + marker, 1)


def main() -> dict:
    print(f"devices: {jax.devices()}")
    results = run()
    _wp.write(results)
    print(markdown(results))
    print(f"elapsed {results['elapsed_s']:.0f} s")
    return results


if __name__ == "__main__":
    main()
