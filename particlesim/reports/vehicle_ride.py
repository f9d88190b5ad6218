"""Report: the full vehicle on a four-post rig (a ride study).

The car of :func:`particlesim.scenes.vehicle.full_vehicle` (HMMWV corners from Chrono's JSON file, 10 degrees of
freedom; assumptions B1-B7 in that module) starts at rest (:func:`~particlesim.mechanism.static_equilibrium`) on
four posts (:mod:`particlesim.scenes.roads`): a 5 cm raised-cosine bump under the front wheels, then an ISO 8608 class
C road at 15 m/s, the left and right tracks drawn from independent seeds and the rear wheels on the front ones' tracks
a wheelbase later. One rollout locates every tyre leaving and landing on its post (``events=True``). Written: the
posts, chassis heave, pitch, roll and vertical acceleration, and the four wheel loads against time (CSV, PNG), and a
JSON of the ride modes (:func:`~particlesim.mechanism.modes`), the RMS acceleration on the random road, the peak and
least wheel loads, the located switches, compile and run times.

The notebook ``notebooks/vehicle_ride.ipynb`` and ``tests/identify/test_vehicle_dampers.py`` build the same rig from
:func:`rig_roads` and :func:`ride_car` and read the chassis with :class:`ChassisMotion`.
"""

from __future__ import annotations

import csv
import json
import time
import warnings
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

__all__ = ["vehicle_ride_report", "rig_roads", "ride_car", "ChassisMotion", "wheel_loads", "ride_outputs",
           "mode_table", "plot_ride", "SPEED", "ROAD_CLASS", "SEEDS", "BUMP", "DURATION", "ISO_START", "ISO_FADE",
           "N_SAVE", "SOLVER", "STILL"]

SPEED = 15.0  # m/s
ROAD_CLASS = "C"
SEEDS = (1, 2)  # left and right tracks
BUMP = {"height": 0.05, "start": 0.3, "duration": 0.1}  # m, s, s: under the front wheels
ISO_START = 1.2  # s: the random road fades in from here ...
ISO_FADE = 0.5  # s: ... over this long
DURATION = 3.5  # s
N_SAVE = 701  # 200 Hz
#: The rig's rollout settings; ``max_step`` below the bump's duration, so that a step from rest cannot stride over it.
SOLVER = {"solver": "dopri8", "rtol": 1e-7, "atol": 1e-9, "max_step": 0.025}
STILL = 1e3  # s: a road starting this late leaves its post still during a run


def rig_roads(*, bump_height: float = BUMP["height"], bump_start: float = BUMP["start"],
              iso_start: float = ISO_START, speed: float = SPEED, road_class: str = ROAD_CLASS,
              seeds=SEEDS) -> dict:
    """The four posts, ``{corner: road}`` for ``full_vehicle(roads=...)``: front ``Sum(Bump, track)``, rear the
    same track a wheelbase later. Other values keep the structure, so every compiled rollout is reused:
    ``bump_height=0`` for the random road alone, ``bump_start=iso_start=STILL`` for posts that stay still."""
    from ..scenes import roads
    from ..scenes.vehicle import WHEELBASE

    bump = roads.Bump(bump_height, bump_start, BUMP["duration"])
    out = {}
    for side, seed in zip("LR", seeds):
        for axle, offset in (("F", 0.0), ("R", WHEELBASE)):
            track = roads.iso8608(road_class, speed, seed=seed, offset=offset, start=iso_start, fade=ISO_FADE)
            out[axle + side] = roads.Sum(bump, track) if axle == "F" else track
    return out


def ride_car(roads: dict | None = None, **options):
    """``(mech, q_rest)``: ``full_vehicle(roads=roads, **options)`` and its static equilibrium at t = 0 (the posts
    at zero). The HMMWV file's arm inertias are repaired as the scene documents (B3); its warning is not repeated."""
    from ..errors import InertiaWarning
    from ..mechanism import static_equilibrium
    from ..scenes.vehicle import full_vehicle

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InertiaWarning)
        mech, q0 = full_vehicle(roads=roads, **options)
    return mech, static_equilibrium(mech, jnp.asarray(q0)).q


class ChassisMotion(eqx.Module):
    """The chassis's motion from its rest: heave of its centre of mass [m], pitch and roll [rad] (Z-Y-X angles of
    its rotation since rest: pitch positive nose down, roll positive right side down), from three of its particles
    (:func:`particlesim.spatial.frame_from_points`), exact for the rigid chassis. It uses no linear solve, so it may
    be vmapped over long trajectories (``body_poses`` solves a batch of 4 x 4 systems per state)."""

    particles: tuple = eqx.field(static=True)  # three indices into mech.all_positions(q)
    rest_points: Float[Array, "3 3"]
    rest_frame: Float[Array, "3 3"]
    rest_com: Float[Array, "3"]

    def __init__(self, mech, q_rest):
        from ..mechanism import body_com_positions
        from ..spatial import frame_from_points

        self.particles = tuple(mech.index(f"chassis {k}") for k in range(3))
        self.rest_points = mech.all_positions(q_rest)[np.array(self.particles)]
        self.rest_frame = frame_from_points(*self.rest_points)
        self.rest_com = body_com_positions(mech, q_rest)[mech.body_index("chassis")]

    def rotation(self, mech, q) -> Float[Array, "3 3"]:
        """The chassis's rotation since rest (world axes)."""
        from ..spatial import frame_from_points

        return frame_from_points(*mech.all_positions(q)[np.array(self.particles)]) @ self.rest_frame.T

    def com(self, mech, q) -> Float[Array, "3"]:
        p0 = mech.all_positions(q)[self.particles[0]]
        return p0 + self.rotation(mech, q) @ (self.rest_com - self.rest_points[0])

    def __call__(self, mech, q) -> Float[Array, "3"]:
        """``(heave, pitch, roll)``."""
        r = self.rotation(mech, q)
        return jnp.stack([self.com(mech, q)[2] - self.rest_com[2], jnp.arcsin(-r[2, 0]), jnp.arctan2(r[2, 1], r[2, 2])])

    def vertical_acceleration(self, mech, q, qd, qdd) -> Float[Array, ""]:
        """The centre of mass's vertical acceleration [m/s^2] from the particles' accelerations ``qdd``."""
        def velocity(x, v):
            return jax.jvp(lambda y: self.com(mech, y)[2], (x,), (v,))[1]

        return jax.jvp(velocity, (q, qd), (qd, qdd))[1]


def wheel_loads(mech, t, q, qd) -> Float[Array, " 4"]:
    """Each tyre's vertical force on its wheel [N] (``mech.topo.tyre_names`` order): ``-(k d + c d')`` while the
    deflection ``d`` (:func:`particlesim.mechanism.forces.tyre_deflections`, the road at ``t`` included) is negative,
    else 0 (the library's tyre law; it has no public output for it)."""
    from ..mechanism.forces import tyre_deflections

    def deflection(x, tt):
        return tyre_deflections(mech, mech.point_positions(mech.all_positions(x)), tt)

    t = jnp.asarray(t, dtype=q.dtype)
    d, rate = jax.jvp(deflection, (q, t), (qd, jnp.ones_like(t)))
    return jnp.where(d < 0.0, -(mech.tyre_stiffness * d + mech.tyre_damping * rate), 0.0)


@eqx.filter_jit
def ride_outputs(mech, motion: ChassisMotion, ts, q, qd) -> dict:
    """Along a trajectory ``(ts, q, qd)``: ``motion`` (T, 3: heave, pitch, roll), vertical ``acceleration`` (T,) of
    the chassis, wheel ``loads`` (T, 4). One state at a time (``lax.map``): the constrained accelerations factorise
    a matrix per state, and a batch of them would be spread over XLA's thread pool."""
    from ..mechanism import accelerations

    def one(state):
        t, x, v = state
        a = accelerations(mech, t, x, v)
        return motion(mech, x), motion.vertical_acceleration(mech, x, v, a), wheel_loads(mech, t, x, v)

    pose, acc, loads = jax.lax.map(one, (ts, q, qd))
    return {"motion": pose, "acceleration": acc, "loads": loads}


def mode_table(mech, q_rest, md) -> list[dict]:
    """The ride modes of ``md = modes(mech, q_rest)`` with stiffness (the free ones skipped; ``index`` into ``md``),
    each named from its shape: the chassis motion with most of its kinetic energy (heave, pitch, roll), else the
    wheels' (an axle's hop, left and right together, or tramp, in opposition)."""
    from ..mechanism import body_velocities

    b = mech.body_index("chassis")
    m, inertia = float(mech.body_mass[b]), np.asarray(mech.body_inertia[b])
    wheels = [mech.free_slice(f"wheel {c}").start + 2 for c in ("FL", "FR", "RL", "RR")]
    rows = []
    for i in np.flatnonzero(np.asarray(md.frequency) > 0.0):
        shape = md.shapes[:, i]
        v, w = (np.asarray(x[b]) for x in body_velocities(mech, q_rest, shape))
        share = {"heave": m * v[2] ** 2, "pitch": inertia[1, 1] * w[1] ** 2, "roll": inertia[0, 0] * w[0] ** 2}
        name = max(share, key=share.get)
        if share[name] < 0.5:  # mass-normalised: the chassis carries under half of the mode's kinetic energy
            z = np.asarray(shape[np.array(wheels)])
            front, rear = np.abs(z[:2]).max(), np.abs(z[2:]).max()
            axle = "front axle" if front > 10 * rear else "rear axle" if rear > 10 * front else "axles"
            pair = z[:2] if front >= rear else z[2:]
            name = f"{axle} {'hop' if pair[0] * pair[1] > 0 else 'tramp'}"
        rows.append({"mode": name, "index": int(i), "frequency_Hz": float(md.frequency[i]),
                     "damped_frequency_Hz": float(md.damped_frequency[i]),
                     "damping_ratio": float(md.damping_ratio[i])})
    return rows


def vehicle_ride_report(out_dir: Path, *, progress: bool = True) -> dict:
    """Run the rig (module docstring), write ``vehicle_ride.csv``, ``.png``, ``.json`` in ``out_dir``; returns the
    JSON's figures."""
    from .. import _xla
    from ..mechanism import modes, simulate_mechanism

    out_dir.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    roads = rig_roads()
    mech, q = ride_car(roads)
    t_rest = time.perf_counter() - t0
    t0 = time.perf_counter()
    table = mode_table(mech, q, modes(mech, q))
    t_modes = time.perf_counter() - t0
    ts = np.linspace(0.0, DURATION, N_SAVE)
    run = _xla.TopJit(lambda m, x: simulate_mechanism(m, x, jnp.zeros_like(x), 0.0, DURATION, saveat_ts=ts,
                                                      events=True, progress=progress, **SOLVER))
    t0 = time.perf_counter()
    compiled = run.lower(mech, q).compile()
    t_compile = time.perf_counter() - t0
    t0 = time.perf_counter()
    sol = jax.block_until_ready(compiled(mech, q))
    t_run = time.perf_counter() - t0
    t0 = time.perf_counter()
    out = {k: np.asarray(v) for k, v in ride_outputs(mech, ChassisMotion(mech, q), jnp.asarray(ts), sol.q,
                                                         sol.qd).items()}
    t_outputs = time.perf_counter() - t0
    posts = np.stack([np.asarray(jax.vmap(roads[c])(jnp.asarray(ts))) for c in ("FL", "FR", "RL", "RR")], axis=1)
    static = np.asarray(wheel_loads(mech, 0.0, q, jnp.zeros_like(q)))
    iso = ts >= ISO_START + ISO_FADE
    names = mech.topo.tyre_names
    used = np.asarray(sol.events.element) >= 0
    figures = {
        "scene": "full vehicle (HMMWV corners, particlesim/scenes/vehicle.py B1-B7) on a four-post rig: a "
                 f"{BUMP['height'] * 100:g} cm raised-cosine bump under the front wheels at {BUMP['start']:g} s, then "
                 f"an ISO 8608 class {ROAD_CLASS} road at {SPEED:g} m/s from {ISO_START:g} s (faded in over "
                 f"{ISO_FADE:g} s; left/right seeds {SEEDS}, rear a wheelbase behind)",
        "duration_s": DURATION, "samples": N_SAVE, **SOLVER, "events": True,
        "accepted_steps": int(sol.steps), "rejected_steps": int(sol.rejected),
        "rest_s": t_rest, "modes_s": t_modes, "compile_s": t_compile, "run_s": t_run, "outputs_s": t_outputs,
        "modes": table,
        "rms_acceleration_iso_m_s2": float(np.sqrt(np.mean(out["acceleration"][iso] ** 2))),
        "rms_window_s": [ISO_START + ISO_FADE, DURATION],
        "peak_acceleration_m_s2": float(np.abs(out["acceleration"]).max()),
        "static_wheel_loads_N": dict(zip(names, static.tolist())),
        "peak_wheel_loads_N": dict(zip(names, out["loads"].max(axis=0).tolist())),
        "least_wheel_loads_N": dict(zip(names, out["loads"].min(axis=0).tolist())),
        "switches": [{"t_s": float(t), "tyre": names[int(e)], "in_contact_after": bool(a)} for t, e, a in
                     zip(np.asarray(sol.events.ts)[used], np.asarray(sol.events.element)[used],
                         np.asarray(sol.events.active)[used])],
        "peak_heave_m": float(np.abs(out["motion"][:, 0]).max()),
        "peak_pitch_rad": float(np.abs(out["motion"][:, 1]).max()),
        "peak_roll_rad": float(np.abs(out["motion"][:, 2]).max()),
    }
    with open(out_dir / "vehicle_ride.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["t_s", *(f"post_{c}_m" for c in ("FL", "FR", "RL", "RR")), "heave_m", "pitch_rad", "roll_rad",
                    "vertical_acceleration_m_s2", *(f"load_{c}_N" for c in ("FL", "FR", "RL", "RR"))])
        for row in zip(ts, posts, out["motion"], out["acceleration"], out["loads"]):
            w.writerow([f"{row[0]:.4f}", *(f"{v:.9g}" for v in row[1]), *(f"{v:.9g}" for v in row[2]),
                        f"{row[3]:.9g}", *(f"{v:.9g}" for v in row[4])])
    (out_dir / "vehicle_ride.json").write_text(json.dumps(figures, indent=2))
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plot_ride(ts, posts, out, static)
    fig.savefig(out_dir / "vehicle_ride.png", dpi=110)
    plt.close(fig)
    return figures


def plot_ride(ts, posts, out, static):
    """The rig run's figure: posts, chassis heave/pitch/roll, vertical acceleration, wheel loads (a matplotlib
    figure; ``out`` as :func:`ride_outputs` returns it, ``static`` the wheel loads at rest)."""
    import matplotlib.pyplot as plt

    corners = ("FL", "FR", "RL", "RR")
    out = {k: np.asarray(v) for k, v in out.items()}
    fig, ax = plt.subplots(4, 1, figsize=(9, 10), sharex=True, constrained_layout=True)
    for i, c in enumerate(corners):
        ax[0].plot(ts, posts[:, i] * 1e3, label=c)
        ax[3].plot(ts, out["loads"][:, i] / 1e3, label=c)
    ax[0].set_ylabel("post [mm]")
    ax[0].set_title(f"Four-post rig: bump under the front wheels, then ISO 8608 class {ROAD_CLASS} at {SPEED:g} m/s")
    m = out["motion"]
    ax[1].plot(ts, m[:, 0] * 1e3, "k", label="heave")
    ax[1].set_ylabel("chassis heave [mm]")
    angles = ax[1].twinx()
    angles.plot(ts, np.degrees(m[:, 1]), "C1", label="pitch")
    angles.plot(ts, np.degrees(m[:, 2]), "C2", label="roll")
    angles.set_ylabel("pitch, roll [deg]")
    angles.legend(loc="lower left", ncol=2, fontsize=8)
    ax[2].plot(ts, out["acceleration"])
    ax[2].set_ylabel("chassis vertical\nacceleration [m/s²]")
    ax[3].axhline(static.mean() / 1e3, color="k", lw=0.5)
    ax[3].set_ylabel("wheel load [kN]")
    ax[3].set_xlabel("t [s]")
    for a in ax:
        a.grid(alpha=0.3)
    for a in (ax[0], ax[1], ax[3]):
        a.legend(loc="upper left", ncol=4, fontsize=8)
    return fig
