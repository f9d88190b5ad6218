"""Tree robots beside the peers a robotics user would pick: jaxsim (JAX) and Drake (C++), float64, CPU.

Each peer loads the same URDF text itself and is driven as its documentation teaches; the accuracy of the
quantities timed here is tested in ``tests/tree/test_peers.py`` (M, bias, forward dynamics within 1e-10).

Forward dynamics, on Krang (``krang_fixed_base_2018.urdf``, 17 joints, fixed base) and Solo-12 (12 joints on a
floating base), µs per state:

* one call from Python with a new state and force: ours ``forward_dynamics(model, q, qd, tau)``; jaxsim its
  ``forward_dynamics_aba`` under ``jax.jit`` from the same arrays (its data object built inside); Drake
  ``SetPositionsAndVelocities``, the force on the applied-generalized-force port, then the generalized-acceleration
  output port (its continuous forward dynamics, articulated bodies), from state vectors in its own coordinates;
* inside one compiled loop over 256 states (ours and jaxsim: ``jax.lax.fori_loop``; Drake has no such loop);
* a batch of 1024 states: ours passed directly (the batch path, on one thread: ``tree.aba.BATCH_THREADS = 1``) and
  ``jit(vmap)`` of the one-state call, jaxsim ``jit(vmap)``, Drake a Python loop over the states (it has no batch
  call).

Compile times are a first call's time less one run's.

Rollouts: Krang's fixed-base file without its collision and visual elements (no ground here), joint limits opened
(±1000 rad) and ``<dynamics damping="1"/>`` on every joint (viscous friction, read by all three), gravity -z, from
a seeded pose at rest, 2 s. Error = max over joints and the 101 save times of |q - q_ref| (rad) against ours at
Dopri8 rtol 1e-13; target 1e-6 rad. Each method's sweep runs from coarse to fine and stops at the first setting
meeting the target (the same rule for all), its time the median of three runs, its compile listed beside:

* ours: :func:`particlesim.simulate.simulate` with Tsit5 and Dopri5 over rtol (atol = rtol / 100), one compile
  per solver (tolerances traced);
* jaxsim ``model.step`` with its RK4 integrator over the model's ``time_step`` (one compile per step size: it is
  a static field), the rollout a ``jax.lax.scan`` of it; ``step`` evaluates the joint friction once per step and
  holds it over the stages, so its error falls like ``dt`` (the sweep shows the order);
* jaxsim stage-wise: the classical RK4 over ``forward_dynamics_aba`` with its own joint torques
  (``compute_resultant_torques``, friction included) at every stage, step and count traced (one compile);
* Drake ``Simulator`` with its error-controlled RK3 (its default) and RK5 over ``set_target_accuracy``, and RK5 in
  fixed-step mode over the step (``ResetIntegratorFromFlags``).

Gradients: d/ds at s = 1 of the rollout loss ``sum over saves and joints of q^2``, the left arm's first link
(``LJ1``'s child) made s times denser (mass and inertia scaled, centre of mass kept; the two values printed agree to
the rollouts' accuracy), ours by reverse mode through ``simulate`` at its target-meeting Tsit5 rtol, jaxsim by
reverse mode through the stage-wise RK4 at its target-meeting step (Drake: not differentiable from Python).

Batched rollouts: 64 members with damping 0.5–2 N m s/rad, ours ``sharded_vmap(chunk=4, threads=1)`` (the chunked
vmap the batch docs recommend for adaptive rollouts, on one thread) and jaxsim ``jit(vmap)`` of the stage-wise RK4, both at their
target-meeting settings; rollouts per second (Drake: a Python loop, one rollout after another).

Run: ``python -m benchmarks.peers``. Writes ``benchmarks/results/peers.{json,csv,png}``.
"""

from __future__ import annotations

import functools
import importlib
import itertools
import logging
import os
import re
import time
import warnings
from importlib import metadata
from pathlib import Path

os.environ.setdefault("ROD_SKIP_SDFORMAT_CHECK", "1")  # Debian's sdformat writes SDF 1.9 (tests/tree/test_peers.py)

import jax  # noqa: E402
import particlesim  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402

from particlesim.batch import sharded_vmap  # noqa: E402
from particlesim.io import load_urdf  # noqa: E402
from particlesim.scenes.krang import urdf_path  # noqa: E402
from particlesim.simulate import simulate  # noqa: E402
from particlesim.tree import aba, forward_dynamics  # noqa: E402

from ._common import compile_and_time, environment, machine, median_time, pyplot, report, save_figure, write_results  # noqa: E402

NAME = "peers"
GRAVITY = (0.0, 0.0, -9.81)
LOOP_STATES = 256
BATCH = 1024
T_END = 2.0
TS = np.linspace(0.0, T_END, 101)
TARGET = 1e-6  # rad, over the trajectory
FV = 1.0  # N m s / rad
REF = dict(solver="dopri8", rtol=1e-13, atol=1e-15)
OURS_RTOLS = (1e-4, 5e-5, 2e-5, 1e-5, 5e-6, 2e-6, 1e-6, 1e-7)
SAVE_DT = TS[1] - TS[0]
#: Fixed steps as whole divisions of the save interval (steps per save), coarse to fine.
JAXSIM_STEP_PER_SAVE = (10, 20, 40)
JAXSIM_RK4_PER_SAVE = (5, 6, 8, 10, 12, 14, 16, 18, 20, 25, 40)
DRAKE_RK5_PER_SAVE = (4, 5, 6, 7, 8, 10, 12, 16, 20)
#: Drake's accuracy settings on 1-2-5 grids, as our tolerances.
DRAKE_ACCURACIES = {"runge_kutta3": (1e-5, 5e-6, 2e-6, 1e-6, 5e-7, 2e-7, 1e-7, 5e-8),
                    "runge_kutta5": (1e-8, 5e-9, 2e-9, 1e-9, 5e-10, 2e-10, 1e-10, 5e-11)}
MEMBERS = 64


def _quiet():
    """jaxsim's warnings of unresolved mesh files (geometry is not used here; importing jaxsim sets its logger's
    level, so the level is set after) and the loaders' warnings of unmodelled joint limits (ignored as asked)."""
    importlib.import_module("jaxsim")
    logging.getLogger("jaxsim").setLevel(logging.ERROR)
    warnings.filterwarnings("ignore", message=".*(limits|mesh).*")


def solo12_path() -> Path:
    return next(Path(f.locate()) for f in metadata.files("example-robot-data") or ()
                if str(f).endswith("solo_description/robots/solo12.urdf"))


def rollout_urdf() -> str:
    """Krang's fixed-base file for the rollouts: no collision or visual elements, open limits, damping FV."""
    text = urdf_path("krang_fixed_base_2018.urdf").read_text()
    text = re.sub(r"<(collision|visual)>.*?</\1>", "", text, flags=re.S)
    return re.sub(r"<limit [^>]*/>", f'<limit effort="1e6" lower="-1e3" upper="1e3" velocity="1e6"/>'
                  f'<dynamics damping="{FV}"/>', text)


# ----------------------------------------------------------------------------------------------------------------
# Peers' models and state conversions


class Jaxsim:
    """A jaxsim model of a URDF and our states in its terms (joints matched by name, ``VelRepr.Body``)."""

    def __init__(self, description, ours, **kw):
        import jaxsim.api as js
        from jaxsim import VelRepr

        self.js, self.repr = js, VelRepr.Body
        self.m = js.model.JaxSimModel.build_from_model_description(model_description=description, gravity=9.81,
                                                                    is_urdf=True, **kw)
        self.floating = ours.floating
        names = list(self.m.joint_names())
        self.idx = np.array([names.index(n) for n in ours.coordinate_names[1 if self.floating else 0:]])
        self.base = 6 if self.floating else 0  # our velocity coordinates before the joints'
        self.base_link = list(self.m.link_names()).index(ours.link_names[0])
        self.data0 = js.data.JaxSimModelData.build(model=self.m, velocity_representation=self.repr)

    def data(self, q, qd):
        """Traceable: the peer's data at our state."""
        n = self.m.dofs()
        sj = jnp.zeros(n).at[self.idx].set(q[7 if self.floating else 0:])
        vj = jnp.zeros(n).at[self.idx].set(qd[self.base:])
        kw = dict(joint_positions=sj, joint_velocities=vj)
        if self.floating:
            kw.update(base_position=q[:3], base_quaternion=jnp.concatenate([q[6:7], q[3:6]]),
                      base_linear_velocity=qd[:3], base_angular_velocity=qd[3:6])
        return self.data0.replace(model=self.m, **kw)

    def joint_forces(self, tau):
        return jnp.zeros(self.m.dofs()).at[self.idx].set(tau[self.base:])

    def forward(self, q, qd, tau):
        """Traceable: forward dynamics at our state and generalized force (a floating base's six entries as the
        base link's wrench in its own frame)."""
        wrench = jnp.zeros((self.m.number_of_links(), 6))
        if self.floating:
            wrench = wrench.at[self.base_link].set(tau[:6])
        a_base, a_joints = self.js.model.forward_dynamics_aba(self.m, self.data(q, qd),
                                                              joint_forces=self.joint_forces(tau), link_forces=wrench)
        return jnp.concatenate([a_base, a_joints[self.idx]]) if self.floating else a_joints[self.idx]


class Drake:
    """A Drake MultibodyPlant (continuous) of a URDF text; our joint order mapped to its positions."""

    def __init__(self, text, ours):
        from pydrake.multibody.parsing import Parser
        from pydrake.multibody.plant import MultibodyPlant

        self.plant = MultibodyPlant(0.0)
        Parser(self.plant).AddModelsFromString(text, "urdf")
        self.plant.Finalize()
        self.plant.mutable_gravity_field().set_gravity_vector(GRAVITY)
        self.ctx = self.plant.CreateDefaultContext()
        first = 1 if ours.floating else 0
        joints = [self.plant.GetJointByName(n) for n in ours.coordinate_names[first:]]
        self.iq = np.array([j.position_start() for j in joints])
        self.iv = np.array([j.velocity_start() for j in joints])
        self.nq, self.nv = self.plant.num_positions(), self.plant.num_velocities()

    def state(self, q, qd, tau):
        """Drake's ``x = (q, v)`` and generalized force at our state and force (tests/tree/test_peers.py maps them
        alike): a floating base's ``q = (qw, qx, qy, qz, x, y, z)``, ``v = T v_ours`` in world axes, ``tau = T^-T
        tau_ours``."""
        n_base = len(qd) - len(self.iv)
        x, t = np.zeros(self.nq + self.nv), np.zeros((self.nv, len(qd)))
        x[self.iq] = q[len(q) - len(self.iq):]
        t[self.iv, n_base + np.arange(len(self.iv))] = 1.0
        if n_base:
            from scipy.spatial.transform import Rotation

            x[:4], x[4:7] = q[[6, 3, 4, 5]], q[:3]
            r = Rotation.from_quat(q[3:7]).as_matrix()
            t[0:3, 3:6], t[3:6, 0:3] = r, r
        x[self.nq:] = t @ qd
        return x, np.linalg.solve(t.T, tau)


# ----------------------------------------------------------------------------------------------------------------
# Forward dynamics


def forward_rows(label: str, path: Path, floating: bool) -> list[dict]:
    _quiet()
    ours = load_urdf(path, gravity=GRAVITY, floating_base=floating, limits="ignore")
    peer, drake = Jaxsim(path, ours), Drake(path.read_text(), ours)
    rng = np.random.default_rng(0)
    q = rng.uniform(-1.0, 1.0, (BATCH, ours.nq))
    if floating:
        u = rng.normal(size=(BATCH, 4))
        q[:, 3:7] = u / np.linalg.norm(u, axis=1, keepdims=True)
    qd, tau = rng.normal(size=(BATCH, ours.nv)), rng.normal(size=(BATCH, ours.nv))
    qj, qdj, tj = (jnp.asarray(a) for a in (q, qd, tau))
    rows = []

    def row(peer_name, kind, how, timing, per=1):
        (c, seconds, _) = timing if isinstance(timing, tuple) else (None, timing, None)
        rows.append(dict(robot=label, peer=peer_name, kind=kind, how=how, us_per_state=seconds / per * 1e6,
                         compile_s=c))
        print(f"  {label:7s} {peer_name:8s} {kind:14s} {how:22s} {seconds / per * 1e6:9.2f} us/state", flush=True)

    block = jax.block_until_ready
    aba.BATCH_THREADS = 1  # a batch passed directly runs as one program on one thread, as the peers' do
    ours_fd = functools.partial(forward_dynamics, ours)
    # one call from Python, a new state each time (arrays in, as a user passes them)
    states = itertools.cycle([(qj[i], qdj[i], tj[i]) for i in range(64)])
    row("ours", "one call", "", compile_and_time(lambda: ours_fd(*next(states)), number=200, block=block))
    with jax.numpy_rank_promotion("allow"):
        peer_fd = jax.jit(peer.forward)
        row("jaxsim", "one call", "", compile_and_time(lambda: peer_fd(*next(states)), number=200, block=block))
    port = drake.plant.get_generalized_acceleration_output_port()
    force_port = drake.plant.get_applied_generalized_force_input_port()
    xs = [drake.state(q[i], qd[i], tau[i]) for i in range(64)]
    drake_states = itertools.cycle(xs)

    def drake_call():
        x, f = next(drake_states)
        drake.plant.SetPositionsAndVelocities(drake.ctx, x)
        force_port.FixValue(drake.ctx, f)
        return port.Eval(drake.ctx)

    row("drake", "one call", "", median_time(drake_call, number=200))

    # a compiled loop over LOOP_STATES states
    def loop_of(f):
        @functools.partial(jax.jit, compiler_options=particlesim.compiler_options())
        def run(q, qd, tau):
            return jax.lax.fori_loop(0, LOOP_STATES, lambda i, acc: acc + f(q[i], qd[i], tau[i]),
                                     jnp.zeros(ours.nv))
        return run

    args = (qj[:LOOP_STATES], qdj[:LOOP_STATES], tj[:LOOP_STATES])
    for name, f in (("ours", ours_fd), ("jaxsim", peer.forward)):
        with jax.numpy_rank_promotion("allow"):
            run = loop_of(f)
            row(name, "compiled loop", "", compile_and_time(lambda: run(*args), number=5, block=block), LOOP_STATES)

    # a batch of BATCH states, one thread each (the peers' are single-threaded)
    row("ours", f"batch {BATCH}", "direct, 1 thread",
        compile_and_time(lambda: ours_fd(qj, qdj, tj), number=5, block=block), BATCH)
    for name, f in (("ours", ours_fd), ("jaxsim", peer.forward)):
        with jax.numpy_rank_promotion("allow"):
            run = jax.jit(jax.vmap(f), compiler_options=particlesim.compiler_options())
            row(name, f"batch {BATCH}", "jit(vmap)", compile_and_time(lambda: run(qj, qdj, tj), number=5, block=block),
                BATCH)

    def drake_batch():
        for _ in range(BATCH):
            drake_call()

    row("drake", f"batch {BATCH}", "Python loop", median_time(drake_batch, number=1, repeat=3), BATCH)
    return rows


# ----------------------------------------------------------------------------------------------------------------
# Rollouts


def rollout_scene():
    text = rollout_urdf()
    model = load_urdf(text, gravity=GRAVITY, limits="ignore")
    q0 = 0.5 * np.random.default_rng(8).uniform(-1.0, 1.0, model.nq)
    return text, model, q0


def error(q, q_ref) -> float:
    """Largest joint-angle error over the save times (inf for a diverged run)."""
    d = np.abs(np.asarray(q) - q_ref)
    return float(np.max(d)) if np.all(np.isfinite(d)) else float("inf")


def ours_rollout(solver: str):
    @jax.jit
    def run(model, q0, rtol):
        s = simulate(forward_dynamics, model, q0, jnp.zeros_like(q0), 0.0, T_END, solver=solver, rtol=rtol,
                     atol=rtol / 100, saveat_ts=jnp.asarray(TS), max_steps=100_000)
        return s.q, s.steps
    return run


def jaxsim_stagewise(peer: Jaxsim, model=None):
    """``run(viscous, q0, dt, per) -> q at TS``: the classical RK4, ``per`` steps of ``dt`` between saves, the
    peer's own joint torques (its friction model) at every stage; ``model`` replaces the peer's (other masses)."""
    js, idx = peer.js, peer.idx
    m = peer.m if model is None else model

    def rollout(viscous, q0, dt, per):
        params = m.kin_dyn_parameters.joint_parameters
        mv = _replace(m, "kin_dyn_parameters.joint_parameters", _replace(params, "friction_viscous", viscous))
        d0 = js.data.JaxSimModelData.build(model=mv, velocity_representation=peer.repr)

        def f(x):
            d = d0.replace(model=mv, joint_positions=x[0], joint_velocities=x[1])
            tau = js.actuation_model.compute_resultant_torques(mv, d, joint_force_references=jnp.zeros(mv.dofs()))
            return x[1], js.model.forward_dynamics_aba(mv, d, joint_forces=tau)[1]

        def rk4(_, x):
            add = lambda x, k, h: jax.tree.map(lambda a, b: a + h * b, x, k)  # noqa: E731
            k1 = f(x)
            k2 = f(add(x, k1, dt / 2))
            k3 = f(add(x, k2, dt / 2))
            k4 = f(add(x, k3, dt))
            return jax.tree.map(lambda a, b, c, d_, e: a + dt / 6 * (b + 2 * c + 2 * d_ + e), x, k1, k2, k3, k4)

        s0 = jnp.zeros(mv.dofs()).at[idx].set(q0)
        _, qs = jax.lax.scan(lambda x, _: (y := jax.lax.fori_loop(0, per, rk4, x), y[0]), (s0, jnp.zeros_like(s0)),
                             None, length=len(TS) - 1)
        return jnp.concatenate([s0[None], qs])[:, idx]

    return rollout


def _replace(obj, path: str, value):
    """``obj`` with the attribute at dotted ``path`` replaced (jaxsim's dataclasses are immutable pytrees)."""
    import dataclasses

    head, _, rest = path.partition(".")
    if rest:
        return dataclasses.replace(obj, **{head: _replace(getattr(obj, head), rest, value)})
    return dataclasses.replace(obj, **{head: value})


def jaxsim_step_rollout(text: str, ours, q0, per: int):
    """jaxsim's own ``step`` (RK4 integrator), ``per`` steps between saves: ``(q at TS, compile s, run s)``."""
    dt = SAVE_DT / per
    from jaxsim.api.model import IntegratorType

    peer = Jaxsim(text, ours, time_step=dt, integrator=IntegratorType.RungeKutta4)
    js, m, idx = peer.js, peer.m, peer.idx
    s0 = jnp.zeros(m.dofs()).at[idx].set(q0)

    @jax.jit
    def run(s0):
        d = js.data.JaxSimModelData.build(model=m, joint_positions=s0, velocity_representation=peer.repr)
        _, qs = jax.lax.scan(lambda d, _: (e := jax.lax.fori_loop(0, per, lambda i, d: js.model.step(m, d), d),
                                           e.joint_positions), d, None, length=len(TS) - 1)
        return jnp.concatenate([s0[None], qs])[:, idx]

    c, r, out = compile_and_time(lambda: run(s0), block=jax.block_until_ready)
    return np.asarray(out), c, r


def drake_rollout(drake: Drake, q0, scheme: str, *, accuracy=None, step=None):
    from pydrake.systems.analysis import ResetIntegratorFromFlags, Simulator

    def once():
        sim = Simulator(drake.plant)
        ctx = sim.get_mutable_context()
        x = np.zeros(drake.nq)
        x[drake.iq] = q0
        drake.plant.SetPositions(ctx, x)
        drake.plant.SetVelocities(ctx, np.zeros(drake.nv))
        integ = ResetIntegratorFromFlags(sim, scheme, step if step is not None else 0.1)
        if accuracy is not None:
            integ.set_target_accuracy(accuracy)
        else:
            integ.set_fixed_step_mode(True)
        sim.Initialize()
        out = [drake.plant.GetPositions(ctx)[drake.iq]]
        for t in TS[1:]:
            sim.AdvanceTo(t)
            out.append(drake.plant.GetPositions(ctx)[drake.iq])
        return np.asarray(out), integ.get_num_steps_taken()

    out, steps = once()
    return out, median_time(once, number=1, repeat=3), steps


def rollout_rows() -> tuple[list[dict], dict]:
    _quiet()
    text, ours, q0 = rollout_scene()
    q0j = jnp.asarray(q0)
    ref = simulate(forward_dynamics, ours, q0, np.zeros_like(q0), 0.0, T_END, saveat_ts=TS, max_steps=200_000, **REF)
    q_ref = np.asarray(ref.q)
    rows, best = [], {}

    def add(peer, method, setting, err, run_s, compile_s=None, steps=None):
        r = dict(peer=peer, method=method, setting=setting, error=err, run_s=run_s, compile_s=compile_s,
                 steps=steps)
        rows.append(r)
        print(f"  {peer:7s} {method:34s} {setting:9.2e} err {err:8.2e} run {run_s * 1e3:9.1f} ms"
              f"{'' if compile_s is None else f'  compile {compile_s:5.1f} s'}", flush=True)
        if err <= TARGET and method not in best:
            best[method] = r
        return err <= TARGET

    block = jax.block_until_ready
    for solver in ("tsit5", "dopri5"):
        run = ours_rollout(solver)
        c = None
        for rtol in OURS_RTOLS:
            c_now, t, out = compile_and_time(lambda: run(ours, q0j, rtol), block=block)
            c = c_now if c is None else c  # the first setting compiles, the others reuse it
            if add("ours", f"simulate {solver}", rtol, error(out[0], q_ref), t, c, int(out[1])):
                break
    for per in JAXSIM_STEP_PER_SAVE:
        out, c, t = jaxsim_step_rollout(text, ours, q0, per)
        add("jaxsim", "model.step RK4 (friction held per step)", SAVE_DT / per, error(out, q_ref), t, c,
            per * (len(TS) - 1))
    peer = Jaxsim(text, ours)
    with jax.numpy_rank_promotion("allow"):
        rk4 = jax.jit(jaxsim_stagewise(peer))
        viscous = jnp.full(peer.m.dofs(), FV)
        c = None
        for per in JAXSIM_RK4_PER_SAVE:
            c_now, t, out = compile_and_time(lambda: rk4(viscous, q0j, SAVE_DT / per, per), block=block)
            c = c_now if c is None else c
            if add("jaxsim", "RK4 stage-wise (forward_dynamics_aba)", SAVE_DT / per, error(out, q_ref), t, c,
                   per * (len(TS) - 1)):
                break
    drake = Drake(text, ours)
    for scheme, accuracies in DRAKE_ACCURACIES.items():
        for acc in accuracies:
            out, t, steps = drake_rollout(drake, q0, scheme, accuracy=acc)
            if add("drake", f"Simulator {scheme} (error-controlled)", acc, error(out, q_ref), t, None, steps):
                break
    for per in DRAKE_RK5_PER_SAVE:
        out, t, steps = drake_rollout(drake, q0, "runge_kutta5", step=SAVE_DT / per)
        if add("drake", "Simulator runge_kutta5 (fixed step)", SAVE_DT / per, error(out, q_ref), t, None, steps):
            break
    return rows, dict(best=best, text=text, ours=ours, q0=q0, q_ref=q_ref, peer=peer, reference_steps=int(ref.steps))


# ----------------------------------------------------------------------------------------------------------------
# Gradients and batches at the target-meeting settings


def gradient_and_batch_rows(scene: dict) -> list[dict]:
    ours, q0, peer, best = scene["ours"], jnp.asarray(scene["q0"]), scene["peer"], scene["best"]
    rows = []
    link = ours.link_names.index(_child_of(ours, "LJ1"))
    rtol = best["simulate tsit5"]["setting"]
    dt = best.get("RK4 stage-wise (forward_dynamics_aba)", {}).get("setting")
    block = jax.block_until_ready

    def ours_loss(scale):
        model = ours.with_params(inertia=ours.inertia.at[link].multiply(scale))
        s = simulate(forward_dynamics, model, q0, jnp.zeros_like(q0), 0.0, T_END, solver="tsit5", rtol=rtol,
                     atol=rtol / 100, saveat_ts=jnp.asarray(TS), max_steps=100_000)
        return jnp.sum(s.q ** 2)

    one = jnp.asarray(1.0)
    g = jax.jit(jax.grad(ours_loss))
    c, t, g_ours = compile_and_time(lambda: g(one), block=block)
    rows.append(dict(peer="ours", kind="gradient", setting=rtol, run_s=t, compile_s=c, value=float(g_ours)))
    if dt is not None:
        per = int(round(SAVE_DT / dt))
        jlink = list(peer.m.link_names()).index(_child_of(ours, "LJ1"))
        viscous = jnp.full(peer.m.dofs(), FV)

        def peer_loss(scale):
            lp = peer.m.kin_dyn_parameters.link_parameters
            lp = _replace(lp, "mass", lp.mass.at[jlink].multiply(scale))
            lp = _replace(lp, "inertia_elements", lp.inertia_elements.at[jlink].multiply(scale))
            m2 = _replace(peer.m, "kin_dyn_parameters.link_parameters", lp)
            return jnp.sum(jaxsim_stagewise(peer, m2)(viscous, q0, dt, per) ** 2)

        with jax.numpy_rank_promotion("allow"):
            gp = jax.jit(jax.grad(peer_loss))
            c, t, g_peer = compile_and_time(lambda: gp(one), block=block)
            rows.append(dict(peer="jaxsim", kind="gradient", setting=dt, run_s=t, compile_s=c, value=float(g_peer)))
    # batched rollouts over damping
    damping = jnp.linspace(0.5, 2.0, MEMBERS)

    def ours_member(c_):
        model = ours.with_params(viscous=jnp.full(ours.nv, c_))
        return simulate(forward_dynamics, model, q0, jnp.zeros_like(q0), 0.0, T_END, solver="tsit5", rtol=rtol,
                        atol=rtol / 100, saveat_ts=jnp.asarray(TS), max_steps=100_000).q

    batched = sharded_vmap(ours_member, chunk=4, threads=1)  # one thread, as the peer's one program
    c, t, _ = compile_and_time(lambda: batched(damping), block=block)
    rows.append(dict(peer="ours", kind=f"{MEMBERS} rollouts", setting=rtol, run_s=t, compile_s=c,
                     value=MEMBERS / t))
    if dt is not None:
        rk4 = jaxsim_stagewise(peer)
        with jax.numpy_rank_promotion("allow"):
            vb = jax.jit(jax.vmap(lambda c_: rk4(jnp.full(peer.m.dofs(), c_), q0, dt, per)))
            c, t, _ = compile_and_time(lambda: vb(damping), block=block)
        rows.append(dict(peer="jaxsim", kind=f"{MEMBERS} rollouts", setting=dt, run_s=t, compile_s=c,
                         value=MEMBERS / t))
    for r in rows:
        print(f"  {r['peer']:7s} {r['kind']:14s} {r['run_s'] * 1e3:9.1f} ms  compile {r['compile_s']:5.1f} s", flush=True)
    return rows


def _child_of(model, joint: str) -> str:
    return model.link_names[model.joint_names.index(joint)]


# ----------------------------------------------------------------------------------------------------------------


def run() -> dict:
    started = time.perf_counter()
    versions = {p: metadata.version(p) for p in ("jaxsim", "drake")}
    print("forward dynamics", flush=True)
    forward = forward_rows("Krang", urdf_path("krang_fixed_base_2018.urdf"), False)
    forward += forward_rows("Solo-12", solo12_path(), True)
    print("rollouts", flush=True)
    rollouts, scene = rollout_rows()
    print("gradients and batches", flush=True)
    extra = gradient_and_batch_rows(scene)
    best = {m: dict(r) for m, r in scene["best"].items()}
    return dict(name=NAME, environment=environment(), peer_versions=versions, target=TARGET, t_end=T_END,
                reference=dict(REF, steps=scene["reference_steps"]), forward=forward, rollouts=rollouts,
                best=best, gradients_and_batches=extra, elapsed_s=time.perf_counter() - started)


def write(res: dict) -> None:
    rows = ([dict(section="forward", **r) for r in res["forward"]]
            + [dict(section="rollout", **r) for r in res["rollouts"]]
            + [dict(section="gradient/batch", **r) for r in res["gradients_and_batches"]])
    keys = list(dict.fromkeys(k for r in rows for k in r))
    write_results(NAME, res, [{k: r.get(k, "") for k in keys} for r in rows])
    fig, ax = pyplot().subplots(figsize=(7.5, 4.8))
    for method in dict.fromkeys(r["method"] for r in res["rollouts"]):
        pts = [(r["run_s"], r["error"], r["peer"]) for r in res["rollouts"] if r["method"] == method]
        ax.loglog([p[0] for p in pts], [p[1] for p in pts], "o-", label=f"{pts[0][2]}: {method}")
    ax.axhline(res["target"], color="k", lw=0.8, ls="--")
    ax.set(xlabel="run time (s)", ylabel="max |q - q_ref| over 2 s (rad)")
    ax.legend(fontsize=7)
    save_figure(fig, NAME, dpi=120, tight=True,
                title=f"Krang, damped 2 s fall: ours, jaxsim, Drake\n{machine(res['environment'])}")


def _forward_cell(r: dict) -> str:
    how = f" {r['how']}" if r["how"] else ""
    comp = "" if r["compile_s"] is None else f", compile {r['compile_s']:.1f} s"
    return f"{r['us_per_state']:.2f}{how}{comp}"


def markdown(res: dict) -> str:
    env = res["environment"]
    out = [f"### Peers: jaxsim {res['peer_versions']['jaxsim']} and Drake {res['peer_versions']['drake']} "
           f"(`peers`, {env['date'][:10]})", "",
           f"{machine(env)}. Accuracy of the quantities timed: tests/tree/test_peers.py.", "",
           "Forward dynamics, µs per state (ratio: the peer's time over ours in the same row kind; compile beside):",
           "", "| robot | row | ours | jaxsim | Drake |", "|---|---|---|---|---|"]
    for robot in dict.fromkeys(r["robot"] for r in res["forward"]):
        for kind in dict.fromkeys(r["kind"] for r in res["forward"] if r["robot"] == robot):
            mine = [r for r in res["forward"] if r["robot"] == robot and r["kind"] == kind]
            best = {p: min(r["us_per_state"] for r in mine if r["peer"] == p) for p in {r["peer"] for r in mine}}

            def cell(p):
                if p not in best:
                    return "—"
                text = "; ".join(_forward_cell(r) for r in mine if r["peer"] == p)
                return text + ("" if p == "ours" else f" (**{best[p] / best['ours']:.2f}×**)")

            out.append(f"| {robot} | {kind} | {cell('ours')} | {cell('jaxsim')} | {cell('drake')} |")
    ours_best = min((r for m, r in res["best"].items() if r["peer"] == "ours"), key=lambda r: r["run_s"])
    out += ["", f"Rollouts, Krang damped 2 s, first setting of each sweep meeting {res['target']:.0e} rad "
            "(ratio: its time over ours' best):", "",
            "| peer | method | setting | error (rad) | run | compile | ratio |", "|---|---|---|---|---|---|---|"]
    for method in dict.fromkeys(r["method"] for r in res["rollouts"]):
        r = res["best"].get(method)
        if r is None:
            last = [x for x in res["rollouts"] if x["method"] == method][-1]
            comp = "—" if last["compile_s"] is None else f"{last['compile_s']:.1f} s"
            out.append(f"| {last['peer']} | {method} | not met: finest {last['setting']:.1e} | {last['error']:.1e} | "
                       f"{last['run_s'] * 1e3:.0f} ms | {comp} | — |")
            continue
        comp = "—" if r["compile_s"] is None else f"{r['compile_s']:.1f} s"
        out.append(f"| {r['peer']} | {method} | {r['setting']:.1e} | {r['error']:.1e} | {r['run_s'] * 1e3:.1f} ms | "
                   f"{comp} | {r['run_s'] / ours_best['run_s']:.2f}× |")
    out += ["", "Gradient of the rollout loss w.r.t. a link's density, and 64 rollouts (damping 0.5–2), at the settings "
            "above:", "", "| peer | row | run | compile | |", "|---|---|---|---|---|"]
    for r in res["gradients_and_batches"]:
        extra = f"{r['value']:.1f} rollouts/s" if "rollouts" in r["kind"] else f"dL/ds = {r['value']:.6g}"
        out.append(f"| {r['peer']} | {r['kind']} | {r['run_s'] * 1e3:.1f} ms | {r['compile_s']:.1f} s | {extra} |")
    return "\n".join(out) + "\n"


def main() -> dict:
    return report(run, write, markdown, elapsed=True)


if __name__ == "__main__":
    main()
