"""MJX twins of the pendulum chains and of the quarter car, against MuJoCo C and against ours (float64).

Error sources, each measured in the test rather than assumed:

* RK4's truncation error at step ``dt``: Richardson's estimate from MuJoCo C at ``dt`` and ``dt/2``,
  ``(16/15) |x_dt - x_dt/2|`` (as in ``test_chains.py``).
* Round-off: MJX and MuJoCo C integrate the same equations in a different order of operations; over ``k`` steps
  it accumulates to about ``k * ROUNDOFF_ULPS * eps * scale`` (``scale`` = the largest coordinate, metres).
* Soft loops (quarter car only): MuJoCo's ``connect`` and tendon equalities are regularised, so the twins' chassis
  carries an error of the order of their measured loop residual; MJX 3.17 omits the ``J̇ v`` term of ``connect``
  rows (docs/twins.md), so MJX's loop residual, and with it its error, is larger than MuJoCo C's.

``SAFETY`` is the same factor of the existing twin tests; nothing here is tuned to the results.
"""

import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

from particlesim.mechanism import simulate_mechanism
from particlesim.scenes import quarter_car as qc
from particlesim.scenes.chains import chain_geometry, chain_mechanism
from particlesim.twins.chains import chain_mjcf
from particlesim.twins.quarter_car import SOLREF_TC, twin_rollout, twin_xml

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository root, for ``benchmarks``
from particlesim.twins.mjx import chain_rollout, quarter_car_rollout  # noqa: E402

SAFETY = 3.0
ROUNDOFF_ULPS = 64.0  # per step and coordinate, for the reordered float64 arithmetic of two RK4 implementations
EPS = float(np.finfo(np.float64).eps)

CHAIN_T, CHAIN_DT, CHAIN_PER = 1.0, 1e-3, 100
CHAIN_TS = np.linspace(0.0, CHAIN_T, int(round(CHAIN_T / (CHAIN_DT * CHAIN_PER))) + 1)
CHAIN_FLOOR = 1e-10  # m: ours (Dopri8, rtol 1e-12) is itself exact only to about this

QC_T, QC_DT, QC_PER = 2.0, 5e-4, 20
QC_TS = np.linspace(0.0, QC_T, int(round(QC_T / (QC_DT * QC_PER))) + 1)


def _ours(mech, x0, ts, atol):
    run = jax.jit(lambda m, x: simulate_mechanism(m, x, jnp.zeros_like(x), 0.0, float(ts[-1]), solver="dopri8",
                                                  rtol=1e-12, atol=atol, saveat_ts=ts))
    sol = run(mech, jnp.asarray(x0))
    assert bool(sol.ok)
    return sol


def _mujoco_c_chain(xml, dt, per, n_save):
    """MuJoCo C RK4; sites recomputed from the state (after ``mj_step`` MuJoCo C 4.0's ``site_xpos`` is not the
    kinematics of the new ``qpos``: 4.8e-9 m off after 1 s on the revolute chain)."""
    m = mujoco.MjModel.from_xml_string(xml.replace(f'timestep="{CHAIN_DT}"', f'timestep="{dt}"'))
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    out = [d.site_xpos.copy()]
    for _ in range(n_save - 1):
        for _ in range(per):
            mujoco.mj_step(m, d)
        mujoco.mj_kinematics(m, d)
        out.append(d.site_xpos.copy())
    return np.asarray(out)


@pytest.mark.slow
@pytest.mark.parametrize("joint", ["revolute", "spherical"])
def test_mjx_chain_matches_mujoco_c_and_ours(joint):
    """Revolute: MJX and MuJoCo C run the same RK4 and must agree to round-off. Spherical: MJX 3.17 advances a ball
    joint's quaternion by body-frame stage velocities without the dexp correction, so its RK4 is second order
    there (measured: the error falls 4x per halving) while MuJoCo C 4.0 stays fourth order; each twin is then
    read against its own step-halving estimate (order >= 2 assumed for MJX: ``(4/3)|x_dt - x_dt/2|``)."""
    n = 3
    geom = chain_geometry(n, joint, seed=n)
    mech, x0 = chain_mechanism(geom)
    xml, names = chain_mjcf(geom, timestep=CHAIN_DT)
    fn, _, d0 = chain_rollout(mujoco.MjModel.from_xml_string(xml), len(CHAIN_TS))
    half_model = mujoco.MjModel.from_xml_string(xml.replace(f'timestep="{CHAIN_DT}"', f'timestep="{CHAIN_DT / 2}"'))
    mjx_dt = np.asarray(fn(mjx.put_model(mujoco.MjModel.from_xml_string(xml)), d0, CHAIN_PER))
    mjx_half = np.asarray(fn(mjx.put_model(half_model), d0, 2 * CHAIN_PER))
    c_dt = _mujoco_c_chain(xml, CHAIN_DT, CHAIN_PER, len(CHAIN_TS))
    c_half = _mujoco_c_chain(xml, CHAIN_DT / 2, 2 * CHAIN_PER, len(CHAIN_TS))
    sol = _ours(mech, x0, CHAIN_TS, atol=1e-13)

    sites = [i for i, nm in enumerate(names) if mech.index(nm) in mech.free]
    cols = [mech.free.index(mech.index(names[i])) for i in sites]
    ours = np.asarray(sol.q).reshape(len(CHAIN_TS), -1, 3)[:, cols]
    steps = int(round(CHAIN_T / CHAIN_DT))
    roundoff = steps * ROUNDOFF_ULPS * EPS * np.abs(c_dt).max()
    est_c = 16.0 / 15.0 * np.abs(c_dt[:, sites] - c_half[:, sites]).max()
    est_mjx = 4.0 / 3.0 * np.abs(mjx_dt[:, sites] - mjx_half[:, sites]).max()
    mjx_vs_c = np.abs(mjx_dt - c_dt).max()
    mjx_vs_ours = np.abs(mjx_dt[:, sites] - ours).max()
    mjx_half_vs_ours = np.abs(mjx_half[:, sites] - ours).max()
    c_vs_ours = np.abs(c_dt[:, sites] - ours).max()
    print(f"{joint} N={n}, dt {CHAIN_DT:g}, {CHAIN_T:g} s: |MJX - C| = {mjx_vs_c:.1e} (round-off bound "
          f"{roundoff:.1e}); |MJX - ours| = {mjx_vs_ours:.1e} (dt/2: {mjx_half_vs_ours:.1e}), |C - ours| = "
          f"{c_vs_ours:.1e}; estimates: MJX {est_mjx:.1e}, C {est_c:.1e}")
    if joint == "revolute":
        assert mjx_vs_c <= roundoff
    else:
        assert mjx_vs_c <= SAFETY * (est_mjx + est_c) + roundoff
    assert mjx_vs_ours <= SAFETY * est_mjx + CHAIN_FLOOR
    assert c_vs_ours <= SAFETY * est_c + CHAIN_FLOOR


def _chassis_height(mech, q):
    k = mech.point_index("centre")
    return np.asarray(jax.vmap(lambda x: mech.point_positions(mech.all_positions(x))[k, 2])(q))


@pytest.mark.slow
def test_mjx_quarter_car_matches_mujoco_c_and_ours():
    """MuJoCo clamps the twin's constraint time constant ``SOLREF_TC`` to ``>= 2 dt``: at ``QC_DT`` the loops are
    softer than at the C twin test's 1e-4 s, and both twins' errors are read against their own loop residuals."""
    m = mujoco.MjModel.from_xml_string(twin_xml(QC_DT))
    ground = float(qc._p(10)[2]) - qc.TYRE["radius"]
    fn, mx, d0 = quarter_car_rollout(m, len(QC_TS), ground=ground, tyre=qc.TYRE)
    mjx_chassis, _, mjx_loop = (np.asarray(a) for a in fn(mx, d0, QC_PER))
    coarse = twin_rollout(QC_TS, QC_DT)
    fine = twin_rollout(QC_TS, QC_DT / 2)
    mech, x0 = qc.quarter_car()
    ours = _chassis_height(mech, _ours(mech, x0, QC_TS, atol=1e-14).q)

    # The MJX residual function measures the same thing as the C twin's (independent code): at t = 0 both are 0.
    assert mjx_loop[0] <= 1e-12
    c_loop = coarse["loop_residual"].max()
    mjx_loop_max = mjx_loop.max()
    rk4 = 16.0 / 15.0 * np.abs(coarse["chassis_z"] - fine["chassis_z"]).max()
    c_vs_ours = np.abs(coarse["chassis_z"] - ours).max()
    mjx_vs_c = np.abs(mjx_chassis - coarse["chassis_z"]).max()
    mjx_vs_ours = np.abs(mjx_chassis - ours).max()
    print(f"quarter car, dt {QC_DT:g} (solref {SOLREF_TC:g} s clamped to {max(SOLREF_TC, 2 * QC_DT):g} s), "
          f"{QC_T:g} s: chassis |C - ours| = {c_vs_ours:.1e}, |MJX - C| = {mjx_vs_c:.1e}, |MJX - ours| = "
          f"{mjx_vs_ours:.1e}; loop residual C {c_loop:.1e}, MJX {mjx_loop_max:.1e}; RK4 estimate {rk4:.1e}")
    assert c_vs_ours <= SAFETY * (c_loop + rk4)
    assert mjx_vs_c <= SAFETY * (mjx_loop_max + c_loop)
    assert mjx_vs_ours <= SAFETY * (mjx_loop_max + rk4)
