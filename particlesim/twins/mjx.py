"""MuJoCo's RK4 around MJX's forward stages, for twins whose forces must be evaluated at every stage.

MJX has no passive-force callback, so a state- or time-dependent force law (a one-sided tyre, a torque input)
cannot ride inside ``mjx.step``; written into ``qfrc_applied`` once per step it would be first order. Here the
user's ``forward(mx, d)`` (an ``mjx.forward`` that inserts the force itself) is called at every RK4 stage, with
the stage's positions, velocities and time, exactly as ``mj_RungeKutta`` does in MuJoCo C (same tableau; positions
advance by ``mj_integratePos``, quaternions by their body-frame angular velocity).

All MJX calls trace under ``jax.numpy_rank_promotion("allow")`` (MJX 3.17 needs it).

Rollouts of the twins built on it (used by ``tests/twins/test_mjx_twins.py`` and the benchmarks):

* :func:`chain_rollout` runs a chain's MJCF (:func:`particlesim.twins.chains.chain_mjcf`) with MJX's own RK4
  (``mjx.step`` in a ``lax.scan``) and records every site.
* :func:`quarter_car_rollout` runs the quarter-car twin (:func:`particlesim.twins.quarter_car.twin_xml`) with
  an RK4 loop of our own around MJX's forward stages: MJX has no passive-force callback, so the one-sided tyre is
  evaluated from the state at every RK4 stage (wheel-centre height and velocity from the kinematics and the site
  Jacobian, ``qfrc_applied = J_z^T F``) before the velocity and acceleration stages. The law is then exact per
  stage, as the MuJoCo C twin's ``mjcb_passive`` (a force held over a step would be first order, docs/twins.md).
  The RK4 loop is :func:`rk4_rollout` (MuJoCo's ``mj_RungeKutta`` tableau).
* :func:`forced_rk4_rollout` is the same RK4 loop around ``mjx.forward`` for any model driven by a time-dependent
  generalised force ``force(t)`` (e.g. Krang's arm torques), applied in ``qfrc_applied`` at every stage at the
  stage time (as the MuJoCo C twin's ``mjcb_passive`` reading ``d.time``).

The rollouts are built once per model structure: the MJX model is an argument, so another step size does not recompile.
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

__all__ = ["RK4_TABLEAU", "integrate_pos", "initial_data", "rk4_step", "rk4_rollout", "tyre_forward",
           "connect_residual", "chain_rollout", "quarter_car_rollout", "forced_rk4_rollout"]

#: MuJoCo's RK4: (stage offset a_i, weight b_i).
RK4_TABLEAU = np.array([[0.0, 1 / 6], [0.5, 1 / 3], [0.5, 1 / 3], [1.0, 1 / 6]])


def integrate_pos(m: mujoco.MjModel, qpos, qvel, dt):
    """``qpos`` advanced by ``qvel`` over ``dt`` (MuJoCo's ``mj_integratePos`` for slide, hinge, ball and free
    joints; rotations by their body-frame angular velocity)."""
    out = []
    for j in range(m.njnt):
        a, v, kind = int(m.jnt_qposadr[j]), int(m.jnt_dofadr[j]), int(m.jnt_type[j])
        if kind in (int(mujoco.mjtJoint.mjJNT_SLIDE), int(mujoco.mjtJoint.mjJNT_HINGE)):
            out.append(qpos[a:a + 1] + dt * qvel[v:v + 1])
        elif kind in (int(mujoco.mjtJoint.mjJNT_BALL), int(mujoco.mjtJoint.mjJNT_FREE)):
            if kind == int(mujoco.mjtJoint.mjJNT_FREE):  # world-frame translation, then the ball part
                out.append(qpos[a:a + 3] + dt * qvel[v:v + 3])
                a, v = a + 3, v + 3
            q, w = qpos[a:a + 4], qvel[v:v + 3]
            nw = jnp.sqrt(w @ w)
            axis = w / jnp.where(nw > 0, nw, 1.0)
            half = 0.5 * nw * dt
            w0, x0, y0, z0 = q[0], q[1], q[2], q[3]
            w1, (x1, y1, z1) = jnp.cos(half), jnp.sin(half) * axis
            r = jnp.stack([w0 * w1 - x0 * x1 - y0 * y1 - z0 * z1, w0 * x1 + x0 * w1 + y0 * z1 - z0 * y1,
                           w0 * y1 - x0 * z1 + y0 * w1 + z0 * x1, w0 * z1 + x0 * y1 - y0 * x1 + z0 * w1])
            out.append(r / jnp.sqrt(r @ r))
        else:
            raise NotImplementedError(f"joint {j}: type {kind} (only slide, hinge, ball and free are supported)")
    return jnp.concatenate(out)


def rk4_step(m: mujoco.MjModel, forward: Callable) -> Callable:
    """``step(mx, d) -> d``: one RK4 step of ``mx.opt.timestep``, ``forward(mx, d_stage)`` at each stage (the stage
    data carry the stage's ``qpos``, ``qvel`` and ``time``; ``forward`` must fill ``qacc``)."""

    def step(mx, d):
        dt = mx.opt.timestep
        q0, v0, t0 = d.qpos, d.qvel, d.time

        def stage(c, ab):
            kv, ka, sv, sa = c
            ds = forward(mx, d.replace(qpos=integrate_pos(m, q0, kv, ab[0] * dt), qvel=v0 + ab[0] * dt * ka,
                                       time=t0 + ab[0] * dt))
            return (ds.qvel, ds.qacc, sv + ab[1] * ds.qvel, sa + ab[1] * ds.qacc), None

        z = jnp.zeros_like(v0)
        (_, _, vel, acc), _ = jax.lax.scan(stage, (z, z, z, z), jnp.asarray(RK4_TABLEAU))
        return d.replace(qpos=integrate_pos(m, q0, vel, dt), qvel=v0 + dt * acc, time=t0 + dt)

    return step


def rk4_rollout(m: mujoco.MjModel, n_save: int, forward: Callable, observe: Callable) -> Callable:
    """Jitted ``fn(mx, d0, per)``: ``(n_save - 1) * per`` RK4 steps (:func:`rk4_step`), returning
    ``observe(mx, d)`` (an array or a pytree of them) every ``per`` steps, the first at ``d0``, stacked to
    ``(n_save, ...)``. The MJX model is an argument and ``per`` is traced, so another step size (another
    ``mjx.put_model``) does not recompile."""
    step = rk4_step(m, forward)

    def fn(mx, d, per):
        def outer(d, _):
            d = jax.lax.fori_loop(0, per, lambda i, d: step(mx, d), d)
            return d, observe(mx, d)

        with jax.numpy_rank_promotion("allow"):
            rest = jax.lax.scan(outer, d, None, length=n_save - 1)[1]
            return jax.tree.map(lambda a, b: jnp.concatenate([a[None], b]), observe(mx, d), rest)

    return jax.jit(fn)



def initial_data(m: mujoco.MjModel, mx):
    """MJX data at the model's reference pose after one jitted forward (x64 field types settle, see the brief)."""
    with jax.numpy_rank_promotion("allow"):
        return jax.jit(mjx.forward)(mx, mjx.put_data(m, mujoco.MjData(m)))


def tyre_forward(wheel_body: int, axis: int, ground: float, tyre: dict) -> Callable:
    """``forward(mx, d)``: ``mjx.forward`` with the one-sided tyre on body ``wheel_body``'s origin (the wheel centre)
    along world ``axis`` inserted after the position stage, from this stage's state (``qfrc_applied = J^T f``)."""

    def forward(mx, d):
        d = mjx.fwd_position(mx, d)
        jacp, _ = mjx.jac(mx, d, d.xpos[wheel_body], wheel_body)
        dist = d.xpos[wheel_body, axis] - ground - tyre["radius"]
        rate = jacp[:, axis] @ d.qvel
        f = jnp.where(dist < 0.0, -(tyre["stiffness"] * dist + tyre["damping"] * rate), 0.0)
        d = d.replace(qfrc_applied=jacp[:, axis] * f)
        d = mjx.fwd_velocity(mx, d)
        d = mjx.fwd_actuation(mx, d)
        d = mjx.fwd_acceleration(mx, d)
        return mjx.solve(mx, d)

    return forward


def connect_residual(m: mujoco.MjModel, eq: int) -> Callable:
    """``residual(k)``: the gap of ``connect`` equality ``eq`` (its two anchors) from MJX kinematics ``k``."""
    b1, b2 = int(m.eq_obj1id[eq]), int(m.eq_obj2id[eq])
    anchor1, anchor2 = np.array(m.eq_data[eq, 0:3]), np.array(m.eq_data[eq, 3:6])

    def residual(k):
        return jnp.linalg.norm(k.xpos[b1] + k.xmat[b1] @ anchor1 - (k.xpos[b2] + k.xmat[b2] @ anchor2))

    return residual


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
    return jax.jit(fn), mx, initial_data(m, mx)


def quarter_car_rollout(m: mujoco.MjModel, n_save: int, *, ground: float, tyre: dict):
    """``(fn, mx, d0)`` for the quarter-car twin ``m``: ``fn(mx, d0, per)`` runs ``(n_save - 1) * per`` RK4 steps of
    ``m.opt.timestep`` and returns ``(chassis z, wheel-centre z, upper ball-joint (connect) residual)`` every
    ``per`` steps, each ``(n_save,)``. ``tyre``: ``radius``, ``stiffness``, ``damping``; ``ground``: plane height."""
    wb = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "wheel")
    cb = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "chassis")
    eq = 0  # the connect equality (upper ball joint)

    forward = tyre_forward(wb, 2, ground, tyre)
    loop = connect_residual(m, eq)

    def observe(mx, d):
        k = mjx.kinematics(mx, d)
        return jnp.stack([k.xpos[cb, 2], k.xpos[wb, 2], loop(k)])

    roll = rk4_rollout(m, n_save, forward, observe)

    @jax.jit
    def fn(mx, d, per):
        out = roll(mx, d, per)
        return out[:, 0], out[:, 1], out[:, 2]

    mx = mjx.put_model(m)
    return fn, mx, initial_data(m, mx)


def forced_rk4_rollout(m: mujoco.MjModel, n_save: int, force, *, observe=lambda mx, d: d.qpos):
    """``(fn, mx, d0)``: ``fn(mx, d0, per)`` runs ``(n_save - 1) * per`` RK4 steps of ``mx.opt.timestep`` with
    ``qfrc_applied = force(t)`` (``(nv,)``, jnp, MuJoCo order) at every stage time ``t = time + a_i dt``, and returns
    ``observe(mx, d)`` every ``per`` steps (the first at ``d0``), stacked ``(n_save, ...)``. Set the start state
    with ``d0.replace(qpos=..., qvel=...)``; ``fn`` is jitted, ``per`` and the model's numbers are traced."""

    def forward(mx, d):
        return mjx.forward(mx, d.replace(qfrc_applied=force(d.time)))

    mx = mjx.put_model(m)
    return rk4_rollout(m, n_save, forward, observe), mx, initial_data(m, mx)
