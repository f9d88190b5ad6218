"""Work against precision for Andrews' squeezing mechanism (IFToMM A03), 0–0.03 s (float64, CPU): ours against
its MuJoCo C twin (:mod:`particlesim.twins.andrews`).

Error = the largest relative error of the seven joint angles at 0.03 s against the published 16-digit reference
(PSIDE, rtol = atol = 1e-14; ours at Dopri8 rtol 1e-13 lies 3e-10 from it). Only the end state is published, so
final and largest error coincide. The crank turns 2.5 times in 30 ms (up to 1.2e3 rad/s).

* ours: Tsit5, Dopri5, Dopri8 over a sweep of rtol (atol = rtol / 1000), through the public entry point; timed
  saving the end state, the angles unwrapped from a dense run of the same settings;
* MuJoCo C twin: RK4 through ``mujoco.rollout`` over a sweep of fixed steps; the loops are ``connect`` equalities
  stiffened to MuJoCo's limit (``solref`` 2 dt), the spring a tendon and the motor a constant actuator bias (all
  native elements, no callback). No MJX row (its ``connect`` rows omit J̇v, docs/twins.md).

Run: ``python -m benchmarks.wp_andrews``.
"""

from __future__ import annotations

import jax.numpy as jnp
import mujoco
import numpy as np

from particlesim.scenes import andrews as an
from particlesim.twins.andrews import twin_xml

from . import _wp
from ._native import Rollout, initial_state

NAME = "wp_andrews"
T_END = an.REFERENCE_T
TARGET = 1e-6  # relative, joint angles
TS = np.linspace(0.0, T_END, 1501)  # dense enough to unwrap the crank angle
# 1-2-5 steps where the cheapest runs meet the target (MuJoCo's time is interpolated to it), decades beyond
RTOLS = (1e-5, 5e-6, 2e-6, 1e-6, 5e-7, 2e-7, 1e-7, 1e-8, 1e-9, 1e-10)
EXPLICIT = {"tsit5": RTOLS, "dopri5": RTOLS, "dopri8": RTOLS}
C_RK4_STEPS = (4e-5, 2e-5, 1e-5, 5e-6, 2.5e-6)
SCALE = np.abs(an.REFERENCE_Q)
SCENE = _wp.Scene(NAME, "Andrews' squeezing mechanism (IFToMM A03)", T_END, TARGET, "rel.",
                  "joint angles at 0.03 s, relative")
NOTES = (
    "Error: max over the seven joint angles of |q - q_ref| / |q_ref| at 0.03 s, q_ref the published reference "
    "(the only published state; final and largest error coincide).",
    f"{_wp.NATIVE_LOOP}, every force a native element; its loops are soft (`solref` 2 dt), so its error falls as dt² "
    "rather than dt⁴. The ratios use its time interpolated (log-log) to exactly the target between the bracketing "
    f"steps. {_wp.OURS_PUBLIC}.",
)


def _ours(mech, x0):
    def angles(s):  # unwrapped over the dense saves; the error is taken at the end
        ang, _ = an.joint_angles(mech, np.asarray(s.q), np.asarray(s.qd))
        return ang[-1:] / SCALE

    return _wp.public_runner(mech, x0, jnp.zeros_like(x0), T_END, TS, angles, atol_ratio=1e-3, max_steps=1_000_000)


def _c_rows(errors) -> list[dict]:
    def make(dt):
        m = mujoco.MjModel.from_xml_string(twin_xml(dt))
        ro = Rollout(m, initial_state(m), int(round(T_END / dt)))
        sites = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, n) for n in "FEGH"]
        stride = max(1, int(round(2e-5 / dt)))

        def to_traj(states):
            obs = ro.trajectory(states, lambda mm, dd: dd.site_xpos[sites, :2], stride)
            pts = obs.reshape(len(obs), 4, 2)
            z = np.zeros_like(pts[:, 0])
            ang, _ = an.angles_from_points(*(pts[:, i] for i in range(4)), z, z, z, z)
            return ang[-1:] / SCALE

        return ro, to_traj

    return _wp.sweep_rollout("MuJoCo C twin RK4 (mujoco.rollout)", C_RK4_STEPS, make, errors, T_END,
                             setting=_wp.soft_setting)


def _build():
    mech, x0 = an.andrews_mechanism()
    return (_ours(mech, jnp.asarray(x0)), (an.REFERENCE_Q / SCALE)[None],
            {"what": "published reference (PSIDE, tol 1e-14)"})


run, markdown, main = _wp.against_twin(SCENE, _build, _c_rows, EXPLICIT, NOTES)


if __name__ == "__main__":
    main()
