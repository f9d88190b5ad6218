"""Integrating a mechanism: the acceleration-level equations plus a projection onto the constraints every step.

Stabilisation scheme: *coordinate projection* (Hairer, Lubich & Wanner, Geometric Numerical Integration, §IV.4; Eich
1993). After every step of any diffrax solver, positions are projected back onto ``Phi(q) = 0`` along the
mass-orthogonal correction ``dx = -M^-1 J^T (J M^-1 J^T)^-1 Phi`` (the correction of least kinetic-energy norm),
then velocities onto ``J qd = 0`` the same way. One Cholesky factorisation of ``S = J M^-1 J^T`` at the stepped
state serves both: simplified-Newton position iterations with that factor, then velocity passes with ``J`` at the
projected positions. Between steps one of each: the factor is exact at the stepped state, so the first position
iteration leaves a residual of the order of the square of the correction, i.e. of the local error squared, and the
velocity pass likewise (it contracts the residual by the size of the position correction) — far below the step's own
error, and removed again at the next step, so nothing accumulates (a second iteration of each between steps costs
about 8 % of a quarter car's rollout and moves its end position by rounding). Saved outputs get two of each, which
reach round-off (the tests measure it): all of them when saved at given times (which fall inside steps) or with
events; else the initial and the final state. The projection
leaves the method's order intact (the correction is of the size of the local error), needs no tuning constant
(unlike Baumgarte's), and is a smooth function of state and parameters, so gradients pass through it. Its iteration
count is fixed rather than a tolerance-driven loop because a data-dependent loop cannot be differentiated in reverse
mode. The O(N) chain path (:func:`~.chain.chain_project`) projects the same way. Mechanisms whose mass matrix is
singular project with ``J J^T`` instead: three Gauss–Newton steps and one velocity pass, between steps and at
outputs alike.

Adjoints: "checkpoint" (default), "direct" and "forward" differentiate the discrete computation, projections
included. "backsolve" integrates the continuous adjoint equations of the vector field backwards in time; the
projection is a map applied between steps, not part of that vector field, so the backward solve would return the
sensitivities of a different (unprojected) flow. It is therefore refused with ``stabilise=True`` and allowed with
``stabilise=False``, where the integrated equations are exactly the ones it differentiates.
"""

from __future__ import annotations


import diffrax
import jax
import jax.numpy as jnp
import numpy as np

from .. import _ode
from .._ode import ADJOINTS, Solution
from ..errors import ModelError
from ..inertia import check_inertia, physical_inertia
from .chain import chain_accelerations, chain_mass_blocks, chain_plan, chain_project
from ._algebra import (BETWEEN_STEPS, FULL, Prepared, apply_j, apply_minv_jt, drive_at, factor_schur, jacobian,
                       prepare, residual, rows, schur, schur_solve, solve_schur, velocity_target)
from .dynamics import _solve
from .implicit import stage_system
from .forces import one_sided_gaps, one_sided_names
from .model import ELEMENT_FIELDS, ELEMENT_LABELS, NON_NEGATIVE, Mechanism
from .._jit import compiled
from .._threads import inline_batch

__all__ = ["ADJOINTS", "project", "simulate_mechanism", "SwitchCrossedWarning"]

SwitchCrossedWarning = _ode.SwitchCrossedWarning

# The projections' pass counts (FULL, BETWEEN_STEPS) are :mod:`._algebra`'s, shared with the O(N) chain path.


def _project_euclid(mech: Mechanism, prep: Prepared, q, qd, drive):
    """Minimum-norm (``J J^T``) projection for mechanisms with a singular mass matrix (LU, 3 Gauss–Newton steps)."""
    lsq = mech.topo.least_squares
    for _ in range(3):
        r = rows(prep, q, drive=drive)
        j = jacobian(prep, r).reshape(mech.n_constraints, -1)
        q = q - j.T @ solve_schur(factor_schur(j @ j.T, lsq), residual(prep, mech.dot_kappa, r, q))
    r = rows(prep, q, drive=drive)
    j = jacobian(prep, r).reshape(mech.n_constraints, -1)
    return q, qd - j.T @ solve_schur(factor_schur(j @ j.T, lsq), j @ qd - velocity_target(prep, r))


def project_prepared(mech: Mechanism, prep: Prepared, q, qd, t=0.0, passes: tuple[int, int] = FULL):
    """Project ``(q, qd)`` onto ``Phi(q, t) = 0`` and ``J qd = nu(t)`` (module docstring; ``t`` matters only for
    driving constraints); ``prep`` from :func:`prepare`; ``passes``: position iterations and velocity passes."""
    if mech.n_constraints == 0:
        return q, qd
    drive = drive_at(mech, t)
    if mech.topo.saddle_point:
        return _project_euclid(mech, prep, q, qd, drive)
    r0 = r = rows(prep, q, drive=drive)
    # One factorisation at the stepped state serves every pass below (least squares: minimum-norm corrections).
    # Without least squares each pass is a ``schur_solve`` with the same S: XLA computes its factorisation once, and
    # derivatives take the solve's tangent (dS applied to the multipliers, never formed) instead of going through
    # the factorisation and S.
    s0 = schur(prep, r0)
    if mech.topo.least_squares:
        factor = factor_schur(s0, True)
        solve = lambda rhs: solve_schur(factor, rhs)  # noqa: E731
    else:
        solve = lambda rhs: schur_solve(prep, r0, s0, rhs)  # noqa: E731
    for _ in range(passes[0]):
        lam = solve(residual(prep, mech.dot_kappa, r, q))
        q = q - apply_minv_jt(prep, r0, lam).reshape(-1)
        r = rows(prep, q, drive=drive)
    nu = velocity_target(prep, r)
    for _ in range(passes[1]):
        lam = solve(apply_j(prep, r, qd.reshape(-1, 3)) - nu)
        qd = qd - apply_minv_jt(prep, r0, lam).reshape(-1)
    return q, qd


@compiled("project")
def project(mech: Mechanism, q, qd, *, t=0.0, props: Prepared | None = None):
    """Project ``(q, qd)`` onto ``Phi(q, t) = 0`` and ``J qd = nu(t)`` (mass-orthogonal corrections; ``t`` matters
    only for driving constraints)."""
    return project_prepared(mech, prepare(mech) if props is None else props, q, qd, t)


def parameter_groups(mech: Mechanism) -> list:
    """``(labels, array)`` of every parameter, one label per entry along the leading axis."""
    topo = mech.topo
    body = [f"body '{n}'" for n in topo.body_names]
    groups = [([f"{b} mass" for b in body], mech.body_mass), ([f"{b} centre of mass" for b in body], mech.body_com),
              ([f"{b} inertia" for b in body], mech.body_inertia),
              ([f"{b} primaries" for b in body], mech.body_primaries),
              ([f"point '{n}' position" for n in topo.point_names], mech.point_local),
              ([f"ground particle '{topo.particle_names[i]}' position" for i in topo.ground], mech.ground_xyz),
              (list(topo.dot.labels), mech.dot_kappa), ("gravity", mech.gravity)]
    for kind, fields in ELEMENT_FIELDS.items():
        names = getattr(topo, f"{kind}_names")
        for f in fields:
            groups.append(([f"{ELEMENT_LABELS[kind]} '{n}' {f.replace('_', ' ')}" for n in names],
                           getattr(mech, f"{kind}_{f}")))
    for kind in ("force", "damping"):
        for n, table in zip(topo.spring_names, getattr(mech, f"spring_{kind}_curve")):
            if table.size:
                groups.append((f"spring '{n}' {kind} curve", table))
    for ap in mech.applied:
        groups += [(f"applied '{ap.name}' {lab}", leaf) for lab, leaf in _ode.leaf_groups(ap.fn)]
    for name, fn in zip(topo.drive.names, mech.drive_fns):
        groups += [(f"driver '{name}' {lab}", leaf) for lab, leaf in _ode.leaf_groups(fn)]
    if len(topo.drive):
        groups.append(([f"driver '{n}' offset" for n in topo.drive.names], mech.drive_offset))
    return [(lab, arr) for lab, arr in groups if arr.size]


def physical_checks(mech: Mechanism, entry: str = "simulate_mechanism") -> tuple | None:
    """Run-time flags of non-physical parameter values, with their messages (for :func:`_ode.runtime_checks`): a
    body whose mass is not positive or whose inertia about its centre of mass is not symmetric, positive
    semi-definite with principal moments meeting the triangle inequalities (the builder's and
    :meth:`~.model.Mechanism.with_params`' conditions, :func:`~particlesim.inertia.check_inertia` with
    ``degenerate_ok``, for values they did not see: traced ones, or leaves set by ``eqx.tree_at``;
    :func:`~particlesim.inertia.physical_inertia`); a negative stiffness, damping, free length or radius."""
    topo = mech.topo
    flags, msgs = [], []
    if topo.body_names:
        ok = physical_inertia(mech.body_mass, mech.body_inertia)
        flags.append(~ok)
        msgs += [f"{entry}: body '{n}' is not physical: its mass must be positive and its inertia about the centre "
                 "of mass symmetric, positive semi-definite, with principal moments meeting the triangle inequality "
                 "(a value set under a trace, which is not checked when set)"
                 for n in topo.body_names]
    for prefix, fields in NON_NEGATIVE.items():
        names = getattr(topo, f"{prefix}_names")
        for f in fields:
            if names:
                flags.append(~jnp.all((getattr(mech, f"{prefix}_{f}") >= 0.0).reshape(len(names), -1), axis=1))
                msgs += [f"{entry}: {ELEMENT_LABELS[prefix]} '{n}' {f.replace('_', ' ')} must be non-negative"
                         for n in names]
    if not flags:
        return None
    return jnp.concatenate(flags), msgs


def physical_checks_eager(mech: Mechanism, entry: str = "simulate_mechanism") -> None:
    """:func:`physical_checks` on concrete values, raising :class:`~particlesim.errors.ModelError` (a body's by
    :func:`~particlesim.inertia.check_inertia`, an :class:`~particlesim.errors.InertiaError`) before any run."""
    topo = mech.topo
    masses, coms, inertias = (np.asarray(x) for x in (mech.body_mass, mech.body_com, mech.body_inertia))
    for b, name in enumerate(topo.body_names):
        check_inertia(masses[b], coms[b], inertias[b], f"{entry}: body {name!r}", degenerate_ok=True)
    for prefix, fields in NON_NEGATIVE.items():
        for f in fields:
            values = np.asarray(getattr(mech, f"{prefix}_{f}"))
            for n, v in zip(getattr(topo, f"{prefix}_names"), values):
                if not np.all(v >= 0.0):
                    raise ModelError(f"{entry}: {ELEMENT_LABELS[prefix]} '{n}' {f.replace('_', ' ')} must be "
                                     f"non-negative, got {np.asarray(v).tolist()!r}")


def _initial_contact(deflection, t0, q0, qd0, xdd_free):
    """Each tyre's law at the start (1.0 in contact): compressed (deflection < 0), or at exactly zero deflection
    heading into the ground: deflection rate < 0 (a moving road's rate included), or at rest relative to the ground
    with the free (no-contact) acceleration pressing in.

    A tyre that starts exactly touching (the usual assembly) must start in the law it is entering: its switching
    function starts at zero, where no sign change is ever seen, so starting it "off" let it sink unopposed."""
    def along(s):  # the deflections along the start's free motion, s seconds on
        return deflection(t0 + s, q0 + s * qd0 + 0.5 * s**2 * xdd_free)

    zero = jnp.zeros((), q0.dtype)
    d, rate = jax.jvp(along, (zero,), (jnp.ones_like(zero),))
    push = jax.jacfwd(jax.jacfwd(along))(zero)  # the second derivative, which decides when the rate is 0
    entering = jnp.where(rate != 0.0, rate < 0.0, push < 0.0)
    return jnp.where(d != 0.0, d < 0.0, entering).astype(q0.dtype)


def _budget_hint(mech: Mechanism, solver: str, solve: str) -> str:
    """What usually exhausts a mechanism rollout's step budget, and what to do (appended to diffrax's message)."""
    causes = []
    if solver not in _ode.IMPLICIT_SOLVERS:
        causes.append("a force element much stiffer than the motion (spring, damper, tyre), which holds an explicit "
                      "solver to tiny steps (an implicit solver such as solver='kvaerno5' takes large ones)")
    if solve == "dense" and mech.n_constraints and not mech.topo.least_squares:
        causes.append("a singular position, where the constraint rows lose rank (e.g. a parallelogram four-bar "
                      "passing its flat position): this mechanism solves for exact multipliers, which are not unique "
                      "there or do not exist, and the step size collapses (many rejected steps: "
                      "simulate_mechanism(..., throw=False) returns them in Solution.rejected). Build it with "
                      "multipliers='least_squares' to move through such positions")
    return f"For a mechanism, the usual {'causes' if len(causes) > 1 else 'cause'}: {'; or '.join(causes)}." \
        if causes else ""


@_ode.cached("simulate_mechanism")
def _simulate(mech, q0, qd0, t0, t1, rtol, atol, dt0, ts, time_bad, cfg, stabilise, baumgarte, solve,
              max_events=0, warn_switch=False, check_physical=True):
    # Non-physical values are looked for here only when the eager check could not see them (traced leaves): the
    # bodies' test (a 3 x 3 eigendecomposition per body) is a noticeable part of a short rollout's cost.
    param_bad = _ode.merge_checks(_ode.check_finite("simulate_mechanism", parameter_groups(mech)),
                                  physical_checks(mech) if check_physical else None)
    q0, qd0 = _ode.runtime_checks((q0, qd0), time_bad, param_bad, "simulate_mechanism", "(q0, qd0)")
    plan = chain_plan(mech) if solve == "chain" else None
    split = solve == "sparse"
    # The chain path needs only the bodies' mass blocks; the dense path its prepared constants (Prepared).
    cblocks = chain_mass_blocks(mech) if plan is not None else None
    prep = prepare(mech, split) if plan is None else None
    # The mechanism and its prepared quantities reach diffrax through ``args`` (so every adjoint differentiates
    # them) as a flat list of array leaves; the rest is rebuilt from the static structure inside.
    leaves, treedef = jax.tree.flatten((mech, prep, cblocks))
    arrays = [i for i, leaf in enumerate(leaves) if isinstance(leaf, jax.Array)]

    def unpack(args):
        full = list(leaves)
        for i, a in zip(arrays, args):
            full[i] = a
        return jax.tree.unflatten(treedef, full)

    def field(t, y, args):
        m, p, cb = unpack(args)
        q, qd = y
        if plan is not None:
            return qd, chain_accelerations(m, plan, t, q, qd, mass_blocks=cb)
        return qd, _solve(m, p, t, q, qd, baumgarte, split=split)[0]

    def projection(t, y, args, passes=BETWEEN_STEPS):
        m, p, cb = unpack(args)
        if plan is not None:
            return chain_project(m, plan, *y, mass_blocks=cb, passes=passes)
        return project_prepared(m, p, *y, t, passes)

    def full_projection(t, y, args):
        return projection(t, y, args, FULL)

    def deflections(t, q, m, p):  # every one-sided element's switching function (tyres, bump stops)
        return one_sided_gaps(m, p.wk @ q.reshape(-1, 3) + p.p0, t)

    n_switch = len(one_sided_names(mech))
    # Implicit solvers take their Newton matrix from the mechanism's structure (:mod:`.implicit`). Diffrax's own
    # stays with the chain path (its O(N) solve has no saddle-point form) and with redundant rows (least-squares
    # multipliers: the saddle-point matrix is singular, and damping its multiplier block left the stage solves
    # short of tight tolerances on a doubly closed four-bar).
    implicit = cfg.solver in _ode.IMPLICIT_SOLVERS and plan is None and not mech.topo.least_squares

    def system(contact_of=None):
        return stage_system(unpack, baumgarte, split, contact_of, mech.n_constraints, n_switch > 0)

    events = None
    args0 = [leaves[i] for i in arrays]
    if max_events:  # tyres switch at located events: each segment keeps every tyre's law fixed
        def field_modes(t, y, args):
            m, p, cb = unpack(args[0])
            q, qd = y
            return qd, _solve(m, p, t, q, qd, baumgarte, contact=args[1] > 0.5, split=split)[0]

        def surfaces(t, y, args, modes):
            m, p, _ = unpack(args)
            d = deflections(t, y[0], m, p)
            return jnp.where(modes > 0.5, -d, d)  # positive in the current law, crossing zero downwards

        modes0 = _initial_contact(lambda t, q: deflections(t, q, mech, prep), t0, q0, qd0,
                                  _solve(mech, prep, t0, q0, qd0, baumgarte,
                                         contact=jnp.zeros(n_switch, bool))[0])
        ts_, (qs, qds), steps, rejected, result, ok, events = _ode.integrate_events(
            field_modes, (q0, qd0), args0, modes0, surfaces, n_switch, max_events, t0=t0, t1=t1,
            rtol=rtol, atol=atol, dt0=dt0, ts=ts, cfg=cfg,
            projection=(lambda t, y, args: projection(t, y, args[0])) if stabilise else None,  # args: (args, modes)
            hint=_budget_hint(mech, cfg.solver, solve),
            system=system(lambda args: args[1] > 0.5) if implicit else None)
    else:
        ts_, (qs, qds), steps, rejected, result, ok = _ode.integrate(
            field, (q0, qd0), args0, t0=t0, t1=t1, rtol=rtol, atol=atol, dt0=dt0, ts=ts,
            cfg=cfg, projection=projection if stabilise else None, hint=_budget_hint(mech, cfg.solver, solve),
            system=system() if implicit else None)
    if stabilise and (cfg.save_ts or max_events):  # saved states interpolated inside steps: onto the constraints
        qs, qds = jax.lax.map(lambda tab: full_projection(tab[0], tab[1:], args0), (ts_, qs, qds))
    elif stabilise:  # saved at t0 and t1 only: both to round-off (t1 ends a lighter projection); together while
        # their two factorisations stay on this thread in one LAPACK call (particlesim._threads.inline_batch)
        qs, qds = jax.lax.map(lambda tab: full_projection(tab[0], tab[1:], args0), (ts_, qs, qds),
                              batch_size=inline_batch(max(1, mech.n_constraints)))
    if warn_switch:  # a differentiated rollout stepping across a tyre's switch: say so (derivatives are biased)
        touching = jax.vmap(lambda t, q: deflections(t, q, mech, prep) < 0.0)(
            jnp.concatenate([jnp.asarray(t0, ts_.dtype)[None], ts_]), jnp.concatenate([q0[None], qs]))
        jax.debug.callback(_warn_switches, jnp.any(touching[1:] != touching[:-1], axis=0),
                           names=one_sided_names(mech))
    return Solution(ts=ts_, q=qs, qd=qds, steps=steps, rejected=rejected, status=result, ok=ok, events=events)


def _warn_switches(changed, names):
    _ode.warn_switches(changed, list(names))


#: A driven mechanism's initial state must meet its driving rows to this fraction of the mechanism's size (and
#: speed): a start that does not is a modelling error (e.g. the crank's speed left out of ``qd0``), not drift.
DRIVEN_START_RTOL = 1e-6


def _check_driven_start(mech: Mechanism, q0, qd0, t0) -> None:
    """Refuse an initial state that violates the driving constraints at ``t0`` (concrete values only)."""
    from .constraints import constraints, velocity_constraints

    if not all(_ode._concrete(v) for v in (q0, qd0, t0)) or any(
            isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves(mech)):
        return
    n = mech.n_constraints - len(mech.topo.drive)
    pos = np.asarray(q0).reshape(-1, 3)
    size = max(float(np.ptp(pos, axis=0).max()), 1.0)
    speed = max(float(np.abs(np.asarray(qd0)).max()), 1.0)
    res = np.asarray(constraints(mech, q0, t=float(t0)))[n:]
    vel = np.asarray(velocity_constraints(mech, q0, qd0, t=float(t0)))[n:]
    labels = mech.topo.drive.labels
    for what, r, tol in (("position", res, DRIVEN_START_RTOL * size), ("velocity", vel, DRIVEN_START_RTOL * speed)):
        bad = np.flatnonzero(np.abs(r) > tol)
        if bad.size:
            raise ValueError(f"simulate_mechanism: the initial state violates {labels[bad[0]]} at t0 = {float(t0)} "
                             f"({what} residual {float(r[bad[0]]):.3g}); start it consistently, e.g. "
                             "x0, xd0 = project(mech, x0, xd0, t=t0)")


def simulate_mechanism(mech: Mechanism, q0, qd0, t0: float, t1: float, *, solver: str = "tsit5",
                       rtol: float = 1e-8, atol: float = 1e-10, dt0=None, saveat_ts=None, max_steps: int = 100_000,
                       stabilise: bool = True, baumgarte: float = 0.0, adjoint=None, pid=None, throw: bool = True,
                       progress: bool = False, solve: str = "dense", events: bool = False,
                       max_events: int = 16, max_step=None) -> Solution:
    """Integrate the mechanism from ``(q0, qd0)``; returns a :class:`~particlesim.simulate.Solution` whose ``q``
    and ``qd`` are particle positions and velocities ``(T, 3F)``.

    Compiles once per mechanism structure (its :class:`~.model.Topology` and applied-force functions) and solver
    settings: new parameter values (:meth:`~.model.Mechanism.with_params`), initial states, ``t0``/``t1``,
    tolerances and save times (of the same count) reuse the compiled program.

    ``stabilise`` projects after every step (module docstring); ``baumgarte`` optionally adds Baumgarte terms
    instead of (or besides) it. Solver names as in :data:`particlesim.simulate.SOLVERS`. ``solve``: "dense" (any
    mechanism; one Cholesky factorisation of the ``C x C`` constraint system per evaluation), "chain" (the O(N)
    tip-to-base recursion of :mod:`.chain`, for uniform serial chains) or "sparse" (the groups hanging from a hub
    body, e.g. a vehicle's corners from its chassis, eliminated apart: :mod:`.sparse`; where ``mech.topo.sparse``
    holds a plan; its projections between steps stay dense, where one factorisation serves both passes). ``adjoint``: a name in :data:`ADJOINTS`
    or a diffrax adjoint; ``None`` is "checkpoint". "backsolve" requires ``stabilise=False`` (module docstring).
    ``pid``: ``(pcoeff, icoeff, dcoeff)`` of the step-size controller, as in :func:`particlesim.simulate.simulate`
    (defaults (0, 1, 0) explicit, integral control; (0.3, 0.3, 0) implicit). A scene whose step is bounded by
    stability rather than accuracy (a stiff tyre or spring under an explicit solver: a quarter of the steps
    rejected, step counts nearly flat in ``rtol``) takes fewer steps with a less sensitive controller such as
    ``(0.2, 0.4, 0.0)``.

    ``events=True`` locates every switch of a one-sided element (a tyre's contact or a bump stop's engagement
    closing or opening) instead of stepping across it: the run is split into smooth segments (each element's law
    fixed), each ending where a gap crosses zero (root-found on the step's dense output), so that derivatives carry
    the jump at the switch; at most ``max_events`` switches. The switches are reported in ``Solution.events``
    (:class:`~particlesim._ode.Events`; ``element`` indexes the tyres, then the bump stops:
    :func:`~.forces.one_sided_names`). Without events, a differentiated rollout in which such an element
    switches warns (:class:`SwitchCrossedWarning`). "backsolve" is not available with events.

    ``max_step`` bounds each step [s] (``None``: unbounded). An adaptive solver sees the road only where it
    steps: from rest it may stride over a short bump whole and never feel it (no crossing either, so ``events``
    cannot help); a bound below the road's shortest feature (a bump's duration) rules that out.

    ``max_steps`` bounds the steps of the run (of each smooth segment, with ``events``); exhausting it raises
    (``throw=True``, at run time) with the usual causes for this mechanism and solver — a stiff element under an
    explicit solver; with exact multipliers, a singular position (build with ``multipliers='least_squares'``) —
    or is reported in ``Solution.status`` with NaN states (``throw=False``).

    Raises ``ValueError`` for unknown names, bad tolerances or times, a non-finite initial state; ``ModelError``
    for wrong state shapes, non-finite parameters and non-physical ones (a non-positive mass, an inertia breaking
    the triangle inequality, a negative stiffness...: values ``with_params`` did not check, such as leaves set by
    ``eqx.tree_at``); the error names the offending parameter. Values traced in a caller's ``jit``, ``vmap`` or
    ``grad`` are checked when the program runs (:func:`physical_checks`), raising JAX's run-time error
    (``jax.errors.JaxRuntimeError``) with the same message.
    """
    cfg = _ode.settings(solver=solver, adjoint=adjoint, max_steps=max_steps, throw=throw, progress=progress,
                        pid=pid, save_ts=saveat_ts is not None, max_step=max_step)
    if stabilise and isinstance(cfg.adjoint, diffrax.BacksolveAdjoint):
        raise ValueError(
            "adjoint 'backsolve' cannot differentiate a projected rollout (stabilise=True): it integrates the adjoint "
            "equations of the unprojected vector field backwards in time and cannot see the coordinate projection "
            "applied after every step, so its gradients would belong to a different flow. Use 'checkpoint', "
            "'direct' or 'forward', or stabilise=False (then with Baumgarte terms if drift matters)")
    if solve not in ("dense", "chain", "sparse"):
        raise ValueError(f"unknown solve {solve!r}; choose 'dense', 'chain' or 'sparse'")
    if solve == "sparse" and mech.topo.sparse is None:
        raise ValueError("solve='sparse' needs a hub body whose removal splits the mechanism into groups that are "
                         "cheaper to solve apart (particlesim.mechanism.sparse); this mechanism has none (no body "
                         "splits it, a body shares a particle with the hub, a group's rows are dependent with the hub "
                         "held still, or its multipliers are least-squares): use solve='dense'")
    if isinstance(max_events, bool) or not isinstance(max_events, (int, np.integer)) or max_events < 1:
        raise ValueError(f"max_events must be a positive integer, got {max_events!r}")
    switching = bool(mech.topo.tyre_names or mech.topo.bump_names)
    evented = bool(events) and switching
    if evented and (solve == "chain" or isinstance(cfg.adjoint, diffrax.BacksolveAdjoint)):
        raise ValueError("events=True needs solve='dense' or 'sparse' and a discrete adjoint ('checkpoint', 'direct', "
                         "'forward'): 'backsolve' would integrate backwards across the located switches")
    if solve == "chain":
        if baumgarte:
            raise ValueError("baumgarte terms are available with solve='dense' only")
        chain_plan(mech)  # refuses what is not a uniform chain, now
    q0 = _ode.as_state(q0)
    qd0 = _ode.as_state(qd0)
    if q0.shape != (mech.n_coords,) or qd0.shape != q0.shape:
        raise ModelError(f"state must be two vectors of length {mech.n_coords} (3 x free particles), "
                         f"got {q0.shape} and {qd0.shape}")
    _ode.check_state((q0, qd0), ("q0", "qd0"))
    t0_, t1_, rtol_, atol_, dt0_, ts, time_bad = _ode.times(t0, t1, rtol, atol, dt0, saveat_ts)
    concrete = _ode.check_finite_eager("simulate_mechanism", mech, lambda: parameter_groups(mech),  # concrete values
                                       lambda: physical_checks_eager(mech))
    if len(mech.topo.drive):
        _check_driven_start(mech, q0, qd0, t0)
    warn = not evented and switching and _ode.differentiated((mech, q0, qd0))
    return _simulate(mech, q0, qd0, t0_, t1_, rtol_, atol_, dt0_, ts, time_bad, cfg, bool(stabilise),
                     float(baumgarte), solve, int(max_events) if evented else 0, warn, not concrete)
