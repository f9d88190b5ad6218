"""The exceptions particlesim raises for bad input. Each message names the body/joint/file and the condition."""

from __future__ import annotations

__all__ = ["ModelError", "InertiaError", "PlacementError", "NegativeMassWarning", "ParseError", "DataError",
           "InertiaWarning", "BatchStalledError"]


class ModelError(ValueError):
    """A model (body, joint, mechanism, file) violates a stated condition."""


class InertiaError(ModelError):
    """A rigid-body inertia is not physical (mass, symmetry, positive definiteness, triangle inequalities)."""


class PlacementError(ModelError):
    """Equivalent particles placed where they cannot represent the body (singular or wrong-dimension placement)."""


class ParseError(ModelError):
    """A model file could not be parsed or describes something unsupported."""


class DataError(ModelError):
    """A data file or array is unusable (missing, NaN, mismatched lengths, a joint that never moves); names the
    file/joint."""


class NegativeMassWarning(UserWarning):
    """An equivalent particle received a negative mass: the dynamics stay exact, physical consistency is lost."""


class InertiaWarning(UserWarning):
    """A model file's inertia is not physical and was loaded anyway (``inertia="warn"``) or repaired
    (``inertia="balance"``); the message names every such link."""


class BatchStalledError(RuntimeError):
    """A batch split over threads did not finish within its bound; names the batch, the part and its thread."""
