"""MuJoCo C twin of the flyball governor (:func:`particlesim.scenes.iftomm.a05_flyball`, IFToMM A05).

A tree in MuJoCo's own terms: shaft (hinge z at the origin) carrying the slider (slide along z) and the two rods
(hinges along y at the shaft top, ±0.05 m); each rod body carries its ball. Every body frame is world-aligned at
its joint, so ``qpos = 0`` is the initial configuration; the shaft starts at 2π rad/s. The spring-dampers are
spatial tendons (stiffness, damping, spring length 0.5 m): native elements, no callback and no loop, so the twin is
exact up to its integrator. RK4.
"""

from __future__ import annotations

import mujoco
import numpy as np

from ..scenes.iftomm import A05, _prism, _shift

__all__ = ["twin_xml", "twin_rollout"]


def _v(x) -> str:
    return " ".join(f"{float(c):.17g}" for c in x)


def twin_xml(timestep: float = 1e-4, g: float = A05["g"]) -> str:
    c = A05
    rho, ell, a, off = c["density"], c["length"], c["section"], c["offset"]
    m_prism = rho * ell * a * a
    m_cube = rho * c["cube"] ** 3
    i_shaft = _prism(m_prism, (a, a, ell), np.eye(3))
    i_cube = _prism(m_cube, (c["cube"],) * 3, np.eye(3))
    al, s0 = c["alpha0"], c["s0"]
    rods = ""
    for i, sgn in ((1, 1.0), (2, -1.0)):
        d = np.array([sgn * np.cos(al), 0.0, -np.sin(al)])
        n = np.array([sgn * np.sin(al), 0.0, np.cos(al)])
        tip, mid = ell * d, ell / 2 * d  # relative to the pivot
        mass = m_prism + c["ball"]
        com = (m_prism * mid + c["ball"] * tip) / mass
        inertia = (_prism(m_prism, (ell, a, a), np.stack([d, (0.0, 1.0, 0.0), n]))
                   + m_prism * _shift(mid - com) + c["ball"] * _shift(tip - com))
        full = [inertia[0, 0], inertia[1, 1], inertia[2, 2], inertia[0, 1], inertia[0, 2], inertia[1, 2]]
        rods += (f'<body name="rod{i}" pos="{_v((sgn * off, 0.0, ell))}"><joint type="hinge" axis="0 1 0"/>'
                 f'<inertial pos="{_v(com)}" mass="{mass!r}" fullinertia="{_v(full)}"/>'
                 f'<site name="M{i}" pos="{_v(mid)}"/></body>')
    tendons = "".join(
        f'<spatial stiffness="{c["stiffness"]!r}" damping="{c["damping"]!r}" springlength="{c["free_length"]!r}">'
        f'<site site="B{i}"/><site site="M{i}"/></spatial>' for i in (1, 2))
    return f"""<mujoco>
  <option gravity="0 0 {-g!r}" timestep="{timestep!r}" integrator="RK4"><flag contact="disable"/></option>
  <worldbody>
    <body name="shaft"><joint type="hinge" axis="0 0 1"/>
      <inertial pos="0 0 {ell / 2!r}" mass="{m_prism!r}" diaginertia="{_v(np.diag(i_shaft))}"/>
      <body name="slider"><joint name="s" type="slide" axis="0 0 1"/>
        <inertial pos="0 0 {s0!r}" mass="{m_cube!r}" diaginertia="{_v(np.diag(i_cube))}"/>
        <site name="B1" pos="{off!r} 0 {s0!r}"/><site name="B2" pos="{-off!r} 0 {s0!r}"/>
      </body>
      {rods}
    </body>
  </worldbody>
  <tendon>{tendons}</tendon>
</mujoco>"""


def twin_rollout(t_end: float, timestep: float = 1e-4, n_save: int = 101):
    """Step the twin to ``t_end``; the slider height ``s`` at ``n_save`` evenly spaced times."""
    model = mujoco.MjModel.from_xml_string(twin_xml(timestep))
    data = mujoco.MjData(model)
    data.qvel[0] = A05["omega0"]
    nstep = int(round(t_end / timestep))
    every = nstep // (n_save - 1)
    if every * (n_save - 1) != nstep:
        raise ValueError("t_end / timestep must be a multiple of n_save - 1")
    out = []
    for k in range(nstep + 1):
        if k % every == 0:
            out.append(A05["s0"] + data.qpos[1])
        if k < nstep:
            mujoco.mj_step(model, data)
    return np.asarray(out)
