"""Bad input is refused with a message naming the link/joint and the violated condition."""

import numpy as np
import pytest

from particlesim.errors import InertiaError, ModelError, ParseError
from particlesim.tree import TreeModel, load_urdf

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


def test_missing_inertial_on_moving_link():
    text = _urdf(GOOD).replace(f'<link name="b">{INERTIAL}</link>', '<link name="b"/>')
    with pytest.raises(ParseError, match="link 'b' is moved by joint 'j2' but has no <inertial>"):
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
