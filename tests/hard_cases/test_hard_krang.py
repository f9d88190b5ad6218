"""Krang hard cases: both arms stretched (singular arm Jacobians), a 100 s horizon, a fast wrist spin.

Expectations: at the stretched pose the mass matrix stays SPD and well conditioned, the forward dynamics equal
Pinocchio's ABA, each arm Jacobian has exactly the rank loss the geometry predicts and wrench torques stay finite;
rollouts (no friction, no input) keep the total energy to the stated drift bounds and contain no NaN.
"""

import xml.etree.ElementTree as ET

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from particlesim.scenes.krang import krang_2018_pitch_urdf
from particlesim.simulate import simulate
from particlesim.tree import (
    forward_dynamics,
    kinetic_energy,
    link_jacobian,
    mass_matrix,
    potential_energy,
    wrench_torques,
)
from particlesim.io import load_urdf

KRANG_GRAVITY = (0.0, -9.81, 0.0)
#: Forward dynamics against Pinocchio's ABA at the singular pose (both float64 rigid-body algorithms).
ABA_RTOL = 1e-10
#: Singular values of a 6 x 6 arm Jacobian at most this (times the largest) count as zero.
RANK_RTOL = 1e-12
#: The mass matrix stays well conditioned at the stretched pose (the arm Jacobian's singularity is kinematic).
MASS_COND_MAX = 1e6
KRANG_RTOL, KRANG_ATOL = 1e-12, 1e-12  # dopri8
#: Relative drift of the total energy (scale: kinetic + |potential| at t = 0) over 1 s through the pose.
ENERGY_DRIFT_1S = 1e-10
#: Same over 100 s.
ENERGY_DRIFT_100S = 1e-9
#: A wrist spinning at 100 rad/s, 1 s.
ENERGY_DRIFT_SPIN = 1e-10
KRANG_MAX_STEPS = 400_000


@pytest.fixture(scope="module")
def krang_exact_urdf():
    """Krang (2018, base pitch joint) with its rpy angles snapped to exact multiples of pi/2, so that q = 0 puts
    both arms exactly straight."""
    return krang_2018_pitch_urdf(exact_angles=True)


@pytest.fixture(scope="module")
def krang(krang_exact_urdf):
    return load_urdf(krang_exact_urdf, gravity=KRANG_GRAVITY)


def _arm(model, side):
    names = list(model.joint_names)
    return [names.index(f"{side}J{i}") for i in range(1, 7)]


def _pinocchio(urdf_text, joint_names):
    import pinocchio as pin

    root = ET.fromstring(urdf_text)
    for joint in root.iter("joint"):  # Pinocchio's parser wants limits on revolute joints (JBase has none)
        if joint.get("type") == "revolute" and joint.find("limit") is None:
            joint.append(ET.fromstring('<limit effort="1" lower="-4" upper="4" velocity="1"/>'))
    model = pin.buildModelFromXML(ET.tostring(root, encoding="unicode"))
    model.gravity.linear = np.asarray(KRANG_GRAVITY)
    idx = np.array([model.joints[model.getJointId(n)].idx_v for n in joint_names])
    assert model.nq == model.nv == len(joint_names)  # revolute joints only: q maps one to one
    return pin, model, model.createData(), idx


def _energy(model, q, qd):
    return float(kinetic_energy(model, q, qd) + potential_energy(model, q))


@pytest.fixture(scope="module")
def krang_run(krang):
    """``(q0, qd0, t1) -> Solution`` (11 saves), Dopri8, compiled once for every Krang rollout of this module."""
    return jax.jit(lambda q0, qd0, t1: simulate(
        forward_dynamics, krang, q0, qd0, 0.0, t1, solver="dopri8", rtol=KRANG_RTOL, atol=KRANG_ATOL,
        saveat_ts=jnp.linspace(0.0, t1, 11), max_steps=KRANG_MAX_STEPS))


def _drift(model, sol):
    e = np.array([_energy(model, q, qd) for q, qd in zip(sol.q, sol.qd)])
    scale = float(kinetic_energy(model, sol.q[0], sol.qd[0])) + abs(float(potential_energy(model, sol.q[0])))
    return np.abs(e - e[0]).max() / scale


def test_stretched_arm_dynamics_match_pinocchio(krang, krang_exact_urdf):
    q = np.zeros(krang.nq)  # both arms straight
    qd = np.random.default_rng(5).normal(size=krang.nq)
    tau = np.random.default_rng(6).normal(size=krang.nq)
    # The singularity: in each straight arm, joints 1, 3, 5 turn about the arm's own line, which carries the gripper
    # origin (three equal Jacobian columns, rank 1), and joints 2, 4, 6 about parallel axes (rank 2): the 6 x 6
    # arm Jacobian (gripper, world axes) has rank 3.
    for side, link in (("L", "lGripper"), ("R", "rGripper")):
        sv = np.linalg.svd(np.asarray(link_jacobian(krang, q, link))[:, _arm(krang, side)], compute_uv=False)
        print(f"\n{link}: arm Jacobian singular values {np.array2string(sv, precision=3)}")
        assert np.sum(sv <= RANK_RTOL * sv[0]) == 3 and sv[2] >= 0.1 * sv[0]
    a = np.asarray(mass_matrix(krang, q))
    eig = np.linalg.eigvalsh(a)
    print(f"mass matrix eigenvalues [{eig[0]:.3e}, {eig[-1]:.3e}], condition {eig[-1] / eig[0]:.3e}")
    assert np.all(np.isfinite(a)) and eig[0] > 0 and eig[-1] / eig[0] < MASS_COND_MAX
    pin, pmodel, pdata, idx = _pinocchio(krang_exact_urdf, krang.joint_names)
    qp, vp, tp = np.zeros(pmodel.nq), np.zeros(pmodel.nv), np.zeros(pmodel.nv)
    qp[idx], vp[idx], tp[idx] = q, qd, tau
    ref = pin.aba(pmodel, pdata, qp, vp, tp)[idx]
    ours = np.asarray(forward_dynamics(krang, q, qd, tau))
    rel = np.abs(ours - ref).max() / np.abs(ref).max()
    print(f"forward dynamics vs Pinocchio ABA at the stretched pose: {rel:.2e} relative")
    assert np.all(np.isfinite(ours)) and rel <= ABA_RTOL
    # A wrench at the gripper maps to finite joint torques J^T f (Pinocchio's frame Jacobian as reference).
    f = np.array([3.0, -2.0, 1.0, 0.5, 0.2, -0.4])
    pin.computeJointJacobians(pmodel, pdata, qp)
    pin.updateFramePlacements(pmodel, pdata)
    jac = pin.getFrameJacobian(pmodel, pdata, pmodel.getFrameId("lGripper"), pin.LOCAL_WORLD_ALIGNED)[:, idx]
    wt = np.asarray(wrench_torques(krang, q, "lGripper", f))
    assert np.all(np.isfinite(wt))
    np.testing.assert_allclose(wt, jac.T @ f, rtol=0, atol=ABA_RTOL * np.abs(jac.T @ f).max())


def test_stretched_arm_rollout_keeps_energy(krang, krang_run):
    # Start 0.2 rad before the straight pose, moving towards it at 1 rad/s: the arms pass through it near t = 0.2 s.
    qd0 = np.zeros(krang.nq)
    for side in ("L", "R"):
        qd0[_arm(krang, side)] = [0.0, 1.0, 0.0, 1.0, 0.0, 1.0]
    sol = krang_run(jnp.asarray(-0.2 * qd0), jnp.asarray(qd0), 1.0)
    drift = _drift(krang, sol)
    print(f"\n1 s through the stretched pose: {int(sol.steps)} steps, energy drift {drift:.2e}")
    assert bool(sol.ok) and np.all(np.isfinite(sol.q)) and drift <= ENERGY_DRIFT_1S


def test_krang_100_s_horizon_keeps_energy(krang, krang_run):
    # Hanging (base pitched by pi) with every joint displaced by up to 0.5 rad: 100 s of swinging arms and torso.
    q0 = np.random.default_rng(3).uniform(-0.5, 0.5, krang.nq)
    q0[list(krang.joint_names).index("JBase")] += np.pi
    sol = krang_run(jnp.asarray(q0), jnp.zeros(krang.nq), 100.0)
    drift = _drift(krang, sol)
    print(f"\n100 s: {int(sol.steps)} steps, energy drift {drift:.2e}, max |qd| {np.abs(sol.qd).max():.3g} rad/s")
    assert bool(sol.ok) and np.all(np.isfinite(sol.q)) and drift <= ENERGY_DRIFT_100S


def test_krang_fast_wrist_spin_keeps_energy(krang, krang_run):
    # LJ6 (the last wrist joint) at 100 rad/s, the rest at rest, 1 s (16 turns) under gravity.
    qd0 = np.zeros(krang.nq)
    qd0[list(krang.joint_names).index("LJ6")] = 100.0
    q0 = np.random.default_rng(4).uniform(-0.5, 0.5, krang.nq)
    sol = krang_run(jnp.asarray(q0), jnp.asarray(qd0), 1.0)
    drift = _drift(krang, sol)
    print(f"\nwrist spin 100 rad/s: {int(sol.steps)} steps, energy drift {drift:.2e}")
    assert bool(sol.ok) and np.all(np.isfinite(sol.q)) and drift <= ENERGY_DRIFT_SPIN
