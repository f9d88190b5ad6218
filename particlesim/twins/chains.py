"""MJCF twins of the pendulum chains of :mod:`particlesim.scenes.chains` (the same geometry: nested bodies at
their assembly poses, a site at every particle)."""

from __future__ import annotations

import numpy as np

from ..scenes.chains import LINK, ChainGeometry, _particles

__all__ = ["chain_mjcf"]


def chain_mjcf(g: ChainGeometry, *, timestep: float = 1e-4, gravity=(0.0, 0.0, -9.81)) -> tuple[str, list[str]]:
    """MJCF text of the same chain (nested bodies at their assembly poses, qpos = 0 there) with a site at every
    particle; returns the XML and the particle names in site order."""
    parts, _ = _particles(g)
    m, a, b, ell = LINK["mass"], LINK["a"], LINK["b"], LINK["length"]
    diag = m / 12 * np.array([b**2 + ell**2, a**2 + ell**2, a**2 + b**2])

    def quat(rm):
        from scipy.spatial.transform import Rotation

        x, y, z, w_ = Rotation.from_matrix(rm).as_quat()
        return f"{w_:.17g} {x:.17g} {y:.17g} {z:.17g}"

    def vec(v):
        return " ".join(f"{c:.17g}" for c in v)

    site_names = []
    xml = [f'<mujoco><option gravity="{vec(gravity)}" timestep="{timestep}" integrator="RK4">'
           '<flag contact="disable"/></option><worldbody>']
    for j in range(g.n):
        if j == 0:
            pos, rel = g.origins[0], g.rotations[0]
        else:
            pos, rel = np.array([0.0, 0.0, -ell]), g.rotations[j - 1].T @ g.rotations[j]
        jt = ('<joint type="ball"/>' if g.joint == "spherical" else f'<joint type="hinge" axis="{vec(g.axes[j])}"/>')
        xml.append(f'<body name="link{j + 1}" pos="{vec(pos)}" quat="{quat(rel)}">{jt}'
                   f'<inertial pos="0 0 {-ell / 2:.17g}" mass="{m}" diaginertia="{vec(diag)}"/>')
        for nm, (x, owner) in parts.items():
            if owner == j:
                local = g.rotations[j].T @ (x - g.origins[j])
                xml.append(f'<site name="{nm}" pos="{vec(local)}"/>')
                site_names.append(nm)
    xml.append("</body>" * g.n + "</worldbody></mujoco>")
    return "".join(xml), site_names
