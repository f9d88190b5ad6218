"""The MuJoCo C twin of the full vehicle (:func:`particlesim.scenes.vehicle.full_vehicle`), read from the built
:class:`~particlesim.mechanism.Mechanism` (its bodies' masses, centres of mass and inertias, its points at ``q0``,
its springs' and tyres' parameters), so that it follows ``with_params`` and any source of the same named bodies.

* tree: chassis (free joint) -> per corner XX: ``lower arm XX`` (hinge about the chassis pivot axis
  ``chassis lca_f XX`` -> ``chassis lca_b XX``, at the front pivot) -> ``upright XX`` (ball at ``lca_u XX``); chassis
  -> ``upper arm XX`` (hinge about ``chassis uca_f XX`` -> ``chassis uca_b XX``). Every MuJoCo body frame is our body
  frame at ``q0`` (:func:`~particlesim.mechanism.body_poses`), with our centre of mass and full inertia tensor, so
  ``qpos0`` is the assembly ``q0``;
* loops: the upper ball joint is an equality ``connect`` (``uca_u XX`` on the upper arm = on the upright); the tie
  rod is a spatial tendon ``tierod_u XX`` - ``chassis tierod XX`` whose length an equality holds at its value at
  ``q0``. Both are soft in MuJoCo: stiffened as far as it allows (``solref`` time constant 2 dt, the least
  MuJoCo accepts, and ``solimp`` 0.9999, its cap; docs/twins.md);
* every spring-damper of ``mech.topo.spring_names`` (springs and shocks) is a spatial tendon with stiffness, damping
  and spring length: the same law (force along the line, linear in length and length rate);
* the one-sided tyres are not MuJoCo elements: the compiled ``mjcb_passive`` of :mod:`.callbacks` evaluates our law
  at every RK4 stage, so :func:`twin_rollout` runs MuJoCo's native loop (``mujoco.rollout``). A tyre's road
  (``full_vehicle(roads=...)``: ``Bump``, ``SineSum`` and ``Sum`` of those from :mod:`particlesim.scenes.roads`) is
  evaluated there in closed form at the stage time ``d->time``, from the road's own arrays, its time derivative
  entering the damping as in :func:`particlesim.mechanism.forces.point_forces` (gap ``z - ground - radius - h(t)``,
  rate ``v_z - h'(t)``).

The MJX twin (:func:`mjx_twin_rollout`) is the same model run by MJX: the RK4 loop of :mod:`.mjx` around MJX's
forward stages, the tyres' law (and their roads, the road Modules themselves, their rates by ``jax.jvp``) evaluated
in JAX at every stage before MJX's velocity stage. MJX 3.17 omits the ``J̇ v`` term of ``connect`` rows (docs/twins.md),
so its ball joints sit further open than MuJoCo C's at the same step.

Not represented (refused by name): any other road (a Python function, a road of the point ``ground(t, p)``), a
tyre force applied away from its measuring point, applied loads, drivers, any force element other than
spring-dampers and tyres (rotational springs, and any later kind), bodies other than the chassis and the three per
corner. The twin starts from rest at ``t = 0`` (MuJoCo's velocities of our particle velocities are not mapped),
from any configuration on the constraints: the assembly ``q0`` or a static equilibrium.
"""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

from . import callbacks

__all__ = ["twin_xml", "twin_model", "install_callback", "twin_rollout", "mjx_twin_rollout", "attitude", "corners",
           "solref_tc"]

_NAMED = {"particle_names", "body_names", "point_names", "spring_names", "tyre_names"}  # what the twin represents
_SOLIMP = "0.9999 0.9999 0.001 0.5 2"
_STATE = mujoco.mjtState.mjSTATE_FULLPHYSICS


def solref_tc(timestep: float) -> float:
    """The loops' ``solref`` time constant at ``timestep``: the smallest MuJoCo accepts (2 dt)."""
    return 2.0 * timestep


def _v(x) -> str:
    return " ".join(f"{float(c):.17g}" for c in np.ravel(x))


def corners(mech) -> list[str]:
    """The corner labels (``"FL"``...) of ``mech``, refusing any body the twin has no place for."""
    names = mech.topo.body_names
    found = [n.removeprefix("lower arm ") for n in names if n.startswith("lower arm ")]
    expected = {"chassis"} | {f"{kind} {c}" for c in found for kind in ("lower arm", "upper arm", "upright")}
    if set(names) != expected:
        raise ValueError(f"vehicle twin: bodies {sorted(set(names) ^ expected)} are missing or have no place in the "
                         f"twin (a chassis and 'lower arm XX', 'upper arm XX', 'upright XX' per corner XX)")
    return found


def _roads(mech) -> list:
    """Per tyre its road (``None``: the plane), refusing any the compiled callback cannot evaluate, by name."""
    topo = mech.topo
    if not topo.tyre_road_args:
        return [None] * len(topo.tyre_names)
    for name, arity, road in zip(topo.tyre_names, topo.tyre_road_args, mech.tyre_roads):
        if arity == 2:
            raise NotImplementedError(f"vehicle twin: tyre '{name}' runs on a road of the point, ground(t, p); the "
                                      f"twin's tyre callback evaluates roads of time only")
        if arity == 1:
            try:
                callbacks.road_terms(road)
            except (NotImplementedError, ValueError) as e:
                raise NotImplementedError(f"vehicle twin: tyre '{name}': {e}") from None
    return [road if arity else None for arity, road in zip(topo.tyre_road_args, mech.tyre_roads)]


def _refuse_unsupported(mech) -> None:
    topo = mech.topo
    _roads(mech)
    if topo.tyre_apply and tuple(topo.tyre_apply) != tuple(topo.tyre_points):
        raise NotImplementedError("vehicle twin: a tyre force applied away from its measuring point is not supported")
    if len(topo.tyre_names) > callbacks.MAX_TYRES:
        raise NotImplementedError(f"vehicle twin: at most {callbacks.MAX_TYRES} tyres, got {len(topo.tyre_names)}")
    if mech.applied:
        raise NotImplementedError(f"vehicle twin: applied loads {[a.name for a in mech.applied]} are not represented")
    if len(topo.drive):
        raise NotImplementedError(f"vehicle twin: drivers {list(topo.drive.labels)} are not represented")
    for field in dataclasses.fields(topo):  # force elements other than springs and tyres (rotational, bushings...)
        names = getattr(topo, field.name)
        if field.name.endswith("_names") and field.name not in _NAMED and names:
            raise NotImplementedError(f"vehicle twin: {field.name.removesuffix('_names')} elements {list(names)} "
                                      f"are not represented")


class _Frames:
    """Our body frames and points at ``q0`` (numpy): world ``(R, origin)`` per body, world position per point."""

    def __init__(self, mech, q0):
        from ..mechanism import body_poses

        rot, org = body_poses(mech, q0)
        self.mech = mech
        self.rot, self.org = np.asarray(rot, float), np.asarray(org, float)
        self.pts = np.asarray(mech.point_positions(mech.all_positions(q0)), float)

    def point(self, name: str) -> np.ndarray:
        return self.pts[self.mech.point_index(name)]

    def local(self, body: str, p) -> np.ndarray:
        """World point ``p`` in ``body``'s frame."""
        b = self.mech.body_index(body)
        return self.rot[b].T @ (np.asarray(p) - self.org[b])

    def relative(self, parent: str, child: str) -> str:
        """``pos``/``quat`` attributes of ``child``'s frame in ``parent``'s."""
        p, c = self.mech.body_index(parent), self.mech.body_index(child)
        quat = np.zeros(4)
        mujoco.mju_mat2Quat(quat, (self.rot[p].T @ self.rot[c]).ravel())
        return f'pos="{_v(self.rot[p].T @ (self.org[c] - self.org[p]))}" quat="{_v(quat)}"'

    def inertial(self, body: str) -> str:
        b = self.mech.body_index(body)
        i = np.asarray(self.mech.body_inertia[b], float)
        full = (i[0, 0], i[1, 1], i[2, 2], i[0, 1], i[0, 2], i[1, 2])
        return (f'<inertial pos="{_v(self.mech.body_com[b])}" mass="{float(self.mech.body_mass[b])!r}" '
                f'fullinertia="{_v(full)}"/>')

    def home(self, k: int) -> str:
        """The body a point ``k`` rides on (a shared particle: the first body holding it)."""
        b = self.mech.topo.point_body[k]
        if b < 0:
            b = next(i for i, ps in enumerate(self.mech.topo.body_particles) if k in ps)
        return self.mech.topo.body_names[b]


def _element_sites(fr: _Frames) -> dict[str, list[str]]:
    """A site of every spring-damper end and tyre point (named as the point), grouped by their body."""
    topo = fr.mech.topo
    needed = sorted({k for ab in topo.spring_points for k in ab} | set(topo.tyre_points))
    sites: dict[str, list[str]] = {}
    for k in needed:
        body = fr.home(k)
        site = f'<site name="{topo.point_names[k]}" pos="{_v(fr.local(body, fr.pts[k]))}"/>'
        sites.setdefault(body, []).append(site)
    return sites


def twin_xml(mech, q0, timestep: float = 1e-4, tc: float | None = None) -> str:
    """MJCF text of the twin of ``mech`` assembled at ``q0`` (gravity ``mech.gravity``, RK4, no contacts). ``tc``:
    the loops' ``solref`` time constant (default :func:`solref_tc`)."""
    _refuse_unsupported(mech)
    cs = corners(mech)
    fr = _Frames(mech, q0)
    sites = _element_sites(fr)

    def body_sites(body, extra=()):
        return "".join(sites.get(body, [])) + "".join(
            f'<site name="{name}" pos="{_v(fr.local(body, fr.point(pt)))}"/>' for name, pt in extra)

    def hinge(arm, prefix, c):
        f, b = fr.point(f"chassis {prefix}_f {c}"), fr.point(f"chassis {prefix}_b {c}")
        axis = fr.rot[mech.body_index(arm)].T @ (f - b)
        return (f'<joint name="{arm} hinge" type="hinge" pos="{_v(fr.local(arm, f))}" '
                f'axis="{_v(axis / np.linalg.norm(axis))}"/>')

    arms, loops, rods = [], [], []
    sol = f'solref="{float(solref_tc(timestep) if tc is None else tc)!r} 1" solimp="{_SOLIMP}"'
    for c in cs:
        la, ua, up = f"lower arm {c}", f"upper arm {c}", f"upright {c}"
        arms.append(f"""
      <body name="{la}" {fr.relative('chassis', la)}>
        {hinge(la, 'lca', c)}{fr.inertial(la)}{body_sites(la)}
        <body name="{up}" {fr.relative(la, up)}>
          <joint name="{up} ball" type="ball" pos="{_v(fr.local(up, fr.point(f'lca_u {c}')))}"/>
          {fr.inertial(up)}{body_sites(up, [(f'tie rod {c} upright', f'tierod_u {c}')])}
        </body>
      </body>
      <body name="{ua}" {fr.relative('chassis', ua)}>
        {hinge(ua, 'uca', c)}{fr.inertial(ua)}{body_sites(ua)}
      </body>""")
        loops.append(f'<connect name="upper ball {c}" body1="{ua}" body2="{up}" '
                     f'anchor="{_v(fr.local(ua, fr.point(f"uca_u {c}")))}" {sol}/>'
                     f'<tendon name="tie rod {c}" tendon1="tie rod {c}" polycoef="0 0 0 0 0" {sol}/>')
        rods.append(f'<spatial name="tie rod {c}"><site site="tie rod {c} upright"/>'
                    f'<site site="tie rod {c} chassis"/></spatial>')
    chassis_sites = body_sites("chassis", [(f"tie rod {c} chassis", f"chassis tierod {c}") for c in cs])
    springs = "".join(
        f'<spatial name="{name}" stiffness="{float(k)!r}" damping="{float(d)!r}" springlength="{float(l0)!r}">'
        f'<site site="{mech.topo.point_names[a]}"/><site site="{mech.topo.point_names[b]}"/></spatial>'
        for name, (a, b), k, d, l0 in zip(mech.topo.spring_names, mech.topo.spring_points, mech.spring_stiffness,
                                          mech.spring_damping, mech.spring_free_length))
    return f"""
<mujoco model="full vehicle twin">
  <compiler angle="radian" balanceinertia="false" inertiafromgeom="false"/>
  <option timestep="{float(timestep)!r}" integrator="RK4" gravity="{_v(mech.gravity)}">
    <flag contact="disable"/>
  </option>
  <worldbody>
    <body name="chassis" pos="{_v(fr.org[mech.body_index('chassis')])}" quat="{_v(_quat(fr, 'chassis'))}">
      <freejoint name="chassis"/>
      {fr.inertial('chassis')}{chassis_sites}{''.join(arms)}
    </body>
  </worldbody>
  <tendon>{springs}{''.join(rods)}</tendon>
  <equality>{''.join(loops)}</equality>
</mujoco>"""


def _quat(fr: _Frames, body: str) -> np.ndarray:
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, fr.rot[fr.mech.body_index(body)].ravel())
    return quat


def twin_model(mech, q0, timestep: float = 1e-4, tc: float | None = None) -> mujoco.MjModel:
    """The compiled twin of ``mech`` at ``q0`` (:func:`twin_xml`); run it with :func:`install_callback` done."""
    return mujoco.MjModel.from_xml_string(twin_xml(mech, q0, timestep, tc))


def install_callback(m: mujoco.MjModel, mech) -> None:
    """Install the compiled tyre callback (``mjcb_passive``, process-global) for the twin ``m`` of ``mech``: its
    tyres and their roads. Remove it with :func:`particlesim.twins.callbacks.uninstall`."""
    callbacks.install_tyres(_tyres(m, mech), _roads(mech))


def _tyres(m: mujoco.MjModel, mech) -> list:
    """The compiled callback's tyres: ``(site, normal, ground, radius, stiffness, damping)`` per tyre of ``mech``."""
    site = lambda k: mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SITE, mech.topo.point_names[k])  # noqa: E731
    return [(site(k), n, float(g), float(r), float(s), float(c))
            for k, n, g, r, s, c in zip(mech.topo.tyre_points, mech.topo.tyre_normals, mech.tyre_ground,
                                        mech.tyre_radius, mech.tyre_stiffness, mech.tyre_damping)]


def attitude(rot, rot0) -> tuple[np.ndarray, np.ndarray]:
    """``(pitch, roll)`` [rad] of the rotations ``rot`` (..., 3, 3) relative to ``rot0`` (3, 3), world axes (x
    forward, y left, z up): ``rot rot0^T = Rz(yaw) Ry(pitch) Rx(roll)``."""
    r = np.asarray(rot) @ np.asarray(rot0).T
    return -np.arcsin(np.clip(r[..., 2, 0], -1.0, 1.0)), np.arctan2(r[..., 2, 1], r[..., 2, 2])


def _save_grid(t_end: float, timestep: float, save_dt: float) -> tuple[int, int]:
    """``(steps per save, saves after t = 0)``, refusing a ``save_dt`` that is no multiple of ``timestep`` or does
    not divide ``t_end``."""
    per, n_save = (int(round(x)) for x in (save_dt / timestep, t_end / save_dt))
    if abs(per * timestep - save_dt) > 1e-9 * save_dt or abs(n_save * save_dt - t_end) > 1e-9 * t_end:
        raise ValueError(f"save_dt {save_dt} must be a multiple of timestep {timestep} and divide t_end {t_end}")
    return per, n_save


def twin_rollout(mech, q0, t_end: float, timestep: float = 1e-4, *, save_dt: float = 0.01,
                 tc: float | None = None) -> dict[str, np.ndarray]:
    """Release the twin from rest at ``q0`` (from :func:`~particlesim.mechanism.static_equilibrium` too: any
    configuration on the constraints) at ``t = 0`` and run it to ``t_end`` with MuJoCo C RK4 in ``mujoco.rollout``'s
    native loop (the compiled tyre callback installed for the run and removed afterwards). Returns, every
    ``save_dt`` (a multiple of ``timestep`` dividing ``t_end``): ``t``; ``heave``, the chassis centre-of-mass height
    [m]; ``pitch`` and ``roll`` of the chassis since ``q0`` [rad] (:func:`attitude`); the loops' residuals per
    corner (:func:`corners` order), ``ball`` = |upper ball joint on the arm - on the upright| [m] and ``tie_rod`` =
    |tie-rod length - its length at q0| [m], each ``(T, corners)``."""
    per, n_save = _save_grid(t_end, timestep, save_dt)
    m = twin_model(mech, q0, timestep, tc)
    d = mujoco.MjData(m)
    install_callback(m, mech)
    try:
        mujoco.mj_forward(m, d)
        state0 = np.zeros((1, mujoco.mj_stateSize(m, _STATE)))
        mujoco.mj_getState(m, d, state0[0], _STATE)
        states, _ = mj_rollout.Rollout(nthread=0).rollout(m, d, state0, nstep=per * n_save)
    finally:
        callbacks.uninstall()
    return _observe(m, np.concatenate([state0, states[0, per - 1::per]]), corners(mech), per * timestep)


def _observe(m: mujoco.MjModel, states: np.ndarray, cs: list[str], every: float) -> dict[str, np.ndarray]:
    d = mujoco.MjData(m)
    name = lambda kind, n: mujoco.mj_name2id(m, kind, n)  # noqa: E731
    chassis = name(mujoco.mjtObj.mjOBJ_BODY, "chassis")
    balls = [name(mujoco.mjtObj.mjOBJ_EQUALITY, f"upper ball {c}") for c in cs]
    rods = [name(mujoco.mjtObj.mjOBJ_TENDON, f"tie rod {c}") for c in cs]
    heave, rot, ball, rod = [], [], [], []
    for row in states:
        mujoco.mj_setState(m, d, row, _STATE)
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        mujoco.mj_tendon(m, d)
        heave.append(d.xipos[chassis, 2])
        rot.append(d.xmat[chassis].reshape(3, 3).copy())
        ball.append([_connect_residual(m, d, e) for e in balls])
        rod.append([abs(d.ten_length[t] - m.tendon_length0[t]) for t in rods])
    rot = np.asarray(rot)
    pitch, roll = attitude(rot, rot[0])
    return {"t": every * np.arange(len(states)), "heave": np.asarray(heave), "pitch": pitch, "roll": roll,
            "ball": np.asarray(ball), "tie_rod": np.asarray(rod)}


def _connect_residual(m: mujoco.MjModel, d: mujoco.MjData, e: int) -> float:
    b1, b2 = int(m.eq_obj1id[e]), int(m.eq_obj2id[e])
    p1 = d.xpos[b1] + d.xmat[b1].reshape(3, 3) @ m.eq_data[e, 0:3]
    p2 = d.xpos[b2] + d.xmat[b2].reshape(3, 3) @ m.eq_data[e, 3:6]
    return float(np.linalg.norm(p1 - p2))


def mjx_twin_rollout(mech, q0, t_end: float, timestep: float = 5e-4, *, save_dt: float = 0.01,
                     tc: float | None = None) -> dict[str, np.ndarray]:
    """:func:`twin_rollout` run by MJX instead of MuJoCo C (same model, same RK4 tableau, same outputs): released
    from rest at ``q0`` at ``t = 0``, the tyres (and roads) evaluated in JAX at every RK4 stage. Compiled per call
    (one step size per comparison; MJX's compile dominates)."""
    import jax
    import jax.numpy as jnp
    from mujoco import mjx

    from . import mjx as rk4

    per, n_save = _save_grid(t_end, timestep, save_dt)
    m = twin_model(mech, q0, timestep, tc)
    cs = corners(mech)
    name = lambda kind, n: mujoco.mj_name2id(m, kind, n)  # noqa: E731
    sites = [name(mujoco.mjtObj.mjOBJ_SITE, mech.topo.point_names[k]) for k in mech.topo.tyre_points]
    bodies = [int(m.site_bodyid[s]) for s in sites]
    normal = jnp.asarray(mech.topo.tyre_normals, float)
    level = jnp.asarray(mech.tyre_ground) + jnp.asarray(mech.tyre_radius)
    stiffness, damping = jnp.asarray(mech.tyre_stiffness), jnp.asarray(mech.tyre_damping)
    roads = _roads(mech)

    def road(t):
        """Heights and rates of the roads under the tyres at ``t`` (zeros for the plane)."""
        one = lambda fn: jax.jvp(fn, (t,), (jnp.ones_like(t),)) if fn is not None else (0.0 * t, 0.0 * t)  # noqa
        h, rate = zip(*(one(fn) for fn in roads))
        return jnp.stack(h), jnp.stack(rate)

    def forward(mx, d):
        d = mjx.fwd_position(mx, d)
        h, h_rate = road(d.time)
        jn = jnp.stack([mjx.jac(mx, d, d.site_xpos[s], b)[0] @ normal[i] for i, (s, b) in enumerate(zip(sites, bodies))])
        gap = jnp.stack([d.site_xpos[s] @ normal[i] for i, s in enumerate(sites)]) - level - h
        f = jnp.where(gap < 0.0, -(stiffness * gap + damping * (jn @ d.qvel - h_rate)), 0.0)
        d = d.replace(qfrc_applied=jn.T @ f)
        d = mjx.fwd_velocity(mx, d)
        d = mjx.fwd_actuation(mx, d)
        d = mjx.fwd_acceleration(mx, d)
        return mjx.solve(mx, d)

    chassis = name(mujoco.mjtObj.mjOBJ_BODY, "chassis")
    balls = [rk4.connect_residual(m, name(mujoco.mjtObj.mjOBJ_EQUALITY, f"upper ball {c}")) for c in cs]
    rod_sites = [(name(mujoco.mjtObj.mjOBJ_SITE, f"tie rod {c} upright"), name(mujoco.mjtObj.mjOBJ_SITE,
                                                                             f"tie rod {c} chassis")) for c in cs]
    rod_length0 = jnp.asarray([m.tendon_length0[name(mujoco.mjtObj.mjOBJ_TENDON, f"tie rod {c}")] for c in cs])

    def observe(mx, d):
        k = mjx.kinematics(mx, d)
        rods = jnp.stack([jnp.linalg.norm(k.site_xpos[a] - k.site_xpos[b]) for a, b in rod_sites])
        return {"heave": k.xipos[chassis, 2], "rot": k.xmat[chassis], "ball": jnp.stack([f(k) for f in balls]),
                "tie_rod": jnp.abs(rods - rod_length0)}

    mx = mjx.put_model(m)
    out = jax.device_get(rk4.rk4_rollout(m, n_save + 1, forward, observe)(mx, rk4.initial_data(m, mx), per))
    pitch, roll = attitude(out["rot"], out["rot"][0])
    return {"t": per * timestep * np.arange(n_save + 1), "heave": np.asarray(out["heave"]), "pitch": pitch,
            "roll": roll, "ball": np.asarray(out["ball"]), "tie_rod": np.asarray(out["tie_rod"])}
