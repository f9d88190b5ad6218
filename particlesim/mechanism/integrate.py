"""Integrating a mechanism: the acceleration-level equations plus a projection onto the constraints every step.

Stabilisation scheme: *coordinate projection* (Hairer, Lubich & Wanner, Geometric Numerical Integration, §IV.4;
Eich 1993). After every accepted or rejected step of any diffrax solver, positions are projected back onto
``Phi(x) = 0`` by Gauss–Newton steps with the minimum-norm correction ``dx = -J^T (J J^T)^-1 Phi``, then
velocities onto ``J xd = 0``. The projection leaves the method's order intact (the correction is of the size of
the local error), needs no tuning constant (unlike Baumgarte's), and keeps the residuals at round-off, which the
tests measure. Saved outputs are projected the same way. It is a smooth function of the state and parameters,
so gradients pass through it.

Adjoints: "checkpoint" (default), "direct" and "forward" differentiate the discrete computation, projections
included. "backsolve" integrates the continuous adjoint equations of the vector field backwards in time; the
projection is a map applied between steps, not part of that vector field, so the backward solve would return the
sensitivities of a different (unprojected) flow. It is therefore refused with ``stabilise=True`` and allowed with
``stabilise=False``, where the integrated equations are exactly the ones it differentiates.
"""

from __future__ import annotations

from typing import Callable

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..simulate import IMPLICIT_SOLVERS, SOLVERS, Solution
from .constraints import constraint_jacobian, constraints
from .chain import chain_accelerations, chain_plan
from .dynamics import accelerations, mass_properties
from .model import Mechanism

__all__ = ["ADJOINTS", "ProjectedSolver", "project", "simulate_mechanism"]

_GN_ITERATIONS = 3

#: Adjoints by name (the names :func:`particlesim.simulate.simulate` takes).
ADJOINTS: dict[str, Callable[[], diffrax.AbstractAdjoint]] = {
    "checkpoint": diffrax.RecursiveCheckpointAdjoint,
    "direct": diffrax.DirectAdjoint,
    "forward": diffrax.ForwardMode,
    "backsolve": diffrax.BacksolveAdjoint,
}


def project(mech: Mechanism, x, xd):
    """Project ``(x, xd)`` onto ``Phi = 0`` and ``J xd = 0`` (minimum-norm corrections)."""
    if not (mech.distance_pairs or mech.coincide_pairs or mech.generic):
        return x, xd
    for _ in range(_GN_ITERATIONS):
        j = constraint_jacobian(mech, x)
        x = x - j.T @ jnp.linalg.solve(j @ j.T, constraints(mech, x))
    j = constraint_jacobian(mech, x)
    xd = xd - j.T @ jnp.linalg.solve(j @ j.T, j @ xd)
    return x, xd


class ProjectedSolver(diffrax.AbstractAdaptiveSolver, diffrax.AbstractWrappedSolver):
    """Wraps a diffrax solver; after each step maps ``y1`` through ``projection(y1, args)``."""

    solver: diffrax.AbstractSolver
    projection: Callable = eqx.field(static=True)

    @property
    def term_structure(self):
        return self.solver.term_structure

    @property
    def interpolation_cls(self):  # pyright: ignore
        return self.solver.interpolation_cls

    @property
    def term_compatible_contr_kwargs(self):
        return self.solver.term_compatible_contr_kwargs

    def order(self, terms):
        return self.solver.order(terms)

    def error_order(self, terms):
        return self.solver.error_order(terms)

    def strong_order(self, terms):
        return self.solver.strong_order(terms)

    @property
    def scan_kind(self):  # diffrax's adjoints ask Runge-Kutta solvers (and their wrappers) for it
        return self.solver.scan_kind

    @property
    def root_finder(self):  # diffrax asks implicit solvers (and their wrappers) for it
        return self.solver.root_finder

    def init(self, terms, t0, t1, y0, args):
        return self.solver.init(terms, t0, t1, y0, args)

    def step(self, terms, t0, t1, y0, args, solver_state, made_jump):
        y1, y_error, dense_info, solver_state, result = self.solver.step(
            terms, t0, t1, y0, args, solver_state, made_jump)
        return self.projection(y1, args), y_error, dense_info, solver_state, result

    def func(self, terms, t0, y0, args):
        return self.solver.func(terms, t0, y0, args)


def _adjoint(adjoint, stabilise: bool) -> diffrax.AbstractAdjoint:
    if adjoint is None:
        adjoint = diffrax.RecursiveCheckpointAdjoint()
    elif isinstance(adjoint, str):
        if adjoint not in ADJOINTS:
            raise ValueError(f"unknown adjoint {adjoint!r}; choose one of {sorted(ADJOINTS)} or a diffrax adjoint")
        adjoint = ADJOINTS[adjoint]()
    elif not isinstance(adjoint, diffrax.AbstractAdjoint):
        raise ValueError(f"adjoint must be a name in {sorted(ADJOINTS)} or a diffrax adjoint, got {adjoint!r}")
    if stabilise and isinstance(adjoint, diffrax.BacksolveAdjoint):
        raise ValueError(
            "adjoint 'backsolve' cannot differentiate a projected rollout (stabilise=True): it integrates the adjoint "
            "equations of the unprojected vector field backwards in time and cannot see the coordinate projection "
            "applied after every step, so its gradients would belong to a different flow. Use 'checkpoint', "
            "'direct' or 'forward', or stabilise=False (then with Baumgarte terms if drift matters)")
    return adjoint


def _parameter_label(mech: Mechanism, path) -> str:
    """Readable name of a floating leaf of the mechanism from its pytree path, e.g. ``spring 'suspension' stiffness``."""
    keys = [getattr(k, "name", getattr(k, "idx", getattr(k, "key", None))) for k in path]
    head = keys[0]
    named = {"springs": "spring", "tyres": "tyre", "points": "point"}
    if head in ("body_mass", "body_com", "body_inertia", "body_primaries") and len(keys) > 1:
        return f"body '{mech.bodies[keys[1]].name}' {head.removeprefix('body_')}"
    if head in named and len(keys) > 2:
        return f"{named[head]} '{getattr(mech, head)[keys[1]].name}' {keys[2]}"
    return str(head)


def _finite_parameters(mech: Mechanism, x0):
    """Refuse non-finite floating leaves of ``mech`` (e.g. swapped in with ``eqx.tree_at`` after the build): eagerly
    with their names when the values are concrete, else by a run-time error (under jit, grad, vmap)."""
    flat = [(path, leaf) for path, leaf in jax.tree_util.tree_flatten_with_path(mech)[0]
            if eqx.is_inexact_array(leaf) or isinstance(leaf, (float, complex))]
    if not flat:
        return x0
    labels = [_parameter_label(mech, path) for path, _ in flat]
    if not any(isinstance(leaf, jax.core.Tracer) for _, leaf in flat):
        bad = [lab for lab, (_, leaf) in zip(labels, flat) if not np.all(np.isfinite(np.asarray(leaf)))]
        if bad:
            raise ValueError(f"simulate_mechanism: the mechanism parameters are not finite: {', '.join(bad)} "
                             "(NaN or inf)")
        return x0
    bad = jnp.stack([~jnp.all(jnp.isfinite(leaf)) for _, leaf in flat])
    msgs = [f"simulate_mechanism: the mechanism parameters are not finite: {lab} (NaN or inf)" for lab in labels]
    return eqx.branched_error_if(x0, jnp.any(bad), jnp.argmax(bad), msgs)


def simulate_mechanism(mech: Mechanism, x0, xd0, t0: float, t1: float, *, solver: str = "tsit5",
                       rtol: float = 1e-8, atol: float = 1e-10, dt0=None, saveat_ts=None, max_steps: int = 100_000,
                       stabilise: bool = True, baumgarte: float = 0.0, adjoint=None, throw: bool = True,
                       progress: bool = False, solve: str = "dense") -> Solution:
    """Integrate the mechanism from ``(x0, xd0)``; returns a :class:`~particlesim.simulate.Solution` whose ``q``
    and ``qd`` are particle positions and velocities ``(T, 3F)``.

    ``stabilise`` projects after every step (see module docstring); ``baumgarte`` optionally adds Baumgarte terms
    instead of (or besides) it. Solver names as in :data:`particlesim.simulate.SOLVERS`. ``solve``: "dense" (any
    mechanism) or "chain" (the O(N) tip-to-base recursion of :mod:`.chain`, for uniform serial chains).
    ``adjoint``: a name in :data:`ADJOINTS` or a diffrax adjoint; ``None`` is "checkpoint". "backsolve" requires
    ``stabilise=False`` (module docstring).

    Raises ``ValueError`` for unknown names, wrong shapes, a non-finite initial state or non-finite mechanism
    parameters (at run time under jit); the error names the offending parameter.
    """
    if solver.lower() not in SOLVERS:
        raise ValueError(f"unknown solver {solver!r}; choose one of {sorted(SOLVERS)}")
    adjoint = _adjoint(adjoint, stabilise)
    x0 = jnp.asarray(x0, dtype=float)
    xd0 = jnp.asarray(xd0, dtype=float)
    if x0.shape != (mech.n_coords,) or xd0.shape != x0.shape:
        raise ValueError(f"state must be two vectors of length {mech.n_coords} (3 x free particles), "
                         f"got {x0.shape} and {xd0.shape}")
    for name, v in (("x0", x0), ("xd0", xd0)):
        if not isinstance(v, jax.core.Tracer) and not np.all(np.isfinite(np.asarray(v))):
            raise ValueError(f"{name} is not finite")
    x0 = _finite_parameters(mech, x0)

    # The mechanism travels to the solver as its flat list of leaves (rebuilt inside from the static tree
    # structure): diffrax 0.7's BacksolveAdjoint fails on empty tuples in ``args`` (a mechanism without tyres or
    # applied forces has some).
    leaves, treedef = jax.tree_util.tree_flatten(mech)

    def unpack(args):
        return jax.tree_util.tree_unflatten(treedef, args[0]), args[1]

    def project_y(y, args):
        return project(unpack(args)[0], *y)

    if solve == "chain":
        if baumgarte:
            raise ValueError("baumgarte terms are available with solve='dense' only")
        plan = chain_plan(mech)

        def field(t, y, args):
            x, xd = y
            return xd, chain_accelerations(unpack(args)[0], plan, t, x, xd)
    elif solve == "dense":
        def field(t, y, args):
            m, props = unpack(args)
            x, xd = y
            return xd, accelerations(m, t, x, xd, baumgarte=baumgarte, props=props)
    else:
        raise ValueError(f"unknown solve {solve!r}; choose 'dense' or 'chain'")

    implicit = solver.lower() in IMPLICIT_SOLVERS
    pid = (0.3, 0.3, 0.0) if implicit else (0.4, 1.0, 0.0)
    controller = diffrax.PIDController(rtol=rtol, atol=atol, pcoeff=pid[0], icoeff=pid[1], dcoeff=pid[2])
    # Settings diffrax would patch into an unwrapped solver, given up front: the root finder takes the
    # controller's tolerances; the stage loop kind suits the adjoint (forward mode needs "lax").
    kw = {"scan_kind": "lax" if isinstance(adjoint, diffrax.ForwardMode) else "bounded"}
    if implicit:
        kw["root_finder"] = diffrax.VeryChord(rtol=rtol, atol=atol, norm=controller.norm)
    inner = SOLVERS[solver.lower()](**kw)
    slv = ProjectedSolver(inner, project_y) if stabilise else inner
    saveat = diffrax.SaveAt(t0=True, t1=True) if saveat_ts is None else diffrax.SaveAt(ts=jnp.asarray(saveat_ts))
    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(field), slv, t0=t0, t1=t1, dt0=dt0, y0=(x0, xd0), args=(leaves, mass_properties(mech)),
        saveat=saveat,
        stepsize_controller=controller, max_steps=max_steps, throw=throw,
        adjoint=adjoint,
        progress_meter=diffrax.TqdmProgressMeter() if progress else diffrax.NoProgressMeter())
    xs, xds = sol.ys
    if stabilise:
        xs, xds = jax.vmap(lambda a, b: project(mech, a, b))(xs, xds)
    ok = sol.result == diffrax.RESULTS.successful
    return Solution(ts=sol.ts, q=jnp.where(ok, xs, jnp.nan), qd=jnp.where(ok, xds, jnp.nan),
                    steps=sol.stats["num_accepted_steps"], rejected=sol.stats["num_rejected_steps"],
                    status=sol.result, ok=ok)
