"""Static equilibrium: the rest configuration under gravity, springs, tyres and applied loads, without a pre-run.

At rest (``qd = 0``) the constrained equations reduce to ``Q(t, q, 0) = J(q)^T lam`` and ``Phi(q, t) = 0``: the
generalised forces on the free particles are carried by the constraints alone. Both are solved together for ``(q,
lam)`` by Newton's method (``optimistix``) with minimum-norm steps (``lineax.SVD``), so that directions in which the
mechanism is free to move at no cost (a car's horizontal position and heading on vertical tyres) and redundant rows
leave the step determined: the solution nearest the guess along them. The result is differentiable in the
mechanism's parameters by the implicit function theorem (``optimistix.ImplicitAdjoint``), through the same solve.
"""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
from jaxtyping import Array, Float

from .. import _ode
from ..errors import ModelError
from .constraints import constraint_jacobian, constraints
from .forces import generalized_forces, one_sided_gaps, one_sided_names
from .model import Mechanism

__all__ = ["Equilibrium", "static_equilibrium"]

#: Singular values of Newton's matrix below this fraction of the largest are taken as free directions.
RCOND = 1e-11


class Equilibrium(NamedTuple):
    """A static equilibrium: the particle positions ``q`` (3F,), the constraint multipliers ``lam`` (C,) (forces
    of the joints), the largest force imbalance ``|Q - J^T lam|`` [N] and constraint residual ``|Phi|`` [m] left,
    and the Newton steps taken."""

    q: Float[Array, " 3F"]
    lam: Float[Array, " C"]
    force_residual: Float[Array, ""]
    constraint_residual: Float[Array, ""]
    steps: Array


def _residual(y, args):
    """The force balance over a force scale and the constraints (metres): both of order one."""
    q, lam = y
    mech, t, contact, scale = args
    force = generalized_forces.raw(mech, t, q, jnp.zeros_like(q), contact=contact)
    return (force - constraint_jacobian.raw(mech, q, t=t).T @ lam) / scale, constraints.raw(mech, q, t=t)


@eqx.filter_jit
def _solve(mech, q_guess, t, contact, rtol, atol, max_steps):
    scale = jnp.maximum(jnp.sum(mech.body_mass) * jnp.linalg.norm(mech.gravity), 1.0)  # the weight [N]
    lam0 = jnp.zeros(mech.n_constraints, dtype=q_guess.dtype)
    solver = optx.Newton(rtol=rtol, atol=atol, linear_solver=lx.SVD(rcond=RCOND))
    args = (mech, t, contact, scale)
    sol = optx.root_find(_residual, solver, (q_guess, lam0), args=args, max_steps=max_steps, throw=False,
                         adjoint=optx.ImplicitAdjoint(linear_solver=lx.SVD(rcond=RCOND)))
    q, lam = sol.value
    force, phi = _residual((q, lam), args)
    force = force * scale
    gaps = one_sided_gaps(mech, mech.point_positions(mech.all_positions(q)), t)
    return (q, lam, jnp.max(jnp.abs(force), initial=0.0), jnp.max(jnp.abs(phi), initial=0.0),
            sol.stats["num_steps"], sol.result, gaps)


def static_equilibrium(mech: Mechanism, q_guess, *, t=0.0, contact=None, rtol: float = 1e-10,
                       atol: float = 1e-12, max_steps: int = 64) -> Equilibrium:
    """The static equilibrium nearest ``q_guess`` (e.g. the assembly's ``q0``) at time ``t`` (for drivers and a
    moving road); module docstring. Differentiable in ``mech``'s parameters (implicit function theorem); compiled
    once per mechanism structure. ``rtol``/``atol`` bound Newton's last step in the positions and multipliers.

    Tyres and bump stops are one-sided; Newton's method needs each one's law fixed: ``contact`` (one entry per
    tyre, then per bump stop: :func:`~.forces.one_sided_names`) says which are engaged (default: every tyre, a
    vehicle standing on its wheels, and the bump stops engaged at ``q_guess``). At the solution those must be
    engaged and the others clear, else the call raises (at run time): pass the other contact set.

    Raises (at run time) when Newton's method has not converged in ``max_steps`` steps: no equilibrium near the
    guess (a body left without support, a load its springs cannot carry)."""
    q_guess = jnp.asarray(q_guess, dtype=jnp.float64)
    if q_guess.shape != (mech.n_coords,):
        raise ModelError(f"static_equilibrium: q_guess must have shape ({mech.n_coords},) (3 coordinates per free "
                         f"particle), got {q_guess.shape}")
    if _ode._concrete(q_guess) and not np.all(np.isfinite(np.asarray(q_guess))):
        raise ModelError("static_equilibrium: q_guess has non-finite entries")
    names = one_sided_names(mech)
    if contact is None:  # tyres on the ground; bump stops as they are at the guess
        gaps = one_sided_gaps(mech, mech.point_positions(mech.all_positions(q_guess)), t)
        contact = jnp.concatenate([jnp.ones(len(mech.topo.tyre_names), bool),
                                   gaps[len(mech.topo.tyre_names):] < 0.0])
    contact = jnp.asarray(contact, bool)
    if contact.shape != (len(names),):
        raise ModelError(f"static_equilibrium: contact must have one entry per one-sided element (tyres, then bump "
                         f"stops): {list(names)}, got shape {contact.shape}")
    t, rtol, atol = (jnp.asarray(v, jnp.float64) for v in (t, rtol, atol))
    q, lam, force, phi, steps, result, gaps = _solve(mech, q_guess, t, contact, rtol, atol, max_steps)
    q = eqx.error_if(q, result != optx.RESULTS.successful,
                     "static_equilibrium: Newton's method did not converge: no equilibrium near q_guess (a body "
                     "left without support, a load its springs cannot carry) or max_steps too small")
    q = eqx.error_if(q, jnp.any(jnp.where(contact, gaps > 0.0, gaps < 0.0)),
                     "static_equilibrium: a tyre or bump stop taken as engaged is clear at the equilibrium (or one "
                     "taken clear is engaged): pass contact= with the other set")
    return Equilibrium(q=q, lam=lam, force_residual=force, constraint_residual=phi, steps=steps)
