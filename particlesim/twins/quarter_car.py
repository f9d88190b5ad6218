"""The MuJoCo C twin of the quarter car (:func:`particlesim.scenes.quarter_car.quarter_car`): same bodies, same
assumed geometry, joints in MuJoCo's own terms.

* tree: chassis (slide z) -> lower arm (hinge x at 2) -> knuckle (ball at 6) -> wheel (hinge y at 10); chassis ->
  upper arm (hinge x at 4);
* loops: the upper ball joint is an equality ``connect`` (8 on the upper arm = 8 on the knuckle); the steering rod
  is a spatial tendon SA-TI whose length an equality holds at its assembly value. Both are soft in MuJoCo; they are stiffened
  (``solref`` time constant ``SOLREF_TC``, ``solimp`` 0.9999) as far as MuJoCo allows at the step used;
* the suspension spring-damper is a spatial tendon with stiffness, damping and spring length (the same law);
* the one-sided tyre is not expressible by MuJoCo elements: a passive-force callback evaluates the same law at
  every RK4 stage (``mjcb_passive``), so it is not held over a step (see docs/twins.md).
"""

from __future__ import annotations

import mujoco
import numpy as np

from ..scenes import quarter_car as qc
from .callbacks import python_tyre

__all__ = ["twin_xml", "twin_rollout", "SOLREF_TC"]

SOLREF_TC = 2e-4  # s; MuJoCo clamps the constraint time constant to >= 2 dt


def _v(x) -> str:
    return " ".join(f"{float(c):.17g}" for c in x)


def twin_xml(timestep: float = 1e-4, spring: dict | None = None) -> str:
    """MJCF text of the twin (gravity -z, RK4, no contacts); ``spring``: overrides of :data:`~..scenes.quarter_car.
    SPRING` (as ``quarter_car(spring=...)``)."""
    spring = {**qc.SPRING, **(spring or {})}
    com = {name: qc._com(name) for name in qc.TABLE1}
    p = {i: qc._p(i) for i in range(1, 11)}
    ex = qc._extra()
    body = qc.bodies()

    def inertial(name):
        b = body[name]
        d = np.diag(np.asarray(b.inertia))
        return f'<inertial pos="0 0 0" mass="{float(b.mass)!r}" diaginertia="{_v(d)}"/>'

    sol = f'solref="{SOLREF_TC} 1" solimp="0.9999 0.9999 0.001 0.5 2"'
    return f"""
<mujoco model="quarter car twin">
  <compiler angle="radian" balanceinertia="false" inertiafromgeom="false"/>
  <option timestep="{timestep}" integrator="RK4" gravity="0 0 -9.81"><flag contact="disable"/></option>
  <worldbody>
    <body name="chassis" pos="{_v(com['chassis'])}">
      <joint name="slide" type="slide" axis="0 0 1"/>
      {inertial('chassis')}
      <site name="TI" pos="{_v(ex['TI'] - com['chassis'])}"/>
      <site name="SC" pos="{_v(ex['SC'] - com['chassis'])}"/>
      <body name="lower_arm" pos="{_v(com['lower_arm'] - com['chassis'])}">
        <joint name="lower" type="hinge" axis="1 0 0" pos="{_v(p[2] - com['lower_arm'])}"/>
        {inertial('lower_arm')}
        <site name="SL" pos="{_v(ex['SL'] - com['lower_arm'])}"/>
        <body name="knuckle" pos="{_v(com['knuckle'] - com['lower_arm'])}">
          <joint name="ball" type="ball" pos="{_v(p[6] - com['knuckle'])}"/>
          {inertial('knuckle')}
          <site name="SA" pos="{_v(ex['SA'] - com['knuckle'])}"/>
          <body name="wheel" pos="{_v(com['wheel'] - com['knuckle'])}">
            <joint name="spin" type="hinge" axis="0 1 0" pos="0 0 0"/>
            {inertial('wheel')}
            <site name="centre" pos="0 0 0"/>
          </body>
        </body>
      </body>
      <body name="upper_arm" pos="{_v(com['upper_arm'] - com['chassis'])}">
        <joint name="upper" type="hinge" axis="1 0 0" pos="{_v(p[4] - com['upper_arm'])}"/>
        {inertial('upper_arm')}
      </body>
    </body>
  </worldbody>
  <tendon>
    <spatial name="spring" stiffness="{spring['stiffness']}" damping="{spring['damping']}"
             springlength="{spring['free_length']}"><site site="SL"/><site site="SC"/></spatial>
    <spatial name="steering"><site site="SA"/><site site="TI"/></spatial>
  </tendon>
  <equality>
    <connect body1="upper_arm" body2="knuckle" anchor="{_v(p[8] - com['upper_arm'])}" {sol}/>
    <tendon tendon1="steering" polycoef="0 0 0 0 0" {sol}/>
  </equality>
</mujoco>"""


def twin_rollout(ts: np.ndarray, timestep: float = 1e-4) -> dict[str, np.ndarray]:
    """Run the twin from rest with MuJoCo C RK4; return chassis-centre z, wheel-centre z and loop residuals at
    ``ts`` (a uniform grid whose spacing is a multiple of ``timestep``)."""
    m = mujoco.MjModel.from_xml_string(twin_xml(timestep))
    d = mujoco.MjData(m)
    site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "centre")
    ground = float(qc._p(10)[2]) - qc.TYRE["radius"]
    mujoco.set_mjcb_passive(python_tyre(site, (0.0, 0.0, 1.0), ground, qc.TYRE["radius"], qc.TYRE["stiffness"],
                                          qc.TYRE["damping"]))
    try:
        mujoco.mj_forward(m, d)
        per = int(round((ts[1] - ts[0]) / timestep))
        chassis, wheel, loop = [], [], []
        kb = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "knuckle")
        ub = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "upper_arm")
        a_upper = qc._p(8) - qc._com("upper_arm")
        a_knuckle = qc._p(8) - qc._com("knuckle")
        for k in range(len(ts)):
            mujoco.mj_kinematics(m, d)  # after an RK4 mj_step, xpos is not the kinematics of the new qpos
            chassis.append(d.xpos[mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "chassis"), 2])
            wheel.append(d.site_xpos[site, 2])
            pu = d.xpos[ub] + d.xmat[ub].reshape(3, 3) @ a_upper
            pk = d.xpos[kb] + d.xmat[kb].reshape(3, 3) @ a_knuckle
            loop.append(np.linalg.norm(pu - pk))
            if k + 1 < len(ts):
                for _ in range(per):
                    mujoco.mj_step(m, d)
    finally:
        mujoco.set_mjcb_passive(None)
    return {"chassis_z": np.asarray(chassis), "wheel_z": np.asarray(wheel), "loop_residual": np.asarray(loop)}
