"""MuJoCo C twin of the IFToMM A02 N-four-bar (:func:`particlesim.scenes.iftomm.a02_four_bar`).

In MuJoCo's own terms: N + 1 cranks hinged to the ground at ``A{i}`` (hinge z), coupler ``i`` hinged to the top of
crank ``i - 1`` and joined to the top of crank ``i`` by an equality ``connect`` (N loops, soft in MuJoCo; stiffened
as far as it allows, ``solref`` 2 dt, ``solimp`` 0.9999, docs/twins.md). Uniform 1 m, 1 kg rods (MuJoCo needs a
positive axial moment: 1e-6 kg m², which planar motion never uses). Gravity along −y; cranks start at −1 rad/s,
couplers translating (+1 rad/s relative to their crank). RK4. Soft loops let the linkage pass the flat positions
(MuJoCo's constraint solve is regularised).
"""

from __future__ import annotations

import mujoco
import numpy as np

from ..scenes.iftomm import A02

__all__ = ["twin_xml", "twin_model", "b0_observer"]

_SOLIMP = "0.9999 0.9999 0.001 0.5 2"
_AXIAL = 1e-6


def twin_xml(n: int = A02["n"], timestep: float = 1e-3, g: float = A02["g"]) -> str:
    j = 1.0 / 12.0
    sol = f'solref="{2 * timestep!r} 1" solimp="{_SOLIMP}"'
    crank = f'<inertial pos="0 0.5 0" mass="1" diaginertia="{j!r} {_AXIAL!r} {j!r}"/>'
    coupler = f'<inertial pos="0.5 0 0" mass="1" diaginertia="{_AXIAL!r} {j!r} {j!r}"/>'
    bodies = []
    for i in range(n + 1):
        inner = "" if i == n else (f'<body name="coupler{i + 1}" pos="0 1 0"><joint type="hinge" axis="0 0 1"/>'
                                   f'{coupler}</body>')
        site = '<site name="B0" pos="0 1 0"/>' if i == 0 else ""
        bodies.append(f'<body name="crank{i}" pos="{i} 0 0"><joint type="hinge" axis="0 0 1"/>{crank}{site}'
                      f'{inner}</body>')
    eq = "".join(f'<connect body1="coupler{i}" body2="crank{i}" anchor="1 0 0" {sol}/>' for i in range(1, n + 1))
    return f"""<mujoco>
  <option gravity="0 {-g!r} 0" timestep="{timestep!r}" integrator="RK4"><flag contact="disable"/></option>
  <worldbody>{''.join(bodies)}</worldbody>
  <equality>{eq}</equality>
</mujoco>"""


def twin_model(n: int = A02["n"], timestep: float = 1e-3):
    """``(model, data)`` at the initial state (cranks at -1 rad/s, couplers translating), after ``mj_forward``."""
    model = mujoco.MjModel.from_xml_string(twin_xml(n, timestep))
    data = mujoco.MjData(model)
    for jnt in range(model.njnt):
        name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, model.jnt_bodyid[jnt])
        data.qvel[model.jnt_dofadr[jnt]] = -1.0 if name.startswith("crank") else 1.0
    mujoco.mj_forward(model, data)
    return model, data


def b0_observer(model):
    """``observe(model, data) -> (2,)``: B0's x, y."""
    site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "B0")
    return lambda m, d: np.array(d.site_xpos[site][:2])
