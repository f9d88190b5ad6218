"""Work against precision, shared by the scene benchmarks (``wp_*.py``, ``quarter_car.py``, ``events.py``).

Every scene is run by our diffrax solvers over a sweep of tolerances and by its MuJoCo C / MJX twins over a sweep
of fixed steps, all against one reference trajectory (ours, Dopri8 at a tight tolerance, float64). Each run is one
*row*:

    method, setting, wall_s (least of repeats, compile excluded), compile_s, error (final state), max_error (largest
    error over the saved trajectory), steps, rejected, plus scene-specific extras.

Rows come from :func:`sweep_public` (ours as a user calls it; :func:`public_runner` builds the runner),
:func:`sweep_ours` (ours jitted here; :func:`compile_ours` compiles one solver's run with tolerances traced, and
passing one ``compiled`` dict to both lets the reference and the sweep share a compile), :func:`sweep_rollout`
(a MuJoCo C twin in its native loop) and :func:`sweep_fixed` (any other fixed-step twin). :func:`finish` adds the
headline (per method, the cheapest run whose error reaches the target), the speed ratios at equal error and the
goal sentences (:func:`headline_notes`: ≥ 2× faster than MJX, no slower than MuJoCo C); :func:`conclude` times the
headline ratio again interleaved (:func:`check_interleaved`) and stamps the elapsed time; :func:`write` writes
``results/<name>.{json,csv,png}``; :func:`markdown` renders the section of ``benchmarks/README.md``; :func:`main` is
a module's ``main``. A scene measured against its MuJoCo C twin alone gets all of that from :func:`against_twin`,
given its :class:`Scene`, runner, reference, twin rows and notes.

Wall times: the least over ``repeat`` runs, the first included (functions are compiled beforehand); short runs are
repeated until they have taken ``MIN_TOTAL_S`` (at most ``MAX_REPEAT`` times), a row stops once it has taken
``ROW_BUDGET_S``.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Sequence
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from particlesim import compiler_options
from particlesim.mechanism import simulate_mechanism
from particlesim.twins import callbacks as mjcb

from ._common import environment, machine, pyplot, report, save_figure, timed, write_csv, write_json

__all__ = ["Errors", "Scene", "against_twin", "check_interleaved", "compile_ours", "conclude", "finish", "fmt_time",
           "headline", "headline_notes", "main", "markdown", "markdown_without_mjx", "public_runner", "say",
           "sweep_fixed", "sweep_ours", "sweep_public", "sweep_rollout", "write"]


def say(row: object) -> None:
    """The sweeps' default log: each row printed as it is measured (flushed, so a long run's log is current when
    piped)."""
    print(row, flush=True)


class Errors:
    """Errors of a trajectory ``(T, k)`` (or ``(T,)``) against the reference: the final-state error (max norm
    over the observed components at the last save time) and the largest error over all save times."""

    def __init__(self, reference):
        self.ref = np.asarray(reference, dtype=float)

    def __call__(self, traj) -> dict:
        t = np.asarray(traj, dtype=float)
        d = np.abs(t - self.ref)
        if not np.all(np.isfinite(d)):
            if np.all(np.isnan(t[:-1])) and np.all(np.isfinite(d[-1])):  # final state only (steps off the grid)
                return {"error": float(np.max(d[-1])), "max_error": float("nan")}
            return {"error": float("inf"), "max_error": float("inf")}
        return {"error": float(np.max(d[-1])), "max_error": float(np.max(d))}


#: A row's repeats stop once they have taken this long (the first run counts): slow rows are timed fewer times.
ROW_BUDGET_S = 10.0
#: Short runs are repeated at least until they have taken this long in all (up to MAX_REPEAT times).
MIN_TOTAL_S = 0.3
MAX_REPEAT = 30


def _time(fn: Callable[[], object], repeat: int, block: Callable) -> tuple[object, float]:
    """``(output of the first run, least wall time over the repeats)``. The machine is shared and its load
    fluctuates; the least time is the least disturbed run, and every method (ours, MuJoCo C, MJX) is timed the
    same way. At least ``repeat`` runs, more for short ones (until ``MIN_TOTAL_S``, at most ``MAX_REPEAT``), fewer
    once a row has taken ``ROW_BUDGET_S``."""
    times, out = [], None
    while (len(times) < repeat or (sum(times) < MIN_TOTAL_S and len(times) < MAX_REPEAT)) and \
            (not times or sum(times) < ROW_BUDGET_S):
        t = time.perf_counter()
        o = block(fn())
        times.append(time.perf_counter() - t)
        out = o if out is None else out
    return out, float(np.min(times))


def compile_ours(make: Callable[[str], Callable], args: Sequence, solver: str, compiled: dict | None = None, *,
                 rtol: float = 1e-6, atol_ratio: float = 1e-2) -> tuple[float, Callable]:
    """``(compile_s, fn)`` for ``make(solver)`` jitted and compiled at ``args`` (tolerances are traced, so one
    compile serves every tolerance). With a ``compiled`` dict the result is cached there by solver name."""
    if compiled is not None and solver in compiled:
        return compiled[solver]
    r, a = jnp.asarray(rtol), jnp.asarray(rtol * atol_ratio)
    out = timed(lambda: jax.jit(make(solver), compiler_options=compiler_options()).lower(*args, r, a).compile())
    if compiled is not None:
        compiled[solver] = out
    return out


def sweep_ours(make: Callable[[str], Callable], args: Sequence, solvers: Iterable[str], rtols: dict | Sequence,
               errors: Errors, *, atol_ratio: float = 1e-2, repeat: int = 3, log: Callable = say,
               compiled: dict | None = None, label: Callable[[str], str] | None = None) -> list[dict]:
    """Rows of our solvers. ``make(solver)`` returns ``fn(*args, rtol, atol) -> (traj, steps, rejected)``; it is
    compiled once per solver (tolerances are traced arguments) and timed per tolerance. ``rtols``: one sequence
    for all solvers or a dict solver -> sequence. ``compiled``: a cache shared with :func:`compile_ours`.
    ``label(solver)``: the row's method name (default ``"ours <solver>"``)."""
    compiled = {} if compiled is None else compiled
    rows = []
    for solver in solvers:
        sweep = rtols[solver] if isinstance(rtols, dict) else rtols
        comp, f = compile_ours(make, args, solver, compiled, atol_ratio=atol_ratio)
        for rtol in sweep:
            r, a = jnp.asarray(rtol), jnp.asarray(rtol * atol_ratio)
            (traj, steps, rej), wall = _time(lambda: f(*args, r, a), repeat, jax.block_until_ready)
            rows.append({"method": label(solver) if label else f"ours {solver}", "setting": f"rtol {rtol:g}",
                         "wall_s": wall, **errors(traj), "steps": int(steps), "rejected": int(rej),
                         "compile_s": comp})
            log(rows[-1])
    return rows


def sweep_fixed(method: str, dts: Iterable[float], run: Callable[[float], object], errors: Errors, t_end: float, *,
                compile_s: float | None = None, repeat: int = 3, block: Callable = lambda x: x,
                extra: Callable[[object], dict] | None = None, setting: Callable[[float], str] | None = None,
                log: Callable = say, traj: Callable[[object], object] | None = None) -> list[dict]:
    """Rows of a fixed-step twin: ``run(dt)`` returns the observed trajectory, or a dict with key ``"traj"``, or
    anything ``traj(out)`` maps to the trajectory. ``extra(out)`` may add columns (e.g. a loop residual)."""
    rows = []
    for dt in dts:
        out, wall = _time(lambda: run(dt), repeat, block)
        tr = traj(out) if traj else (out["traj"] if isinstance(out, dict) else out)
        rows.append({"method": method, "setting": setting(dt) if setting else f"dt {dt:g}", "wall_s": wall,
                     **errors(tr), "steps": int(round(t_end / dt)), "rejected": 0, "compile_s": compile_s,
                     **(extra(out) if extra else {})})
        log(rows[-1])
    return rows


def public_runner(mech, x0, xd0, t_end: float, ts, observe: Callable, *, atol_ratio: float = 1e-2,
                  **options) -> Callable:
    """``run(solver, rtol, saves=True)`` as :func:`sweep_public` takes it: ``simulate_mechanism`` as a user calls
    it, from ``(x0, xd0)`` over ``[0, t_end]`` at atol = rtol × ``atol_ratio``, with ``options`` (``max_steps``,
    ``events``, ...). With ``saves`` it saves at ``ts`` and returns the observed trajectory ``observe(solution)``,
    without it the end state only (what is timed); either with the steps and rejected steps."""

    def run(solver, rtol, saves=True):
        s = simulate_mechanism(mech, x0, xd0, 0.0, t_end, solver=solver, rtol=rtol, atol=rtol * atol_ratio,
                               saveat_ts=ts if saves else None, **options)
        q = s.q.block_until_ready()
        return (observe(s) if saves else q), s.steps, s.rejected

    return run


def sweep_public(label: str, solvers: Iterable[str], rtols: dict | Sequence, run: Callable, errors: Errors, *,
                 repeat: int = 5, log: Callable = say) -> list[dict]:
    """Rows of ours through the public entry point, as a user calls it (no jit of our own: the entry point caches
    its compiled program per structure and settings).

    ``run(solver, rtol, saves)``: with ``saves=True`` the observed trajectory at the save times (untimed; it gives
    both errors), with ``saves=False`` the same rollout saving its end state only, which is what is timed (the
    measure is the final state, as for MuJoCo's rollout). Each returns ``(traj, steps, rejected)``. The first timed
    call of each solver compiles; its extra time over the least is the row's ``compile_s``."""
    rows = []
    for solver in solvers:
        sweep = rtols[solver] if isinstance(rtols, dict) else rtols
        comp = None
        for rtol in sweep:
            full = run(solver, rtol, True)
            t = time.perf_counter()
            run(solver, rtol, False)
            t_first = time.perf_counter() - t
            _, wall = _time(lambda: run(solver, rtol, False), repeat, lambda o: o)
            if comp is None:
                comp = max(t_first - wall, 0.0)
            rows.append({"method": f"{label} {solver}", "setting": f"rtol {rtol:g}", "wall_s": wall,
                         **errors(full[0]), "steps": int(full[1]), "rejected": int(full[2]), "compile_s": comp})
            log(rows[-1])
    return rows


def sweep_rollout(method: str, dts: Iterable[float], make: Callable[[float], tuple], errors: Errors, t_end: float,
                  *, repeat: int = 5, log: Callable = say, setting: Callable[[float], str] | None = None,
                  extra: Callable | None = None) -> list[dict]:
    """Rows of a MuJoCo C twin through its native loop. ``make(dt) -> (rollout, to_traj)`` with ``rollout`` a
    :class:`benchmarks._native.Rollout` (only its call is timed) and ``to_traj(states)`` the observed trajectory at
    the save times. Runs whose states are not finite (unstable at that step) get an infinite error."""
    rows = []
    for dt in dts:
        ro, to_traj = make(dt)
        states, wall = ro.timed(repeat)
        traj = to_traj(states) if np.all(np.isfinite(states)) else np.full(1, np.inf)
        errs = errors(traj) if np.all(np.isfinite(traj)) and np.shape(traj) == errors.ref.shape else \
            {"error": float("inf"), "max_error": float("inf")}
        rows.append({"method": method, "setting": setting(dt) if setting else f"dt {dt:g}", "wall_s": wall,
                     **errs, "steps": int(round(t_end / dt)), "rejected": 0, "compile_s": None, "dt": dt,
                     **(extra(ro, states) if extra else {})})
        log(rows[-1])
    return rows


#: A failing run brackets the interpolation only if its error is within this factor of the target: beyond it the
#: run is outside the method's asymptotic regime (typically unstable: MuJoCo resets a diverging state and returns a
#: finite, meaningless error), and no time is interpolated across a stability limit.
INTERP_MAX = 1e3


def _interpolated(rows: list[dict], ok: dict, target: float, key: str) -> dict:
    """For a fixed-step method: the wall time at exactly ``target`` error, interpolated in log-log between the
    cheapest passing run and the next cheaper (failing, finite) run, so the baseline is not charged for the
    coarseness of the step grid. Returns ``ok`` with ``interp_wall_s`` added (its own wall time if no bracket)."""
    cheaper = [r for r in rows if r["wall_s"] < ok["wall_s"] and np.isfinite(r[key]) and target < r[key]
               <= INTERP_MAX * target and r.get("dt", 0) > ok.get("dt", 0)]
    out = dict(ok, interp_wall_s=ok["wall_s"])
    if cheaper:
        c = max(cheaper, key=lambda r: r["wall_s"])
        le0, le1 = np.log(ok[key]), np.log(c[key])
        if le1 > le0 and ok[key] > 0:
            w = (np.log(target) - le0) / (le1 - le0)
            out["interp_wall_s"] = float(np.exp((1 - w) * np.log(ok["wall_s"]) + w * np.log(c["wall_s"])))
            out["interp_dt"], out["interp_weight"] = c.get("dt"), float(w)  # for check_interleaved
    return out


def headline(rows: list[dict], target: float, key: str = "error") -> dict:
    """Per method, the cheapest run whose ``key`` error ("error": final state, "max_error": over the run) reaches
    ``target`` (fixed-step MuJoCo rows also carry ``interp_wall_s``, their time interpolated to the target, which
    the ratios use); our best of those, and the ratios of MuJoCo C's and MJX's best to it (> 1: ours faster)."""
    head = {}
    for method in dict.fromkeys(r["method"] for r in rows):
        mine = [r for r in rows if r["method"] == method]
        ok = [r for r in mine if np.isfinite(r[key]) and r[key] <= target]
        best = min(ok, key=lambda r: r["wall_s"]) if ok else None
        if best is not None and "dt" in best:
            best = _interpolated(mine, best, target, key)
        head[method] = best
    ours = [r for m, r in head.items() if m.startswith("ours") and r]
    best = min(ours, key=lambda r: r["wall_s"]) if ours else None
    ratios = {}
    for peer in ("MuJoCo C", "MJX"):
        cand = [r for m, r in head.items() if m.startswith(peer) and r]
        p = min(cand, key=lambda r: r.get("interp_wall_s", r["wall_s"])) if cand else None
        ratios[peer] = (p.get("interp_wall_s", p["wall_s"]) / best["wall_s"]) if (p and best) else None
    return {"headline": head, "ours_best": best, "speedup_vs": ratios}


#: :func:`check_interleaved`: laps, and runs per side per lap.
CHECK_LAPS = 15
CHECK_PER_LAP = 3


def check_interleaved(res: dict, ours: Callable[[str, float, bool], object],
                      peer_make: Callable[[float, dict], Callable], *, peer: str = "MuJoCo C",
                      laps: int = CHECK_LAPS, per_lap: int = CHECK_PER_LAP, log: Callable = say) -> dict | None:
    """The headline ratio to ``peer`` timed again with the two sides interleaved, by two estimators.

    The sweeps time every setting of one method before the next method's, minutes apart on a shared machine whose
    speed moves by tens of percent, and take each row's least of up to :data:`MAX_REPEAT` runs, which favours the
    side whose run times spread more (ours: Python, dispatch and XLA's threads around a short program; MuJoCo C's
    loop varies less). Here each lap runs ours at its headline setting, then the peer at its headline step and at
    the cheaper step its time is interpolated from (the headline's log-log weight), each side ``per_lap`` times.
    Recorded in ``res["interleaved"]`` (> 1: ours faster): ``ratio``, the median over laps of the ratio of the
    lap's least times (a typical call; quartiles beside it), and ``ratio_least``, the ratio of each side's least
    over all laps (the sweeps' estimator, at equal machine state). ``ours(solver, rtol, saves)``: ours as
    :func:`sweep_public` runs it (called with ``saves=False``, the end state only, blocking); ``peer_make(dt, row)``
    returns a callable running the peer (its headline ``row``) at step ``dt``."""
    best = res["ours_best"]
    cands = [r for m, r in res["headline"].items() if m.startswith(peer) and r]
    if best is None or not cands or not best["method"].startswith("ours "):
        return None
    p = min(cands, key=lambda r: r.get("interp_wall_s", r["wall_s"]))
    if "dt" not in p:
        return None
    solver, rtol = best["method"][len("ours "):], float(best["setting"].split()[1])
    dts = [p["dt"]] + ([p["interp_dt"]] if p.get("interp_dt") is not None else [])
    w = p.get("interp_weight", 0.0)
    runs = [lambda: ours(solver, rtol, False)] + [peer_make(dt, p) for dt in dts]
    for fn in runs:  # warm: the programs are compiled and the models built already
        fn()

    def lap(fn):
        ts = []
        for _ in range(per_lap):
            t = time.perf_counter()
            fn()
            ts.append(time.perf_counter() - t)
        return ts

    a = np.asarray([[lap(fn) for fn in runs] for _ in range(laps)])  # (laps, 1 + len(dts), per_lap)

    def peer_time(t):  # the peer's time at the target from its columns, as _interpolated does
        return t[..., 1] if len(dts) == 1 else np.exp((1 - w) * np.log(t[..., 1]) + w * np.log(t[..., 2]))

    lap_least = a.min(axis=2)
    ratio = peer_time(lap_least) / lap_least[:, 0]
    least = a.min(axis=(0, 2))
    out = {"peer": p["method"], "ours": f"{best['method']}, {best['setting']}", "peer_dts": dts, "weight": w,
           "laps": laps, "per_lap": per_lap, "ours_s": float(np.median(lap_least[:, 0])),
           "peer_s": float(np.median(peer_time(lap_least))), "ratio": float(np.median(ratio)),
           "ratio_quartiles": [float(x) for x in np.percentile(ratio, [25, 75])],
           "ours_least_s": float(least[0]), "peer_least_s": float(peer_time(least)),
           "ratio_least": float(peer_time(least) / least[0])}
    res["interleaved"] = out
    log(out)
    return out


def conclude(res: dict, started: float, ours: Callable | None = None, peer_make: Callable | None = None,
             **check) -> dict:
    """The end of a scene's run: with ``peer_make``, the headline ratio timed again interleaved
    (:func:`check_interleaved`, ``check`` its options); then any passive callback a twin builder installed is
    removed, and ``elapsed_s`` counts from ``started`` to now."""
    try:
        if peer_make is not None:
            check_interleaved(res, ours, peer_make, **check)
    finally:
        mjcb.uninstall()
    res["elapsed_s"] = time.perf_counter() - started
    return res


def finish(name: str, scene: str, t_end: float, target: float, unit: str, what: str, reference: dict,
           rows: list[dict], started: float, notes: Sequence[str] = (), key: str = "error",
           goals: Sequence[str] = ()) -> dict:
    """The results record: rows, headline (cheapest run per method whose ``key`` error reaches ``target``: "error"
    the final state, "max_error" the whole run) and the ratios of our best to MuJoCo C's and MJX's best at that
    error (> 1: ours faster). The notes end with the goal sentences (:func:`headline_notes`) of the peers in
    ``goals`` ("MJX", "MuJoCo C"); ``elapsed_s`` counts from ``started``."""
    h = headline(rows, target, key)
    res = {"benchmark": name, "scene": scene, "environment": environment(), "t_end_s": t_end,
           "target_error": target, "error_key": key, "unit": unit, "error_what": what, "reference": reference,
           "rows": rows, **h, "notes": list(notes)}
    res["notes"] += headline_notes(res, peers=goals)
    res["elapsed_s"] = time.perf_counter() - started
    return res


#: The peers our goals name, in the order :func:`headline_notes` states them.
PEERS = ("MJX", "MuJoCo C")


def headline_notes(results: dict, *, mjx_goal: float = 2.0, c_goal: float = 1.0,
                   peers: Sequence[str] = PEERS) -> list[str]:
    """Sentences on the goals at the target error: ours ≥ ``mjx_goal``× as fast as MJX and ≥ ``c_goal``×
    as fast as MuJoCo C (equal simulated time, so per simulated second too), each met, missed or not measurable;
    one per peer in ``peers``."""
    out = []
    for peer, goal in (("MJX", mjx_goal), ("MuJoCo C", c_goal)):
        if peer not in peers:
            continue
        x = results["speedup_vs"].get(peer)
        want = f"≥ {goal:g}× as fast as {peer}"
        tgt = f"{results['target_error']:g} {results['unit']}"
        if results["ours_best"] is None:
            out.append(f"Goal {want} at {tgt}: not measurable, no run of ours reached it.")
        elif x is None:
            out.append(f"Goal {want} at {tgt}: met by default, no {peer} run tried reached it.")
        else:
            out.append(f"Goal {want} at {tgt}: {'met' if x >= goal else 'missed'} ({x:.2f}×).")
    return out


def write(results: dict) -> None:
    """``results/<name>.json``, ``.csv`` and a two-panel ``.png`` (final and trajectory error against wall time)."""
    name = results["benchmark"]
    write_json(name, results)
    write_csv(name, results["rows"], list(dict.fromkeys(k for r in results["rows"] for k in r)))
    fig, axes = pyplot().subplots(1, 2, figsize=(11, 4.6), constrained_layout=True, sharey=True)
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
    save_figure(fig, name, dpi=110, title=f"{results['scene']}: work against precision "
                f"({results['environment']['cpu']}, {results['environment']['cpu_count']} cores)")


def fmt_time(s: float) -> str:
    return f"{s * 1e3:.1f} ms" if s < 10 else f"{s:.1f} s"


def _fmt(r: dict, unit: str) -> str:
    comp = "" if r.get("compile_s") is None else f"{r['compile_s']:.1f} s"
    wall = fmt_time(r["wall_s"])
    if r.get("interp_wall_s") is not None and r["interp_wall_s"] != r["wall_s"]:
        wall += f" ({fmt_time(r['interp_wall_s'])} at the target)"
    return (f"| {r['method']} | {r['setting']} | {wall} | {r['error']:.1e} | "
            f"{r['max_error']:.1e} | {r['steps']} | {comp} |")


def _relative(x: float) -> str:
    return f"{x:.2f}× faster" if x >= 1 else f"{1 / x:.2f}× slower"


def _interleaved_line(chk: dict) -> str:
    q = sorted(chk["ratio_quartiles"])
    spread = f"{q[0]:.2f}–{q[1]:.2f}" if chk["ratio"] >= 1 else f"{1 / q[1]:.2f}–{1 / q[0]:.2f}"
    line = (f"Interleaved check of that ratio ({chk['laps']} laps of {chk['per_lap']} runs per side; "
            f"`_wp.check_interleaved`), against {chk['peer']} at the target (steps "
            f"{', '.join(f'{d:g}' for d in chk['peer_dts'])} s): median over laps of each lap's least times, ours "
            f"{fmt_time(chk['ours_s'])} against {fmt_time(chk['peer_s'])}: ours **{_relative(chk['ratio'])}** "
            f"(lap quartiles {spread}×)")
    if "ratio_least" in chk:
        line += (f"; each side's least over all laps, ours {fmt_time(chk['ours_least_s'])} against "
                 f"{fmt_time(chk['peer_least_s'])}: {_relative(chk['ratio_least'])}")
    return line + "."


def markdown(results: dict, *, all_rows: bool = False) -> str:
    unit = results["unit"]
    lines = [f"### {results['scene']}: work against precision ({results['t_end_s']:g} s)", "",
             f"{machine(results['environment'])}. Error = {results['error_what']} [{unit}], against "
             f"{results['reference']['what']}. Wall time per run (least of repeats), compile excluded and listed "
             f"separately; benchmark took "
             f"{results['elapsed_s'] / 60:.1f} min.", ""]
    best, sp = results["ours_best"], results["speedup_vs"]
    if best:
        parts = []
        for peer, x in sp.items():
            if x is None:
                parts.append(f"{peer}: no run reached the target")
            else:
                parts.append(f"{x:.2f}× faster than {peer}" if x >= 1 else f"{1 / x:.2f}× slower than {peer}")
        over = " (largest over the run)" if results.get("error_key") == "max_error" else ""
        lines += [f"**At {results['target_error']:g} {unit}{over}: ours ({best['method']}, {best['setting']}) "
                  f"{fmt_time(best['wall_s'])}; " + "; ".join(parts) + ".**", ""]
        chk = results.get("interleaved")
        if chk:
            lines += [_interleaved_line(chk), ""]
    over = " over the whole run" if results.get("error_key") == "max_error" else ""
    lines += [f"Cheapest run reaching {results['target_error']:g} {unit}{over}:", "",
              "| method | setting | wall time | final error | max error | steps | compile |",
              "|---|---|---:|---:|---:|---:|---:|"]
    for method, r in results["headline"].items():
        lines.append(_fmt(r, unit) if r else f"| {method} | none of the settings tried | | | | | |")
    if all_rows:
        lines += ["", "All runs:", "", "| method | setting | wall time | final error | max error | steps | compile |",
                  "|---|---|---:|---:|---:|---:|---:|"] + [_fmt(r, unit) for r in results["rows"]]
    lines += [""] + [f"{n}" for n in results["notes"]] + [""]
    return "\n".join(lines)


def markdown_without_mjx(results: dict) -> str:
    """All rows, the headline's MJX clause replaced by "(no MJX row)"."""
    return markdown(results, all_rows=True).replace("; MJX: no run reached the target", " (no MJX row)")


def main(run: Callable[[], dict], to_markdown: Callable[[dict], str]) -> dict:
    """A benchmark module's ``main``: run, write JSON/CSV/PNG, print the table and the elapsed time."""
    return report(run, write, to_markdown, devices=True, elapsed=True)


#: Wording the scene modules' notes share: how MuJoCo C ran, how its time is read at the target, how ours ran.
NATIVE_LOOP = "MuJoCo C runs in its native loop (`mujoco.rollout`, calling thread)"
INTERPOLATED = "the ratios use its time interpolated (log-log) to exactly the target between the bracketing steps"
OURS_PUBLIC = ("Ours: `simulate_mechanism` as a user calls it (compile cached, listed separately), timed saving the "
               "end state")


def soft_setting(dt: float) -> str:
    """The setting column of a twin whose loops are soft at MuJoCo's limit (``solref`` time constant 2 dt)."""
    return f"dt {dt:g} (solref {2 * dt:g} s)"


class Scene(NamedTuple):
    """What a scene's section states: its results name, title, simulated time [s], target error, the error's unit,
    what the error measures, and the error the target applies to ("error": the final state, "max_error": the
    largest over the run)."""

    name: str
    title: str
    t_end: float
    target: float
    unit: str
    what: str
    key: str = "error"


def against_twin(scene: Scene, build: Callable[[], tuple], twin_rows: Callable[[Errors], list[dict]],
                 sweep: dict, notes: Sequence[str], *, repeat: int = 5,
                 peer_make: Callable | None = None) -> tuple[Callable, Callable, Callable]:
    """``(run, markdown, main)`` of a module that measures ours against a MuJoCo C twin alone (no MJX row).

    ``build() -> (ours, reference, record)``: ``ours(solver, rtol, saves)`` as :func:`sweep_public` runs it, the
    reference trajectory the errors are taken against, and the results' ``reference`` record (``{"what": ...}``).
    Ours runs over ``sweep`` (solver -> rtols, ``repeat`` as in :func:`sweep_public`), the twin's rows are
    ``twin_rows(errors)``; the notes are ``notes`` and the MuJoCo C goal sentence. With ``peer_make`` the headline
    ratio is timed again interleaved (:func:`conclude`). The table lists every row (:func:`markdown_without_mjx`)."""

    def run() -> dict:
        started = time.perf_counter()
        ours, reference, record = build()
        errors = Errors(reference)
        rows = sweep_public("ours", list(sweep), sweep, ours, errors, repeat=repeat)
        rows += twin_rows(errors)
        res = finish(*scene[:6], record, rows, started, notes, key=scene.key, goals=("MuJoCo C",))
        return conclude(res, started, ours, peer_make)

    def module_main() -> dict:
        return main(run, markdown_without_mjx)

    return run, markdown_without_mjx, module_main
