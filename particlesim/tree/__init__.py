"""Lagrangian tree dynamics (Zafar, *Equations of Motion of Krang on Fixed Wheels*).

A :class:`TreeModel` holds static topology and differentiable parameters; every function is pure and takes
the model first. Models come from :func:`particlesim.io.load_urdf` / :func:`particlesim.io.load_mjcf` or are
written directly. ``A(q) qdd + C(q, qd) qd + Q(q) + Gamma_f = tau``.

Batching over parameter sets::

    batch = jax.tree.map(lambda *x: jnp.stack(x), *models)      # same topology, stacked leaves
    jax.vmap(forward_dynamics, in_axes=(0, None, None, None))(batch, q, qd, tau)
"""

from .coriolis import christoffel_symbols, coriolis_matrix
from .dynamics import (
    bias_forces,
    coriolis_times_qdot,
    forward_dynamics,
    friction_torques,
    gravity_torques,
    inverse_dynamics,
    mass_matrix,
    spring_torques,
    limit_torques,
)
from .energy import kinetic_energy, link_kinetic_energies, potential_energy
from .kinematics import spring_deflections, frame_pose, link_jacobian, link_jacobians, link_poses, link_velocities, wrench_torques
from .model import PRISMATIC, REVOLUTE, TreeModel

__all__ = [
    "TreeModel",
    "REVOLUTE",
    "PRISMATIC",
    "mass_matrix",
    "bias_forces",
    "coriolis_matrix",
    "christoffel_symbols",
    "coriolis_times_qdot",
    "gravity_torques",
    "kinetic_energy",
    "link_kinetic_energies",
    "potential_energy",
    "forward_dynamics",
    "inverse_dynamics",
    "friction_torques",
    "spring_torques",
    "limit_torques",
    "spring_deflections",
    "link_poses",
    "link_velocities",
    "link_jacobian",
    "frame_pose",
    "link_jacobians",
    "wrench_torques",
]

