"""Springs and dampers from tables (``spring_damper(..., force_curve=, damping_curve=)``): a block on a vertical
guide hanging from a spring with Chrono's HMMWV spring curve (scaled) and a progressive damper curve, against its
one-coordinate equation with SciPy's natural cubic splines (``CubicSpline``) integrated by SciPy; the spring's
energy against SciPy's quadrature of the same spline; energy held without damping; gradients in a table value
(reverse, forward) against central differences; bad tables refused by name."""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from rollout_helpers import assert_derivative_matches_central_difference
from scipy.integrate import quad, solve_ivp
from scipy.interpolate import CubicSpline

from particlesim.errors import ModelError
from particlesim.mechanism import (MechanismBuilder, potential_energy, simulate_mechanism, spring_lengths,
                                   total_energy)

M, G, Y0, L0 = 40.0, 9.81, -0.58, 0.45  # block mass, its start height below the hook, the spring's free length
T_END = 1.0
TS = np.linspace(0.0, T_END, 21)
RTOL, ATOL = 1e-11, 1e-13
REF_TOL = 1e-8  # heights [m] against SciPy
ENERGY_TOL = 1e-10  # the spring's energy against quadrature, relative
ENERGY_RTOL = 1e-8  # undamped run: total energy drift relative to the spring's energy at the start
GRAD_RTOL = 1e-6
DAMPER = (np.array([-1.0, -0.3, 0.0, 0.3, 1.0]), np.array([-900.0, -400.0, 0.0, 250.0, 600.0]))


def spring_table(shared_data):
    data = json.loads((shared_data / "double_wishbone_chrono" / "HMMWV_DoubleWishboneFront.json").read_text())
    curve = np.asarray(data["Spring"]["Curve Data"])
    return curve[:, 0], curve[:, 1] / 20.0  # a lighter spring for a 40 kg block


def block(shared_data):
    mb = MechanismBuilder(planar=True)
    mb.ground("hook", (0.0, 0.0))
    mb.particle("A", (0.0, Y0))
    mb.particle("B", (0.2, Y0))
    mb.particle("D", (0.0, Y0 + 0.2))
    mb.planar_body("block", M, 2.0, (0.0, Y0), ["A", "B", "D"], on_negative="ignore")
    mb.drive_position("guide", "A", lambda t: 0.0 * t, axis=(1.0, 0.0, 0.0))
    mb.drive_angle("level", "block", lambda t: 0.0 * t)
    mb.spring_damper("main", "A", "hook", free_length=L0, force_curve=spring_table(shared_data),
                     damping_curve=DAMPER)
    mech, q0 = mb.build(dof=1)
    return mech, jnp.asarray(q0), jnp.zeros(len(q0))


def _extended(x, y):
    """SciPy's natural cubic spline through ``(x, y)``, continued along its end tangents beyond the table."""
    cs = CubicSpline(x, y, bc_type="natural")
    lo, hi = float(x[0]), float(x[-1])

    def f(s):
        if s < lo:
            return float(cs(lo) + cs(lo, 1) * (s - lo))
        if s > hi:
            return float(cs(hi) + cs(hi, 1) * (s - hi))
        return float(cs(s))

    return f


def _splines(shared_data):
    return _extended(*spring_table(shared_data)), _extended(*DAMPER)


def reference(shared_data, damped=True):
    """``m y'' = -m g + F(-y - L0) + D(-y')`` (the tension pulls the block up; the spring's length is -y)."""
    spring, damper = _splines(shared_data)

    def rhs(t, s):
        y, v = s
        return [v, -G + (spring(-y - L0) + (damper(-v) if damped else 0.0)) / M]

    sol = solve_ivp(rhs, (0.0, T_END), [Y0, 0.0], method="DOP853", rtol=1e-13, atol=1e-15, t_eval=TS)
    return sol.y[0]


@pytest.fixture(scope="module")
def case(shared_data):
    mech, q0, qd0 = block(shared_data)
    sol = simulate_mechanism(mech, q0, qd0, 0.0, T_END, rtol=RTOL, atol=ATOL, saveat_ts=TS)
    return mech, q0, qd0, sol


def test_the_block_moves_as_its_equation_with_scipy_splines(case, shared_data):
    mech, _, _, sol = case
    assert bool(sol.ok)
    y = np.asarray(sol.q[:, mech.free_slice("A").start + 1])
    assert np.abs(y - reference(shared_data)).max() <= REF_TOL
    assert np.ptp(y) > 0.02  # it moved across several table points (0.02 m apart)


def test_the_spring_energy_is_the_curve_integral(case, shared_data):
    mech, q0, _, _ = case
    spring, _ = _splines(shared_data)
    for dy in (0.0, -0.07, 0.05, 0.3):  # the last beyond the table (linear continuation)
        q = q0.at[mech.free_slice("A").start + 1::3].add(dy)
        stretch = float(spring_lengths(mech, q)[0]) - L0
        expected = quad(spring, 0.0, stretch, epsabs=1e-12, epsrel=1e-13, limit=200)[0]
        gravity = M * G * float(q[mech.free_slice("A").start + 1])  # the centre of mass is at A
        u = float(potential_energy(mech, q))
        assert abs((u - gravity) - expected) <= ENERGY_TOL * max(abs(expected), 1.0)


def test_without_damping_the_energy_is_held(case, shared_data):
    mech, q0, qd0, _ = case
    free = mech.with_params(spring={"main": {"damping_curve": np.zeros(5)}})
    sol = simulate_mechanism(free, q0, qd0, 0.0, T_END, rtol=RTOL, atol=ATOL, saveat_ts=TS)
    e = np.asarray(jax.vmap(lambda q, v: total_energy(free, q, v))(sol.q, sol.qd))
    y = np.asarray(sol.q[:, free.free_slice("A").start + 1])
    assert np.abs(y - reference(shared_data, damped=False)).max() <= REF_TOL
    assert np.abs(e - e[0]).max() <= ENERGY_RTOL * M * G * 0.1


def test_gradient_in_a_table_value_matches_central_differences(case):
    mech, q0, qd0, _ = case
    i = mech.free_slice("A").start + 1
    base = mech.spring_force_curve[0]
    k = 12  # the table point at +0.04 m

    def end(v, adjoint=None):
        m = mech.with_params(spring={"main": {"force_curve": base.at[k].set(v)}})
        sol = simulate_mechanism(m, q0, qd0, 0.0, 0.5, rtol=1e-12, atol=1e-14, adjoint=adjoint)
        return sol.q[-1, i]

    v0 = float(base[k])
    assert_derivative_matches_central_difference(end, v0, GRAD_RTOL, least=1e-8)


def test_bad_tables_are_refused_by_name(case):
    mb = MechanismBuilder()
    for kw, msg in [(dict(force_curve=([0, 1], [0, 1])), "spring 'x': force curve must be \\(x, y\\) with at least 3"),
                    (dict(force_curve=([0, 2, 1], [0, 1, 2])), "spring 'x': force curve's abscissae must increase"),
                    (dict(damping_curve=([0, 1, 2], [0, np.nan, 2])), "spring 'x': damping curve has non-finite"),
                    (dict(force_curve="stiff"), "spring 'x': force curve must be"),
                    (dict(stiffness=1.0, force_curve=([0, 1, 2], [0, 1, 2])), "spring 'x': give stiffness or "
                                                                              "force_curve, not both")]:
        with pytest.raises(ModelError, match=msg):
            mb.spring_damper("x", "a", "b", free_length=1.0, **kw)
    mech = case[0]
    with pytest.raises(ModelError, match=r"spring 'main' force curve must have shape \(21,\)"):
        mech.with_params(spring={"main": {"force_curve": np.zeros(3)}})
