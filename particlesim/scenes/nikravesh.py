"""Nikravesh's planar double A-arm quarter car (DAP_BC model "AA"), as a particle mechanism.

Data: ``shared/data/nikravesh_planar_aa/MODEL.md`` (bodies, points, joints, spring-damper, tyre; gravity -y).
Particle layout (choices of this package):

* lower arm (body 1): a rod, particles Q (= ground point Q0, its pivot) and A (shared with the wheel assembly);
  its CoM E1 lies on that line, as a rod needs;
* upper arm (body 3): a rod, particles O (= ground point O0) and B (shared with the wheel assembly);
* wheel assembly (body 2): a planar set A, B and a third particle C at the body's CoM;
* the revolute joints are the shared particles; the chassis is the ground.

The model gives only the polar moment J of each body; a planar set needs the in-plane split, chosen as
``I_xx = I_yy = J/2`` (it does not enter planar motion). The mechanism lives in 3-D, where the rods may in
principle swing out of the plane (4 degrees of freedom: the planar one and three out-of-plane ones); nothing
excites those, and the out-of-plane coordinates stay exactly zero (tested).
"""

from __future__ import annotations

import numpy as np

from ..data import data_dir
from ..inertia import RigidInertia
from ..mechanism import MechanismBuilder

__all__ = ["BODIES", "POINTS", "aa_mechanism", "load_reference", "WHEEL_COM"]

#: body: (mass, J about CoM, x0, y0, phi0)
BODIES = {
    "lower_arm": (2.0, 0.5, 0.439838247024165, 0.251190047424894, -0.0367163846898516),
    "wheel": (30.0, 2.5, 0.681683323878566, 0.349749908307923, 0.0782727601195614),
    "upper_arm": (1.0, 0.5, 0.446303177783148, 0.430781606226421, 6.52223719911075),
}
#: point: (body or None for ground, xi, eta)
POINTS = {
    "Q1": ("lower_arm", -0.24, 0.0), "A1": ("lower_arm", 0.18, 0.0), "E1": ("lower_arm", 0.0, 0.0),
    "A2": ("wheel", -0.07, -0.10), "B2": ("wheel", -0.10, 0.12),
    "B3": ("upper_arm", 0.13, 0.0), "O3": ("upper_arm", -0.13, 0.0),
    "Q0": (None, 0.20, 0.26), "O0": (None, 0.32, 0.40), "F0": (None, 0.38, 0.43),
}
SPRING = {"stiffness": 90000.0, "damping": 1100.0, "free_length": 0.23}
TYRE = {"stiffness": 50000.0, "damping": 1000.0, "radius": 0.35}
WHEEL_COM = "G2"


def _rot(phi: float) -> np.ndarray:
    c, s = np.cos(phi), np.sin(phi)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _global(point: str) -> np.ndarray:
    body, xi, eta = POINTS[point]
    if body is None:
        return np.array([xi, eta, 0.0])
    _, _, q0, y0, phi = BODIES[body]
    return np.array([q0, y0, 0.0]) + _rot(phi) @ np.array([xi, eta, 0.0])


def aa_mechanism(*, spring=None, tyre=None, masses=None):
    """Build the AA mechanism; optional overrides of the spring/tyre constants and body masses (dicts)."""
    spring = {**SPRING, **(spring or {})}
    tyre = {**TYRE, **(tyre or {})}
    masses = masses or {}
    mb = MechanismBuilder(gravity=(0.0, -9.81, 0.0))
    mb.ground("Q", _global("Q0"))
    mb.ground("O", _global("O0"))
    mb.ground("F", _global("F0"))
    mb.particle("A", _global("A1"))
    mb.particle("B", _global("B3"))
    mb.particle("C", np.array([BODIES["wheel"][2], BODIES["wheel"][3], 0.0]))
    for name, parts in (("lower_arm", ["Q", "A"]), ("upper_arm", ["O", "B"]), ("wheel", ["A", "B", "C"])):
        m, j, q0, y0, phi = BODIES[name]
        m = masses.get(name, m)
        if name == "wheel":
            inertia = RigidInertia(m, np.zeros(3), np.diag([j / 2, j / 2, j]), degenerate_ok=True, name=name)
        else:
            inertia = RigidInertia(m, np.zeros(3), np.diag([0.0, j, j]), degenerate_ok=True, name=name)
        mb.body(name, inertia, parts, pose=(_rot(phi), np.array([q0, y0, 0.0])), on_negative="ignore")
    mb.point("E", "lower_arm", _global("E1"))
    mb.point(WHEEL_COM, "wheel", np.array([BODIES["wheel"][2], BODIES["wheel"][3], 0.0]))
    mb.spring_damper("suspension", "E", "F", spring["stiffness"], spring["damping"], spring["free_length"])
    mb.tyre("tyre", WHEEL_COM, tyre["stiffness"], tyre["damping"], tyre["radius"], normal=(0.0, 1.0, 0.0))
    return mb.build(dof=4)


def load_reference() -> np.ndarray:
    """``AA_results.csv``: columns t, (x, y, phi) of bodies 1..3, then their velocities; 1 ms rows."""
    return np.loadtxt(data_dir() / "nikravesh_planar_aa" / "AA_results.csv", delimiter=",")
