"""Soft joint limits (optional, off by default): a one-sided spring-damper beyond each bound, against the closed
form of a rotor bouncing off its stop."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from particlesim.errors import ModelError
from particlesim.io import load_mjcf
from particlesim.simulate import simulate
from particlesim.tree import TreeModel, forward_dynamics, limit_torques, potential_energy
from particlesim.io import load_urdf

#: Adaptive Dopri8 at rtol 1e-11 stepping through the two kinks (contact, release) against the closed form.
CLOSED_FORM_TOL = 1e-9  # measured 2e-11
I_ZZ, K, C, UPPER, W0 = 0.05, 50.0, 0.5, 0.1, 1.0
ROTOR = ('<robot name="rotor"><link name="base"/><link name="disc"><inertial><mass value="2"/>'
         f'<inertia ixx="0.03" ixy="0" ixz="0" iyy="0.03" iyz="0" izz="{I_ZZ}"/></inertial></link>'
         '<joint name="spin" type="revolute"><parent link="base"/><child link="disc"/><axis xyz="0 0 1"/>'
         f'<limit lower="-1" upper="{UPPER}" effort="1" velocity="1"/></joint></robot>')


def test_rotor_bouncing_off_its_stop_matches_the_closed_form():
    model = load_urdf(ROTOR, limits="model", limit_stiffness=K, limit_damping=C)
    np.testing.assert_array_equal(np.asarray(model.limits), [[-1.0, UPPER, K, C]])
    t_in = UPPER / W0  # free flight to the stop
    wn, zeta = np.sqrt(K / I_ZZ), C / (2.0 * np.sqrt(K * I_ZZ))
    wd = wn * np.sqrt(1.0 - zeta**2)
    t_out = t_in + np.pi / wd  # the damped half-oscillation beyond the stop
    w_out = -W0 * np.exp(-zeta * wn * np.pi / wd)
    ts = np.array([t_in + 0.3 * np.pi / wd, 0.5])
    sol = simulate(forward_dynamics, model, np.zeros(1), np.array([W0]), 0.0, 0.5, saveat_ts=ts, rtol=1e-11,
                   atol=1e-13, solver="dopri8")
    tau = ts[0] - t_in
    inside = UPPER + W0 / wd * np.exp(-zeta * wn * tau) * np.sin(wd * tau)
    after = UPPER + w_out * (0.5 - t_out)
    np.testing.assert_allclose(np.asarray(sol.q)[:, 0], [inside, after], rtol=0, atol=CLOSED_FORM_TOL)
    np.testing.assert_allclose(float(sol.qd[-1, 0]), w_out, rtol=0, atol=CLOSED_FORM_TOL)
    # the stop's spring is part of the potential; inside the bounds it is free
    assert float(potential_energy(model, np.array([UPPER + 0.02]))) == pytest.approx(0.5 * K * 0.02**2, rel=1e-12)
    assert float(limit_torques(model, np.array([0.05]), np.array([3.0]))[0]) == 0.0


def test_limits_are_off_by_default_and_refused_when_malformed():
    with pytest.warns(UserWarning, match="position limits of 1 joint"):
        assert load_urdf(ROTOR).limits is None
    with pytest.raises(ValueError, match="limits='model' needs limit_stiffness and limit_damping"):
        load_urdf(ROTOR, limits="model", limit_stiffness=1.0)
    with pytest.raises(ValueError, match="limit_damping must be one value or one per velocity coordinate"):
        load_urdf(ROTOR, limits="model", limit_stiffness=1.0, limit_damping=[1.0, 2.0])
    kw = dict(parents=[-1], kinds=["revolute"], axes=[[0, 0, 1.0]], origin_rotations=[np.eye(3)],
              origin_xyz=np.zeros((1, 3)), inertia=[[1.0, 0, 0, 0, 1, 0, 0, 1, 0, 1]], joint_names=["j"])
    with pytest.raises(ModelError, match="limits of 'j': need lower <= upper"):
        TreeModel(**kw, limits=[[0.5, -0.5, 1.0, 1.0]])
    with pytest.raises(ModelError, match="limits of 'j': need lower <= upper and non-negative stiffness"):
        TreeModel(**kw, limits=[[-0.5, 0.5, -1.0, 1.0]])
    with pytest.raises(ModelError, match=r"limits must have shape \(1, 4\)"):
        TreeModel(**kw, limits=[-0.5, 0.5, 1.0, 1.0])
    free = dict(kw, kinds=["free"])
    with pytest.raises(ModelError, match="free and ball joints take no limits"):
        TreeModel(**free, limits=[[-1.0, 1.0, 1.0, 1.0]] + [[-np.inf, np.inf, 0.0, 0.0]] * 5)


def test_mjcf_ranges_become_soft_limits_and_ball_cones_are_said():
    xml = """<mujoco><compiler angle="radian"/><worldbody><body><joint name="hinge" range="-0.5 0.7" limited="true"/><geom size="0.1"/>
    <body pos="0 0 -0.3"><joint name="cone" type="ball" range="0 0.4" limited="true"/><geom size="0.1"/></body>
    </body></worldbody></mujoco>"""
    with pytest.warns(UserWarning, match="joint ranges of 1 joint\\(s\\) are not modelled \\(e.g. 'cone'\\)"):
        model = load_mjcf(xml, limits="model", limit_stiffness=30.0, limit_damping=0.2)
    np.testing.assert_array_equal(np.asarray(model.limits), [[-0.5, 0.7, 30.0, 0.2]] + [[-np.inf, np.inf, 30.0, 0.2]] * 3)


def test_continuous_joints_with_modelled_limits_run_unbounded():
    """``limits="model"`` on a file with a continuous joint: that joint's bounds are infinite (no stop), which every
    entry accepts as finite parameters (only NaN bounds or non-finite stiffness and damping are refused); the rotor
    spins past any angle exactly as without limits (a rollout and its gradient), while its limited neighbour's stop
    still acts."""
    urdf = ROTOR.replace('type="revolute"', 'type="continuous"').replace(
        '</robot>', '<link name="arm"><inertial><mass value="1"/><origin xyz="0.2 0 0"/><inertia ixx="0.01" ixy="0" '
        'ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial></link><joint name="hinge" type="revolute"><parent '
        'link="disc"/><child link="arm"/><origin xyz="0.3 0 0"/><axis xyz="0 0 1"/><limit lower="-0.5" upper="0.5" '
        'effort="1" velocity="1"/></joint></robot>')
    limited = load_urdf(urdf, limits="model", limit_stiffness=K, limit_damping=C)
    free = load_urdf(urdf, limits="ignore")
    lim = np.asarray(limited.limits)
    assert np.isinf(lim[0, :2]).all() and np.isfinite(lim[1]).all()
    wrong = [lim.copy(), lim.copy()]  # an infinite bound on the wrong side is no open side: refused
    wrong[0][0, 0], wrong[1][0, 1] = np.inf, -np.inf  # lower bound +inf, upper bound -inf
    for w in wrong:
        with pytest.raises(ModelError, match="limits is not finite"):
            forward_dynamics(eqx.tree_at(lambda m: m.limits, limited, jnp.asarray(w)), np.zeros(2), np.zeros(2),
                             np.zeros(2))
    q, qd = np.array([40.0, 0.1]), np.array([3.0, -0.2])
    np.testing.assert_array_equal(np.asarray(forward_dynamics(limited, q, qd, np.zeros(2))),
                                  np.asarray(forward_dynamics(free, q, qd, np.zeros(2))))

    def final(model, w):
        return simulate(forward_dynamics, model, jnp.zeros(2), jnp.array([w, 0.0]), 0.0, 1.0, rtol=1e-10,
                        atol=1e-12).q[-1]

    ours, ref = final(limited, 20.0), final(free, 20.0)
    assert float(ours[0]) > 15.0  # turned past any bound
    np.testing.assert_allclose(np.asarray(ours), np.asarray(ref), rtol=0, atol=1e-9)
    g = jax.grad(lambda w: final(limited, w)[0])(20.0)
    assert np.isfinite(float(g)) and float(g) == pytest.approx(float(jax.grad(lambda w: final(free, w)[0])(20.0)),
                                                               rel=1e-6)
    ts = np.linspace(0.0, 0.5, 51)

    def hinge(model):
        return np.asarray(simulate(forward_dynamics, model, jnp.array([0.0, 0.45]), jnp.array([0.0, 2.0]), 0.0, 0.5,
                                   saveat_ts=ts, rtol=1e-10, atol=1e-12).q[:, 1])

    assert hinge(limited).max() < 0.6 and hinge(free).max() > 0.9  # the hinge's stop holds it back
