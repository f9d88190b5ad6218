"""Identification of Krang's real left arm: ours beside MuJoCo's own ``mujoco.sysid``, same data, model and loss.

Data: ``krang/arm_hardware`` (train and test runs, the lab's row alignment; :func:`particlesim.identify.load_arm_run`).
Model: ``krang_single_arm_2018.urdf``, 7 joints; for MuJoCo its twin ``particlesim.twins.urdf.mujoco_spec`` (the same
rigid tree: inverse dynamics agree to round-off, checked below before anything is timed).

Both tools fit the same thing: joint torque ``tau = ID(q, qd, qdd; bodies) + I_a qdd + Fv qd + Fc tanh(qd / eps)``
on the same training rows, every body kept physically consistent by the same Rucker–Wensing log-Cholesky
pseudo-inertia parameters (``mujoco.sysid.InertiaType.Pseudo``; ours :mod:`particlesim.identify._params`), from the
same starts (the URDF bodies with unit actuator parameters, and random perturbations of it). The Coulomb smoothing
``eps`` and whether current-saturated samples are fitted are chosen once, on a hold-out of the training run, by
:func:`particlesim.reports.identify_arm.select_friction_model`, and used by both.

- **Ours**: the linear-in-parameters regressor by autodiff, QR-compressed once, then Levenberg–Marquardt
  (optimistix) with autodiff Jacobians, all starts vmapped in one compiled call (:func:`particlesim.identify.
  fit_consistent`). Wall time includes building the regressor and every compile.
- **mujoco.sysid**: its ``Parameter``/``ParameterDict`` with ``body_inertia_param(..., InertiaType.Pseudo)`` per
  body, armature and damping written into the spec by modifiers, and ``mujoco.sysid.optimize`` with its default
  backend (``mujoco.minimize.least_squares``: box-bounded Gauss–Newton/LM with finite-difference Jacobians). Its
  rollout residual compares simulated sensors with measured ones; a torque residual is what this data supports, so
  the residual function (the ``(x, params) -> (residuals, ...)`` callable ``optimize`` takes) builds the model from
  the parameters with sysid's own modifiers and evaluates ``mj_inverse`` on every training sample. MuJoCo has no
  smooth Coulomb element for inverse dynamics (``frictionloss`` is a constraint force), so ``Fc tanh(qd/eps)`` is a
  sysid ``Parameter`` added in the residual. Box bounds are widened (mass x[1e-2, 1e2], principal stretches
  x[1e-4, 1e4], shears and CoM terms +-10) so they do not bind where ours has no bounds.

Scored for both: pooled and per-joint test-set torque RMSE (all test samples), training RMSE on the fitted rows, the
minimum pseudo-inertia eigenvalue of every body, wall time and evaluations to convergence, and the time each needs
to reach ours' training loss (+0.1 %).

Run: ``python -m benchmarks.identification`` (about 20-30 min: sysid's finite-difference Jacobians dominate).
``python -m benchmarks.identification uncertainty`` (or ``simulated``) reruns only that section into the saved results.
"""

from __future__ import annotations

import json
import sys
import time
import warnings

import mujoco
import numpy as np

from particlesim.data import data_dir
from particlesim.identify import (
    arm_data_from_arrays, base_uncertainty, bootstrap_base, compress, current_limits, fit_base_consistent,
    robust_base_uncertainty,
    fit_consistent, identifiable_basis, load_arm_run, ordinary_least_squares, params_from_pseudo_inertia, params_from_theta,
    pseudo_inertia, regressor, rigid_regressor, theta_from_params,
)
from particlesim.twins.urdf import mujoco_spec
from particlesim.reports.identify_arm import EPS_GRID, select_friction_model
from particlesim.tree import inverse_dynamics
from particlesim.io import load_urdf

from ._common import RESULTS, environment, pyplot, save_figure, write_json, write_table

NAME = "identification"
GRAVITY = (0.0, -9.81, 0.0)
STARTS = 3
SPREAD = 0.3  # start perturbation in the unconstrained coordinates (as the arm report)
SEED = 0
OURS_MAX_STEPS = 2000
SYSID_MAX_ITERS = 100
TWIN_TOL = 1e-9  # N m: MuJoCo twin (through sysid's modifiers) vs our inverse dynamics at the URDF values
REACH = 1e-3  # "same training loss": within 0.1 % of ours' best
BASE_RTOL = 1e-6  # singular-value cut defining the base parameters (column-scaled regressor)
WELL_IDENTIFIED = 0.1  # relative standard error below which a base parameter counts as well identified
BOOT = 50  # bootstrap resamples
BLOCK = 100  # samples per bootstrap block (1 s at 100 Hz)
SIM_LEVELS = (0.0, 0.01, 0.05)
SIM_EPS = 0.05
SIM_ROTOR = np.array([3.0, 3.0, 2.5, 2.5, 0.8, 0.8, 0.5])
SIM_VISCOUS = np.array([60.0, 55.0, 50.0, 40.0, 12.0, 10.0, 8.0])
SIM_COULOMB = np.array([8.0, 9.0, 7.0, 6.0, 3.0, 2.5, 2.0])


def _rmse(pred, tau):
    r = np.asarray(pred) - np.asarray(tau)
    return np.sqrt(np.mean(r ** 2, axis=0)), float(np.sqrt(np.mean(r ** 2)))


def _inverse(m: mujoco.MjModel, d: mujoco.MjData, q, qd, qdd) -> np.ndarray:
    out = np.empty_like(q)
    for k in range(q.shape[0]):
        d.qpos[:] = q[k]
        d.qvel[:] = qd[k]
        d.qacc[:] = qdd[k]
        mujoco.mj_inverse(m, d)
        out[k] = d.qfrc_inverse
    return out


def problem() -> dict:
    root = data_dir() / "krang"
    urdf = root / "urdf" / "krang_single_arm_2018.urdf"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # joint limits: not part of inverse dynamics
        model = load_urdf(urdf, gravity=GRAVITY)
    train = load_arm_run(root / "arm_hardware" / "train")
    test = load_arm_run(root / "arm_hardware" / "test")
    sat = np.abs(train.current) >= current_limits(train.current)
    t0 = time.perf_counter()
    rig = np.asarray(rigid_regressor(model, train.q, train.qd, train.qdd))
    build_rigid = time.perf_counter() - t0
    w_tr = {e: np.asarray(regressor(model, train.q, train.qd, train.qdd, eps=e, rigid=rig)) for e in EPS_GRID}
    eps, drop, choices = select_friction_model(w_tr, train.torque, sat)
    mask = ~sat if drop else np.ones_like(sat)
    return dict(urdf=urdf, model=model, train=train, test=test, eps=eps, drop=drop, mask=mask, rigid=rig,
                build_rigid=build_rigid, choices=choices)


def starts(p: dict) -> np.ndarray:
    """``(STARTS, 13 n)`` physical parameter vectors: URDF + unit actuator parameters, then perturbations."""
    n = p["model"].nq
    pi0 = np.concatenate([np.asarray(p["model"].inertia).ravel(), np.ones(3 * n)])
    th0 = np.asarray(theta_from_params(pi0))
    rng = np.random.default_rng(SEED)
    th = np.stack([th0] + [th0 + SPREAD * rng.standard_normal(th0.shape) for _ in range(STARTS - 1)])
    return np.asarray(params_from_theta(th))


def _score(p, pi_inertia, predict_test, train_rmse, label) -> dict:
    per_joint, pooled = _rmse(predict_test, p["test"].torque)
    eig = np.linalg.eigvalsh(np.asarray(pseudo_inertia(pi_inertia))).min(axis=1)
    return {"tool": label, "test_rmse_pooled": pooled, "test_rmse_per_joint": per_joint.tolist(),
            "train_rmse": train_rmse, "pseudo_inertia_min_eig": eig.tolist(), "consistent": bool(np.all(eig > 0))}


def run_ours(p: dict, pi_starts: np.ndarray) -> dict:
    n = p["model"].nq
    test = p["test"]
    t0 = time.perf_counter()
    # the regressor at the chosen eps (rigid part timed when it was first built, compile included)
    w = np.asarray(regressor(p["model"], p["train"].q, p["train"].qd, p["train"].qdd, eps=p["eps"],
                             rigid=p["rigid"]))
    lsq = compress(w, p["train"].torque, p["mask"])
    fit = fit_consistent(lsq, np.asarray(theta_from_params(pi_starts)), max_steps=OURS_MAX_STEPS, verbose=False)
    wall = time.perf_counter() - t0
    pi = fit.best_pi
    w_te = np.asarray(regressor(p["model"], test.q, test.qd, test.qdd, eps=p["eps"]))
    res = _score(p, pi[:10 * n].reshape(n, 10), w_te @ pi, float(fit.rmse[fit.best]), "ours")
    res.update(wall_s=wall, per_start_train_rmse=fit.rmse.tolist(), lm_steps=fit.steps.tolist(),
               evaluations="one residual + autodiff Jacobian per LM step (all starts vmapped in one call)",
               pi=pi.tolist())
    return res


class _SysidResidual:
    """``(x, params) -> ([r], None, None)`` for ``mujoco.sysid.optimize``: torque residual over the fitted rows."""

    def __init__(self, p: dict, spec: mujoco.MjSpec, build):
        tr = p["train"]
        self.q, self.qd, self.qdd, self.tau = tr.q, tr.qd, tr.qdd, tr.torque
        self.mask, self.eps = p["mask"], p["eps"]
        self.spec, self.build = spec, build
        self.evals = 0
        self.trace: list = []
        self.xs: list = []
        self.t0 = time.perf_counter()

    def predict(self, params, q, qd, qdd):
        m = self.build(params, self.spec)
        return _inverse(m, mujoco.MjData(m), q, qd, qdd) + params["coulomb"].value * np.tanh(qd / self.eps)

    def __call__(self, x, params):
        x2 = np.asarray(x).reshape(x.shape[0], -1)
        cols = []
        for k in range(x2.shape[1]):
            params.update_from_vector(x2[:, k])
            cols.append((self.predict(params, self.q, self.qd, self.qdd) - self.tau)[self.mask])
        self.evals += x2.shape[1]
        r = np.stack(cols, -1)
        if x2.shape[1] == 1:
            self.trace.append((time.perf_counter() - self.t0, self.evals, float(np.sqrt(np.mean(r ** 2)))))
            self.xs.append(x2[:, 0].copy())
        return [r[:, 0] if np.ndim(x) == 1 else r], None, None


def _sysid_params(p: dict, spec: mujoco.MjSpec):
    from mujoco import sysid

    # A consistent pseudo-inertia can still fail MuJoCo's triangle check A + B >= C by round-off after its
    # conversion to principal moments (a thin link, a finite-difference step): let MuJoCo balance those.
    spec.compiler.balanceinertia = True
    m0 = spec.compile()
    params = sysid.ParameterDict()
    for body in p["model"].link_names:
        params.add(sysid.body_inertia_param(
            spec, m0, body, inertia_type=sysid.InertiaType.Pseudo, mass_bound_mult=np.array([1e-2, 1e2]),
            stretch_bound_mult=np.array([1e-4, 1e4]), shear_bound_off=np.array([-10.0, 10.0]),
            ipos_bound_off=np.array([-10.0, 10.0]), modifier=_pseudo_modifier(body)))
    joints = list(p["model"].joint_names)

    def armature(s, prm):
        for j, v in zip(joints, prm.value):
            s.joint(j).armature = float(v)

    def damping(s, prm):
        for j, v in zip(joints, prm.value):
            s.joint(j).damping = np.array([float(v), 0.0, 0.0])

    n = len(joints)
    params.add(sysid.Parameter("armature", np.ones(n), np.zeros(n), np.full(n, 200.0), modifier=armature))
    params.add(sysid.Parameter("damping", np.ones(n), np.zeros(n), np.full(n, 200.0), modifier=damping))
    params.add(sysid.Parameter("coulomb", np.ones(n), np.zeros(n), np.full(n, 200.0)))
    return params


def _pseudo_modifier(body: str):
    """sysid's own pseudo-inertia modifier, then the inertial frame's quaternion set to identity.

    In mujoco 4.0.0, ``apply_body_theta_inertia`` leaves ``iquat`` NaN beside ``inertia = 0`` and a full inertia,
    and the compiler rejects the body ("mass and inertia of moving bodies must be larger than mjMINVAL"); with an
    identity ``iquat`` it compiles the full inertia as given (checked by :func:`check_twin`)."""
    from mujoco.sysid._src.model_modifier import apply_body_theta_inertia

    def modify(spec, param):
        apply_body_theta_inertia(spec, body, param.value)
        spec.body(body).iquat = np.array([1.0, 0.0, 0.0, 0.0])
    return modify


def _sysid_vector(pi: np.ndarray, n: int) -> np.ndarray:
    """Our ``pi`` (13 n) -> sysid's vector: per body its log-Cholesky theta, then armature, damping, Coulomb."""
    from mujoco.sysid._src.model_modifier import theta_from_pseudoinertia

    bodies = np.asarray(pseudo_inertia(pi[:10 * n].reshape(n, 10)))
    return np.concatenate([theta_from_pseudoinertia(b) for b in bodies] + [pi[10 * n:]])


def _ours_inertia(x: np.ndarray, n: int) -> np.ndarray:
    from mujoco.sysid._src.model_modifier import pi_from_theta, pseudoinertia_from_pi

    return np.stack([np.asarray(params_from_pseudo_inertia(pseudoinertia_from_pi(pi_from_theta(x[10 * i:10 * i + 10]))))
                     for i in range(n)])


def check_twin(p: dict) -> float:
    """sysid's modifiers applied at the URDF values reproduce our inverse dynamics (else nothing here compares)."""
    from mujoco.sysid import apply_param_modifiers
    import jax

    spec = mujoco_spec(p["urdf"], gravity=GRAVITY)
    params = _sysid_params(p, spec)
    n = p["model"].nq
    x = _sysid_vector(np.concatenate([np.asarray(p["model"].inertia).ravel(), np.zeros(3 * n)]), n)
    params.update_from_vector(x)
    m = apply_param_modifiers(params, spec)
    te = p["test"]
    ref = np.asarray(jax.vmap(lambda a, b, c: inverse_dynamics(p["model"], a, b, c))(te.q, te.qd, te.qdd))
    err = float(np.abs(_inverse(m, mujoco.MjData(m), te.q, te.qd, te.qdd) - ref).max())
    if not err < TWIN_TOL:
        raise RuntimeError(f"MuJoCo twin through sysid's modifiers differs from ours by {err:.3g} N m")
    return err


def run_sysid(p: dict, pi_start: np.ndarray, target: float, *, score: bool = True, **options) -> dict:
    from mujoco import sysid

    n = p["model"].nq
    spec = mujoco_spec(p["urdf"], gravity=GRAVITY)
    params = _sysid_params(p, spec)
    x0 = _sysid_vector(pi_start, n)
    lo, hi = params.get_bounds()
    params.update_from_vector(np.clip(x0, lo, hi))
    fn = _SysidResidual(p, spec, sysid.apply_param_modifiers)
    t0 = time.perf_counter()
    fn.t0 = t0
    opt, result = sysid.optimize(params, fn, optimizer="mujoco", verbose=False, max_iters=SYSID_MAX_ITERS,
                                 **options)
    wall = time.perf_counter() - t0
    x = opt.as_vector()
    if not score:
        return {"wall_s": wall, "evaluations": fn.evals, "x": x, "trace": fn.trace, "xs": fn.xs}
    r = fn(x, opt)[0][0]
    train_rmse = float(np.sqrt(np.mean(r ** 2)))
    te = p["test"]
    pred = fn.predict(opt, te.q, te.qd, te.qdd)
    inertia = _ours_inertia(x, n)
    res = _score(p, inertia, pred, train_rmse, "mujoco.sysid")
    reached = [t for t, _, loss in fn.trace if loss <= target * (1 + REACH)]
    res.update(wall_s=wall, evaluations=fn.evals, options={k: str(v) for k, v in options.items()},
               time_to_target_s=reached[0] if reached else None, trace=fn.trace,
               at_bounds=int(np.sum((np.abs(x - lo) < 1e-9) | (np.abs(x - hi) < 1e-9))),
               pi=np.concatenate([inertia.ravel(), x[10 * n:]]).tolist())
    return res


def real_uncertainty(p: dict, pi: np.ndarray) -> dict:
    """Standard errors of ours' base parameters on the real arm: pooled-sigma Gauss–Newton and sandwich (scores
    per sample, and per 1 s block: the residuals of real data differ between joints and are correlated in time),
    each beside the bootstrap spread over the same resampling unit."""
    w = np.asarray(regressor(p["model"], p["train"].q, p["train"].qd, p["train"].qdd, eps=p["eps"],
                             rigid=p["rigid"]))
    lsq = compress(w, p["train"].torque, p["mask"])
    basis, rank = identifiable_basis(np.asarray(lsq.r), rtol=BASE_RTOL)
    theta = np.asarray(theta_from_params(pi))
    u = base_uncertainty(lsq, theta, basis=basis)
    good = u.rel_std < WELL_IDENTIFIED
    res = {"rank": rank, "n_params": int(pi.size), "sigma_Nm": u.sigma, "well_identified": int(good.sum()),
           "rel_std": u.rel_std.tolist()}

    def compare(spread, std):
        ratio = spread[good] / std[good]
        return {"min": float(ratio.min()), "median": float(np.median(ratio)), "max": float(ratio.max()),
                "within_factor_2": float(np.mean((ratio < 2) & (ratio > 0.5)))}

    for label, block in (("iid", 1), ("block", BLOCK)):
        boot = bootstrap_base(w, p["train"].torque, theta, basis, mask=p["mask"], count=BOOT, block=block, seed=SEED)
        sandwich = robust_base_uncertainty(w, p["train"].torque, theta, basis, mask=p["mask"], block=block)
        res[f"bootstrap_{label}_over_gn"] = compare(boot.std(axis=0), u.std)
        res[f"bootstrap_{label}_over_sandwich"] = compare(boot.std(axis=0), sandwich.std)
    print(f"real arm: {rank} base parameters of {pi.size}, {good.sum()} with relative standard error < "
          f"{WELL_IDENTIFIED:g}; bootstrap/GN spread iid {res['bootstrap_iid_over_gn']}, "
          f"1 s blocks {res['bootstrap_block_over_gn']}; bootstrap/sandwich iid "
          f"{res['bootstrap_iid_over_sandwich']}, 1 s blocks {res['bootstrap_block_over_sandwich']}", flush=True)
    return res


def _simulate(model, pi):
    """2 s of the arm with parameters ``pi`` under PD tracking of a multi-sine plus gravity compensation;
    ``(t, q, qd, qdd, tau)`` at 100 Hz, ``qdd`` from the forward dynamics."""
    import jax
    import jax.numpy as jnp

    from particlesim.identify import model_with_params
    from particlesim.simulate import simulate
    from particlesim.tree import forward_dynamics, gravity_torques

    m = model_with_params(model, pi)
    amp = jnp.array([0.8, 0.6, 0.9, 0.7, 1.0, 0.8, 1.0])
    freq = jnp.array([0.6, 0.8, 0.7, 0.9, 1.1, 1.3, 1.2]) * 2 * jnp.pi

    def control(t, q, qd, mm):
        return gravity_torques(mm, q) + 400.0 * (amp * jnp.sin(freq * t) - q) + 60.0 * (amp * freq * jnp.cos(freq * t) - qd)

    def dynamics(mm, q, qd, tau):
        return forward_dynamics(mm, q, qd, tau, smooth_friction=SIM_EPS)

    ts = jnp.linspace(0.0, 2.0, 201)
    sol = simulate(dynamics, m, jnp.zeros(7), jnp.zeros(7), 0.0, 2.0, control=control, saveat_ts=ts, rtol=1e-10,
                   atol=1e-12)
    tau = jax.vmap(lambda t, q, qd: control(t, q, qd, m))(ts, sol.q, sol.qd)
    qdd = jax.vmap(lambda q, qd, u: dynamics(m, q, qd, u))(sol.q, sol.qd, tau)
    return tuple(np.asarray(a) for a in (ts, sol.q, sol.qd, qdd, tau))


def simulated_comparison(p: dict) -> dict:
    """Known parameters (URDF bodies, plausible rotor inertia and friction), torque noise 0, 1 %, 5 % of the RMS
    torque; both tools from the same start (the truth perturbed by SPREAD in the unconstrained coordinates); error
    of the base parameters ``|E^T (pi - pi_true)| / |E^T pi_true|`` (column-scaled units) against wall time."""
    model, n = p["model"], p["model"].nq
    true = np.concatenate([np.asarray(model.inertia).ravel(), SIM_ROTOR, SIM_VISCOUS, SIM_COULOMB])
    t, q, qd, qdd, tau = _simulate(model, true)
    w = np.asarray(regressor(model, q, qd, qdd, eps=SIM_EPS))
    basis, rank = identifiable_basis(w, rtol=BASE_RTOL)
    ref = basis.T @ true
    err = lambda pi: float(np.linalg.norm(basis.T @ pi - ref) / np.linalg.norm(ref))  # noqa: E731
    start = np.asarray(theta_from_params(true)) + SPREAD * np.random.default_rng(SEED + 1).standard_normal(13 * n)
    pi_start = np.asarray(params_from_theta(start))
    rms = float(np.sqrt(np.mean(tau ** 2)))
    rows = []
    for level in SIM_LEVELS:
        noisy = tau + level * rms * np.random.default_rng(SEED + 2).standard_normal(tau.shape)
        data = arm_data_from_arrays(t=t, q=q, qd=qd, qdd=qdd, current=noisy, km=np.ones(n), gear=np.ones(n),
                                    name=f"simulated, noise {level:g}", joint_names=model.joint_names)
        t0 = time.perf_counter()
        lsq = compress(np.asarray(regressor(model, q, qd, qdd, eps=SIM_EPS)), noisy)
        if level == 0:  # exact data: the consistent point with the least-squares base parameters
            fit = fit_base_consistent(lsq, start[None], rtol=BASE_RTOL)
        else:  # noisy data: the consistent least-squares fit (the estimator the standard errors describe)
            fit = fit_consistent(lsq, start[None], max_steps=OURS_MAX_STEPS, verbose=False)
        ours_wall = time.perf_counter() - t0
        u = base_uncertainty(lsq, fit.theta[fit.best], basis=basis)
        ours_err = err(fit.best_pi)
        z = (u.beta - ref) / u.std if level > 0 else np.zeros(rank)
        sp = dict(p, train=data, eps=SIM_EPS, mask=np.ones(noisy.shape, bool))
        r = run_sysid(sp, pi_start, 0.0, score=False)
        sys_err = [err(np.concatenate([_ours_inertia(x, n).ravel(), x[10 * n:]])) for x in r["xs"]]
        sys_curve = [(tt, min(sys_err[:k + 1])) for k, (tt, _, _) in enumerate(r["trace"])]
        loss = lambda pi: float(np.sqrt((np.sum((np.asarray(lsq.r) @ pi - np.asarray(lsq.y)) ** 2)  # noqa: E731
                                         + float(lsq.rest)) / lsq.count))
        x_end = r["x"]
        sys_pi = np.concatenate([_ours_inertia(x_end, n).ravel(), x_end[10 * n:]])
        rows.append({"noise": level, "ols_base_error": err(ordinary_least_squares(w, noisy)),
                     "ours": {"wall_s": ours_wall, "base_error": ours_err, "train_rmse": loss(fit.best_pi),
                                               "inside_2_std": float(np.mean(np.abs(z) < 2)) if level > 0 else None},
                     "sysid": {"wall_s": r["wall_s"], "evaluations": r["evaluations"], "base_error": err(sys_pi),
                               "train_rmse": loss(sys_pi),
                               "curve": sys_curve}})
        print(f"simulated arm, noise {level:.0%}: base-parameter error ours {ours_err:.2e} in {ours_wall:.1f} s"
              + (f" ({rows[-1]['ours']['inside_2_std']:.0%} inside 2 standard errors)" if level > 0 else "")
              + f"; mujoco.sysid {sys_curve[-1][1]:.2e} in {r['wall_s']:.1f} s ({r['evaluations']} evaluations)",
              flush=True)
    return {"rank": rank, "levels": list(SIM_LEVELS), "rows": rows}


def main() -> dict:
    t_start = time.perf_counter()
    p = problem()
    twin = check_twin(p)
    pi0 = starts(p)
    ours = run_ours(p, pi0)
    ours["wall_s"] += p["build_rigid"]
    print(f"ours: train {ours['train_rmse']:.4f}, test {ours['test_rmse_pooled']:.3f} N m, "
          f"{ours['wall_s']:.1f} s ({STARTS} starts), LM steps {ours['lm_steps']}", flush=True)
    sys_runs = []
    for s, options in [(s, {}) for s in range(STARTS)] + [(0, {"x_scale": "jac"})]:
        r = run_sysid(p, pi0[s], ours["train_rmse"], **options)
        r["start"] = s
        sys_runs.append(r)
        print(f"sysid start {s}: train {r['train_rmse']:.4f}, test {r['test_rmse_pooled']:.3f} N m, "
              f"{r['wall_s']:.1f} s, {r['evaluations']} evaluations, reached ours' loss at "
              f"{r['time_to_target_s']}", flush=True)
    unc = real_uncertainty(p, np.asarray(ours["pi"]))
    sim = simulated_comparison(p)
    out = {"env": environment(), "uncertainty": unc, "simulated": sim, "eps": p["eps"], "drop_saturated": bool(p["drop"]), "n_train": len(p["train"]),
           "n_test": len(p["test"]), "fitted_residuals": int(p["mask"].sum()), "twin_max_diff_Nm": twin,
           "starts": STARTS, "ours": ours, "sysid": sys_runs, "joints": list(p["model"].joint_names),
           "settings": {"ours_max_steps": OURS_MAX_STEPS, "sysid_max_iters": SYSID_MAX_ITERS, "reach": REACH}}
    out["wall_s"] = time.perf_counter() - t_start
    write(out)
    return out


def write(out: dict) -> None:
    write_json(NAME, out, indent=1, newline=False)
    write_table(NAME, ["tool", "start", "test_rmse_pooled", "train_rmse", "wall_s", "time_to_ours_loss_s",
                       "consistent", "min_pseudo_eig"],
                ([r["tool"], r.get("start", "all"), r["test_rmse_pooled"], r["train_rmse"], r["wall_s"],
                  r.get("time_to_target_s", r["wall_s"]), r["consistent"], min(r["pseudo_inertia_min_eig"])]
                 for r in [out["ours"]] + out["sysid"]))
    plot(out)
    print(markdown(out))


def plot(out: dict) -> None:
    fig, (ax, bx) = pyplot().subplots(1, 2, figsize=(12, 4.2))
    for r in out["sysid"]:
        t, _, loss = zip(*r["trace"])
        opt = ", ".join(f"{k}={v}" for k, v in r["options"].items())
        ax.semilogy(t, np.minimum.accumulate(loss), label=f"mujoco.sysid, start {r['start']} {opt}")
    ax.axhline(out["ours"]["train_rmse"], color="k", ls="--", lw=0.8)
    ax.plot([out["ours"]["wall_s"]], [out["ours"]["train_rmse"]], "k*", ms=12,
            label=f"ours ({out['starts']} starts, compile included)")
    ax.set_xscale("log")
    ax.set_xlabel("wall time [s]")
    ax.set_ylabel("training torque RMSE [N m]")
    ax.set_title("Real arm: training loss against wall time")
    ax.legend(fontsize=7)
    for k, r in enumerate(out["simulated"]["rows"]):
        t, e = zip(*r["sysid"]["curve"])
        bx.loglog(t, e, color=f"C{k}", label=f"mujoco.sysid, noise {r['noise']:.0%}")
        bx.loglog([r["ours"]["wall_s"]], [max(r["ours"]["base_error"], 1e-12)], "*", color=f"C{k}", ms=12,
                  label=f"ours, noise {r['noise']:.0%}")
    bx.set_xlabel("wall time [s]")
    bx.set_ylabel("base-parameter error (relative)")
    bx.set_title("Simulated arm: parameter error against time")
    bx.legend(fontsize=7)
    save_figure(fig, NAME, dpi=100, tight=True)


def markdown(out: dict) -> str:
    env, j, o = out["env"], out["joints"], out["ours"]
    lines = ["### Identification: Krang's real left arm, ours beside `mujoco.sysid`", "",
             f"{env['cpu']}, {env['cpu_count']} cores, {env['date']}, load {env['load_average_1_5_15min'][0]:.1f}; "
             f"took {out['wall_s'] / 60:.1f} min. Same data ({out['n_train']} training samples, "
             f"{out['fitted_residuals']} fitted torques; {out['n_test']} test samples), same model (MuJoCo twin "
             f"equal to ours to {out['twin_max_diff_Nm']:.0e} N m), same loss (torque, Coulomb "
             f"tanh(qd/{out['eps']:g})), same log-Cholesky consistency parameters and starts. sysid: its default "
             f"`mujoco.minimize` backend, finite-difference Jacobians, at most {out['settings']['sysid_max_iters']} "
             "iterations (its residual loop over samples runs on one core); ours: autodiff regressor, vmapped "
             "Levenberg–Marquardt, on both cores (XLA), its wall time including every compile (not shown separately: "
             f"regressor build and LM compile are part of the {o['wall_s']:.1f} s). The simulated-arm section ran "
             "pinned to one core for both.", "",
             "| tool | start | test RMSE pooled [N m] | " + " | ".join(j) + " | train RMSE | wall [s] | "
             "to ours' loss [s] | evaluations | min pseudo-inertia eig |", "|---" * (len(j) + 8) + "|"]
    lines.append(f"| ours | all {out['starts']} (vmapped) | **{o['test_rmse_pooled']:.2f}** | "
                 + " | ".join(f"{x:.2f}" for x in o["test_rmse_per_joint"])
                 + f" | {o['train_rmse']:.3f} | {o['wall_s']:.1f} | {o['wall_s']:.1f} | "
                 + "/".join(str(s) for s in o["lm_steps"]) + f" LM steps | {min(o['pseudo_inertia_min_eig']):.1e} |")
    for r in out["sysid"]:
        opt = ", ".join(f"{k}={v}" for k, v in r["options"].items())
        tt = "not reached" if r["time_to_target_s"] is None else f"{r['time_to_target_s']:.1f}"
        lines.append(f"| mujoco.sysid{' (' + opt + ')' if opt else ''} | {r['start']} | "
                     f"**{r['test_rmse_pooled']:.2f}** | " + " | ".join(f"{x:.2f}" for x in r["test_rmse_per_joint"])
                     + f" | {r['train_rmse']:.3f} | {r['wall_s']:.1f} | {tt} | {r['evaluations']} model builds |"
                     f" {min(r['pseudo_inertia_min_eig']):.1e} |")
    u = out["uncertainty"]
    bi, bb = u["bootstrap_iid_over_gn"], u["bootstrap_block_over_gn"]
    si, sb = u.get("bootstrap_iid_over_sandwich"), u.get("bootstrap_block_over_sandwich")
    lines += ["", f"Uncertainty (ours, real arm): {u['rank']} base parameters of {u['n_params']}; {u['well_identified']} "
              f"with Gauss–Newton relative standard error < {WELL_IDENTIFIED:g} (residual σ {u['sigma_Nm']:.2f} N m). "
              f"Bootstrap spread / GN standard error on those, {BOOT} resamples: independent samples "
              f"{bi['min']:.2f}..{bi['max']:.2f} (median {bi['median']:.2f}, {bi['within_factor_2']:.0%} within a "
              f"factor 2); 1 s blocks {bb['min']:.2f}..{bb['max']:.2f} (median {bb['median']:.2f}): the residuals differ "
              "between joints and are correlated in time, so pooled independent-noise errors misstate the spread."
              + ("" if si is None else
                 f" Sandwich standard errors on the same Gauss–Newton Hessian (`robust_base_uncertainty`, scores "
                 f"per sample / per 1 s block) against the bootstrap over the same unit: {si['min']:.2f}.."
                 f"{si['max']:.2f} (median {si['median']:.2f}, {si['within_factor_2']:.0%} within a factor 2) and "
                 f"{sb['min']:.2f}..{sb['max']:.2f} (median {sb['median']:.2f}, {sb['within_factor_2']:.0%})."),
              "",
              "Simulated arm (known parameters, 2 s PD-tracked multi-sine, 201 samples; both from the same start): "
              "base-parameter error |Eᵀ(π − π_true)| / |Eᵀπ_true| and wall time.", "",
              "| torque noise | ours error | ours train RMSE | ours wall [s] | ours base parameters inside 2σ | "
              "sysid error | sysid train RMSE | sysid wall [s] | sysid evaluations | unconstrained OLS error |",
              "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in out["simulated"]["rows"]:
        inside = "–" if r["ours"]["inside_2_std"] is None else f"{r['ours']['inside_2_std']:.0%}"
        lines.append(f"| {r['noise']:.0%} | {r['ours']['base_error']:.1e} | {r['ours']['train_rmse']:.4f} | "
                     f"{r['ours']['wall_s']:.1f} | {inside} | {r['sysid']['base_error']:.1e} | "
                     f"{r['sysid']['train_rmse']:.4f} | {r['sysid']['wall_s']:.1f} | {r['sysid']['evaluations']} | "
                     f"{r['ols_base_error']:.1e} |")
    return "\n".join(lines) + "\n"


def rerun_uncertainty() -> dict:
    """Rerun only the real-arm uncertainty section (at the saved fit) and merge it into the saved results."""
    out = json.loads((RESULTS / f"{NAME}.json").read_text())
    out["uncertainty"] = real_uncertainty(problem(), np.asarray(out["ours"]["pi"]))
    write(out)
    return out


def rerun_simulated() -> dict:
    """Rerun only the simulated-arm section and merge it into the saved results."""
    out = json.loads((RESULTS / f"{NAME}.json").read_text())
    out["simulated"] = simulated_comparison(problem())
    write(out)
    return out


if __name__ == "__main__":
    if sys.argv[1:] == ["simulated"]:
        rerun_simulated()
    elif sys.argv[1:] == ["uncertainty"]:
        rerun_uncertainty()
    else:
        main()
