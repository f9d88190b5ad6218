"""MuJoCo C twin of Bricard's linkage (:func:`particlesim.scenes.iftomm.a04_bricard`, IFToMM A04).

Same data in MuJoCo's own terms: an open chain ground -> rod1 -> ... -> rod5 of hinges at P1..P5 (axes y, z, x, y,
z), every body frame at its hinge with world axes so that ``qpos = 0`` is the assembled state; the sixth joint
(P6, axis x, to the ground) is two equality ``connect`` constraints, at P6 and one ``AXIS_OFFSET`` along the axis
(six rows for five conditions: MuJoCo's soft constraints take the redundancy as they come). Loops in MuJoCo are soft;
stiffened as far as it allows (``solref`` time constant 2 dt, ``solimp`` 0.9999; docs/twins.md). RK4.
"""

from __future__ import annotations

import mujoco
import numpy as np

from ..scenes.iftomm import _BRICARD_AXES, _BRICARD_P, A04, AXIS_OFFSET

__all__ = ["twin_xml", "twin_rollout"]

_SOLIMP = "0.9999 0.9999 0.001 0.5 2"


def _v(x) -> str:
    return " ".join(f"{float(c):.17g}" for c in x)


def twin_xml(timestep: float = 1e-4, g: float = A04["g"]) -> str:
    c = A04
    side, m, ell = c["side"], c["mass"], c["length"]
    axial, transverse = m * (2 * side**2) / 12, m * (ell**2 + side**2) / 12
    body = ""
    for i in range(5):
        p, q = _BRICARD_P[i], _BRICARD_P[i + 1]
        u = np.abs(q - p)
        diag = transverse * (1 - u) + axial * u
        origin = p - (_BRICARD_P[i - 1] if i else 0.0)
        body += (f'<body name="rod{i + 1}" pos="{_v(origin)}"><joint type="hinge" axis="{_v(_BRICARD_AXES[i])}"/>'
                 f'<inertial pos="{_v((q - p) / 2)}" mass="{m!r}" diaginertia="{_v(diag)}"/>'
                 f'<site name="P{i + 1}" pos="0 0 0"/>')
    body += "</body>" * 5
    sol = f'solref="{2 * timestep!r} 1" solimp="{_SOLIMP}"'
    p5, p6 = _BRICARD_P[4], _BRICARD_P[5]
    return f"""<mujoco>
  <option gravity="0 {-g!r} 0" timestep="{timestep!r}" integrator="RK4"><flag contact="disable"/></option>
  <worldbody>{body}</worldbody>
  <equality>
    <connect body1="rod5" body2="world" anchor="{_v(p6 - p5)}" {sol}/>
    <connect body1="rod5" body2="world" anchor="{_v(p6 - p5 + AXIS_OFFSET * _BRICARD_AXES[5])}" {sol}/>
  </equality>
</mujoco>"""


def twin_rollout(t_end: float, timestep: float = 1e-4, n_save: int = 11):
    """Step the twin from rest to ``t_end``; returns P3's positions ``(n_save, 3)`` at evenly spaced times and the
    largest loop residual (distance of rod 5's end from P6) over the saved states."""
    model = mujoco.MjModel.from_xml_string(twin_xml(timestep))
    data = mujoco.MjData(model)
    p3 = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "P3")
    p5 = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "P5")
    nstep = int(round(t_end / timestep))
    every = nstep // (n_save - 1)
    if every * (n_save - 1) != nstep:
        raise ValueError("t_end / timestep must be a multiple of n_save - 1")
    out, loop = [], 0.0
    rod5 = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "rod5")
    for k in range(nstep + 1):
        if k % every == 0:
            mujoco.mj_forward(model, data)
            out.append(data.site_xpos[p3].copy())
            end = data.site_xpos[p5] + data.xmat[rod5].reshape(3, 3) @ (_BRICARD_P[5] - _BRICARD_P[4])
            loop = max(loop, float(np.linalg.norm(end - _BRICARD_P[5])))
        if k < nstep:
            mujoco.mj_step(model, data)
    return np.asarray(out), loop
