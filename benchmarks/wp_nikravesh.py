"""Work against precision for 2 s of Nikravesh's planar double A-arm (float64, CPU): ours against its MuJoCo C and
MJX twins (:mod:`particlesim.twins.nikravesh`).

Error = the wheel-assembly CoM height y2 (the quantity of ``AA_results.csv``) against ours (Dopri8, rtol 1e-12,
atol 1e-14), sampled every 10 ms: at 2 s (final state) and the largest over the run. The AA settles well before
2 s, so the final-state error measures the static equilibrium only (a first-order integrator reaches it too); the
largest error over the run is the one that tells the methods apart, and it gets its own headline.

* ours: Tsit5, Dopri5, Dopri8 and Kvaerno5 over a sweep of rtol (atol = rtol / 100), through the public entry point
  (its compiled program cached per structure and settings, compile listed separately). Bosh3 is left out to keep
  the module within its time budget: it adds about 20 s of compile and is not the cheapest at 1e-6 m;
* MuJoCo C twin: in its native loop (``mujoco.rollout``), the tyre a compiled C passive callback at every stage,
  loop ``solref`` time constant 2 dt: RK4 over a sweep of fixed steps, Euler and implicitfast over short sweeps
  (first order);
* MJX twin: our RK4 loop around MJX's forward stages (tyre per stage), one compile, a few steps.

Run: ``python -m benchmarks.wp_nikravesh``.
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from particlesim.scenes import nikravesh as nk
from particlesim.twins.nikravesh import mjx_rollout, solref_tc, twin_xml

from particlesim.twins import callbacks as mjcb

from . import _wp
from ._common import timed
from ._native import Rollout, initial_state

NAME = "wp_nikravesh"
T_END = 2.0
TARGET = 1e-6  # m, wheel height
TS = np.linspace(0.0, T_END, 201)  # every 10 ms (AA_results.csv rows 0, 10, 20, ...)
# 1-2-5 steps where the cheapest runs meet the target (MuJoCo's time is interpolated to it), decades beyond
RTOLS = (1e-2, 5e-3, 2e-3, 1e-3, 5e-4, 2e-4, 1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10)
EXPLICIT = {"tsit5": RTOLS, "dopri5": RTOLS, "dopri8": RTOLS}
IMPLICIT = {"kvaerno5": (1e-3, 1e-4, 1e-5, 1e-6)}
REF_RTOL = 1e-12
C_RK4_STEPS = (4e-2, 2e-2, 1e-2, 5e-3, 2e-3, 1e-3, 5e-4, 2e-4)
C_FIRST_ORDER_STEPS = (1e-3, 1e-4)
MJX_STEPS = (5e-3, 2e-3, 1e-3, 5e-4)
COST_STEPS = 2000  # RK4 steps timed with and without the tyre callback


def _ours(mech, x0):
    k = mech.point_index(nk.WHEEL_COM)
    wheel = jax.jit(jax.vmap(lambda m, x: m.point_position(k, m.all_positions(x))[1], in_axes=(None, 0)))
    return _wp.public_runner(mech, x0, jnp.zeros_like(x0), T_END, TS, lambda s: np.asarray(wheel(mech, s.q)),
                             max_steps=1_000_000)


def _setting(kind: str):
    return lambda dt: f"dt {dt:g} (solref {solref_tc(dt):g} s)" if kind == "RK4" else f"dt {dt:g}"


def _tyre(m):
    site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "G2")
    return [(site, (0.0, 1.0, 0.0), 0.0, nk.TYRE["radius"], nk.TYRE["stiffness"], nk.TYRE["damping"])]


def _c_rollout(dt: float, kind: str) -> Rollout:
    """The MuJoCo C twin's native loop at step ``dt`` with integrator ``kind``, the tyre's callback installed."""
    m = mujoco.MjModel.from_xml_string(twin_xml(dt, kind))
    mjcb.install_tyres(_tyre(m))
    return Rollout(m, initial_state(m), int(round(T_END / dt)))


def _c_rows(errors) -> list[dict]:
    """MuJoCo C through ``mujoco.rollout`` on the calling thread, the tyre as a compiled ``mjcb_passive``."""
    from particlesim.twins.nikravesh import _loop_residual

    rows = []
    save_dt = TS[1] - TS[0]
    for kind, dts in (("RK4", C_RK4_STEPS), ("Euler", C_FIRST_ORDER_STEPS), ("implicitfast", C_FIRST_ORDER_STEPS)):
        loops = {}

        def make(dt, kind=kind, loops=loops):
            ro = _c_rollout(dt, kind)
            m = ro.models
            site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "G2")
            b1, b2 = int(m.eq_obj1id[0]), int(m.eq_obj2id[0])
            stride = int(round(save_dt / dt))
            on_grid = dt <= save_dt and abs(stride * dt - save_dt) < 1e-12

            def to_traj(states):
                obs = ro.trajectory(states, lambda mm, dd: (dd.site_xpos[site, 1], _loop_residual(mm, dd, b1, b2)),
                                    stride if on_grid else ro.nstep)
                loops[dt] = float(obs[:, 1].max())
                if not on_grid:
                    return np.concatenate([np.full(len(TS) - 1, np.nan), obs[-1:, 0]])
                return obs[:, 0]

            return ro, to_traj

        rows += _wp.sweep_rollout(f"MuJoCo C twin {kind} (mujoco.rollout)", dts, make, errors, T_END,
                                  setting=_setting(kind))
        for r in rows[-len(dts):]:
            r["loop_residual_m"] = loops.get(r["dt"], float("nan"))
    mjcb.uninstall()
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
                           extra=lambda out: {"loop_residual_m": float(np.max(out["loop"]))})


def _callback_cost() -> dict:
    """µs per MuJoCo C RK4 step (``mujoco.rollout``, dt 1e-3) with the compiled tyre callback and without any
    (other physics; cost only)."""
    m = mujoco.MjModel.from_xml_string(twin_xml(1e-3))
    out = {}
    for label, tyres in (("with_c_callback_us", _tyre(m)), ("without_callback_us", None)):
        if tyres:
            mjcb.install_tyres(tyres)
        else:
            mjcb.uninstall()
        ro = Rollout(m, initial_state(m), COST_STEPS)
        out[label] = ro.timed(5)[1] / COST_STEPS * 1e6
    mjcb.uninstall()
    return out


def run() -> dict:
    started = time.perf_counter()
    mech, x0 = nk.aa_mechanism()
    x0 = jnp.asarray(x0)
    ours = _ours(mech, x0)
    y_ref, ref_steps, _ = ours("dopri8", REF_RTOL)
    y_ref = np.asarray(y_ref)
    aa = nk.load_reference()[: len(TS) * 10 - 9 : 10]
    assert np.allclose(aa[:, 0], TS, atol=1e-12, rtol=0)
    file_dist = float(np.abs(y_ref - aa[:, 5]).max())
    print(f"reference: y2(2 s) = {y_ref[-1]:.12f} m, {int(ref_steps)} steps; vs AA_results.csv {file_dist:.2e} m",
          flush=True)
    errors = _wp.Errors(y_ref)
    rows = _wp.sweep_public("ours", list(EXPLICIT), EXPLICIT, ours, errors)
    rows += _wp.sweep_public("ours", list(IMPLICIT), IMPLICIT, ours, errors, repeat=3)
    rows += _c_rows(errors)
    rows += _mjx_rows(errors)
    cost = _callback_cost()
    print(cost, flush=True)
    loop = {r["method"]: r["loop_residual_m"] for r in rows if r["setting"].startswith("dt 0.001 ")}
    loop_ratio = loop["MJX twin RK4 (jit)"] / loop["MuJoCo C twin RK4 (mujoco.rollout)"]
    notes = [
        f"The AA settles before {T_END:g} s, so the final-state error measures the static equilibrium only (the "
        "first-order Euler and implicitfast runs reach it as well); the largest error over the run, sampled every "
        "10 ms, separates the methods and has its own headline below.",
        f"Reference: ours Dopri8 rtol {REF_RTOL:g} atol {REF_RTOL * 1e-2:g} ({int(ref_steps)} steps); it lies "
        f"{file_dist:.1e} m from `AA_results.csv` (MATLAB ode45, RelTol 1e-6) at the same samples.",
        f"MuJoCo C runs in its native loop (`mujoco.rollout`, calling thread) with the tyre as a compiled C "
        f"`mjcb_passive` (particlesim.twins.callbacks): {cost['with_c_callback_us']:.1f} µs per RK4 step, "
        f"{cost['without_callback_us']:.1f} µs without the tyre (cost only). Its step is swept from coarse to fine; "
        "the ratios use its time interpolated (log-log) to exactly the target error. Ours: `simulate_mechanism` "
        "as a user calls it (compile cached per structure, listed separately), timed saving the end state, the "
        "error over the run from the same settings saving every 10 ms.",
        "The twins' loop is soft (`solref` time constant 2 dt, the smallest MuJoCo accepts); MJX 3.17 also omits "
        f"J̇v in `connect` rows, so its loop opens {loop_ratio:.0f}× further than MuJoCo C's at dt 1e-3 "
        "(docs/twins.md).",
    ]
    res = _wp.finish(NAME, "Nikravesh planar double A-arm", T_END, TARGET, "m", "wheel-assembly CoM height y2",
                     {"what": f"ours Dopri8 rtol {REF_RTOL:g}", "y2_final_m": float(y_ref[-1]),
                      "steps": int(ref_steps), "distance_to_AA_results_m": file_dist},
                     rows, started, notes, goals=_wp.PEERS)
    res["trajectory_headline"] = _wp.headline(rows, TARGET, key="max_error")
    res["notes"] += ["On the largest error over the run: " + n[0].lower() + n[1:]
                     for n in _wp.headline_notes({**res, **res["trajectory_headline"]})]
    res["callback_cost"] = cost
    # the twin's method label is "MuJoCo C twin <integrator> (mujoco.rollout)"
    return _wp.conclude(res, started, ours, lambda dt, row: _c_rollout(dt, row["method"].split()[3]))


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
    return _wp.main(run, markdown)


if __name__ == "__main__":
    main()
