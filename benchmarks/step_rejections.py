"""Why an explicit solver rejects steps on the full vehicle: counts against rtol, projection, controller and tyre
stiffness, beside a single oscillator at the car's wheel-hop frequency (float64, CPU; counts only, no timings).

* **Car** (:func:`particlesim.scenes.vehicle.full_vehicle` released from its assembly, every tyre staying in
  contact; undamped: springs and tyres without damping), Tsit5 over 3 s at rtol 1e-4, 1e-6, 1e-8 (atol = rtol/100):
  the default integral controller with and without the projection between steps, the PI controller (0.2, 0.4), and
  the tyres ten times softer.
* **Oscillator**: ``x'' = -w^2 x`` at the undamped wheel hop (w = 102 rad/s, 16.2 Hz) in diffrax directly, in its
  natural variables ``(x, v)`` (rtol, atol = rtol/100) and in balanced ones ``(w x, v)`` under an absolute
  tolerance alone, whose error estimate then has a constant size around the cycle.

Writes ``results/step_rejections.{json,csv}``. Run: ``python -m benchmarks.step_rejections``.
"""

from __future__ import annotations

import diffrax
import jax.numpy as jnp

from particlesim.mechanism import simulate_mechanism
from particlesim.scenes.vehicle import full_vehicle

from ._common import environment, write_results

NAME = "step_rejections"
RTOLS = (1e-4, 1e-6, 1e-8)
T_END = 3.0
HOP = 102.0  # rad/s: the undamped car's wheel hop at the assembly (linearisation)


def _undamped(m):
    return m.with_params(spring={n: {"damping": 0.0} for n in m.topo.spring_names},
                         tyre={n: {"damping": 0.0} for n in m.topo.tyre_names})


def car_rows() -> list[dict]:
    damped, q0 = full_vehicle()
    soft, q_soft = full_vehicle(tyre={"stiffness": 4.0e4})
    cases = {"undamped": (_undamped(damped), q0, {}), "undamped, no projection": (_undamped(damped), q0,
                                                                                 {"stabilise": False}),
             "undamped, PI (0.2, 0.4)": (_undamped(damped), q0, {"pid": (0.2, 0.4, 0.0)}),
             "undamped, tyres x0.1": (_undamped(soft), q_soft, {}),
             "damped": (damped, q0, {}), "damped, PI (0.2, 0.4)": (damped, q0, {"pid": (0.2, 0.4, 0.0)})}
    rows = []
    for name, (mech, q, kw) in cases.items():
        q = jnp.asarray(q)
        for rtol in RTOLS:
            s = simulate_mechanism(mech, q, jnp.zeros_like(q), 0.0, T_END, solver="tsit5", rtol=rtol,
                                   atol=rtol * 1e-2, max_steps=200_000, **kw)
            acc, rej = int(s.steps), int(s.rejected)
            rows.append({"scene": f"car, {name}", "rtol": rtol, "accepted": acc, "rejected": rej,
                         "rejected_share": rej / (acc + rej)})
            print(rows[-1], flush=True)
    return rows


def oscillator_rows() -> list[dict]:
    def natural(t, y, args):  # a wheel 1 cm from its rest height of 0.5 m, as the car's coordinates
        return jnp.stack([y[1], -HOP**2 * (y[0] - 0.5)])

    def balanced(t, z, args):  # z = (w (x - 0.5), v), measured by an absolute tolerance alone
        return jnp.stack([HOP * z[1], -HOP * z[0]])

    rows = []
    for name, field, y0, relative in (("oscillator (x, v)", natural, [0.51, 0.0], True),
                                      ("oscillator (w x, v), atol only", balanced, [HOP * 0.01, 0.0], False)):
        for rtol in RTOLS:
            c = diffrax.PIDController(rtol=rtol if relative else 1e-14, atol=rtol * 1e-2)
            s = diffrax.diffeqsolve(diffrax.ODETerm(field), diffrax.Tsit5(), 0.0, T_END, None, jnp.asarray(y0),
                                    stepsize_controller=c, max_steps=10**6)
            acc, rej = int(s.stats["num_accepted_steps"]), int(s.stats["num_rejected_steps"])
            rows.append({"scene": name, "rtol": rtol, "accepted": acc, "rejected": rej,
                         "rejected_share": rej / (acc + rej)})
            print(rows[-1], flush=True)
    return rows


def main() -> dict:
    res = {"environment": environment(), "rows": car_rows() + oscillator_rows()}
    write_results(NAME, res, res["rows"])
    return res


if __name__ == "__main__":
    main()
