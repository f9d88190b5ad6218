"""Work against precision for the IFToMM A02 N-four-bar (N = 40, 81 links, 20 s through 20 flat singular
positions), float64, CPU: ours (least-squares multipliers) against its MuJoCo C twin
(:mod:`particlesim.twins.four_bar`).

Error = the largest error of B0 (x, y) over 401 saves against the one-coordinate model of the parallelogram
motion (SciPy DOP853 at 1e-13; it reproduces the spec's derived period and passage figures, tested). Target 1e-3 m,
the benchmark specification's threshold for positions.

* ours: Tsit5 and Dopri8 over a sweep of rtol (atol = rtol), through the public entry point;
* MuJoCo C twin: RK4 through ``mujoco.rollout`` over a sweep of fixed steps; its loops are ``connect`` equalities
  stiffened to MuJoCo's limit (``solref`` 2 dt), and its error falls only about linearly with dt here.

Run: ``python -m benchmarks.wp_a02``.
"""

from __future__ import annotations

import time

import particlesim  # noqa: F401  (float64)
import jax.numpy as jnp
import numpy as np
from scipy.integrate import solve_ivp

from particlesim.mechanism import simulate_mechanism
from particlesim.twins.four_bar import b0_observer, twin_model
from particlesim.scenes.iftomm import A02, a02_four_bar, a02_reduced

from . import _wp
from ._native import Rollout, initial_state

NAME = "wp_a02"
T_END = A02["t_end"]
TARGET = 1e-3  # m, B0 over the run (the spec's threshold)
TS = np.linspace(0.0, T_END, A02["outputs"] + 1)
# 1-2-5 steps where the cheapest runs meet the target (MuJoCo's time is interpolated to it), decades beyond
RTOLS = (1e-4, 1e-5, 1e-6, 5e-7, 2e-7, 1e-7, 5e-8, 2e-8, 1e-8)
EXPLICIT = {"tsit5": RTOLS, "dopri8": RTOLS}
C_RK4_STEPS = (2e-3, 1e-3, 5e-4, 2.5e-4)


def reference() -> np.ndarray:
    inertia, c = a02_reduced(A02["n"])
    r = solve_ivp(lambda t, y: [y[1], c * np.sin(y[0]) / inertia], (0.0, T_END), [0.0, 1.0], method="DOP853",
                  rtol=1e-13, atol=1e-13, t_eval=TS)
    return np.stack([np.sin(r.y[0]), np.cos(r.y[0])], axis=1)


def _ours(mech, x0, xd0):
    sl = mech.free_slice("B0")

    def run(solver, rtol, saves=True):
        s = simulate_mechanism(mech, x0, xd0, 0.0, T_END, solver=solver, rtol=rtol, atol=rtol, max_steps=1_000_000,
                               saveat_ts=TS if saves else None)
        q = s.q.block_until_ready()
        return (np.asarray(q[:, sl])[:, :2] if saves else q), s.steps, s.rejected

    return run


def _c_rows(errors) -> list[dict]:
    def make(dt):
        m, d = twin_model(A02["n"], dt)
        ro = Rollout(m, initial_state(m, d), int(round(T_END / dt)))
        stride = int(round((TS[1] - TS[0]) / dt))
        obs = b0_observer(m)
        return ro, lambda states: ro.trajectory(states, obs, stride)

    return _wp.sweep_rollout("MuJoCo C twin RK4 (mujoco.rollout)", C_RK4_STEPS, make, errors, T_END,
                             setting=lambda dt: f"dt {dt:g} (solref {2 * dt:g} s)", log=lambda r: print(r, flush=True))


def run() -> dict:
    started = time.perf_counter()
    mech, x0, xd0 = a02_four_bar()
    ours = _ours(mech, jnp.asarray(x0), jnp.asarray(xd0))
    errors = _wp.Errors(reference())
    rows = _wp.sweep_public("ours", list(EXPLICIT), EXPLICIT, ours, errors, repeat=2,
                            log=lambda r: print(r, flush=True))
    rows += _c_rows(errors)
    notes = [
        "Error: max over 401 saves (0.05 s apart) of the largest coordinate error of B0 [m] against the "
        "one-coordinate parallelogram model (SciPy DOP853, 1e-13). Target: the benchmark specification's 1e-3 m.",
        "MuJoCo C runs in its native loop (`mujoco.rollout`, calling thread); its 40 loops are soft (`solref` 2 dt), "
        "so its error falls about linearly with dt (7e-4 m at dt 1e-3, 1.3e-4 m at 2.5e-4 in a Python-stepped check) "
        "and it cannot reach 1e-6 m at any affordable step. Ours: `simulate_mechanism` as a user calls it (compile "
        "cached, listed separately), timed saving the end state; 81 rows, least-squares multipliers.",
    ]
    res = _wp.finish(NAME, "N-four-bar, N = 40 (IFToMM A02)", T_END, TARGET, "m", "B0 over 20 s",
                     {"what": "the one-coordinate parallelogram model"}, rows, started, notes, key="max_error")
    return _wp.finish_without_mjx(res, started)


markdown = _wp.markdown_without_mjx


def main() -> dict:
    return _wp.main(run, markdown)


if __name__ == "__main__":
    main()
