"""Bad input is refused with a message naming the link/joint and the violated condition."""

import numpy as np
import pytest

from particlesim.errors import InertiaError, ModelError, ParseError
from particlesim.tree import TreeModel
from particlesim.io import load_urdf

INERTIAL = ('<inertial><mass value="1"/><origin xyz="0 0 0.1"/>'
            '<inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial>')


def _urdf(joints, links=("a", "b"), inertial=INERTIAL):
    body = "".join(f'<link name="{n}">{inertial if n != "base" else ""}</link>' for n in ("base",) + tuple(links))
    return f'<robot name="r">{body}{joints}</robot>'


def _joint(name, kind, parent, child):
    return (f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
            f'<axis xyz="0 0 1"/></joint>')


GOOD = _joint("j1", "revolute", "base", "a") + _joint("j2", "prismatic", "a", "b")


def test_good_urdf_loads():
    m = load_urdf(_urdf(GOOD))
    assert m.joint_names == ("j1", "j2") and m.kinds == ("revolute", "prismatic")


@pytest.mark.parametrize("kind", ["floating", "planar", "ball"])
def test_unsupported_joint_type(kind):
    with pytest.raises(ParseError, match=f"joint 'j2' has unsupported type '{kind}'"):
        load_urdf(_urdf(_joint("j1", "revolute", "base", "a") + _joint("j2", kind, "a", "b")))


def test_kinematic_loop_two_parents():
    joints = GOOD + _joint("j3", "revolute", "base", "b")
    with pytest.raises(ParseError, match="link 'b' has two parents .*'j2' and 'j3'.*loops"):
        load_urdf(_urdf(joints))


def test_kinematic_loop_without_root():
    joints = _joint("j1", "revolute", "a", "b") + _joint("j2", "revolute", "b", "a")
    with pytest.raises(ParseError, match="links \\['a', 'b'\\] are not connected to the root"):
        load_urdf(_urdf(joints))


def test_joint_moving_no_mass():
    text = _urdf(GOOD).replace(f'<link name="b">{INERTIAL}</link>', '<link name="b"/>')
    with pytest.raises(InertiaError, match="joint 'j2' moves no mass .*link 'b'.*singular"):
        load_urdf(text)


def test_non_physical_inertia():
    bad = INERTIAL.replace('izz="0.01"', 'izz="0.05"')  # 0.05 > 0.01 + 0.01: triangle inequality
    with pytest.raises(InertiaError, match="link 'a'.*triangle inequality"):
        load_urdf(_urdf(GOOD, inertial=bad))
    negative = INERTIAL.replace('<mass value="1"/>', '<mass value="-1"/>')
    with pytest.raises(InertiaError, match="link 'a': mass must be positive"):
        load_urdf(_urdf(GOOD, inertial=negative))


def test_unparsable_file(tmp_path):
    p = tmp_path / "broken.urdf"
    p.write_text("<robot><link name='a'></robot>")
    with pytest.raises(ParseError, match="broken.urdf: not well-formed XML"):
        load_urdf(p)
    with pytest.raises(ParseError, match="cannot read URDF file"):
        load_urdf(tmp_path / "missing.urdf")
    with pytest.raises(ParseError, match="joint 'j1' origin xyz: cannot read numbers"):
        load_urdf(_urdf(GOOD.replace('<axis xyz="0 0 1"/>', '<origin xyz="0 zero 0"/><axis xyz="0 0 1"/>', 1)))
    with pytest.raises(ParseError, match="joint 'j1' refers to undefined link 'nowhere'"):
        load_urdf(_urdf(GOOD.replace('parent link="base"', 'parent link="nowhere"')))


def _tree_kwargs(**over):
    kw = dict(parents=[-1, 0], kinds=["revolute", "prismatic"], axes=np.eye(3)[:2],
              origin_rotations=np.stack([np.eye(3)] * 2), origin_xyz=np.zeros((2, 3)),
              inertia=np.array([[1.0, 0, 0, 0.1, 0.02, 0, 0, 0.02, 0, 0.01]] * 2),
              link_names=["upper", "lower"], joint_names=["shoulder", "slide"])
    kw.update(over)
    return kw


def test_tree_model_refuses_bad_input():
    TreeModel(**_tree_kwargs())
    with pytest.raises(ModelError, match="joint 'slide': unknown joint kind 'helical'"):
        TreeModel(**_tree_kwargs(kinds=["revolute", "helical"]))
    with pytest.raises(ModelError, match="inertia must have shape \\(2, 10\\)"):
        TreeModel(**_tree_kwargs(inertia=np.zeros((2, 9))))
    with pytest.raises(ModelError, match="joint 'slide': origin_xyz is NaN"):
        TreeModel(**_tree_kwargs(origin_xyz=np.array([[0, 0, 0], [np.nan, 0, 0]])))
    bad = np.array([[1.0, 0, 0, 0.1, 0.02, 0, 0, 0.02, 0, 0.01], [np.nan] * 10])
    with pytest.raises(InertiaError, match="link 'lower': inertial parameters contain NaN"):
        TreeModel(**_tree_kwargs(inertia=bad))
    bad = np.array([[1.0, 0, 0, 0.1, 0.02, 0, 0, 0.02, 0, 0.01], [1.0, 0, 0, 0, 0.01, 0, 0, 0.01, 0, 0.05]])
    with pytest.raises(InertiaError, match="link 'lower'.*triangle inequality"):
        TreeModel(**_tree_kwargs(inertia=bad))
    with pytest.raises(ModelError, match="joint 'shoulder': axis .* is not a unit vector"):
        TreeModel(**_tree_kwargs(axes=np.array([[0.0, 0, 0], [1, 0, 0]])))
    with pytest.raises(ModelError, match="joints \\['shoulder', 'slide'\\] form a kinematic loop"):
        TreeModel(**_tree_kwargs(parents=[1, 0]))
    with pytest.raises(ModelError, match="viscous friction of joint 'slide' is NaN"):
        TreeModel(**_tree_kwargs(viscous=[0.1, np.nan]))
    with pytest.raises(ModelError, match="unknown link 'elbow'"):
        TreeModel(**_tree_kwargs()).link_index("elbow")


def test_user_errors_name_the_argument_or_element():
    import jax.numpy as jnp

    from particlesim.simulate import simulate
    from particlesim.tree import forward_dynamics, inverse_dynamics

    m = load_urdf(_urdf(GOOD))
    z = jnp.zeros(2)
    with pytest.raises(ModelError, match="viscous friction of joint 'j1' is negative"):
        load_urdf(_urdf(GOOD), viscous=[-1.0, 0.0])
    with pytest.raises(ModelError, match="Coulomb friction of joint 'j2' is negative"):
        load_urdf(_urdf(GOOD), coulomb=[0.0, -0.1])
    with pytest.raises(ParseError, match="joint 'j1' is defined twice"):
        load_urdf(_urdf(_joint("j1", "revolute", "base", "a") + _joint("j1", "revolute", "a", "b")))
    with pytest.raises(ModelError, match="joint name 'j' is used twice"):
        TreeModel(**_tree_kwargs(joint_names=["j", "j"]))
    with pytest.raises(ParseError, match="the robot has no <link>"):
        load_urdf('<robot name="empty"></robot>')
    with pytest.raises(ParseError, match="empty URDF source"):
        load_urdf("  ")
    with pytest.raises(ModelError, match="q must have shape \\(2,\\)"):
        forward_dynamics(m, jnp.zeros(3), z, z)
    with pytest.raises(ModelError, match="tau must have shape \\(2,\\)"):
        forward_dynamics(m, z, z, jnp.zeros(1))
    with pytest.raises(ModelError, match="qdd must have shape \\(2,\\)"):
        inverse_dynamics(m, z, z, jnp.zeros(4))
    for bad in (lambda t, q, qd, p: jnp.asarray(1.0), lambda t, q, qd, p: jnp.ones(1)):
        with pytest.raises(ModelError, match="control returned shape .*no broadcasting"):
            simulate(forward_dynamics, m, z, z, 0.0, 0.1, control=bad)
    with pytest.raises(RuntimeError, match="the control returned a non-finite generalised force"):
        simulate(forward_dynamics, m, z, z, 0.0, 0.1, control=lambda t, q, qd, p: q * jnp.nan)
    with pytest.raises(ValueError, match="rtol must be positive"):
        simulate(forward_dynamics, m, z, z, 0.0, 0.1, rtol=-1e-6)
    with pytest.raises(ValueError, match="t1 must be greater than t0"):
        simulate(forward_dynamics, m, z, z, 1.0, 0.0)
    with pytest.raises(ValueError, match="max_steps must be a positive integer"):
        simulate(forward_dynamics, m, z, z, 0.0, 0.1, max_steps=0)


def test_urdf_dynamics_fields_and_limits_against_pinocchio():
    """``<dynamics damping friction>`` become viscous and Coulomb friction, as Pinocchio reads them into
    ``model.damping`` and ``model.friction``; limits that are not modelled are said, not dropped silently."""
    import warnings

    pin = pytest.importorskip("pinocchio")
    from particlesim.io.urdf import UnmodelledLimitsWarning

    j1 = ('<joint name="j1" type="revolute"><parent link="base"/><child link="a"/><axis xyz="0 0 1"/>'
          '<limit lower="-1" upper="1" effort="5" velocity="2"/><dynamics damping="0.3" friction="0.2"/></joint>')
    j2 = ('<joint name="j2" type="revolute"><parent link="a"/><child link="b"/><axis xyz="1 0 0"/>'
          '<limit lower="-2" upper="2" effort="5" velocity="2"/><dynamics damping="0.05"/></joint>')
    text = _urdf(j1 + j2)
    with pytest.warns(UnmodelledLimitsWarning, match="2 joint\\(s\\) are not modelled.*'j1', 'j2'"):
        m = load_urdf(text)
    ref = pin.buildModelFromXML(text)
    np.testing.assert_array_equal(np.asarray(m.viscous), np.asarray(ref.damping))
    np.testing.assert_array_equal(np.asarray(m.coulomb), np.asarray(ref.friction))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        load_urdf(text, limits="ignore", viscous=[0.0, 0.0])  # silent when asked; arguments replace the file's
    with pytest.raises(ParseError, match="joint 'j1': dynamics damping and friction must be non-negative"):
        load_urdf(_urdf(j1.replace('damping="0.3"', 'damping="-0.3"') + j2), limits="ignore")


def test_links_merged_by_fixed_joints_keep_their_frames_as_pinocchio_does():
    """A tool frame on a fixed joint below a moving link and a frame welded to the world: their poses and
    Jacobians (world axes, velocity of the frame's origin) against Pinocchio's frames at random states."""
    import jax.numpy as jnp

    from particlesim.tree import frame_pose, link_jacobian

    pin = pytest.importorskip("pinocchio")
    tool = ('<link name="tool0"/><joint name="flange" type="fixed"><parent link="b"/><child link="tool0"/>'
            '<origin xyz="0.1 -0.2 0.3" rpy="0.3 -0.2 0.5"/></joint>'
            '<link name="mount"/><joint name="bolt" type="fixed"><parent link="base"/><child link="mount"/>'
            '<origin xyz="0 0 0.5" rpy="0 0 1"/></joint>')
    lim = '<limit lower="-3" upper="3" effort="1" velocity="1"/>'  # Pinocchio's parser requires limits
    j = ('<joint name="j1" type="revolute"><parent link="base"/><child link="a"/><axis xyz="0 0 1"/>' + lim +
         '</joint><joint name="j2" type="revolute"><parent link="a"/><child link="b"/><origin xyz="0 0.4 0.1"/>'
         '<axis xyz="1 0 0"/>' + lim + '</joint>')
    text = _urdf(j).replace("</robot>", tool + "</robot>")
    m = load_urdf(text, limits="ignore")
    ref = pin.buildModelFromXML(text)
    data = ref.createData()
    rng = np.random.default_rng(3)
    for _ in range(5):
        q = rng.uniform(-2, 2, 2)
        pin.computeJointJacobians(ref, data, q)
        pin.updateFramePlacements(ref, data)
        for name in ("tool0", "mount", "b"):
            fid = ref.getFrameId(name)
            r, p = frame_pose(m, jnp.asarray(q), name)
            np.testing.assert_allclose(np.asarray(r), data.oMf[fid].rotation, atol=1e-12)
            np.testing.assert_allclose(np.asarray(p), data.oMf[fid].translation, atol=1e-12)
            jac = pin.getFrameJacobian(ref, data, fid, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
            np.testing.assert_allclose(np.asarray(link_jacobian(m, jnp.asarray(q), name)), jac, atol=1e-12)
            jl = pin.getFrameJacobian(ref, data, fid, pin.ReferenceFrame.LOCAL)
            np.testing.assert_allclose(np.asarray(link_jacobian(m, jnp.asarray(q), name, frame="local")), jl,
                                       atol=1e-12)
    with pytest.raises(ModelError, match="unknown link 'tool9'.*frames \\['base', "):
        link_jacobian(m, jnp.zeros(2), "tool9")


def test_non_finite_parameters_refused_by_name_before_dispatch():
    """A NaN or inf put into a model after construction (``with_params``, ``eqx.tree_at``: unchecked) is refused by
    every tree entry, one state or a batch, naming the parameter and the link, instead of returning NaN. A model of
    NumPy arrays that passed once is checked again (changed in place here)."""
    import equinox as eqx
    import jax.numpy as jnp

    from particlesim.tree import forward_dynamics, link_jacobian, mass_matrix

    model = load_urdf(_urdf(GOOD))
    q = np.zeros(2)
    assert np.all(np.isfinite(np.asarray(forward_dynamics(model, q, q, q))))  # the intact model passes
    bad = model.with_params(inertia=model.inertia.at[1, 0].set(jnp.nan))
    calls = [lambda m: forward_dynamics(m, q, q, q), lambda m: forward_dynamics(m, np.zeros((3, 2)), q, q),
             lambda m: forward_dynamics(m, np.zeros((40, 2)), q, q), lambda m: mass_matrix(m, q),
             lambda m: link_jacobian(m, q, "b")]
    for call in calls:
        with pytest.raises(ModelError, match=r"inertia of link 'b' is not finite"):
            call(bad)
    far = model.with_params(origin_xyz=model.origin_xyz.at[0, 2].set(jnp.inf))
    with pytest.raises(ModelError, match=r"origin_xyz of link 'a' is not finite"):
        mass_matrix(far, q)
    held = eqx.tree_at(lambda m: m.viscous, model, np.zeros(2), is_leaf=lambda x: x is None)
    forward_dynamics(held, q, q, q)  # passes, and is not remembered (NumPy leaves are mutable)
    held.viscous[0] = np.nan
    with pytest.raises(ModelError, match=r"viscous is not finite"):
        forward_dynamics(held, q, q, q)


def test_non_physical_tree_values_refused_by_simulate():
    """``simulate`` refuses non-physical tree parameters that no constructor saw, naming the link or joint: concrete
    values replaced as whole arrays (``with_params(inertia=...)``, ``eqx.tree_at``) before the run, traced ones when
    the program runs (JAX's run-time error): a negative link mass, an inertia breaking the triangle inequality, a joint
    left moving no mass, a negative viscous friction, a soft limit with negative damping; NaN as not finite. A
    physical traced change runs and equals the same change made concretely; a model loaded with ``inertia="warn"``
    keeps its links unchecked."""
    import equinox as eqx
    import jax
    import jax.numpy as jnp

    from particlesim.simulate import simulate
    from particlesim.inertia import origin_params
    from particlesim.tree import forward_dynamics

    model = load_urdf(_urdf(GOOD), viscous=[0.1, 0.2], limits="ignore")
    q0 = jnp.asarray([0.3, 0.05])

    def final(m):
        return simulate(forward_dynamics, m, q0, jnp.zeros(2), 0.0, 0.05).q[-1]

    row = np.asarray(model.inertia[1])
    flat = np.asarray(origin_params(1.0, np.array([0.0, 0.0, 0.1]), np.diag([1.0, 1.0, 3.0])))  # 3 > 1 + 1
    cases = [("inertia", model.inertia.at[1, 0].set(-1.0), InertiaError, "link 'b'"),
             ("inertia", model.inertia.at[1].set(flat), InertiaError, "link 'b'"),
             ("inertia", model.inertia.at[1].set(0.0), InertiaError, "joint 'j2' moves no mass"),
             ("viscous", jnp.asarray([0.1, -0.2]), ModelError, "viscous friction of joint 'j2' is negative")]
    for field, value, error, match in cases:
        bypass = eqx.tree_at(lambda m: getattr(m, field), model, value)
        with pytest.raises(error, match="simulate: " + match):
            final(bypass)
        with pytest.raises(jax.errors.JaxRuntimeError, match="simulate: " + match):
            jax.block_until_ready(jax.jit(lambda v: final(model.with_params(**{field: v})))(value))
    with pytest.raises(jax.errors.JaxRuntimeError, match="parameter inertia of link 'a' is not finite"):
        jax.block_until_ready(jax.jit(lambda v: final(model.with_params(inertia=v)))(model.inertia.at[0, 4].set(
            jnp.nan)))
    limited = load_urdf(_urdf(GOOD), limits="model", limit_stiffness=100.0, limit_damping=1.0)
    bad_limits = limited.limits.at[0, 3].set(-1.0)
    with pytest.raises(ModelError, match="simulate: limits of 'j1'"):
        final(eqx.tree_at(lambda m: m.limits, limited, bad_limits))
    with pytest.raises(jax.errors.JaxRuntimeError, match="simulate: limits of 'j1'"):
        jax.block_until_ready(jax.jit(lambda v: final(limited.with_params(limits=v)))(bad_limits))
    heavier = model.inertia.at[1].set(2.0 * row)
    traced = jax.jit(lambda v: final(model.with_params(inertia=v)))(heavier)
    np.testing.assert_allclose(np.asarray(traced), np.asarray(final(model.with_params(inertia=heavier))), rtol=0.0,
                               atol=1e-12)
    bad_inertial = INERTIAL.replace('izz="0.01"', 'izz="0.05"')  # 0.05 > 0.01 + 0.01
    with pytest.warns(Warning):
        kept = load_urdf(_urdf(GOOD, inertial=bad_inertial), inertia="warn", limits="ignore")
    assert not kept.inertia_checked and np.all(np.isfinite(np.asarray(final(kept))))
    assert np.all(np.isfinite(np.asarray(jax.jit(lambda v: final(kept.with_params(inertia=v)))(kept.inertia))))


def test_run_time_link_test_agrees_with_the_constructors_check():
    """The links' run-time test (NumPy and traced) against the constructor's ``origin_params_check`` on rows about
    the link origin: rotated physical bodies, a rod, a massless (zero) row, a point-like link far from its joint
    (a 1.3 kg mass with a 1e-18 tensor 0.4 m away: physical only with the shift's rounding allowed), a broken
    triangle inequality, a negative moment, a negative mass, a mass with a zero tensor, and a NaN."""
    import jax
    import jax.numpy as jnp

    from particlesim.inertia import origin_params
    from particlesim.spatial import rpy_to_matrix
    from particlesim.tree.checks import _links_physical
    from particlesim.tree.model import origin_params_check

    rng = np.random.default_rng(5)
    rows = []
    for moments in ((1.0, 2.0, 2.5), (0.0, 1.0, 1.0), (1.0, 2.0, 3.0 + 1e-3), (-0.1, 1.0, 1.0), (0.3, 0.4, 0.5)):
        r = np.asarray(rpy_to_matrix(rng.uniform(-np.pi, np.pi, 3)))
        rows.append(np.asarray(origin_params(2.0, rng.normal(size=3), r @ np.diag(moments) @ r.T)))
    rows += [np.zeros(10), np.asarray(origin_params(1.3, np.array([0.0, 0.0, 0.4]), 1e-18 * np.eye(3))),
             np.asarray(origin_params(-1.0, np.zeros(3), np.eye(3))), np.r_[1.0, np.zeros(9)],
             np.r_[np.nan, np.zeros(9)]]
    expected = []
    for row in rows:
        try:
            origin_params_check(row, "link")
            expected.append(True)
        except InertiaError:
            expected.append(False)
    assert expected == [True, True, False, False, True, True, True, False, True, False]
    table = np.stack(rows)
    assert _links_physical(table).tolist() == expected
    assert np.asarray(jax.jit(_links_physical)(jnp.asarray(table))).tolist() == expected


def test_trees_inside_the_parameters_are_checked_too():
    """A tree inside a parameter pytree (here with a controller gain) gets the same checks as one passed alone:
    infinite soft-limit bounds of a continuous joint accepted, a negative link mass refused before the run and when
    traced (named with the tree's path), a NaN gain named by its path."""
    import equinox as eqx
    import jax
    import jax.numpy as jnp

    from particlesim.simulate import simulate
    from particlesim.tree import forward_dynamics

    urdf = _urdf(_joint("j1", "continuous", "base", "a") + _joint("j2", "revolute", "a", "b"))
    model = load_urdf(urdf, limits="model", limit_stiffness=100.0, limit_damping=1.0)
    assert np.isinf(np.asarray(model.limits)[0, :2]).all()

    def dynamics(p, q, qd, tau):
        return forward_dynamics(p["robot"], q, qd, tau)

    def control(t, q, qd, p):
        return -p["gain"] * qd

    def final(p):
        return simulate(dynamics, p, jnp.array([0.2, 0.1]), jnp.zeros(2), 0.0, 0.05, control=control).q[-1]

    ok = final({"robot": model, "gain": jnp.asarray(0.5)})
    assert np.all(np.isfinite(np.asarray(ok)))
    light = eqx.tree_at(lambda m: m.inertia, model, model.inertia.at[1, 0].set(-1.0))
    with pytest.raises(InertiaError, match=r"simulate \['robot'\]: link 'b'"):
        final({"robot": light, "gain": jnp.asarray(0.5)})
    with pytest.raises(jax.errors.JaxRuntimeError, match=r"simulate \['robot'\]: link 'b' is not physical"):
        jax.block_until_ready(jax.jit(lambda v: final({"robot": model.with_params(inertia=v),
                                                       "gain": jnp.asarray(0.5)}))(light.inertia))
    with pytest.raises(ModelError, match=r"parameter \['gain'\] is not finite"):
        final({"robot": model, "gain": jnp.asarray(jnp.nan)})
    with pytest.raises(ModelError, match=r"parameter \['robot'\]\.gravity is not finite"):
        final({"robot": model.with_params(gravity=jnp.array([0.0, jnp.nan, 0.0])), "gain": jnp.asarray(0.5)})
    with pytest.raises(ModelError, match=r"parameter \['robot'\] inertia of link 'a' is not finite"):
        final({"robot": model.with_params(inertia=model.inertia.at[0, 5].set(jnp.inf)), "gain": jnp.asarray(0.5)})
