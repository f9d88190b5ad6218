"""The full vehicle (``particlesim.scenes.vehicle``, assumptions in its module): transcription of the Chrono data,
assembly, constraint closure over a run, energy conservation without dampers, left/right mirror symmetry."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from particlesim.mechanism import (body_poses, constraint_jacobian, kinetic_energy, residuals, simulate_mechanism,
                                   total_energy)
from particlesim.scenes import vehicle as vh

T_END = 0.5
TS = np.linspace(0.0, T_END, 26)
G = 9.81


@pytest.fixture(scope="module")
def car():
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


def test_transcription_matches_the_chrono_file(shared_data):
    data = json.loads((shared_data / "double_wishbone_chrono" / "HMMWV_DoubleWishboneFront.json").read_text())
    uca, lca = "Upper Control Arm", "Lower Control Arm"
    where = {"uca_f": (uca, "Location Chassis Front"), "uca_b": (uca, "Location Chassis Back"),
             "uca_u": (uca, "Location Upright"), "lca_f": (lca, "Location Chassis Front"),
             "lca_b": (lca, "Location Chassis Back"), "lca_u": (lca, "Location Upright"),
             "tierod_c": ("Tierod", "Location Chassis"), "tierod_u": ("Tierod", "Location Upright"),
             "spring_c": ("Spring", "Location Chassis"), "spring_a": ("Spring", "Location Arm"),
             "shock_c": ("Shock", "Location Chassis"), "shock_a": ("Shock", "Location Arm")}
    assert set(where) == set(vh.HARDPOINTS)
    for name, (part, field) in where.items():
        assert vh.HARDPOINTS[name] == tuple(data[part][field]), name
    for name, (mass, com, moments) in vh.BODIES.items():
        entry = data[{"spindle": "Spindle", "upright": "Upright", "uca": uca, "lca": lca}[name]]
        assert (mass, com, moments) == (entry["Mass"], tuple(entry["COM"]),
                                        tuple(entry.get("Moments of Inertia", entry.get("Inertia"))))
        assert tuple(entry.get("Products of Inertia", (0, 0, 0))) == (0, 0, 0)
    assert data["Vehicle-Frame Inertia"] is False  # B3, B4: arm frames for the arms
    curve = np.asarray(data["Spring"]["Curve Data"])
    zero = int(np.flatnonzero(curve[:, 0] == 0.0)[0])
    slope = (curve[zero + 1, 1] - curve[zero - 1, 1]) / (curve[zero + 1, 0] - curve[zero - 1, 0])
    assert vh.SPRING["stiffness"] == pytest.approx(slope, rel=1e-15)
    assert vh.SPRING["free_length"] == data["Spring"]["Free Length"]
    assert vh.SPRING["damping"] == data["Shock"]["Damping Coefficient"]


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


def test_constraints_hold_after_a_run(car, damped):
    mech, _ = car
    pos, vel = residuals(mech, damped.q[-1], damped.qd[-1])
    assert float(jnp.abs(pos).max()) <= 1e-10
    assert float(jnp.abs(vel).max()) <= 1e-10


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
