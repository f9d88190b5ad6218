"""Physical parameter values of a tree, checked where a rollout starts (:func:`particlesim.simulate`).

A model's constructor and :meth:`~.model.TreeModel.with_params` (for links given by name) check concrete values, but
a leaf replaced as a whole array (``with_params(inertia=...)``, ``eqx.tree_at``) and any value set under a trace
(a fit, a ``vmap`` over parameter sets) reach the dynamics unchecked, where a negative mass or an indefinite inertia
runs silently into a wrong or NaN trajectory. :func:`physical_checks_eager` refuses concrete values before a run
(:class:`~particlesim.errors.InertiaError` or :class:`~particlesim.errors.ModelError`, naming the link or joint);
:func:`physical_checks` gives the same tests as run-time flags for traced values (JAX's run-time error under ``jit``).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from ..errors import InertiaError, ModelError
from .._namespace import xp_of
from ..inertia import physical_inertia, unpack_params
from .model import TreeModel, origin_params_check

__all__ = ["physical_checks", "physical_checks_eager"]

#: Joint-space leaves that must be non-negative, with their names in messages (one entry per velocity coordinate).
NON_NEGATIVE = {"viscous": "viscous friction", "coulomb": "Coulomb friction", "rotor_inertia": "rotor inertia",
                "stiffness": "joint stiffness"}

_UNIT = np.array([1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 1.0, 0.0, 1.0])  # a stand-in for massless rows


def _links_physical(inertia):
    """Per link (rows ``(n, 10)`` about the link origin): an exactly zero row (a massless link), or a physical body
    by :func:`~.model.origin_params_check`'s conditions and tolerances (the shift to the centre of mass allowed its
    rounding). Traceable (no derivative passes through it); NumPy in, NumPy out."""
    xp = xp_of(inertia)
    p = xp.asarray(inertia)
    if not xp.issubdtype(p.dtype, xp.floating):  # integers set by hand: judged as floats
        p = p.astype(float)
    if xp is not np:
        p = jax.lax.stop_gradient(p)
    zero = xp.all(p == 0.0, axis=-1)
    safe = xp.where(zero[..., None], xp.asarray(_UNIT, dtype=p.dtype), p)
    m, h, j = unpack_params(safe)
    c = h / xp.where(m == 0.0, 1.0, m)[..., None]  # a zero mass is refused below (m > 0): no 0/0 on the way
    cc = xp.sum(c * c, axis=-1)
    shift = cc[..., None, None] * xp.broadcast_to(xp.eye(3), j.shape) - c[..., :, None] * c[..., None, :]
    i_com = j - m[..., None, None] * shift
    rounding = 16 * jnp.finfo(p.dtype).eps * (xp.abs(xp.trace(j, axis1=-2, axis2=-1)) + m * cc)  # (float32 too)
    return zero | (physical_inertia(m, i_com, rounding) & xp.all(xp.isfinite(p), axis=-1))


def physical_checks(model: TreeModel, entry: str = "simulate") -> tuple | None:
    """Run-time flags of non-physical values, with their messages (for :func:`particlesim._ode.runtime_checks`): a
    link whose inertial parameters are not a physical body or exactly zero (models built with checked inertias
    only), a joint that moves no mass, a negative friction level, rotor inertia or joint stiffness, a soft limit
    with a negative stiffness or damping or its lower bound above its upper one."""
    flags, msgs = [], []
    if model.inertia_checked:
        flags.append(~_links_physical(model.inertia))
        msgs += [f"{entry}: link '{n}' is not physical: its inertial parameters must be zero (a massless link) or a "
                 "positive mass with an inertia about the centre of mass that is symmetric, positive semi-definite "
                 "and meets the triangle inequality (a value set under a trace, which is not checked when set)"
                 for n in model.link_names]
    moved = jnp.asarray(model.support.T, dtype=float) @ jax.lax.stop_gradient(model.inertia[:, 0])
    flags.append(~(moved > 0.0))
    msgs += [f"{entry}: joint '{n}' moves no mass (its link and every link after it are massless): the mass "
             "matrix would be singular" for n in model.joint_names]
    coords = model.velocity_names
    for field, label in NON_NEGATIVE.items():
        v = getattr(model, field)
        if v is not None:
            flags.append(~(jax.lax.stop_gradient(v) >= 0.0))
            msgs += [f"{entry}: {label} of joint '{n}' is negative: it would feed energy in" for n in coords]
    if model.limits is not None:
        lim = jax.lax.stop_gradient(model.limits)
        flags.append(~((lim[:, 0] <= lim[:, 1]) & (lim[:, 2] >= 0.0) & (lim[:, 3] >= 0.0)))
        msgs += [f"{entry}: limits of '{n}': need lower <= upper and non-negative stiffness and damping"
                 for n in coords]
    return jnp.concatenate(flags), msgs


def physical_checks_eager(model: TreeModel, entry: str = "simulate") -> None:
    """:func:`physical_checks` on concrete values, raising before any run: :class:`~particlesim.errors.InertiaError`
    for a link (:func:`~.model.origin_params_check`) or a joint that moves no mass,
    :class:`~particlesim.errors.ModelError` for the joint-space values."""
    inertia = np.asarray(model.inertia)
    if model.inertia_checked:
        for k in np.flatnonzero(~_links_physical(inertia)):  # all links at once (one by one is much slower)
            # raises for the link, in the constructor's words (which decide at the tolerance's edge)
            origin_params_check(inertia[k], f"{entry}: link '{model.link_names[k]}'")
    moved = model.support.T.astype(float) @ inertia[:, 0]
    for i, name in enumerate(model.joint_names):
        if not moved[i] > 0.0:
            raise InertiaError(f"{entry}: joint '{name}' moves no mass (link '{model.link_names[i]}' and every link "
                               "after it are massless): the mass matrix would be singular")
    coords = model.velocity_names
    for field, label in NON_NEGATIVE.items():
        v = getattr(model, field)
        if v is not None:
            v = np.asarray(v)
            for n, x in zip(coords, v):
                if not x >= 0.0:
                    raise ModelError(f"{entry}: {label} of joint '{n}' is negative ({float(x)!r}): it would feed "
                                     "energy in; friction levels, rotor inertias and stiffnesses are non-negative")
    if model.limits is not None:
        for n, (lo, hi, k, d) in zip(coords, np.asarray(model.limits)):
            if not (lo <= hi and k >= 0.0 and d >= 0.0):
                raise ModelError(f"{entry}: limits of '{n}': need lower <= upper and non-negative stiffness and "
                                 f"damping, got {[float(x) for x in (lo, hi, k, d)]}")
