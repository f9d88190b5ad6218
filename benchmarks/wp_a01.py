"""Work against precision for the IFToMM A01 pendulum over its full 2000 s (845 periods; float64, CPU): ours against
a MuJoCo C twin (a hinge about z at the origin with the 1 kg bob, gravity along -y).

Error = the largest distance error of the bob over the benchmark's 4000 output steps (every 0.5 s) against the
exact solution in Jacobi elliptic functions (SciPy), the same measure for every row; the benchmark's high precision
is 1e-3 m, its low 1e-1 m.

* ours: Tsit5, Dopri5, Dopri8 over a sweep of rtol (atol = rtol / 100), through the public entry point;
* MuJoCo C twin: RK4 through ``mujoco.rollout`` over a sweep of fixed steps up to the coarsest that still meets the
  target. MuJoCo needs a positive inertia for a moving body: the bob carries 1e-12 kg m^2 about its centre
  (a relative change of 1e-12 in the pendulum's moment, far below every error here).

Run: ``python -m benchmarks.wp_a01``.
"""

from __future__ import annotations


import jax.numpy as jnp
import mujoco
import numpy as np
from scipy.special import ellipj, ellipk

from particlesim.scenes.iftomm import A01, a01_pendulum

from . import _wp
from ._native import sampled

NAME = "wp_a01"
T_END = A01["t_end"]
TARGET = 1e-3  # m: the benchmark's high precision
TS = np.linspace(0.0, T_END, A01["outputs"] + 1)
# 1-2-5 steps where the cheapest runs meet the target (MuJoCo's time is interpolated to it), decades beyond
RTOLS = (1e-6, 1e-7, 1e-8, 5e-9, 2e-9, 1e-9, 5e-10, 2e-10, 1e-10, 1e-11)
EXPLICIT = {"tsit5": RTOLS, "dopri5": RTOLS, "dopri8": RTOLS}
C_RK4_STEPS = (2e-2, 1e-2, 5e-3, 2.5e-3, 1e-3)
SCENE = _wp.Scene(NAME, "Simple pendulum (IFToMM A01)", T_END, TARGET, "m", "bob over 2000 s", key="max_error")
NOTES = (
    "Error: max over the 4001 outputs (0.5 s apart) of the bob's largest coordinate error [m] against the exact "
    "solution (Jacobi elliptic functions); the benchmark's high precision is 1e-3 m.",
    f"{_wp.NATIVE_LOOP}; {_wp.INTERPOLATED}. {_wp.OURS_PUBLIC}.",
)


def exact(ts):
    """The bob ``(x, y)`` released at rest from the horizontal: sin(theta/2) = k sn(K - w t | k^2), k^2 = 1/2."""
    m = 0.5
    sn = ellipj(ellipk(m) - np.sqrt(A01["g"] / A01["length"]) * ts, m)[0]
    th = 2 * np.arcsin(np.sqrt(m) * sn)
    return A01["length"] * np.stack([np.sin(th), -np.cos(th)], axis=1)


def twin_xml(dt: float) -> str:
    """The MuJoCo twin: the link along +x at qpos = 0 (the spec's start), RK4 at step ``dt``."""
    return f"""<mujoco model="iftomm_a01">
  <option timestep="{dt!r}" integrator="RK4" gravity="0 {-A01['g']!r} 0"/>
  <worldbody>
    <body name="bob">
      <joint name="pin" type="hinge" axis="0 0 1" pos="0 0 0"/>
      <inertial pos="{A01['length']!r} 0 0" mass="{A01['mass']!r}" diaginertia="1e-12 1e-12 1e-12"/>
      <site name="P1" pos="{A01['length']!r} 0 0"/>
    </body>
  </worldbody>
</mujoco>"""


def _ours(mech, x0):
    sl = mech.free_slice("P1")
    return _wp.public_runner(mech, x0, jnp.zeros_like(x0), T_END, TS, lambda s: np.asarray(s.q[:, sl][:, :2]),
                             max_steps=4_000_000)


def _c_rows(errors) -> list[dict]:
    def make(dt):
        m = mujoco.MjModel.from_xml_string(twin_xml(dt))
        site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "P1")
        return sampled(m, None, T_END, dt, TS[1] - TS[0], lambda mm, dd: dd.site_xpos[site][:2].copy())

    return _wp.sweep_rollout("MuJoCo C twin RK4 (mujoco.rollout)", C_RK4_STEPS, make, errors, T_END,
                             setting=lambda dt: f"dt {dt:g}")


def _build():
    mech, x0 = a01_pendulum()
    return _ours(mech, jnp.asarray(x0)), exact(TS), {"what": "exact solution (Jacobi elliptic functions)"}


run, markdown, main = _wp.against_twin(SCENE, _build, _c_rows, EXPLICIT, NOTES)


if __name__ == "__main__":
    main()
