"""MuJoCo (C) and MJX twins of a URDF tree robot, and the joint map between MuJoCo's order and ours.

MuJoCo reads URDF directly. We hand it the URDF with visual and collision elements removed (meshes are not
shipped) and a ``<mujoco><compiler .../></mujoco>`` block that keeps every link as its own body
(``fusestatic="false"``) and every inertia exactly as written (``balanceinertia="false"``; MuJoCo stores the
inertia diagonalised, as principal moments ``body_inertia`` and axes ``body_iquat``, which is a change of frame,
not of value). Then, through ``mujoco.MjSpec``, the twin is made a pure rigid tree: no joint limits, no
contacts, no damping, friction loss, armature or springs unless asked, and the requested gravity, integrator and
timestep.

Joint order: MuJoCo numbers joints depth first over its body tree, which for a URDF need not be the order of the
URDF's movable joints that ``particlesim.tree`` uses. :class:`JointMap` maps by joint name.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from pathlib import Path

import mujoco
import numpy as np

from ..io.urdf import read_urdf

__all__ = ["urdf_for_mujoco", "mujoco_spec", "mujoco_model", "mjx_model", "JointMap"]

_INTEGRATORS = {
    "euler": mujoco.mjtIntegrator.mjINT_EULER,
    "rk4": mujoco.mjtIntegrator.mjINT_RK4,
    "implicit": mujoco.mjtIntegrator.mjINT_IMPLICIT,
    "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST,
}


def urdf_for_mujoco(urdf: str | Path) -> str:
    """URDF text (or a path to it) stripped of visual/collision elements, with a MuJoCo compiler block.

    Raises ``ParseError`` if the text is not a URDF ``<robot>``.
    """
    _, root = read_urdf(urdf)  # one reader for both twins: the same errors for the same files
    for link in root.iter("link"):
        for tag in ("visual", "collision"):
            for el in link.findall(tag):
                link.remove(el)
    for el in root.findall("mujoco"):
        root.remove(el)
    mj = ET.Element("mujoco")
    ET.SubElement(
        mj, "compiler", discardvisual="true", fusestatic="false", balanceinertia="false", strippath="true"
    )
    root.insert(0, mj)
    return ET.tostring(root, encoding="unicode")


def _per_joint(value: float | Mapping[str, float] | None, name: str) -> float:
    if value is None:
        return 0.0
    if isinstance(value, Mapping):
        return float(value.get(name, 0.0))
    return float(value)


def mujoco_model(urdf: str | Path, **kwargs) -> mujoco.MjModel:
    """Compile a URDF into a ``mujoco.MjModel`` that is the same rigid tree as ``particlesim.io.load_urdf``;
    ``mujoco_spec(urdf, **kwargs).compile()`` (see :func:`mujoco_spec` for the arguments)."""
    return mujoco_spec(urdf, **kwargs).compile()


def mujoco_spec(
    urdf: str | Path,
    *,
    gravity: Sequence[float] = (0.0, -9.81, 0.0),
    timestep: float = 1e-3,
    integrator: str = "rk4",
    damping: float | Mapping[str, float] | None = None,
    armature: float | Mapping[str, float] | None = None,
) -> mujoco.MjSpec:
    """The ``mujoco.MjSpec`` of a URDF's MuJoCo twin (edit it, e.g. with ``mujoco.sysid`` modifiers, then compile).

    Args:
        urdf: path or URDF text.
        gravity: (3,) in the URDF world frame (the Krang data use (0, -9.81, 0)).
        timestep: integrator step (s).
        integrator: "rk4" (default; the one to compare against at tight accuracy), "euler", "implicit",
            "implicitfast".
        damping, armature: viscous joint damping (N m s/rad) and armature (reflected rotor inertia, kg m²),
            one value for every joint or a mapping joint name -> value; default none.
    """
    try:
        integ = _INTEGRATORS[integrator.lower()]
    except KeyError:
        raise ValueError(f"unknown MuJoCo integrator {integrator!r}; choose one of {sorted(_INTEGRATORS)}") from None
    spec = mujoco.MjSpec.from_string(urdf_for_mujoco(urdf))
    for j in spec.joints:
        j.limited = mujoco.mjtLimited.mjLIMITED_FALSE
        j.actfrclimited = mujoco.mjtLimited.mjLIMITED_FALSE
        j.frictionloss = 0.0
        # mujoco 4 stores stiffness and damping as 3 polynomial coefficients; the first is the linear one.
        j.stiffness = np.zeros(3)
        j.damping = np.array([_per_joint(damping, j.name), 0.0, 0.0])
        j.armature = _per_joint(armature, j.name)
    names = {j.name for j in spec.joints}
    for arg, value in (("damping", damping), ("armature", armature)):
        if isinstance(value, Mapping) and not set(value) <= names:
            raise ValueError(f"{arg} names joints not in the model: {sorted(set(value) - names)}")
    spec.option.gravity = np.asarray(gravity, dtype=float)
    spec.option.timestep = float(timestep)
    spec.option.integrator = integ
    spec.option.disableflags |= int(mujoco.mjtDisableBit.mjDSBL_CONTACT) | int(mujoco.mjtDisableBit.mjDSBL_LIMIT)
    return spec


def mjx_model(m: mujoco.MjModel):
    """The MJX counterpart of ``m`` (``mjx.put_model``). Float64 requires ``jax_enable_x64`` (set on
    ``import particlesim``); this function checks it and raises otherwise."""
    import jax
    from mujoco import mjx

    if not jax.config.jax_enable_x64:
        raise RuntimeError("MJX twin in float64 needs jax_enable_x64 (import particlesim first)")
    mx = mjx.put_model(m)
    if mx.body_mass.dtype != np.float64:
        raise RuntimeError(f"MJX model came out in {mx.body_mass.dtype}, expected float64")
    return mx


class JointMap:
    """Permutation between our joint order (``names``, URDF movable-joint order) and MuJoCo's qpos/qvel order.

    Only one-dof joints (hinge, slide) are supported, which is what URDF revolute/continuous/prismatic give.
    ``idx[i]`` is MuJoCo's dof address of our joint i, so ``x_ours = x_mj[idx]`` and
    ``M_ours = M_mj[np.ix_(idx, idx)]``.
    """

    def __init__(self, m: mujoco.MjModel, names: Sequence[str]):
        idx = []
        for n in names:
            jid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, n)
            if jid < 0:
                raise ValueError(f"joint {n!r} is not in the MuJoCo model")
            if int(m.jnt_type[jid]) not in (int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)):
                raise ValueError(f"joint {n!r} is not a one-dof joint in the MuJoCo model")
            if m.jnt_qposadr[jid] != m.jnt_dofadr[jid]:
                raise ValueError(f"joint {n!r}: qpos and dof addresses differ (free/ball joints present)")
            idx.append(int(m.jnt_dofadr[jid]))
        if len(idx) != m.nv:
            raise ValueError(f"{len(idx)} joint names for a MuJoCo model with nv = {m.nv}")
        self.names = tuple(names)
        self.idx = np.asarray(idx)
        self.inv = np.argsort(self.idx)

    def from_mujoco(self, x_mj):
        """(..., nv) in MuJoCo order -> (..., n) in ours."""
        return x_mj[..., self.idx]

    def to_mujoco(self, x_ours):
        """(..., n) in our order -> (..., nv) in MuJoCo's."""
        return x_ours[..., self.inv]

    def matrix_from_mujoco(self, a_mj):
        """(nv, nv) in MuJoCo order -> (n, n) in ours."""
        return a_mj[np.ix_(self.idx, self.idx)]
