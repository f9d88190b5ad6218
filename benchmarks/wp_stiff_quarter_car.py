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

import jax.numpy as jnp

from particlesim.scenes import quarter_car as qc
from particlesim.twins import callbacks as mjcb

from . import _wp
from .quarter_car import T_END, _c_make, _ours, _setting  # the same runs, observations and twin

NAME = "wp_stiff_quarter_car"
TARGET = 1e-6  # m, chassis z, largest over the run
SPRING = {"stiffness": 10 * qc.SPRING["stiffness"]}
TYRE = {**qc.TYRE, "stiffness": 100 * qc.TYRE["stiffness"]}
REF = {"solver": "dopri8", "rtol": 1e-12}
RTOLS = (1e-3, 1e-4, 1e-5, 1e-6, 1e-7)
SWEEP = {"kvaerno5": RTOLS, "tsit5": RTOLS, "dopri5": RTOLS, "tsit5 PI(0.2, 0.4)": RTOLS, "bosh3 PI(0.2, 0.4)": RTOLS}
C_STEPS = (5e-3, 4e-3, 3e-3, 2e-3, 1e-3, 5e-4, 2.5e-4, 1e-4, 5e-5, 2e-5, 1e-5)
SCENE = _wp.Scene(NAME, "Quarter car, tyre 100x and spring 10x stiffer", T_END, TARGET, "m",
                  "|chassis z − reference|, largest over the run", key="max_error")
NOTES = (
    f"Tyre stiffness {TYRE['stiffness']:.3g} N/m (100x) and suspension spring {SPRING['stiffness']:.3g} N/m "
    "(10x): the wheel hop's rate rises about tenfold and holds explicit solvers to steps of a few 1e-4 s.",
    "Error: the largest |chassis z − reference| over 301 saves (10 ms apart); the target applies to it "
    "(`key = max_error`).",
    "The twins' loops are soft (MuJoCo clamps the `solref` time constant to ≥ 2 dt), so their error has a floor "
    "set by the loop compliance at each step.",
)


def scene():
    mech, x0 = qc.quarter_car(spring=SPRING, tyre={"stiffness": TYRE["stiffness"]})
    return mech, jnp.asarray(x0)


def _build():
    mech, x0 = scene()
    ours = _ours(mech, x0)
    ref_z, ref_steps, _ = ours(REF["solver"], REF["rtol"])
    return ours, ref_z, {"what": f"ours Dopri8 rtol {REF['rtol']:g} atol {REF['rtol'] * 1e-2:g}",
                         "steps": int(ref_steps)}


def _c_rows(errors) -> list[dict]:
    rows = []
    try:
        for integrator in ("RK4", "implicitfast"):
            rows += _wp.sweep_rollout(f"MuJoCo C twin {integrator} (mujoco.rollout)", C_STEPS,
                                      lambda dt, i=integrator: _c_make(dt, i, SPRING, TYRE), errors, T_END,
                                      setting=_setting)
    finally:
        mjcb.uninstall()
    return rows


def _twin(dt, row):
    """The twin at step ``dt`` with the integrator of the headline ``row`` (for the interleaved check)."""
    return _c_make(dt, "implicitfast" if "implicitfast" in row["method"] else "RK4", SPRING, TYRE)[0]


run, markdown, main = _wp.against_twin(SCENE, _build, _c_rows, SWEEP, NOTES, peer_make=_twin)


if __name__ == "__main__":
    main()
