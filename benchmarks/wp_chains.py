"""Work against precision for 2 s of two pendulum chains released from rest (float64, CPU): a revolute chain of
N = 4 links and a spherical chain of N = 3 (:mod:`particlesim.scenes.chains`), ours against their MuJoCo C and MJX
twins (:func:`particlesim.twins.chains.chain_mjcf`).

Error = max over the free particles (the MJCF sites at the same material points) and the three coordinates of
|x - x_ref| (m), at 2 s (final) and over the 101 save times (trajectory); reference: ours, Dopri8, rtol 1e-13,
atol 1e-15, dense solve. Rows:

* ours: :func:`particlesim.mechanism.simulate_mechanism` (coordinate projection after every step) with the dense
  saddle-point solve (Tsit5, Dopri5, Dopri8, Kvaerno5) and with the O(N) tip-to-base recursion
  (``solve="chain"``: Tsit5), over a sweep of rtol (atol = rtol / 100), one compile per solver and solve;
* MuJoCo C RK4 over a sweep of fixed steps (``mj_step`` in a Python loop);
* MJX RK4 (``mjx.step`` in a jitted scan, :func:`particlesim.twins.mjx.chain_rollout`), one compile per chain.

Writes ``results/wp_chains_revolute.*`` and ``results/wp_chains_spherical.*`` (JSON/CSV/PNG per chain) and
``results/wp_chains.json`` (both, for ``run_all``). Run: ``python -m benchmarks.wp_chains``.
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from particlesim.mechanism import simulate_mechanism
from particlesim.scenes.chains import chain_geometry, chain_mechanism
from particlesim.twins.chains import chain_mjcf

from . import _wp
from ._common import report, timed, write_json
from particlesim.twins.mjx import chain_rollout
from ._native import Rollout, initial_state

NAME = "wp_chains"
T_END = 2.0
TS = np.linspace(0.0, T_END, 101)
TARGET = 1e-6  # m, final particle positions
CHAINS = (("revolute", 4), ("spherical", 3))
REF = {"solver": "dopri8", "rtol": 1e-13}
# 1-2-5 steps from 1e-3 to 1e-6, around where the 1e-6 m target is met (MuJoCo's time is interpolated to it), decades
# beyond
EXPLICIT = (1e-3, 5e-4, 2e-4, 1e-4, 5e-5, 2e-5, 1e-5, 5e-6, 2e-6, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10)
SWEEP = {"tsit5": EXPLICIT, "dopri5": EXPLICIT, "dopri8": EXPLICIT + (1e-11,)}
# MuJoCo's fixed step, swept from steps too coarse for the target (its RK4 loses accuracy or stability) down
C_STEPS = (0.05, 0.04, 0.025, 0.02, 0.01, 0.005, 0.004, 0.0025, 0.002, 1e-3, 5e-4)
MJX_STEPS = (1e-3, 5e-4)


def _ours(mech, x0, cols, solve="dense"):
    xd0 = jnp.zeros_like(x0)

    def run(solver, rtol, saves=True):
        s = simulate_mechanism(mech, x0, xd0, 0.0, T_END, solver=solver, rtol=rtol, atol=rtol * 1e-2,
                               saveat_ts=TS if saves else None, solve=solve, max_steps=200_000)
        q = np.asarray(s.q)  # blocks on the result
        return q.reshape(len(q), -1, 3)[:, cols].reshape(len(q), -1), s.steps, s.rejected

    return run


def _mujoco_rollout(geom, sites):
    def make(dt):
        m = mujoco.MjModel.from_xml_string(chain_mjcf(geom, timestep=dt)[0])
        nstep = int(round(T_END / dt))
        ro = Rollout(m, initial_state(m), nstep)
        save_dt = TS[1] - TS[0]
        stride = int(round(save_dt / dt)) if dt <= save_dt else None

        def to_traj(states):
            if stride is None or abs(stride * dt - save_dt) > 1e-12:  # steps off the save grid: final state only
                final = ro.trajectory(states, lambda mm, dd: dd.site_xpos[sites], nstep)[-1]
                return np.concatenate([np.full((len(TS) - 1, final.size), np.nan), final[None]])
            return ro.trajectory(states, lambda mm, dd: dd.site_xpos[sites], stride)

        return ro, to_traj

    return make


def run_chain(joint: str, n: int) -> dict:
    started = time.perf_counter()
    geom = chain_geometry(n, joint, seed=n)
    mech, x0 = chain_mechanism(geom)
    x0 = jnp.asarray(x0)
    _, names = chain_mjcf(geom)
    sites = [i for i, nm in enumerate(names) if mech.index(nm) in mech.free]
    cols = np.asarray([mech.free.index(mech.index(names[i])) for i in sites])
    ours = _ours(mech, x0, cols)
    ref, ref_steps, _ = ours(REF["solver"], REF["rtol"], True)
    errors = _wp.Errors(np.asarray(ref))
    print(f"{joint} N={n}: reference {int(ref_steps)} steps", flush=True)
    rows = _wp.sweep_public("ours", tuple(SWEEP), SWEEP, ours, errors)
    rows += _wp.sweep_rollout("MuJoCo C RK4 (mujoco.rollout)", C_STEPS, _mujoco_rollout(geom, sites), errors, T_END)

    def model(dt):
        return mujoco.MjModel.from_xml_string(chain_mjcf(geom, timestep=dt)[0])

    fn, mx0, d0 = chain_rollout(model(MJX_STEPS[0]), len(TS))
    per = lambda dt: int(round((TS[1] - TS[0]) / dt))  # noqa: E731
    with jax.numpy_rank_promotion("allow"):
        comp_mjx, compiled = timed(lambda: fn.lower(mx0, d0, per(MJX_STEPS[0])).compile())
        mxs = {dt: mjx.put_model(model(dt)) for dt in MJX_STEPS}
    rows += _wp.sweep_fixed("MJX RK4 (jit)", MJX_STEPS,
                            lambda dt: np.asarray(compiled(mxs[dt], d0, per(dt)))[:, sites].reshape(len(TS), -1),
                            errors, T_END, compile_s=comp_mjx)
    notes = ["Ours: `simulate_mechanism` called as a user calls it (its compiled program is cached per structure and "
             "settings; the first call's compile is the `compile` column, not in the ratios); timed saving the end "
             "state (the measure), the error over the run taken from the same settings saving 101 states. "
             "MuJoCo C: `mujoco.rollout` on the calling thread (nthread 0), its RK4 step swept from coarse to fine; "
             "the ratio uses its time interpolated (log-log) to exactly the target error between the bracketing "
             "steps. Steps coarser than the 20 ms save grid are judged on the final state only."]
    if joint == "spherical":
        notes.append("MJX 3.17's RK4 is second order on ball joints (it advances the quaternion by body-frame stage "
                     "velocities without the dexp correction; tests/twins/test_mjx_twins.py measures the error "
                     "falling 4× per halving), so its error falls slowly with the step; MuJoCo C's RK4 stays fourth "
                     "order.")
    res = _wp.finish(f"{NAME}_{joint}", f"{joint.capitalize()} chain, N = {n}, released from rest", T_END, TARGET,
                      "m", "max |particle position − reference| over the free particles",
                      {"what": f"ours Dopri8 rtol {REF['rtol']:g} atol {REF['rtol'] * 1e-2:g}", "steps": int(ref_steps)},
                      rows, started, notes=notes, goals=_wp.PEERS)
    mujoco_at = _mujoco_rollout(geom, sites)
    return _wp.conclude(res, started, ours, lambda dt, _: mujoco_at(dt)[0])


def run() -> dict:
    started = time.perf_counter()
    sections = [run_chain(j, n) for j, n in CHAINS]
    return {"benchmark": NAME, "sections": sections, "elapsed_s": time.perf_counter() - started}


def write(results: dict) -> None:
    for sec in results["sections"]:
        _wp.write(sec)
    write_json(NAME, results)


def markdown(results: dict) -> str:
    return "\n".join(_wp.markdown(sec) for sec in results["sections"])


def main() -> dict:
    return report(run, write, markdown)


if __name__ == "__main__":
    main()
