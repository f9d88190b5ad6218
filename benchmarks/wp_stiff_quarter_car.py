"""Work against precision for 3 s of the quarter car made stiff (tyre 100x, suspension spring 10x; float64, CPU):
the implicit solver against our explicit ones and the MuJoCo C twin, on the shared rows of :mod:`benchmarks._wp`.

Scene: :func:`particlesim.scenes.quarter_car.quarter_car` with the tyre's stiffness 100x and the spring's 10x,
released from its assembly (the car drops onto the tyre and settles). Error = |chassis z − reference| [m], the
largest over 301 saves (every 10 ms; the target 1e-6 m applies to it), the final one beside it. Reference: ours,
Dopri8 at rtol 1e-12.

* ours: ``simulate_mechanism`` as a user calls it (compiled once per solver and settings, listed separately):
  Kvaerno5 (the structured ESDIRK, :mod:`particlesim._esdirk`), Tsit5 and Dopri5 under the default controller, and
  Tsit5 and Bosh3 under the PI (0.2, 0.4) controller a user would pick for a stiff scene, over a sweep of rtol
  (atol = rtol / 100);
* MuJoCo C twin (:mod:`particlesim.twins.quarter_car`, its spring stiffened the same way, the tyre a compiled
  ``mjcb_passive``): RK4 and ``implicitfast`` in the native loop (``mujoco.rollout``), swept over fixed steps; the
  coarsest step meeting the target gives its time (interpolated log-log to the target between bracketing steps).

Run: ``python -m benchmarks.wp_stiff_quarter_car`` (about 3 min).
"""

from __future__ import annotations

import time

import particlesim  # noqa: F401  (float64)
import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from particlesim.mechanism import simulate_mechanism
from particlesim.scenes import quarter_car as qc
from particlesim.twins import callbacks as mjcb
from particlesim.twins.quarter_car import SOLREF_TC, twin_xml

from . import _wp
from ._native import Rollout, initial_state

NAME = "wp_stiff_quarter_car"
T_END = 3.0
TARGET = 1e-6  # m, chassis z, largest over the run
TS = np.linspace(0.0, T_END, 301)
SPRING = {"stiffness": 10 * qc.SPRING["stiffness"]}
TYRE = {**qc.TYRE, "stiffness": 100 * qc.TYRE["stiffness"]}
REF = {"solver": "dopri8", "rtol": 1e-12}
RTOLS = (1e-3, 1e-4, 1e-5, 1e-6, 1e-7)
PIDS = {"PI(0.2, 0.4)": (0.2, 0.4, 0.0)}
SWEEP = {"kvaerno5": RTOLS, "tsit5": RTOLS, "dopri5": RTOLS, "tsit5 PI(0.2, 0.4)": RTOLS, "bosh3 PI(0.2, 0.4)": RTOLS}
C_STEPS = (5e-3, 4e-3, 3e-3, 2e-3, 1e-3, 5e-4, 2.5e-4, 1e-4, 5e-5, 2e-5, 1e-5)


def scene():
    mech, x0 = qc.quarter_car(spring=SPRING, tyre={"stiffness": TYRE["stiffness"]})
    return mech, jnp.asarray(x0)


def _ours(mech, x0):
    k = mech.point_index("centre")
    xd0 = jnp.zeros_like(x0)
    chassis = jax.jit(jax.vmap(lambda m, x: m.point_positions(m.all_positions(x))[k, 2], in_axes=(None, 0)))

    def run(solver, rtol, saves=True):
        name, _, pid = solver.partition(" ")
        s = simulate_mechanism(mech, x0, xd0, 0.0, T_END, solver=name, rtol=rtol, atol=rtol * 1e-2,
                               max_steps=1_000_000, saveat_ts=TS if saves else None, pid=PIDS.get(pid))
        q = s.q.block_until_ready()
        return (np.asarray(chassis(mech, q)) if saves else q), s.steps, s.rejected

    return run


def _c_make(dt, integrator="RK4"):
    m = mujoco.MjModel.from_xml_string(twin_xml(dt, spring=SPRING).replace('integrator="RK4"',
                                                                          f'integrator="{integrator}"'))
    site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "centre")
    ground = float(qc._p(10)[2]) - TYRE["radius"]
    mjcb.install_tyres([(site, (0.0, 0.0, 1.0), ground, TYRE["radius"], TYRE["stiffness"], TYRE["damping"])])
    ro = Rollout(m, initial_state(m), int(round(T_END / dt)))
    body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "chassis")
    save_dt = TS[1] - TS[0]
    stride = int(round(save_dt / dt))
    on_grid = dt <= save_dt and abs(stride * dt - save_dt) < 1e-12

    def to_traj(states):
        obs = ro.trajectory(states, lambda mm, dd: dd.xpos[body, 2], stride if on_grid else ro.nstep)[:, 0]
        return obs if on_grid else np.concatenate([np.full(len(TS) - 1, np.nan), obs[-1:]])

    return ro, to_traj


def _setting(dt):
    return f"dt {dt:g} (solref {max(SOLREF_TC, 2 * dt):g} s)"


def run() -> dict:
    started = time.perf_counter()
    mech, x0 = scene()
    ours = _ours(mech, x0)
    ref_z, ref_steps, _ = ours(REF["solver"], REF["rtol"])
    errors = _wp.Errors(ref_z)
    rows = _wp.sweep_public("ours", tuple(SWEEP), SWEEP, ours, errors, log=lambda r: print(r, flush=True))
    try:
        for integrator in ("RK4", "implicitfast"):
            rows += _wp.sweep_rollout(f"MuJoCo C twin {integrator} (mujoco.rollout)", C_STEPS,
                                      lambda dt, i=integrator: _c_make(dt, i), errors, T_END, setting=_setting,
                                      log=lambda r: print(r, flush=True))
    finally:
        mjcb.uninstall()
    notes = [
        f"Tyre stiffness {TYRE['stiffness']:.3g} N/m (100x) and suspension spring {SPRING['stiffness']:.3g} N/m "
        "(10x): the wheel hop's rate rises about tenfold and holds explicit solvers to steps of a few 1e-4 s.",
        "Error: the largest |chassis z − reference| over 301 saves (10 ms apart); the target applies to it "
        "(`key = max_error`).",
        "The twins' loops are soft (MuJoCo clamps the `solref` time constant to ≥ 2 dt), so their error has a floor "
        "set by the loop compliance at each step.",
    ]
    res = _wp.finish(NAME, "Quarter car, tyre 100x and spring 10x stiffer", T_END, TARGET, "m",
                     "|chassis z − reference|, largest over the run",
                     {"what": f"ours Dopri8 rtol {REF['rtol']:g} atol {REF['rtol'] * 1e-2:g}",
                      "steps": int(ref_steps)}, rows, started, notes=notes, key="max_error")
    try:
        _wp.check_interleaved(res, lambda solver, rtol: ours(solver, rtol, False),
                              lambda dt, row: _c_make(dt, "implicitfast" if "implicitfast" in row["method"]
                                                      else "RK4")[0])
    finally:
        mjcb.uninstall()
    return _wp.finish_without_mjx(res, started)


markdown = _wp.markdown_without_mjx


def main() -> dict:
    return _wp.main(run, markdown)


if __name__ == "__main__":
    main()
