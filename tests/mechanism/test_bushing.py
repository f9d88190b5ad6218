"""Bushings (``mb.bushing``): a box held by one bushing against the ground, its axes fixed in the ground or turning
with the box, against the box's Newton-Euler equations written out here (rotation matrix, world-frame Euler
equation, the bushing's force and torque in closed form) and integrated by SciPy; energy held without damping; a
joint's reaction next to a bushing against the body's balance; gradients (reverse, forward) against central
differences; bad input refused by name."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from rollout_helpers import assert_derivative_matches_central_difference
from scipy.integrate import solve_ivp

from particlesim.errors import ModelError
from particlesim.inertia import RigidInertia
from particlesim.mechanism import (MechanismBuilder, accelerations, joint_reaction, project, simulate_mechanism,
                                   total_energy)
from particlesim.spatial import rotation_log

M, G = 3.0, 9.81
I_PRINCIPAL = np.array([0.05, 0.08, 0.11])
COM = np.array([0.02, -0.03, 0.05])  # world, at assembly: off the bushing point
AT = np.array([0.1, 0.05, -0.04])
K, C = np.array([2.0e4, 3.0e4, 5.0e4]), np.array([20.0, 30.0, 40.0])
KR, CR = np.array([300.0, 400.0, 500.0]), np.array([0.3, 0.2, 0.1])
V0, W0 = np.array([0.1, -0.2, 0.15]), np.array([1.0, -2.0, 1.5])  # the box's start twist (centre of mass)
T_END = 0.4
TS = np.linspace(0.0, T_END, 9)
RTOL, ATOL = 1e-11, 1e-13  # our rollouts
REF_TOL = 1e-8  # centre of mass [m] and rotation against SciPy
ENERGY_RTOL = 1e-8  # undamped: total energy over the run, relative to its kinetic part at the start
GRAD_RTOL = 1e-6  # reverse and forward derivatives against central differences


def _axes():
    """The bushing's axes (rows), a rotation away from the world's."""
    a = np.asarray(jax.scipy.linalg.expm(jnp.asarray(np.cross(np.eye(3), [0.3, -0.5, 0.7]))))
    return a.T


ROT0 = np.asarray(jax.scipy.linalg.expm(jnp.asarray(np.cross(np.eye(3), [-0.2, 0.4, 0.1]))))  # the box's axes


def box(frame):
    """The box on its bushing (``frame``: the axes fixed in the ground, None, or turning with the box)."""
    mb = MechanismBuilder(gravity=(0.0, 0.0, -G))
    corners = np.array([[0.12, 0, 0], [-0.06, 0.1, 0], [-0.06, -0.1, 0.03], [0.0, 0.0, 0.12]])
    names = [mb.particle(f"p{i}", COM + ROT0 @ c) for i, c in enumerate(corners)]
    inertia = RigidInertia(M, COM, ROT0 @ np.diag(I_PRINCIPAL) @ ROT0.T, name="box")
    mb.body("box", inertia, names, on_negative="ignore")
    mb.bushing("mount", None, "box", at=AT, stiffness=K, damping=C, rotational_stiffness=KR, rotational_damping=CR,
               frame=frame, axes=_axes())
    mech, q0 = mb.build(dof=6)
    r0 = np.asarray(q0).reshape(-1, 3)
    qd0 = (V0 + np.cross(W0, r0 - COM)).reshape(-1)
    q0, qd0 = project(mech, jnp.asarray(q0), jnp.asarray(qd0))
    return mech, q0, qd0


def _jl_inv(phi):
    """Inverse left Jacobian of the rotation vector: ``d phi = Jl^-1 d theta`` for a world-frame turn ``d theta``."""
    th = np.linalg.norm(phi)
    px = np.array([[0, -phi[2], phi[1]], [phi[2], 0, -phi[0]], [-phi[1], phi[0], 0]])
    if th < 1e-8:
        return np.eye(3) - 0.5 * px + px @ px / 12.0
    return np.eye(3) - 0.5 * px + (1 / th**2 - (1 + np.cos(th)) / (2 * th * np.sin(th))) * px @ px


def reference(frame, damping=True):
    """The box's Newton-Euler equations with the bushing's force and torque in closed form; SciPy DOP853."""
    a0 = _axes().T  # columns: the bushing's axes in the world at assembly
    c, cr = (C, CR) if damping else (np.zeros(3), np.zeros(3))
    lever0 = AT - COM  # the box's bushing point from its centre of mass, at assembly

    def rhs(t, y):
        x, rot, v, w = y[:3], y[3:12].reshape(3, 3), y[12:15], y[15:18]
        rel = rot @ ROT0.T  # the box's rotation since assembly
        lever = rel @ lever0
        p, p_dot = x + lever, v + np.cross(w, lever)
        axes = a0 if frame is None else rel @ a0
        d = axes.T @ (p - AT)
        if frame is None:
            d_dot = axes.T @ p_dot
        else:  # the axes turn with the box: d = a0^T rel^T (p - AT)
            d_dot = axes.T @ (p_dot - np.cross(w, p - AT))
        tau_t = K * d + c * d_dot
        force = -axes @ tau_t
        torque = np.cross(lever, force)
        if frame is not None:  # the turning axes: as if the force acted at the ground point
            torque = np.cross(AT - x, force)
        phi = np.asarray(rotation_log(jnp.asarray(rel)))  # the box's rotation vector since assembly (world)
        jinv = _jl_inv(phi)
        # in the bushing's axes: a0^T phi whichever frame carries them (rel turns about phi, so rel^T phi = phi)
        tau_r = KR * (a0.T @ phi) + cr * (a0.T @ jinv @ w)
        torque = torque - jinv.T @ (a0 @ tau_r)
        inertia = rel @ ROT0 @ np.diag(I_PRINCIPAL) @ ROT0.T @ rel.T
        w_dot = np.linalg.solve(inertia, torque - np.cross(w, inertia @ w))
        v_dot = force / M + np.array([0.0, 0.0, -G])
        rot_dot = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]]) @ rot
        return np.concatenate([v, rot_dot.reshape(-1), v_dot, w_dot])

    y0 = np.concatenate([COM, ROT0.reshape(-1), V0, W0])
    sol = solve_ivp(rhs, (0.0, T_END), y0, method="DOP853", rtol=1e-13, atol=1e-15, t_eval=TS)
    return sol.y[:3].T, sol.y[3:12].T.reshape(-1, 3, 3)


def _poses(mech, qs):
    from particlesim.mechanism import body_poses

    rot, org = jax.vmap(lambda q: body_poses(mech, q))(qs)
    com = jnp.einsum("tij,j->ti", rot[:, 0], mech.body_com[0]) + org[:, 0]
    return np.asarray(com), np.asarray(rot[:, 0])


@pytest.fixture(scope="module", params=[None, "box"], ids=["axes in the ground", "axes turning with the box"])
def case(request):
    frame = request.param
    mech, q0, qd0 = box(frame)
    sol = simulate_mechanism(mech, q0, qd0, 0.0, T_END, rtol=RTOL, atol=ATOL, saveat_ts=TS)
    return frame, mech, q0, qd0, sol


def test_the_box_moves_as_its_newton_euler_equations(case):
    frame, mech, _, _, sol = case
    assert bool(sol.ok)
    com, rot = _poses(mech, sol.q)
    com_ref, rot_ref = reference(frame)
    assert np.abs(com - com_ref).max() <= REF_TOL
    assert np.abs(rot @ ROT0 - rot_ref).max() <= REF_TOL  # the body frame is the world's at assembly
    assert np.abs(com - com_ref[0]).max() > 1e-3  # it moved


def test_without_damping_the_energy_is_held(case):
    frame, mech, q0, qd0, _ = case
    free = mech.with_params(bushing={"mount": {"damping": np.zeros(6)}})
    sol = simulate_mechanism(free, q0, qd0, 0.0, T_END, rtol=RTOL, atol=ATOL, saveat_ts=TS)
    e = np.asarray(jax.vmap(lambda q, v: total_energy(free, q, v))(sol.q, sol.qd))
    kinetic = 0.5 * M * V0 @ V0 + 0.5 * W0 @ ROT0 @ np.diag(I_PRINCIPAL) @ ROT0.T @ W0
    assert np.abs(e - e[0]).max() <= ENERGY_RTOL * kinetic
    if frame is None:  # and the motion is the reference's without damping
        com_ref, _ = reference(frame, damping=False)
        assert np.abs(_poses(free, sol.q)[0] - com_ref).max() <= REF_TOL


def test_a_joint_reaction_beside_a_bushing_balances_the_body():
    """A box on a ball joint to the ground and a bushing: the joint's force is the box's mass times its centre's
    acceleration less gravity and the bushing's force (in closed form here)."""
    mb = MechanismBuilder(gravity=(0.0, 0.0, -G))
    pts = [mb.ground("O", (0.0, 0.0, 0.0))] + [mb.particle(f"p{i}", p) for i, p in
                                                 enumerate([(0.3, 0, 0), (0.1, 0.2, 0), (0.1, 0.0, 0.25)])]
    mb.body("box", RigidInertia(M, (0.12, 0.05, 0.06), np.diag(I_PRINCIPAL), name="box"), pts, on_negative="ignore")
    mb.bushing("mount", None, "box", at=(0.2, 0.1, 0.1), stiffness=K, damping=C, axes=_axes())
    mech, q0 = mb.build(dof=3)
    q0 = jnp.asarray(q0)
    w = np.array([0.5, -1.0, 2.0])
    qd0 = jnp.asarray(np.cross(w, np.asarray(q0).reshape(-1, 3)).reshape(-1))
    q = q0 + 0.05 * qd0  # a state off the assembly (first order on the sphere; projected)
    q, qd = project(mech, q, qd0)
    qdd = accelerations(mech, 0.0, q, qd)
    from particlesim.mechanism import body_poses

    (rot, org), (rot_d, org_d) = jax.jvp(lambda y: body_poses(mech, y), (q,), (qd,))
    acc = jax.jvp(lambda y, v: jax.jvp(lambda z: body_poses(mech, z), (y,), (v,))[1], (q, qd), (qd, qdd))[1]
    a_com = np.asarray(acc[0][0] @ mech.body_com[0] + acc[1][0])
    at = np.array([0.2, 0.1, 0.1])  # the body frame is the world's at assembly: the bushing's point in it
    p = np.asarray(rot[0] @ at + org[0])
    p_dot = np.asarray(rot_d[0] @ at + org_d[0])
    a = _axes().T
    force = -a @ (K * (a.T @ (p - at)) + C * (a.T @ p_dot))
    f_joint, _ = joint_reaction(mech, 0.0, q, qd, "box", "O")
    expected = M * a_com - M * np.array([0.0, 0.0, -G]) - force
    assert np.abs(np.asarray(f_joint) - expected).max() <= 1e-9 * np.abs(expected).max()


def test_gradients_in_the_bushing_match_central_differences():
    mech, q0, qd0 = box(None)  # axes in the ground: one frame suffices for the derivative check
    i = mech.free_slice("p3")

    def end(ky, adjoint=None):
        m = mech.with_params(bushing={"mount": {"stiffness": mech.bushing_stiffness[0].at[1].set(ky)}})
        sol = simulate_mechanism(m, q0, qd0, 0.0, T_END, rtol=1e-12, atol=1e-14, adjoint=adjoint)
        return sol.q[-1, i.start + 1]

    k0 = float(K[1])
    assert_derivative_matches_central_difference(end, k0, GRAD_RTOL, least=1e-10)


def test_bad_bushings_are_refused_by_name():
    def builder():
        mb = MechanismBuilder()
        mb.ground("O", (0, 0, 0))
        mb.particle("a", (1, 0, 0))
        mb.particle("b", (0, 1, 0))
        mb.particle("c", (0, 0, 1))
        mb.body("box", RigidInertia(1.0, (0.2, 0.2, 0.2), 0.01 * np.eye(3)), ["O", "a", "b", "c"],
                on_negative="ignore")
        mb.particle("e", (2, 0, 0))
        mb.rod("rod", "a", "e", 1.0)
        return mb

    cases = [(dict(stiffness=(1.0, -2.0, 3.0)), "bushing 'x': stiffness must be a finite and non-negative"),
             (dict(stiffness=(1.0, 2.0)), "bushing 'x': stiffness must be 3 numbers"),
             (dict(stiffness=1.0, damping=float("nan")), "bushing 'x': damping must be a finite"),
             (dict(stiffness=1.0, axes=np.diag([1.0, 1.0, 2.0])), "bushing 'x': axes must be orthonormal"),
             (dict(stiffness=1.0, axes=np.diag([1.0, 1.0, -1.0])), "right-handed"),
             (dict(stiffness=lambda t: 1.0), "bushing 'x': stiffness must be")]
    for kw, msg in cases:
        with pytest.raises(ModelError, match=msg):
            builder().bushing("x", None, "box", at=(0.5, 0, 0), **kw)
    with pytest.raises(ModelError, match="bushing 'x': joins body 'box' to itself"):
        builder().bushing("x", "box", "box", at=(0.5, 0, 0), stiffness=1.0)
    mb = builder()
    mb.bushing("x", None, "rod", at=(1.5, 0, 0), stiffness=1.0, rotational_stiffness=1.0)
    with pytest.raises(ModelError, match="bushing 'x': body 'rod' is a rod"):
        mb.build()
    mb = builder()
    mb.bushing("x", None, "crate", at=(1.5, 0, 0), stiffness=1.0)
    with pytest.raises(ModelError, match="bushing 'x': unknown body 'crate'"):
        mb.build()
    mb = builder()
    mb.bushing("x", None, "box", at=(0.5, 0, 0), stiffness=1.0)
    with pytest.raises(ModelError, match="bushing 'x' is defined twice"):
        mb.bushing("x", None, "box", at=(0.5, 0, 0), stiffness=1.0)
    mech, _ = mb.build()
    with pytest.raises(ModelError, match="bushing 'x' stiffness must be finite and non-negative"):
        mech.with_params(bushing={"x": {"stiffness": -np.ones(6)}})
    with pytest.raises(ModelError, match=r"bushing 'x' stiffness must have shape \(6,\)"):
        mech.with_params(bushing={"x": {"stiffness": np.ones(3)}})
