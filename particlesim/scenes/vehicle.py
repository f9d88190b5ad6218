"""A full vehicle: a free chassis on four double-wishbone corners and four vertical tyres (10 degrees of freedom).

Corner data are read from Project Chrono's ``DoubleWishbone`` suspension JSON files by :func:`load_double_wishbone`
(default: ``HMMWV_DoubleWishboneFront.json`` in ``../shared/data/double_wishbone_chrono``; frame x forward, y left,
z up, metres): hardpoints, masses, centres of mass and inertias of the control arms, upright and spindle, the spring
(coefficient, or curve and free length), the shock's damping. Gravity -z.

Reading the file (as Chrono's ``DoubleWishbone::Create`` does, except where said):

L1. ``"Vehicle-Frame Inertia"`` absent means false (Chrono's default): the arms' inertias are in the arm frame
    (x from the back pivot to the front one, z normal to the hardpoint plane), the upright's and the spindle's in
    vehicle axes. True: the arms' are in vehicle axes too.
L2. A body's ``"Inertia"`` (the older format, e.g. ``Generic_DoubleWishbone.json``) is read as its moments, with
    zero products, as Chrono's older reader did. Non-zero ``"Products of Inertia"`` are refused (neither file has
    any). ``//`` and ``/* */`` comments are allowed (Chrono parses with comments on). ``"Axle"``, radii and widths
    (drawing only) are not read; a shock given by a curve is refused.

Assumptions (choices of this module, not of the data):

B1. Four corners: the front file's at the front, the rear file's (default: the front file again, so four identical
    corners) shifted back by :data:`WHEELBASE` (3.3 m); the right ones mirrored (y -> -y). No steering rack,
    anti-roll bar, driveline or wheel spin: the tie rods end at fixed chassis points, which locks the steering.
B2. Chassis: ``chassis_mass`` (2000 kg) at mid-wheelbase, 0.4 m above the front lower-arm pivots, with the inertia
    of a uniform box 4.6 x 2.2 x 1.2 m (HMMWV length and width) unless ``chassis_inertia`` (principal moments about
    the vehicle axes) is given; its particles a tetrahedron on its principal axes, mirror symmetric.
B3. Inertia policy (``load_double_wishbone(..., inertia=)``): ``"strict"`` refuses moments breaking the triangle
    inequality, naming the body; ``"balance"`` (default) repairs them and warns (``InertiaWarning``), the change
    listed in ``CornerData.notes``: an arm keeps its in-plane moments and its normal moment is set to their sum (a
    lamina in the hardpoint plane); the upright and spindle get MuJoCo's ``balanceinertia``. HMMWV's arms break it
    (lower 0.4 + 0.4 < 0.8938, upper 0.03 + 0.03 < 0.06276): "balance" sets 0.8 and 0.06. An arm whose inertia is a
    lamina in its hardpoint plane is a planar particle set on its three hardpoints, its centre of mass projected onto
    the plane (HMMWV's upper arm's lies 0.3 mm off it); any other arm (e.g. Generic's, physical but not laminae) is
    a spatial set with a fourth particle on the plane's normal, exact. Each arm has negative equivalent particle
    masses (exact motion, ``on_negative="ignore"``).
B4. Upright and spindle are one body (the spindle's spin about y is not modelled); their inertias are taken in
    vehicle axes (as Chrono does) and combined about the joint centre of mass. Its particles: the two ball joints,
    the spindle centre (the wheel centre) and the tie rod's upright end. Its equivalent particles include negative
    masses (the motion is exact; ``on_negative="ignore"``). No wheel or tyre mass: the files have none.
B5. Revolute joints to the chassis: each arm's front pivot coincides with a chassis point (cut joint), its back
    pivot is kept on the chassis's pivot axis (a point on a line). Ball joints are shared particles; the tie rod is
    a massless link.
B6. Spring (``"spring FL"``...): the file's coefficient, or its curve linearised at zero deflection (HMMWV: the
    slope between the table points at -0.02 and +0.02 m, 181.5 kN/m, the tangent; the curve's secant at 0.1 m is 2.9
    times that); the file's minimum and maximum lengths (no bump stops) are not modelled. HMMWV's free length 0.339 m
    leaves it compressed by 93 mm (16.8 kN) at the hardpoints, more than the default car's weight needs: released
    from rest, the chassis rises 7.4 cm and settles there. Shock (``"shock FL"``...): a separate pure damper. On a
    planar lower arm the arm ends of both (HMMWV: 11-12 mm off the hardpoint plane) are slid along their own axes
    into the plane (same line of action at assembly), the spring's free length lengthened by the same amount.
B7. Tyres (``"tyre FL"``...): not in the file. Vertical, on the wheel centre, radius 0.47 m (HMMWV 37 inch tyre),
    400 kN/m, 1 kN s/m; the ground plane lies so that each tyre carries a quarter of the total weight at assembly
    (its height the tyre's ``ground`` parameter; a road, ``roads=``, is added to it).

Options of :func:`full_vehicle` (off by default; not in the files):

B8. Anti-roll bars: a torsion spring between the left and right lower arms about the lower arms' pivot axis
    (parallel on both sides, so the twist is the difference of the arms' swings, whatever the chassis does); the
    bar's own mass, links and compliance are not modelled.
B9. The tabulated spring: the file's curve through a natural cubic spline, linear beyond its ends (tension at the
    spring's elongation from its free length, Chrono's sign).
B10. Bump and rebound stops: one-sided springs on each spring's line engaging at the file's minimum and maximum
    lengths (HMMWV: 0.15 and 0.30 m; Chrono's own stop curves are not in the file), with the given stiffness and
    damping.
B11. Steering: a rack of 5 kg (a rod) between the front tie rods' inner ends, both ends kept on the chassis line
    through them, its left end driven along the world's y axis relative to the chassis (the rack's direction while
    the chassis neither yaws nor rolls: a yawed chassis sees the rack travel's cosine).
"""
from __future__ import annotations

import json
import re
import warnings
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Mapping, Optional

import numpy as np

from ..errors import InertiaError, InertiaWarning, ModelError, ParseError
from ..inertia import PHYSICAL_RTOL, RigidInertia, balance_inertia

__all__ = ["BodyData", "SpringData", "CornerData", "load_double_wishbone", "hmmwv_front_path", "TYRE", "WHEELBASE",
           "CORNERS", "full_vehicle"]  # and ``SPRING`` (module ``__getattr__``)

TYRE = {"radius": 0.47, "stiffness": 4.0e5, "damping": 1.0e3}  # B7
WHEELBASE = 3.3
CORNERS = {"FL": (0.0, 1.0), "FR": (0.0, -1.0), "RL": (-WHEELBASE, 1.0), "RR": (-WHEELBASE, -1.0)}
_CHASSIS_HEIGHT, _BOX, _G = 0.4, (4.6, 2.2, 1.2), 9.81
_RACK_MASS = 5.0  # kg, B11
_UCA, _LCA = "Upper Control Arm", "Lower Control Arm"
#: Hardpoint names, with their file section and key.
_POINTS = {"uca_f": (_UCA, "Location Chassis Front"), "uca_b": (_UCA, "Location Chassis Back"),
           "uca_u": (_UCA, "Location Upright"), "lca_f": (_LCA, "Location Chassis Front"),
           "lca_b": (_LCA, "Location Chassis Back"), "lca_u": (_LCA, "Location Upright"),
           "tierod_c": ("Tierod", "Location Chassis"), "tierod_u": ("Tierod", "Location Upright"),
           "spring_c": ("Spring", "Location Chassis"), "spring_a": ("Spring", "Location Arm"),
           "shock_c": ("Shock", "Location Chassis"), "shock_a": ("Shock", "Location Arm")}
_BODIES = {"spindle": "Spindle", "upright": "Upright", "uca": _UCA, "lca": _LCA}


@dataclass(frozen=True, eq=False)
class BodyData:
    """A body of a corner: ``mass`` [kg], ``com`` [m] (vehicle axes), ``moments`` (Ixx, Iyy, Izz) and ``products``
    (Ixy, Ixz, Iyz, the tensor's off-diagonal entries as Chrono's ``SetInertiaXY`` takes them) [kg m^2] about the
    centre of mass, in ``frame``: ``"vehicle"`` or ``"arm"`` (L1)."""
    mass: float
    com: tuple
    moments: tuple
    products: tuple = (0.0, 0.0, 0.0)
    frame: str = "vehicle"

    def tensor(self) -> np.ndarray:
        """The inertia tensor (3, 3) about the centre of mass, in :attr:`frame`."""
        (xx, yy, zz), (xy, xz, yz) = self.moments, self.products
        return np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]], dtype=float)


@dataclass(frozen=True, eq=False)
class SpringData:
    """The spring: ``coefficient`` [N/m] or ``curve`` (n, 2) (deflection [m], force [N], deflection increasing), the
    ``free_length`` [m], and the ``min_length``/``max_length`` [m] when the file gives them."""
    coefficient: Optional[float]
    curve: Optional[np.ndarray]
    free_length: float
    min_length: Optional[float] = None
    max_length: Optional[float] = None


@dataclass(frozen=True, eq=False)
class CornerData:
    """One double-wishbone corner (the left one) as :func:`load_double_wishbone` read it."""
    name: str
    source: str
    hardpoints: Mapping[str, tuple]  # "uca_f", "uca_b", "uca_u", "lca_*", "tierod_c/u", "spring_c/a", "shock_c/a"
    bodies: Mapping[str, BodyData]  # "spindle", "upright", "uca", "lca"
    spring: SpringData
    damping: float  # the shock's [N s/m]
    notes: tuple = ()  # what the inertia policy changed, one line per body


def hmmwv_front_path() -> Path:
    """The HMMWV front suspension file in the reference data (``particlesim.data.data_dir``)."""
    from ..data import data_dir

    return data_dir() / "double_wishbone_chrono" / "HMMWV_DoubleWishboneFront.json"


def __getattr__(name):
    """``SPRING``: the default corner's ``{"stiffness", "free_length", "damping"}`` (B6), read from the HMMWV file
    when asked for (importing this module reads no file)."""
    if name == "SPRING":
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", InertiaWarning)
            return _spring_values(load_double_wishbone(hmmwv_front_path()))
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


# ---- reading ----
_COMMENT = re.compile(r'("(?:\\.|[^"\\])*")|//[^\n]*|/\*.*?\*/', re.S)


def _read(path) -> dict:
    try:
        text = Path(path).read_text()
    except (OSError, UnicodeDecodeError) as e:
        raise ParseError(f"{path}: cannot read the file: {e}") from None
    try:
        doc = json.loads(_COMMENT.sub(lambda m: m.group(1) or "", text))
    except json.JSONDecodeError as e:
        raise ParseError(f"{path}: not a JSON file ({e})") from None
    if not isinstance(doc, dict):
        raise ParseError(f"{path}: not a Chrono JSON object (top level is a {type(doc).__name__})")
    return doc


def _get(path, doc, section, key):
    sec = doc.get(section) if section else doc
    if not isinstance(sec, dict):
        raise ParseError(f"{path}: section '{section}' is missing" if sec is None else
                         f"{path}: section '{section}' is not an object")
    if key not in sec:
        raise ParseError(f"{path}: section '{section or '(top level)'}' has no key '{key}'")
    return sec[key]


def _numbers(path, doc, section, key, shape=(), *, positive=False):
    v = _get(path, doc, section, key)
    where = f"{path}: section '{section}', key '{key}'"
    try:
        a = np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        a = None
    if a is None or isinstance(v, bool) or (a.shape != shape if shape is not None else a.ndim != 2):
        raise ParseError(f"{where}: expected {'a number' if shape == () else f'numbers of shape {shape}'}, got {v!r}")
    if not np.all(np.isfinite(a)):
        raise ParseError(f"{where}: not finite: {v!r}")
    if positive and not np.all(a > 0):
        raise ModelError(f"{where}: must be positive, got {v!r}")
    return float(a) if shape == () else a


def _triangle(m) -> Optional[str]:
    """The first triangle inequality the moments ``m`` (principal, axes x, y, z) break, as text; None if none."""
    for k, (i, j) in enumerate(((1, 2), (0, 2), (0, 1))):
        if m[k] > m[i] + m[j] + PHYSICAL_RTOL * sum(m):
            a, b, c = ("xyz"[n] for n in (k, i, j))
            return f"I{a}{a} <= I{b}{b} + I{c}{c} ({m[k]:.6g} > {m[i] + m[j]:.6g})"
    return None


def _arm_axes(f, b, u) -> np.ndarray:
    """Chrono's arm frame (columns x, y, z): x from the back pivot to the front one, z normal to the hardpoints."""
    w = _unit(np.cross(b - u, f - u))
    x = _unit(f - b)
    return np.stack([x, np.cross(w, x), w], axis=1)


def load_double_wishbone(path, *, inertia: str = "balance") -> CornerData:
    """Read a Chrono ``DoubleWishbone`` suspension JSON file (its left corner; L1, L2 in the module docstring).

    ``inertia="strict"`` refuses a body whose moments of inertia break a triangle inequality
    (:class:`~particlesim.errors.InertiaError` naming the file, the body, its moments and the inequality);
    ``"balance"`` repairs them (B3) and warns (:class:`~particlesim.errors.InertiaWarning`) naming each body with
    its old and new moments, listed again in ``notes``. Missing sections or keys, a wrong ``Type``/``Template``,
    non-finite numbers, non-positive masses or moments, non-zero products of inertia and a spring curve that is not
    (n, 2) with increasing deflection raise :class:`~particlesim.errors.ModelError` naming the file, section and key.
    """
    if inertia not in ("strict", "balance"):
        raise ValueError(f"inertia must be 'strict' or 'balance', got {inertia!r}")
    doc = _read(path)
    for key, want in (("Type", "Suspension"), ("Template", "DoubleWishbone")):
        if _get(path, doc, None, key) != want:
            raise ParseError(f"{path}: '{key}' is {doc[key]!r}, expected {want!r}")
    vehicle_frame = doc.get("Vehicle-Frame Inertia", False)  # L1: Chrono's default
    if not isinstance(vehicle_frame, bool):
        raise ParseError(f"{path}: 'Vehicle-Frame Inertia' must be true or false, got {vehicle_frame!r}")
    hp = {k: tuple(_numbers(path, doc, s, key, (3,)).tolist()) for k, (s, key) in _POINTS.items()}
    bodies, broken, notes = {}, [], []
    for name, sec in _BODIES.items():
        mass = _numbers(path, doc, sec, "Mass", positive=True)
        com = tuple(_numbers(path, doc, sec, "COM", (3,)).tolist())
        key = ("Inertia" if name == "spindle" or ("Inertia" in doc[sec] and "Moments of Inertia" not in doc[sec])
               else "Moments of Inertia")  # L2
        moments = tuple(_numbers(path, doc, sec, key, (3,), positive=True).tolist())
        if key != "Inertia" and np.any(_numbers(path, doc, sec, "Products of Inertia", (3,))):
            raise ModelError(f"{path}: section '{sec}', key 'Products of Inertia': non-zero products of inertia are "
                             f"not supported, got {doc[sec]['Products of Inertia']!r}")
        body = BodyData(mass, com, moments, frame="arm" if name in ("uca", "lca") and not vehicle_frame else "vehicle")
        if _triangle(moments) and inertia == "strict":
            broken.append(f"'{sec}': moments {moments} kg m^2 ({body.frame} frame) violate {_triangle(moments)}")
        elif _triangle(moments):
            body = _balanced(name, body, hp)
            products = f", products {body.products}" if any(body.products) else ""
            notes.append(f"'{sec}': moments {moments} -> {body.moments}{products} kg m^2 ({body.frame} frame; "
                         + ("normal moment set to the sum of the in-plane ones)" if name in ("uca", "lca")
                            else "MuJoCo's balanceinertia)"))
        bodies[name] = body
    if broken:
        raise InertiaError(f"{path}: non-physical inertia of {len(broken)} body(ies) (triangle inequality broken): "
                           + "; ".join(broken) + "; inertia='balance' repairs them (B3)")
    if notes:
        warnings.warn(f"{path}: non-physical inertia of {len(notes)} body(ies) repaired (inertia='balance'): "
                      + "; ".join(notes), InertiaWarning, stacklevel=2)
    spring = _spring(path, doc)
    if "Damping Coefficient" not in doc["Shock"] and "Curve Data" in doc["Shock"]:
        raise ModelError(f"{path}: section 'Shock': a damper curve ('Curve Data') is not supported; give "
                         "'Damping Coefficient'")
    damping = _numbers(path, doc, "Shock", "Damping Coefficient")
    if damping < 0:
        raise ModelError(f"{path}: section 'Shock', key 'Damping Coefficient': must be >= 0, got {damping!r}")
    return CornerData(str(doc.get("Name", Path(path).stem)), str(path), MappingProxyType(hp), MappingProxyType(bodies),
                      spring, damping, tuple(notes))


def _balanced(name, body: BodyData, hp) -> BodyData:
    """B3's repair: an arm keeps its in-plane moments, its normal one set to their sum (in the arm frame); the
    upright and spindle get MuJoCo's ``balanceinertia``."""
    if name not in ("uca", "lca"):
        i, _ = balance_inertia(body.tensor())
    elif body.frame == "arm":
        m = body.moments
        return BodyData(body.mass, body.com, (m[0], m[1], m[0] + m[1]), body.products, body.frame)
    else:
        axes = _arm_axes(*(np.array(hp[f"{name}_{k}"]) for k in "fbu"))
        a = axes.T @ body.tensor() @ axes
        a[2, :2] = a[:2, 2] = 0.0
        a[2, 2] = a[0, 0] + a[1, 1]
        i = axes @ a @ axes.T
    return BodyData(body.mass, body.com, tuple(np.diag(i).tolist()), (i[0, 1], i[0, 2], i[1, 2]), body.frame)


def _spring(path, doc) -> SpringData:
    free = _numbers(path, doc, "Spring", "Free Length", positive=True)
    lims = [_numbers(path, doc, "Spring", k, positive=True) if k in doc["Spring"] else None
            for k in ("Minimum Length", "Maximum Length")]
    if "Spring Coefficient" in doc["Spring"]:  # as Chrono, the coefficient wins over a curve
        k = _numbers(path, doc, "Spring", "Spring Coefficient")
        if k < 0:
            raise ModelError(f"{path}: section 'Spring', key 'Spring Coefficient': must be >= 0, got {k!r}")
        return SpringData(k, None, free, *lims)
    if "Curve Data" not in doc["Spring"]:
        raise ParseError(f"{path}: section 'Spring' has no key 'Spring Coefficient' or 'Curve Data'")
    curve = _numbers(path, doc, "Spring", "Curve Data", None)
    if curve.shape[1] != 2 or curve.shape[0] < 2 or not np.all(np.diff(curve[:, 0]) > 0):
        raise ModelError(f"{path}: section 'Spring', key 'Curve Data': must be (n, 2) rows (deflection, force), n >= "
                         f"2, deflection strictly increasing; got shape {curve.shape}"
                         + ("" if curve.shape[1] != 2 else f", deflections {curve[:, 0].tolist()}"))
    curve.setflags(write=False)
    return SpringData(None, curve, free, *lims)


def _spring_values(corner: CornerData) -> dict:
    """B6: ``{"stiffness", "free_length", "damping"}`` of a corner (a curve's slope at zero deflection)."""
    s = corner.spring
    if s.coefficient is not None:
        k = s.coefficient
    else:
        x, f = s.curve[:, 0], s.curve[:, 1]
        if not x[0] <= 0.0 <= x[-1]:
            raise ModelError(f"{corner.source}: section 'Spring', key 'Curve Data': zero deflection lies outside "
                             f"the curve's range [{x[0]}, {x[-1]}]; cannot linearise it there")
        z = int(np.searchsorted(x, 0.0))
        if 0 < z < len(x) - 1 and x[z] == 0.0:  # a table point: the secant through its neighbours
            lo, hi = z - 1, z + 1
        else:  # the segment holding zero
            lo = int(np.clip(np.searchsorted(x, 0.0, "right") - 1, 0, len(x) - 2))
            hi = lo + 1
        k = (f[hi] - f[lo]) / (x[hi] - x[lo])
    return {"stiffness": float(k), "free_length": s.free_length, "damping": corner.damping}


# ---- building ----
def _unit(v):
    return np.asarray(v, float) / np.linalg.norm(v)


def _combined(name, parts):
    """B4: one body from ``(mass, com, inertia tensor in world axes)`` parts."""
    m = sum(p[0] for p in parts)
    c = sum(p[0] * np.asarray(p[1]) for p in parts) / m
    i = sum(p[2] + p[0] * (np.dot(d, d) * np.eye(3) - np.outer(d, d))
            for p in parts for d in [np.asarray(p[1]) - c])
    return RigidInertia(m, c, i, name=name)


def _slide_into_plane(a, c, origin, w):
    """B6: the point where the line from ``c`` through ``a`` meets the plane through ``origin`` with normal ``w``."""
    e = a - c
    return c + e * np.dot(origin - c, w) / np.dot(e, w)


def _corner(mb, c, corner: CornerData, dx, sy, spring, tyre, ground_lift, road=None, curve=False, stops=None,
            rack=None):
    """Corner ``c`` of ``corner`` shifted by ``dx`` along x, mirrored when ``sy < 0`` (B1, B3-B7)."""
    mirror = np.array([1.0, sy, 1.0])
    hp = {k: np.array(v) * mirror + [dx, 0, 0] for k, v in corner.hardpoints.items()}
    bd = {k: (b.mass, np.array(b.com) * mirror + [dx, 0, 0], b) for k, b in corner.bodies.items()}
    world = {k: np.diag(mirror) @ b.tensor() @ np.diag(mirror) for k, (_, _, b) in bd.items()}  # vehicle frames
    pt = {k: mb.particle(f"{k} {c}", hp[k]) for k in ("lca_f", "lca_b", "lca_u", "uca_f", "uca_b", "uca_u", "tierod_u")}
    pt["wheel"] = mb.particle(f"wheel {c}", bd["spindle"][1])
    normal = {}
    for arm, label in (("lca", "lower arm"), ("uca", "upper arm")):
        (mass, com, b), f, bk, u = bd[arm], hp[f"{arm}_f"], hp[f"{arm}_b"], hp[f"{arm}_u"]
        axes = _arm_axes(f, bk, u)
        i = axes @ b.tensor() @ axes.T if b.frame == "arm" else world[arm]
        a = axes.T @ i @ axes
        lamina = max(abs(a[2, 2] - a[0, 0] - a[1, 1]), abs(a[0, 2]), abs(a[1, 2])) <= PHYSICAL_RTOL * np.trace(a)
        prim = [pt[f"{arm}_{k}"] for k in "fbu"]
        if lamina:  # B3: a planar set, the centre of mass projected onto the hardpoint plane
            normal[arm] = w = axes[:, 2]
            inertia = RigidInertia(mass, com - np.dot(com - u, w) * w, i, name=f"{label} {c}", degenerate_ok=True)
        else:  # B3: a spatial set, the fourth particle on the plane's normal through the hardpoints' centroid
            mid = (f + bk + u) / 3
            h = np.sqrt(np.mean([np.dot(p - mid, p - mid) for p in (f, bk, u)]))
            prim.append(mb.particle(f"{arm}_n {c}", mid + h * axes[:, 2]))
            inertia = RigidInertia(mass, com, i, name=f"{label} {c}")
        mb.body(f"{label} {c}", inertia, prim, on_negative="ignore")
        front, back = (mb.point(f"chassis {arm}_{k} {c}", "chassis", hp[f"{arm}_{k}"]) for k in "fb")
        mb.cut_joint(pt[f"{arm}_f"], front, name=f"{label} front pivot {c}")
        mb.on_line(pt[f"{arm}_b"], front, (front, back), "chassis 0", name=f"{label} back pivot {c}")
    mb.body(f"upright {c}", _combined(f"upright {c}", [(*bd[k][:2], world[k]) for k in ("upright", "spindle")]),
            [pt["lca_u"], pt["uca_u"], pt["wheel"], pt["tierod_u"]], on_negative="ignore")
    inner = rack if rack is not None else mb.point(f"chassis tierod {c}", "chassis", hp["tierod_c"])
    mb.link(pt["tierod_u"], inner, name=f"tie rod {c}")
    for el, stiff, damp, fl in (("spring", spring["stiffness"], 0.0, spring["free_length"]),
                                ("shock", 0.0, spring["damping"], None)):
        a = hp[f"{el}_a"]
        if "lca" in normal:  # B6: into the planar arm's plane
            a = _slide_into_plane(a, hp[f"{el}_c"], hp["lca_u"], normal["lca"])
        top = mb.point(f"chassis {el} {c}", "chassis", hp[f"{el}_c"])
        length = np.linalg.norm(a - hp[f"{el}_c"])
        fl = length if fl is None else fl + length - np.linalg.norm(hp[f"{el}_a"] - hp[f"{el}_c"])
        bottom = mb.point(f"lower arm {el} {c}", f"lower arm {c}", a)
        if el == "spring" and curve:  # B9: the file's curve, tabulated
            mb.spring_damper(f"{el} {c}", bottom, top, free_length=fl, force_curve=corner.spring.curve)
        else:
            mb.spring_damper(f"{el} {c}", bottom, top, stiff, damp, fl)
        if el == "spring" and stops is not None:  # B10: bump and rebound stops at the file's length limits
            shift = length - np.linalg.norm(hp[f"{el}_a"] - hp[f"{el}_c"])
            for kind, limit, rebound in (("bump", corner.spring.min_length, False),
                                         ("rebound", corner.spring.max_length, True)):
                if limit is None:
                    continue
                gap = (length - (limit + shift)) * (-1.0 if rebound else 1.0)
                if gap < 0:
                    raise ModelError(f"{corner.source}: the spring of corner {c} is {length:.4g} m long at the "
                                     f"hardpoints, beyond its {kind} limit {limit + shift:.4g} m")
                mb.bump_stop(f"{kind} stop {c}", bottom, top, gap, stops["stiffness"], stops.get("damping", 0.0),
                             rebound=rebound)
    mb.tyre(f"tyre {c}", pt["wheel"], tyre["stiffness"], tyre["damping"], tyre["radius"],
            ground=0.0 if road is None else road)
    return float(bd["spindle"][1][2]) - tyre["radius"] + ground_lift  # the tyre's ground height (B7)


def _chassis(mb, mass: float, com, moments) -> None:
    """The body ``"chassis"`` with principal ``moments`` about the vehicle axes at ``com``, its four primaries
    ``"chassis 0..3"`` a regular simplex stretched along the principal axes (B2)."""
    sigma = (np.sum(moments) / 2 - np.asarray(moments)) / mass  # second moments per kg
    tet = np.array([[1, 0, -0.5**0.5], [-1, 0, -0.5**0.5], [0, 1, 0.5**0.5], [0, -1, 0.5**0.5]]) / 1.5**0.5
    prim = com + tet * np.sqrt(5 * sigma)
    mb.body("chassis", RigidInertia.from_principal(mass, com, moments, name="chassis"),
            [mb.particle(f"chassis {k}", p) for k, p in enumerate(prim)])


def full_vehicle(*, front=None, rear=None, chassis_mass=2000.0, chassis_inertia=None, spring=None, tyre=None,
                 roads=None, spring_curve=False, stops=None, anti_roll_bar=None, steering=None):
    """The full vehicle (10 degrees of freedom); returns ``(mech, q0)``, at rest in the assembly configuration.
    ``front``, ``rear``: a Chrono ``DoubleWishbone`` JSON path or a :class:`CornerData` (default: the HMMWV front
    file, read with ``inertia="balance"``, which warns; ``rear=None``: the front one, B1).
    ``chassis_inertia``: principal moments (Ixx, Iyy, Izz) about the vehicle axes [kg m^2] (default B2); ``spring``:
    overrides of every corner's ``{"stiffness", "free_length", "damping"}`` (B6; ``damping`` is the shock's), ``tyre``
    of :data:`TYRE`. Force elements ``"spring XX"``, ``"shock XX"``, ``"tyre XX"`` for XX in :data:`CORNERS`, bodies
    ``"chassis"``, ``"lower arm XX"``, ``"upper arm XX"``, ``"upright XX"`` (parameters by name:
    ``mech.with_params``).

    Options (each off by default):

    * ``roads``: ``{corner: road}``, each tyre's road as a function of time added to its ground plane (a post of a
      four-post rig; :mod:`particlesim.scenes.roads`);
    * ``spring_curve=True``: the files' spring curves, tabulated (B9), instead of their linearisation;
    * ``stops={"stiffness": k, "damping": c}``: bump and rebound stops on each spring's line at the file's minimum
      and maximum lengths (B10; ``"bump stop XX"``, ``"rebound stop XX"``);
    * ``anti_roll_bar={"front": k, "rear": k}``: anti-roll bars of ``k`` N m/rad between the left and right lower
      arms (B8; ``"anti-roll bar front"``, ``"anti-roll bar rear"``);
    * ``steering=f``: a steering rack (B11): the front tie rods' inner ends on a rack body that slides along the
      chassis, moved ``f(t)`` metres (to the left: positive) by a driver ``"steering"``; ``f(0)`` must be 0."""
    from ..mechanism import MechanismBuilder

    front = front if isinstance(front, CornerData) else load_double_wishbone(front or hmmwv_front_path())
    rear = front if rear is None else rear if isinstance(rear, CornerData) else load_double_wishbone(rear)
    tyre = {**TYRE, **(tyre or {})}
    mb = MechanismBuilder(gravity=(0.0, 0.0, -_G))
    xf, xr = front.bodies["spindle"].com[0], rear.bodies["spindle"].com[0]
    pivots = (front.hardpoints["lca_f"][2] + front.hardpoints["lca_b"][2]) / 2
    com = np.array([xf - (WHEELBASE + (xf - xr)) / 2, 0.0, pivots + _CHASSIS_HEIGHT])
    if chassis_inertia is None:
        lx, ly, lz = _BOX
        chassis_inertia = chassis_mass / 12 * np.array([ly**2 + lz**2, lx**2 + lz**2, lx**2 + ly**2])
    _chassis(mb, chassis_mass, com, chassis_inertia)
    masses = [sum(b.mass for b in cd.bodies.values()) for cd in (front, rear)]
    deflection = (chassis_mass + 2 * (masses[0] + masses[1])) * _G / 4 / tyre["stiffness"]
    roads = dict(roads or {})
    unknown = set(roads) - set(CORNERS)
    if unknown:
        raise ModelError(f"full_vehicle: roads for unknown corners {sorted(unknown)}; corners: {list(CORNERS)}")
    racks = _rack(mb, front, steering) if steering is not None else {}
    heights = {}
    for c, (dx, sy) in CORNERS.items():
        corner = front if dx == 0.0 else rear
        if spring_curve and corner.spring.curve is None:
            raise ModelError(f"full_vehicle: spring_curve=True, but {corner.source} gives no spring curve")
        if stops is not None and not (set(stops) <= {"stiffness", "damping"} and "stiffness" in stops):
            raise ModelError(f"full_vehicle: stops must be {{'stiffness': k, 'damping': c}}, got {stops!r}")
        heights[c] = _corner(mb, c, corner, dx, sy, {**_spring_values(corner), **(spring or {})}, tyre, deflection,
                             roads.get(c), spring_curve, stops, racks.get(c))
    for axle, pair in (anti_roll_bar or {}).items():
        if axle not in ("front", "rear"):
            raise ModelError(f"full_vehicle: anti_roll_bar axles are 'front' and 'rear', got {axle!r}")
        left, right = ("FL", "FR") if axle == "front" else ("RL", "RR")
        corner = front if axle == "front" else rear
        axis = np.asarray(corner.hardpoints["lca_f"]) - np.asarray(corner.hardpoints["lca_b"])
        mb.torsion_spring(f"anti-roll bar {axle}", f"lower arm {left}", f"lower arm {right}", axis, pair)
    mech, q0 = mb.build(dof=10)
    return mech.with_params(tyre={f"tyre {c}": {"ground": h} for c, h in heights.items()}), q0


def _rack(mb, corner: CornerData, steering) -> dict:
    """B11: the rack, a rod between the front tie rods' inner ends held on the chassis line through them and driven
    along it; returns the rack end of each front corner."""
    hp = np.asarray(corner.hardpoints["tierod_c"], dtype=float)
    ends = {"FL": hp, "FR": hp * np.array([1.0, -1.0, 1.0])}
    names = {c: mb.particle(f"rack {c}", p) for c, p in ends.items()}
    mb.rod("rack", names["FL"], names["FR"], _RACK_MASS)
    a = mb.point("chassis rack FL", "chassis", ends["FL"])
    b = mb.point("chassis rack FR", "chassis", ends["FR"])
    for c in ends:
        mb.on_line(names[c], a, (a, b), "chassis 0", name=f"rack {c} on its guide")
    mb.drive_position("steering", names["FL"], steering, axis=(0.0, 1.0, 0.0), relative_to=a)
    return names
