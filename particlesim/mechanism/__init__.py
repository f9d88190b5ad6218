"""Mechanisms in particle Cartesian coordinates (Attia): bodies as equivalent particles, joints as shared
particles, loops closed by cut-joint constraints, force elements, and their simulation."""

from .assembly import Assembly, assemble
from .builder import MechanismBuilder
from .chain import ChainPlan, chain_accelerations, chain_mass_blocks, chain_plan
from .constraints import constraint_gamma, constraint_jacobian, constraint_labels, constraints, velocity_constraints
from .dynamics import (Prepared, accelerations, accelerations_and_multipliers, kinetic_energy, lumped_masses, mass_matrix,
                       mass_properties, prepare, residuals, scalar_mass_matrix, total_energy)
from .forces import body_angular_velocity, generalized_forces, potential_energy, spring_lengths
from .integrate import SwitchCrossedWarning, project, simulate_mechanism
from .kinematics import KinematicSolution, kinematic_analysis
from .linear import Linearization, Modes, linearize, modes
from .model import AppliedForce, AppliedTorque, BodyLoad, BodyState, Mechanism
from .statics import Equilibrium, static_equilibrium
from .outputs import (body_angles, body_com_positions, body_poses, body_reactions, body_velocities, cut_joint_forces,
                      driver_efforts, joint_reaction, point_positions)

__all__ = [
    "Mechanism",
    "AppliedForce",
    "AppliedTorque",
    "BodyLoad",
    "BodyState",
    "ChainPlan",
    "chain_plan",
    "chain_accelerations",
    "chain_mass_blocks",
    "Prepared",
    "prepare",
    "MechanismBuilder",
    "Assembly",
    "assemble",
    "constraints",
    "constraint_jacobian",
    "constraint_gamma",
    "constraint_labels",
    "velocity_constraints",
    "mass_properties",
    "mass_matrix",
    "scalar_mass_matrix",
    "lumped_masses",
    "accelerations",
    "accelerations_and_multipliers",
    "kinetic_energy",
    "potential_energy",
    "total_energy",
    "residuals",
    "generalized_forces",
    "spring_lengths",
    "body_angular_velocity",
    "project",
    "simulate_mechanism",
    "SwitchCrossedWarning",
    "kinematic_analysis",
    "KinematicSolution",
    "static_equilibrium",
    "Equilibrium",
    "driver_efforts",
    "body_poses",
    "body_com_positions",
    "body_velocities",
    "body_angles",
    "point_positions",
    "cut_joint_forces",
    "body_reactions",
    "joint_reaction",
    "linearize",
    "Linearization",
    "modes",
    "Modes",
]
