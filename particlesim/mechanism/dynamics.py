"""Equations of motion of a mechanism in particle coordinates, and their acceleration-level solve.

With the secondary particles eliminated (Attia eqs. (23)–(27)), the particles' kinetic energy is
``T = 1/2 qd^T M qd`` with a *constant* mass matrix ``M = M_s (x) I_3`` (``M_s`` the sum of the bodies' primary mass
matrices, :func:`~particlesim.particles.primary_mass_matrix`). D'Alembert's principle with the constraints
``Phi(q) = 0`` (:mod:`.constraints`) gives

    M xdd + J^T lam = Q(t, x, xd),      J xdd = gamma(x, xd)

The force and moment equations of Attia (9)–(10) and (23)–(24) are this system's rows projected on the rigid
motions of each body: the internal distance forces cancel pairwise and the reactions of a joint particle have no
moment about it. The multipliers ``lam`` are the constraint forces.

Solve (``M`` is constant, so everything that depends on parameters only is computed once per parameter set, in
:class:`Prepared`): with ``W = M_s^-1``, eliminate the accelerations,

    S lam = J M^-1 Q - gamma,   S = J M^-1 J^T (C x C, symmetric positive definite),   xdd = M^-1 (Q - J^T lam)

by one Cholesky factorisation of ``S`` per evaluation; :mod:`._algebra` arranges ``S``, ``J y`` and ``M^-1 J^T lam``
as a few small dense products with constants of the parameter set, and gravity's ``M^-1 Q_g`` is one of them. When ``M_s`` is singular
(a free particle carried by no body, e.g. the joint of two massless links) the full saddle-point system is solved
instead (:func:`_solve_kkt`, LU), the reference for every mechanism.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import jax.scipy.linalg  # noqa: F401
from jaxtyping import Array, Float

from ._algebra import (Prepared, apply_j, apply_minv_jt, drive_at, factor_schur, gamma, jacobian, prepare,
                       residual, rows, schur, schur_solve, solve_schur, velocity_target)
from ._algebra import LSQ_REFINE, LSQ_RTOL
from ._algebra import lumped_masses, mass_matrix, scalar_mass_matrix
from .forces import generalized_point_forces, point_force_terms, potential_energy, torque_forces
from .model import AppliedForce, Mechanism
from .sparse import solve_sparse
from .._jit import compiled

__all__ = ["Prepared", "prepare", "mass_properties", "mass_matrix", "scalar_mass_matrix", "lumped_masses",
           "accelerations", "accelerations_and_multipliers", "kinetic_energy", "total_energy", "residuals"]


@compiled("mass_properties")
def mass_properties(mech: Mechanism) -> Prepared:
    """The parameter-only quantities (mass matrix, its inverse, the rows' constant parts); pass them as ``props``
    to the functions of this module to compute them once for many states. Differentiate with respect to the
    mechanism (``mass_properties`` inside the differentiated function), not with respect to the fields of a
    ``props``: several fields hold one quantity in different forms (``a = d minv d^T``, ...), and the multipliers'
    solve takes its derivative from some of them only (:func:`~._algebra.schur_solve`)."""
    return prepare(mech)


def _forces(mech: Mechanism, prep: Prepared, t, q, qd, contact=None):
    """Point forces as ``(idx, f)`` (:func:`~.forces.point_force_terms`; or None) and torque generalised forces
    ``(3F,)`` (or None)."""
    topo = mech.topo
    terms = None
    if topo.spring_names or topo.tyre_names or topo.bump_names or any(isinstance(ap, AppliedForce)
                                                                       for ap in mech.applied):
        x, xd = q.reshape(-1, 3), qd.reshape(-1, 3)

        # Matrix products here, not _mm's outer sums: the same forward cost, and their transposes are matrix
        # products too, which makes the quarter car's reverse-mode and forward-mode (jacfwd) gradients cheaper.
        def read(i):  # the points' rows of W (constant gathers) times the particles: the read points only
            return prep.wk[i] @ x + prep.p0[i], prep.wk[i] @ xd

        terms = point_force_terms(mech, t, q, qd, read, contact)
    return terms, torque_forces(mech, t, q, qd)


def _solve(mech: Mechanism, prep: Prepared, t, q, qd, baumgarte: float, contact=None, split: bool = False):
    """``(qdd, lam)``; ``split``: by the hub split of :mod:`.sparse` (``mech.topo.sparse``) instead of the dense
    Schur complement."""
    r = rows(prep, q, qd, drive_at(mech, t))
    g = gamma(prep, r)
    if baumgarte:
        g = g - 2.0 * baumgarte * (apply_j(prep, r, qd.reshape(-1, 3)) - velocity_target(prep, r)) - \
            baumgarte**2 * residual(prep, mech.dot_kappa, r, q)
    terms, q_torque = _forces(mech, prep, t, q, qd, contact)
    if mech.topo.saddle_point:
        return _solve_kkt(prep, r, g, terms, q_torque, mech.topo.least_squares)
    minv_q = prep.minv_qg
    if terms is not None:  # only the loaded points' columns of M^-1 W^T (a constant gather), no scatter
        minv_q = minv_q + prep.mwk[:, terms[0]] @ terms[1]
    if q_torque is not None:
        minv_q = minv_q + prep.minv @ q_torque.reshape(-1, 3)
    if g.shape[0] == 0:
        return minv_q.reshape(-1), g
    if split:
        qdd, lam = solve_sparse(mech.topo.sparse, prep, r, g, minv_q)
        return qdd.reshape(-1), lam
    if mech.topo.least_squares:
        lam = solve_schur(factor_schur(schur(prep, r), True), apply_j(prep, r, minv_q) - g)
    else:
        lam = schur_solve(prep, r, schur(prep, r), apply_j(prep, r, minv_q) - g)
    return (minv_q - apply_minv_jt(prep, r, lam)).reshape(-1), lam


def _solve_kkt(prep: Prepared, r, g, terms, q_torque, least_squares: bool = False):
    """The full saddle-point system by LU (any mechanism, ``M`` singular included); with ``least_squares`` the
    multiplier block is damped (``-mu I``) and refined against the undamped system (minimum-norm multipliers).
    ``terms``: the point forces as :func:`~.forces.point_force_terms` gives them (or None)."""
    q = prep.qg.reshape(-1)
    if terms is not None:  # W^T F over the loaded points' rows of W only
        q = q + generalized_point_forces(prep.wk[terms[0]], terms[1])
    if q_torque is not None:
        q = q + q_torque
    j = jacobian(prep, r)
    j = j.reshape(j.shape[0], -1)
    m = jnp.kron(prep.ms, jnp.eye(3, dtype=prep.ms.dtype))
    n, c = m.shape[0], j.shape[0]
    kkt = jnp.block([[m, j.T], [j, jnp.zeros((c, c), dtype=m.dtype)]])
    rhs = jnp.concatenate([q, g])
    if not least_squares:
        sol = jnp.linalg.solve(kkt, rhs)
        return sol[:n], sol[n:]
    mu = LSQ_RTOL * jnp.max(jnp.abs(m))
    lu = jax.scipy.linalg.lu_factor(kkt - jnp.diag(jnp.concatenate([jnp.zeros(n, m.dtype), jnp.full(c, mu, m.dtype)])))
    sol = jax.scipy.linalg.lu_solve(lu, rhs)
    for _ in range(LSQ_REFINE):
        sol = sol + jax.scipy.linalg.lu_solve(lu, rhs - kkt @ sol)
    return sol[:n], sol[n:]


@compiled("accelerations_and_multipliers", static=('baumgarte',))
def accelerations_and_multipliers(mech: Mechanism, t, q: Float[Array, " 3F"], qd: Float[Array, " 3F"], *,
                                  baumgarte: float = 0.0, props: Prepared | None = None) -> tuple[Array, Array]:
    """Solve for ``(qdd, lam)``; ``props`` as from :func:`mass_properties` (computed here if not given).

    ``baumgarte`` (a rate ``a`` in 1/s, default 0) adds ``-2 a J qd - a^2 Phi`` to ``gamma`` so that drift decays
    critically damped; with the per-step projection of :func:`~particlesim.mechanism.simulate_mechanism` it is not
    needed.
    """
    prep = prepare(mech) if props is None else props
    return _solve(mech, prep, t, q, qd, baumgarte)


@compiled("accelerations", static=('baumgarte',))
def accelerations(mech: Mechanism, t, q: Float[Array, " 3F"], qd: Float[Array, " 3F"], *,
                  baumgarte: float = 0.0, props: Prepared | None = None) -> Float[Array, " 3F"]:
    """Particle accelerations ``qdd`` (see :func:`accelerations_and_multipliers`)."""
    return accelerations_and_multipliers(mech, t, q, qd, baumgarte=baumgarte, props=props)[0]


@compiled("kinetic_energy")
def kinetic_energy(mech: Mechanism, q: Float[Array, " 3F"], qd: Float[Array, " 3F"], *,
                   props: Prepared | None = None) -> Float[Array, ""]:
    """``1/2 qd^T M qd``: equal to the bodies' rigid kinetic energy for admissible velocities (``M`` is constant:
    ``q`` is taken for the state's usual order, ``(mech, q, qd)``, and not read)."""
    del q
    ms = prepare(mech).ms if props is None else props.ms
    v = qd.reshape(-1, 3)
    return 0.5 * jnp.sum(v * (ms @ v))


@compiled("total_energy")
def total_energy(mech: Mechanism, q, qd, *, t=0.0, props: Prepared | None = None) -> Float[Array, ""]:
    """Kinetic plus potential energy (:func:`~.forces.potential_energy`; ``t`` places a tyre's moving road)."""
    return kinetic_energy(mech, q, qd, props=props) + potential_energy(mech, q, t=t)


@compiled("residuals")
def residuals(mech: Mechanism, q, qd, *, t=0.0) -> tuple[Array, Array]:
    """Position- and velocity-level constraint residuals ``(Phi(q, t), J qd - nu(t))`` (``t`` matters only for
    driving constraints)."""
    from .constraints import constraints, velocity_constraints

    return constraints(mech, q, t=t), velocity_constraints(mech, q, qd, t=t)
