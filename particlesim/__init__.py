"""particlesim: differentiable multibody dynamics in JAX.

Equivalent-particle mechanisms (Attia) and Lagrangian tree robots (Krang), float64 by default.
"""

import jax

# Dynamics here is validated in float64; enable it before any array is created.
jax.config.update("jax_enable_x64", True)

from . import spatial  # noqa: E402
from .errors import DataError, InertiaError, ModelError, NegativeMassWarning, ParseError, PlacementError  # noqa: E402
from .inertia import RigidInertia, check_inertia  # noqa: E402
from ._xla import compiler_options  # noqa: E402

__version__ = "0.1.0"

__all__ = [
    "spatial",
    "RigidInertia",
    "check_inertia",
    "ModelError",
    "InertiaError",
    "PlacementError",
    "ParseError",
    "DataError",
    "NegativeMassWarning",
    "compiler_options",
]
