"""MJCF import into a :class:`~particlesim.tree.TreeModel`, through MuJoCo's own compiler.

MuJoCo compiles the file (defaults, classes, includes, inertias from geoms, ``fusestatic`` ... exactly as MuJoCo
itself would), and the compiled ``MjModel`` is read back:

* a body with one hinge or slide joint becomes one link; a body with several joints becomes a chain of links, the
  first ones massless (as MuJoCo, each joint moves the body about its own anchor, in the order written); a hinge
  turns about an axis through its anchor, so the link frame is the body frame moved to the anchor;
* a body without joints is welded to its parent (its inertia added, its name kept as a frame);
* a ``ball`` joint becomes a ball joint (``q = [qx, qy, qz, qw]``, ``qd = w`` in the body's axes);
* a ``freejoint`` on a root body becomes a free joint (``q = [x, y, z, qx, qy, qz, qw]`` with the quaternion in
  Pinocchio's ``xyzw`` order, ``qd = [v, w]`` both in the body's axes: MuJoCo's ``qvel`` has ``v`` in world axes;
  :func:`from_mujoco_state` converts);
* ``damping``, ``frictionloss`` and ``armature`` become viscous friction, Coulomb friction and rotor inertia,
  ``stiffness`` about ``springref`` joint springs (hinge, slide, ball);
  ``<equality><joint>`` couplings with a linear polynomial become mimic joints; gravity comes from ``<option>``.

Not imported: springs on free joints, nonlinear (polynomial) stiffness or damping, tendons with armature,
stiffness, damping or friction loss, and equality constraints other than linear joint couplings are refused by
name; other tendons and actuators are left out with a warning (their forces enter through the control); contacts
are not modelled. ``<option><flag>`` switches for gravity, springs, dampers and friction loss are honoured. Joint
ranges are not modelled (:class:`~particlesim.io.urdf.UnmodelledLimitsWarning`, as for URDF).
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path
from typing import Union

import mujoco
import numpy as np

from ..errors import ModelError, ParseError
from ..inertia import origin_params
from ..spatial import quaternion_to_matrix
from ..tree.model import BALL, FREE, PRISMATIC, REVOLUTE, TreeModel
from .urdf import UnmodelledLimitsWarning

__all__ = ["load_mjcf", "from_mujoco_state", "joint_ids", "UnmodelledElementsWarning"]


class UnmodelledElementsWarning(UserWarning):
    """An MJCF model has elements (tendons, actuators) that the imported tree does not carry."""


def _quat_wxyz(q) -> np.ndarray:
    """Rotation of a MuJoCo quaternion ``[w, x, y, z]``."""
    q = np.asarray(q, dtype=float)
    return np.asarray(quaternion_to_matrix(np.array([q[1], q[2], q[3], q[0]])))


def _compile(source) -> tuple[str, mujoco.MjModel]:
    if isinstance(source, mujoco.MjModel):
        return "<MjModel>", source
    if isinstance(source, str) and not source.strip():
        raise ParseError("empty MJCF source: give a file path or the MJCF XML text")
    text = isinstance(source, str) and source.lstrip().startswith("<")
    label = "<mjcf string>" if text else str(source)
    try:
        m = mujoco.MjModel.from_xml_string(source) if text else mujoco.MjModel.from_xml_path(str(Path(source)))
    except ValueError as e:
        raise ParseError(f"{label}: MuJoCo cannot compile it: {e}") from None
    return label, m


def _names(m, obj, count, fallback) -> list:
    """Element names; unnamed elements get ``fallback + index`` (prefixed with ``_`` until no named one uses it)."""
    given = [mujoco.mj_id2name(m, obj, i) for i in range(count)]
    out = []
    for i, g in enumerate(given):
        alt = f"{fallback}{i}"
        while not g and (alt in given or alt in out):
            alt = "_" + alt
        out.append(g or alt)
    return out


def mimic_names(m: mujoco.MjModel, joint_names) -> set:
    """Joints that active ``<equality><joint>`` couplings make followers."""
    return {joint_names[int(m.eq_obj1id[e])] for e in range(m.neq)
            if m.eq_active0[e] and m.eq_type[e] == mujoco.mjtEq.mjEQ_JOINT}


def joint_ids(model: TreeModel, m: mujoco.MjModel) -> list:
    """MuJoCo's joint id of every joint of ``model`` (from :func:`load_mjcf` of ``m``), in the model's order."""
    names = _names(m, mujoco.mjtObj.mjOBJ_JOINT, m.njnt, "joint")
    return [names.index(jn) for jn in model.joint_names]


def load_mjcf(source: Union[str, os.PathLike, mujoco.MjModel], *, limits: str = "warn",
              friction: bool = True, limit_stiffness=None, limit_damping=None) -> TreeModel:
    """Build a :class:`TreeModel` from an MJCF file path, MJCF XML text or a compiled ``mujoco.MjModel``.

    ``friction=False`` drops ``damping``/``frictionloss``/``armature``. ``limits``, ``limit_stiffness`` and
    ``limit_damping`` as in :func:`~particlesim.io.urdf.load_urdf` (``"model"`` turns hinge and slide ranges into
    soft limits; ball-joint cone limits stay unmodelled and are warned about). Raises :class:`ParseError` naming the body or joint for what the tree
    model cannot represent (see the module docstring).
    """
    if limits not in ("warn", "ignore", "model"):
        raise ValueError(f"limits must be 'warn', 'ignore' or 'model', got {limits!r}")
    if (limits == "model") != (limit_stiffness is not None and limit_damping is not None):
        raise ValueError("limits='model' needs limit_stiffness and limit_damping (and they mean nothing without it)")
    label, m = _compile(source)

    body_names = _names(m, mujoco.mjtObj.mjOBJ_BODY, m.nbody, "body")
    joint_names = _names(m, mujoco.mjtObj.mjOBJ_JOINT, m.njnt, "joint")
    links = []  # dicts: name, joint, kind, parent link, R0, p0, axis, dof
    owner = {0: -1}  # body -> link that carries it (-1: the world)
    body_in_owner = {0: (np.eye(3), np.zeros(3))}  # body frame in its owner's link frame
    inertia = {}
    frames = []
    for b in range(1, m.nbody):
        par = int(m.body_parentid[b])
        rp, pp = body_in_owner[par]
        r, p = rp @ _quat_wxyz(m.body_quat[b]), pp + rp @ m.body_pos[b]  # body frame before its joints
        adr, num = int(m.body_jntadr[b]), int(m.body_jntnum[b])
        parent_link = owner[par]
        anchor = np.zeros(3)  # the current link frame = body frame (after earlier joints) moved to this point
        for j in range(adr, adr + num):
            jt, jn = int(m.jnt_type[j]), joint_names[j]
            if jt == mujoco.mjtJoint.mjJNT_FREE:  # MuJoCo's compiler allows it only alone on a top-level body
                links.append(dict(name=body_names[b], joint=jn, kind=FREE, parent=-1, r0=np.eye(3), p0=np.zeros(3),
                                  axis=np.array([1.0, 0.0, 0.0]), jnt=j))
                owner[b], body_in_owner[b] = len(links) - 1, (np.eye(3), np.zeros(3))
                break
            turns = jt in (mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_BALL)
            new_anchor = m.jnt_pos[j].astype(float) if turns else anchor
            if j == adr:  # from the parent link: the body's placement, then to the anchor
                r0, p0 = r, p + r @ new_anchor
            else:  # from the previous joint's link (same body axes): the anchors' difference
                r0, p0 = np.eye(3), new_anchor - anchor
            ball = jt == mujoco.mjtJoint.mjJNT_BALL
            ref = 0.0 if ball else float(m.qpos0[m.jnt_qposadr[j]])  # a hinge/slide moves by q - qpos0 (``ref``)
            ax = m.jnt_axis[j].astype(float) / np.linalg.norm(m.jnt_axis[j])
            if ref and jt == mujoco.mjtJoint.mjJNT_HINGE:
                c, s_, k = np.cos(-ref), np.sin(-ref), np.array([[0, -ax[2], ax[1]], [ax[2], 0, -ax[0]],
                                                                   [-ax[1], ax[0], 0]])
                r0 = r0 @ (np.eye(3) + s_ * k + (1 - c) * k @ k)
            elif ref:
                p0 = p0 - r0 @ ax * ref
            last = j == adr + num - 1
            links.append(dict(name=body_names[b] if last else f"{body_names[b]}/{jn}", joint=jn,
                              kind=BALL if ball else REVOLUTE if jt == mujoco.mjtJoint.mjJNT_HINGE else PRISMATIC,
                              parent=parent_link, r0=r0, p0=p0, axis=ax, jnt=j))
            parent_link, anchor = len(links) - 1, new_anchor
        else:
            if num:
                owner[b], body_in_owner[b] = parent_link, (np.eye(3), -anchor)
            else:  # welded: its frame in the owner's link frame
                owner[b], body_in_owner[b] = owner[par], (r, p)
                frames.append((body_names[b], owner[par], r, p))
        if m.body_mass[b] > 0 or np.any(m.body_inertia[b]):
            o = owner[b]
            if o < 0:
                continue  # welded to the world
            rb, pb = body_in_owner[b]
            ri = rb @ _quat_wxyz(m.body_iquat[b])
            c = pb + rb @ m.body_ipos[b]
            i_com = ri @ np.diag(m.body_inertia[b]) @ ri.T
            inertia[o] = inertia.get(o, 0.0) + origin_params(float(m.body_mass[b]), c, i_com)
    if not links:
        raise ParseError(f"{label}: the model has no joints (nothing moves)")
    n = len(links)
    limited = [joint_names[lk["jnt"]] for lk in links if lk["kind"] != FREE and m.jnt_limited[lk["jnt"]]]
    soft = None
    if limits == "model":  # hinge and slide ranges as soft limits; a ball's cone limit is not representable
        soft, modelled = [], set()
        for lk in links:
            j, w = lk["jnt"], {FREE: 6, BALL: 3}.get(lk["kind"], 1)
            if lk["joint"] in mimic_names(m, joint_names):
                continue
            on = w == 1 and m.jnt_limited[j]
            soft += [[*(m.jnt_range[j] if on else (-np.inf, np.inf)), 0.0, 0.0]] * w
            modelled |= {joint_names[j]} if on else set()
        soft = np.array(soft)
        for col, (arg, value) in ((2, ("limit_stiffness", limit_stiffness)), (3, ("limit_damping", limit_damping))):
            v = np.asarray(value, dtype=float)
            if v.shape not in ((), (len(soft),)):
                raise ValueError(f"{arg} must be one value or one per velocity coordinate ({len(soft)}), got "
                                 f"shape {v.shape}")
            soft[:, col] = v
        limited = [x for x in limited if x not in modelled]
    if limited and limits != "ignore":
        warnings.warn(f"{label}: joint ranges of {len(limited)} joint(s) are not modelled (e.g. "
                      f"{', '.join(repr(x) for x in limited[:4])}): the joints move freely past them. Pass "
                      "limits='ignore' to accept this silently", UnmodelledLimitsWarning, stacklevel=2)
    # tendons with passive dynamics or armature act on the joints and are not imported: refuse; others (and
    # actuators) only matter through controls: say so
    tendon_names = _names(m, mujoco.mjtObj.mjOBJ_TENDON, m.ntendon, "tendon")
    for t in range(m.ntendon):
        if m.tendon_armature[t] or m.tendon_stiffness[t] or m.tendon_damping[t] or np.any(m.tendon_stiffnesspoly[t]) \
                or np.any(m.tendon_dampingpoly[t]) or m.tendon_frictionloss[t]:
            raise ParseError(f"{label}: tendon '{tendon_names[t]}' has armature, stiffness, damping or friction loss, "
                             "which act on the joints and are not imported")
    if m.ntendon or m.nu:
        warnings.warn(f"{label}: {m.ntendon} tendon(s) and {m.nu} actuator(s) are not imported: apply their forces "
                      "through the control", UnmodelledElementsWarning, stacklevel=2)
    bad = [joint_names[j] for j in range(m.njnt) if np.any(m.jnt_stiffnesspoly[j])]
    bad += [joint_names[m.dof_jntid[v]] for v in range(m.nv) if np.any(m.dof_dampingpoly[v])]
    if bad:
        raise ParseError(f"{label}: nonlinear joint stiffness or damping (polynomial terms) is not imported "
                         f"(joints {sorted(set(bad))})")
    disabled = int(m.opt.disableflags)
    off = {flag: bool(disabled & int(getattr(mujoco.mjtDisableBit, f"mjDSBL_{flag}")))
           for flag in ("GRAVITY", "SPRING", "DAMPER", "FRICTIONLOSS")}
    mimic = {}
    for e in range(m.neq):
        if not m.eq_active0[e]:
            continue
        if m.eq_type[e] != mujoco.mjtEq.mjEQ_JOINT:
            raise ParseError(f"{label}: equality constraint {e} ({mujoco.mjtEq(m.eq_type[e]).name}) is not a joint "
                             "coupling; only <equality><joint> with a linear polycoef is imported")
        j1, j2, coef = int(m.eq_obj1id[e]), int(m.eq_obj2id[e]), m.eq_data[e][:5]
        if j2 < 0 or np.any(coef[2:]):
            raise ParseError(f"{label}: joint coupling of '{joint_names[j1]}' is not linear in a second joint")
        # MuJoCo: q1 - q1_0 = c0 + c1 (q2 - q2_0), with the reference positions qpos0
        q10, q20 = m.qpos0[m.jnt_qposadr[j1]], m.qpos0[m.jnt_qposadr[j2]]
        mimic[joint_names[j1]] = (joint_names[j2], float(coef[1]), float(q10 + coef[0] - coef[1] * q20))
    order = [lk["jnt"] for lk in links]
    width = {FREE: 6, BALL: 3}
    dofs = np.concatenate([np.arange(m.jnt_dofadr[j], m.jnt_dofadr[j] + width.get(links[i]["kind"], 1))
                           for i, j in enumerate(order) if joint_names[j] not in mimic])
    extra = {}
    if friction:
        for key, field, fold in (("viscous", m.dof_damping, "sq"), ("coulomb", m.dof_frictionloss, "abs"),
                                 ("rotor_inertia", m.dof_armature, "sq")):
            vals = np.asarray(field, dtype=float).copy()
            if (key == "viscous" and off["DAMPER"]) or (key == "coulomb" and off["FRICTIONLOSS"]):
                continue  # disabled by <option><flag>
            for jn, (src, mult, _) in mimic.items():  # a follower's term acts on its source, as in load_urdf
                vals[m.jnt_dofadr[joint_names.index(src)]] += (mult * mult if fold == "sq" else abs(mult)) * \
                    vals[m.jnt_dofadr[joint_names.index(jn)]]
            if np.any(vals):
                for i, lk in enumerate(links):
                    if lk["kind"] == FREE and np.any(vals[m.jnt_dofadr[lk["jnt"]]:m.jnt_dofadr[lk["jnt"]] + 6]):
                        raise ParseError(f"{label}: free joint '{lk['joint']}' has damping, frictionloss or armature, "
                                         "which are not imported on a floating base")
                extra[key] = vals[dofs]
    if np.any(m.jnt_stiffness[order] != 0.0) and not off["SPRING"]:  # joint springs about qpos_spring, per velocity coordinate
        k, ref = [], []
        for lk in links:
            j, kind = lk["jnt"], lk["kind"]
            if m.jnt_stiffness[j] != 0.0 and (kind == FREE or lk["joint"] in mimic):
                what = "a free joint" if kind == FREE else "a coupled joint"
                raise ParseError(f"{label}: joint '{lk['joint']}' has stiffness, which is not imported on {what}")
            if lk["joint"] in mimic:
                continue
            a = int(m.jnt_qposadr[j])
            k += [float(m.jnt_stiffness[j])] * width.get(kind, 1)
            ref += (list(m.qpos_spring[a:a + 3]) + [*m.qpos_spring[a + 4:a + 7], m.qpos_spring[a + 3]]
                    if kind == FREE else [*m.qpos_spring[a + 1:a + 4], m.qpos_spring[a]] if kind == BALL
                    else [m.qpos_spring[a]])
        extra["stiffness"], extra["spring_ref"] = np.array(k), np.array(ref)
    try:
        return TreeModel(
            parents=[lk["parent"] for lk in links],
            kinds=[lk["kind"] for lk in links],
            axes=np.array([lk["axis"] for lk in links]).reshape(n, 3),
            origin_rotations=np.array([lk["r0"] for lk in links]).reshape(n, 3, 3),
            origin_xyz=np.array([lk["p0"] for lk in links]).reshape(n, 3),
            inertia=np.array([inertia.get(i, np.zeros(10)) for i in range(n)]),
            gravity=np.zeros(3) if off["GRAVITY"] else np.asarray(m.opt.gravity, dtype=float),
            link_names=[lk["name"] for lk in links],
            joint_names=[lk["joint"] for lk in links],
            frames=frames,
            mimic=mimic,
            limits=soft,
            **extra,
        )
    except ModelError as e:
        raise type(e)(f"{label}: {e}") from None


def from_mujoco_state(model: TreeModel, m: mujoco.MjModel, qpos, qvel) -> tuple[np.ndarray, np.ndarray]:
    """``(q, qd)`` of ``model`` (from :func:`load_mjcf` of ``m``) at MuJoCo's ``(qpos, qvel)``: free joints'
    quaternions reordered ``wxyz -> xyzw`` and linear velocities turned from world into body axes; mimic joints
    dropped."""
    qpos, qvel = np.asarray(qpos, dtype=float), np.asarray(qvel, dtype=float)
    q, qd = [], []
    for j, kind, mim in zip(joint_ids(model, m), model.kinds, model.mimic):
        if mim:
            continue
        a, d = int(m.jnt_qposadr[j]), int(m.jnt_dofadr[j])
        if kind == FREE:
            quat = qpos[a + 3:a + 7]
            rot = _quat_wxyz(quat)
            q += [*qpos[a:a + 3], *quat[1:], quat[0]]
            qd += [*(rot.T @ qvel[d:d + 3]), *qvel[d + 3:d + 6]]
        elif kind == BALL:
            q += [*qpos[a + 1:a + 4], qpos[a]]
            qd += list(qvel[d:d + 3])
        else:
            q.append(qpos[a])
            qd.append(qvel[d])
    return np.array(q), np.array(qd)
