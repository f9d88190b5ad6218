"""Gradients across contact switches: a planar two-mass suspension (:mod:`particlesim.scenes.suspension_drop`:
chassis and wheel on a vertical guide, a spring-damper between them, a one-sided tyre under the wheel) dropped so that its tyre touches down, lifts off and
touches down again within the run. With ``events=True`` every switch is located, so that derivatives carry the
jump of the tyre's damping force at contact:

* event times against an independent solution: the two-coordinate equations of the same suspension integrated by
  SciPy's DOP853 with its own event location (rtol 1e-13);
* derivatives of the final state and of a trajectory loss with respect to every spring, damper, tyre and mass
  parameter, by reverse mode (checkpointed adjoint) and forward mode, against central differences whose
  convergence the test shows (two step sizes agreeing);
* without events, a differentiated rollout that crosses a switch warns, naming the tyre.
"""

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from particlesim import _ode
from particlesim.mechanism import SwitchCrossedWarning, simulate_mechanism
from particlesim.scenes.suspension_drop import DROP, drop_params, suspension_drop

#: Event times against SciPy's event location on the two-coordinate equations [s].
EVENT_TOL = 1e-9
#: Automatic derivatives against converged central differences, relative.
GRAD_RTOL = 1e-6
#: Central differences at two sets of steps must agree to this (their convergence), relative.
FD_AGREE = 1e-6
MC, MW, K, C, KT, CT, R, G, L0 = (DROP[k] for k in ("mc", "mw", "k", "c", "kt", "ct", "radius", "g", "free_length"))
YC0, YW0, T_END = DROP["yc0"], DROP["yw0"], DROP["t_end"]
TS = np.linspace(0.0, T_END, 27)
P0 = np.array([K, C, KT, CT, MC, MW])
NAMES = ["suspension stiffness", "suspension damping", "tyre stiffness", "tyre damping", "chassis mass",
         "wheel mass"]


@pytest.fixture(scope="module")
def model():
    mech, x0 = suspension_drop()
    names = [mech.topo.particle_names[i] for i in mech.topo.free]
    iy_c, iy_w = 3 * names.index("C") + 1, 3 * names.index("W") + 1

    def outputs(p, adjoint=None, events=True):
        sol = simulate_mechanism(drop_params(mech, p), jnp.asarray(x0), jnp.zeros(mech.n_coords), 0.0, T_END,
                                 solver="dopri8", rtol=1e-12, atol=1e-14, saveat_ts=TS, events=events,
                                 adjoint=adjoint)
        yc = sol.q[:, iy_c]
        return jnp.stack([sol.q[-1, iy_w], sol.q[-1, iy_c], jnp.mean((yc - yc[0]) ** 2)])

    return mech, x0, outputs


def _reference_events(yc0=YC0, yw0=YW0, contact=False):
    """SciPy DOP853 with its own event location from rest at heights ``(yc0, yw0)`` starting in the tyre law
    ``contact``; returns ``[(t, contact after), ...]`` and the final ``(yc, yw)``."""
    def rhs(t, y, contact):
        yc, yw, vc, vw = y
        fs = K * (L0 - (yc - yw)) - C * (vc - vw)
        ft = -(KT * (yw - R) + CT * vw) if contact else 0.0
        return [vc, vw, fs / MC - G, (-fs + ft) / MW - G]

    t, y, out = 0.0, np.array([yc0, yw0, 0.0, 0.0]), []
    while t < T_END:
        def hit(t, y, c):
            return y[1] - R
        hit.terminal, hit.direction = True, (1 if contact else -1)
        s = solve_ivp(rhs, (t, T_END), y, args=(contact,), events=hit, rtol=1e-13, atol=1e-15, method="DOP853")
        if not s.t_events[0].size:
            y = s.y[:, -1]
            break
        t, y, contact = s.t_events[0][0], s.y_events[0][0], not contact
        out.append((t, contact))
    return out, y[:2]


def test_switches_are_located_at_the_reference_event_times(model):
    mech, x0, _ = model
    sol = simulate_mechanism(mech, jnp.asarray(x0), jnp.zeros(mech.n_coords), 0.0, T_END, solver="dopri8",
                             rtol=1e-12, atol=1e-14, saveat_ts=TS, events=True)
    ref, _ = _reference_events()
    assert [c for _, c in ref] == [True, False, True]  # touch down, lift off, touch down
    n = len(ref)
    ev = sol.events
    assert np.all(np.isinf(np.asarray(ev.ts[n:])))
    assert np.max(np.abs(np.asarray(ev.ts[:n]) - [t for t, _ in ref])) < EVENT_TOL
    assert list(np.asarray(ev.active[:n])) == [c for _, c in ref]
    assert list(np.asarray(ev.element[:n])) == [0] * n  # mech.topo.tyre_names[0]


def test_a_tyre_starting_exactly_touching_at_rest_enters_contact(model):
    """Regression: released with the tyre exactly touching (zero deflection, the usual assembly), the evented
    rollout started the tyre out of contact and the wheel sank through the ground (the switching function starts
    at zero, so no sign change is ever seen). Now the initial law follows where the tyre is heading; the run matches
    SciPy started in contact (heights to EVENT_TOL, the same later switches)."""
    mech, x0, _ = model
    names = [mech.topo.particle_names[i] for i in mech.topo.free]
    shift = np.zeros(mech.n_coords)
    shift[1::3] = R - YW0  # every particle down by the same amount: constraints hold, wheel centre at y = R
    sol = simulate_mechanism(mech, jnp.asarray(x0 + shift), jnp.zeros(mech.n_coords), 0.0, T_END,
                             solver="dopri8", rtol=1e-12, atol=1e-14, saveat_ts=TS, events=True)
    ref, (yc, yw) = _reference_events(YC0 + R - YW0, R, contact=True)
    n = len(ref)
    assert np.all(np.isinf(np.asarray(sol.events.ts[n:])))
    assert list(np.asarray(sol.events.active[:n])) == [c for _, c in ref]
    q = np.asarray(sol.q[-1])
    assert abs(q[3 * names.index("W") + 1] - yw) < EVENT_TOL and abs(q[3 * names.index("C") + 1] - yc) < EVENT_TOL


def test_derivatives_across_switches_match_converged_central_differences(model):
    _, _, outputs = model
    p0 = jnp.asarray(P0)
    # Reverse mode row by row (one compiled vjp), forward mode column by column (one compiled jvp): the same
    # Jacobians as jacrev / jacfwd, without compiling their vmapped (batched while loop) programs.
    vjp_row = jax.jit(lambda p, ct: jax.vjp(lambda p: outputs(p, "checkpoint"), p)[1](ct)[0])
    jvp_col = jax.jit(lambda p, t: jax.jvp(lambda p: outputs(p, "forward"), (p,), (t,))[1])
    rev = np.stack([np.asarray(vjp_row(p0, ct)) for ct in jnp.eye(3)])
    fwd = np.stack([np.asarray(jvp_col(p0, t)) for t in jnp.eye(len(P0))], axis=1)
    # Central differences, Richardson-extrapolated (h and h/2: the h^2 term cancels), so that steps large enough
    # to lift the output changes far above the adaptive integrator's noise (its step sequence changes with the
    # parameters) are still exact to O(h^4); shown converged by repeating the extrapolation at half the steps.
    # (Plain differences at relative steps 1e-5 are off by up to 2.6e-5 on the tyre damping, whose influence is
    # smallest: noise, not truncation.)
    def central(rel):
        cols = []
        for i in range(len(P0)):
            e = np.zeros(len(P0))
            e[i] = rel * P0[i]
            cols.append((np.asarray(outputs(p0 + e)) - np.asarray(outputs(p0 - e))) / (2 * e[i]))
        return np.stack(cols, axis=1)

    traces = _ode.TRACES["simulate_mechanism"]
    d = {rel: central(rel) for rel in (4e-3, 2e-3, 1e-3)}
    assert _ode.TRACES["simulate_mechanism"] - traces <= 1  # 36 new parameter sets, one compiled evented rollout
    fd = [(4 * d[2e-3] - d[4e-3]) / 3, (4 * d[1e-3] - d[2e-3]) / 3]
    scale = np.abs(fd[1])
    conv = np.abs(fd[0] - fd[1]) / scale
    assert conv.max() < FD_AGREE, f"central differences not converged: {conv.max():.2e}"
    for name, ad in (("reverse", rev), ("forward", fwd)):
        err = np.abs(ad - fd[1]) / scale
        worst = np.unravel_index(np.argmax(err), err.shape)
        assert err.max() < GRAD_RTOL, f"{name}: {err.max():.2e} at output {worst[0]}, {NAMES[worst[1]]}"


def test_a_differentiated_rollout_without_events_warns_when_the_tyre_switches(model):
    _, _, outputs = model
    p0 = jnp.asarray(P0)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        jax.jvp(lambda p: outputs(p, "forward", events=False), (p0,), (jnp.eye(len(P0))[3],))
        jax.effects_barrier()
    hits = [w for w in caught if issubclass(w.category, SwitchCrossedWarning)]
    assert hits and "'tyre'" in str(hits[0].message)


#: Quarter car with a 45 ms tyre lift-off: event times of runs at rtol 1e-7 against one at rtol 1e-11 [s], and
#: final chassis heights against a run without events at rtol 1e-12 [m].
LIFT_OFF_T_TOL = 1e-6
LIFT_OFF_Z_TOL = 1e-6


def test_a_brief_lift_off_is_located_at_neighbouring_constants():
    """The quarter car (spatial double wishbone) with a 100 kg payload and constants where its tyre lifts off for
    45 ms, found by a fit stepping through them: at these constants and at the damping 1e-4 (relative) higher,
    the evented rollout locates the lift-off and the landing (with one event function per surface and Newton's
    method, the second run failed to converge and returned NaN) and ends where a tight run without events ends."""
    from particlesim.scenes.quarter_car import quarter_car

    mech, x0 = quarter_car()
    x0 = jnp.asarray(x0)
    k = mech.point_index("centre")

    def run(damping, rtol, events):
        m = mech.with_params(spring={"suspension": {"stiffness": 41228.40764452131, "damping": damping}},
                             tyre={"tyre": {"stiffness": 357898.4191658963}},
                             body={"chassis": {"mass": 240.97197785159906 + 100.0},
                                   "wheel": {"mass": 84.41323494724588}})
        s = simulate_mechanism(m, x0, jnp.zeros_like(x0), 0.0, 2.0, solver="dopri8", rtol=rtol, atol=rtol * 1e-2,
                               saveat_ts=np.linspace(0.0, 2.0, 201), events=events, stabilise=False)
        return s, float(m.point_positions(m.all_positions(s.q[-1]))[k, 2])

    for damping in (16964.715180154468, 16966.41173649888):
        sol, z = run(damping, 1e-7, True)
        tight, _ = run(damping, 1e-11, True)
        _, z_ref = run(damping, 1e-12, False)
        t_ev = np.asarray(sol.events.ts)[np.isfinite(np.asarray(sol.events.ts))]
        t_tight = np.asarray(tight.events.ts)[np.isfinite(np.asarray(tight.events.ts))]
        assert bool(sol.ok) and t_ev.size == 2 and t_tight.size == 2, (damping, t_ev, t_tight)
        assert 0.03 < t_ev[1] - t_ev[0] < 0.06  # off the ground for ~45 ms
        assert np.max(np.abs(t_ev - t_tight)) < LIFT_OFF_T_TOL
        assert abs(z - z_ref) < LIFT_OFF_Z_TOL
