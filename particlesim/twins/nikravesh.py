"""MuJoCo C and MJX twins of Nikravesh's planar double A-arm (:mod:`particlesim.scenes.nikravesh`).

Same bodies and data (``shared/data/nikravesh_planar_aa/MODEL.md``), joints in MuJoCo's own terms, plane x-y,
gravity -y:

* tree: ground -> lower arm (hinge z at Q0) -> wheel assembly (hinge z at A); ground -> upper arm (hinge z at O0).
  Every body frame sits at its CoM, turned by its assembled angle phi0, so ``qpos = 0`` is the assembled state;
* the loop is closed by an equality ``connect`` (B3 on the upper arm = B2 on the wheel). It is soft in MuJoCo; it is
  stiffened as far as MuJoCo allows: ``solref`` time constant 2 dt (MuJoCo clamps it to >= 2 dt) and ``solimp``
  0.9999 (the cap). The planar inertias are ``ixx = iyy = izz = J`` (MuJoCo refuses ``ixx + iyy < izz``; only
  ``izz`` enters);
* the suspension spring-damper E1-F0 is a spatial tendon with stiffness, damping and spring length (the same law,
  evaluated by MuJoCo at every stage);
* the one-sided tyre is not a MuJoCo element. In MuJoCo C a passive-force callback (``mjcb_passive``) evaluates it
  at every RK4 stage; MJX has no callback, so :func:`mjx_rollout` runs its own RK4 loop around MJX's forward
  stages and writes ``qfrc_applied = J_y^T F`` from each stage's state. Either way the law is exact per stage (a
  force held over a step would be first order, docs/twins.md).

MJX 3.17 omits the ``J̇ v`` term of ``connect`` rows, so its loop residual, and with it its wheel height, is looser
than MuJoCo C's at the same step (measured in ``tests/twins/test_nikravesh_twin.py``).
"""

from __future__ import annotations

import mujoco
import numpy as np

from ..scenes import nikravesh as nk
from .callbacks import python_tyre

__all__ = ["twin_xml", "twin_rollout", "mjx_rollout", "solref_tc"]

_SOLIMP = "0.9999 0.9999 0.001 0.5 2"


def solref_tc(timestep: float) -> float:
    """The loop's ``solref`` time constant at ``timestep``: the smallest MuJoCo accepts (2 dt)."""
    return 2.0 * timestep


def _v(x) -> str:
    return " ".join(f"{float(c):.17g}" for c in x)


def _local(point: str) -> np.ndarray:
    """Body-frame coordinates of ``point`` (relative to its body's CoM)."""
    _, xi, eta = nk.POINTS[point]
    return np.array([xi, eta, 0.0])


def _pose(body: str) -> tuple[np.ndarray, float]:
    _, _, x0, y0, phi = nk.BODIES[body]
    return np.array([x0, y0, 0.0]), phi


def twin_xml(timestep: float = 1e-3, integrator: str = "RK4") -> str:
    """MJCF text of the twin (plane x-y, gravity -y, no contacts)."""

    def inertial(body):
        m, j = nk.BODIES[body][:2]
        return f'<inertial pos="0 0 0" mass="{m!r}" diaginertia="{j!r} {j!r} {j!r}"/>'

    r1, p1 = _pose("lower_arm")
    r2, p2 = _pose("wheel")
    r3, p3 = _pose("upper_arm")
    c1 = np.cos(-p1)
    s1 = np.sin(-p1)
    r2_in_1 = np.array([[c1, -s1, 0.0], [s1, c1, 0.0], [0.0, 0.0, 1.0]]) @ (r2 - r1)
    sol = f'solref="{solref_tc(timestep)!r} 1" solimp="{_SOLIMP}"'
    s = nk.SPRING
    return f"""
<mujoco model="nikravesh planar double A-arm twin">
  <compiler angle="radian" balanceinertia="false" inertiafromgeom="false"/>
  <option timestep="{timestep!r}" integrator="{integrator}" gravity="0 -9.81 0"><flag contact="disable"/></option>
  <worldbody>
    <site name="F0" pos="{_v(nk._global('F0'))}"/>
    <body name="lower_arm" pos="{_v(r1)}" euler="0 0 {p1!r}">
      <joint name="Q" type="hinge" axis="0 0 1" pos="{_v(_local('Q1'))}"/>
      {inertial('lower_arm')}
      <site name="E1" pos="{_v(_local('E1'))}"/>
      <body name="wheel" pos="{_v(r2_in_1)}" euler="0 0 {p2 - p1!r}">
        <joint name="A" type="hinge" axis="0 0 1" pos="{_v(_local('A2'))}"/>
        {inertial('wheel')}
        <site name="G2" pos="0 0 0"/>
      </body>
    </body>
    <body name="upper_arm" pos="{_v(r3)}" euler="0 0 {p3!r}">
      <joint name="O" type="hinge" axis="0 0 1" pos="{_v(_local('O3'))}"/>
      {inertial('upper_arm')}
    </body>
  </worldbody>
  <tendon>
    <spatial name="suspension" stiffness="{s['stiffness']!r}" damping="{s['damping']!r}"
             springlength="{s['free_length']!r}"><site site="E1"/><site site="F0"/></spatial>
  </tendon>
  <equality>
    <connect body1="upper_arm" body2="wheel" anchor="{_v(_local('B3'))}" {sol}/>
  </equality>
</mujoco>"""


def _loop_residual(m, d, b1: int, b2: int) -> float:
    p1 = d.xpos[b1] + d.xmat[b1].reshape(3, 3) @ m.eq_data[0, 0:3]
    p2 = d.xpos[b2] + d.xmat[b2].reshape(3, 3) @ m.eq_data[0, 3:6]
    return float(np.linalg.norm(p1 - p2))


def twin_rollout(ts: np.ndarray, timestep: float = 1e-3, integrator: str = "RK4") -> dict[str, np.ndarray]:
    """Run the MuJoCo C twin from rest; return the wheel-assembly CoM height ``y2`` (the quantity of
    ``AA_results.csv``, m) and the loop residual |B3 - B2| (m) at ``ts`` (a uniform grid from 0 whose spacing is a
    multiple of ``timestep``). The tyre callback is installed for the run and removed afterwards."""
    m = mujoco.MjModel.from_xml_string(twin_xml(timestep, integrator))
    d = mujoco.MjData(m)
    site = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, "G2")
    b1, b2 = int(m.eq_obj1id[0]), int(m.eq_obj2id[0])
    per = int(round((ts[1] - ts[0]) / timestep)) if len(ts) > 1 else 1
    wheel, loop = np.empty(len(ts)), np.empty(len(ts))
    mujoco.set_mjcb_passive(python_tyre(site, (0.0, 1.0, 0.0), 0.0, nk.TYRE["radius"], nk.TYRE["stiffness"],
                                        nk.TYRE["damping"]))
    try:
        mujoco.mj_forward(m, d)
        for k in range(len(ts)):
            if k:
                mujoco.mj_step(m, d, nstep=per)
                mujoco.mj_kinematics(m, d)  # after an RK4 mj_step, xpos is not the kinematics of the new qpos
            wheel[k] = d.site_xpos[site, 1]
            loop[k] = _loop_residual(m, d, b1, b2)
    finally:
        mujoco.set_mjcb_passive(None)
    return {"wheel_y": wheel, "loop_residual": loop}


def mjx_rollout(m: mujoco.MjModel, n_save: int):
    """``(fn, mx, d0)`` for the twin ``m`` (from :func:`twin_xml`): ``fn(mx, d0, per)`` runs ``(n_save - 1) * per``
    RK4 steps of ``mx.opt.timestep`` and returns ``(wheel height y2, loop residual)``, each ``(n_save,)``, every
    ``per`` steps (the first at t = 0). ``fn`` is jitted; ``per`` and the model's numbers are traced, so another
    step size (another ``mjx.put_model``) does not recompile. The RK4 tableau follows MuJoCo's ``mj_RungeKutta``
    (all joints are hinges: positions advance linearly)."""
    import jax
    import jax.numpy as jnp
    from mujoco import mjx

    from .mjx import connect_residual, rk4_rollout, rk4_step, tyre_forward

    wb = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "wheel")
    forward = tyre_forward(wb, 1, 0.0, nk.TYRE)
    loop = connect_residual(m, 0)

    def observe(mx, d):
        k = mjx.kinematics(mx, d)
        return jnp.stack([k.xpos[wb, 1], loop(k)])

    roll = rk4_rollout(m, n_save, forward, observe)

    @jax.jit
    def fn(mx, d, per):
        out = roll(mx, d, per)
        return out[:, 0], out[:, 1]

    mx = mjx.put_model(m)
    d0 = mjx.put_data(m, mujoco.MjData(m))
    with jax.numpy_rank_promotion("allow"):
        # With x64 some integer fields change type in the first forward; the scan carry needs the types after a
        # step. They are read by abstract evaluation (no compile), instead of running a jitted mjx.forward first.
        after = jax.eval_shape(rk4_step(m, forward), mx, d0)
    d0 = jax.tree.map(lambda x, s: jnp.asarray(x, dtype=s.dtype), d0, after)
    return jax.jit(fn), mx, d0
