"""Tabulated force curves: natural cubic splines through measured points, for nonlinear springs and dampers.

A curve is fixed by its abscissae (static: a spring's deflections or a damper's velocities) and its values (a
parameter, differentiable). The spline's second derivatives are a fixed linear map of the values (the natural end
conditions, solved once in NumPy from the abscissae), so the curve, its slope and its integral are smooth in both
the argument and the values: adaptive steps see no kinks at the table points, and gradients reach every value.
Beyond the table the curve continues along its end tangents. The integral gives a nonlinear spring's energy.
"""

from __future__ import annotations

from functools import lru_cache

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

__all__ = ["check_curve", "curve_value", "curve_integral"]


def check_curve(owner: str, label: str, curve) -> tuple[tuple[float, ...], np.ndarray]:
    """``(x, y)`` of a table given as ``(x, y)`` or as rows ``[[x0, y0], [x1, y1], ...]``: at least 3 points,
    finite, strictly increasing ``x``. Raises :class:`~particlesim.errors.ModelError` naming ``owner``."""
    from ..errors import ModelError

    try:
        arr = np.asarray(curve, dtype=float)
    except (TypeError, ValueError):
        raise ModelError(f"{owner}: {label} must be numbers, as (x, y) or rows [[x, y], ...]") from None
    if arr.ndim == 2 and arr.shape[1] == 2 and arr.shape[0] != 2:
        arr = arr.T
    if arr.ndim != 2 or arr.shape[0] != 2 or arr.shape[1] < 3:
        raise ModelError(f"{owner}: {label} must be (x, y) with at least 3 points each, or rows [[x, y], ...], got "
                         f"shape {np.shape(curve)}")
    if not np.all(np.isfinite(arr)):
        raise ModelError(f"{owner}: {label} has non-finite entries")
    if np.any(np.diff(arr[0]) <= 0.0):
        k = int(np.flatnonzero(np.diff(arr[0]) <= 0.0)[0])
        raise ModelError(f"{owner}: {label}'s abscissae must increase strictly; entry {k + 1} ({arr[0, k + 1]!r}) "
                         f"follows {arr[0, k]!r}")
    return tuple(float(v) for v in arr[0]), arr[1].copy()


@lru_cache(maxsize=None)
def _second_derivative_map(x: tuple[float, ...]) -> np.ndarray:
    """``S`` with ``m = S y``: the natural spline's second derivatives at the points from the values."""
    x = np.asarray(x)
    n, h = len(x), np.diff(x)
    a = np.zeros((n, n))
    b = np.zeros((n, n))
    a[0, 0] = a[-1, -1] = 1.0
    for i in range(1, n - 1):
        a[i, i - 1], a[i, i], a[i, i + 1] = h[i - 1], 2.0 * (h[i - 1] + h[i]), h[i]
        b[i, i - 1], b[i, i], b[i, i + 1] = 6.0 / h[i - 1], -6.0 / h[i - 1] - 6.0 / h[i], 6.0 / h[i]
    return np.linalg.solve(a, b)


def _pieces(x: tuple[float, ...], y, s):
    xs = np.asarray(x)
    m = jnp.asarray(_second_derivative_map(x), y.dtype) @ y
    h = jnp.asarray(np.diff(xs), y.dtype)
    i = jnp.clip(jnp.searchsorted(jnp.asarray(xs, y.dtype), s, side="right") - 1, 0, len(xs) - 2)
    lo, hi = jnp.asarray(xs[:-1], y.dtype)[i], jnp.asarray(xs[1:], y.dtype)[i]
    slope0 = (y[1] - y[0]) / h[0] - h[0] * (2.0 * m[0] + m[1]) / 6.0
    slope1 = (y[-1] - y[-2]) / h[-1] + h[-1] * (m[-2] + 2.0 * m[-1]) / 6.0
    return xs, m, h, i, lo, hi, slope0, slope1


def curve_value(x: tuple[float, ...], y: Float[Array, " n"], s: Float[Array, ""]) -> Float[Array, ""]:
    """The spline through ``(x, y)`` at ``s`` (linear beyond the ends, along the end tangents)."""
    xs, m, h, i, lo, hi, slope0, slope1 = _pieces(x, y, s)
    hh = h[i]
    u, w = s - lo, hi - s
    inside = (m[i] * w**3 + m[i + 1] * u**3) / (6.0 * hh) + (y[i] / hh - m[i] * hh / 6.0) * w \
        + (y[i + 1] / hh - m[i + 1] * hh / 6.0) * u
    left = y[0] + slope0 * (s - xs[0])
    right = y[-1] + slope1 * (s - xs[-1])
    return jnp.where(s < xs[0], left, jnp.where(s > xs[-1], right, inside))


def curve_integral(x: tuple[float, ...], y: Float[Array, " n"], s: Float[Array, ""], start: float = 0.0
                   ) -> Float[Array, ""]:
    """``integral of the spline from start to s`` (a nonlinear spring's energy from its free length)."""
    return _antiderivative(x, y, s) - _antiderivative(x, y, jnp.asarray(start, y.dtype))


def _antiderivative(x, y, s):
    """The spline's integral from the first table point to ``s``."""
    xs, m, h, i, lo, hi, slope0, slope1 = _pieces(x, y, s)
    whole = h * (y[:-1] + y[1:]) / 2.0 - h**3 * (m[:-1] + m[1:]) / 24.0
    cum = jnp.concatenate([jnp.zeros(1, y.dtype), jnp.cumsum(whole)])
    hh = h[i]
    u, w = s - lo, hi - s
    inside = cum[i] + m[i] * (hh**4 - w**4) / (24.0 * hh) + m[i + 1] * u**4 / (24.0 * hh) \
        + (y[i] / hh - m[i] * hh / 6.0) * (hh**2 - w**2) / 2.0 + (y[i + 1] / hh - m[i + 1] * hh / 6.0) * u**2 / 2.0
    d0, d1 = s - xs[0], s - xs[-1]
    left = y[0] * d0 + slope0 * d0**2 / 2.0
    right = cum[-1] + y[-1] * d1 + slope1 * d1**2 / 2.0
    return jnp.where(s < xs[0], left, jnp.where(s > xs[-1], right, inside))
