"""Tyres on a moving road (``mb.tyre(..., ground=f)``): a post of a four-post rig ``ground(t)``, a profile under a
wheel moving along it ``ground(t, p)``, and a wheel dropped onto a rising ramp with located events, each against its
one-coordinate equation written out here and integrated by SciPy (or, for the event time, solved in closed form);
gradients in the road's parameters (reverse and forward) against central differences; bad road functions refused.

The wheel is a planar body held level (a driven angle) whose centre is driven along x, so its one coordinate is its
height ``y``: ``m y'' = -m g + k (r + h - y) - c (y' - h')`` while the tyre is compressed, with ``h`` the road height
under it and ``h'`` its rate along the motion.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from particlesim.errors import ModelError
from particlesim.mechanism import MechanismBuilder, simulate_mechanism, total_energy

M, K, C, R, G = 100.0, 1.0e5, 800.0, 0.3, 9.81
Y_REST = R - M * G / K  # the centre's height at rest on a level road at 0
T_END = 2.0
TS = np.linspace(0.0, T_END, 81)
RTOL, ATOL = 1e-11, 1e-13  # our rollouts
REF_TOL = 1e-8  # heights against the SciPy solution of the one-coordinate equation [m]
EVENT_TOL = 1e-9  # located contact time against the closed form [s]
GRAD_RTOL = 1e-6  # reverse and forward derivatives against central differences of the same loss


class Sine(eqx.Module):
    """A post moving ``amplitude sin(omega t)``: its amplitude an array, so a parameter of the rollout."""
    amplitude: jax.Array
    omega: float = 12.0

    def __call__(self, t):
        return self.amplitude * jnp.sin(self.omega * t)


class Profile(eqx.Module):
    """A road ``amplitude sin(wavenumber x)`` under the wheel's centre ``p``."""
    amplitude: jax.Array
    wavenumber: float = 2.0

    def __call__(self, t, p):
        return self.amplitude * jnp.sin(self.wavenumber * p[0])


class Ramp(eqx.Module):
    """A road rising at ``slope`` metres per second."""
    slope: jax.Array

    def __call__(self, t):
        return self.slope * t


def wheel(ground, *, y0=Y_REST, speed=0.0):
    """The level wheel of the module docstring, its centre ``A`` at height ``y0``, driven along x at ``speed``."""
    mb = MechanismBuilder(planar=True)
    mb.particle("A", (0.0, y0))
    mb.particle("B", (0.2, y0))
    mb.particle("D", (0.0, y0 + 0.2))
    mb.planar_body("wheel", M, 2.0, (0.0, y0), ["A", "B", "D"], on_negative="ignore")  # (it does not turn)
    mb.drive_position("travel", "A", lambda t: speed * t, axis=(1.0, 0.0, 0.0))
    mb.drive_angle("level", "wheel", lambda t: 0.0 * t)
    mb.tyre("tyre", "A", K, C, R, normal=(0.0, 1.0, 0.0), ground=ground)
    mech, q0 = mb.build(dof=1)
    qd0 = jnp.tile(jnp.asarray([speed, 0.0, 0.0]), mech.n_coords // 3)  # moving along x from the start
    return mech, q0, qd0


def reference(h, h_rate, y0, ts):
    """SciPy's DOP853 on the one-coordinate equation, the tyre's law switched by the sign of its deflection."""
    def rhs(t, s):
        y, v = s
        d = y - h(t) - R
        f = -(K * d + C * (v - h_rate(t))) if d < 0.0 else 0.0
        return [v, -G + f / M]

    sol = solve_ivp(rhs, (0.0, ts[-1]), [y0, 0.0], method="DOP853", t_eval=ts, rtol=1e-13, atol=1e-15)
    return sol.y[0]


def _heights(mech, q0, qd0, ts=TS, **kw):
    sol = simulate_mechanism(mech, q0, qd0, 0.0, float(ts[-1]), rtol=RTOL, atol=ATOL, saveat_ts=ts, **kw)
    assert bool(sol.ok)
    return sol, np.asarray(sol.q[:, mech.free_slice("A")][:, 1])


def test_a_post_of_a_four_post_rig_drives_the_wheel_as_its_equation():
    a, w = 0.01, 12.0
    mech, q0, qd0 = wheel(Sine(jnp.asarray(a), w))
    sol, y = _heights(mech, q0, qd0)
    ref = reference(lambda t: a * np.sin(w * t), lambda t: a * w * np.cos(w * t), Y_REST, TS)
    assert np.max(np.abs(y - ref)) <= REF_TOL
    assert np.max(y - a * np.sin(w * TS) - R) < -1e-3  # in contact all along: the road's rate is in the damping
    # the tyre's energy is read off the road at t: with the post raised by a, the same state stores more
    e0 = float(total_energy(mech, q0, 0 * q0, t=0.0))
    lifted = float(total_energy(mech, q0, 0 * q0, t=np.pi / (2 * w)))
    assert lifted - e0 == pytest.approx(0.5 * K * ((M * G / K + a) ** 2 - (M * G / K) ** 2), rel=1e-10)


def test_a_profile_under_a_moving_wheel_is_read_at_its_position():
    b, kappa, v = 0.005, 2.0, 3.0
    mech, q0, qd0 = wheel(Profile(jnp.asarray(b), kappa), speed=v)
    _, y = _heights(mech, q0, qd0)
    ref = reference(lambda t: b * np.sin(kappa * v * t), lambda t: b * kappa * v * np.cos(kappa * v * t), Y_REST, TS)
    assert np.max(np.abs(y - ref)) <= REF_TOL


def test_contact_with_a_rising_road_is_located_on_the_moving_surface():
    """Dropped from rest 5 cm above the ground, which rises at ``slope``: contact when ``y0 - g t^2 / 2 - r = slope
    t``; the event's time against that root, the motion after it against SciPy."""
    slope, y0 = 0.2, R + 0.05
    mech, q0, qd0 = wheel(Ramp(jnp.asarray(slope)), y0=y0)
    ts = np.linspace(0.0, 0.4, 41)
    sol, y = _heights(mech, q0, qd0, ts, events=True)
    t_hit = (-slope + np.sqrt(slope**2 + 2 * G * (y0 - R))) / G
    events = np.asarray(sol.events.ts)
    assert abs(events[0] - t_hit) <= EVENT_TOL and bool(sol.events.active[0])
    assert np.max(np.abs(y - reference(lambda t: slope * t, lambda t: slope, y0, ts))) <= REF_TOL


@pytest.mark.parametrize("case", ["post", "ramp with events"])
def test_gradients_in_the_road_match_central_differences(case):
    """The wheel's height at the end with respect to the post's amplitude, and (through the located contact) the
    ramp's slope: reverse and forward mode against central differences of the same rollout."""
    if case == "post":
        road, p0, y0, t1, kw = Sine, 0.01, Y_REST, 1.0, {}
    else:
        road, p0, y0, t1, kw = Ramp, 0.2, R + 0.05, 0.3, {"events": True}
    mech, q0, qd0 = wheel(road(jnp.asarray(p0)), y0=y0)
    i = mech.free_slice("A").start + 1

    def end_height(p, adjoint=None):
        m = eqx.tree_at(lambda m: m.tyre_roads[0], mech, road(p))
        sol = simulate_mechanism(m, q0, qd0, 0.0, t1, rtol=1e-12, atol=1e-14, adjoint=adjoint, **kw)
        return sol.q[-1, i]

    f = jax.jit(end_height)
    h = 1e-4 * p0
    cd = (float(f(p0 + h)) - float(f(p0 - h))) / (2 * h)
    rev = float(jax.jit(jax.grad(end_height))(jnp.asarray(p0)))
    fwd = float(jax.jit(lambda p: jax.jvp(lambda x: end_height(x, "forward"), (p,), (jnp.ones_like(p),))[1])(
        jnp.asarray(p0)))
    assert abs(cd) > 1e-3
    assert abs(rev - cd) <= GRAD_RTOL * abs(cd)
    assert abs(fwd - cd) <= GRAD_RTOL * abs(cd)


def test_bad_road_functions_and_numbers_are_refused_by_name():
    def broken(t):
        raise RuntimeError("no road data")

    for ground, match in (("level", "ground must be a number .* or a function"),
                          (lambda t, p, q: 0.0, r"the road function must take \(t\) or \(t, p\), got signature "
                                                r"\(t, p, q\)"),
                          (lambda t: jnp.ones(2), "the road function must return one finite number"),
                          (lambda t: jnp.nan, "the road function must return one finite number"),
                          (broken, r"ground\(t\) failed at t = 0: RuntimeError: no road data")):
        with pytest.raises(ModelError, match="tyre 'tyre': " + match):
            wheel(ground)
    mb = MechanismBuilder(planar=True)
    mb.particle("A", (0.0, 1.0))
    with pytest.raises(ModelError, match="tyre 'soft': stiffness must be a finite and non-negative number, got a function"):
        mb.tyre("soft", "A", lambda t: K, C, R)
    with pytest.raises(ModelError, match="tyre 'soft': radius must be a finite and non-negative number, got -0.3"):
        mb.tyre("soft", "A", K, C, -R)


def test_a_short_bump_is_felt_with_a_bounded_step():
    """From rest on a level post, a 2 cm bump lasting 40 ms at t = 1 s: with ``max_step`` below its duration the
    wheel follows its equation (SciPy, its steps bounded alike); an unbounded adaptive step may stride over it."""
    from particlesim.scenes.roads import Bump

    bump = Bump(0.02, 1.0, 0.04)
    mech, q0, qd0 = wheel(bump)
    ts = np.linspace(0.0, 1.5, 31)
    sol = simulate_mechanism(mech, q0, qd0, 0.0, 1.5, rtol=1e-10, atol=1e-12, saveat_ts=ts, max_step=0.01)
    y = np.asarray(sol.q[:, mech.free_slice("A")][:, 1])

    def h(t):
        return float(bump(t))

    def h_rate(t):
        return float(jax.jvp(bump, (jnp.asarray(t),), (jnp.asarray(1.0),))[1])

    def rhs(t, s):
        d = s[0] - h(t) - R
        f = -(K * d + C * (s[1] - h_rate(t))) if d < 0.0 else 0.0
        return [s[1], -G + f / M]

    ref = solve_ivp(rhs, (0.0, 1.5), [Y_REST, 0.0], method="DOP853", t_eval=ts, rtol=1e-13, atol=1e-15,
                    max_step=0.005).y[0]
    assert np.max(np.abs(y - ref)) <= REF_TOL
    assert np.max(np.abs(y - Y_REST)) > 1e-3  # the bump was felt
    for bad in (0.0, -1.0, float("nan"), "1"):
        with pytest.raises(ValueError, match="max_step must be a positive number"):
            simulate_mechanism(mech, q0, qd0, 0.0, 1.5, max_step=bad)


def test_bad_roads_are_refused_by_name():
    from particlesim.scenes.roads import Bump, SineSum, iso8608

    for make, msg in [(lambda: Bump(0.05, 0.2, 0.0), "Bump: duration must be finite and positive"),
                      (lambda: Bump(float("nan"), 0.2, 0.1), "Bump: height must be finite"),
                      (lambda: SineSum([1.0, 2.0], [1.0], [0.0, 0.0], speed=10.0), "SineSum: amplitude, wavenumber"),
                      (lambda: SineSum([1.0], [1.0], [0.0], speed=float("inf")), "SineSum: speed must be finite"),
                      (lambda: iso8608("Z", 10.0, seed=0), "unknown ISO 8608 class 'Z'")]:
        with pytest.raises(ValueError, match=msg):
            make()
