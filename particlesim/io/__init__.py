"""Model file import: URDF and MJCF -> :class:`~particlesim.tree.TreeModel`."""

from .mjcf import from_mujoco_state, load_mjcf
from .urdf import load_urdf

__all__ = ["load_urdf", "load_mjcf", "from_mujoco_state"]
