"""Mimic joints (URDF ``<mimic>``) reduced to their sources, against Pinocchio's ``mimic=True`` and the Lagrangian."""

import xml.etree.ElementTree as ET

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from particlesim.errors import ModelError, ParseError
from particlesim.tree import TreeModel, forward_dynamics, friction_torques, kinetic_energy, mass_matrix
from particlesim.io import load_urdf
from tree_helpers import PinocchioOracle, batched_terms, max_rel, random_tree_urdf, states

#: Both sides are float64 implementations of the same reduced rigid-body model.
PIN_RTOL = 1e-10
#: Hessian of the kinetic energy (autodiff) against the composite-inertia mass matrix.
LAGRANGE_RTOL = 1e-12
GRAVITY = (0.2, -9.81, 0.4)
N_STATES = 50


def with_mimics(urdf: str, mimics: dict, *, damping: dict | None = None) -> str:
    """``urdf`` with ``<mimic joint= multiplier= offset=>`` added to the joints named in ``mimics`` (continuous
    joints made revolute: Pinocchio pairs a mimic only with a joint of the same configuration size)."""
    root = ET.fromstring(urdf)
    for el in root.findall("joint"):
        name = el.get("name")
        if el.get("type") == "continuous":
            el.set("type", "revolute")
        if name in mimics:
            src, mult, off = mimics[name]
            ET.SubElement(el, "mimic", joint=src, multiplier=repr(mult), offset=repr(off))
        if damping and name in damping:
            ET.SubElement(el, "dynamics", damping=repr(damping[name][0]), friction=repr(damping[name][1]))
    return ET.tostring(root, encoding="unicode")


# seed, links, {mimic joint: (source, multiplier, offset)}: revolute and prismatic sources and followers, a
# negative multiplier, two followers of one source (Pinocchio needs the source earlier in the file)
CASES = [
    (0, 5, {"j3": ("j1", -0.7, 0.25)}),
    (1, 6, {"j4": ("j2", 1.3, -0.1), "j5": ("j2", 0.5, 0.0)}),
    (2, 4, {"j1": ("j0", 2.0, 0.3)}),
]


@pytest.mark.parametrize("seed,n,mimics", CASES)
def test_mimic_trees_against_pinocchio(seed, n, mimics):
    urdf = with_mimics(random_tree_urdf(seed, n=n, prismatic=0.4), mimics)
    model = load_urdf(urdf, gravity=GRAVITY, limits="ignore")
    assert (model.n_joints, model.nq) == (n, n - len(mimics))
    assert set(model.coordinate_names) == {f"j{i}" for i in range(n)} - set(mimics)
    oracle = PinocchioOracle(urdf, model.coordinate_names, GRAVITY, mimic=True)
    q, qd, tau, qdd = states(np.random.default_rng(seed), N_STATES, model.nq, model.nq)
    out = batched_terms(model, model.link_names)(q, qd, tau, qdd)  # followers' links included
    for s in range(N_STATES):
        m_ref, b_ref = oracle.mass_matrix(q[s]), oracle.bias(q[s], qd[s])
        assert max_rel(out["m"][s], m_ref) <= PIN_RTOL
        assert max_rel(out["bias"][s], b_ref) <= PIN_RTOL
        assert max_rel(out["grav"][s], oracle.gravity(q[s])) <= PIN_RTOL
        assert max_rel(out["fd"][s], np.linalg.solve(m_ref, tau[s] - b_ref)) <= PIN_RTOL
        assert max_rel(out["id"][s], m_ref @ qdd[s] + b_ref) <= PIN_RTOL
        for link in model.link_names:
            for frame, local in (("world", False), ("local", True)):
                ref = oracle.jacobian(q[s], link, local)
                assert max_rel(out["jac"][(link, frame)][s], ref) <= PIN_RTOL, (link, frame)
    # the Lagrangian route: A is the Hessian of the kinetic energy in the reduced velocities
    hess = jax.hessian(lambda v: kinetic_energy(model, jnp.asarray(q[0]), v))(jnp.asarray(qd[0]))
    assert max_rel(hess, out["m"][0]) <= LAGRANGE_RTOL * 1e2


def test_mimic_chain_composes_and_mimic_false_keeps_joints():
    base = random_tree_urdf(3, n=5, prismatic=0.3)
    # a follower of a follower, and a source later in the file than its follower
    chain = load_urdf(with_mimics(base, {"j4": ("j2", -0.5, 0.1), "j2": ("j1", 1.5, 0.2)}), limits="ignore")
    # j4 = -0.5 (1.5 j1 + 0.2) + 0.1 = -0.75 j1 + 0.0
    direct = load_urdf(with_mimics(base, {"j4": ("j1", -0.75, 0.0), "j2": ("j1", 1.5, 0.2)}), limits="ignore")
    assert chain.mimic == direct.mimic
    full = load_urdf(with_mimics(base, {"j4": ("j2", -0.5, 0.1)}), mimic=False, limits="ignore")
    assert full.nq == full.n_joints == 5
    # reduction by hand: A_red = G^T A_full(G q + o) G with the full model's joint-space matrix
    q = np.array([0.4, -0.3, 0.9])
    g, off = direct.coordinate_map
    a_full = np.asarray(mass_matrix(full, g @ q + off))
    assert max_rel(mass_matrix(chain, q), g.T @ a_full @ g) <= LAGRANGE_RTOL


def test_mimic_friction_is_folded_into_the_source_exactly():
    base = random_tree_urdf(4, n=3, prismatic=0.0)
    urdf = with_mimics(base, {"j2": ("j0", -2.0, 0.0)}, damping={"j0": (0.3, 0.1), "j1": (0.2, 0.0),
                                                                 "j2": (0.5, 0.4)})
    model = load_urdf(urdf, limits="ignore")
    # G^T diag(Fv) G qd and G^T Fc sign(G qd): j0 carries 0.3 + 4 * 0.5 and 0.1 + 2 * 0.4
    np.testing.assert_allclose(model.viscous, [0.3 + 4 * 0.5, 0.2], rtol=1e-15)
    np.testing.assert_allclose(model.coulomb, [0.1 + 2 * 0.4, 0.0], rtol=1e-15)
    qd = np.array([0.7, -0.2])
    direct = 0.3 * 0.7 + 0.1 + (-2.0) * (0.5 * (-2.0 * 0.7) + 0.4 * np.sign(-2.0 * 0.7))
    np.testing.assert_allclose(friction_torques(model, qd)[0], direct, rtol=1e-14)


def test_mimic_errors_name_the_joint():
    base = random_tree_urdf(5, n=3, prismatic=0.0)
    with pytest.raises(ParseError, match="'j2' mimics 'nope'"):
        load_urdf(with_mimics(base, {"j2": ("nope", 1.0, 0.0)}), limits="ignore")
    with pytest.raises(ParseError, match="cycle"):
        load_urdf(with_mimics(base, {"j2": ("j1", 1.0, 0.0), "j1": ("j2", 1.0, 0.0)}), limits="ignore")
    with pytest.raises(ParseError, match="'j1' mimics itself"):
        load_urdf(with_mimics(base, {"j1": ("j1", 1.0, 0.0)}), limits="ignore")
    model = load_urdf(with_mimics(base, {"j2": ("j0", 1.0, 0.0)}), limits="ignore")
    with pytest.raises(ModelError, match=r"shape \(2,\)"):
        forward_dynamics(model, np.zeros(3), np.zeros(3), np.zeros(3))
    kw = dict(parents=[-1, 0], kinds=["revolute"] * 2, axes=np.eye(3)[:2], origin_rotations=np.stack([np.eye(3)] * 2),
              origin_xyz=np.zeros((2, 3)), inertia=np.tile([1.0, 0, 0, 0, 1, 0, 0, 1, 0, 1], (2, 1)))
    with pytest.raises(ModelError, match="'b' follows itself"):
        TreeModel(**kw, joint_names=["a", "b"], mimic={"b": ("b", 1.0, 0.0)})
    with pytest.raises(ModelError, match="multiplier and offset must be finite"):
        TreeModel(**kw, joint_names=["a", "b"], mimic={"b": ("a", float("nan"), 0.0)})
    with pytest.raises(ModelError, match="viscous friction must have shape \\(1,\\)"):
        TreeModel(**kw, joint_names=["a", "b"], mimic={"b": ("a", 1.0, 0.0)}, viscous=[0.1, 0.2])
