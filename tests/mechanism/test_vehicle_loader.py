"""The Chrono JSON loader of the full vehicle (``particlesim.scenes.vehicle.load_double_wishbone``) and the car built
from it: both Chrono files read as written (checked against the raw JSON), the inertia policies, bad files refused
by file, section and key, the Generic file's car, and the documentation's user model of the same car.

The regression check against ``data/vehicle_before_loader.npz`` (the default car's q0 and parameter arrays, saved
from the hand-transcribed module before the loader replaced it) says the default build did not change; it is not a
physics check (the physics is checked in ``test_vehicle.py`` and ``test_statics.py``).
"""

import copy
import json
import re
import warnings
from pathlib import Path

import numpy as np
import pytest

from particlesim.errors import InertiaError, InertiaWarning, ModelError
from particlesim.mechanism import constraint_jacobian, residuals
from particlesim.scenes import vehicle as vh

HERE = Path(__file__).resolve().parent
DOCS = HERE.parent.parent / "docs" / "mechanisms.md"
#: Parameter arrays of the mechanism compared with the snapshot (bitwise in practice; round-off allowed).
SNAPSHOT_FIELDS = ("body_mass", "body_com", "body_inertia", "body_primaries", "point_local", "dot_kappa",
                   "spring_stiffness", "spring_damping", "spring_free_length", "tyre_stiffness", "tyre_damping",
                   "tyre_radius", "tyre_ground", "gravity")
#: Snapshot and documentation model against ``full_vehicle()``, relative to each array's scale (both measured 0:
#: the same operations in the same order).
MATCH_RTOL = 1e-12
#: Constraint residuals of a built car at its assembly [m] (measured ~1e-13 for the Generic car).
ASSEMBLY_ATOL = 1e-12


@pytest.fixture(scope="module")
def files(shared_data):
    root = shared_data / "double_wishbone_chrono"
    return {"hmmwv": root / "HMMWV_DoubleWishboneFront.json", "generic": root / "Generic_DoubleWishbone.json"}


def _quiet_load(path, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InertiaWarning)
        return vh.load_double_wishbone(path, **kw)


def _close(a, b, rtol=MATCH_RTOL):
    a, b = np.asarray(a, float), np.asarray(b, float)
    assert a.shape == b.shape
    np.testing.assert_allclose(a, b, rtol=0, atol=rtol * max(1.0, float(np.abs(b).max(initial=0.0))))


@pytest.mark.parametrize("which", ["hmmwv", "generic"])
def test_both_chrono_files_load_as_written(files, which):
    raw = json.loads(files[which].read_text())
    d = _quiet_load(files[which])
    for name, (sec, key) in vh._POINTS.items():
        assert d.hardpoints[name] == tuple(raw[sec][key]), name
    for name, sec in vh._BODIES.items():
        body, entry = d.bodies[name], raw[sec]
        assert (body.mass, body.com) == (entry["Mass"], tuple(entry["COM"]))
        moments = tuple(entry.get("Moments of Inertia", entry.get("Inertia")))
        assert body.moments == moments or name in ("uca", "lca") and which == "hmmwv"  # HMMWV's arms: balanced
        assert body.frame == ("arm" if name in ("uca", "lca") else "vehicle")  # L1: "Vehicle-Frame Inertia" false
    assert d.spring.free_length == raw["Spring"]["Free Length"]
    assert d.damping == raw["Shock"]["Damping Coefficient"]
    if which == "hmmwv":
        np.testing.assert_array_equal(d.spring.curve, raw["Spring"]["Curve Data"])
        assert (d.spring.coefficient, d.spring.min_length, d.spring.max_length) == (None, 0.15, 0.3)
    else:  # the older format: "Inertia", "Spring Coefficient", no "Vehicle-Frame Inertia"; physical, no notes
        assert "Vehicle-Frame Inertia" not in raw
        assert (d.spring.coefficient, d.spring.curve, d.notes) == (369149.0, None, ())
        assert vh.load_double_wishbone(files[which], inertia="strict").bodies["lca"].moments == (0.0151, 0.0207, 0.0355)


def test_strict_refuses_the_hmmwv_arms_naming_them(files):
    with pytest.raises(InertiaError) as e:
        vh.load_double_wishbone(files["hmmwv"], inertia="strict")
    msg = str(e.value)
    assert "HMMWV_DoubleWishboneFront.json" in msg
    assert "'Upper Control Arm': moments (0.03, 0.03, 0.06276)" in msg and "(0.06276 > 0.06)" in msg
    assert "'Lower Control Arm': moments (0.4, 0.4, 0.8938)" in msg and "(0.8938 > 0.8)" in msg
    assert "Izz <= Ixx + Iyy" in msg and "Upright" not in msg and "Spindle" not in msg
    with pytest.raises(ValueError, match="'strict' or 'balance'"):
        vh.load_double_wishbone(files["hmmwv"], inertia="as_is")


def test_balance_warns_naming_the_arms_and_gives_b3s_numbers(files):
    with pytest.warns(InertiaWarning) as rec:
        d = vh.load_double_wishbone(files["hmmwv"])
    msg = " ".join(str(r.message) for r in rec)
    assert "'Upper Control Arm': moments (0.03, 0.03, 0.06276) -> (0.03, 0.03, 0.06)" in msg
    assert "'Lower Control Arm': moments (0.4, 0.4, 0.8938) -> (0.4, 0.4, 0.8)" in msg
    # B3 as the hand-transcribed module applied it: in-plane moments kept, the normal one their sum
    assert d.bodies["uca"].moments == (0.03, 0.03, 0.03 + 0.03)
    assert d.bodies["lca"].moments == (0.4, 0.4, 0.4 + 0.4)
    assert len(d.notes) == 2 and all("normal moment set to the sum" in n for n in d.notes)


def test_default_car_is_the_hand_transcribed_one():
    """Regression (not physics): the default build equals the one saved before the loader existed."""
    ref = np.load(HERE / "data" / "vehicle_before_loader.npz")
    with pytest.warns(InertiaWarning):
        mech, q0 = vh.full_vehicle()
    assert mech.particle_names == tuple(ref["particle_names"])
    assert mech.topo.body_names == tuple(ref["body_names"])
    assert mech.topo.point_names == tuple(ref["point_names"])
    _close(q0, ref["q0"])
    for field in SNAPSHOT_FIELDS:
        _close(getattr(mech, field), ref[field])
    # a CornerData and a path give the same car; rear=None is the front again
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InertiaWarning)
        mech2, q2 = vh.full_vehicle(front=_quiet_load(vh.hmmwv_front_path()), rear=vh.hmmwv_front_path())
    _close(q2, ref["q0"])
    _close(mech2.body_inertia, ref["body_inertia"])


def test_generic_file_builds_a_ten_dof_car(files):
    with warnings.catch_warnings():
        warnings.simplefilter("error", InertiaWarning)  # physical data: nothing to repair
        mech, q0 = vh.full_vehicle(front=files["generic"])
    assert float(np.abs(np.asarray(residuals(mech, q0, 0 * q0)[0])).max()) <= ASSEMBLY_ATOL
    jac = np.asarray(constraint_jacobian(mech, q0)).reshape(mech.n_constraints, mech.n_coords)
    assert mech.n_coords - np.linalg.matrix_rank(jac) == 10
    d = vh.load_double_wishbone(files["generic"])
    assert float(mech.total_mass()) == pytest.approx(2000.0 + 4 * sum(b.mass for b in d.bodies.values()), rel=1e-14)
    # its arms are not laminae (0.0151 + 0.0207 != 0.0355): spatial sets, the file's inertia kept exactly (B3)
    assert "lca_n FL" in mech.particle_names and "uca_n RR" in mech.particle_names
    lca = mech.body_index("lower arm FL")
    i = np.asarray(mech.body_inertia[lca])
    np.testing.assert_allclose(np.sort(np.linalg.eigvalsh(i)), sorted(d.bodies["lca"].moments), rtol=1e-12)
    np.testing.assert_allclose(mech.spring_stiffness[::2], 369149.0)  # "spring XX" then "shock XX", per corner


def test_vehicle_frame_inertia_arms_are_balanced_in_the_arm_frame(files, tmp_path):
    raw = json.loads(files["hmmwv"].read_text())
    raw["Vehicle-Frame Inertia"] = True  # the arms' moments now in vehicle axes: not laminae in their planes
    path = tmp_path / "vehicle_frame.json"
    path.write_text(json.dumps(raw))
    with pytest.warns(InertiaWarning, match="'Lower Control Arm'.*vehicle frame"):
        d = vh.load_double_wishbone(path)
    lca = d.bodies["lca"]
    assert lca.frame == "vehicle" and any(lca.products)
    axes = vh._arm_axes(*(np.array(d.hardpoints[f"lca_{k}"]) for k in "fbu"))
    a = axes.T @ lca.tensor() @ axes
    assert a[2, 2] == pytest.approx(a[0, 0] + a[1, 1], rel=1e-12) and abs(a[0, 2]) + abs(a[1, 2]) < 1e-14
    mech, q0 = vh.full_vehicle(front=d)
    assert float(np.abs(np.asarray(residuals(mech, q0, 0 * q0)[0])).max()) <= ASSEMBLY_ATOL


def _edit(raw, edit):
    raw = copy.deepcopy(raw)
    edit(raw)
    return json.dumps(raw)


BAD = {  # name: (edit of the HMMWV file, or replacement text; what the message must say)
    "missing key": (lambda r: r["Lower Control Arm"].pop("Mass"), ["section 'Lower Control Arm'", "'Mass'"]),
    "missing section": (lambda r: r.pop("Tierod"), ["section 'Tierod' is missing"]),
    "negative mass": (lambda r: r["Upright"].update(Mass=-19.45), ["section 'Upright'", "'Mass'", "positive"]),
    "non-finite COM": (lambda r: r["Spindle"].update(COM=[0, "x", 0]), ["section 'Spindle'", "'COM'"]),
    "negative moment": (lambda r: r["Upright"].update({"Moments of Inertia": [0.1, -0.2, 0.1]}),
                        ["section 'Upright'", "'Moments of Inertia'", "positive"]),
    "products": (lambda r: r["Upright"].update({"Products of Inertia": [0, 0.01, 0]}),
                 ["section 'Upright'", "'Products of Inertia'", "not supported"]),
    "curve not increasing": (lambda r: r["Spring"]["Curve Data"].__setitem__(3, [-0.01, -1.0]),
                             ["section 'Spring'", "'Curve Data'", "strictly increasing"]),
    "curve not (n, 2)": (lambda r: r["Spring"].update({"Curve Data": [[0.0, 1.0, 2.0], [0.1, 1.0, 2.0]]}),
                         ["section 'Spring'", "'Curve Data'", "(n, 2)"]),
    "no spring law": (lambda r: r["Spring"].pop("Curve Data"), ["section 'Spring'", "'Spring Coefficient'"]),
    "wrong template": (lambda r: r.update(Template="MacPhersonStrut"), ["'Template'", "MacPhersonStrut"]),
    "wrong type": (lambda r: r.update(Type="Tire"), ["'Type'", "'Tire'"]),
    "shock curve": (lambda r: r["Shock"].update({"Curve Data": [[0, 0], [1, 1]]}) or r["Shock"].pop(
        "Damping Coefficient"), ["section 'Shock'", "not supported"]),
    "flag not a bool": (lambda r: r.update({"Vehicle-Frame Inertia": "no"}), ["'Vehicle-Frame Inertia'"]),
    "not JSON": ("Name: HMMWV\nTemplate = DoubleWishbone\n", ["not a JSON file"]),
    "a JSON list": ("[1, 2, 3]", ["not a Chrono JSON object"]),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_files_are_refused_by_file_section_and_key(files, tmp_path, case):
    edit, words = BAD[case]
    path = tmp_path / f"bad {case}.json"
    path.write_text(edit if isinstance(edit, str) else _edit(json.loads(files["hmmwv"].read_text()), edit))
    with pytest.raises(ModelError) as e, warnings.catch_warnings():
        warnings.simplefilter("ignore", InertiaWarning)
        vh.load_double_wishbone(path)
    assert str(path) in str(e.value)
    for w in words:
        assert w in str(e.value), (case, str(e.value))


def test_comments_are_allowed_as_chrono_allows_them(files, tmp_path):
    text = files["hmmwv"].read_text().replace('"Name":', '// a comment with "quotes"\n  /* and a\n block */ "Name":', 1)
    path = tmp_path / "commented.json"
    path.write_text(text.replace('"HMMWV DoubleWishbone Front"', '"HMMWV // not a comment"'))
    d, ref = _quiet_load(path), _quiet_load(files["hmmwv"])
    assert d.name == "HMMWV // not a comment" and dict(d.hardpoints) == dict(ref.hardpoints)


def test_spring_curve_linearisation(files, tmp_path):
    """B6: the secant through the neighbours of the zero-deflection point, else the segment holding zero."""
    raw = json.loads(files["hmmwv"].read_text())
    assert vh._spring_values(_quiet_load(files["hmmwv"]))["stiffness"] == (3629.923 + 3629.923) / 0.04
    for curve, slope in (([[-0.1, -500.0], [0.05, 1000.0], [0.2, 4000.0]], 10000.0),
                         ([[0.0, 0.0], [0.1, 2000.0], [0.2, 5000.0]], 20000.0)):
        path = tmp_path / "curve.json"
        path.write_text(_edit(raw, lambda r: r["Spring"].update({"Curve Data": curve})))
        assert vh._spring_values(_quiet_load(path))["stiffness"] == pytest.approx(slope, rel=1e-14)
    path.write_text(_edit(raw, lambda r: r["Spring"].update({"Curve Data": [[0.01, 1.0], [0.02, 2.0]]})))
    with pytest.raises(ModelError, match="outside the curve's range"):
        vh.full_vehicle(front=_quiet_load(path))


def _doc_block() -> str:
    m = re.search(r"<!-- vehicle-from-json.*?-->\s*```python\n(.*?)```", DOCS.read_text(), re.S)
    assert m, "docs/mechanisms.md has no ```python block marked <!-- vehicle-from-json ... -->"
    return m.group(1)


def test_the_docs_user_model_is_the_same_car():
    block = _doc_block()
    assert len(block.splitlines()) <= 60
    env: dict = {}
    with pytest.warns(InertiaWarning):  # the block loads with the default policy
        exec(compile(block, "docs/mechanisms.md vehicle-from-json", "exec"), env)  # noqa: S102 (our own docs)
    mech, q0 = env["mech"], np.asarray(env["q0"])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", InertiaWarning)
        ref, q_ref = vh.full_vehicle()
    jac = np.asarray(constraint_jacobian(mech, q0)).reshape(mech.n_constraints, mech.n_coords)
    assert mech.n_coords - np.linalg.matrix_rank(jac) == 10
    assert sorted(mech.particle_names) == sorted(ref.particle_names)
    pos, pos_ref = (np.asarray(m.all_positions(q)) for m, q in ((mech, q0), (ref, q_ref)))
    _close([pos[mech.index(n)] for n in ref.particle_names], pos_ref)
    assert float(mech.total_mass()) == pytest.approx(float(ref.total_mass()), rel=MATCH_RTOL)
    for name in ref.topo.body_names:
        b, r = mech.body_index(name), ref.body_index(name)
        _close(mech.body_inertia[b], ref.body_inertia[r])
        _close(mech.body_com[b], ref.body_com[r])
    _close(mech.spring_stiffness, ref.spring_stiffness)
    _close(mech.spring_free_length, ref.spring_free_length)
    _close(mech.tyre_ground, ref.tyre_ground)
