"""A tyre measured at the wheel centre and applied at a contact point of the same body: a planar upright dropped
on the ground while turning, against its body-coordinate equations (centre height, angle) written here and
integrated by SciPy; the centre-applied tyre for contrast (no torque); bad application point."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from particlesim.errors import ModelError
from particlesim.mechanism import MechanismBuilder, body_angles, simulate_mechanism

#: Centre height and body angle against the body-coordinate solution [m, rad] (both at rtol 1e-11).
TOL = 1e-7
M, J, R, K, C, G = 20.0, 0.8, 0.3, 2.0e4, 150.0, 9.81
Y0, W0, T1 = 0.32, 1.5, 1.0


def _upright(apply: bool):
    mb = MechanismBuilder(planar=True)
    mb.particle("C", (0.0, Y0))
    mb.particle("U1", (0.2, Y0 + 0.1))
    mb.particle("U2", (-0.1, Y0 + 0.25))
    mb.planar_body("upright", M, J, (0.0, Y0), ["C", "U1", "U2"], on_negative="ignore")
    mb.point("contact", "upright", (0.0, Y0 - R))
    mb.tyre("tyre", "C", K, C, R, normal=(0.0, 1.0, 0.0), apply_at="contact" if apply else None)
    return mb.build(dof=3)


def _reference(ts, apply: bool):
    def rhs(t, s):
        x, y, phi, vx, vy, w = s
        f = K * (R - y) - C * vy if y < R else 0.0
        arm_x = R * np.sin(phi)  # contact point relative to the centre: R(phi) (0, -R)
        torque = arm_x * f if apply else 0.0
        return [vx, vy, w, 0.0, -G + f / M, torque / J]

    r = solve_ivp(rhs, (0.0, ts[-1]), [0.0, Y0, 0.0, 0.0, 0.0, W0], method="DOP853", rtol=1e-11, atol=1e-12,
                  t_eval=ts, max_step=1e-3)
    return r.y[1], r.y[2]


@pytest.mark.parametrize("apply", [True, False])
def test_upright_on_the_ground(apply):
    mech, x0 = _upright(apply)
    r = np.asarray(x0).reshape(-1, 3)
    centre = r[mech.free.index(mech.index("C"))]
    v0 = np.cross([0.0, 0.0, W0], r - centre)  # turning about the centre, which starts at rest
    ts = np.linspace(0.0, T1, 101)
    sol = simulate_mechanism(mech, jnp.asarray(x0), jnp.asarray(v0.reshape(-1)), 0.0, T1, solver="dopri8",
                             rtol=1e-11, atol=1e-12, saveat_ts=ts, max_steps=200_000)
    y_ref, phi_ref = _reference(ts, apply)
    q = np.asarray(sol.q)
    y = q[:, mech.free_slice("C")][:, 1]
    phi = np.unwrap(np.asarray(jax.vmap(lambda x: body_angles(mech, x))(sol.q))[:, 0])
    assert np.max(np.abs(y - y_ref)) <= TOL
    assert np.max(np.abs(phi - phi_ref)) <= TOL
    assert np.min(y) < R - 0.005  # it landed and the tyre deflected
    if apply:
        assert np.max(np.abs(phi_ref - W0 * ts)) > 0.05  # the contact force turned it
    else:  # applied at the centre: no moment, the spin stays uniform
        assert np.max(np.abs(phi - W0 * ts)) <= TOL


def test_tyre_application_point_must_exist():
    mb = MechanismBuilder(planar=True)
    mb.particle("C", (0.0, Y0))
    mb.particle("U1", (0.2, Y0 + 0.1))
    mb.particle("U2", (-0.1, Y0 + 0.25))
    mb.planar_body("upright", M, J, (0.0, Y0), ["C", "U1", "U2"], on_negative="ignore")
    mb.tyre("tyre", "C", K, C, R, normal=(0.0, 1.0, 0.0), apply_at="nowhere")
    with pytest.raises(ModelError, match="tyre 'tyre' \\(application point\\)"):
        mb.build()
