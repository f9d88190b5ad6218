"""The full vehicle (``particlesim.scenes.vehicle``, assumptions in its module): built from the Chrono file's data,
assembly, constraint closure over a run, energy conservation without dampers, left/right mirror symmetry."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from particlesim.errors import InertiaWarning
from particlesim.mechanism import (body_poses, constraint_jacobian, kinetic_energy, residuals, simulate_mechanism,
                                   total_energy)
from particlesim.scenes import vehicle as vh

T_END = 0.5
TS = np.linspace(0.0, T_END, 26)
G = 9.81


@pytest.fixture(scope="module")
def car():
    with pytest.warns(InertiaWarning, match="Lower Control Arm"):  # B3: the file's arms, balanced
        mech, q0 = vh.full_vehicle()
    return mech, jnp.asarray(q0)


def _run(mech, q0, rtol):
    """One compiled rollout for every call (new parameters and tolerances reuse it)."""
    sol = simulate_mechanism(mech, q0, jnp.zeros_like(q0), 0.0, T_END, rtol=rtol, atol=1e-2 * rtol, saveat_ts=TS)
    assert bool(sol.ok)
    return sol


@pytest.fixture(scope="module")
def damped(car):
    mech, q0 = car
    return _run(mech, q0, 1e-8)


def test_the_car_is_built_from_the_chrono_file(shared_data, car):
    """What ``full_vehicle()`` is built from is the file's data as written (the loader's own checks, both files and
    bad input, are in ``test_vehicle_loader.py``); the spring is the curve's slope at zero deflection (B6)."""
    data = json.loads((shared_data / "double_wishbone_chrono" / "HMMWV_DoubleWishboneFront.json").read_text())
    with pytest.warns(InertiaWarning):
        corner = vh.load_double_wishbone(vh.hmmwv_front_path())
    assert corner.hardpoints["lca_u"] == tuple(data["Lower Control Arm"]["Location Upright"])
    assert corner.bodies["upright"].moments == tuple(data["Upright"]["Moments of Inertia"])
    assert tuple(data["Upright"]["Products of Inertia"]) == (0, 0, 0)
    assert data["Vehicle-Frame Inertia"] is False  # B3, B4: arm frames for the arms
    curve = np.asarray(data["Spring"]["Curve Data"])
    zero = int(np.flatnonzero(curve[:, 0] == 0.0)[0])
    slope = (curve[zero + 1, 1] - curve[zero - 1, 1]) / (curve[zero + 1, 0] - curve[zero - 1, 0])
    assert vh.SPRING["stiffness"] == pytest.approx(slope, rel=1e-15)
    assert vh.SPRING["free_length"] == data["Spring"]["Free Length"]
    assert vh.SPRING["damping"] == data["Shock"]["Damping Coefficient"]
    mech, _ = car
    np.testing.assert_array_equal(mech.spring_stiffness, [slope, 0.0] * 4)  # "spring XX", "shock XX" per corner
    np.testing.assert_array_equal(mech.spring_damping, [0.0, data["Shock"]["Damping Coefficient"]] * 4)
    assert float(mech.total_mass()) == pytest.approx(
        2000.0 + 4 * sum(data[k]["Mass"] for k in ("Spindle", "Upright", "Upper Control Arm", "Lower Control Arm")),
        rel=1e-14)


def test_builds_assembled_with_ten_freedoms(car):
    mech, q0 = car
    assert float(jnp.abs(residuals(mech, q0, jnp.zeros_like(q0))[0]).max()) <= 1e-12
    jac = np.asarray(constraint_jacobian(mech, q0)).reshape(mech.n_constraints, mech.n_coords)
    assert mech.n_coords - np.linalg.matrix_rank(jac) == 10
    # B7: at assembly the four tyres carry the whole weight, a quarter each
    lift = np.asarray(mech.tyre_stiffness) * (np.asarray(mech.tyre_radius) - (
        np.asarray(mech.all_positions(q0))[[mech.index(f"wheel {c}") for c in vh.CORNERS], 2] -
        np.asarray(mech.tyre_ground)))
    np.testing.assert_allclose(lift, float(jnp.sum(mech.body_mass)) * G / 4, rtol=1e-12)


RESIDUAL_TOL = 1e-12  # constraint residuals over a run [m, m/s] (the issue's bound)


def test_constraints_hold_over_a_run(car, damped):
    mech, _ = car
    pos, vel = jax.vmap(lambda q, qd: residuals(mech, q, qd))(damped.q, damped.qd)
    assert float(jnp.abs(pos).max()) <= RESIDUAL_TOL
    assert float(jnp.abs(vel).max()) <= RESIDUAL_TOL


def test_energy_is_conserved_without_dampers(car):
    mech, q0 = car
    mech = mech.with_params(spring={f"shock {c}": {"damping": 0.0} for c in vh.CORNERS},
                            tyre={f"tyre {c}": {"damping": 0.0} for c in vh.CORNERS})
    sol = _run(mech, q0, 1e-10)
    energy = jax.vmap(lambda q, qd: total_energy(mech, q, qd))(sol.q, sol.qd)
    kinetic = jax.vmap(lambda q, qd: kinetic_energy(mech, q, qd))(sol.q, sol.qd)
    drift = float(jnp.abs(energy - energy[0]).max())
    # relative to the largest kinetic energy (energy exchanged), stricter than to |E(0)|, whose datum is arbitrary
    print(f"energy drift {drift:.2e} J; max kinetic {float(kinetic.max()):.1f} J; |E(0)| {float(energy[0]):.1f} J")
    assert float(kinetic.max()) > 100.0  # the car does move
    assert drift <= 1e-6 * float(kinetic.max())


def test_left_right_mirror_symmetry(car, damped):
    mech, _ = car
    b = mech.body_index("chassis")
    rot = jax.vmap(lambda q: body_poses(mech, q)[0][b])(damped.q)
    roll = np.arctan2(np.asarray(rot[:, 2, 1]), np.asarray(rot[:, 2, 2]))
    assert np.abs(roll).max() <= 1e-9
    # every left particle is the mirror image of its right twin, all along the run
    pos = np.asarray(jax.vmap(mech.all_positions)(damped.q))
    left = [i for i, n in enumerate(mech.particle_names) if n.endswith(("FL", "RL"))]
    right = [mech.index(mech.particle_names[i][:-1] + "R") for i in left]
    assert len(left) == 16
    mirrored = pos[:, left] * np.array([1.0, -1.0, 1.0])
    assert np.abs(mirrored - pos[:, right]).max() <= 1e-9
    assert np.abs(pos[-1] - pos[0]).max() > 1e-2  # and it moved


def test_located_events_keep_the_final_state(car, damped):
    """With ``events=True`` and no switch in the run, the car moves as without events, its last saved state (at
    t1) included: the run's empty trailing segments must not overwrite it."""
    mech, q0 = car
    sol = simulate_mechanism(mech, q0, jnp.zeros_like(q0), 0.0, T_END, rtol=1e-8, atol=1e-10, saveat_ts=TS,
                             events=True)
    assert bool(sol.ok) and not np.isfinite(np.asarray(sol.events.ts)).any()
    assert float(jnp.abs(sol.q - damped.q).max()) <= 1e-6
    assert float(jnp.abs(residuals(mech, sol.q[-1], sol.qd[-1])[0]).max()) <= 1e-10


def test_wheels_leaving_and_landing_together_are_located():
    """A 5 cm bump under both front wheels of the car with anti-roll bars throws them off the ground and back, the
    two together (mirror symmetry): with located events every switch is found (both wheels flip at once) and the
    run agrees with one that steps across the switches at a tight tolerance; neither wheel sinks into the road."""
    from particlesim.mechanism import project, static_equilibrium
    from particlesim.scenes import roads

    bump = roads.Bump(0.05, 0.2, 0.3)
    mech, q0 = vh.full_vehicle(roads={"FL": bump, "FR": bump}, anti_roll_bar={"front": 2e4, "rear": 1e4})
    q, qd = project(mech, static_equilibrium(mech, jnp.asarray(q0)).q, jnp.zeros(mech.n_coords))
    ts = np.linspace(0.0, 0.8, 41)
    kw = dict(saveat_ts=ts, max_steps=20000)
    located = simulate_mechanism(mech, q, qd, 0.0, 0.8, rtol=1e-9, atol=1e-11, events=True, **kw)
    stepped = simulate_mechanism(mech, q, qd, 0.0, 0.8, rtol=1e-11, atol=1e-13, **kw)
    element, times = np.asarray(located.events.element), np.asarray(located.events.ts)
    front = [k for k, e in enumerate(element) if e in (0, 1)]  # tyre FL, tyre FR
    assert len(front) >= 4 and sorted(element[front[:4]]) == [0, 0, 1, 1]  # off, then on again, each pair at once
    assert times[front[0]] == times[front[1]] and times[front[2]] == times[front[3]]
    assert float(jnp.abs(located.q - stepped.q).max()) <= 1e-5
    wheels = [mech.free_slice(f"wheel {c}").start + 2 for c in ("FL", "FR")]
    assert float(jnp.abs(located.q[:, wheels[0]] - located.q[:, wheels[1]]).max()) <= 1e-9


def test_options_build_with_ten_freedoms_and_bad_ones_are_refused():
    import jax.numpy as jnp_

    from particlesim.errors import ModelError

    mech, q0 = vh.full_vehicle(spring_curve=True, stops={"stiffness": 1e6, "damping": 1e3},
                               anti_roll_bar={"front": 1e4}, steering=lambda t: 0.01 * t)
    assert mech.topo.bump_names == tuple(f"{k} stop {c}" for c in vh.CORNERS for k in ("bump", "rebound"))
    assert mech.topo.torsion_names == ("anti-roll bar front",)
    assert all(len(x) == 21 for x in mech.topo.spring_force_knots[::2])  # the springs (shocks stay linear)
    jac = np.asarray(constraint_jacobian(mech, jnp_.asarray(q0), t=0.0))
    # the rack adds one sliding freedom, which its driver takes: ten free ones remain
    assert mech.n_coords - np.linalg.matrix_rank(jac.reshape(mech.n_constraints, -1)) == 10
    for kw, msg in [(dict(roads={"XX": lambda t: 0.0 * t}), "roads for unknown corners"),
                    (dict(anti_roll_bar={"middle": 1.0}), "anti_roll_bar axles are 'front' and 'rear'"),
                    (dict(stops={"k": 1.0}), "stops must be"),
                    (dict(anti_roll_bar={"front": -1.0}), "torsion spring 'anti-roll bar front': stiffness")]:
        with pytest.raises(ModelError, match=msg):
            vh.full_vehicle(**kw)
