"""Bad mechanisms are refused with a message naming the culprit: at build time, or when traced (applied loads
whose functions return the wrong shape)."""

import numpy as np
import pytest

from particlesim import ModelError
from particlesim.inertia import RigidInertia
from particlesim.mechanism import MechanismBuilder


def test_a_consistent_loop_builds(four_bar):
    mech, x0 = four_bar().build(dof=3)  # 9 coordinates - 3 rod lengths - 3 loop rows: planar + 2 out-of-plane
    assert mech.n_coords == 9


def test_dangling_particle(four_bar):
    mb = four_bar()
    mb.particle("lost", (5, 5, 5))
    with pytest.raises(ModelError, match="particle 'lost' is dangling"):
        mb.build()


def test_over_constrained_loop(four_bar):
    with pytest.raises(ModelError, match="over-constrained: the mechanism has 2 degrees of freedom, expected 3"):
        four_bar(extra_link=True).build(dof=3)
    mb = four_bar()
    mb.cut_joint("B", "B2", name="the same cut twice")
    with pytest.raises(ModelError, match="over-constrained: .*the same cut twice"):
        mb.build(multipliers="exact")  # the default keeps redundant rows (least squares, tests/mechanism/test_redundant.py)


def test_under_constrained_loop(four_bar):
    with pytest.raises(ModelError, match="under-constrained: the mechanism has 6 degrees of freedom, expected 3"):
        four_bar(close=False).build(dof=3)


def test_inconsistent_initial_positions(four_bar):
    with pytest.raises(ModelError, match="initial positions violate constraints: loop closure"):
        four_bar(offset=0.01).build()


def test_zero_length_spring(four_bar):
    mb = four_bar()
    mb.spring_damper("bad spring", "A", "A", 100.0, 1.0, 0.1)
    with pytest.raises(ModelError, match="spring 'bad spring': .*zero length"):
        mb.build()


@pytest.mark.parametrize("k, c, l0, match", [(-1.0, 0.0, 0.1, "stiffness .* got -1.0"),
                                             (1.0, np.nan, 0.1, "damping .* got nan"),
                                             (1.0, 0.0, -0.2, "free length .* got -0.2"),
                                             (lambda t: 1.0, 0.0, 0.1, "stiffness .* got a function"),
                                             (1.0, "0.5", 0.1, "damping .* got a str"),
                                             (1.0, 0.0, np.ones(2), "free length .* got a ndarray")])
def test_non_physical_spring_constants(k, c, l0, match, four_bar):
    """Values that are not finite, non-negative numbers (a negative, a NaN, a function, a string, an array) are
    refused naming the spring and the argument."""
    with pytest.raises(ModelError, match=f"spring 's': {match}"):
        four_bar().spring_damper("s", "A", "C", k, c, l0)
    with pytest.raises(ModelError, match=f"spring 's': {match.split()[0]}.* must be a finite and non-negative"):
        four_bar().spring_damper("s", "A", "C", k, c, l0)


def test_unknown_names_and_bad_bodies(four_bar):
    mb = four_bar()
    mb.cut_joint("A", "nowhere", name="typo joint")
    with pytest.raises(ModelError, match="typo joint: unknown particle or point 'nowhere'"):
        mb.build()
    mb = MechanismBuilder()
    mb.particle("P", (0, 0, 0))
    with pytest.raises(ModelError, match="body 'blob': needs 2 .* got 1"):
        mb.body("blob", RigidInertia.slender_rod(1.0, (0, 0, 0), (1, 0, 0)), ["P"])
    with pytest.raises(ModelError, match="particle 'P' is defined twice"):
        mb.particle("P", (1, 0, 0))
    with pytest.raises(ModelError, match="particle 'Q': position must be 3 finite numbers"):
        mb.particle("Q", (0, np.nan, 0))


def test_massless_direction_is_refused(four_bar):
    """A particle held only by a massless link can still move around it: no mass, no dynamics."""
    mb = four_bar()
    mb.particle("bob", (0, 2, 0))
    mb.link("A", "bob", name="string")
    with pytest.raises(ModelError, match="carries no mass"):
        mb.build()


def test_applied_force_of_the_wrong_shape_is_named():
    """An applied force whose function returns other than 3 numbers is refused when traced, naming it (it used to
    fail inside JAX's broadcasting with no name)."""
    import jax.numpy as jnp

    from particlesim.mechanism import accelerations

    mb = MechanismBuilder(planar=True)
    mb.ground("O", (0.0, 0.0))
    mb.particle("A", (1.0, 0.0))
    mb.rod("r", "O", "A", mass=1.0)
    mb.applied_force("push", "A", lambda t, q, qd: jnp.array([1.0, 0.0]))
    mech, q0 = mb.build(dof=1)
    with pytest.raises(ModelError, match=r"applied force 'push' must return a force of shape \(3,\).*got shape \(2,\)"):
        accelerations(mech, 0.0, q0, 0 * q0)


def test_applied_torque_of_the_wrong_shape_is_named():
    """The same for an applied torque, in the dynamics and in the body reactions."""
    import jax.numpy as jnp

    from particlesim.mechanism import accelerations
    from particlesim.mechanism.outputs import body_reactions

    mb = MechanismBuilder(planar=True)
    mb.ground("O", (0.0, 0.0))
    mb.particle("A", (1.0, 0.0))
    mb.particle("B", (0.0, 1.0))
    mb.planar_body("plate", mass=1.0, moment=0.2, com=(0.3, 0.3), primaries=["O", "A", "B"])
    mb.applied_torque("twist", "plate", lambda t, q, qd: jnp.array([0.0, 1.0]))
    mech, q0 = mb.build(dof=1)
    match = r"applied torque 'twist' must return a torque of shape \(3,\).*got shape \(2,\)"
    with pytest.raises(ModelError, match=match):
        accelerations(mech, 0.0, q0, 0 * q0)
    with pytest.raises(ModelError, match=match):
        body_reactions(mech, 0.0, q0, 0 * q0)


def test_parameters_by_name_are_checked_as_the_builder_checks_them(four_bar):
    """``with_params`` refuses, naming the body or element: a value of the wrong shape, a negative or NaN mass or a
    tensor breaking the triangle inequality (``check_inertia``), a negative or non-finite stiffness, damping or free
    length; a physical change is accepted, also traced (values under a trace are not checked here)."""
    import jax
    import jax.numpy as jnp

    mb = four_bar()
    mb.spring_damper("spring", "A", "C", stiffness=10.0, damping=0.5, free_length=2.0)
    mech, _ = mb.build(dof=3)
    for kw, match in (({"body": {"coupler": {"com": (1.0, 1.0)}}}, r"body 'coupler' com must have shape \(3,\)"),
                      ({"spring": {"spring": {"stiffness": np.ones(2)}}}, r"spring 'spring' stiffness must have shape"),
                      ({"body": {"coupler": {"mass": -1.0}}}, "body 'coupler': mass must be positive"),
                      ({"body": {"coupler": {"mass": float("nan")}}}, "body 'coupler': mass contains NaN"),
                      ({"body": {"coupler": {"inertia": np.diag([1.0, 1.0, 3.0])}}}, "triangle inequality"),
                      ({"spring": {"spring": {"damping": -0.1}}}, "spring 'spring' damping must be finite and non"),
                      ({"spring": {"spring": {"free_length": float("inf")}}}, "spring 'spring' free length must be")):
        with pytest.raises(ModelError, match=match):
            mech.with_params(**kw)
    heavier = mech.with_params(body={"coupler": {"mass": 2.0}}, spring={"spring": {"stiffness": 20.0}})
    assert float(heavier.body_mass[mech.body_index("coupler")]) == 2.0
    traced = jax.jit(lambda m: mech.with_params(body={"coupler": {"mass": m}}).body_mass)(jnp.asarray(3.0))
    assert float(traced[mech.body_index("coupler")]) == 3.0


def test_non_physical_values_set_under_a_trace_are_refused_at_run_time(four_bar):
    """Values ``with_params`` cannot check (traced) are refused by ``simulate_mechanism`` when it runs (JAX's
    run-time error), naming the body or element: a negative mass, a tensor breaking the triangle inequality, a
    negative damping; NaN is reported as not finite. Concrete values that bypass ``with_params`` (``eqx.tree_at``)
    are refused before the run with ``ModelError``. A physical traced change runs, equal to the same change made
    concretely (to round-off: the one is compiled inside the caller's jit, the other at top level)."""
    import equinox as eqx
    import jax
    import jax.numpy as jnp

    from particlesim.mechanism import simulate_mechanism

    mb = four_bar()
    mb.spring_damper("spring", "A", "C", stiffness=10.0, damping=0.5, free_length=2.0)
    mech, q0 = mb.build(dof=3)
    q0 = jnp.asarray(q0)
    b = mech.body_index("coupler")

    def final(m):
        return simulate_mechanism(m, q0, jnp.zeros_like(q0), 0.0, 0.05).q[-1]

    cases = ((lambda v: mech.with_params(body={"coupler": {"mass": v}}), -1.0, "body 'coupler' is not physical"),
             (lambda v: mech.with_params(body={"coupler": {"inertia": v}}), jnp.diag(jnp.array([1.0, 1.0, 3.0])),
              "body 'coupler' is not physical"),
             (lambda v: mech.with_params(spring={"spring": {"damping": v}}), -0.1,
              "spring 'spring' damping must be non-negative"),
             (lambda v: mech.with_params(body={"coupler": {"mass": v}}), jnp.nan,
              "parameter body 'coupler' mass is not finite"))
    for set_value, value, match in cases:
        with pytest.raises(jax.errors.JaxRuntimeError, match=match):
            jax.block_until_ready(jax.jit(lambda v: final(set_value(v)))(jnp.asarray(value)))
    bypass = eqx.tree_at(lambda m: m.body_mass, mech, mech.body_mass.at[b].set(-2.0))
    with pytest.raises(ModelError, match="simulate_mechanism: body 'coupler': mass must be positive"):
        final(bypass)
    loose = eqx.tree_at(lambda m: m.spring_stiffness, mech, -mech.spring_stiffness)
    with pytest.raises(ModelError, match="simulate_mechanism: spring 'spring' stiffness must be non-negative"):
        final(loose)
    traced = jax.jit(lambda v: final(mech.with_params(body={"coupler": {"mass": v}})))(jnp.asarray(2.5))
    concrete = final(mech.with_params(body={"coupler": {"mass": 2.5}}))
    np.testing.assert_allclose(np.asarray(traced), np.asarray(concrete), rtol=0.0, atol=1e-12)


def test_physical_inertia_agrees_with_check_inertia():
    """The run-time test (traceable) against the eager ``check_inertia(degenerate_ok=True)`` on rotated tensors:
    physical ones, rods and planar bodies (a zero moment, a triangle equality), a negative moment, triangle
    inequalities broken by 1 %, by 1e-6 and by 2e-7 (100 times the tolerance), a thin rod broken by 2e-6 (Sigma's
    eigenvalues -1e-6, 1e-5, 1), tensors skewed by 1e-3 and by 1.5 times the tolerance, and non-positive or NaN
    masses."""
    import jax.numpy as jnp

    from particlesim.inertia import PHYSICAL_RTOL, InertiaError, check_inertia, physical_inertia

    rng = np.random.default_rng(21)
    moments = [(1.0, 2.0, 2.5), (0.0, 1.0, 1.0), (1.0, 2.0, 3.0), (0.3, 0.3, 0.6), (-0.1, 1.0, 1.0),
               (1.0, 2.0, 3.0 + 1e-6), (1.0, 2.0, 3.03), (4.0, 1.0, 1.0), (1e-3, 2e-3, 2.5e-3), (5.0, 5.0, 5.0),
               (1.0, 2.0, 3.0 + 2e-7), (1.00001, 0.999999, 9e-6)]
    cases = []
    for mom in moments:
        r = np.linalg.qr(rng.normal(size=(3, 3)))[0]  # a random orthogonal matrix
        cases.append((1.5, r @ np.diag(mom) @ r.T))
    skew, slightly = np.diag([1.0, 2.0, 2.5]), np.diag([1.0, 2.0, 2.5])
    skew[0, 1] += 1e-3
    slightly[0, 1] += 1.5 * PHYSICAL_RTOL * 5.5
    cases += [(1.5, skew), (1.5, slightly), (0.0, np.diag([1.0, 2.0, 2.5])), (-1.0, np.diag([1.0, 2.0, 2.5])),
              (np.nan, np.diag([1.0, 2.0, 2.5]))]
    verdicts = np.asarray(physical_inertia(jnp.asarray([m for m, _ in cases]), jnp.asarray([i for _, i in cases])))
    expected = []
    for m, i in cases:
        try:
            check_inertia(m, np.zeros(3), i, degenerate_ok=True)
            expected.append(True)
        except InertiaError:
            expected.append(False)
    assert verdicts.tolist() == expected
    assert expected == [True, True, True, True, False, False, False, False, True, True, False, False,
                        False, False, False, False, False]
