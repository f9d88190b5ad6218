"""Quarter-car identification by autodiff: spring, damper, tyre stiffness and both masses from noisy chassis-height
traces (:mod:`particlesim.identify.quarter_car`), timed whole from a fresh model (compile included).

Data: the free responses from rest with no payload and with a known 100 kg on the chassis, 2 s at 100 Hz, from
the true constants (the scene's Table 1-3 values), plus Gaussian noise of sigma = 1e-5 m. Fit: Gauss–Newton in
``log p`` from two starts 20 % off in every constant (opposite directions), vmapped. Rows: the forward-mode
Jacobian through the rollout (the package's path) and, for scale, the same Gauss–Newton loop with
forward-difference Jacobians of the same compiled rollout (``P + 1`` rollouts per start and evaluation; step 1e-4
in ``log p``). The measurement model's own accuracy (Dopri8, rtol 1e-7, no projection) is checked against a
projected Dopri8 reference at rtol 1e-11. Run: ``python -m benchmarks.identification_quarter_car``.
"""

from __future__ import annotations

import time

import jax.numpy as jnp
import numpy as np

from particlesim.identify.quarter_car import chassis_traces, fit_quarter_car
from particlesim.scenes.quarter_car import SPRING, TABLE1, TYRE

from ._common import environment, pyplot, save_figure, write_json, write_table

NAME = "identification_quarter_car"
TS = np.linspace(0.0, 2.0, 201)
TRUE = np.array([SPRING["stiffness"], SPRING["damping"], TYRE["stiffness"], TABLE1["chassis"][0],
                 TABLE1["wheel"][0]])
STARTS = TRUE * (1 + 0.2 * np.array([[1, -1, -1, 1, -1], [-1, 1, 1, -1, 1]]))
SIGMA = 1e-5  # m
FD_STEP = 1e-4  # forward-difference step in log p for the comparison row
SEED = 3


def _recorded(fn, log):
    """``fn`` (a residual-and-Jacobian function) that logs the wall time and the best cost of every call."""

    def call(lp, z):
        r, jac = fn(lp, z)
        r = np.asarray(r)
        cost = np.where(np.isfinite(r).all(axis=1), np.einsum("sm,sm->s", r, r), np.inf)
        log.append((time.perf_counter(), float(cost.min())))
        return r, jac

    return call


def _fd(model):
    """Forward-difference residual and Jacobian in ``log p`` from the model's compiled heights."""
    n = len(model.names)
    eye = np.concatenate([np.zeros((1, n)), FD_STEP * np.eye(n)])

    def residual_jacobian(lp, z):
        lp = np.asarray(lp)
        batch = np.exp((lp[:, None, :] + eye[None]).reshape(-1, n))
        h = np.asarray(model.outputs(jnp.asarray(batch))).reshape(lp.shape[0], n + 1, -1)
        r = h[:, 0] - np.asarray(z).ravel()[None]
        return r, np.swapaxes((h[:, 1:] - h[:, :1]) / FD_STEP, 1, 2)

    return residual_jacobian


def run(label: str, make) -> dict:
    """Time a whole fit on a fresh model built by ``make(model)`` (compile included)."""
    t0 = time.perf_counter()
    model = chassis_traces(TS)
    z_true = np.asarray(model.outputs(jnp.asarray(TRUE[None])))[0]
    t_data = time.perf_counter() - t0
    noisy = z_true + SIGMA * np.random.default_rng(SEED).standard_normal(z_true.shape)
    log: list = []
    fitted = model._replace(residual_jacobian=_recorded(make(model), log))
    t1 = time.perf_counter()
    fit = fit_quarter_car(fitted, noisy, STARTS, sigma=SIGMA)
    wall = time.perf_counter() - t1
    rel = fit.p / TRUE - 1
    first_eval = log[0][0] - t1
    later = np.diff([t for t, _ in log])
    row = {"jacobian": label, "wall_s": wall, "first_evaluation_s": first_eval,
           "evaluation_s": float(np.median(later)) if later.size else None, "evaluations": fit.evaluations,
           "steps": fit.steps.tolist(), "converged": fit.converged.tolist(), "p": fit.p.tolist(),
           "rel_error": rel.tolist(), "rel_std": fit.rel_std.tolist(), "rms_m": fit.rms,
           "curve": [(t - t1, float(np.sqrt(c / noisy.size))) for t, c in log], "data_s": t_data}
    print(f"{label}: {wall:.1f} s whole fit (first evaluation, with compile, {first_eval:.1f} s), "
          f"{fit.evaluations} evaluations, max |rel error| {np.abs(rel).max():.1e}", flush=True)
    return row


def model_accuracy() -> float:
    """Largest chassis-height difference (m) of the measurement model against a projected tight reference."""
    model = chassis_traces(TS)
    ref = chassis_traces(TS, rtol=1e-11, atol=1e-13, stabilise=True)
    p = jnp.asarray(TRUE[None])
    return float(np.max(np.abs(np.asarray(model.outputs(p)) - np.asarray(ref.outputs(p)))))


def main() -> dict:
    rows = [run("forward-mode autodiff (ours)", lambda m: m.residual_jacobian),
            run("forward differences (same rollout)", _fd)]
    out = {"env": environment(), "names": ["spring_stiffness", "spring_damping", "tyre_stiffness", "chassis_mass",
                                           "wheel_mass"],
           "true": TRUE.tolist(), "starts": STARTS.tolist(), "sigma_m": SIGMA, "samples": [2, TS.size],
           "payloads_kg": [0.0, 100.0], "model_error_m": model_accuracy(), "rows": rows}
    write(out)
    return out


def write(out: dict) -> None:
    write_json(NAME, out, indent=1, newline=False)
    write_table(NAME, ["jacobian", "wall_s", "first_evaluation_s", "evaluation_s", "evaluations"]
                + [f"rel_error_{n}" for n in out["names"]] + [f"rel_std_{n}" for n in out["names"]],
                ([r["jacobian"], r["wall_s"], r["first_evaluation_s"], r["evaluation_s"], r["evaluations"]]
                 + r["rel_error"] + r["rel_std"] for r in out["rows"]))
    plot(out)
    print(markdown(out))


def plot(out: dict) -> None:
    fig, (ax, bx) = pyplot().subplots(1, 2, figsize=(12, 4.2))
    for r in out["rows"]:
        t, rms = zip(*r["curve"])
        ax.semilogy(t, np.minimum.accumulate(rms), "o-", ms=3, label=r["jacobian"])
    ax.axhline(out["sigma_m"], color="k", ls="--", lw=0.8, label="noise sigma")
    ax.set_xlabel("wall time from the call, compile included [s]")
    ax.set_ylabel("best RMS residual so far [m]")
    ax.set_title("Quarter car: Gauss–Newton from two starts 20 % off")
    ax.legend(fontsize=8)
    x = np.arange(len(out["names"]))
    for k, r in enumerate(out["rows"]):
        bx.bar(x + 0.27 * (k - 0.5), np.abs(r["rel_error"]), 0.27, label=f"|error|, {r['jacobian']}")
    bx.plot(x, 2 * np.asarray(out["rows"][0]["rel_std"]), "k_", ms=20, mew=2, label="2 Gauss–Newton std")
    bx.axhline(1e-3, color="r", ls=":", label="0.1 %")
    bx.set_yscale("log")
    bx.set_xticks(x, [n.replace("_", "\n") for n in out["names"]], fontsize=8)
    bx.set_ylabel("relative error")
    bx.legend(fontsize=7)
    save_figure(fig, NAME, dpi=100, tight=True)


def markdown(out: dict) -> str:
    env = out["env"]
    lines = ["### Identification: quarter-car constants and masses by autodiff", "",
             f"Chassis-height traces of two free responses (no payload, +100 kg), 2 x {out['samples'][1]} samples, "
             f"noise sigma = {out['sigma_m']:.0e} m; Gauss–Newton from two starts 20 % off, vmapped; whole fit "
             f"timed from a fresh model, compile included. Measurement model against a tight reference: "
             f"{out['model_error_m']:.1e} m.", "",
             "| Jacobian | whole fit | first evaluation (compile) | per evaluation | evaluations | "
             + " | ".join(n.replace("_", " ") for n in out["names"]) + " |",
             "|---|---:|---:|---:|---:|" + "---:|" * len(out["names"])]
    for r in out["rows"]:
        errs = " | ".join(f"{e:+.1e} ({s:.1e})" for e, s in zip(r["rel_error"], r["rel_std"]))
        lines.append(f"| {r['jacobian']} | {r['wall_s']:.1f} s | {r['first_evaluation_s']:.1f} s | "
                     f"{r['evaluation_s']:.2f} s | {r['evaluations']} | {errs} |")
    lines += ["", "Relative errors of the fitted constants (Gauss–Newton standard error in brackets). "
              f"{env['cpu']}, {env['cpu_count']} cores, jax {env['versions']['jax']}, diffrax {env['versions']['diffrax']}.",
              ""]
    return "\n".join(lines)


if __name__ == "__main__":
    main()
