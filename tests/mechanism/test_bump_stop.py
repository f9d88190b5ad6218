"""Bump stops (``mb.bump_stop``): a block on a vertical guide falls onto a stop (a compression stop below it, or a
rebound stop above it, each engaging after ``clearance`` of travel), bounces off and lands again. The switch times
against the closed form (free fall; the damped oscillator on the stop, its separation root-found on the closed form
by ``brentq``), the motion against SciPy; energy on the stop; gradients through the located events (reverse,
forward) against central differences; bad input refused by name. A tyre far above the ground is declared first, so
the stop is the second one-sided element (events index the tyres, then the bump stops)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from rollout_helpers import assert_derivative_matches_central_difference
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from particlesim.errors import ModelError
from particlesim.mechanism import MechanismBuilder, potential_energy, simulate_mechanism, static_equilibrium

M, K, C, G = 50.0, 4.0e4, 150.0, 9.81
Y0, CLEAR = 1.0, 0.05
T_END = 0.6
EVENT_TOL = 1e-9  # located switch times against the closed form [s]
REF_TOL = 1e-8  # heights against SciPy [m]
GRAD_RTOL = 1e-6


def block(rebound: bool):
    """The block (a planar set held level, driven to stay at x = 0), its particle ``A`` at height ``Y0``."""
    mb = MechanismBuilder(planar=True)
    mb.particle("A", (0.0, Y0))
    mb.particle("B", (0.2, Y0))
    mb.particle("D", (0.0, Y0 + 0.2))
    mb.planar_body("block", M, 2.0, (0.0, Y0), ["A", "B", "D"], on_negative="ignore")
    mb.drive_position("guide", "A", lambda t: 0.0 * t, axis=(1.0, 0.0, 0.0))
    mb.drive_angle("level", "block", lambda t: 0.0 * t)
    mb.tyre("tyre", "A", 1.0e5, 10.0, 0.1, normal=(0.0, 1.0, 0.0), ground=-5.0)  # never touches
    mb.ground("S", (0.0, 2.0 * Y0) if rebound else (0.0, 0.0))
    mb.bump_stop("stop", "A", "S", CLEAR, K, C, rebound=rebound)
    mech, q0 = mb.build(dof=1)
    return mech, jnp.asarray(q0), jnp.zeros(len(q0))


def closed_form():
    """The first three switch times: contact after falling ``CLEAR``, separation, contact again."""
    t1 = np.sqrt(2 * CLEAR / G)
    w = np.sqrt(K / M)
    z = C / (2 * np.sqrt(K * M))
    wd = w * np.sqrt(1 - z**2)
    a, b = G / w**2, (-G * t1 + z * w * G / w**2) / wd

    def gap(s):  # x'' + 2 z w x' + w^2 x = -g from x = 0, x' = -g t1
        return -G / w**2 + np.exp(-z * w * s) * (a * np.cos(wd * s) + b * np.sin(wd * s))

    s2 = brentq(gap, 0.5 * np.pi / wd, 1.5 * np.pi / wd, xtol=1e-15, rtol=1e-15)
    rate = jax.grad(lambda s: -G / w**2 + jnp.exp(-z * w * s) * (a * jnp.cos(wd * s) + b * jnp.sin(wd * s)))(s2)
    return t1, t1 + s2, t1 + s2 + 2 * float(rate) / G


def reference(ts):
    """The block's height from SciPy, the stop's law switched on the gap's sign (events at the switches)."""
    def rhs(t, y, on):
        gap = y[0] - (Y0 - CLEAR)
        f = -(K * gap + C * y[1]) if on else 0.0
        return [y[1], -G + f / M]

    out, t, y, on = [], 0.0, [Y0, 0.0], False
    while t < ts[-1]:
        ev = lambda t, y, on: y[0] - (Y0 - CLEAR)  # noqa: E731
        ev.terminal, ev.direction = True, (1.0 if on else -1.0)
        sol = solve_ivp(rhs, (t, ts[-1]), y, args=(on,), events=ev, method="DOP853", rtol=1e-13, atol=1e-15,
                        dense_output=True)
        keep = (ts >= t) & (ts <= sol.t[-1])
        out.append(sol.sol(ts[keep])[0])
        t, y, on = sol.t[-1], sol.y[:, -1], not on
        ts = ts[~keep] if keep.any() else ts
        if not len(ts):
            break
    return np.concatenate(out)


@pytest.fixture(scope="module", params=[False, True], ids=["compression stop", "rebound stop"])
def case(request):
    mech, q0, qd0 = block(request.param)
    ts = np.linspace(0.0, T_END, 31)
    sol = simulate_mechanism(mech, q0, qd0, 0.0, T_END, rtol=1e-11, atol=1e-13, saveat_ts=ts, events=True)
    return mech, q0, qd0, ts, sol


def test_switch_times_match_the_closed_form(case):
    mech, _, _, ts, sol = case
    assert bool(sol.ok)
    times = np.asarray(sol.events.ts)
    used = np.asarray(sol.events.element) >= 0
    assert list(np.asarray(sol.events.element)[used][:3]) == [1, 1, 1]  # the stop, after the tyre
    assert list(np.asarray(sol.events.active)[used][:3]) == [True, False, True]
    assert np.abs(times[used][:3] - np.asarray(closed_form())).max() <= EVENT_TOL


def test_the_motion_matches_scipy(case):
    mech, _, _, ts, sol = case
    y = np.asarray(sol.q[:, mech.free_slice("A").start + 1])
    assert np.abs(y - reference(ts)).max() <= REF_TOL
    assert y.min() < Y0 - CLEAR - 0.005  # it pressed into the stop


def test_energy_and_static_rest_on_the_stop(case):
    mech, q0, _, _, _ = case
    i = mech.free_slice("A").start + 1
    pen = 0.01
    q = q0.at[jnp.arange(0, mech.n_coords // 3) * 3 + 1].add(-(CLEAR + pen))
    du = float(potential_energy(mech, q)) - float(potential_energy(mech, q0))
    assert du == pytest.approx(-M * G * (CLEAR + pen) + 0.5 * K * pen**2, rel=1e-12)
    rest = static_equilibrium(mech, q, contact=[False, True])
    assert float(rest.q[i]) == pytest.approx(Y0 - CLEAR - M * G / K, abs=1e-12)


def test_gradients_through_the_events_match_central_differences():
    """On the compression stop: the rebound stop is the same element with its gap's sign turned (its switch times and
    motion are checked above), and each check compiles three rollouts."""
    mech, q0, qd0 = block(False)
    i = mech.free_slice("A").start + 1

    def end(clear, adjoint=None):
        m = mech.with_params(bump={"stop": {"clearance": clear}})
        sol = simulate_mechanism(m, q0, qd0, 0.0, 0.3, rtol=1e-12, atol=1e-14, events=True, adjoint=adjoint)
        return sol.q[-1, i]

    assert_derivative_matches_central_difference(end, CLEAR, GRAD_RTOL, least=1e-3)


def test_bad_bump_stops_are_refused_by_name():
    mb = MechanismBuilder()
    for kw, msg in [(dict(clearance=-0.1), "bump stop 'x': clearance must be a finite and non-negative"),
                    (dict(stiffness=float("nan")), "bump stop 'x': stiffness must be a finite"),
                    (dict(damping=lambda t: t), "bump stop 'x': damping must be"),
                    (dict(rebound="yes"), "bump stop 'x': rebound must be True or False")]:
        args = dict(clearance=0.01, stiffness=1.0, damping=0.0)
        args.update(kw)
        with pytest.raises(ModelError, match=msg):
            mb.bump_stop("x", "a", "b", **args)
    mb = MechanismBuilder()
    mb.ground("O", (0, 0, 0))
    mb.particle("e", (1, 0, 0))
    mb.rod("rod", "O", "e", 1.0)
    mb.bump_stop("x", "e", "O", 1.5, 1.0)
    with pytest.raises(ModelError, match="bump stop 'x': its clearance 1.5 m is not shorter"):
        mb.build()
    mb = MechanismBuilder()
    mb.ground("O", (0, 0, 0))
    mb.particle("e", (1, 0, 0))
    mb.rod("rod", "O", "e", 1.0)
    mb.bump_stop("x", "e", "nowhere", 0.1, 1.0)
    with pytest.raises(ModelError, match="bump stop 'x': unknown particle or point 'nowhere'"):
        mb.build()
