"""Krang on fixed wheels under gravity and a time-dependent torque on both arms (the scene of
``benchmarks/wp_krang.py``, viscous friction on every joint = MuJoCo joint damping): ours against its MuJoCo C twin, with the torque added inside MuJoCo's dynamics by a
passive-force callback that reads the stage time ``d.time``, and against the MJX twin's RK4 loop.

* A torque evaluated at every RK4 stage keeps RK4 fourth order: the difference to ours must fall ~16× per halving
  of the step. A torque held over a step would make it first order (~2× per halving; docs/twins.md), so the
  ratio test fails if MuJoCo's stages did not see their own times.
* Richardson: RK4's error at dt is ``(16/15) |x_dt - x_dt/2|``; ours (Dopri8, rtol 1e-12, its own error ~1e-10
  rad, test_mujoco_twin.py) must sit within ``SAFETY`` times that of the dt run, plus ``OURS_FLOOR``.
"""

import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from particlesim.twins.urdf import JointMap, mjx_model

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # the repository root, for ``benchmarks``
from benchmarks import wp_krang  # noqa: E402

T1 = 1.0
TS = np.linspace(0.0, T1, 11)
DTS = (2e-3, 1e-3, 5e-4)
SAFETY = 2.0
OURS_FLOOR = 1e-9  # rad: Dopri8 at rtol 1e-12 on this scene (its step-halving in tolerance is ~1e-11)
ORDER4_RATIO = (12.0, 20.0)  # accepted range of e(dt) / e(dt/2) for a fourth-order method (exactly 16 asymptotically)
ROUNDOFF_ULPS = 64.0  # MJX vs MuJoCo C: same RK4 tableau, reordered float64 arithmetic; per step and coordinate, as
# in tests/twins/test_mjx_twins.py (bound = steps * ROUNDOFF_ULPS * eps * max |q|)


@pytest.fixture(scope="module")
def krang():
    model, q0, qd0, targs = wp_krang.scene()
    fn = jax.jit(lambda q0, qd0, r, a: _ours_at(model, targs, q0, qd0, r, a))
    sol_q = np.asarray(fn(jnp.asarray(q0), jnp.asarray(qd0), 1e-12, 1e-14))
    jm = JointMap(wp_krang.twin(1e-3), model.joint_names)
    return model, q0, qd0, targs, sol_q, jm


def _ours_at(model, targs, q0, qd0, rtol, atol):
    amp, omega, phase = (jnp.asarray(a) for a in targs)
    from particlesim.simulate import simulate
    from particlesim.tree import forward_dynamics

    s = simulate(forward_dynamics, model, q0, qd0, 0.0, T1, solver="dopri8", rtol=rtol, atol=atol,
                 control=lambda t, q, qd, p: wp_krang.torque(t, amp, omega, phase, jnp), saveat_ts=jnp.asarray(TS))
    return s.q


def _c(krang, dt, callback="torque"):
    model, q0, qd0, targs, _, jm = krang
    m = wp_krang.twin(dt)
    return wp_krang.mujoco_c_rollout(m, jm, q0, qd0, targs, TS, callback=callback)


def test_torque_twin_converges_at_fourth_order_to_ours(krang):
    ours = krang[4]
    runs = [_c(krang, dt) for dt in DTS]
    errs = [float(np.abs(r - ours).max()) for r in runs]
    ratios = [errs[k] / errs[k + 1] for k in range(len(errs) - 1)]
    est = 16.0 / 15.0 * float(np.abs(runs[-2] - runs[-1]).max())
    moved = float(np.abs(ours[-1] - ours[0]).max())
    driven = float(np.abs(_c(krang, DTS[-1], callback="none") - runs[-1]).max())
    print(f"|C RK4 - ours| at dt {DTS}: {[f'{e:.2e}' for e in errs]}, ratios {[f'{r:.2f}' for r in ratios]}; "
          f"Richardson estimate at dt {DTS[-2]:g}: {est:.2e}; largest joint motion {moved:.2f} rad; "
          f"effect of the torque {driven:.2e} rad")
    assert moved > 0.5 and driven > 1e-2  # the robot really moves and the torque really matters
    for r in ratios:
        assert ORDER4_RATIO[0] <= r <= ORDER4_RATIO[1]
    assert errs[-2] <= SAFETY * est + OURS_FLOOR
    assert errs[-1] <= SAFETY * est / 16.0 + OURS_FLOOR


@pytest.mark.slow  # compiling the MJX RK4 loop takes ~20-30 s on this CPU
def test_mjx_forced_rk4_equals_mujoco_c(krang):
    from particlesim.twins.mjx import forced_rk4_rollout

    model, q0, qd0, targs, ours, jm = krang
    dt = DTS[-1]
    m = wp_krang.twin(dt)
    tau = [jnp.asarray(jm.to_mujoco(np.asarray(a))) for a in targs]
    fn, _, d0 = forced_rk4_rollout(m, len(TS), lambda t: wp_krang.torque(t, *tau, xp=jnp))
    d0 = d0.replace(qpos=jnp.asarray(jm.to_mujoco(q0)), qvel=jnp.asarray(jm.to_mujoco(qd0)))
    with jax.numpy_rank_promotion("allow"):
        mjx_q = jm.from_mujoco(np.asarray(fn(mjx_model(m), d0, int(round((TS[1] - TS[0]) / dt)))))
    c_q = _c(krang, dt)
    roundoff = round(T1 / dt) * ROUNDOFF_ULPS * np.finfo(np.float64).eps * np.abs(c_q).max()
    print(f"|MJX - C| = {np.abs(mjx_q - c_q).max():.2e} (round-off bound {roundoff:.1e}), "
          f"|MJX - ours| = {np.abs(mjx_q - ours).max():.2e}")
    assert np.abs(mjx_q - c_q).max() <= roundoff


#: The compiled torque callback against the Python one, same model and steps (only the arithmetic order differs).
COMPILED_VS_PYTHON_ATOL = 1e-11  # rad over 1 s


def test_compiled_torque_callback_equals_python_callback(krang):
    """The benchmark's MuJoCo C rows run the torque as a compiled ``mjcb_passive`` inside ``mujoco.rollout``; it
    must equal the Python callback of the convergence tests above."""
    import mujoco

    from benchmarks._native import Rollout, initial_state
    from particlesim.twins import callbacks as mjcb

    model, q0, qd0, targs, _, jm = krang
    dt = 1e-3
    python = _c(krang, dt)
    m = wp_krang.twin(dt)
    d = mujoco.MjData(m)
    d.qpos[:], d.qvel[:] = jm.to_mujoco(np.asarray(q0)), jm.to_mujoco(np.asarray(qd0))
    ro = Rollout(m, initial_state(m, d), int(round(T1 / dt)))
    mjcb.install_sine_torques(*(jm.to_mujoco(np.asarray(a)) for a in targs))
    try:
        states = ro()
    finally:
        mjcb.uninstall()
    stride = int(round((TS[1] - TS[0]) / dt))
    compiled = jm.from_mujoco(ro.trajectory(states, lambda mm, dd: dd.qpos.copy(), stride))
    assert np.abs(python).max() > 0.1  # the robot moved
    np.testing.assert_allclose(compiled, python, atol=COMPILED_VS_PYTHON_ATOL, rtol=0)
    assert mujoco.get_mjcb_passive() is None
