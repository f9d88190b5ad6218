"""The quarter-car double-wishbone suspension of the Attia reference (§3): data, equivalent particles, mechanism.

Data transcribed from the reference: Table 1 (masses, inertias), Tables 2–3 (spring-damper, tyre), Table 4 (global
particle coordinates, metres; x along the car, y lateral/outboard, z up). Gravity -z.

Assumptions where the reference leaves gaps (each is a choice of this package, not of the reference):

A1. Every body frame is parallel to the global axes at assembly (the reference gives inertias in body axes
    without their directions; with these axes the A-arm inertias are planar in their own planes, which supports
    the choice).
A2. Centres of mass: the chassis at particle 1 (the point on the vertical slider whose motion the reference
    plots); each A-arm at the centroid of its three joint particles; the knuckle at the centroid of particles 6,
    8 and 10; the wheel at particle 10, read as the wheel centre (the only particle outboard of the knuckle).
A3. Particle sets: chassis spatial (particles 2, 3, 4 and C, 0.5 m above particle 1 on the slider axis); A-arms
    planar (their Table 1 inertias satisfy I_zz = I_xx + I_yy): lower 2, 3, 6, upper 4, 5, 8; knuckle spatial (6,
    11 at particle 8's place, 10, and K 0.1 m forward of 10): the reference's three-particle knuckle cannot carry
    its Table 1 inertia (1.6 about every axis is not planar), and 6, 7, 8, 10 all lie in the plane x = -0.2; wheel
    spatial (10, S 0.1 m outboard on the spindle, and two rim points 0.25 m forward and above).
A4. Joints: chassis-lower arm revolute by the shared particles 2 and 3; chassis-upper arm revolute by the shared
    particle 4 with particle 5 kept on the chassis axis through 4 (parallel to 2-3); ball joints at 6 (shared)
    and 8 (cut joint r8 = r11, as in the reference); knuckle-wheel revolute by the shared centre 10 with S kept
    on the knuckle's spindle axis (y); chassis on a vertical prismatic joint to the ground through particle 1.
A5. Steering rod: Table 1 gives it no mass, so it is a massless link. Table 4's particle 7 lies almost on the
    kingpin axis 6-8 (13 mm off it, in the rod's own direction), where a rod cannot hold the steering; following
    the Chrono double-wishbone layout (steering arm behind the kingpin, rod running inboard), the rod joins the
    knuckle at SA = (-0.32, 0.62, -0.24) and the chassis at TI = (-0.32, 0.20, -0.24). Table 4's particles 7 and
    9 are then unused (9 repeats 8; the reference's cut joint r7 = r10 cannot hold at Table 4's values).
A6. Spring-damper (Table 2) between the lower-arm point SL = (-0.22, 0.45, -0.26) and the chassis point SC
    0.345 m (its free length) above it: vertical and unloaded at assembly. Tyre (Table 3): vertical, on the wheel
    centre, ground plane 0.35 m (the radius) below it: touching, unloaded. The free response starts from rest in
    this assembly configuration and settles under gravity.
"""
from __future__ import annotations

import numpy as np

from ..inertia import RigidInertia

__all__ = ["TABLE1", "TABLE4", "SPRING", "TYRE", "PRIMARIES", "bodies", "joint_primaries", "quarter_car"]

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
        "knuckle": (_p(6) + _p(8) + _p(10)) / 3,
        "wheel": _p(10),
    }[name]


def bodies(masses: dict | None = None) -> dict[str, RigidInertia]:
    """Table 1 bodies, each with its frame at its (assumed) CoM and axes parallel to the global axes; ``masses``
    overrides some masses (inertias scale with them)."""
    out = {}
    for name, (mass, (ixx, iyy, izz, iyz, ixz, ixy)) in TABLE1.items():
        scale = (masses or {}).get(name, mass) / mass
        mass, ixx, iyy, izz, iyz, ixz, ixy = (v * scale for v in (mass, ixx, iyy, izz, iyz, ixz, ixy))
        out[name] = RigidInertia.from_principal(mass, np.zeros(3), (ixx, iyy, izz), (iyz, ixz, ixy), name=name,
                                                degenerate_ok=name in ("lower_arm", "upper_arm"))
    return out


def _extra() -> dict[str, np.ndarray]:
    """Particles and points the reference does not list (assumptions A3, A5, A6)."""
    w = _p(10)
    sl = np.array([-0.22, 0.45, -0.26])
    return {"C": _p(1) + [0.0, 0.0, 0.5], "K": w + [0.1, 0.0, 0.0], "S": w + [0.0, 0.1, 0.0],
            "R1": w + [0.25, 0.0, 0.0], "R2": w + [0.0, 0.0, 0.25], "SA": np.array([-0.32, 0.62, -0.24]),
            "TI": np.array([-0.32, 0.20, -0.24]), "SL": sl, "SC": sl + [0.0, 0.0, SPRING["free_length"]]}


#: Primary particles of each body (Table 4 numbers or the names of :func:`_extra`), assumption A3.
PRIMARIES: dict[str, tuple] = {
    "chassis": (2, 3, 4, "C"),
    "lower_arm": (2, 3, 6),
    "upper_arm": (4, 5, 8),
    "knuckle": (6, 11, 10, "K"),
    "wheel": (10, "S", "R1", "R2"),
}


def _xyz(key) -> np.ndarray:
    if key == 11:
        return _p(8)
    return _p(key) if isinstance(key, int) else _extra()[key]


def joint_primaries() -> dict[str, np.ndarray]:
    """Assumption A3: primary particles at the joints, in each body's frame (global minus the body's CoM)."""
    return {name: np.stack([_xyz(k) for k in keys]) - _com(name) for name, keys in PRIMARIES.items()}


def quarter_car(*, spring=None, tyre=None, masses=None):
    """The quarter-car mechanism (3 degrees of freedom); returns ``(mech, q0)``. Optional overrides of the spring
    and tyre constants and body masses (dicts keyed like :data:`SPRING`, :data:`TYRE`, :data:`TABLE1`)."""
    from ..mechanism import MechanismBuilder

    spring = {**SPRING, **(spring or {})}
    tyre = {**TYRE, **(tyre or {})}
    mb = MechanismBuilder(gravity=(0.0, 0.0, -9.81))
    names = {}
    for keys in PRIMARIES.values():
        for k in keys:
            if k not in names:
                names[k] = mb.particle(f"P{k}" if isinstance(k, int) else k, _xyz(k))
    g0 = _p(1)
    for nm, off in (("G0", [0, 0, 0]), ("G1", [0, 0, 1.0]), ("G2", [1.0, 0, 0])):
        mb.ground(nm, g0 + np.asarray(off, float))
    for name, body in bodies(masses).items():
        mb.body(name, body, [names[k] for k in PRIMARIES[name]], pose=(np.eye(3), _com(name)), on_negative="ignore")
    ex = _extra()
    mb.point("centre", "chassis", _p(1))
    mb.point("TI", "chassis", ex["TI"])
    mb.point("SC", "chassis", ex["SC"])
    mb.point("SL", "lower_arm", ex["SL"])
    mb.point("SA", "knuckle", ex["SA"])
    mb.point("spindle", "knuckle", ex["S"])
    mb.prismatic(("G0", "G1", "G2"), ("centre", "C", "P2"), name="chassis slider")
    mb.on_line("P5", "P4", ("P2", "P3"), "C", name="upper arm pivot 5 on the chassis axis")
    mb.cut_joint("P8", "P11", name="upper ball joint (cut) r8 = r11")
    mb.on_line("S", "P10", ("P10", "spindle"), "K", name="wheel spindle S on the knuckle axis")
    mb.link("SA", "TI", name="steering rod")
    mb.spring_damper("suspension", "SL", "SC", spring["stiffness"], spring["damping"], spring["free_length"])
    mb.tyre("tyre", "P10", tyre["stiffness"], tyre["damping"], tyre["radius"], normal=(0.0, 0.0, 1.0),
            ground=float(_p(10)[2]) - tyre["radius"])
    return mb.build(dof=3)
