"""The MuJoCo C twins' passive-force callbacks: the compiled tyre (what ``mujoco.rollout`` runs in the benchmarks)
against the Python reference law."""

import numpy as np
import pytest


def test_compiled_tyre_callback_equals_python_callback():
    """The quarter-car MuJoCo C twin with its tyre as a compiled ``mjcb_passive`` (benchmarks, ``mujoco.rollout``)
    against the same twin with the Python callback of :mod:`particlesim.twins.quarter_car`."""
    mujoco = pytest.importorskip("mujoco")
    from mujoco import rollout

    from particlesim.twins import callbacks as mjcb
    from particlesim.scenes import quarter_car as qc
    from particlesim.twins.quarter_car import twin_rollout, twin_xml

    dt, ts = 1e-3, np.linspace(0.0, 0.5, 6)
    python = twin_rollout(ts, dt)["chassis_z"]
    m = mujoco.MjModel.from_xml_string(twin_xml(dt))
    d = mujoco.MjData(m)
    site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "centre")
    mjcb.install_tyres([(site, (0, 0, 1), float(qc._p(10)[2]) - qc.TYRE["radius"], qc.TYRE["radius"],
                         qc.TYRE["stiffness"], qc.TYRE["damping"])])
    try:
        mujoco.mj_forward(m, d)
        spec = mujoco.mjtState.mjSTATE_FULLPHYSICS
        state0 = np.zeros((1, mujoco.mj_stateSize(m, spec)))
        mujoco.mj_getState(m, d, state0[0], spec)
        states, _ = rollout.Rollout(nthread=1).rollout(m, d, state0, nstep=500)
    finally:
        mjcb.uninstall()
    chassis = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "chassis")
    native = []
    for k in (0, 100, 200, 300, 400, 500):
        d.qpos[:] = state0[0, 1:1 + m.nq] if k == 0 else states[0, k - 1, 1:1 + m.nq]
        mujoco.mj_kinematics(m, d)
        native.append(d.xpos[chassis, 2])
    np.testing.assert_allclose(native, python, rtol=0, atol=1e-12)
