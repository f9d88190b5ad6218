"""Quarter-car identification: suspension spring and damper, tyre stiffness and masses from chassis-height traces.

The traces are free responses of :func:`particlesim.scenes.quarter_car.quarter_car` from rest in its assembly
configuration (assumption A6: spring and tyre unloaded), which settle under gravity: the static sag fixes the
series stiffness ``(1/k_s + 1/k_t)^-1`` over the sprung weight (through the suspension's motion ratio), the
sprung-mass mode (~1.5 Hz) fixes ``k_s / m`` and ``c_s / m`` and the wheel-hop mode (~16 Hz, strongly damped by
``c_s``) separates ``k_t``. One free response cannot tell the masses from the constants: scaling every mass,
stiffness and damper together leaves it unchanged (exactly so but for the small known masses of the arms and
knuckle). A second run with a known payload on the chassis breaks that symmetry, so fitting a mass needs at
least two distinct ``payloads``.

The measurement model is a :func:`~particlesim.identify.traces.trace_model` (tyre switches located as events: the
wheel leaves the ground while the car settles) and the fit is :func:`~particlesim.identify.traces.fit_traces`:
Gauss–Newton with the forward-mode Jacobian of the rollouts, starts vmapped.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from .traces import TraceFit, TraceModel, fit_traces, trace_model

__all__ = ["PARAMETERS", "FITTED", "chassis_traces", "fit_quarter_car", "QuarterCarFit"]

#: Identifiable constants by name: ``(group, element, field)`` of :meth:`~particlesim.mechanism.Mechanism.with_params`.
PARAMETERS = {
    "spring_stiffness": ("spring", "suspension", "stiffness"),
    "spring_damping": ("spring", "suspension", "damping"),
    "tyre_stiffness": ("tyre", "tyre", "stiffness"),
    "tyre_damping": ("tyre", "tyre", "damping"),
    "chassis_mass": ("body", "chassis", "mass"),
    "wheel_mass": ("body", "wheel", "mass"),
}
#: What :func:`chassis_traces` fits unless told otherwise.
FITTED = ("spring_stiffness", "spring_damping", "tyre_stiffness", "chassis_mass", "wheel_mass")

#: The fit of :func:`fit_quarter_car` (chassis heights in m).
QuarterCarFit = TraceFit
fit_quarter_car = fit_traces


def chassis_traces(ts, *, names: Sequence[str] = FITTED, payloads: Sequence[float] = (0.0, 100.0), mech=None,
                   q0=None, solver: str = "dopri8", rtol: float = 1e-7, atol: float = 1e-9,
                   events: bool = True, stabilise: bool = False) -> TraceModel:
    """The measurement model: chassis height (point ``centre``, m) at ``ts`` in free responses from rest of the
    quarter car with each of ``payloads`` (kg) added to the chassis mass (outputs ``(B, R, T)``); the constants
    ``names`` (keys of :data:`PARAMETERS`) are free, the rest keep the mechanism's values. ``mech, q0``: default
    :func:`~particlesim.scenes.quarter_car.quarter_car`; the solver settings as in
    :func:`~particlesim.identify.traces.trace_model`.

    Raises ``ValueError`` for an unknown or repeated name, non-finite payloads, bad sample times, or a mass among
    ``names`` with fewer than two distinct payloads (module docstring: the masses are then not identifiable)."""
    from ..scenes.quarter_car import quarter_car

    names = tuple(names)
    if not names or any(n not in PARAMETERS for n in names) or len(set(names)) != len(names):
        raise ValueError(f"names must be distinct keys of PARAMETERS {list(PARAMETERS)}; got {list(names)}")
    payloads = np.asarray(payloads, dtype=float).reshape(-1)
    if not np.all(np.isfinite(payloads)) or payloads.size == 0:
        raise ValueError(f"payloads must be finite masses in kg; got {payloads}")
    masses = [n for n in names if PARAMETERS[n][0] == "body"]
    if masses and np.unique(payloads).size < 2:
        raise ValueError(f"fitting {masses} needs runs with at least two distinct chassis payloads (one free "
                         f"response cannot separate masses from stiffnesses and dampers); got payloads {payloads}")
    if mech is None:
        mech, q0 = quarter_car()
    k = mech.point_index("centre")
    return trace_model(mech, q0, ts, {n: PARAMETERS[n] for n in names},
                       lambda m, q: m.point_positions(m.all_positions(q))[k, 2],
                       runs=[{("body", "chassis", "mass"): float(p)} for p in payloads], solver=solver, rtol=rtol,
                       atol=atol, events=events, stabilise=stabilise)
