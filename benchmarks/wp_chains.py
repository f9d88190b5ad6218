"""Work against precision for 2 s of two pendulum chains released from rest (float64, CPU): a revolute chain of
N = 4 links and a spherical chain of N = 3 (:mod:`particlesim.scenes.chains`), ours against their MuJoCo C and MJX
twins (:func:`particlesim.scenes.chains.chain_mjcf`).

Error = max over the free particles (the MJCF sites at the same material points) and the three coordinates of
|x - x_ref| (m), at 2 s (final) and over the 101 save times (trajectory); reference: ours, Dopri8, rtol 1e-13,
atol 1e-15, dense solve. Rows:

* ours: :func:`particlesim.mechanism.simulate_mechanism` (coordinate projection after every step) with the dense
  saddle-point solve (Tsit5, Dopri5, Dopri8, Kvaerno5) and with the O(N) tip-to-base recursion
  (``solve="chain"``: Tsit5), over a sweep of rtol (atol = rtol / 100), one compile per solver and solve;
* MuJoCo C RK4 over a sweep of fixed steps (``mj_step`` in a Python loop);
* MJX RK4 (``mjx.step`` in a jitted scan, :func:`benchmarks._mjx_twins.chain_rollout`), one compile per chain.

Writes ``results/wp_chains_revolute.*`` and ``results/wp_chains_spherical.*`` (JSON/CSV/PNG per chain) and
``results/wp_chains.json`` (both, for ``run_all``). Run: ``python -m benchmarks.wp_chains``.
"""

from __future__ import annotations

import json
import time

import particlesim  # noqa: F401  (float64)
import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from particlesim.mechanism import simulate_mechanism
from particlesim.scenes.chains import chain_geometry, chain_mechanism, chain_mjcf

from . import _wp
from ._common import RESULTS, timed
from ._mjx_twins import chain_rollout

NAME = "wp_chains"
T_END = 2.0
TS = np.linspace(0.0, T_END, 101)
TARGET = 1e-6  # m, final particle positions
CHAINS = (("revolute", 4), ("spherical", 3))
REF = {"solver": "dopri8", "rtol": 1e-13, "atol": 1e-15}
EXPLICIT = (1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10)
DENSE = {"tsit5": EXPLICIT, "dopri5": EXPLICIT, "dopri8": EXPLICIT + (1e-11,), "kvaerno5": (1e-4, 1e-5, 1e-6)}
CHAIN = {"tsit5": EXPLICIT}  # the O(N) recursion's rows: the same steps as the dense solve, another cost per step
C_STEPS = (2e-3, 1e-3, 5e-4, 2.5e-4, 1.25e-4)
MJX_STEPS = (1e-3, 5e-4, 2.5e-4)


def _ours_fn(solve: str, cols):
    def make(solver):
        def fn(mech, x0, rtol, atol):
            s = simulate_mechanism(mech, x0, jnp.zeros_like(x0), 0.0, T_END, solver=solver, rtol=rtol, atol=atol,
                                   saveat_ts=jnp.asarray(TS), solve=solve, max_steps=200_000)
            return s.q.reshape(len(TS), -1, 3)[:, cols].reshape(len(TS), -1), s.steps, s.rejected

        return fn

    return make


def _mujoco_c(m, sites):
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    per = int(round((TS[1] - TS[0]) / m.opt.timestep))
    out = [d.site_xpos[sites].copy()]
    for _ in range(len(TS) - 1):
        for _ in range(per):
            mujoco.mj_step(m, d)
        mujoco.mj_kinematics(m, d)  # after an RK4 mj_step, site_xpos is not the kinematics of the new qpos
        out.append(d.site_xpos[sites].copy())
    return np.asarray(out).reshape(len(TS), -1)


def run_chain(joint: str, n: int) -> dict:
    started = time.perf_counter()
    geom = chain_geometry(n, joint, seed=n)
    mech, x0 = chain_mechanism(geom)
    x0 = jnp.asarray(x0)
    xml, names = chain_mjcf(geom, timestep=C_STEPS[0])
    sites = [i for i, nm in enumerate(names) if mech.index(nm) in mech.free]
    cols = np.asarray([mech.free.index(mech.index(names[i])) for i in sites])
    dense, chain = {}, {}
    comp, ref_fn = _wp.compile_ours(_ours_fn("dense", cols), (mech, x0), REF["solver"], dense)
    ref, ref_steps, _ = ref_fn(mech, x0, jnp.asarray(REF["rtol"]), jnp.asarray(REF["atol"]))
    errors = _wp.Errors(np.asarray(ref))
    print(f"{joint} N={n}: reference {int(ref_steps)} steps", flush=True)
    rows = _wp.sweep_ours(_ours_fn("dense", cols), (mech, x0), tuple(DENSE), DENSE, errors, compiled=dense,
                          label=lambda s: f"ours {s} (dense)")
    rows += _wp.sweep_ours(_ours_fn("chain", cols), (mech, x0), tuple(CHAIN), CHAIN, errors, compiled=chain,
                           label=lambda s: f"ours {s} (O(N) chain)")

    def model(dt):
        return mujoco.MjModel.from_xml_string(chain_mjcf(geom, timestep=dt)[0])

    c_models = {dt: model(dt) for dt in C_STEPS}
    rows += _wp.sweep_fixed("MuJoCo C RK4", C_STEPS, lambda dt: _mujoco_c(c_models[dt], sites), errors, T_END)
    fn, mx0, d0 = chain_rollout(model(MJX_STEPS[0]), len(TS))
    per = lambda dt: int(round((TS[1] - TS[0]) / dt))  # noqa: E731
    with jax.numpy_rank_promotion("allow"):
        comp_mjx, compiled = timed(lambda: fn.lower(mx0, d0, per(MJX_STEPS[0])).compile())
        mxs = {dt: mjx.put_model(model(dt)) for dt in MJX_STEPS}
    rows += _wp.sweep_fixed("MJX RK4 (jit)", MJX_STEPS,
                            lambda dt: np.asarray(compiled(mxs[dt], d0, per(dt)))[:, sites].reshape(len(TS), -1),
                            errors, T_END, compile_s=comp_mjx)
    notes = ["Ours runs one jitted call per 2 s rollout (dispatch included); compile times are listed separately "
             "and are not in the ratios. MuJoCo C is stepped from Python (`mj_step` per step)."]
    if joint == "spherical":
        notes.append("MJX 3.17's RK4 is second order on ball joints (it advances the quaternion by body-frame stage "
                     "velocities without the dexp correction; tests/mechanism/test_mjx_twins.py measures the error "
                     "falling 4× per halving), so its error falls slowly with the step; MuJoCo C's RK4 stays fourth "
                     "order.")
    res = _wp.finish(f"{NAME}_{joint}", f"{joint.capitalize()} chain, N = {n}, released from rest", T_END, TARGET,
                      "m", "max |particle position − reference| over the free particles",
                      {"what": f"ours Dopri8 rtol {REF['rtol']:g} atol {REF['atol']:g} (dense)",
                       "steps": int(ref_steps), "compile_s": comp}, rows, started, notes=notes)
    res["notes"] += _wp.headline_notes(res)
    return res


def run() -> dict:
    started = time.perf_counter()
    sections = [run_chain(j, n) for j, n in CHAINS]
    return {"benchmark": NAME, "sections": sections, "elapsed_s": time.perf_counter() - started}


def write(results: dict) -> None:
    for sec in results["sections"]:
        _wp.write(sec)
    (RESULTS / f"{NAME}.json").write_text(json.dumps(results, indent=2) + "\n")


def markdown(results: dict) -> str:
    return "\n".join(_wp.markdown(sec) for sec in results["sections"])


def main() -> dict:
    results = run()
    write(results)
    print(markdown(results))
    return results


if __name__ == "__main__":
    main()
