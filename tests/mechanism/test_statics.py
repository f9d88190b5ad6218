"""Static equilibrium (``particlesim.mechanism.static_equilibrium``) against a long damped settle of the same
mechanism, the tyres' loads against the weight they carry, its derivative in a spring's stiffness against central
differences, and bad guesses refused.

The quarter car of the reference and the full vehicle (``particlesim.scenes``) both start at their assembly, away
from rest (the vehicle's springs are compressed 9 cm more than its weight needs), and are settled by integrating
the damped motion for long enough that what is left of it is far below the tolerance. The vehicle is free to move
horizontally and to turn about the vertical on its vertical tyres at no cost; there the equilibrium is the one
nearest the guess and the settle's drifts, so heights are compared.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from particlesim.errors import ModelError
from particlesim.mechanism import MechanismBuilder, simulate_mechanism, static_equilibrium
from particlesim.mechanism.forces import tyre_deflections
from particlesim.mechanism.outputs import point_positions
from particlesim.scenes import quarter_car as qc
from particlesim.scenes import vehicle as vh

SETTLE_TOL = 1e-9  # equilibrium against the settled state [m]
LOAD_RTOL = 1e-9  # the tyres' loads against the weight, relative
RESIDUAL_TOL = 1e-9  # forces left [N] at the equilibrium (of loads ~1e4 N)
GRAD_RTOL = 1e-6  # derivative in a stiffness against central differences


def _tyre_loads(mech, q):
    d = tyre_deflections(mech, point_positions(mech, q))
    return np.asarray(-mech.tyre_stiffness * jnp.minimum(d, 0.0))


def _weight(mech):
    return float(jnp.sum(mech.body_mass)) * 9.81


@pytest.mark.parametrize("scene, settle_s", [("quarter car", 20.0), ("vehicle", 20.0)])
def test_equilibrium_equals_a_long_settle_and_the_tyres_carry_the_weight(scene, settle_s):
    mech, q0 = qc.quarter_car() if scene == "quarter car" else vh.full_vehicle()
    eq = static_equilibrium(mech, q0)
    assert float(eq.force_residual) <= RESIDUAL_TOL and float(eq.constraint_residual) <= 1e-12
    settled = simulate_mechanism(mech, q0, 0 * q0, 0.0, settle_s, rtol=1e-12, atol=1e-14).q[-1]
    diff = (eq.q - settled).reshape(-1, 3)
    if scene == "quarter car":  # the wheel spins freely: its rim points are left out, its axis kept
        diff = diff[np.asarray([mech.free_slice(p).start // 3 for p in mech.particle_names
                                if p not in ("R1", "R2") and p in [mech.particle_names[i] for i in mech.free]])]
    else:  # free to move horizontally and to turn about the vertical: heights
        diff = diff[:, 2]
    assert float(jnp.max(jnp.abs(diff))) <= SETTLE_TOL
    assert float(jnp.max(jnp.abs(eq.q - q0))) > 1e-3  # it moved: the assembly is not at rest
    loads = _tyre_loads(mech, eq.q)
    assert abs(loads.sum() - _weight(mech)) <= LOAD_RTOL * _weight(mech)


def test_the_equilibrium_differentiates_in_a_stiffness_as_central_differences():
    mech, q0 = qc.quarter_car()
    i = mech.free_slice("C").start + 2  # the chassis's top particle, its height

    def height(k):
        return static_equilibrium(mech.with_params(spring={"suspension": {"stiffness": k}}), q0).q[i]

    k0 = qc.SPRING["stiffness"]
    h = 1e-4 * k0
    cd = (float(height(k0 + h)) - float(height(k0 - h))) / (2 * h)
    rev = float(jax.grad(height)(jnp.asarray(k0)))
    fwd = float(jax.jvp(height, (jnp.asarray(k0),), (jnp.asarray(1.0),))[1])
    assert cd > 0.0  # a stiffer spring holds the chassis higher
    assert abs(rev - cd) <= GRAD_RTOL * abs(cd) and abs(fwd - cd) <= GRAD_RTOL * abs(cd)


def test_bad_guesses_are_refused():
    mech, q0 = qc.quarter_car()
    with pytest.raises(ModelError, match=r"q_guess must have shape \(39,\)"):
        static_equilibrium(mech, q0[:-1])
    with pytest.raises(ModelError, match="q_guess has non-finite entries"):
        static_equilibrium(mech, np.where(np.arange(q0.size) == 0, np.nan, q0))
    with pytest.raises(ModelError, match=r"""contact must have one entry per one-sided element \(tyres, then bump """
               r"""stops\): \["tyre 'tyre'"\]"""):
        static_equilibrium(mech, q0, contact=[True, False])
    with pytest.raises(Exception, match="did not converge"):  # the tyre taken off the ground: nothing holds the car
        jax.block_until_ready(static_equilibrium(mech, q0, contact=[False]).q)


def test_a_tyre_in_contact_must_be_compressed_at_the_equilibrium():
    """A level wheel (mass m) on a tyre, hung from a spring stronger than its weight: taken in contact, the tyre
    would have to pull it down (refused); taken clear, the wheel hangs where the spring carries its weight."""
    m, k_spring, top, length = 10.0, 2000.0, 2.0, 1.0
    mb = MechanismBuilder(planar=True)
    mb.ground("top", (0.0, top))
    mb.particle("A", (0.0, 0.3))
    mb.particle("B", (0.2, 0.3))
    mb.particle("D", (0.0, 0.5))
    mb.planar_body("wheel", m, 0.1, (0.0, 0.3), ["A", "B", "D"], on_negative="ignore")
    mb.drive_position("fixed x", "A", lambda t: 0.0 * t, axis=(1.0, 0.0, 0.0))
    mb.drive_angle("level", "wheel", lambda t: 0.0 * t)
    mb.spring_damper("hanger", "D", "top", k_spring, 0.0, length)
    mb.tyre("tyre", "A", 1e5, 0.0, 0.3, normal=(0.0, 1.0, 0.0))
    mech, q0 = mb.build(dof=1)
    with pytest.raises(Exception, match="a tyre or bump stop taken as engaged is clear at the equilibrium"):
        jax.block_until_ready(static_equilibrium(mech, q0).q)
    eq = static_equilibrium(mech, q0, contact=[False])
    d_y = float(eq.q[mech.free_slice("D")][1])
    assert d_y == pytest.approx(top - length - m * 9.81 / k_spring, abs=1e-12)  # the spring carries the weight


def test_new_parameters_states_and_tolerances_reuse_the_compiled_solve(monkeypatch):
    """Counted by the residual's traces: a new stiffness, guess, time and tolerance run the compiled solve again."""
    from particlesim.mechanism import statics

    traces = []
    real = statics._residual
    monkeypatch.setattr(statics, "_residual", lambda y, args: traces.append(1) or real(y, args))
    mech, q0 = qc.quarter_car()
    static_equilibrium(mech, q0)
    first = len(traces)
    stiffer = mech.with_params(spring={"suspension": {"stiffness": 6e4}})
    eq = static_equilibrium(stiffer, q0 + 1e-3, t=0.5, rtol=1e-9)
    assert len(traces) == first and float(eq.force_residual) <= RESIDUAL_TOL
