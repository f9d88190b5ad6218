"""Loading the arm runs: row alignment, the URDF-only baseline figure, and clear errors on bad data."""

import shutil

import numpy as np
import pytest

from particlesim.identify import DataError, current_limits, load_arm_run, rigid_regressor
from particlesim.tree import inverse_dynamics

URDF_ONLY_POOLED = 51.7  # N m, data README
URDF_ONLY_TOL = 0.1


def test_alignment_and_shapes(arm_train, shared_data):
    raw_q = np.loadtxt(shared_data / "krang" / "arm_hardware" / "train" / "dataQ.txt")
    assert arm_train.q.shape == (raw_q.shape[0] - 1, 7)
    np.testing.assert_array_equal(arm_train.q, raw_q[1:])
    assert arm_train.qdd.shape == arm_train.q.shape


def test_urdf_only_test_rmse_matches_readme(arm_model, arm_test):
    import jax
    pred = jax.vmap(lambda a, b, c: inverse_dynamics(arm_model, a, b, c))(arm_test.q, arm_test.qd, arm_test.qdd)
    pooled = float(np.sqrt(np.mean((np.asarray(pred) - arm_test.torque) ** 2)))
    assert abs(pooled - URDF_ONLY_POOLED) < URDF_ONLY_TOL, pooled


def test_current_limits_detect_plateaus(arm_train):
    lim = current_limits(arm_train.current)
    # Joints 2 and 3 sit at their current limits (~177 N m) on hundreds of samples; joint 1 never does.
    assert np.isinf(lim[0])
    assert (np.abs(arm_train.current[:, 1]) >= lim[1]).sum() > 100
    assert abs(lim[1] * 31.4e-3 * 596 - 177) < 1.0


@pytest.fixture
def run_copy(shared_data, tmp_path):
    src = shared_data / "krang" / "arm_hardware" / "test"
    dst = tmp_path / "run"
    dst.mkdir()
    for f in ("dataQ.txt", "dataDotQ.txt", "dataDDotQ.txt", "dataCur.txt", "dataTimeStamp.txt"):
        lines = (src / f).read_text().splitlines()[:301 if f != "dataDDotQ.txt" else 300]
        (dst / f).write_text("\n".join(lines) + "\n")
    return dst


def test_clean_copy_loads(run_copy):
    assert len(load_arm_run(run_copy)) == 300


def test_nan_row_names_file_and_line(run_copy):
    lines = (run_copy / "dataCur.txt").read_text().splitlines()
    lines[41] = " ".join(["nan"] * 7)
    (run_copy / "dataCur.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(DataError, match=r"dataCur\.txt.*line\(s\) \[42\]"):
        load_arm_run(run_copy)


def test_mismatched_lengths_name_file(run_copy):
    lines = (run_copy / "dataDotQ.txt").read_text().splitlines()
    (run_copy / "dataDotQ.txt").write_text("\n".join(lines[:-5]) + "\n")
    with pytest.raises(DataError, match=r"dataDotQ\.txt: 296 rows but .*dataQ\.txt has 301"):
        load_arm_run(run_copy)
    lines = (run_copy / "dataDDotQ.txt").read_text().splitlines()
    shutil.copy(run_copy / "dataQ.txt", run_copy / "dataDotQ.txt")  # repair, then break the acceleration file
    (run_copy / "dataDotQ.txt").write_text((run_copy / "dataDotQ.txt").read_text())
    (run_copy / "dataDDotQ.txt").write_text("\n".join(lines + lines[-1:]) + "\n")
    with pytest.raises(DataError, match=r"dataDDotQ\.txt: 301 rows; expected one fewer"):
        load_arm_run(run_copy)


def test_joint_that_never_moves_is_named(run_copy):
    q = np.loadtxt(run_copy / "dataQ.txt")
    q[:, 4] = 0.25
    np.savetxt(run_copy / "dataQ.txt", q)
    with pytest.raises(DataError, match=r"joint 5 \('LJ5'\) never moves"):
        load_arm_run(run_copy)


def test_wrong_column_count_and_missing_file(run_copy):
    q = np.loadtxt(run_copy / "dataCur.txt")
    np.savetxt(run_copy / "dataCur.txt", q[:, :6])
    with pytest.raises(DataError, match=r"dataCur\.txt: expected 7 columns"):
        load_arm_run(run_copy)
    (run_copy / "dataCur.txt").unlink()
    with pytest.raises(DataError, match=r"dataCur\.txt: file not found"):
        load_arm_run(run_copy)


def test_regressor_refuses_nothing_silently(arm_model):
    # Non-finite rows never reach the regressor: the loader refuses them; the regressor of finite rows is finite.
    w = rigid_regressor(arm_model, np.zeros((2, 7)), np.ones((2, 7)), np.ones((2, 7)))
    assert np.all(np.isfinite(np.asarray(w)))
