"""M, bias forces and forward dynamics against the two peers a robotics user would pick, jaxsim and Drake, on Krang
(fixed base, 17 joints) and Solo-12 (floating base, 12 joints), each peer loading the same URDF itself.

Conventions mapped (ours: ``q = (x, y, z, qx, qy, qz, qw, joints)``, ``v = (v_B, w_B, joint rates)`` with the base's
linear and angular velocity in its own frame, as Pinocchio's free flyer):

* jaxsim with ``VelRepr.Body`` uses the same base velocity; its quaternion is ``(w, x, y, z)``; a generalized force on
  the base enters as the base link's wrench in its own frame (``link_forces``). Its joints are matched by name.
* Drake's quaternion floating joint has ``q = (qw, qx, qy, qz, x, y, z)`` and ``v = (w_W, v_W)`` in world axes:
  ``v_D = T v`` with ``T = [[0, R], [R, 0]]`` on the base, so ``M = Tᵀ M_D T``, ``bias = Tᵀ (C_D v_D − τ_g + M_D Ṫ v)``
  (``Ṫ v = (0, R (w_B × v_B))``) and ``qdd = T⁻¹ (v̇_D − Ṫ v)`` under ``τ_D = T⁻ᵀ τ``.

jaxsim reads URDF through sdformat's ``gz``/``ign sdf`` converter. Debian's sdformat 12 writes SDF 1.9 where its
parser (rod) asks for 1.10 by default; these files use nothing added in 1.10, so that version check is skipped.
Locally the module skips when a peer or the converter is missing; in CI (``CI`` set) it fails instead.
"""

import os
import shutil
import subprocess
import warnings
from importlib import metadata
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from particlesim.io import load_urdf
from particlesim.scenes.krang import urdf_path
from tree_helpers import batched_terms, max_rel, states

#: Float64 implementations of the same rigid-body model (the peers agree with each other to ~1e-14; ours sits
#: ~3e-13 from both on Krang's forward dynamics, cond(M) ~ 3e4).
PEER_RTOL = 1e-10
N_STATES = 20
GRAVITY = (0.0, 0.0, -9.81)


def _need(module: str):
    """Import a peer; skip without it locally, fail in CI (which installs every peer)."""
    if os.environ.get("CI"):
        return __import__(module)
    return pytest.importorskip(module)


def _solo12() -> Path:
    return next(Path(f.locate()) for f in metadata.files("example-robot-data") or ()
                if str(f).endswith("solo_description/robots/solo12.urdf"))


ROBOTS = {"krang": (lambda: urdf_path("krang_fixed_base_2018.urdf"), False),
          "solo12": (_solo12, True)}


@pytest.fixture(scope="module", params=sorted(ROBOTS))
def robot(request):
    """Our model, states and every quantity at them (one compiled, vmapped evaluation)."""
    path, floating = ROBOTS[request.param][0](), ROBOTS[request.param][1]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # Solo-12's unmodelled joint limits
        model = load_urdf(path, gravity=GRAVITY, floating_base=floating, limits="ignore")
    q, qd, tau, qdd = states(np.random.default_rng(7), N_STATES, model.nq, model.nv,
                             quaternions=(3,) if floating else ())
    out = {k: np.asarray(v) for k, v in batched_terms(model, ())(q, qd, tau, qdd).items() if k != "jac"}
    return dict(path=path, floating=floating, model=model, q=q, qd=qd, tau=tau, out=out)


def test_jaxsim_agrees(robot):
    if not os.environ.get("CI") and not any(shutil.which(x) and subprocess.run([x, "sdf", "--help"],
                                                                               capture_output=True).returncode == 0
                                            for x in ("gz", "ign")):
        pytest.skip("jaxsim reads URDF through sdformat's `gz sdf` / `ign sdf`: not available")
    os.environ.setdefault("ROD_SKIP_SDFORMAT_CHECK", "1")
    _need("jaxsim")
    import jax
    import jaxsim.api as js
    from jaxsim import VelRepr

    with jax.numpy_rank_promotion("allow"):  # jaxsim broadcasts implicitly; the suite raises on it (conftest)
        _jaxsim_states(js, VelRepr, robot)


def _jaxsim_states(js, VelRepr, robot):

    model, floating, out = robot["model"], robot["floating"], robot["out"]
    peer = js.model.JaxSimModel.build_from_model_description(model_description=robot["path"], gravity=9.81)
    assert peer.floating_base() == floating
    first = 1 if floating else 0  # our coordinate 0 is the free joint
    names = list(peer.joint_names())
    joints = np.array([names.index(n) for n in model.coordinate_names[first:]])
    base = 6 if floating else 0
    order = np.r_[np.arange(6), 6 + joints] if floating else 6 + joints  # peer rows in our order
    base_link = list(peer.link_names()).index(model.link_names[0])
    for s in range(N_STATES):
        q, qd, tau = robot["q"][s], robot["qd"][s], robot["tau"][s]
        sj, vj, tj = (np.zeros(peer.dofs()) for _ in range(3))
        sj[joints], vj[joints], tj[joints] = q[7 if floating else 0:], qd[base:], tau[base:]
        kw = dict(joint_positions=sj, joint_velocities=vj, velocity_representation=VelRepr.Body)
        if floating:
            kw.update(base_position=q[:3], base_quaternion=np.r_[q[6], q[3:6]], base_linear_velocity=qd[:3],
                      base_angular_velocity=qd[3:6])
        data = js.data.JaxSimModelData.build(model=peer, **kw)
        m = np.asarray(js.model.free_floating_mass_matrix(peer, data))[np.ix_(order, order)]
        bias = np.asarray(js.model.free_floating_bias_forces(peer, data))[order]
        wrench = np.zeros((peer.number_of_links(), 6))
        if floating:
            wrench[base_link] = tau[:6]
        a_base, a_joints = js.model.forward_dynamics_aba(peer, data, joint_forces=tj, link_forces=wrench)
        fd = np.r_[np.asarray(a_base), np.asarray(a_joints)[joints]] if floating else np.asarray(a_joints)[joints]
        assert max_rel(out["m"][s], m) <= PEER_RTOL, s
        assert max_rel(out["bias"][s], bias) <= PEER_RTOL, s
        assert max_rel(out["fd"][s], fd) <= PEER_RTOL, s


def test_drake_agrees(robot):
    _need("pydrake")
    from pydrake.multibody.parsing import Parser
    from pydrake.multibody.plant import MultibodyPlant

    model, floating, out = robot["model"], robot["floating"], robot["out"]
    plant = MultibodyPlant(0.0)
    Parser(plant).AddModelsFromString(robot["path"].read_text(), "urdf")  # no scene graph: meshes are not read
    plant.Finalize()
    plant.mutable_gravity_field().set_gravity_vector(GRAVITY)
    ctx = plant.CreateDefaultContext()
    nq, nv = plant.num_positions(), plant.num_velocities()
    assert nv == model.nv
    first = 1 if floating else 0
    joints = [plant.GetJointByName(n) for n in model.coordinate_names[first:]]
    iq = np.array([j.position_start() for j in joints])
    iv = np.array([j.velocity_start() for j in joints])
    base = 6 if floating else 0
    for s in range(N_STATES):
        q, qd, tau = robot["q"][s], robot["qd"][s], robot["tau"][s]
        q_d, t = np.zeros(nq), np.zeros((nv, model.nv))
        q_d[iq] = q[7 if floating else 0:]
        t[iv, base + np.arange(len(joints))] = 1.0
        tdot_v = np.zeros(nv)
        if floating:
            q_d[:4], q_d[4:7] = np.r_[q[6], q[3:6]], q[:3]
            r = Rotation.from_quat(q[3:7]).as_matrix()  # scipy's order is ours: (x, y, z, w)
            t[0:3, 3:6], t[3:6, 0:3] = r, r
            tdot_v[3:6] = r @ np.cross(qd[3:6], qd[0:3])
        plant.SetPositions(ctx, q_d)
        plant.SetVelocities(ctx, t @ qd)
        m_d = plant.CalcMassMatrix(ctx)
        bias = t.T @ (plant.CalcBiasTerm(ctx) - plant.CalcGravityGeneralizedForces(ctx) + m_d @ tdot_v)
        plant.get_applied_generalized_force_input_port().FixValue(ctx, np.linalg.solve(t.T, tau))
        fd = np.linalg.solve(t, plant.get_generalized_acceleration_output_port().Eval(ctx) - tdot_v)
        assert max_rel(out["m"][s], t.T @ m_d @ t) <= PEER_RTOL, s
        assert max_rel(out["bias"][s], bias) <= PEER_RTOL, s
        assert max_rel(out["fd"][s], fd) <= PEER_RTOL, s
