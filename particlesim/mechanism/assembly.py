"""Assembly: a consistent configuration from approximate positions.

Data read off a drawing or rounded to a few digits close a loop only approximately. :func:`assemble` moves the free
particles the least (Gauss–Newton with minimum-norm steps in particle coordinates) until every constraint holds to
round-off, optionally holding chosen particles or coordinates where they are (a crank angle, a wheel centre), and
reports the correction. ``MechanismBuilder.build(assemble=True)`` runs it before its checks.
"""

from __future__ import annotations

from typing import Callable, NamedTuple, Sequence, Union

import numpy as np

from ..errors import ModelError
from .constraints import constraint_jacobian, constraints
from .model import Mechanism

__all__ = ["Assembly", "assemble", "ASSEMBLE_RTOL"]

#: Assembly stops when every constraint residual is below this fraction of the mechanism's size (times its size
#: in metres for distance rows).
ASSEMBLE_RTOL = 1e-13
_AXIS = {"x": 0, "y": 1, "z": 2, 0: 0, 1: 1, 2: 2}

Hold = Union[str, tuple]


class Assembly(NamedTuple):
    """Result of :func:`assemble`: the consistent state, the correction applied and how far it moved each particle."""

    q: np.ndarray  #: consistent free-particle positions ``(3F,)``
    correction: np.ndarray  #: ``q - q_given``
    moved: dict  #: particle name -> distance moved [m], largest first
    residual: float  #: largest constraint residual at ``q``
    iterations: int


def held_columns(names: Sequence[str], free: Sequence[int], hold: Sequence[Hold]) -> np.ndarray:
    """Boolean mask ``(3F,)`` of held coordinates. ``hold`` entries: a particle name (all three coordinates) or
    ``(name, axis)`` with axis ``'x'``, ``'y'``, ``'z'`` or 0..2."""
    col = {names[i]: c for c, i in enumerate(free)}
    mask = np.zeros(3 * len(free), dtype=bool)
    for h in hold:
        name, axes = (h, (0, 1, 2)) if isinstance(h, str) else (h[0], (h[1],))
        if name not in col:
            what = "a ground particle (already fixed)" if name in names else "not a particle"
            raise ModelError(f"assemble: cannot hold '{name}': {what}")
        for a in axes:
            if a not in _AXIS:
                raise ModelError(f"assemble: hold ('{name}', {a!r}): the axis must be 'x', 'y', 'z' or 0..2")
            mask[3 * col[name] + _AXIS[a]] = True
    return mask


def gauss_newton(rows: Callable, q: np.ndarray, held: np.ndarray, tol: float, labels: Sequence[str], *,
                 max_iter: int = 50) -> tuple[np.ndarray, float, int]:
    """Minimum-norm Gauss–Newton on ``rows(q) -> (residual (C,), jacobian (C, n))`` over the coordinates not
    ``held``; ``ModelError`` naming the worst rows when it does not reach ``tol``."""
    q = np.array(q, dtype=float)
    move = ~held
    r = np.zeros(0)
    for it in range(max_iter + 1):
        r, j = rows(q)
        worst = float(np.max(np.abs(r))) if r.size else 0.0
        if not np.isfinite(worst):
            break
        if worst <= tol:
            return q, worst, it
        if it == max_iter:
            break
        dx = np.linalg.lstsq(j[:, move], -r, rcond=1e-10)[0]
        q[move] += dx
    order = np.argsort(-np.abs(np.nan_to_num(r, nan=np.inf)))[:4]
    raise ModelError("assembly failed: the constraints cannot all be met from these positions"
                     + (" with the held coordinates" if held.any() else "") + f" after {max_iter} Gauss-Newton "
                     "steps; largest residuals: " + ", ".join(f"{labels[i]} ({r[i]:.3g})" for i in order)
                     + " (check lengths, held coordinates and that the loop can close)")


def report(names: Sequence[str], free: Sequence[int], q_given: np.ndarray, q: np.ndarray, residual: float,
           iterations: int) -> Assembly:
    d = np.linalg.norm((q - q_given).reshape(-1, 3), axis=1)
    moved = {names[free[i]]: float(d[i]) for i in np.argsort(-d) if d[i] > 0}
    return Assembly(q=q, correction=q - q_given, moved=moved, residual=residual, iterations=iterations)


def assemble(mech: Mechanism, q, *, hold: Sequence[Hold] = (), tol: float | None = None) -> Assembly:
    """The consistent configuration nearest (in particle coordinates) to the approximate state ``q (3F,)``.

    ``hold`` keeps particles (by name) or single coordinates (``("crank tip", "y")``) where ``q`` puts them, e.g.
    to set a crank angle and let the rest of the loop follow. The body shapes are those of the mechanism; only
    the joints and loops are closed. Returns an :class:`Assembly` (state, correction, distance moved per particle,
    residual). Raises :class:`ModelError` with the worst constraints when no consistent configuration is reached.
    """
    topo = mech.topo
    q_given = np.asarray(q, dtype=float).reshape(-1)
    if q_given.shape != (mech.n_coords,) or not np.all(np.isfinite(q_given)):
        raise ModelError(f"assemble: q must be {mech.n_coords} finite numbers (3 per free particle), "
                         f"got shape {np.shape(q)}")
    held = held_columns(topo.particle_names, topo.free, hold)
    def rows(y):
        return np.asarray(constraints(mech, y)), np.asarray(constraint_jacobian(mech, y))

    pts = np.asarray(mech.all_positions(q_given))
    size = max(float(np.ptp(pts, axis=0).max()), 1e-12)
    tol = ASSEMBLE_RTOL * size * max(size, 1.0) if tol is None else float(tol)
    xa, res, it = gauss_newton(rows, q_given, held, tol, topo.row_labels())
    return report(topo.particle_names, topo.free, q_given, xa, res, it)
