"""Equations of motion of a mechanism in particle coordinates, and their acceleration-level solve.

With the secondary particles eliminated (Attia eqs. (23)–(27)), the particles' kinetic energy is
``T = 1/2 xd^T M xd`` with a *constant* mass matrix ``M`` (:meth:`Mechanism.mass_matrix`). D'Alembert's principle
with the constraints ``Phi(x) = 0`` (:mod:`.constraints`) gives

    M xdd + J^T lam = Q(t, x, xd),      J xdd = gamma(x, xd)

The force and moment equations of Attia (9)–(10) and (23)–(24) are this system's rows projected on the rigid
motions of each body: the internal distance forces cancel pairwise and the reactions of a joint particle have no
moment about it. Solving the full saddle-point system gives the same accelerations (and the multipliers ``lam``
are the constraint forces). :func:`accelerations` solves it densely; it is the reference for every mechanism,
open or closed.
"""

from __future__ import annotations

import jax.numpy as jnp
from jaxtyping import Array, Float

from .constraints import constraint_gamma, constraint_jacobian, constraints, velocity_constraints
from .forces import generalized_forces, potential_energy
from .model import Mechanism

__all__ = ["mass_properties", "accelerations", "accelerations_and_multipliers", "kinetic_energy", "total_energy", "residuals"]


def mass_properties(mech: Mechanism) -> tuple[Array, Array]:
    """``(M, m_bar)``: the constant mass matrix of the free coordinates and the lumped particle masses. They
    depend on the parameters only, so a simulation computes them once (pass them as ``props``)."""
    return mech.mass_matrix(), mech.lumped_masses()


def accelerations_and_multipliers(mech: Mechanism, t, x: Float[Array, " 3F"], xd: Float[Array, " 3F"],
                                  *, baumgarte: float = 0.0, props=None) -> tuple[Array, Array]:
    """Solve the saddle-point system for ``(xdd, lam)``; ``props`` as from :func:`mass_properties`.

    ``baumgarte`` (a rate ``a`` in 1/s, default 0) adds ``-2 a J xd - a^2 Phi`` to ``gamma`` so that drift decays
    critically damped; with the per-step projection of :func:`~particlesim.mechanism.simulate_mechanism` it is not
    needed.
    """
    m, lumped = mass_properties(mech) if props is None else props
    j = constraint_jacobian(mech, x)
    gamma = constraint_gamma(mech, x, xd)
    if baumgarte:
        gamma = gamma - 2.0 * baumgarte * velocity_constraints(mech, x, xd) - baumgarte**2 * constraints(mech, x)
    q = generalized_forces(mech, t, x, xd, lumped=lumped)
    n, c = m.shape[0], j.shape[0]
    kkt = jnp.block([[m, j.T], [j, jnp.zeros((c, c), dtype=m.dtype)]])
    sol = jnp.linalg.solve(kkt, jnp.concatenate([q, gamma]))
    return sol[:n], sol[n:]


def accelerations(mech: Mechanism, t, x: Float[Array, " 3F"], xd: Float[Array, " 3F"], *,
                  baumgarte: float = 0.0, props=None) -> Float[Array, " 3F"]:
    """Particle accelerations ``xdd`` (see :func:`accelerations_and_multipliers`)."""
    return accelerations_and_multipliers(mech, t, x, xd, baumgarte=baumgarte, props=props)[0]


def kinetic_energy(mech: Mechanism, xd: Float[Array, " 3F"]) -> Float[Array, ""]:
    """``1/2 xd^T M xd``: equal to the bodies' rigid kinetic energy for admissible velocities."""
    return 0.5 * xd @ mech.mass_matrix() @ xd


def total_energy(mech: Mechanism, x, xd) -> Float[Array, ""]:
    return kinetic_energy(mech, xd) + potential_energy(mech, x)


def residuals(mech: Mechanism, x, xd) -> tuple[Array, Array]:
    """Position- and velocity-level constraint residuals ``(Phi(x), J xd)``."""
    return constraints(mech, x), velocity_constraints(mech, x, xd)
