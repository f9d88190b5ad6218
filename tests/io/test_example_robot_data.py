"""Public robots (the example-robot-data package, 69 URDFs): how many load and why the others are refused, and
every tree quantity against Pinocchio on fixed-base, mimic and floating-base robots from it."""

import warnings
from importlib import metadata
from pathlib import Path

import jax
import numpy as np
import pytest

from particlesim.errors import InertiaError, ParseError
from particlesim.tree import kinetic_energy
from particlesim.io import load_urdf
from tree_helpers import batched_terms, max_rel, states

#: Float64 implementations of the same rigid-body model.
PIN_RTOL = 1e-10
N_STATES = 50
GRAVITY = (0.0, 0.0, -9.81)
#: Loading policies tried in order: the default, then the named ones (MuJoCo's balanceinertia; mimic tags kept
#: as independent joints, for a file whose mimic names a joint it does not have).
POLICIES = ({}, {"inertia": "balance"}, {"inertia": "balance", "mimic": False})
MIN_LOADED = 66


def _robots() -> dict:
    files = [f for f in metadata.files("example-robot-data") or () if str(f).endswith(".urdf")]
    return {str(f).split("robots/", 1)[1]: Path(f.locate()) for f in files}


ROBOTS = _robots()


def _load(path, **policy):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # unmodelled limits, repaired inertias: named in warnings, checked elsewhere
        return load_urdf(path, gravity=GRAVITY, limits="ignore", **policy)


def test_public_urdfs_load_or_are_refused_by_name():
    assert len(ROBOTS) == 69
    loaded, refused = {}, {}
    for name, path in sorted(ROBOTS.items()):
        for policy in POLICIES:
            try:
                _load(path, **policy)
            except (InertiaError, ParseError) as e:
                refused[name] = str(e)
                continue
            loaded[name] = policy
            refused.pop(name, None)
            break
    print(f"\n  loaded {len(loaded)} of {len(ROBOTS)}: default {sum(not p for p in loaded.values())}, "
          f"named policy: {', '.join(f'{n} {p}' for n, p in loaded.items() if p)}")
    for name, msg in refused.items():
        print(f"  refused {name}: {msg.split('robots/')[-1]}")
        assert str(ROBOTS[name]) in msg  # the file,
        assert "joint '" in msg or "link '" in msg or "no <link>" in msg  # and the element at fault
    assert len(loaded) >= MIN_LOADED


class Oracle:
    """Pinocchio on the same file (free-flyer root and mimic reduction as asked), in our coordinate order."""

    def __init__(self, path, model, *, floating: bool, mimic: bool):
        import pinocchio as pin

        self.pin = pin
        if floating:
            self.m = pin.buildModelFromUrdf(str(path), pin.JointModelFreeFlyer(), mimic=mimic)
        else:
            self.m = pin.buildModelFromUrdf(str(path), mimic=mimic)
        self.m.gravity.linear = np.asarray(GRAVITY, dtype=float)
        self.mimic = mimic
        self.d = self.m.createData()
        assert self.m.nv == model.nv
        self.joints = [self.m.joints[self.m.getJointId(n)] for n in model.coordinate_names]
        self.iv = np.concatenate([np.arange(j.idx_v, j.idx_v + j.nv) for j in self.joints])

    def q(self, q):
        """Our coordinates to Pinocchio's (a continuous joint has (cos, sin) there; the free flyer is the same)."""
        out, k = np.zeros(self.m.nq), 0
        for j in self.joints:
            if j.nq == 2 and j.nv == 1:
                out[j.idx_q:j.idx_q + 2] = np.cos(q[k]), np.sin(q[k])
                k += 1
            else:
                out[j.idx_q:j.idx_q + j.nq] = q[k:k + j.nq]
                k += j.nq
        return out

    def v(self, v):
        out = np.zeros(self.m.nv)
        out[self.iv] = v
        return out

    def data(self):
        # Pinocchio 4.1's crba with mimic joints depends on what an earlier call left in its Data
        return self.m.createData() if self.mimic else self.d

    def terms(self, q, qd, tau, qdd, links):
        pin, m = self.pin, self.m
        qp, vp = self.q(q), self.v(qd)
        a = pin.crba(m, self.data(), qp)
        out = dict(m=(np.triu(a) + np.triu(a, 1).T)[np.ix_(self.iv, self.iv)],
                   bias=pin.nonLinearEffects(m, self.d, qp, vp)[self.iv],
                   grav=pin.computeGeneralizedGravity(m, self.d, qp)[self.iv],
                   id=pin.rnea(m, self.d, qp, vp, self.v(qdd))[self.iv])
        out["energy"] = 0.5 * qd @ out["m"] @ qd  # (Pinocchio's computeKineticEnergy refuses mimic joints)
        out["fd"] = np.linalg.solve(out["m"], tau - out["bias"])
        pin.computeJointJacobians(m, self.d, qp)
        pin.updateFramePlacements(m, self.d)
        for link in links:
            for frame, ref in (("world", pin.LOCAL_WORLD_ALIGNED), ("local", pin.LOCAL)):
                out[(link, frame)] = pin.getFrameJacobian(m, self.d, m.getFrameId(link), ref)[:, self.iv]
        return out


# file, floating base, mimic reduction, frames whose Jacobians are compared (fixed-joint frames included)
CASES = [
    ("ur_description/urdf/ur5_robot.urdf", False, False, ("tool0", "wrist_3_link")),
    ("z1_description/urdf/z1.urdf", False, False, ("gripperMover", "link06")),
    ("so_arm_description/urdf/so101.urdf", False, False, ("gripper_link",)),
    ("kinova_description/robots/kinova.urdf", False, False, ("j2s6s200_end_effector", "j2s6s200_link_finger_tip_1",)),
    ("panda_description/urdf/panda.urdf", False, True, ("panda_hand", "panda_rightfinger")),
    ("talos_data/robots/talos_left_arm.urdf", False, True, ("gripper_left_fingertip_1_link",)),
    ("solo_description/robots/solo12.urdf", True, False, ("FL_FOOT", "base_link")),
    ("a1_description/urdf/a1.urdf", True, False, ("FR_foot", "trunk")),
    ("talos_data/robots/talos_reduced.urdf", True, True, ("left_sole_link", "gripper_left_fingertip_1_link")),
]


@pytest.mark.slow
@pytest.mark.parametrize("name,floating,mimic,links", CASES, ids=[c[0].split("/")[-1] for c in CASES])
def test_public_robot_against_pinocchio(name, floating, mimic, links):
    path = ROBOTS[name]
    nv = _load(path, floating_base=floating, mimic=mimic).nv
    # without the file's joint damping and friction (Pinocchio's dynamics have none; they are checked elsewhere)
    model = _load(path, floating_base=floating, mimic=mimic, viscous=np.zeros(nv), coulomb=np.zeros(nv))
    oracle = Oracle(path, model, floating=floating, mimic=mimic)
    quats = (3,) if floating else ()
    q, qd, tau, qdd = states(np.random.default_rng(0), N_STATES, model.nq, model.nv, quaternions=quats)
    out = batched_terms(model, links)(q, qd, tau, qdd)
    energy = np.asarray(jax.jit(jax.vmap(lambda a, b: kinetic_energy(model, a, b)))(q, qd))
    worst = {}
    for s in range(N_STATES):
        ref = oracle.terms(q[s], qd[s], tau[s], qdd[s], links)
        for key in ("m", "bias", "grav", "fd", "id"):
            worst[key] = max(worst.get(key, 0.0), max_rel(out[key][s], ref[key]))
        for link in links:
            for frame in ("world", "local"):
                worst["jacobians"] = max(worst.get("jacobians", 0.0),
                                         max_rel(out["jac"][(link, frame)][s], ref[(link, frame)]))
        worst["energy"] = max(worst.get("energy", 0.0), abs(energy[s] - ref["energy"]) / ref["energy"])
    print(f"\n  {name} (nq {model.nq}, nv {model.nv}): " + ", ".join(f"{k} {v:.1e}" for k, v in worst.items()))
    assert all(v <= PIN_RTOL for v in worst.values()), worst
