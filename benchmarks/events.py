"""Evented against un-evented rollouts across contact switches: the dropped suspension
(:mod:`particlesim.scenes.suspension_drop`: touch-down, lift-off, touch-down in 1.3 s; float64, CPU).

* Work against precision: the wheel and chassis heights at 27 saves against a reference (evented Dopri8 at rtol
  1e-13), Dopri5 and Dopri8 over a sweep of rtol (atol = rtol / 100), with ``events=True`` and without, through
  the public ``simulate_mechanism`` (its compile cached; the first call's extra time is the compile).
* Derivatives: the Jacobian of the wheel height at 1.3 s with respect to the six spring, damper, tyre and mass
  parameters, by reverse mode (checkpointed) and forward mode, evented and not, at Dopri8 rtol 1e-12: the largest
  relative error against Richardson-extrapolated central differences of the evented rollout (converged, see
  ``tests/mechanism/test_events.py``), compile and run time.

Run: ``python -m benchmarks.events``.
"""

from __future__ import annotations

import time
import warnings

import jax
import jax.numpy as jnp
import numpy as np

from particlesim.mechanism import simulate_mechanism
from particlesim.scenes.suspension_drop import DROP, drop_params, suspension_drop

from . import _wp
from ._common import median_time, timed

NAME = "events"
T_END = DROP["t_end"]
TARGET = 1e-6  # m, largest over the run
TS = np.linspace(0.0, T_END, 27)
RTOLS = (1e-6, 1e-7, 1e-8, 1e-9, 1e-10, 1e-11)
P0 = np.array([DROP[k] for k in ("k", "c", "kt", "ct", "mc", "mw")])


def _scene():
    mech, x0 = suspension_drop()
    names = [mech.topo.particle_names[i] for i in mech.topo.free]
    cols = [3 * names.index("W") + 1, 3 * names.index("C") + 1]
    return mech, jnp.asarray(x0), cols


def _runner(mech, x0, cols, events):
    return _wp.public_runner(mech, x0, jnp.zeros_like(x0), T_END, TS, lambda s: np.asarray(s.q[:, cols]),
                             events=events)


def _gradients(mech, x0, cols) -> list[dict]:
    def wheel(p, adjoint, events):
        s = simulate_mechanism(drop_params(mech, p), x0, jnp.zeros_like(x0), 0.0, T_END, solver="dopri8",
                               rtol=1e-12, atol=1e-14, events=events, adjoint=adjoint)
        return s.q[-1, cols[0]]

    p0 = jnp.asarray(P0)
    f = jax.jit(lambda p: wheel(p, None, True))

    def central(rel):
        out = []
        for i in range(len(P0)):
            e = np.zeros(len(P0))
            e[i] = rel * P0[i]
            out.append((float(f(p0 + e)) - float(f(p0 - e))) / (2 * e[i]))
        return np.asarray(out)

    d = {rel: central(rel) for rel in (2e-3, 1e-3)}
    fd = (4 * d[1e-3] - d[2e-3]) / 3
    rows = []
    for events in (True, False):
        for mode, make in (("reverse (checkpoint)", lambda ev: jax.grad(lambda p: wheel(p, "checkpoint", ev))),
                           ("forward", lambda ev: jax.jacfwd(lambda p: wheel(p, "forward", ev)))):
            g = jax.jit(make(events))
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                comp, compiled = timed(lambda: g.lower(p0).compile())
                out = np.asarray(compiled(p0))
                wall = median_time(lambda: compiled(p0), number=1, repeat=3, block=jax.block_until_ready)
            err = np.abs(out - fd) / np.abs(fd)
            rows.append({"events": events, "mode": mode, "max_rel_error": float(err.max()),
                         "worst": ["k", "c", "kt", "ct", "mc", "mw"][int(np.argmax(err))], "wall_s": wall,
                         "compile_s": comp})
            print(rows[-1], flush=True)
    return rows


def run() -> dict:
    started = time.perf_counter()
    mech, x0, cols = _scene()
    ref = _runner(mech, x0, cols, True)("dopri8", 1e-13)[0]
    errors = _wp.Errors(ref)
    rows = []
    for label, ev in (("ours evented", True), ("ours un-evented", False)):
        rows += _wp.sweep_public(label, ["dopri5", "dopri8"], RTOLS, _runner(mech, x0, cols, ev), errors)
    grads = _gradients(mech, x0, cols)
    notes = [
        "Error: the largest coordinate error of the wheel and chassis heights over 27 saves [m] against the evented "
        "Dopri8 at rtol 1e-13 (its event times agree with SciPy's to 1e-9 s, tests/mechanism/test_events.py).",
        "Un-evented runs step across the three switches (the tyre's damping force jumps at contact), which costs "
        "rejected steps and accuracy at the kinks; evented runs end a segment at each switch.",
    ]
    res = _wp.finish(NAME, "Dropped suspension, evented vs un-evented", T_END, TARGET, "m",
                     "wheel and chassis heights over 1.3 s", {"what": "evented Dopri8 rtol 1e-13"}, rows, started,
                     notes, key="max_error")
    res["gradients"] = grads
    res["elapsed_s"] = time.perf_counter() - started
    return res


def markdown(results: dict) -> str:
    text = _wp.markdown(results, all_rows=True)
    text = text.replace("; MuJoCo C: no run reached the target; MJX: no run reached the target", "")
    lines = ["", "Derivatives of the wheel height at 1.3 s w.r.t. (k, c, kt, ct, mc, mw), Dopri8 rtol 1e-12, against "
             "Richardson central differences of the evented rollout:", "",
             "| rollout | mode | largest relative error | (parameter) | run | compile |", "|---|---|---:|---|---:|---:|"]
    for g in results.get("gradients", []):
        lines.append(f"| {'evented' if g['events'] else 'un-evented'} | {g['mode']} | {g['max_rel_error']:.1e} | "
                     f"{g['worst']} | {_wp.fmt_time(g['wall_s'])} | {g['compile_s']:.1f} s |")
    return text + "\n".join(lines) + "\n"


def main() -> dict:
    return _wp.main(run, markdown)


if __name__ == "__main__":
    main()
