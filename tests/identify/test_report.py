"""The report command writes its table, JSON and plot, with consistent bodies and positive actuator parameters,
and beats the unconstrained lab model on the test run (subsampled training run)."""

import json

import pytest

from particlesim.reports.identify_arm import identify_arm

OLS_BASELINE = 9.9  # N m, data README


@pytest.mark.slow
def test_identify_arm_report(tmp_path):
    res = identify_arm(tmp_path, step=2, starts=2, max_steps=1500, verbose=False)
    for ext in ("json", "md", "png"):
        assert (tmp_path / f"identify_arm.{ext}").stat().st_size > 0
    data = json.loads((tmp_path / "identify_arm.json").read_text())
    assert all(data["check_inertia_passed"]) and min(data["pseudo_inertia_min_eig"]) > 0
    ident = data["identified"]  # rotor inertia, viscous and Coulomb friction positive
    assert min(min(ident["rotor_inertia"]), min(ident["viscous"]), min(ident["coulomb"])) > 0
    ours = [v for k, v in res["test_rmse"].items() if k.startswith("Ours")][0]
    assert ours["pooled"] < OLS_BASELINE
    assert abs(res["test_rmse"]["URDF"]["pooled"] - 51.7) < 0.1
