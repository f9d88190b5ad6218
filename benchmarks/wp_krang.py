"""Work against precision for 2 s of the fixed-wheel Krang (18 joints) under gravity and a smooth torque input on
both arms (float64, CPU): ours against its MuJoCo C and MJX twins (:mod:`particlesim.twins.urdf`).

Scene (:func:`scene`): ``krang_fixed_wheel_2018-04.urdf``, gravity (0, -9.81, 0), viscous friction ``FV`` on every
joint (MuJoCo's joint damping, the same law; without it the 2 s fall is chaotic: Bosh3 at rtol 1e-7 ended 15 rad
from the reference), from a seeded non-trivial pose at rest; the twelve arm joints (LJ1-LJ6, RJ1-RJ6) driven by ``tau_j(t) = A_j sin(w_j t + phi_j)``
with ``A_j`` of 2-5 N m (0.3-0.75 N m on the light wrists J5, J6) and 0.5-2 Hz. The robot tips over on its wheel axis while the arms swing.

Error = max over the joints of |q_j - q_j,ref| (rad) at 2 s (final) and over the 101 save times (trajectory), with
the reference from ours (Dopri8, rtol 1e-13, atol 1e-15). Rows:

* ours: :func:`particlesim.simulate.simulate` with :func:`particlesim.tree.forward_dynamics` and ``control = tau(t)``
  (evaluated at every stage), Bosh3, Tsit5, Dopri5, Dopri8, Kvaerno3, Kvaerno5 over a sweep of rtol
  (atol = rtol / 100); one compile per solver (tolerances traced), compile time listed separately;
* MuJoCo C twin, RK4 through ``mujoco.rollout`` over a sweep of fixed steps, the torque a compiled C
  ``mjcb_passive`` (:func:`particlesim.twins.callbacks.install_sine_torques`); and, labelled, the same twin driven from
  Python (``mj_step`` loop) with the torque added to ``qfrc_passive`` by a Python ``mjcb_passive`` at
  every RK4 stage at the stage time ``d.time`` (a torque held over a step would be first order, docs/twins.md;
  tests/twins/test_krang_torque_twin.py measures fourth-order convergence), and Euler and implicitfast (first order)
  over a short sweep, all three labelled "Python loop, Python callback"; the interpreter cost of that callback is
  measured separately (a no-op callback against none) in ``callback_overhead``;
* MJX twin: :func:`particlesim.twins.mjx.forced_rk4_rollout` (MuJoCo's RK4 tableau around ``mjx.forward``, torque
  per stage in ``qfrc_applied``), jitted once, the MJX model an argument so other steps do not recompile.

Run: ``python -m benchmarks.wp_krang``. Writes ``benchmarks/results/wp_krang.{json,csv,png}``.
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from particlesim.data import data_dir
from particlesim.twins.urdf import JointMap, mjx_model, mujoco_model
from particlesim.simulate import simulate
from particlesim.tree import forward_dynamics
from particlesim.io import load_urdf

from . import _wp
from ._common import median_time, report, timed
from particlesim.twins.mjx import forced_rk4_rollout

NAME = "wp_krang"
URDF = "krang/urdf/krang_fixed_wheel_2018-04.urdf"
GRAVITY = (0.0, -9.81, 0.0)
T_END = 2.0
TS = np.linspace(0.0, T_END, 101)
TARGET = 1e-6  # rad, final joint angles
FV = 1.0  # N m s / rad, every joint
ARMS = tuple(f"{side}J{k}" for side in "LR" for k in range(1, 7))
REF = {"solver": "dopri8", "rtol": 1e-13, "atol": 1e-15}
RTOLS = {
    "bosh3": (1e-4, 1e-5, 1e-6, 1e-7, 1e-8),
    # 1-2-5 steps around the 1e-6 rad target (as MuJoCo's time is interpolated to it), decades beyond
    "tsit5": (1e-4, 1e-5, 1e-6, 5e-7, 2e-7, 1e-7, 5e-8, 2e-8, 1e-8, 1e-9, 1e-10),
    "dopri5": (1e-4, 1e-5, 1e-6, 5e-7, 2e-7, 1e-7, 5e-8, 2e-8, 1e-8, 1e-9, 1e-10),
    "dopri8": (1e-4, 1e-5, 5e-6, 2e-6, 1e-6, 5e-7, 2e-7, 1e-7, 1e-8, 1e-9, 1e-10, 1e-11),
    # Implicit solvers are costly here (the problem is not stiff): Kvaerno3 took 48 s for 929 steps at rtol 1e-4
    # (load 8.6 on 2 cores), so one or two tolerances each.
    "kvaerno3": (1e-4,),
    "kvaerno5": (1e-4, 1e-5),
}
C_RK4_STEPS = (2e-3, 1e-3, 5e-4, 2.5e-4, 1.25e-4)
#: MuJoCo C's native loop starts coarser, so its sweep brackets the target from above
C_NATIVE_STEPS = (1e-2, 5e-3, 4e-3) + C_RK4_STEPS
C_FIRST_ORDER_STEPS = (1e-3, 1e-4, 1e-5)
MJX_STEPS = (1e-3, 5e-4, 2.5e-4)


def scene():
    """``(model, q0, qd0, torque)``; ``torque = (amp, omega, phase)``, each (n,) in our joint order, zero off the
    arms."""
    model = load_urdf(data_dir() / URDF, gravity=GRAVITY, viscous=FV)
    rng = np.random.default_rng(8)
    q0 = 0.5 * rng.uniform(-1.0, 1.0, model.nq)
    amp, omega, phase = np.zeros(model.nq), np.zeros(model.nq), np.zeros(model.nq)
    for name in ARMS:
        j = model.joint_names.index(name)
        scale = 1.0 if int(name[-1]) <= 4 else 0.15  # the wrists (J5, J6) are light: 0.3-0.75 N m there
        amp[j] = scale * rng.uniform(2.0, 5.0)
        omega[j], phase[j] = 2 * np.pi * rng.uniform(0.5, 2.0), rng.uniform(0, 2 * np.pi)
    return model, q0, np.zeros(model.nq), (amp, omega, phase)


def twin(dt: float, integrator: str = "rk4") -> mujoco.MjModel:
    """The MuJoCo twin of :func:`scene`'s model (joint damping ``FV``) at step ``dt``."""
    return mujoco_model(data_dir() / URDF, gravity=GRAVITY, timestep=dt, integrator=integrator, damping=FV)


def torque(t, amp, omega, phase, xp=np):
    """tau(t) = amp sin(omega t + phase) (N m)."""
    return amp * xp.sin(omega * t + phase)


def ours_fn(solver: str, torque_args, max_steps: int = 200_000):
    """``fn(model, q0, qd0, rtol, atol) -> (q at TS (T, n), steps, rejected)``."""
    amp, omega, phase = (jnp.asarray(a) for a in torque_args)

    def fn(model, q0, qd0, rtol, atol):
        s = simulate(forward_dynamics, model, q0, qd0, 0.0, T_END, solver=solver, rtol=rtol, atol=atol,
                     control=lambda t, q, qd, p: torque(t, amp, omega, phase, jnp), saveat_ts=jnp.asarray(TS),
                     max_steps=max_steps)
        return s.q, s.steps, s.rejected

    return fn


def mujoco_c_rollout(m, jm: JointMap, q0, qd0, torque_args, ts=TS, *, callback: str = "torque"):
    """MuJoCo C from ``(q0, qd0)`` (our order) over ``ts`` (spacing a multiple of ``m.opt.timestep``); returns
    the joint angles ``(T, n)`` in our order. ``callback``: "torque" (tau(d.time) added to ``qfrc_passive`` at
    every evaluation of the dynamics, i.e. every RK4 stage at its stage time), "noop" or "none" (for the cost of
    the callback itself)."""
    amp, omega, phase = (np.asarray(jm.to_mujoco(np.asarray(a))) for a in torque_args)

    def cb(m_, d_):
        d_.qfrc_passive[:] += amp * np.sin(omega * d_.time + phase)

    d = mujoco.MjData(m)
    d.qpos[:], d.qvel[:] = jm.to_mujoco(np.asarray(q0)), jm.to_mujoco(np.asarray(qd0))
    per = int(round((ts[1] - ts[0]) / m.opt.timestep))
    out = [d.qpos.copy()]
    mujoco.set_mjcb_passive({"torque": cb, "noop": lambda m_, d_: None, "none": None}[callback])
    try:
        step = mujoco.mj_step
        for _ in range(len(ts) - 1):
            for _ in range(per):
                step(m, d)
            out.append(d.qpos.copy())
    finally:
        mujoco.set_mjcb_passive(None)
    return jm.from_mujoco(np.asarray(out))


def c_native_rows(jm: JointMap, q0, qd0, torque_args, errors) -> list[dict]:
    """MuJoCo C RK4 through its native loop (``mujoco.rollout``) with the torque as a compiled ``mjcb_passive``
    evaluated at every stage at the stage time (:func:`particlesim.twins.callbacks.install_sine_torques`)."""
    from particlesim.twins import callbacks as mjcb

    from ._native import Rollout, initial_state

    amp, omega, phase = (np.asarray(jm.to_mujoco(np.asarray(a))) for a in torque_args)
    save_dt = TS[1] - TS[0]

    def make(dt):
        m = twin(dt)
        d = mujoco.MjData(m)
        d.qpos[:], d.qvel[:] = jm.to_mujoco(np.asarray(q0)), jm.to_mujoco(np.asarray(qd0))
        ro = Rollout(m, initial_state(m, d), int(round(T_END / dt)))
        stride = int(round(save_dt / dt))
        on_grid = dt <= save_dt and abs(stride * dt - save_dt) < 1e-12

        def to_traj(states):
            q = jm.from_mujoco(ro.trajectory(states, lambda mm, dd: dd.qpos.copy(), stride if on_grid else ro.nstep))
            return q if on_grid else np.concatenate([np.full((len(TS) - 1, q.shape[1]), np.nan), q[-1:]])

        return ro, to_traj

    mjcb.install_sine_torques(amp, omega, phase)
    try:
        return _wp.sweep_rollout("MuJoCo C twin RK4 (mujoco.rollout, C callback)", C_NATIVE_STEPS, make, errors,
                                 T_END)
    finally:
        mjcb.uninstall()


def run() -> dict:
    started = time.perf_counter()
    model, q0, qd0, targs = scene()
    args = (model, jnp.asarray(q0), jnp.asarray(qd0))
    make = lambda solver: ours_fn(solver, targs)  # noqa: E731
    cache: dict = {}
    comp, ref_fn = _wp.compile_ours(make, args, REF["solver"], cache)
    ref_q, ref_steps, _ = ref_fn(*args, jnp.asarray(REF["rtol"]), jnp.asarray(REF["atol"]))
    ref_q = np.asarray(ref_q)
    errors = _wp.Errors(ref_q)
    print(f"reference: dopri8 rtol {REF['rtol']:g}, {int(ref_steps)} steps; max |q(2 s)| = "
          f"{np.abs(ref_q[-1]).max():.3f} rad", flush=True)
    rows = _wp.sweep_ours(make, args, tuple(RTOLS), RTOLS, errors, compiled=cache)

    jm = JointMap(twin(1e-3), model.joint_names)
    rows += c_native_rows(jm, q0, qd0, targs, errors)
    for integ, dts in (("rk4", C_RK4_STEPS), ("euler", C_FIRST_ORDER_STEPS), ("implicitfast", C_FIRST_ORDER_STEPS)):
        models = {dt: twin(dt, integ) for dt in dts}
        label = {"rk4": "RK4", "euler": "Euler", "implicitfast": "implicitfast"}[integ] + \
            " (Python loop, Python callback)"
        rows += _wp.sweep_fixed(f"MuJoCo C twin {label}", dts,
                                lambda dt: mujoco_c_rollout(models[dt], jm, q0, qd0, targs), errors, T_END,
                                repeat=3 if integ == "rk4" else 1)
    # Cost of the Python passive callback: the same RK4 run with a no-op callback and with none.
    m_cb = twin(5e-4)
    cost = {k: median_time(lambda: mujoco_c_rollout(m_cb, jm, q0, qd0, targs, callback=k), number=1, repeat=3)
            for k in ("none", "noop", "torque")}
    overhead = {"dt": 5e-4, "steps": int(round(T_END / 5e-4)), **{f"wall_s_{k}": v for k, v in cost.items()}}
    print("callback overhead:", overhead, flush=True)

    m0 = twin(MJX_STEPS[0])
    tau_mj = [jnp.asarray(jm.to_mujoco(np.asarray(a))) for a in targs]
    fn, mx0, d0 = forced_rk4_rollout(m0, len(TS), lambda t: torque(t, *tau_mj, xp=jnp),
                                     observe=lambda mx, d: d.qpos)
    d0 = d0.replace(qpos=jnp.asarray(jm.to_mujoco(q0)), qvel=jnp.asarray(jm.to_mujoco(qd0)))
    per = lambda dt: int(round((TS[1] - TS[0]) / dt))  # noqa: E731
    with jax.numpy_rank_promotion("allow"):
        comp_mjx, compiled = timed(lambda: fn.lower(mx0, d0, per(MJX_STEPS[0])).compile())
        mxs = {dt: mjx_model(twin(dt)) for dt in MJX_STEPS}
    rows += _wp.sweep_fixed("MJX twin RK4 (jit)", MJX_STEPS,
                            lambda dt: jm.from_mujoco(np.asarray(compiled(mxs[dt], d0, per(dt)))), errors, T_END,
                            compile_s=comp_mjx, repeat=3)

    notes = [
        f"Torque input: {len(ARMS)} arm joints, tau_j = A_j sin(w_j t + phi_j), A 2-5 N m (wrists 0.3-0.75 N m), 0.5-2 Hz, evaluated at "
        "every stage by every method (MuJoCo C through `mjcb_passive` at the stage time `d.time`; its RK4 converges "
        "at fourth order, tests/twins/test_krang_torque_twin.py).",
        "MuJoCo C's headline row runs its native loop (`mujoco.rollout`, calling thread) with the torque as a "
        "compiled C `mjcb_passive` (particlesim.twins.callbacks); its step is swept from too coarse to fine and its time "
        "interpolated to the target. The rows labelled 'Python loop, Python callback' drive `mj_step` from Python "
        f"with the torque in a Python callback (kept for comparison): at dt 5e-4 ({overhead['steps']} RK4 steps) no "
        f"callback {_wp.fmt_time(cost['none'])}, a no-op callback {_wp.fmt_time(cost['noop'])}, the torque "
        f"callback {_wp.fmt_time(cost['torque'])}.",
        "Ours runs one jitted call per 2 s rollout (dispatch included in the wall time); compile times are listed "
        "separately and are not in the ratios.",
        "With joint damping as the only velocity-dependent force, MuJoCo's Euler (which already treats damping "
        "implicitly) and implicitfast make the same update: their rows coincide. Both are first order and far from "
        "the target at any step tried.",
        "The implicit Kvaerno solvers are expensive on this non-stiff scene (per step a few hundred times an "
        "explicit step; see the steps and wall-time columns), hence their short sweeps; they are for stiff friction "
        "(docs/simulation.md), not for this case.",
    ]
    res = _wp.finish(NAME, f"Krang, fixed wheel, 18 joints, gravity + arm torques, viscous friction {FV:g} N m s/rad", T_END, TARGET, "rad",
                      "max |joint angle − reference| over the 18 joints",
                      {"what": f"ours Dopri8 rtol {REF['rtol']:g} atol {REF['atol']:g}", "steps": int(ref_steps),
                       "compile_s": comp}, rows, started, notes=notes, goals=_wp.PEERS)
    return res | {"callback_overhead": overhead}


def markdown(results: dict) -> str:
    return _wp.markdown(results)


def main() -> dict:
    return report(run, _wp.write, markdown)


if __name__ == "__main__":
    main()
