"""Road inputs for tyres (``mb.tyre(..., ground=road)``): a post of a four-post rig as a function of time.

Each road is an ``equinox.Module`` whose arrays are parameters (new values reuse a compiled rollout, and gradients
reach them) and is smooth in time (no kinks for an adaptive step to stumble on):

* :class:`Bump`: a raised-cosine bump of ``height`` over ``duration`` seconds from ``start`` (a cleat under a wheel);
* :class:`SineSum`: a sum of sinusoids of the distance travelled, faded in over ``fade`` seconds from ``start``;
  :func:`iso8608` draws one for a road class of ISO 8608 (the standard's synthesis: harmonics with the class's
  displacement spectral density ``G_d(n) = G_d(n0) (n / n0)^-2``, ``n0 = 0.1`` cycles/m, and random phases);
* :class:`Sum`: roads added.
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

__all__ = ["Bump", "SineSum", "Sum", "iso8608", "ISO8608_CLASSES"]

#: ISO 8608 road classes: the geometric mean of ``G_d(n0)`` [m^3], ``n0 = 0.1`` cycles/m.
ISO8608_CLASSES = {"A": 16e-6, "B": 64e-6, "C": 256e-6, "D": 1024e-6, "E": 4096e-6}


def _check(road: str, *, positive=(), **values) -> None:
    """Refuse non-finite values (and non-positive ``positive`` ones), naming the road and the value; traced values
    (a road built under ``jit``) are not checked."""
    from jax.core import Tracer

    for name, v in values.items():
        if isinstance(v, Tracer):
            continue
        a = np.asarray(v)
        if not np.all(np.isfinite(a)) or (name in positive and not np.all(a > 0)):
            need = "finite and positive" if name in positive else "finite"
            raise ValueError(f"{road}: {name} must be {need}, got {a.tolist()!r}")


def _smoothstep(s):
    """0 before 0, 1 after 1, a raised cosine between (continuous slope)."""
    s = jnp.clip(s, 0.0, 1.0)
    return 0.5 - 0.5 * jnp.cos(jnp.pi * s)


class Bump(eqx.Module):
    """``height (1 - cos(2 pi (t - start) / duration)) / 2`` for ``start <= t <= start + duration``, else 0."""

    height: Float[Array, ""]
    start: Float[Array, ""]
    duration: Float[Array, ""]

    def __init__(self, height, start, duration):
        self.height, self.start, self.duration = (jnp.asarray(v, dtype=float) for v in (height, start, duration))
        _check("Bump", height=self.height, start=self.start, duration=self.duration, positive=("duration",))

    def __call__(self, t):
        s = jnp.clip((t - self.start) / self.duration, 0.0, 1.0)
        return self.height * 0.5 * (1.0 - jnp.cos(2.0 * jnp.pi * s))


class SineSum(eqx.Module):
    """``w(t) sum_k amplitude_k sin(wavenumber_k x(t) + phase_k)`` with ``x(t) = speed (t - start) - offset`` the
    distance travelled past the road's origin (``offset``: how far behind the first axle this wheel runs) and
    ``w`` a fade-in over ``fade`` seconds from ``start`` (0 before it)."""

    amplitude: Float[Array, " K"]
    wavenumber: Float[Array, " K"]  # rad/m
    phase: Float[Array, " K"]
    speed: Float[Array, ""]
    offset: Float[Array, ""]
    start: Float[Array, ""]
    fade: Float[Array, ""]

    def __init__(self, amplitude, wavenumber, phase, *, speed, offset=0.0, start=0.0, fade=0.5):
        self.amplitude, self.wavenumber, self.phase = (jnp.asarray(v, dtype=float) for v in
                                                       (amplitude, wavenumber, phase))
        self.speed, self.offset, self.start, self.fade = (jnp.asarray(v, dtype=float) for v in
                                                          (speed, offset, start, fade))
        _check("SineSum", amplitude=self.amplitude, wavenumber=self.wavenumber, phase=self.phase, speed=self.speed,
               offset=self.offset, start=self.start, fade=self.fade, positive=("fade",))
        if self.amplitude.shape != self.wavenumber.shape or self.amplitude.shape != self.phase.shape \
                or self.amplitude.ndim != 1:
            raise ValueError(f"SineSum: amplitude, wavenumber and phase must be 1-d of one length, got shapes "
                             f"{self.amplitude.shape}, {self.wavenumber.shape}, {self.phase.shape}")

    def __call__(self, t):
        x = self.speed * (t - self.start) - self.offset
        return _smoothstep((t - self.start) / self.fade) * jnp.sum(
            self.amplitude * jnp.sin(self.wavenumber * x + self.phase))


class Sum(eqx.Module):
    """Roads added: ``sum(road(t) for road in roads)``."""

    roads: tuple

    def __init__(self, *roads):
        self.roads = tuple(roads)

    def __call__(self, t):
        return sum(road(t) for road in self.roads)


def iso8608(road_class: str, speed: float, *, seed: int, n_waves: int = 64, band=(0.011, 2.83), offset=0.0,
            start=0.0, fade=0.5) -> SineSum:
    """One track of an ISO 8608 road of class ``road_class`` ("A"-"E") under a wheel moving at ``speed`` m/s:
    ``n_waves`` harmonics at spatial frequencies spaced evenly over ``band`` (cycles/m; the standard's range), each
    of amplitude ``sqrt(2 G_d(n) dn)`` and a uniformly random phase drawn from ``seed``. A rear wheel on the same
    track runs ``offset`` (the wheelbase) behind the front one."""
    if road_class not in ISO8608_CLASSES:
        raise ValueError(f"unknown ISO 8608 class {road_class!r}; choose from {list(ISO8608_CLASSES)}")
    n = np.linspace(band[0], band[1], n_waves)
    dn = n[1] - n[0]
    psd = ISO8608_CLASSES[road_class] * (n / 0.1) ** -2.0
    phase = np.random.default_rng(seed).uniform(0.0, 2.0 * np.pi, n_waves)
    return SineSum(np.sqrt(2.0 * psd * dn), 2.0 * np.pi * n, phase, speed=speed, offset=offset, start=start,
                   fade=fade)
