"""The main job's particle report: it runs, writes its files, and every body is reproduced to round-off."""

import json

import numpy as np
import pytest

from particlesim.cli import main
from particlesim.scenes import quarter_car

REPORT_RTOL = 1e-12


def test_particle_report_writes_files_and_reproduces_every_body(tmp_path, capsys):
    assert main(["particles", "--out", str(tmp_path)]) == 0
    summary = json.loads((tmp_path / "particles_summary.json").read_text())
    assert {s["body"] for s in summary} == set(quarter_car.TABLE1)
    for s in summary:
        assert s["mass_rel"] <= REPORT_RTOL and s["com_rel"] <= REPORT_RTOL and s["inertia_rel"] <= REPORT_RTOL, s
        if s["layout"] == "balanced":
            assert s["consistent"] and np.isclose(s["min_mass"], quarter_car.TABLE1[s["body"]][0] / s["n_particles"])
    out = capsys.readouterr().out
    assert "chassis" in out and "negative masses" in out  # the joint layouts are reported as inconsistent


def test_quarter_car_bodies_match_table_1():
    b = quarter_car.bodies()
    assert float(b["chassis"].mass) == 300.0
    np.testing.assert_array_equal(np.diag(np.asarray(b["lower_arm"].inertia)), [0.028, 0.002, 0.03])
    prim = quarter_car.joint_primaries()
    # The lower arm's primaries are Table 4 particles 2, 3, 6 relative to its centroid.
    glob = np.array([quarter_car.TABLE4[i] for i in (2, 3, 6)])
    np.testing.assert_allclose(prim["lower_arm"], glob - glob.mean(0), atol=1e-15)


# The report's Krang fall against MuJoCo C RK4 (dt = 1e-4): measured 3e-10 rad over 2 s; RK4's own global error
# at this step is of that order (see tests/twins/test_krang_twin.py for the step-halving estimate). A twin that
# disagreed on any dynamics term would be off by orders of magnitude more.
KRANG_REPORT_ATOL = 1e-8


@pytest.mark.slow
def test_krang_fall_report_agrees_with_mujoco(tmp_path):
    from particlesim.reports.krang_fall import krang_fall

    f = krang_fall(tmp_path, progress=False)
    assert f["max_abs_joint_deviation_rad"] <= KRANG_REPORT_ATOL
    assert f["energy_non_increasing"]
    for name in ("krang_fall.csv", "krang_fall.png", "krang_fall.json"):
        assert (tmp_path / name).stat().st_size > 0
