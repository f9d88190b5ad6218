"""Work against precision, shared by the scene benchmarks (``wp_*.py``, ``quarter_car.py``).

Every scene is run by our diffrax solvers over a sweep of tolerances and by its MuJoCo C / MJX twins over a sweep
of fixed steps, all against one reference trajectory (ours, Dopri8 at a tight tolerance, float64). Each run is one
*row*:

    method, setting, wall_s (median, compile excluded), compile_s, error (final state), max_error (largest
    error over the saved trajectory), steps, rejected, plus scene-specific extras.

:func:`sweep_ours` and :func:`sweep_fixed` produce rows; :func:`finish` adds the headline (per method, the cheapest
run whose final error reaches the target) and the speed ratios at equal error; :func:`write` writes
``results/<name>.{json,csv,png}``; :func:`markdown` renders the README section.
"""

from __future__ import annotations

import csv
import json
import time
from collections.abc import Callable, Iterable, Sequence

import jax
import jax.numpy as jnp
import numpy as np

from ._common import RESULTS, environment, median_time, timed

__all__ = ["Errors", "sweep_ours", "sweep_fixed", "finish", "write", "markdown", "fmt_time"]


class Errors:
    """Errors of a trajectory ``(T, k)`` (or ``(T,)``) against the reference: the final-state error (max norm
    over the observed components at the last save time) and the largest error over all save times."""

    def __init__(self, reference):
        self.ref = np.asarray(reference, dtype=float)

    def __call__(self, traj) -> dict:
        d = np.abs(np.asarray(traj, dtype=float) - self.ref)
        if not np.all(np.isfinite(d)):
            return {"error": float("inf"), "max_error": float("inf")}
        return {"error": float(np.max(d[-1])), "max_error": float(np.max(d))}


def sweep_ours(make: Callable[[str], Callable], args: Sequence, solvers: Iterable[str], rtols: dict | Sequence,
               errors: Errors, *, atol_ratio: float = 1e-2, repeat: int = 3, log: Callable = print) -> list[dict]:
    """Rows of our solvers. ``make(solver)`` returns ``fn(*args, rtol, atol) -> (traj, steps, rejected)``; it is
    compiled once per solver (tolerances are traced arguments) and timed per tolerance. ``rtols``: one sequence
    for all solvers or a dict solver -> sequence."""
    rows = []
    for solver in solvers:
        sweep = rtols[solver] if isinstance(rtols, dict) else rtols
        compiled, comp = None, None
        for rtol in sweep:
            r, a = jnp.asarray(rtol), jnp.asarray(rtol * atol_ratio)
            if compiled is None:
                comp, compiled = timed(lambda: jax.jit(make(solver)).lower(*args, r, a).compile())
            f = compiled
            wall = median_time(lambda: f(*args, r, a), number=1, repeat=repeat, block=jax.block_until_ready)
            traj, steps, rej = f(*args, r, a)
            rows.append({"method": f"ours {solver}", "setting": f"rtol {rtol:g}", "wall_s": wall, **errors(traj),
                         "steps": int(steps), "rejected": int(rej), "compile_s": comp})
            log(rows[-1])
    return rows


def sweep_fixed(method: str, dts: Iterable[float], run: Callable[[float], object], errors: Errors, t_end: float, *,
                compile_s: float | None = None, repeat: int = 3, block: Callable = lambda x: x,
                extra: Callable[[object], dict] | None = None, setting: Callable[[float], str] | None = None,
                log: Callable = print) -> list[dict]:
    """Rows of a fixed-step twin: ``run(dt)`` returns the observed trajectory (or a tuple/dict whose trajectory
    ``errors`` understands via ``extra``). ``extra(out)`` may add columns (e.g. a loop residual)."""
    rows = []
    for dt in dts:
        wall = median_time(lambda: run(dt), number=1, repeat=repeat, block=block)
        out = run(dt)
        traj = out["traj"] if isinstance(out, dict) else out
        rows.append({"method": method, "setting": setting(dt) if setting else f"dt {dt:g}", "wall_s": wall,
                     **errors(traj), "steps": int(round(t_end / dt)), "rejected": 0, "compile_s": compile_s,
                     **(extra(out) if extra else {})})
        log(rows[-1])
    return rows


def _best(rows: list[dict], target: float) -> dict:
    out = {}
    for method in dict.fromkeys(r["method"] for r in rows):
        ok = [r for r in rows if r["method"] == method and r["error"] <= target]
        out[method] = min(ok, key=lambda r: r["wall_s"]) if ok else None
    return out


def finish(name: str, scene: str, t_end: float, target: float, unit: str, what: str, reference: dict,
           rows: list[dict], started: float, notes: Sequence[str] = ()) -> dict:
    """The results record: rows, headline (cheapest run per method reaching ``target``) and the ratios of our
    best to MuJoCo C's and MJX's best at that error (> 1: ours faster)."""
    head = _best(rows, target)
    ours = [r for m, r in head.items() if m.startswith("ours") and r]
    best = min(ours, key=lambda r: r["wall_s"]) if ours else None
    ratios = {}
    for peer in ("MuJoCo C", "MJX"):
        cand = [r for m, r in head.items() if m.startswith(peer) and r]
        p = min(cand, key=lambda r: r["wall_s"]) if cand else None
        ratios[peer] = (p["wall_s"] / best["wall_s"]) if (p and best) else None
    return {"benchmark": name, "scene": scene, "environment": environment(), "t_end_s": t_end,
            "target_error": target, "unit": unit, "error_what": what, "reference": reference, "rows": rows,
            "headline": head, "ours_best": best, "speedup_vs": ratios, "notes": list(notes),
            "elapsed_s": time.perf_counter() - started}


def write(results: dict) -> None:
    """``results/<name>.json``, ``.csv`` and a two-panel ``.png`` (final and trajectory error against wall time)."""
    name = results["benchmark"]
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / f"{name}.json").write_text(json.dumps(results, indent=2) + "\n")
    keys = list(dict.fromkeys(k for r in results["rows"] for k in r))
    with open(RESULTS / f"{name}.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=keys, restval="")
        w.writeheader()
        w.writerows(results["rows"])
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.6), constrained_layout=True, sharey=True)
    for ax, key, label in ((axes[0], "error", "final-state error"), (axes[1], "max_error", "largest error over the run")):
        for i, method in enumerate(dict.fromkeys(r["method"] for r in results["rows"])):
            sel = [r for r in results["rows"] if r["method"] == method and np.isfinite(r[key])]
            if not sel:
                continue
            style = "-" if method.startswith("ours") else "--"
            ax.loglog([max(r[key], 1e-16) for r in sel], [r["wall_s"] for r in sel], style, marker="o", ms=4,
                      label=method)
        ax.axvline(results["target_error"], color="grey", ls=":", lw=1)
        ax.set_xlabel(f"{label} [{results['unit']}]")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel(f"wall time for {results['t_end_s']:g} s simulated [s] (compile excluded)")
    axes[1].legend(fontsize=7)
    fig.suptitle(f"{results['scene']}: work against precision ({results['environment']['cpu']}, "
                 f"{results['environment']['cpu_count']} cores)", fontsize=9)
    fig.savefig(RESULTS / f"{name}.png", dpi=110)
    plt.close(fig)


def fmt_time(s: float) -> str:
    return f"{s * 1e3:.1f} ms" if s < 10 else f"{s:.1f} s"


def _fmt(r: dict, unit: str) -> str:
    comp = "" if r.get("compile_s") is None else f"{r['compile_s']:.1f} s"
    return (f"| {r['method']} | {r['setting']} | {fmt_time(r['wall_s'])} | {r['error']:.1e} | "
            f"{r['max_error']:.1e} | {r['steps']} | {comp} |")


def markdown(results: dict, *, all_rows: bool = False) -> str:
    env, unit = results["environment"], results["unit"]
    load = env["load_average_1_5_15min"][0]
    lines = [f"### {results['scene']}: work against precision ({results['t_end_s']:g} s)", "",
             f"{env['cpu']}, {env['cpu_count']} cores, load average {load:.1f} (1 min), {env['date']}. "
             f"Error = {results['error_what']} [{unit}], against {results['reference']['what']}. Wall time per "
             f"run (median of repeats), compile excluded and listed separately; benchmark took "
             f"{results['elapsed_s'] / 60:.1f} min.", ""]
    best, sp = results["ours_best"], results["speedup_vs"]
    if best:
        parts = []
        for peer, x in sp.items():
            if x is None:
                parts.append(f"{peer}: no run reached the target")
            else:
                parts.append(f"{x:.2f}× faster than {peer}" if x >= 1 else f"{1 / x:.2f}× slower than {peer}")
        lines += [f"**At {results['target_error']:g} {unit}: ours ({best['method']}, {best['setting']}) "
                  f"{fmt_time(best['wall_s'])}; " + "; ".join(parts) + ".**", ""]
    lines += [f"Cheapest run reaching {results['target_error']:g} {unit}:", "",
              "| method | setting | wall time | final error | max error | steps | compile |",
              "|---|---|---:|---:|---:|---:|---:|"]
    for method, r in results["headline"].items():
        lines.append(_fmt(r, unit) if r else f"| {method} | none of the settings tried | | | | | |")
    if all_rows:
        lines += ["", "All runs:", "", "| method | setting | wall time | final error | max error | steps | compile |",
                  "|---|---|---:|---:|---:|---:|---:|"] + [_fmt(r, unit) for r in results["rows"]]
    lines += [""] + [f"{n}" for n in results["notes"]] + [""]
    return "\n".join(lines)
