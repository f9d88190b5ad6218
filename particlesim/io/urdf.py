"""URDF import into a :class:`~particlesim.tree.TreeModel` (``xml.etree``; visual/collision ignored).

Supported joints: ``revolute``/``continuous`` (both revolute; position limits modelled on request, else warned),
``prismatic`` and ``fixed``. ``<dynamics damping friction>`` become viscous and Coulomb friction.
Fixed joints are merged away: a link welded to a moving link adds its inertia to that link (the report's
10-vectors about a common origin simply add), and the joints below it are re-expressed in that link's frame; the
merged link keeps its name as a frame (``frame_pose``, ``link_jacobian``: ``tool0``, ``panda_hand``).
Links welded to the root are part of the world; the root link is fixed to the world at identity unless
``floating_base=True`` puts it on a free joint.

URDF conventions (ROS): a joint places its child at ``origin`` (``xyz``, then ``rpy`` with ``R = Rz Ry Rx``),
followed by the joint motion about/along ``axis`` (child frame, normalised here); ``<inertial>`` gives the mass,
the CoM pose in the link frame and the inertia about the CoM in the axes of that pose.

Joint order of the model = the document order of the movable joints. A joint with ``<mimic joint= multiplier=
offset=>`` follows its source (``q = multiplier q_source + offset``) and has no coordinate of its own (as
Pinocchio's ``mimic=True``); its damping, friction and rotor inertia are folded exactly into the source's
(``multiplier^2 Fv``, ``|multiplier| Fc``). ``mimic=False`` keeps every mimic joint as an independent joint.
"""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Optional, Union

import numpy as np

from ..errors import InertiaError, InertiaWarning, ModelError, ParseError
from ..inertia import balance_inertia, check_inertia, origin_params, sym_from_six
from ..spatial import rpy_to_matrix
from ..tree.model import FREE, PRISMATIC, REVOLUTE, TreeModel

__all__ = ["load_urdf", "UnmodelledLimitsWarning"]

_KINDS = {"revolute": REVOLUTE, "continuous": REVOLUTE, "prismatic": PRISMATIC, "fixed": None}


def _floats(text: Optional[str], n: int, default, where: str) -> np.ndarray:
    if text is None:
        return np.asarray(default, dtype=float)
    try:
        v = np.array([float(t) for t in text.split()], dtype=float)
    except ValueError:
        raise ParseError(f"{where}: cannot read numbers from {text!r}") from None
    if v.shape != (n,) or not np.all(np.isfinite(v)):
        raise ParseError(f"{where}: expected {n} finite numbers, got {text!r}")
    return v


def _pose(elem, where: str):
    if elem is None:
        return np.eye(3), np.zeros(3)
    xyz = _floats(elem.get("xyz"), 3, np.zeros(3), f"{where} origin xyz")
    rpy = _floats(elem.get("rpy"), 3, np.zeros(3), f"{where} origin rpy")
    return np.asarray(rpy_to_matrix(rpy)), xyz


def _inertial(link, name: str):
    """``(m, com, I_com)`` in the link frame, or None without ``<inertial>``."""
    inr = link.find("inertial")
    if inr is None:
        return None
    where = f"link '{name}' inertial"
    mass_el = inr.find("mass")
    if mass_el is None or mass_el.get("value") is None:
        raise ParseError(f"{where}: missing <mass value=...>")
    m = _floats(mass_el.get("value"), 1, None, f"{where} mass")[0]
    r, c = _pose(inr.find("origin"), where)
    it = inr.find("inertia")
    keys = ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
    if it is None:
        raise ParseError(f"{where}: missing <inertia .../>")
    vals = [_floats(it.get(k, "0"), 1, None, f"{where} {k}")[0] for k in keys]
    return m, c, r @ sym_from_six(np.array(vals)) @ r.T


def read_urdf(source: Union[str, os.PathLike]):
    """``(label, root element)`` of a URDF path or string; :class:`ParseError` if unreadable or not a <robot>."""
    if isinstance(source, str) and not source.strip():
        raise ParseError("empty URDF source: give a file path or the URDF XML text")
    if isinstance(source, str) and source.lstrip().startswith("<"):
        label, text = "<urdf string>", source
    else:
        label = str(source)
        try:
            text = Path(source).read_text()
        except OSError as e:
            raise ParseError(f"{label}: cannot read URDF file: {e}") from None
    try:
        root = ET.fromstring(text)
    except ET.ParseError as e:
        raise ParseError(f"{label}: not well-formed XML: {e}") from None
    if root.tag != "robot":
        raise ParseError(f"{label}: root element is <{root.tag}>, expected <robot>")
    return label, root


class UnmodelledLimitsWarning(UserWarning):
    """A URDF declares joint position limits, which the model does not enforce."""


def load_urdf(source: Union[str, os.PathLike], gravity=(0.0, 0.0, -9.81), *, viscous=None, coulomb=None,
              rotor_inertia=None, limits: str = "warn", mimic: bool = True, inertia: str = "strict",
              floating_base: bool = False, limit_stiffness=None, limit_damping=None) -> TreeModel:
    """Build a :class:`TreeModel` from a URDF file path or a URDF XML string.

    ``gravity`` is in the frame of the root link. Joint friction: the file's ``<dynamics damping=... friction=...>``
    become the model's ``viscous`` (N m s/rad) and ``coulomb`` (N m) levels (eq. 17) unless given here (an
    argument replaces the file's values for every joint); ``rotor_inertia`` (eq. 18) is not a URDF field; these arguments have one entry per coordinate. ``mimic=True``
    (default) reduces ``<mimic>`` joints to their sources (``model.nq`` counts coordinates, ``model.n_joints``
    joints); ``mimic=False`` keeps them independent. Joint
    position limits are not modelled by default: ``limits="warn"`` (default) warns
    (:class:`UnmodelledLimitsWarning`) naming the limited joints, ``"ignore"`` accepts that silently, and
    ``"model"`` makes them soft limits (``TreeModel.limits``: a one-sided spring-damper beyond each bound) with
    ``limit_stiffness`` (N m/rad or N/m) and ``limit_damping`` (N m s/rad or N s/m), one value or one per coordinate
    (both required). Raises :class:`ParseError` naming the link/joint for
    unparsable files, unsupported joint types, duplicate names and kinematic loops.

    ``floating_base=True`` joins the root link to the world by a free joint named ``'root_joint'`` (Pinocchio's
    ``JointModelFreeFlyer``): ``q = [x, y, z, qx, qy, qz, qw, joints...]`` (``nq = 7 + n``) and
    ``qd = [v, w, joints...]`` with the root's linear and angular velocity in its own axes (``nv = 6 + n``);
    friction and rotor-inertia arguments then have ``nv`` entries. Without it the root is fixed to the world.

    Inertias: a link without ``<inertial>`` (or with zero mass and inertia) is massless, accepted as long as every
    joint moves some mass (the usual way to write a spherical joint as three revolutes). ``inertia="strict"``
    (default) raises :class:`~particlesim.errors.InertiaError` naming the link for a non-physical inertia (negative
    or zero mass with inertia, a tensor that is not positive semi-definite, principal moments violating a triangle
    inequality); ``"balance"`` repairs such tensors as MuJoCo's ``balanceinertia`` does (negative principal moments
    clipped to zero, then all three set to their mean if a triangle inequality fails) and ``"warn"`` loads them
    unchanged; both warn (:class:`~particlesim.errors.InertiaWarning`) naming every such link. A zero mass with a
    nonzero tensor (as some files write a sensor frame) is refused, except that ``"balance"`` loads the link as
    massless (the tensor dropped, the link named in the warning); negative masses are refused in every mode.
    """
    if limits not in ("warn", "ignore", "model"):
        raise ValueError(f"limits must be 'warn', 'ignore' or 'model', got {limits!r}")
    if (limits == "model") != (limit_stiffness is not None and limit_damping is not None):
        raise ValueError("limits='model' needs limit_stiffness and limit_damping (and they mean nothing without it)")
    if inertia not in ("strict", "balance", "warn"):
        raise ValueError(f"inertia must be 'strict', 'balance' or 'warn', got {inertia!r}")
    label, root = read_urdf(source)
    links = {}
    for el in root.findall("link"):
        name = el.get("name")
        if name is None:
            raise ParseError(f"{label}: a <link> has no name")
        if name in links:
            raise ParseError(f"{label}: link '{name}' is defined twice")
        links[name] = el
    if not links:
        raise ParseError(f"{label}: the robot has no <link>")
    joints, parent_joint, seen_names = [], {}, set()
    for el in root.findall("joint"):
        name, jtype = el.get("name"), el.get("type")
        where = f"{label}: joint '{name}'"
        if name in seen_names:
            raise ParseError(f"{where} is defined twice")
        seen_names.add(name)
        if jtype not in _KINDS:
            raise ParseError(f"{where} has unsupported type {jtype!r} (supported: {sorted(_KINDS)})")
        try:
            parent, child = el.find("parent").get("link"), el.find("child").get("link")
        except AttributeError:
            raise ParseError(f"{where}: missing <parent link=...> or <child link=...>") from None
        for ln in (parent, child):
            if ln not in links:
                raise ParseError(f"{where} refers to undefined link '{ln}'")
        if child in parent_joint:
            raise ParseError(f"{label}: link '{child}' has two parents (joints '{parent_joint[child]}' and "
                             f"'{name}'): kinematic loops are not supported")
        parent_joint[child] = name
        r0, p0 = _pose(el.find("origin"), where)
        axis = np.array([1.0, 0.0, 0.0])
        if _KINDS[jtype] is not None:
            ax_el = el.find("axis")
            axis = _floats(None if ax_el is None else ax_el.get("xyz"), 3, axis, f"{where} axis")
            nrm = np.linalg.norm(axis)
            if nrm < 1e-12:
                raise ParseError(f"{where}: axis is zero")
            axis = axis / nrm
        dyn = el.find("dynamics")
        damping = _floats(None if dyn is None else dyn.get("damping"), 1, [0.0], f"{where} dynamics damping")[0]
        friction = _floats(None if dyn is None else dyn.get("friction"), 1, [0.0], f"{where} dynamics friction")[0]
        if damping < 0 or friction < 0:
            raise ParseError(f"{where}: dynamics damping and friction must be non-negative, got {damping!r}, "
                             f"{friction!r}")
        mim = el.find("mimic")
        follows = None
        if mim is not None and mimic and _KINDS[jtype] is not None:
            if mim.get("joint") is None:
                raise ParseError(f"{where}: <mimic> has no joint= attribute")
            if mim.get("joint") == name:
                raise ParseError(f"{where} mimics itself")
            follows = (mim.get("joint"),
                       _floats(mim.get("multiplier"), 1, [1.0], f"{where} mimic multiplier")[0],
                       _floats(mim.get("offset"), 1, [0.0], f"{where} mimic offset")[0])
        lim = el.find("limit")
        limited = jtype in ("revolute", "prismatic") and lim is not None and (
            lim.get("lower") is not None or lim.get("upper") is not None)
        bounds = (_floats(lim.get("lower"), 1, [-np.inf], f"{where} limit lower")[0],
                  _floats(lim.get("upper"), 1, [np.inf], f"{where} limit upper")[0]) if limited else (-np.inf, np.inf)
        joints.append(dict(name=name, kind=_KINDS[jtype], parent=parent, child=child, r0=r0, p0=p0, axis=axis,
                           damping=damping, friction=friction, limited=limited, mimic=follows, bounds=bounds))
    roots = [ln for ln in links if ln not in parent_joint]
    if len(roots) != 1:
        raise ParseError(f"{label}: expected one root link, found {roots or 'none (kinematic loop)'}")
    movable = [jt for jt in joints if jt["kind"] is not None]
    if floating_base:  # the root link becomes a moving body on a free joint (Pinocchio's name for it)
        if "root_joint" in seen_names:
            raise ParseError(f"{label}: a joint is already named 'root_joint', the name of the floating base's joint")
        movable.insert(0, dict(name="root_joint", kind=FREE, parent=None, child=roots[0], axis=np.array([1.0, 0, 0]),
                               damping=0.0, friction=0.0, limited=False, mimic=None, bounds=(-np.inf, np.inf)))
    index = {jt["name"]: i for i, jt in enumerate(movable)}
    # Walk the tree from the root: owner body (-1 = world) and pose of every link in its owner's frame.
    owner = {roots[0]: 0 if floating_base else -1}
    pose = {roots[0]: (np.eye(3), np.zeros(3))}
    placement = {"root_joint": (-1, np.eye(3), np.zeros(3))} if floating_base else {}
    children = {}
    for jt in joints:
        children.setdefault(jt["parent"], []).append(jt)
    stack, seen = [roots[0]], {roots[0]}
    while stack:
        ln = stack.pop()
        rp, pp = pose[ln]
        for jt in children.get(ln, []):
            c = jt["child"]
            if c in seen:
                raise ParseError(f"{label}: joint '{jt['name']}' closes a kinematic loop at link '{c}'")
            seen.add(c)
            r_o, p_o = rp @ jt["r0"], pp + rp @ jt["p0"]
            if jt["kind"] is None:
                owner[c], pose[c] = owner[ln], (r_o, p_o)
            else:
                owner[c], pose[c] = index[jt["name"]], (np.eye(3), np.zeros(3))
                placement[jt["name"]] = (owner[ln], r_o, p_o)
            stack.append(c)
    unreached = [ln for ln in links if ln not in seen]
    if unreached:
        raise ParseError(f"{label}: links {unreached} are not connected to the root '{roots[0]}' (kinematic loop)")
    n = len(movable)
    mimics = {jt["name"]: jt["mimic"] for jt in movable if jt["mimic"] is not None}
    for name, (src, _, _) in mimics.items():
        if src not in index:
            raise ParseError(f"{label}: joint '{name}' mimics '{src}', which is not a movable joint of the file")
    coords = [jt for jt in movable if jt["mimic"] is None and jt["kind"] != FREE]
    damping = {jt["name"]: jt["damping"] for jt in coords}
    friction = {jt["name"]: jt["friction"] for jt in coords}
    for jt in movable:  # a mimic joint's bearing acts on its source: G^T diag(F) G
        if jt["mimic"] is not None:
            src, mult, seen = jt["mimic"][0], jt["mimic"][1], {jt["name"]}
            while src in mimics:
                if src in seen:
                    raise ParseError(f"{label}: mimic joints {sorted(seen)} follow each other in a cycle")
                seen.add(src)
                src, mult = mimics[src][0], mult * mimics[src][1]
            damping[src] += mult * mult * jt["damping"]
            friction[src] += abs(mult) * jt["friction"]
    base = [0.0] * 6 if floating_base else []  # no friction on the floating base's six velocities
    if viscous is None and any(damping.values()):
        viscous = base + [damping[jt["name"]] for jt in coords]
    if coulomb is None and any(friction.values()):
        coulomb = base + [friction[jt["name"]] for jt in coords]
    limited = [jt["name"] for jt in movable if jt["limited"] and (limits != "model" or jt["mimic"] is not None)]
    soft = None
    if limits == "model":  # per velocity coordinate: [lower, upper, stiffness, damping]
        nv = sum(6 if jt["kind"] == FREE else 1 for jt in movable if jt["mimic"] is None)
        soft = np.zeros((nv, 4))
        at = 0
        for jt in movable:
            if jt["mimic"] is None:
                w = 6 if jt["kind"] == FREE else 1
                soft[at:at + w, 0], soft[at:at + w, 1] = jt["bounds"]
                at += w
        for col, (arg, value) in ((2, ("limit_stiffness", limit_stiffness)), (3, ("limit_damping", limit_damping))):
            v = np.asarray(value, dtype=float)
            if v.shape not in ((), (nv,)):
                raise ValueError(f"{arg} must be one value or one per velocity coordinate ({nv}), got shape {v.shape}")
            soft[:, col] = v
    if limited and limits != "ignore":
        import warnings

        warnings.warn(f"{label}: joint position limits of {len(limited)} joint(s) are not modelled (e.g. "
                      f"{', '.join(repr(j) for j in limited[:4])}): the joints move freely past them. Pass "
                      "limits='ignore' to accept this silently", UnmodelledLimitsWarning, stacklevel=2)
    params = np.zeros((n, 10))
    flagged, dropped = [], []
    for ln, el in links.items():
        b = owner[ln]
        data = _inertial(el, ln)
        if data is None or b < 0:
            continue  # massless, or welded to the world (no dynamics)
        m, c, i_com = data
        if m == 0.0 and not np.any(i_com):
            continue  # an explicitly massless link
        if m == 0.0 and inertia == "balance":
            dropped.append(ln)  # a tensor without mass: the nearest physical body is a massless link
            continue
        try:
            check_inertia(m, c, i_com, f"link '{ln}'", degenerate_ok=True)
        except InertiaError as e:
            if inertia == "strict" or not m > 0:
                hint = "" if not m > 0 else " (inertia='balance' repairs it as MuJoCo's balanceinertia, 'warn' loads it)"
                raise InertiaError(f"{label}: {e}{hint}") from None
            if inertia == "balance":
                i_com, _ = balance_inertia(i_com)
                check_inertia(m, c, i_com, f"link '{ln}' (balanced)", degenerate_ok=True)
            flagged.append(ln)
        r, p = pose[ln]
        params[b] += origin_params(m, r @ c + p, r @ i_com @ r.T)
    if flagged:
        import warnings

        what = "repaired (principal moments balanced)" if inertia == "balance" else "loaded unchanged"
        warnings.warn(f"{label}: non-physical inertia of {len(flagged)} link(s) {what}: "
                      f"{', '.join(repr(x) for x in flagged)}", InertiaWarning, stacklevel=2)
    if dropped:
        import warnings

        warnings.warn(f"{label}: {len(dropped)} link(s) with zero mass and a nonzero inertia tensor loaded as "
                      f"massless (tensor dropped): {', '.join(repr(x) for x in dropped)}", InertiaWarning,
                      stacklevel=2)
    # every link merged by a fixed joint (or welded to the world) keeps its name as a frame of its owner
    moved = {jt["child"] for jt in movable}
    frames = [(ln, owner[ln], *pose[ln]) for ln in links if ln not in moved]
    try:
        return TreeModel(
            parents=[placement[jt["name"]][0] for jt in movable],
            kinds=[jt["kind"] for jt in movable],
            axes=np.array([jt["axis"] for jt in movable]).reshape(n, 3),
            origin_rotations=np.array([placement[jt["name"]][1] for jt in movable]).reshape(n, 3, 3),
            origin_xyz=np.array([placement[jt["name"]][2] for jt in movable]).reshape(n, 3),
            inertia=params,
            gravity=gravity,
            link_names=[jt["child"] for jt in movable],
            joint_names=[jt["name"] for jt in movable],
            viscous=viscous,
            coulomb=coulomb,
            rotor_inertia=rotor_inertia,
            frames=frames,
            mimic=mimics,
            limits=soft,
            validate_inertia=inertia != "warn",
        )
    except ModelError as e:
        raise type(e)(f"{label}: {e}") from None
