"""A full vehicle: a free chassis on four double-wishbone corners and four vertical tyres (10 degrees of freedom).

Data transcribed from Project Chrono's ``HMMWV_DoubleWishboneFront.json`` (``../shared/data/double_wishbone_chrono``;
frame x forward, y left, z up, metres): hardpoints, masses, centres of mass and inertias of the control arms,
upright and spindle, the spring curve and free length, the shock's damping. Gravity -z.

Assumptions (choices of this module, not of the data):

B1. Four identical corners from the front file: the left front at the file's hardpoints, the rear ones shifted
    back by :data:`WHEELBASE` (3.3 m), the right ones mirrored (y -> -y). No steering rack, anti-roll bar,
    driveline or wheel spin: the tie rods end at fixed chassis points, which locks the steering.
B2. Chassis: ``chassis_mass`` (2000 kg) at mid-wheelbase, 0.4 m above the lower-arm pivots, with the inertia of a
    uniform box 4.6 x 2.2 x 1.2 m (HMMWV length and width) unless ``chassis_inertia`` (principal moments about the
    vehicle axes) is given; its particles a tetrahedron on its principal axes, mirror symmetric.
B3. Control arms are planar particle sets on their three hardpoints (front and back pivots, ball joint), with the
    file's inertias in the arm frame Chrono uses (x along the pivot axis, z normal to the hardpoint plane). Both
    violate the triangle inequality (lower 0.4 + 0.4 < 0.8938, upper 0.03 + 0.03 < 0.06276): the in-plane moments
    are kept (about the pivot axis, the one the arm swings about) and the normal moment set to their sum, a lamina
    in the hardpoint plane. The upper arm's centre of mass, 0.3 mm off that plane, is projected onto it. Each arm
    has one negative equivalent particle mass (exact motion, ``on_negative="ignore"``).
B4. Upright and spindle are one body (the spindle's spin about y is not modelled); their inertias are taken in
    vehicle axes (as Chrono does) and combined about the joint centre of mass. Its particles: the two ball joints,
    the spindle centre (the wheel centre) and the tie rod's upright end. Its equivalent particles include negative
    masses (the motion is exact; ``on_negative="ignore"``). No wheel or tyre mass: the file has none.
B5. Revolute joints to the chassis: each arm's front pivot coincides with a chassis point (cut joint), its back
    pivot is kept on the chassis's pivot axis (a point on a line). Ball joints are shared particles; the tie rod is
    a massless link.
B6. Spring (``"spring FL"``...): the file's curve linearised at zero deflection, its slope between the table
    points at -0.02 and +0.02 m, 181.5 kN/m (the tangent; the curve's secant at 0.1 m is 2.9 times that), free
    length 0.339 m: compressed by 93 mm (16.8 kN) at the hardpoints, more than the default car's weight needs:
    released from rest, the chassis rises 7.4 cm and settles there. Shock (``"shock FL"``...): a separate pure
    damper, 19015.6 N s/m. The arm ends of both lie 11-12 mm off the lower arm's hardpoint plane; each is slid
    along its own axis into the plane (same line of action at assembly), the spring's free length lengthened by
    the same amount.
B7. Tyres (``"tyre FL"``...): not in the file. Vertical, on the wheel centre, radius 0.47 m (HMMWV 37 inch tyre),
    400 kN/m, 1 kN s/m; the ground plane lies so that each tyre carries a quarter of the total weight at assembly.
"""
from __future__ import annotations

import numpy as np

from ..inertia import RigidInertia

__all__ = ["HARDPOINTS", "BODIES", "SPRING", "TYRE", "WHEELBASE", "CORNERS", "full_vehicle"]

#: Hardpoints of the left front corner [m].
HARDPOINTS = {
    "uca_f": (-0.048, 0.446, 0.245), "uca_b": (-0.268, 0.478, 0.196), "uca_u": (-0.053, 0.716, 0.215),
    "lca_f": (0.223, 0.307, 0.000), "lca_b": (-0.223, 0.307, 0.000), "lca_u": (-0.036, 0.787, -0.118),
    "tierod_c": (-0.250, 0.448, 0.054), "tierod_u": (-0.176, 0.821, -0.016),
    "spring_c": (0.104, 0.510, 0.197), "spring_a": (0.097, 0.543, -0.047),
    "shock_c": (0.104, 0.498, 0.323), "shock_a": (0.097, 0.543, -0.047),
}
#: Mass [kg], centre of mass [m], principal moments [kg m^2] (arms: arm frame, B3; others: vehicle axes).
BODIES = {
    "spindle": (14.705, (-0.040, 0.910, -0.026), (0.04117, 0.07352, 0.04117)),
    "upright": (19.450, (-0.040, 0.751, -0.026), (0.1656, 0.1934, 0.04367)),
    "uca": (5.813, (-0.106, 0.589, 0.218), (0.03, 0.03, 0.06276)),
    "lca": (23.965, (0.000, 0.547, -0.059), (0.4, 0.4, 0.8938)),
}
#: Linearised spring (B6; the curve's points at -0.02 and +0.02 m) and the shock's damping.
SPRING = {"stiffness": 2 * 3629.923 / 0.04, "free_length": 0.339, "damping": 19015.5692}
TYRE = {"radius": 0.47, "stiffness": 4.0e5, "damping": 1.0e3}  # B7
WHEELBASE = 3.3
CORNERS = {"FL": (0.0, 1.0), "FR": (0.0, -1.0), "RL": (-WHEELBASE, 1.0), "RR": (-WHEELBASE, -1.0)}
_CHASSIS_HEIGHT, _BOX, _G = 0.4, (4.6, 2.2, 1.2), 9.81


def _unit(v):
    return np.asarray(v, float) / np.linalg.norm(v)


def _arm(name, f, b, u, mass, com, moments):
    """B3: a planar arm's inertia (world axes, CoM in the plane) from its hardpoints ``f, b, u``, and the normal."""
    w = _unit(np.cross(b - u, f - u))
    axes = np.stack([_unit(f - b), np.cross(w, _unit(f - b)), w], axis=1)
    com = com - np.dot(com - u, w) * w
    i = axes @ np.diag([moments[0], moments[1], moments[0] + moments[1]]) @ axes.T
    return RigidInertia(mass, com, i, name=name, degenerate_ok=True), w


def _combined(name, parts):
    """B4: one body from ``(mass, com, principal moments in world axes)`` parts."""
    m = sum(p[0] for p in parts)
    c = sum(p[0] * np.asarray(p[1]) for p in parts) / m
    i = sum(np.diag(p[2]) + p[0] * (np.dot(d, d) * np.eye(3) - np.outer(d, d))
            for p in parts for d in [np.asarray(p[1]) - c])
    return RigidInertia(m, c, i, name=name)


def _slide_into_plane(a, c, origin, w):
    """B6: the point where the line from ``c`` through ``a`` meets the plane through ``origin`` with normal ``w``."""
    e = a - c
    return c + e * np.dot(origin - c, w) / np.dot(e, w)


def full_vehicle(*, chassis_mass=2000.0, chassis_inertia=None, spring=None, tyre=None):
    """The full vehicle (10 degrees of freedom); returns ``(mech, q0)``, at rest in the assembly configuration.
    ``chassis_inertia``: principal moments (Ixx, Iyy, Izz) about the vehicle axes [kg m^2] (default B2); ``spring``,
    ``tyre``: overrides of :data:`SPRING` (its ``damping`` is the shock's) and :data:`TYRE`, for all corners.
    Force elements ``"spring XX"``, ``"shock XX"``, ``"tyre XX"`` for XX in :data:`CORNERS`, bodies ``"chassis"``,
    ``"lower arm XX"``, ``"upper arm XX"``, ``"upright XX"`` (parameters by name: ``mech.with_params``)."""
    from ..mechanism import MechanismBuilder

    spring, tyre = {**SPRING, **(spring or {})}, {**TYRE, **(tyre or {})}
    mb = MechanismBuilder(gravity=(0.0, 0.0, -_G))
    com = np.array([BODIES["spindle"][1][0] - WHEELBASE / 2, 0.0, _CHASSIS_HEIGHT])
    if chassis_inertia is None:
        lx, ly, lz = _BOX
        chassis_inertia = chassis_mass / 12 * np.array([ly**2 + lz**2, lx**2 + lz**2, lx**2 + ly**2])
    chassis = RigidInertia.from_principal(chassis_mass, com, chassis_inertia, name="chassis")
    sigma = (np.sum(chassis_inertia) / 2 - np.asarray(chassis_inertia)) / chassis_mass  # second moments per kg
    tet = np.array([[1, 0, -0.5**0.5], [-1, 0, -0.5**0.5], [0, 1, 0.5**0.5], [0, -1, 0.5**0.5]]) / 1.5**0.5
    prim = com + tet * np.sqrt(5 * sigma)  # B2: a regular simplex stretched along the principal axes
    mb.body("chassis", chassis, [mb.particle(f"chassis {k}", p) for k, p in enumerate(prim)])
    corner_mass = sum(v[0] for v in BODIES.values())
    deflection = (chassis_mass + 4 * corner_mass) * _G / 4 / tyre["stiffness"]
    for c, (dx, sy) in CORNERS.items():
        mirror = np.array([1.0, sy, 1.0])
        hp = {k: np.array(v) * mirror + [dx, 0, 0] for k, v in HARDPOINTS.items()}
        bd = {k: (m, np.array(p) * mirror + [dx, 0, 0], i) for k, (m, p, i) in BODIES.items()}
        pt = {k: mb.particle(f"{k} {c}", hp[k]) for k in ("lca_f", "lca_b", "lca_u", "uca_f", "uca_b", "uca_u",
                                                          "tierod_u")}
        pt["wheel"] = mb.particle(f"wheel {c}", bd["spindle"][1])
        normal = {}
        for arm, label in (("lca", "lower arm"), ("uca", "upper arm")):
            inertia, normal[arm] = _arm(f"{label} {c}", hp[f"{arm}_f"], hp[f"{arm}_b"], hp[f"{arm}_u"], *bd[arm])
            mb.body(f"{label} {c}", inertia, [pt[f"{arm}_{k}"] for k in "fbu"], on_negative="ignore")
            front, back = (mb.point(f"chassis {arm}_{k} {c}", "chassis", hp[f"{arm}_{k}"]) for k in "fb")
            mb.cut_joint(pt[f"{arm}_f"], front, name=f"{label} front pivot {c}")
            mb.on_line(pt[f"{arm}_b"], front, (front, back), "chassis 0", name=f"{label} back pivot {c}")
        mb.body(f"upright {c}", _combined(f"upright {c}", [bd["upright"], bd["spindle"]]),
                [pt["lca_u"], pt["uca_u"], pt["wheel"], pt["tierod_u"]], on_negative="ignore")
        mb.link(pt["tierod_u"], mb.point(f"chassis tierod {c}", "chassis", hp["tierod_c"]), name=f"tie rod {c}")
        for el, stiff, damp, fl in (("spring", spring["stiffness"], 0.0, spring["free_length"]),
                                    ("shock", 0.0, spring["damping"], None)):
            a = _slide_into_plane(hp[f"{el}_a"], hp[f"{el}_c"], hp["lca_u"], normal["lca"])
            top = mb.point(f"chassis {el} {c}", "chassis", hp[f"{el}_c"])
            length = np.linalg.norm(a - hp[f"{el}_c"])
            fl = length if fl is None else fl + length - np.linalg.norm(hp[f"{el}_a"] - hp[f"{el}_c"])
            mb.spring_damper(f"{el} {c}", mb.point(f"lower arm {el} {c}", f"lower arm {c}", a), top, stiff, damp, fl)
        mb.tyre(f"tyre {c}", pt["wheel"], tyre["stiffness"], tyre["damping"], tyre["radius"],
                ground=float(bd["spindle"][1][2]) - tyre["radius"] + deflection)
    return mb.build(dof=10)
