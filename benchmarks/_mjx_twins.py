"""MJX twins of the particle-coordinate scenes (used by ``tests/mechanism/test_mjx_twins.py`` and the benchmarks).

* :func:`chain_rollout` runs a chain's MJCF (:func:`particlesim.scenes.chains.chain_mjcf`) with MJX's own RK4
  (``mjx.step`` in a ``lax.scan``) and records every site.
* :func:`quarter_car_rollout` runs the quarter-car twin (:func:`particlesim.scenes.quarter_car_twin.twin_xml`) with
  an RK4 loop of our own around MJX's forward stages: MJX has no passive-force callback, so the one-sided tyre is
  evaluated from the state at every RK4 stage (wheel-centre height and velocity from the kinematics and the site
  Jacobian, ``qfrc_applied = J_z^T F``) before the velocity and acceleration stages. The law is then exact per
  stage, as the MuJoCo C twin's ``mjcb_passive`` (a force held over a step would be first order, MUJOCO-TWINS.md).
  The RK4 loop is :func:`particlesim.io.mjx_rk4.rk4_rollout` (MuJoCo's ``mj_RungeKutta`` tableau).
* :func:`forced_rk4_rollout` is the same RK4 loop around ``mjx.forward`` for any model driven by a time-dependent
  generalised force ``force(t)`` (e.g. Krang's arm torques), applied in ``qfrc_applied`` at every stage at the
  stage time (as the MuJoCo C twin's ``mjcb_passive`` reading ``d.time``).

MJX 3.17 fails under ``jax_numpy_rank_promotion="raise"``; every function here traces under "allow". The rollouts
are built once per model structure: the MJX model is an argument, so another step size does not recompile.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from particlesim.io.mjx_rk4 import rk4_rollout

__all__ = ["chain_rollout", "quarter_car_rollout", "forced_rk4_rollout"]

def _start(m: mujoco.MjModel, mx):
    """MJX data at the model's reference pose after one jitted forward (x64 field types settle, see the brief)."""
    with jax.numpy_rank_promotion("allow"):
        return jax.jit(mjx.forward)(mx, mjx.put_data(m, mujoco.MjData(m)))


def chain_rollout(m: mujoco.MjModel, n_save: int):
    """``(fn, mx, d0)``: ``fn(mx, d0, per)`` runs ``(n_save - 1) * per`` MJX RK4 steps of ``mx.opt.timestep``
    and returns the site positions ``(n_save, n_sites, 3)`` every ``per`` steps (the first at t = 0). ``fn`` is
    jitted; ``per`` and the model's numbers are traced (another step size does not recompile)."""

    def fn(mx, d, per):
        def outer(d, _):
            d = jax.lax.fori_loop(0, per, lambda i, d: mjx.step(mx, d), d)
            return d, mjx.kinematics(mx, d).site_xpos

        with jax.numpy_rank_promotion("allow"):
            last = jax.lax.scan(outer, d, None, length=n_save - 1)[1]
        return jnp.concatenate([mjx.kinematics(mx, d).site_xpos[None], last])

    mx = mjx.put_model(m)
    return jax.jit(fn), mx, _start(m, mx)


def quarter_car_rollout(m: mujoco.MjModel, n_save: int, *, ground: float, tyre: dict):
    """``(fn, mx, d0)`` for the quarter-car twin ``m``: ``fn(mx, d0, per)`` runs ``(n_save - 1) * per`` RK4 steps of
    ``m.opt.timestep`` and returns ``(chassis z, wheel-centre z, upper ball-joint (connect) residual)`` every
    ``per`` steps, each ``(n_save,)``. ``tyre``: ``radius``, ``stiffness``, ``damping``; ``ground``: plane height."""
    wb = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "wheel")
    cb = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "chassis")
    eq = 0  # the connect equality (upper ball joint)
    b1, b2 = int(m.eq_obj1id[eq]), int(m.eq_obj2id[eq])
    anchor1, anchor2 = np.array(m.eq_data[eq, 0:3]), np.array(m.eq_data[eq, 3:6])

    def forward(mx, d):
        """``mjx.forward`` with the tyre force from this stage's state inserted after the position stage."""
        d = mjx.fwd_position(mx, d)
        jacp, _ = mjx.jac(mx, d, d.xpos[wb], wb)  # the wheel body's origin (= CoM) is the wheel centre
        dist = d.xpos[wb, 2] - ground - tyre["radius"]
        vz = jacp[:, 2] @ d.qvel
        f = jnp.where(dist < 0.0, -(tyre["stiffness"] * dist + tyre["damping"] * vz), 0.0)
        d = d.replace(qfrc_applied=jacp[:, 2] * f)
        d = mjx.fwd_velocity(mx, d)
        d = mjx.fwd_actuation(mx, d)
        d = mjx.fwd_acceleration(mx, d)
        return mjx.solve(mx, d)

    def observe(mx, d):
        k = mjx.kinematics(mx, d)
        p1 = k.xpos[b1] + k.xmat[b1] @ anchor1
        p2 = k.xpos[b2] + k.xmat[b2] @ anchor2
        return jnp.stack([k.xpos[cb, 2], k.xpos[wb, 2], jnp.linalg.norm(p1 - p2)])

    roll = rk4_rollout(m, n_save, forward, observe)

    @jax.jit
    def fn(mx, d, per):
        out = roll(mx, d, per)
        return out[:, 0], out[:, 1], out[:, 2]

    mx = mjx.put_model(m)
    return fn, mx, _start(m, mx)


def forced_rk4_rollout(m: mujoco.MjModel, n_save: int, force, *, observe=lambda mx, d: d.qpos):
    """``(fn, mx, d0)``: ``fn(mx, d0, per)`` runs ``(n_save - 1) * per`` RK4 steps of ``mx.opt.timestep`` with
    ``qfrc_applied = force(t)`` (``(nv,)``, jnp, MuJoCo order) at every stage time ``t = time + a_i dt``, and returns
    ``observe(mx, d)`` every ``per`` steps (the first at ``d0``), stacked ``(n_save, ...)``. Set the start state
    with ``d0.replace(qpos=..., qvel=...)``; ``fn`` is jitted, ``per`` and the model's numbers are traced."""

    def forward(mx, d):
        return mjx.forward(mx, d.replace(qfrc_applied=force(d.time)))

    mx = mjx.put_model(m)
    return rk4_rollout(m, n_save, forward, observe), mx, _start(m, mx)
