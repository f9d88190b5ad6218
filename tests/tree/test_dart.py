"""Krang on fixed wheels against 880 samples logged from DART (real data nobody here wrote)."""

import jax
import numpy as np

from particlesim.tree import bias_forces, mass_matrix
from tree_helpers import DART_DOF_ORDER

#: Pinocchio on the same URDF reaches 4.8e-6 (M) and 1.8e-5 (Cg): the data are printed to ~6 digits.
M_RTOL = 1e-5
CG_RTOL = 5e-5


def _load(folder, name):
    path = folder / name
    with open(path) as f:
        header = f.readline().strip()
    assert header.isidentifier(), f"{path}: expected a header word, got {header!r}"
    return np.loadtxt(path, skiprows=1)


def test_joint_order_matches_dart(fixed_wheel):
    assert fixed_wheel.joint_names == DART_DOF_ORDER
    assert fixed_wheel.nq == 18


def test_dart_samples_reproduced(fixed_wheel, shared_data):
    folder = shared_data / "krang" / "dart_fixed_wheel"
    q, qd = _load(folder, "dataQ.txt"), _load(folder, "dataQdot.txt")
    m_ref = _load(folder, "dataM.txt").reshape(-1, 18, 18)
    cg_ref = _load(folder, "dataCg.txt")
    assert q.shape == qd.shape == cg_ref.shape == (880, 18) and m_ref.shape == (880, 18, 18)
    f = jax.jit(jax.vmap(lambda q, qd: (mass_matrix(fixed_wheel, q), bias_forces(fixed_wheel, q, qd))))
    m, cg = (np.asarray(x) for x in f(q, qd))
    err_m = np.max(np.abs(m - m_ref), axis=(1, 2)) / np.max(np.abs(m_ref), axis=(1, 2))
    err_cg = np.max(np.abs(cg - cg_ref), axis=1) / np.max(np.abs(cg_ref), axis=1)
    print(f"DART: max relative error M {err_m.max():.3g} (sample {err_m.argmax()}), "
          f"Cg {err_cg.max():.3g} (sample {err_cg.argmax()})")
    assert err_m.max() <= M_RTOL
    assert err_cg.max() <= CG_RTOL
