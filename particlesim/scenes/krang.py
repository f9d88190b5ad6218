"""Golem Krang on fixed wheels, in two forms.

(a) :func:`krang_report` — the tree of the report's own frames (Zafar, appendix B.2 ``getKrangFrames``): 17 joints
    ``q_imu, q_w, q_torso, q_1l..q_7l, q_1r..q_7r``, frame 0 with gravity along ``-z``, joint frames placed by
    ``L1..L9``. Each frame ``j`` is given by its axes at ``q = 0`` in the antecedent frame, its origin ``P`` and its
    local rotation direction ``e_j``; the report's ``^iT_j(q)`` equals ``(R0, P) o Rot(e_j, q_j)`` for every frame
    (checked term by term against the listing's ``x, y, z`` columns).

    Numeric parameters (:func:`krang_report_params`) are derived from ``krang_2018.urdf``:
      * lengths: ``L1 = 0.499`` (JWaist y), ``L2 = 0.091`` (-JWaist z), ``L3 = 0.584`` (JTorso y), ``L4 = 0.1088``
        (JTorso z), ``L5 = 0.0845`` (LJ1 y), ``L6 = 0.2823`` (|LJ1 x|), ``L7 = 0.328``, ``L8 = 0.2765``, ``L9 = 0.2``
        (data README, checked against the file);
      * link ``1`` = Base, ``2`` = Spine, ``3`` = Bracket, ``4l..9l`` = L1..L6, ``10l`` = lGripper with its two
        plates (fixed joints) merged, and likewise on the right. The wheels are not links of the report (they
        are the fixed ground) and the 2018 file has no Kinect;
      * each URDF CoM inertia is moved to its link frame origin (parallel axes; fixed children merged) by
        :func:`~particlesim.io.urdf.load_urdf`, then rotated into the report frame with the constant
        :data:`REPORT_FROM_URDF` rotation. This rotation is the identity for every link except ``10l``/``10r``,
        whose report frame is the URDF gripper frame turned by -90 deg about the joint axis ``z``
        (report ``x`` = URDF ``y``, report ``y`` = -URDF ``x``).

(b) :func:`krang_urdf` — any of the shipped URDFs through the loader.

Conventions that differ between (a) and the URDFs (what :mod:`tests.tree.test_krang` pins down):
  * ``q_imu`` turns about ``-x`` of the base (``e_1``); the fixed-wheel URDF's JLWheel and the pitch joint added
    by :func:`krang_2018_pitch_urdf` turn about ``+x``: ``q_imu = -q_JLWheel``. All other joints have the same
    sign and zero.
  * The URDF's lateral offsets ``JWaist x = 0.026`` and ``JTorso x = -0.0285`` have no counterpart in the report.
  * The URDF writes pi as 3.14 or 3.1416 (and pi/2 as 1.5708); the report's frames are exact.
  * ``krang_fixed_wheel_2018-04.urdf`` turns RJ6's frame by a further +90 deg about the joint axis (rpy
    ``1.5708 0 3.1416``), a zero offset the 2018 files and the report do not have.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Mapping

import jax.numpy as jnp
import numpy as np

from ..data import data_dir
from ..inertia import rotate_origin_params
from ..io.urdf import load_urdf
from ..tree.model import REVOLUTE, TreeModel

__all__ = [
    "KRANG_LENGTHS_2018",
    "REPORT_JOINTS",
    "REPORT_LINKS",
    "REPORT_TO_URDF",
    "REPORT_FROM_URDF",
    "report_origins",
    "krang_report",
    "krang_report_params",
    "krang_urdf",
    "krang_2018_pitch_urdf",
    "urdf_path",
]

KRANG_LENGTHS_2018 = dict(L1=0.499, L2=0.091, L3=0.584, L4=0.1088, L5=0.0845, L6=0.2823, L7=0.328, L8=0.2765,
                          L9=0.200)
_L_NAMES = tuple(f"L{i}" for i in range(1, 10))

_SIDE = ("l", "r")
REPORT_LINKS = ("1", "2", "3") + tuple(f"{k}{s}" for s in _SIDE for k in range(4, 11))
REPORT_JOINTS = ("q_imu", "q_w", "q_torso") + tuple(f"q_{k}{s}" for s in _SIDE for k in range(1, 8))

# Axes of frame j at q = 0 in its antecedent (columns x, y, z), from the listing's x, y, z at q = 0.
_X, _Y, _Z = np.eye(3)
_ARM_ODD = np.column_stack([-_X, -_Y, _Z])  # frames 5, 7, 9 (and 6, 8 share it)
_R0 = {
    "1": np.column_stack([-_Y, _Z, -_X]),
    "2": np.eye(3),
    "3": np.column_stack([-_X, _Y, -_Z]),
    "4l": np.column_stack([_Y, _X, -_Z]),
    "4r": np.column_stack([_Y, -_X, _Z]),
    "10": np.column_stack([-_X, -_Z, -_Y]),
}
# (antecedent, R0 key, e_j, origin as a list of (length name or None, sign) per axis)
_FRAMES = {
    "1": ("0", "1", -_X, (None, None, None)),
    "2": ("1", "2", -_X, (None, ("L1", 1), ("L2", -1))),
    "3": ("2", "3", -_Y, (None, ("L3", 1), ("L4", 1))),
}
for _s in _SIDE:
    _FRAMES[f"4{_s}"] = ("3", f"4{_s}", -_Y, (("L6", 1 if _s == "l" else -1), ("L5", 1), None))
    for _k, (_e, _len) in zip(range(5, 10), ((-_X, None), (-_Y, "L7"), (-_X, None), (-_Y, "L8"), (-_X, None))):
        _FRAMES[f"{_k}{_s}"] = (f"{_k - 1}{_s}", "arm", _e, (None, (_len, -1) if _len else None, None))
    _FRAMES[f"10{_s}"] = (f"9{_s}", "10", -_Z, (None, ("L9", -1), None))

#: report joint -> (URDF joint name, sign) with q_report = sign * q_urdf (the URDF is the 2018 pitch variant).
REPORT_TO_URDF = {"q_imu": ("JBase", -1.0), "q_w": ("JWaist", 1.0), "q_torso": ("JTorso", 1.0)}
for _s, _p in (("l", "L"), ("r", "R")):
    for _k in range(1, 7):
        REPORT_TO_URDF[f"q_{_k}{_s}"] = (f"{_p}J{_k}", 1.0)
    REPORT_TO_URDF[f"q_7{_s}"] = (f"{_p}JFT", 1.0)

_GRIPPER = np.column_stack([_Y, -_X, _Z])  # report 10 axes in URDF gripper axes (columns)
#: Constant rotation R (report axes from URDF axes) per report link; identity unless listed.
REPORT_FROM_URDF = {"10l": _GRIPPER.T, "10r": _GRIPPER.T}


def urdf_path(name: str = "krang_2018.urdf") -> Path:
    """Path of a shipped Krang URDF in the shared data folder."""
    return data_dir() / "krang" / "urdf" / name


def report_origins(lengths) -> jnp.ndarray:
    """``(17, 3)`` joint origins ``P_j`` in the antecedent frames from ``L1..L9`` (a mapping or a 9-vector);
    differentiable in the lengths."""
    if isinstance(lengths, Mapping):
        lv = jnp.stack([jnp.asarray(lengths[k], dtype=float) for k in _L_NAMES])
    else:
        lv = jnp.asarray(lengths, dtype=float)
    rows = []
    for link in REPORT_LINKS:
        axes = _FRAMES[link][3]
        rows.append(jnp.stack([0.0 * lv[0] if a is None else a[1] * lv[_L_NAMES.index(a[0])] for a in axes]))
    return jnp.stack(rows)


def _r0(key: str) -> np.ndarray:
    return _ARM_ODD if key == "arm" else _R0[key]


def krang_report(params=None, lengths=None, *, g: float = 9.81, **terms) -> TreeModel:
    """Form (a): the report's 17-joint tree. ``params`` ``(17, 10)`` in report order and frames (default:
    :func:`krang_report_params`), ``lengths`` L1..L9 (default :data:`KRANG_LENGTHS_2018`), gravity ``(0, 0, -g)``
    in frame 0. ``terms`` are passed on (``viscous``, ``coulomb``, ``rotor_inertia``)."""
    params = krang_report_params() if params is None else params
    lengths = KRANG_LENGTHS_2018 if lengths is None else lengths
    parents = [-1 if _FRAMES[k][0] == "0" else REPORT_LINKS.index(_FRAMES[k][0]) for k in REPORT_LINKS]
    return TreeModel(
        parents=parents,
        kinds=[REVOLUTE] * 17,
        axes=np.stack([_FRAMES[k][2] for k in REPORT_LINKS]),
        origin_rotations=np.stack([_r0(_FRAMES[k][1]) for k in REPORT_LINKS]),
        origin_xyz=report_origins(lengths),
        inertia=params,
        gravity=(0.0, 0.0, -g),
        link_names=REPORT_LINKS,
        joint_names=REPORT_JOINTS,
        **terms,
    )


def _snap(text: str) -> str:
    vals = [float(t) for t in text.split()]
    quarter = np.pi / 2
    return " ".join(repr(float(np.round(v / quarter) * quarter)) if abs(v / quarter - np.round(v / quarter)) < 1e-2
                    else repr(v) for v in vals)


def krang_2018_pitch_urdf(path=None, *, zero_lateral: bool = False, exact_angles: bool = False) -> str:
    """``krang_2018.urdf`` as the report sees it, as a URDF string: wheels removed, a ``world`` root and a revolute
    base-pitch joint ``JBase`` (axis +x of Base, as the fixed-wheel URDF's JLWheel) first in the joint list.

    ``zero_lateral`` sets the JWaist/JTorso x offsets to zero; ``exact_angles`` snaps rpy values within 1e-2 of a
    multiple of pi/2 to it (the file writes pi as 3.14/3.1416).
    """
    root = ET.parse(urdf_path() if path is None else path).getroot()
    for el in list(root):
        if el.tag == "link" and el.get("name") in ("LWheel", "RWheel"):
            root.remove(el)
        if el.tag == "joint" and el.get("name") in ("JLWheel", "JRWheel"):
            root.remove(el)
    for el in root.iter("origin"):
        if exact_angles and el.get("rpy"):
            el.set("rpy", _snap(el.get("rpy")))
    if zero_lateral:
        for j in root.findall("joint"):
            if j.get("name") in ("JWaist", "JTorso"):
                o = j.find("origin")
                xyz = o.get("xyz").split()
                o.set("xyz", " ".join(["0"] + xyz[1:]))
    first_joint = [i for i, el in enumerate(list(root)) if el.tag == "joint"][0]
    root.insert(0, ET.fromstring('<link name="world"/>'))
    root.insert(first_joint + 1, ET.fromstring(
        '<joint name="JBase" type="revolute"><parent link="world"/><child link="Base"/>'
        '<origin xyz="0 0 0" rpy="0 0 0"/><axis xyz="1 0 0"/></joint>'))
    return ET.tostring(root, encoding="unicode")


def krang_report_params(path=None) -> jnp.ndarray:
    """``(17, 10)`` report parameters derived from ``krang_2018.urdf`` (see the module docstring)."""
    urdf = load_urdf(krang_2018_pitch_urdf(path, exact_angles=True))
    rows = []
    for link, joint in zip(REPORT_LINKS, REPORT_JOINTS):
        p = urdf.inertia[urdf.joint_names.index(REPORT_TO_URDF[joint][0])]
        rows.append(rotate_origin_params(p, REPORT_FROM_URDF[link]) if link in REPORT_FROM_URDF else p)
    return jnp.stack(rows)


def krang_urdf(name: str = "krang_fixed_wheel_2018-04.urdf", *, gravity=(0.0, -9.81, 0.0),
               **terms) -> TreeModel:
    """Form (b): a shipped Krang URDF (file name in the data folder, or a path) through the loader."""
    path = Path(name) if Path(name).is_file() else urdf_path(name)
    return load_urdf(path, gravity=gravity, **terms)
