"""Report: identification of Krang's left arm (7 joints) from the hardware runs; test-set torque RMSE table.

``python -m particlesim.reports.identify_arm [--out out] [--step 1] [--starts 3] [--max-steps 2000] [--rollout]``
writes ``out/identify_arm.{json,md,png}``.

Pipeline (all on the lab's signals and row alignment, :func:`particlesim.identify.load_arm_run`):

1. ``URDF``: rigid-body inverse dynamics of ``krang_single_arm_2018.urdf`` (gravity (0, -9.81, 0) in the Bracket
   frame), no friction or rotor inertia.
2. ``OLS (lab model)``: our unconstrained least squares of the lab's 13-per-joint model (autodiff rigid-body
   regressor + rotor ``qdd`` + ``qd`` + ``tanh(qd)``), all training samples.
3. ``Ours``: the same regressor with the Coulomb sign smoothed as ``tanh(qd / eps)``, every body kept physically
   consistent (log-Cholesky pseudo-inertias) and ``I_a, Fv, Fc > 0``, multi-start Levenberg–Marquardt.
   ``eps`` and whether current-saturated samples are fitted are chosen on a hold-out (last quarter of the
   training run) by the unconstrained fit's hold-out RMSE, then the model is refitted on the whole training run.
   Also shown: the unconstrained OLS with the same choices (what consistency costs).
4. Lab figures are quoted from the data README (not recomputed). Test RMSE is scored on *all* test samples,
   saturated ones included.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from ..data import data_dir
from ..identify import (
    compress, current_limits, fit_consistent, load_arm_run, ordinary_least_squares, params_from_theta,
    pseudo_inertia, regressor, rigid_regressor, theta_from_params,
)

__all__ = ["identify_arm", "select_friction_model", "QUOTED_LAB", "EPS_GRID"]

#: Pooled test RMSE (N m) quoted from ``shared/data/README.md`` (lab's own identification; not recomputed).
QUOTED_LAB = {"lab arm_betaFull (quoted)": 10.2, "lab arm_betaConsistent (quoted)": 11.4}
EPS_GRID = (1.0, 0.1, 0.03, 0.01)  # rad/s, Coulomb smoothing candidates
HOLDOUT = 0.25


def _rmse(pred, tau):
    r = np.asarray(pred) - np.asarray(tau)
    return np.sqrt(np.mean(r ** 2, axis=0)), float(np.sqrt(np.mean(r ** 2)))


def select_friction_model(w_tr: dict, torque, saturated) -> tuple:
    """Choose the Coulomb smoothing ``eps`` (keys of ``w_tr``, regressors of the training run) and whether
    current-saturated samples are left out, by the unconstrained fit's RMSE on a hold-out (the last
    ``HOLDOUT`` of the training run). Returns ``(eps, drop_saturated, [(holdout_rmse, eps, drop), ...])``."""
    cut = int(len(torque) * (1 - HOLDOUT))
    fit_rows, val_rows = slice(0, cut), slice(cut, None)
    choices = []
    for e, w in w_tr.items():
        for drop in (False, True):
            mask = np.broadcast_to(~saturated[fit_rows] if drop else True, torque[fit_rows].shape)
            x = ordinary_least_squares(w[fit_rows], torque[fit_rows], mask)
            choices.append((_rmse(w[val_rows] @ x, torque[val_rows])[1], e, drop))
    _, eps, drop = min(choices)
    return eps, drop, choices


def identify_arm(out="out", *, step: int = 1, starts: int = 3, max_steps: int = 2000, rollout: bool = False,
                 seed: int = 0, verbose: bool = True) -> dict:
    """Run the pipeline above; ``step`` subsamples the *training* rows (test is always scored in full)."""
    from ..io import load_urdf
    from ..tree.model import origin_params_check

    t_start = time.time()
    root = data_dir() / "krang"
    model = load_urdf(root / "urdf" / "krang_single_arm_2018.urdf", gravity=(0.0, -9.81, 0.0))
    n = model.nq
    train = load_arm_run(root / "arm_hardware" / "train").subsample(step)
    test = load_arm_run(root / "arm_hardware" / "test")
    limits = current_limits(load_arm_run(root / "arm_hardware" / "train").current)
    sat_train = np.abs(train.current) >= limits
    say = print if verbose else (lambda *a, **k: None)
    say(f"train {len(train)} samples, test {len(test)}; current limits (A) {np.round(limits, 3).tolist()}; "
        f"saturated training samples per joint {sat_train.sum(0).tolist()}")

    rig_tr = np.asarray(rigid_regressor(model, train.q, train.qd, train.qdd))
    rig_te = np.asarray(rigid_regressor(model, test.q, test.qd, test.qdd))
    w_tr = {e: np.asarray(regressor(model, train.q, train.qd, train.qdd, eps=e, rigid=rig_tr)) for e in EPS_GRID}
    w_te = {e: np.asarray(regressor(model, test.q, test.qd, test.qdd, eps=e, rigid=rig_te)) for e in EPS_GRID}
    say(f"regressors built ({time.time() - t_start:.1f} s)")

    rows = {}
    urdf_pred = np.einsum("tjp,p->tj", rig_te, np.asarray(model.inertia).ravel())
    rows["URDF"] = _rmse(urdf_pred, test.torque)
    x_lab = ordinary_least_squares(w_tr[1.0], train.torque)
    rows["OLS, lab model (tanh qd, all samples)"] = _rmse(w_te[1.0] @ x_lab, test.torque)

    eps, drop, choices = select_friction_model(w_tr, train.torque, sat_train)
    say("hold-out RMSE (eps, drop saturated): " + ", ".join(f"({e:g}, {d}) {v:.2f}" for v, e, d in choices))
    say(f"chosen eps = {eps:g} rad/s, drop saturated samples = {drop}")
    mask = ~sat_train if drop else None
    x_ols = ordinary_least_squares(w_tr[eps], train.torque, mask)
    rows[f"OLS, tanh(qd/{eps:g}) (unconstrained, reference)"] = _rmse(w_te[eps] @ x_ols, test.torque)

    # Physically consistent fit, multi-start around the URDF with unit actuator parameters.
    pi_urdf = np.concatenate([np.asarray(model.inertia).ravel(), np.ones(3 * n)])
    th0 = np.asarray(theta_from_params(pi_urdf))
    rng = np.random.default_rng(seed)
    theta0 = np.stack([th0] + [th0 + 0.3 * rng.standard_normal(th0.shape) for _ in range(starts - 1)])
    lsq = compress(w_tr[eps], train.torque, mask)
    t_fit = time.time()
    say(f"consistent fit: {starts} starts (vmapped), Levenberg-Marquardt, up to {max_steps} steps")
    fit = fit_consistent(lsq, theta0, max_steps=max_steps, verbose=verbose)
    fit_seconds = time.time() - t_fit
    pi = fit.best_pi
    ours_label = "Ours: consistent, tanh(qd/%g)" % eps
    pred_te = w_te[eps] @ pi
    rows[ours_label] = _rmse(pred_te, test.torque)

    inertia = pi[:10 * n].reshape(n, 10)
    eig_min = np.linalg.eigvalsh(np.asarray(pseudo_inertia(inertia))).min(axis=1)
    consistent = []
    for i in range(n):
        try:
            origin_params_check(inertia[i], f"identified link '{model.link_names[i]}'")
            consistent.append(True)
        except ValueError:
            consistent.append(False)

    result = {
        "joints": list(model.joint_names),
        "test_rmse": {k: {"per_joint": v[0].tolist(), "pooled": v[1]} for k, v in rows.items()},
        "quoted_pooled_test_rmse": QUOTED_LAB,
        "eps": eps, "drop_saturated": bool(drop), "holdout_choices": [list(c) for c in choices],
        "train_step": step, "n_train": len(train), "n_test": len(test),
        "fit": {"starts": starts, "rmse_per_start": fit.rmse.tolist(), "steps": fit.steps.tolist(),
                "best": fit.best, "seconds": fit_seconds},
        "identified": {"inertia": inertia.tolist(), "rotor_inertia": pi[10 * n:11 * n].tolist(),
                       "viscous": pi[11 * n:12 * n].tolist(), "coulomb": pi[12 * n:].tolist()},
        "pseudo_inertia_min_eig": eig_min.tolist(), "check_inertia_passed": consistent,
    }
    if rollout:
        result["rollout"] = _rollout_stage(model, train, test, fit.best_theta, eps, say)
    result["seconds"] = time.time() - t_start
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "identify_arm.json").write_text(json.dumps(result, indent=1))
    (out / "identify_arm.md").write_text(_markdown(result))
    _plot(out / "identify_arm.png", test, pred_te, urdf_pred, model.joint_names, ours_label)
    say(_markdown(result))
    return result


def _rollout_stage(model, train, test, theta, eps, say):
    """Refine by simulation on a few 0.5 s training windows; report the RMS position error on test windows."""
    from ..identify import fit_rollout, make_windows, rollout_residuals

    w_tr = make_windows(train.t, train.q, train.qd, train.torque, length=51,
                        starts=np.linspace(50, len(train) - 60, 4).astype(int))
    w_te = make_windows(test.t, test.q, test.qd, test.torque, length=51,
                        starts=np.linspace(50, len(test) - 60, 4).astype(int))
    err = lambda th: float(np.sqrt(np.mean(np.asarray(rollout_residuals(th, model, w_te, eps=eps)) ** 2)))  # noqa
    before = err(theta)
    theta2, a, b = fit_rollout(theta, model, w_tr, eps=eps, max_steps=3)
    after = err(theta2)
    say(f"rollout: test-window RMS position error {before:.4f} -> {after:.4f} rad (train windows {a:.4f} -> {b:.4f})")
    return {"test_windows_rms_rad_before": before, "test_windows_rms_rad_after": after,
            "train_windows_rms_rad_before": a, "train_windows_rms_rad_after": b,
            "pi_after": np.asarray(params_from_theta(theta2)).tolist()}


def _markdown(res) -> str:
    joints = res["joints"]
    lines = ["| model | " + " | ".join(joints) + " | pooled |", "|---" * (len(joints) + 2) + "|"]
    for k, v in res["test_rmse"].items():
        lines.append(f"| {k} | " + " | ".join(f"{x:.2f}" for x in v["per_joint"]) + f" | **{v['pooled']:.2f}** |")
    for k, v in res["quoted_pooled_test_rmse"].items():
        lines.append(f"| {k} | " + " | ".join("–" for _ in joints) + f" | {v:.1f} |")
    lines += ["", "Test-set joint-torque RMSE (N m), all test samples. Pseudo-inertia minimum eigenvalues of the "
              "identified bodies: " + ", ".join(f"{e:.2e}" for e in res["pseudo_inertia_min_eig"])
              + f"; check_inertia passed on all: {all(res['check_inertia_passed'])}."]
    return "\n".join(lines) + "\n"


def _plot(path, test, pred, urdf_pred, names, label):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(names)
    fig, axes = plt.subplots(n, 1, figsize=(11, 2.0 * n), sharex=True)
    t = test.t - test.t[0]
    for j, ax in enumerate(axes):
        ax.plot(t, test.torque[:, j], "k", lw=0.8, label="measured")
        ax.plot(t, urdf_pred[:, j], color="0.6", lw=0.6, label="URDF")
        ax.plot(t, pred[:, j], "C3", lw=0.8, label=label)
        ax.set_ylabel(f"{names[j]} [N m]")
    axes[0].legend(loc="upper right", ncol=3, fontsize=8)
    axes[-1].set_xlabel("test time [s]")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--out", default="out")
    p.add_argument("--step", type=int, default=1, help="subsample training rows")
    p.add_argument("--starts", type=int, default=3)
    p.add_argument("--max-steps", type=int, default=2000)
    p.add_argument("--rollout", action="store_true", help="also refine by simulation (slow, ~2 min)")
    a = p.parse_args(argv)
    identify_arm(a.out, step=a.step, starts=a.starts, max_steps=a.max_steps, rollout=a.rollout)


if __name__ == "__main__":
    main()
