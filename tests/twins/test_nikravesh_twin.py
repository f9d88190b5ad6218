"""The MuJoCo C and MJX twins of Nikravesh's planar double A-arm against ours and against ``AA_results.csv``.

Error sources of a twin, each measured in the test rather than assumed:

* RK4's truncation error at step ``dt``: Richardson's estimate from MuJoCo C at ``dt`` and ``dt/2``,
  ``(16/15) |y_dt - y_dt/2|``;
* the soft loop: MuJoCo's ``connect`` is regularised, so the twin's wheel carries an error of the order of its
  measured loop residual |B3 - B2|;
* the reference file's own error: ``AA_results.csv`` is MATLAB ode45 at RelTol 1e-6; its distance from ours
  (Dopri8, rtol 1e-12) is measured here and added by the triangle inequality.

MJX 3.17 omits the ``J̇ v`` term of ``connect`` rows (docs/twins.md): its loop opens much further than MuJoCo C's
at the same step, and its wheel height is compared with MuJoCo C within MJX's own loop residual. That residual is
the compliance's response to a missing acceleration term, so it scales as the squared ``solref`` time constant
(2 dt): it must fall four-fold per halving of the step.
"""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from mujoco import mjx

from particlesim.mechanism import simulate_mechanism
from particlesim.scenes import nikravesh as nk
from particlesim.twins.nikravesh import mjx_rollout, twin_rollout, twin_xml

SAFETY = 3.0  # the factor of the other twin tests; nothing here is tuned to the results
DT = 1e-3  # s, the twins' RK4 step
T_END = 2.0
MJX_T, MJX_PER = 0.3, 10  # a short MJX run (one compile), saved every 10 ms
ORDER_TOL = 0.25  # on log2 of the MJX loop-residual ratio per halving of dt (expected 2: residual ~ tc^2)
LOOP_RATIO_MIN = 100.0  # MJX's loop residual over MuJoCo C's at the same step: the missing J̇v term, not round-off


@pytest.fixture(scope="module")
def reference():
    return nk.load_reference()[: int(round(T_END / DT)) + 1]


@pytest.fixture(scope="module")
def ours(reference):
    mech, x0 = nk.aa_mechanism()
    k = mech.point_index(nk.WHEEL_COM)

    def run(m, x):
        s = simulate_mechanism(m, x, jnp.zeros_like(x), 0.0, T_END, solver="dopri8", rtol=1e-12, atol=1e-14,
                               saveat_ts=reference[:, 0])
        return jax.vmap(lambda q: m.point_position(k, m.all_positions(q))[1])(s.q), s.ok

    y, ok = jax.jit(run)(mech, jnp.asarray(x0))
    assert bool(ok)
    return np.asarray(y)


@pytest.fixture(scope="module")
def twin_c(reference):
    coarse = twin_rollout(reference[:, 0], DT)
    fine = twin_rollout(reference[:, 0], DT / 2)
    return coarse, fine


def _budget(coarse, fine) -> float:
    """The C twin's own error bound at DT: loop residual plus RK4's step-halving estimate."""
    rk4 = 16.0 / 15.0 * np.abs(coarse["wheel_y"] - fine["wheel_y"]).max()
    return SAFETY * (coarse["loop_residual"].max() + rk4)


def test_mujoco_c_twin_matches_ours(ours, twin_c):
    coarse, fine = twin_c
    err = np.abs(coarse["wheel_y"] - ours).max()
    tol = _budget(coarse, fine)
    print(f"C twin vs ours: {err:.2e} m; loop residual {coarse['loop_residual'].max():.2e} m, "
          f"RK4 estimate {16 / 15 * np.abs(coarse['wheel_y'] - fine['wheel_y']).max():.2e} m, tolerance {tol:.2e} m")
    assert err <= tol


def test_mujoco_c_twin_matches_reference_file(reference, ours, twin_c):
    coarse, fine = twin_c
    ref_noise = np.abs(ours - reference[:, 5]).max()
    err = np.abs(coarse["wheel_y"] - reference[:, 5]).max()
    tol = ref_noise + _budget(coarse, fine)
    print(f"C twin vs AA_results.csv: {err:.2e} m (ours vs the file {ref_noise:.2e} m), tolerance {tol:.2e} m")
    assert err <= tol
    i = int(np.argmin(coarse["wheel_y"]))
    assert abs(reference[i, 0] - 0.081) < 1e-12  # the minimum falls on the file's row


def test_tyre_callback_is_removed_after_a_run(reference):
    twin_rollout(reference[:3, 0], DT)
    assert mujoco.get_mjcb_passive() is None


def test_mjx_twin_matches_mujoco_c_within_its_loop_residual():
    ts = np.linspace(0.0, MJX_T, int(round(MJX_T / (DT * MJX_PER))) + 1)
    fn, mx, d0 = mjx_rollout(mujoco.MjModel.from_xml_string(twin_xml(DT)), len(ts))
    y, loop = (np.asarray(a) for a in fn(mx, d0, MJX_PER))
    half = mjx.put_model(mujoco.MjModel.from_xml_string(twin_xml(DT / 2)))  # same structure: no recompile
    loop_half = np.asarray(fn(half, d0, 2 * MJX_PER)[1])
    c = twin_rollout(ts, DT)
    err = np.abs(y - c["wheel_y"]).max()
    order = np.log2(loop.max() / loop_half.max())
    print(f"MJX vs C over {MJX_T} s: {err:.2e} m; loop residual MJX {loop.max():.2e} m (dt/2: {loop_half.max():.2e} m, "
          f"order {order:.2f}), C {c['loop_residual'].max():.2e} m")
    assert err <= SAFETY * loop.max()
    assert loop.max() >= LOOP_RATIO_MIN * c["loop_residual"].max()
    assert abs(order - 2.0) <= ORDER_TOL
