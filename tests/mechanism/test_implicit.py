"""The structured implicit solver (:mod:`particlesim._esdirk`) on a stiff mechanism with an independent reference.

Scene: the planar cart pendulum of ``test_cart_pendulum`` with the cart tied to the ground by a stiff spring-damper
along its rail (k = 1e5 N/m, c = 2000 N s/m on a 2 kg cart: rates of ~1000 1/s beside a pole swinging at ~3 rad/s).
Reference: its Lagrange equations in (cart position, pole angle), written out by hand and integrated by SciPy's
Radau at rtol 1e-12. Kvaerno5 through ``simulate_mechanism`` must meet it, its error must shrink with the tolerance,
its derivatives (reverse and forward mode through the stage solves) must match central differences of the
reference, and new parameter values, states and tolerances must reuse the compiled rollout.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from particlesim import _ode
from particlesim.mechanism import MechanismBuilder, body_angles, point_positions, simulate_mechanism

#: Against the reference at rtol 1e-9 (atol 1e-11): the pole angle [rad] and the cart position [m] over the run
#: (measured 3.2e-10 rad, 2.0e-11 m).
ANGLE_TOL = 1e-8
POSITION_TOL = 1e-9
#: d(cart position at T_END)/d(log spring stiffness), reverse and forward mode against the reference's central
#: difference (step 1e-4 in the log), relative (measured 1.3e-9 in both modes).
GRAD_RTOL = 1e-6

G = 9.81
M_CART, M_POLE, L_POLE = 2.0, 0.5, 1.0
K, C = 1.0e5, 2.0e3
TH0 = np.deg2rad(60.0)
T_END = 1.0
TS = np.linspace(0.0, T_END, 21)


def build(k=K, c=C):
    mb = MechanismBuilder(planar=True)
    mb.ground("R0", (0.0, 0.0))
    mb.ground("R1", (1.0, 0.0))
    mb.ground("S", (-1.0, 0.0))
    mb.particle("C1", (0.0, 0.0))
    mb.particle("C2", (0.4, 0.0))
    mb.particle("P", (L_POLE * np.sin(TH0), -L_POLE * np.cos(TH0)))
    mb.rod("cart", "C1", "C2", mass=M_CART)
    mb.rod("pole", "C1", "P", mass=M_POLE)
    mb.on_line("C1", "R0", ("R0", "R1"))
    mb.on_line("C2", "R0", ("R0", "R1"))
    mb.spring_damper("tie", "S", "C1", k, c, 1.0)  # along the rail: force -k x - c x'
    return mb.build(dof=2)


def reference(ts, k=K, c=C):
    """(x, theta) at ``ts``."""
    m, ell = M_POLE, L_POLE

    def rhs(t, y):
        x, th, xd, thd = y
        mass = np.array([[M_CART + m, m * ell / 2 * np.cos(th)], [m * ell / 2 * np.cos(th), m * ell**2 / 3]])
        force = np.array([m * ell / 2 * np.sin(th) * thd**2 - k * x - c * xd, -m * G * ell / 2 * np.sin(th)])
        return [xd, thd, *np.linalg.solve(mass, force)]

    sol = solve_ivp(rhs, (0.0, float(ts[-1])), [0.0, TH0, 0.0, 0.0], method="Radau", t_eval=ts, rtol=1e-12,
                    atol=1e-14)
    assert sol.success
    return sol.y[0], sol.y[1]


@pytest.fixture(scope="module")
def scene():
    mech, q0 = build()
    return mech, jnp.asarray(q0)


def _run(mech, q0, rtol, **kw):
    return simulate_mechanism(mech, q0, jnp.zeros_like(q0), 0.0, T_END, solver="kvaerno5", rtol=rtol,
                              atol=rtol * 1e-2, saveat_ts=TS, **kw)


def _errors(mech, sol):
    ref_x, ref_th = reference(TS)
    x = np.asarray(jax.vmap(lambda q: point_positions(mech, q))(sol.q))[:, mech.point_index("C1"), 0]
    th = np.unwrap(np.asarray(jax.vmap(lambda q: body_angles(mech, q))(sol.q))[:, mech.body_index("pole")], axis=0)
    th = th - th[0] + TH0
    return np.max(np.abs(x - ref_x)), np.max(np.abs(th - ref_th))


def test_kvaerno5_meets_the_lagrangian_reference(scene):
    mech, q0 = scene
    sol = _run(mech, q0, 1e-9)
    ex, eth = _errors(mech, sol)
    assert ex < POSITION_TOL and eth < ANGLE_TOL, (ex, eth)


def test_error_shrinks_with_the_tolerance_and_compiles_once(scene):
    mech, q0 = scene
    before = _ode.TRACES["simulate_mechanism"]
    errs = [max(_errors(mech, _run(mech, q0, r))) for r in (1e-4, 1e-6, 1e-8)]
    stiffer = mech.with_params(spring={"tie": {"stiffness": 2 * K}})
    _run(stiffer, q0 + 1e-3, 1e-5)  # new parameters, state and tolerance: no new trace
    assert _ode.TRACES["simulate_mechanism"] - before <= 1
    assert errs[0] > errs[1] > errs[2], errs
    assert errs[2] < 1e-7, errs  # measured 2.5e-9 (rtol 1e-4: 2.5e-5, 1e-6: 1.8e-6)


def _cart_at_end(mech, q):
    return point_positions(mech, q)[mech.point_index("C1"), 0]


@pytest.mark.parametrize("adjoint", ["checkpoint", "forward"])
def test_gradient_through_the_stage_solves_matches_the_reference(scene, adjoint):
    mech, q0 = scene

    def end_x(log_k):
        m = mech.with_params(spring={"tie": {"stiffness": K * jnp.exp(log_k)}})
        s = simulate_mechanism(m, q0, jnp.zeros_like(q0), 0.0, T_END, solver="kvaerno5", rtol=1e-10, atol=1e-13,
                               adjoint=adjoint)
        return _cart_at_end(m, s.q[-1])

    s0 = jnp.zeros(())
    grad = jax.grad(end_x)(s0) if adjoint == "checkpoint" else jax.jvp(end_x, (s0,), (jnp.ones_like(s0),))[1]
    ds = 1e-4
    ref = (reference(TS, k=K * np.exp(ds))[0][-1] - reference(TS, k=K * np.exp(-ds))[0][-1]) / (2 * ds)
    assert abs(float(grad) - ref) <= GRAD_RTOL * abs(ref), (float(grad), ref)


#: Through located switches (a tyre touching down, lifting off and landing again): d(final wheel height)/d(tyre
#: damping) against Richardson-extrapolated central differences of the same rollout (relative steps 4e-3, 2e-3,
#: 1e-3; the two extrapolations agree to 1.2e-6, the noise of the adaptive steps at rtol 1e-11), relative:
#: measured 1.2e-6 reverse, 1.9e-6 forward.
EVENT_GRAD_RTOL = 1e-5


def test_gradient_through_located_switches_matches_central_differences():
    from particlesim.scenes.suspension_drop import DROP, drop_params, suspension_drop

    mech, x0 = suspension_drop()
    names = [mech.topo.particle_names[i] for i in mech.topo.free]
    iy_w = 3 * names.index("W") + 1
    p0 = jnp.asarray([DROP[k] for k in ("k", "c", "kt", "ct", "mc", "mw")])

    def run(ct, adjoint=None):
        return simulate_mechanism(drop_params(mech, p0.at[3].set(ct)), jnp.asarray(x0), jnp.zeros(mech.n_coords),
                                  0.0, DROP["t_end"], solver="kvaerno5", rtol=1e-11, atol=1e-13, events=True,
                                  adjoint=adjoint)

    def end(ct, adjoint=None):
        return run(ct, adjoint).q[-1, iy_w]

    ct = p0[3]
    assert int(jnp.sum(jnp.isfinite(run(ct).events.ts))) == 3  # touch down, lift off, touch down
    rev = float(jax.grad(end)(ct))
    fwd = float(jax.jvp(lambda c: end(c, "forward"), (ct,), (jnp.ones(()),))[1])

    def central(rel):
        h = rel * float(ct)
        return (float(end(ct + h)) - float(end(ct - h))) / (2 * h)

    d = {rel: central(rel) for rel in (4e-3, 2e-3, 1e-3)}
    fd = [(4 * d[2e-3] - d[4e-3]) / 3, (4 * d[1e-3] - d[2e-3]) / 3]
    assert abs(fd[0] - fd[1]) < 0.5 * EVENT_GRAD_RTOL * abs(fd[1]), fd  # converged
    for got in (rev, fwd):
        assert abs(got - fd[1]) < EVENT_GRAD_RTOL * abs(fd[1]), (rev, fwd, fd)
