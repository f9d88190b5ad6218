"""The public rollouts compile once per structure and solver settings (a trace counter, not a timer), and the shared
integration core refuses bad settings the same way for trees and mechanisms."""

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from particlesim import _ode
from particlesim.errors import ModelError
from particlesim.inertia import RigidInertia
from particlesim.mechanism import MechanismBuilder, simulate_mechanism
from particlesim.simulate import simulate

TWO_LINK_URDF = """<?xml version="1.0"?>
<robot name="two_link">
  <link name="world"/>
  <link name="a"><inertial><origin xyz="0 -0.25 0"/><mass value="1.3"/>
    <inertia ixx="0.030" ixy="0" ixz="0" iyy="0.004" iyz="0" izz="0.029"/></inertial></link>
  <link name="b"><inertial><origin xyz="0 -0.2 0"/><mass value="0.8"/>
    <inertia ixx="0.012" ixy="0" ixz="0" iyy="0.002" iyz="0" izz="0.011"/></inertial></link>
  <joint name="j1" type="revolute"><parent link="world"/><child link="a"/><axis xyz="0 0 1"/>
    <limit effort="1" lower="-3" upper="3" velocity="1"/></joint>
  <joint name="j2" type="revolute"><parent link="a"/><child link="b"/><origin xyz="0 -0.5 0"/><axis xyz="1 0 0"/>
    <limit effort="1" lower="-3" upper="3" velocity="1"/></joint>
</robot>
"""


@pytest.fixture(scope="module")
def pendulum():
    """Two rods and a spring: a small mechanism whose parameters all have names."""
    mb = MechanismBuilder(gravity=(0, 0, -9.81))
    mb.ground("O", (0, 0, 0))
    mb.particle("A", (0.5, 0, 0))
    mb.particle("B", (1.0, 0, 0.2))
    mb.body("link1", RigidInertia.slender_rod(1.0, (0, 0, 0), (0.5, 0, 0)), ["O", "A"])
    mb.body("link2", RigidInertia.slender_rod(0.7, (0.5, 0, 0), (1.0, 0, 0.2)), ["A", "B"])
    mb.spring_damper("spring", "O", "B", 20.0, 0.5, 0.8)
    mech, x0 = mb.build()
    return mech, jnp.asarray(x0)


@pytest.fixture(scope="module")
def two_link(tmp_path_factory):
    from particlesim.io import load_urdf

    p = tmp_path_factory.mktemp("urdf") / "two_link.urdf"
    p.write_text(TWO_LINK_URDF)
    return load_urdf(p, gravity=(0.0, -9.81, 0.0))


def _tree_dynamics(model, q, qd, tau):
    from particlesim.tree import forward_dynamics

    return forward_dynamics(model, q, qd, tau)


class _PD(eqx.Module):
    """A control with parameters of its own: its arrays are traced, so new gains reuse the compiled rollout."""

    kp: jax.Array
    kd: jax.Array

    def __call__(self, t, q, qd, params):
        return -self.kp * q - self.kd * qd


def test_mechanism_rollout_compiles_once(pendulum):
    mech, x0 = pendulum
    xd0 = jnp.zeros_like(x0)
    before = _ode.TRACES["simulate_mechanism"]
    first = simulate_mechanism(mech, x0, xd0, 0.0, 0.2, solver="tsit5", rtol=1e-8, saveat_ts=np.linspace(0, 0.2, 5))
    assert _ode.TRACES["simulate_mechanism"] == before + 1
    changed = mech.with_params(spring={"spring": {"stiffness": 35.0, "damping": 0.9}},
                               body={"link2": {"mass": 0.9}}, gravity=(0.0, 0.0, -9.7))
    second = simulate_mechanism(changed, x0, xd0.at[4].set(0.3), 0.1, 0.4, solver="tsit5", rtol=1e-6, atol=1e-9,
                                saveat_ts=np.linspace(0.1, 0.4, 5))
    assert _ode.TRACES["simulate_mechanism"] == before + 1  # new parameters, state, times, tolerances: no retrace
    assert not np.allclose(first.q[-1], second.q[-1])  # and the new values did take effect
    simulate_mechanism(mech, x0, xd0, 0.0, 0.2, solver="dopri5")  # new settings: one new compile
    assert _ode.TRACES["simulate_mechanism"] == before + 2


def test_controller_coefficients_are_a_setting_of_both_entry_points(pendulum):
    """``pid`` reaches diffrax's controller (the step counts change) and is part of the compile key, and both
    controllers integrate the same motion to their tolerance."""
    mech, x0 = pendulum
    xd0 = jnp.zeros_like(x0)
    before = _ode.TRACES["simulate_mechanism"]
    kw = dict(solver="bosh3", rtol=1e-8, atol=1e-10)
    a = simulate_mechanism(mech, x0, xd0, 0.0, 1.0, **kw)
    b = simulate_mechanism(mech, x0, xd0, 0.0, 1.0, pid=(0.2, 0.4, 0.0), **kw)
    assert _ode.TRACES["simulate_mechanism"] == before + 2
    assert (int(a.steps), int(a.rejected)) != (int(b.steps), int(b.rejected))
    assert np.max(np.abs(np.asarray(a.q[-1] - b.q[-1]))) <= 1e-6  # both at rtol 1e-8 over 1 s


def test_tree_rollout_compiles_once(two_link):
    q0, qd0 = jnp.array([0.3, -0.2]), jnp.zeros(2)
    before = _ode.TRACES["simulate"]
    a = simulate(_tree_dynamics, two_link, q0, qd0, 0.0, 0.2, control=_PD(jnp.asarray(2.0), jnp.asarray(0.1)))
    b = simulate(_tree_dynamics, two_link.with_params(inertia=two_link.inertia * 1.1), q0 * 0.5, qd0, 0.0, 0.3,
                 control=_PD(jnp.asarray(5.0), jnp.asarray(0.3)), rtol=1e-6)
    assert _ode.TRACES["simulate"] == before + 1
    assert not np.allclose(a.q[-1], b.q[-1])


#: Our entries' compiler options choose how XLA emits the code, not what it computes. One state: float64 round-off,
#: relative to the result's scale. A rollout: the same up to its adaptive steps, which round-off may accept or reject
#: differently, so to the solver's tolerance (rtol = atol = 1e-10 below; measured 1.1e-11 on the two-link tree).
OPTIONS_RTOL = 1e-13
OPTIONS_ROLLOUT_TOL = 1e-9


def test_entries_compile_with_their_options_and_agree_with_xla_defaults(pendulum, two_link):
    """A top-level call of an entry is compiled with ``particlesim.compiler_options()`` (this XLA knows them: the probe
    kept them; the batch of tree states adds the batch options), a call inside a trace is inlined, and either gives
    what the same function gives inlined into a user's jit compiled with XLA's default emitters; the returned dict is
    a copy."""
    import particlesim
    from particlesim._xla import BATCH_OPTIONS, COMPILE_OPTIONS, top_level
    from particlesim.mechanism import accelerations
    from particlesim.mechanism import integrate as mechanism_integrate
    from particlesim.tree import dynamics as tree_dynamics
    from particlesim.tree import forward_dynamics

    if jax.default_backend() != "cpu":
        pytest.skip("the options are XLA:CPU's")
    options = particlesim.compiler_options()
    assert options == COMPILE_OPTIONS
    options.clear()
    assert particlesim.compiler_options() == COMPILE_OPTIONS
    # Top level is told apart from every kind of trace (JAX refuses compiler options on a nested jit).
    assert top_level()
    seen = []
    probe = lambda x: (seen.append(top_level()), x)[1]  # noqa: E731
    jax.jit(probe)(1.0), jax.vmap(probe)(jnp.ones(2)), jax.grad(probe)(1.0), jax.checkpoint(probe)(1.0)
    jax.lax.scan(lambda c, x: (probe(c), None), 0.0, jnp.ones(2))
    assert seen == [False] * 5
    # The entries used here compile their top-level programs with the options.
    mech, x0 = pendulum
    simulate_mechanism(mech, x0, jnp.zeros_like(x0), 0.0, 0.01)
    forward_dynamics(two_link, jnp.zeros((3, 2)), jnp.zeros((3, 2)), jnp.zeros((3, 2)))  # a batch of three states
    forward_dynamics(two_link, jnp.zeros(2), jnp.zeros(2), jnp.zeros(2))
    assert mechanism_integrate._simulate.jit.top_options == COMPILE_OPTIONS
    assert tree_dynamics._one_state.jit.top_options == COMPILE_OPTIONS
    assert tree_dynamics._batched.jit.top_options == {**COMPILE_OPTIONS, **BATCH_OPTIONS}
    defaults = {key: not value for key, value in COMPILE_OPTIONS.items()}  # the fusion emitters, XLA's default
    xd0 = jnp.zeros_like(x0).at[4].set(0.5)
    q0, qd0, tau = jnp.array([0.3, -0.2]), jnp.array([0.5, 1.0]), jnp.array([0.1, -0.4])
    kw = dict(solver="dopri8", rtol=1e-10, atol=1e-10, saveat_ts=np.linspace(0.0, 0.5, 6))
    for run, tol in ((lambda: forward_dynamics(two_link, q0, qd0, tau), OPTIONS_RTOL),
                     (lambda: accelerations(mech, 0.0, x0, xd0), OPTIONS_RTOL),
                     (lambda: simulate_mechanism(mech, x0, xd0, 0.0, 0.5, **kw).q, OPTIONS_ROLLOUT_TOL),
                     (lambda: simulate(_tree_dynamics, two_link, q0, qd0, 0.0, 0.5, **kw).q, OPTIONS_ROLLOUT_TOL)):
        ours, default = run(), jax.jit(run, compiler_options=defaults)()
        np.testing.assert_allclose(ours, default, rtol=0, atol=tol * float(jnp.max(jnp.abs(default))))


def test_one_state_tree_functions_are_compiled_entries(tmp_path):
    """An eager call of a one-state tree function is one compiled entry per model structure and static setting: the
    first call traces it once, new parameter values and states reuse it (trace counter), its values equal the same
    function traced inside an outer jit, and plain Python or NumPy inputs are converted, not traced as pytrees of
    scalars."""
    from particlesim.io import load_urdf
    from particlesim.tree import forward_dynamics, inverse_dynamics, link_jacobian, mass_matrix

    path = tmp_path / "two_link.urdf"
    path.write_text(TWO_LINK_URDF)
    # a structure no other test uses (rotor inertia and viscous friction present): its first call must trace
    model = load_urdf(path, gravity=(0.0, -9.81, 0.0), rotor_inertia=[0.01, 0.02], viscous=[0.1, 0.3])
    q, qd, tau = np.array([0.3, -0.2]), np.array([0.5, 1.0]), np.array([0.1, -0.4])
    heavier = model.with_params(inertia=model.inertia * 1.3, gravity=jnp.array([0.0, -9.7, 0.1]))
    for name, call in (("forward_dynamics", lambda m, s: forward_dynamics(m, q + s, qd, tau)),
                       ("mass_matrix", lambda m, s: mass_matrix(m, list(q + s))),
                       ("inverse_dynamics", lambda m, s: inverse_dynamics(m, q + s, qd, tau)),
                       ("link_jacobian", lambda m, s: link_jacobian(m, q + s, "b", frame="local"))):
        before = _ode.TRACES[name]
        first = call(model, 0.0)
        assert _ode.TRACES[name] == before + 1, name
        second = call(heavier, 0.1)
        call(model, -0.7)
        assert _ode.TRACES[name] == before + 1, name  # new parameters and states: no retrace
        assert not np.allclose(first, second), name
        inside = jax.jit(lambda m: call(m, 0.1))(heavier)  # the same function traced inside a user's jit
        np.testing.assert_allclose(second, inside, rtol=1e-13, atol=1e-15)
    before = _ode.TRACES["link_jacobian"]
    link_jacobian(model, q, "b", frame="world")  # a new static setting: one new compile
    assert _ode.TRACES["link_jacobian"] == before + 1
    with pytest.raises(ModelError, match=r"q must have shape \(2,\)"):
        mass_matrix(model, np.zeros(3))


def test_mechanism_parameters_by_name(pendulum):
    mech, _ = pendulum
    m = mech.with_params(spring={"spring": {"free_length": 0.9}}, body={"link1": {"com": (0.25, 0.0, 0.01)}})
    assert float(m.spring_free_length[0]) == 0.9 and float(mech.spring_free_length[0]) == 0.8
    np.testing.assert_array_equal(m.body_com[0], [0.25, 0.0, 0.01])
    with pytest.raises(KeyError, match="no spring named 'nope'"):
        mech.with_params(spring={"nope": {"stiffness": 1.0}})
    with pytest.raises(KeyError, match="body 'link1' has no parameter 'colour'"):
        mech.with_params(body={"link1": {"colour": 1.0}})


@pytest.mark.parametrize("kwargs,match", [
    ({"rtol": -1e-6}, "rtol must be positive"),
    ({"atol": -1.0}, "atol must be non-negative"),
    ({"t1": -0.1}, "t1 must be greater than t0"),
    ({"max_steps": 0}, "max_steps must be a positive integer"),
    ({"dt0": 0.0}, "dt0 must be positive"),
    ({"saveat_ts": [0.0, 0.3]}, "saveat_ts must be non-decreasing times inside"),
    ({"solver": "rk45"}, "unknown solver 'rk45'"),
    ({"pid": (0.2, 0.4)}, "pid must be three finite numbers"),
])
def test_bad_settings_are_refused_alike(pendulum, two_link, kwargs, match):
    mech, x0 = pendulum
    kw = {"t1": 0.2, **kwargs}
    t1 = kw.pop("t1")
    with pytest.raises(ValueError, match=match):
        simulate_mechanism(mech, x0, jnp.zeros_like(x0), 0.0, t1, **kw)
    with pytest.raises(ValueError, match=match):
        simulate(_tree_dynamics, two_link, jnp.zeros(2), jnp.zeros(2), 0.0, t1, **kw)


def test_non_finite_parameters_raise_model_error_in_both(pendulum, two_link):
    mech, x0 = pendulum
    nan_damping = eqx.tree_at(lambda m: m.spring_damping, mech, jnp.full_like(mech.spring_damping, jnp.nan))
    with pytest.raises(ModelError, match="simulate_mechanism: parameter spring 'spring' damping is not finite"):
        simulate_mechanism(nan_damping, x0, jnp.zeros_like(x0), 0.0, 0.1)
    with pytest.raises(ModelError, match=r"simulate: parameter inertia of link 'a' is not finite"):
        simulate(_tree_dynamics, two_link.with_params(inertia=two_link.inertia * jnp.nan), jnp.zeros(2), jnp.zeros(2),
                 0.0, 0.1)


def test_eager_parameter_check_is_remembered_only_for_immutable_models(pendulum):
    """The eager finite check remembers a model that passed (by identity, jax-array leaves only): a NaN set in place
    in a NumPy leaf of a model that passed before is still refused before dispatch, and a new model with a NaN
    too."""
    mech, x0 = pendulum
    xd0 = jnp.zeros_like(x0)
    simulate_mechanism(mech, x0, xd0, 0.0, 0.05)
    assert _ode._PASSED[id(mech)][0]() is mech  # remembered: jax arrays only
    damping = np.asarray(mech.spring_damping, dtype=np.float64).copy()
    mutable = eqx.tree_at(lambda m: m.spring_damping, mech, damping)
    simulate_mechanism(mutable, x0, xd0, 0.0, 0.05)
    assert id(mutable) not in _ode._PASSED
    damping[0] = np.nan
    with pytest.raises(ModelError, match="simulate_mechanism: parameter spring 'spring' damping is not finite"):
        simulate_mechanism(mutable, x0, xd0, 0.0, 0.05)
    new_nan = eqx.tree_at(lambda m: m.spring_damping, mech, jnp.full_like(mech.spring_damping, jnp.nan))
    with pytest.raises(ModelError, match="simulate_mechanism: parameter spring 'spring' damping is not finite"):
        simulate_mechanism(new_nan, x0, xd0, 0.0, 0.05)  # (with_params refuses a concrete NaN itself)


class _Gains(eqx.Module):
    table: dict  # a mutable container of jax arrays: the same object can hold new leaves


def _gained(params, q, qd, tau):
    return -params.table["w"] ** 2 * q + tau


class _Checked(eqx.Module):
    w: jax.Array

    @staticmethod
    def check_configuration(q):  # a static method: called as the instance hands it out
        if not np.all(np.abs(np.asarray(q)) < 10.0):
            raise ModelError("configuration out of range")


def test_eager_parameter_check_sees_leaves_replaced_in_place():
    """A model remembered as checked is checked again when a container inside it now holds other leaves."""
    params = _Gains({"w": jnp.array(2.0)})
    q0, qd0 = jnp.array([1.0, 0.0]), jnp.array([0.0, 0.5])
    simulate(_gained, params, q0, qd0, 0.0, 0.1)
    params.table["w"] = jnp.array(jnp.nan)
    with pytest.raises(ModelError, match=r"simulate: parameter \.table\['w'\] is not finite"):
        simulate(_gained, params, q0, qd0, 0.0, 0.1)


def test_configuration_check_given_as_a_static_method_is_called():
    params = _Checked(jnp.array(2.0))
    dyn = lambda p, q, qd, tau: -p.w ** 2 * q + tau  # noqa: E731
    simulate(dyn, params, jnp.array([1.0, 0.0]), jnp.zeros(2), 0.0, 0.1)
    with pytest.raises(ModelError, match="configuration out of range"):
        simulate(dyn, params, jnp.array([11.0, 0.0]), jnp.zeros(2), 0.0, 0.1)


def test_settings_are_remembered_by_typed_value():
    a = _ode.settings(solver="tsit5", max_steps=10, throw=True, progress=False, pid=None, save_ts=False)
    assert _ode.settings(solver="tsit5", max_steps=10, throw=True, progress=False, pid=None, save_ts=False) is a
    one = _ode.settings(solver="tsit5", max_steps=1, throw=True, progress=False, pid=None, save_ts=False)
    assert one.max_steps == 1
    with pytest.raises(ValueError, match="max_steps must be a positive integer"):  # True == 1, but not a step count
        _ode.settings(solver="tsit5", max_steps=True, throw=True, progress=False, pid=None, save_ts=False)
    listed = _ode.settings(solver="tsit5", max_steps=10, throw=True, progress=False, pid=[0.2, 0.4, 0.0],
                           save_ts=False)  # unhashable: built, not remembered
    assert listed.pid == (0.2, 0.4, 0.0)
    own = diffrax.RecursiveCheckpointAdjoint()
    b = _ode.settings(solver="tsit5", adjoint=own, max_steps=10, throw=True, progress=False, pid=None, save_ts=False)
    assert b.adjoint is own and b.adjoint_key == _ode._ByIdentity(own)


def test_traced_bad_times_raise_at_run_time(pendulum):
    mech, x0 = pendulum
    f = jax.jit(lambda t1: simulate_mechanism(mech, x0, jnp.zeros_like(x0), 0.0, t1).q)
    assert np.all(np.isfinite(np.asarray(f(jnp.asarray(0.05)))))
    with pytest.raises(Exception, match="t1 <= t0"):
        jax.block_until_ready(f(jnp.asarray(-0.05)))
