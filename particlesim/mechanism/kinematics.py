"""Kinematic analysis of a fully driven mechanism: positions, velocities and accelerations from the constraints
alone, and the efforts the drivers must supply.

With as many independent driving constraints as the mechanism has degrees of freedom (``dof = 0``) the
constraints ``Phi(q, t) = 0`` fix the configuration at every time: at each requested time the positions solve
``Phi = 0`` by Newton's method (started from a second-order prediction from the previous time), the velocities
``J qd = nu`` and the accelerations ``J qdd = gamma`` (:mod:`.constraints`). The solves use ``J^T (J J^T)^-1``, so
they need no masses; with ``dof = 0`` it is ``J``'s (left) inverse. The driving efforts (torques and forces, the
inverse dynamics of the prescribed motion) come from the multipliers of the equations of motion at each state.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .. import _ode
from ..errors import ModelError
from ._algebra import drive_at, factor_schur, gamma, jacobian, prepare, residual, rows, solve_schur, velocity_target
from .dynamics import _solve
from .model import Mechanism

__all__ = ["KinematicSolution", "kinematic_analysis"]

#: Newton iterations per output time (quadratic convergence from a second-order prediction; the residual reached
#: is reported and checked against :data:`KINEMATICS_RTOL`).
NEWTON_ITERATIONS = 8
#: The largest position residual accepted, as a fraction of the mechanism's size.
KINEMATICS_RTOL = 1e-10


class KinematicSolution(eqx.Module):
    """``q``, ``qd``, ``qdd`` (T, 3F): particle positions, velocities, accelerations at ``ts``; ``efforts`` (T, K)
    the drivers' torques/forces (``mech.topo.drive.names`` order); ``residual`` (T,) the largest position
    residual reached at each time."""

    ts: Float[Array, " T"]
    q: Float[Array, "T 3F"]
    qd: Float[Array, "T 3F"]
    qdd: Float[Array, "T 3F"]
    efforts: Float[Array, "T K"]
    residual: Float[Array, " T"]


@_ode.cached("kinematic_analysis")
def _kinematics(mech, q0, ts, tol):
    prep = prepare(mech)
    lsq = mech.topo.least_squares
    n_drive = len(mech.topo.drive)

    def min_norm(j, rhs):
        return j.T @ solve_schur(factor_schur(j @ j.T, lsq), rhs)

    def solve_at(t, guess):
        drive = drive_at(mech, t)
        q = guess
        for _ in range(NEWTON_ITERATIONS):
            r = rows(prep, q, drive=drive)
            j = jacobian(prep, r).reshape(mech.n_constraints, -1)
            q = q - min_norm(j, residual(prep, mech.dot_kappa, r, q))
        r = rows(prep, q, drive=drive)
        res = jnp.max(jnp.abs(residual(prep, mech.dot_kappa, r, q)))
        j = jacobian(prep, r).reshape(mech.n_constraints, -1)
        qd = min_norm(j, velocity_target(prep, r) + jnp.zeros(mech.n_constraints, q.dtype))
        qdd = min_norm(j, gamma(prep, rows(prep, q, qd, drive)))
        lam = _solve(mech, prep, t, q, qd, 0.0)[1]
        return q, qd, qdd, -lam[mech.n_constraints - n_drive:], res

    def step(carry, t):
        t_prev, q, qd, qdd = carry
        h = t - t_prev
        out = solve_at(t, q + h * qd + 0.5 * h**2 * qdd)
        return (t, *out[:3]), out

    first = solve_at(ts[0], q0)
    _, rest = jax.lax.scan(step, (ts[0], *first[:3]), ts[1:])
    pos, vel, acc, eff, res = (jnp.concatenate([a[None], b]) for a, b in zip(first, rest))
    pos = eqx.error_if(pos, jnp.max(res) > tol, "kinematic_analysis: Newton's method did not reach the constraints at "
                                            "every time (a time step too coarse for the motion, or the driven "
                                            "mechanism passes a singular position); give more output times")
    return KinematicSolution(ts=ts, q=pos, qd=vel, qdd=acc, efforts=eff, residual=res)


def kinematic_analysis(mech: Mechanism, q0, ts) -> KinematicSolution:
    """Positions, velocities, accelerations and driver efforts of a fully driven mechanism (``dof = 0``) at the
    increasing times ``ts``; ``q0`` an approximate configuration at ``ts[0]`` (e.g. the builder's assembly state).

    Compiles once per mechanism structure and number of output times. Raises :class:`ModelError` if the mechanism
    is not fully driven at ``q0`` (naming its degrees of freedom) and ``ValueError`` for bad times or states."""
    from .constraints import constraint_jacobian

    ts = np.asarray(ts, dtype=float)
    if ts.ndim != 1 or ts.size < 1 or not np.all(np.isfinite(ts)) or np.any(np.diff(ts) <= 0):
        raise ValueError("kinematic_analysis: ts must be a non-empty, finite, strictly increasing 1-D array")
    q0 = _ode.as_state(q0)
    if q0.shape != (mech.n_coords,):
        raise ModelError(f"kinematic_analysis: q0 must have length {mech.n_coords} (3 x free particles), got "
                         f"{q0.shape}")
    _ode.check_state((q0,), ("q0",))
    j = np.asarray(constraint_jacobian(mech, q0, t=float(ts[0])))
    rank = int(np.sum(np.linalg.svd(j, compute_uv=False) > 1e-9 * np.abs(j).max())) if j.size else 0
    if mech.n_coords - rank:
        raise ModelError(f"kinematic_analysis: the mechanism has {mech.n_coords - rank} degree(s) of freedom left "
                         "at q0; prescribe each with a driver (drive_angle, drive_position) or simulate it with "
                         "simulate_mechanism")
    pos = np.asarray(q0).reshape(-1, 3)
    size = max(float(np.ptp(pos, axis=0).max()) if len(pos) else 1.0, 1e-12)
    return _kinematics(mech, q0, jnp.asarray(ts), jnp.asarray(KINEMATICS_RTOL * size * max(size, 1.0)))
