"""MuJoCo's RK4 around MJX's forward stages, for twins whose forces must be evaluated at every stage.

MJX has no passive-force callback, so a state- or time-dependent force law (a one-sided tyre, a torque input)
cannot ride inside ``mjx.step``; written into ``qfrc_applied`` once per step it would be first order. Here the
user's ``forward(mx, d)`` (an ``mjx.forward`` that inserts the force itself) is called at every RK4 stage, with
the stage's positions, velocities and time, exactly as ``mj_RungeKutta`` does in MuJoCo C (same tableau; positions
advance by ``mj_integratePos``, quaternions by their body-frame angular velocity).

All MJX calls trace under ``jax.numpy_rank_promotion("allow")`` (MJX 3.17 needs it).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

__all__ = ["RK4_TABLEAU", "integrate_pos", "rk4_step", "rk4_rollout"]

#: MuJoCo's RK4: (stage offset a_i, weight b_i).
RK4_TABLEAU = np.array([[0.0, 1 / 6], [0.5, 1 / 3], [0.5, 1 / 3], [1.0, 1 / 6]])


def integrate_pos(m: mujoco.MjModel, qpos, qvel, dt):
    """``qpos`` advanced by ``qvel`` over ``dt`` (MuJoCo's ``mj_integratePos`` for slide, hinge and ball joints)."""
    out = []
    for j in range(m.njnt):
        a, v, kind = int(m.jnt_qposadr[j]), int(m.jnt_dofadr[j]), int(m.jnt_type[j])
        if kind in (int(mujoco.mjtJoint.mjJNT_SLIDE), int(mujoco.mjtJoint.mjJNT_HINGE)):
            out.append(qpos[a:a + 1] + dt * qvel[v:v + 1])
        elif kind == int(mujoco.mjtJoint.mjJNT_BALL):
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
            raise NotImplementedError(f"joint {j}: type {kind} (only slide, hinge and ball are supported)")
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
    ``observe(mx, d)`` every ``per`` steps, the first at ``d0``, stacked to ``(n_save, ...)``. The MJX model is an
    argument and ``per`` is traced, so another step size (another ``mjx.put_model``) does not recompile."""
    step = rk4_step(m, forward)

    def fn(mx, d, per):
        def outer(d, _):
            d = jax.lax.fori_loop(0, per, lambda i, d: step(mx, d), d)
            return d, observe(mx, d)

        with jax.numpy_rank_promotion("allow"):
            rest = jax.lax.scan(outer, d, None, length=n_save - 1)[1]
            return jnp.concatenate([observe(mx, d)[None], rest])

    return jax.jit(fn)
