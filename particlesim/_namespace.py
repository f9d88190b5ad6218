"""Which array library a function of static model data or traced values should use."""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

__all__ = ["xp_of"]


def xp_of(*xs):
    """NumPy when every input is a NumPy array or a Python/NumPy number (model building and input checks stay exact
    and cost no compiles), JAX otherwise (traced, differentiable, batched)."""
    return np if all(isinstance(x, (np.ndarray, np.generic, float, int)) for x in xs) else jnp
