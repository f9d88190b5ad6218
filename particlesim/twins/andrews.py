"""MuJoCo C twin of Andrews' squeezing mechanism (:mod:`particlesim.scenes.andrews`, IFToMM A03).

Same constants, joints in MuJoCo's own terms, plane x-y, no gravity:

* tree: ground -> crank (hinge z at O) -> link FE (hinge at F) -> at E, three branches: triangle BDE, link EG ->
  link GA, link EH -> link HA (hinges at E, G, H). Every body frame sits at its hinge with world axes at the
  initial angles, so ``qpos = 0`` is the assembled state;
* the two loops are closed by three equality ``connect`` constraints (B on BDE, A on GA and A on HA to the
  ground). They are soft in MuJoCo; stiffened as far as it allows (``solref`` time constant 2 dt, ``solimp``
  0.9999, see docs/twins.md);
* the spring D-C is a spatial tendon (stiffness c0, spring length l0); the motor a ``general`` actuator whose
  affine bias is the constant torque (no control input). Planar inertias ``ixx = iyy = izz = J``.
"""

from __future__ import annotations

import mujoco
import numpy as np

from ..scenes import andrews as an

__all__ = ["twin_xml", "twin_rollout"]

_SOLIMP = "0.9999 0.9999 0.001 0.5 2"


def _v(x) -> str:
    return " ".join(f"{float(c):.17g}" for c in np.append(x, 0.0)[:3])


def twin_xml(timestep: float = 1e-5, integrator: str = "RK4") -> str:
    c = an.CONST
    p = an._points(an.Q0)
    sol = f'solref="{2 * timestep!r} 1" solimp="{_SOLIMP}"'

    def inertial(k, frame):
        m, j = c[f"m{k}"], c[f"I{k}"]
        return f'<inertial pos="{_v(p[f"com{k}"] - p[frame])}" mass="{m!r}" diaginertia="{j!r} {j!r} {j!r}"/>'

    hinge = '<joint type="hinge" axis="0 0 1"/>'
    return f"""<mujoco>
  <option gravity="0 0 0" timestep="{timestep!r}" integrator="{integrator}"><flag contact="disable"/></option>
  <worldbody>
    <site name="C" pos="{_v(p['C'])}"/>
    <body name="crank" pos="0 0 0"><joint name="beta" type="hinge" axis="0 0 1"/>{inertial(1, 'O')}
      <site name="F" pos="{_v(p['F'])}"/>
      <body name="FE" pos="{_v(p['F'])}">{hinge}{inertial(2, 'F')}
        <site name="E" pos="{_v(p['E'] - p['F'])}"/>
        <body name="BDE" pos="{_v(p['E'] - p['F'])}">{hinge}{inertial(3, 'E')}
          <site name="D" pos="{_v(p['D'] - p['E'])}"/>
        </body>
        <body name="EG" pos="{_v(p['E'] - p['F'])}">{hinge}{inertial(4, 'E')}
          <body name="GA" pos="{_v(p['G'] - p['E'])}">{hinge}{inertial(5, 'G')}<site name="G" pos="0 0 0"/></body>
        </body>
        <body name="EH" pos="{_v(p['E'] - p['F'])}">{hinge}{inertial(6, 'E')}
          <body name="HA" pos="{_v(p['H'] - p['E'])}">{hinge}{inertial(7, 'H')}<site name="H" pos="0 0 0"/></body>
        </body>
      </body>
    </body>
  </worldbody>
  <equality>
    <connect body1="BDE" body2="world" anchor="{_v(p['B'] - p['E'])}" {sol}/>
    <connect body1="GA" body2="world" anchor="{_v(p['A'] - p['G'])}" {sol}/>
    <connect body1="HA" body2="world" anchor="{_v(p['A'] - p['H'])}" {sol}/>
  </equality>
  <tendon><spatial name="spring" stiffness="{c['c0']!r}" springlength="{c['l0']!r}">
    <site site="D"/><site site="C"/></spatial></tendon>
  <actuator><general name="motor" joint="beta" gaintype="fixed" gainprm="0" biastype="affine"
    biasprm="{c['mom']!r} 0 0"/></actuator>
</mujoco>"""


def twin_rollout(t_end: float = an.REFERENCE_T, timestep: float = 1e-5, n_save: int = 1501):
    """Step the twin (RK4) to ``t_end``; joint angles and rates ``(n_save, 7)`` at evenly spaced times (from the
    site positions and velocities, as :func:`particlesim.scenes.andrews.angles_from_points`)."""
    m = mujoco.MjModel.from_xml_string(twin_xml(timestep))
    d = mujoco.MjData(m)
    sites = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, n) for n in "FEGH"]
    nstep = int(round(t_end / timestep))
    every = nstep // (n_save - 1)
    if every * (n_save - 1) != nstep:
        raise ValueError("t_end / timestep must be a multiple of n_save - 1")
    pos, vel = [], []
    res = np.zeros(6)
    for k in range(nstep + 1):
        if k % every == 0:
            mujoco.mj_forward(m, d)
            pos.append(np.stack([d.site_xpos[s][:2].copy() for s in sites]))
            v = []
            for s in sites:
                mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_SITE, s, res, 0)
                v.append(res[3:5].copy())
            vel.append(np.stack(v))
        if k < nstep:
            mujoco.mj_step(m, d)
    pos, vel = np.asarray(pos), np.asarray(vel)
    return an.angles_from_points(*(pos[:, i] for i in range(4)), *(vel[:, i] for i in range(4)))
