"""Model file import: URDF -> :class:`~particlesim.tree.TreeModel`."""

from .urdf import load_urdf

__all__ = ["load_urdf"]
