"""The quarter-car double-wishbone suspension of the Attia reference (§3): data and equivalent particles.

Data transcribed from the reference: Table 1 (masses, inertias), Tables 2–3 (spring-damper, tyre), Table 4 (global
particle coordinates, metres; x along the car, y lateral/outboard, z up).

Assumptions where the reference leaves gaps (each is a choice of this package, not of the reference):

A1. Every body frame is parallel to the global axes at the assembled position (the reference gives the inertias in
    body axes without the axes' directions; with these axes the A-arm inertias are planar in their own plane, which
    supports the choice).
A2. Centres of mass: the chassis CoM is particle 1 (the point on the vertical slider whose motion the reference
    plots); each A-arm's CoM is the centroid of its three joint particles; the knuckle's CoM is the centroid of its
    joint particles 6, 7, 8; the wheel's CoM is particle 10 (the only particle outboard of the knuckle).
A3. Particle sets: chassis and knuckle spatial (the knuckle's Table 1 inertia, 1.6 about every axis, is not a
    planar mass distribution, so the reference's three-particle knuckle cannot carry it); the A-arms planar
    (their Table 1 inertias satisfy I_zz = I_xx + I_yy); the wheel spatial.
A4. Joint-based primaries: lower arm 2, 3 (chassis pivots) and 6 (ball joint); upper arm 4, 5 and 8; knuckle 6, 7,
    8 and a fourth point 0.1 m forward of particle 7 (6, 7, 8, 10 all lie in the plane x = -0.2); chassis 1, 2, 4
    and a fourth point 0.5 m above particle 1; wheel 10, a point 0.1 m outboard on the spindle (y), and two
    points 0.35 m (the tyre radius) forward and above the centre.
A5. Table 4 lists particles 8 and 9 at the same place and no particle 11; the cut joint r8 = r11 implies 11 sits
    at 8, and 9 is not used here. Table 4's particle 10 (y = 0.67) does not coincide with 7 (y = 0.62) although
    the cut joint r7 = r10 says it should: 10 is read as the wheel centre instead, and the steering-rod geometry
    is left to the mechanism scene.
A6. The steering rod has no mass in Table 1: it is a massless link (a distance constraint), with no particles of
    its own here.
"""

from __future__ import annotations

import numpy as np

from ..inertia import RigidInertia

__all__ = ["TABLE1", "TABLE4", "SPRING", "TYRE", "bodies", "joint_primaries"]

#: Table 1: mass [kg], inertia about the CoM (xx, yy, zz, yz, xz, xy) [kg m^2].
TABLE1: dict[str, tuple[float, tuple[float, ...]]] = {
    "chassis": (300.0, (130.0, 250.0, 200.0, 0.0, 0.0, 0.0)),
    "lower_arm": (1.0, (0.028, 0.002, 0.03, 0.0, 0.0, 0.0)),
    "upper_arm": (1.0, (0.028, 0.002, 0.03, 0.0, 0.0, 0.0)),
    "knuckle": (8.0, (1.6, 1.6, 1.6, 0.0, 0.0, 0.0)),
    "wheel": (22.0, (2.0, 1.35, 2.0, 0.0, 0.0, 0.0)),
}

#: Table 4: global particle coordinates [m].
TABLE4: dict[int, tuple[float, float, float]] = {
    1: (-1.0, 0.2, -0.24),
    2: (-0.2, 0.19, -0.26),
    3: (-0.3, 0.19, -0.26),
    4: (-0.2, 0.32, -0.1),
    5: (-0.3, 0.32, -0.1),
    6: (-0.2, 0.61, -0.26),
    7: (-0.2, 0.62, -0.24),
    8: (-0.2, 0.58, -0.1),
    9: (-0.2, 0.58, -0.1),
    10: (-0.2, 0.67, -0.24),
}

#: Table 2: suspension spring-damper between chassis and lower arm.
SPRING = {"stiffness": 5.11e4, "damping": 1.44e4, "free_length": 0.345}
#: Table 3: tyre.
TYRE = {"radius": 0.35, "stiffness": 0.3e6, "damping": 0.1e4}


def _p(i: int) -> np.ndarray:
    return np.asarray(TABLE4[i], dtype=float)


def _com(name: str) -> np.ndarray:
    """Assumption A2, global coordinates."""
    return {
        "chassis": _p(1),
        "lower_arm": (_p(2) + _p(3) + _p(6)) / 3,
        "upper_arm": (_p(4) + _p(5) + _p(8)) / 3,
        "knuckle": (_p(6) + _p(7) + _p(8)) / 3,
        "wheel": _p(10),
    }[name]


def bodies() -> dict[str, RigidInertia]:
    """Table 1 bodies, each with its frame at its (assumed) CoM and axes parallel to the global axes."""
    out = {}
    for name, (mass, (ixx, iyy, izz, iyz, ixz, ixy)) in TABLE1.items():
        out[name] = RigidInertia.from_principal(mass, np.zeros(3), (ixx, iyy, izz), (iyz, ixz, ixy), name=name,
                                                degenerate_ok=name in ("lower_arm", "upper_arm"))
    return out


def joint_primaries() -> dict[str, np.ndarray]:
    """Assumption A4: primary particles at the joints, in each body's frame (global minus the body's CoM)."""
    glob = {
        "chassis": [_p(1), _p(2), _p(4), _p(1) + [0.0, 0.0, 0.5]],
        "lower_arm": [_p(2), _p(3), _p(6)],
        "upper_arm": [_p(4), _p(5), _p(8)],
        "knuckle": [_p(6), _p(7), _p(8), _p(7) + [0.1, 0.0, 0.0]],
        "wheel": [_p(10), _p(10) + [0.0, 0.1, 0.0], _p(10) + [TYRE["radius"], 0.0, 0.0],
                  _p(10) + [0.0, 0.0, TYRE["radius"]]],
    }
    return {name: np.asarray(pts) - _com(name) for name, pts in glob.items()}


def body_origins() -> dict[str, np.ndarray]:
    """Global position of each body frame (its assumed CoM)."""
    return {name: _com(name) for name in TABLE1}
