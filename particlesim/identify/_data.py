"""Krang arm hardware runs: loading, row alignment, torque from current, checks, current limits.

Files (``/work/shared/data/krang/arm_hardware/{train,test}``, whitespace-separated, no header, ~100 Hz): ``dataQ``,
``dataDotQ`` (causal ~3 Hz Butterworth velocity, lags the position), ``dataDDotQ`` (backward difference, one row
shorter), ``dataCur`` (motor current, A), ``dataTimeStamp`` (s). Row alignment (as the lab used it): q, filtered
velocity, current and time from the second row on, ``dataDDotQ`` whole. Joint torque = current x k_m x gear ratio.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from ..errors import DataError

__all__ = [
    "KRANG_ARM_KM",
    "KRANG_ARM_GEAR",
    "KRANG_ARM_JOINTS",
    "DataError",
    "ArmData",
    "load_arm_run",
    "arm_data_from_arrays",
    "current_limits",
]

#: Motor torque constants (N m / A) and gear ratios of the 7 arm joints (data README). Joint 7: the simulator
#: config lists a PRL60 with ratio 300 instead of 552; with a free per-joint scale (rotor inertia, friction) only
#: the rigid-body part of joint 7's torque depends on it, and 552 is used as in the lab's identification.
KRANG_ARM_KM = np.array([31.4, 31.4, 38.0, 38.0, 16.0, 16.0, 16.0]) * 1e-3
KRANG_ARM_GEAR = np.array([596.0, 596.0, 625.0, 625.0, 552.0, 552.0, 552.0])
KRANG_ARM_JOINTS = ("LJ1", "LJ2", "LJ3", "LJ4", "LJ5", "LJ6", "LJFT")

#: A joint "never moves" when the range of its position over a run is below this (rad).
MIN_JOINT_RANGE = 1e-3


@dataclasses.dataclass(frozen=True)
class ArmData:
    """One aligned run. Arrays are numpy, ``(N, n)`` except ``t`` ``(N,)``; ``torque = current k_m N``."""

    t: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    qdd: np.ndarray
    current: np.ndarray
    torque: np.ndarray
    name: str = "run"
    joint_names: tuple = KRANG_ARM_JOINTS

    def __len__(self) -> int:
        return self.q.shape[0]

    def subsample(self, step: int = 1, start: int = 0, stop: Optional[int] = None) -> "ArmData":
        """Rows ``start:stop:step`` (the signals are already computed: subsampling changes no derivative)."""
        s = slice(start, stop, step)
        return dataclasses.replace(self, t=self.t[s], q=self.q[s], qd=self.qd[s], qdd=self.qdd[s],
                                   current=self.current[s], torque=self.torque[s])


def _read(path: Path, ncols: Optional[int]) -> np.ndarray:
    if not path.is_file():
        raise DataError(f"{path}: file not found")
    try:
        a = np.loadtxt(path, ndmin=2)
    except ValueError as e:
        raise DataError(f"{path}: not a whitespace-separated numeric table ({e})") from None
    if ncols is not None and a.shape[1] != ncols:
        raise DataError(f"{path}: expected {ncols} columns (one per joint), found {a.shape[1]}")
    bad = ~np.all(np.isfinite(a), axis=1)
    if bad.any():
        rows = (np.flatnonzero(bad) + 1).tolist()
        raise DataError(f"{path}: non-finite (NaN/inf) values on line(s) {rows[:10]}{' ...' if len(rows) > 10 else ''}")
    return a


def arm_data_from_arrays(*, t, q, qd, qdd, current, km=KRANG_ARM_KM, gear=KRANG_ARM_GEAR, name="run",
                         joint_names: Sequence[str] = KRANG_ARM_JOINTS, sources=None) -> ArmData:
    """Check already aligned arrays and build :class:`ArmData`; ``sources`` names the file of each array."""
    sources = sources or {}
    arrays = {"t": np.asarray(t, float).reshape(-1), "q": np.asarray(q, float), "qd": np.asarray(qd, float),
              "qdd": np.asarray(qdd, float), "current": np.asarray(current, float)}
    n = len(joint_names)
    for key, a in arrays.items():
        where = sources.get(key, key)
        if key != "t" and (a.ndim != 2 or a.shape[1] != n):
            raise DataError(f"{where}: expected shape (N, {n}), got {a.shape}")
        bad = ~np.isfinite(a.reshape(a.shape[0], -1)).all(axis=1)
        if bad.any():
            raise DataError(f"{where}: non-finite (NaN/inf) values at aligned row(s) {np.flatnonzero(bad)[:10].tolist()}")
    lengths = {sources.get(k, k): a.shape[0] for k, a in arrays.items()}
    if len(set(lengths.values())) != 1:
        raise DataError(f"{name}: aligned lengths differ: {lengths}")
    if not np.all(np.diff(arrays["t"]) > 0):
        raise DataError(f"{sources.get('t', 't')}: time stamps are not strictly increasing")
    rng = np.ptp(arrays["q"], axis=0)
    for j in range(n):
        if not rng[j] > MIN_JOINT_RANGE:
            raise DataError(f"{sources.get('q', name)}: joint {j + 1} ('{joint_names[j]}') never moves "
                            f"(position range {rng[j]:.3g} rad <= {MIN_JOINT_RANGE} rad): its parameters cannot be "
                            "identified from this run")
    torque = arrays["current"] * np.asarray(km) * np.asarray(gear)
    return ArmData(t=arrays["t"], q=arrays["q"], qd=arrays["qd"], qdd=arrays["qdd"], current=arrays["current"],
                   torque=torque, name=name, joint_names=tuple(joint_names))


def load_arm_run(folder, *, km=KRANG_ARM_KM, gear=KRANG_ARM_GEAR,
                 joint_names: Sequence[str] = KRANG_ARM_JOINTS) -> ArmData:
    """Load one run folder with the lab's row alignment (see module docstring).

    Raises :class:`DataError` naming the file (and line) for a missing file, NaN/inf values, a wrong column
    count or a length mismatch (``dataDDotQ`` must be exactly one row shorter than the others), and naming the
    joint for a joint that never moves.
    """
    folder = Path(folder)
    n = len(joint_names)
    files = {"q": "dataQ.txt", "qd": "dataDotQ.txt", "qdd": "dataDDotQ.txt", "current": "dataCur.txt",
             "t": "dataTimeStamp.txt"}
    raw = {k: _read(folder / f, None if k == "t" else n) for k, f in files.items()}
    nq = raw["q"].shape[0]
    for k in ("qd", "current", "t"):
        if raw[k].shape[0] != nq:
            raise DataError(f"{folder / files[k]}: {raw[k].shape[0]} rows but {folder / files['q']} has {nq}")
    if raw["qdd"].shape[0] != nq - 1:
        raise DataError(f"{folder / files['qdd']}: {raw['qdd'].shape[0]} rows; expected one fewer than "
                        f"{folder / files['q']} ({nq - 1})")
    return arm_data_from_arrays(
        t=raw["t"][1:, 0], q=raw["q"][1:], qd=raw["qd"][1:], qdd=raw["qdd"], current=raw["current"][1:],
        km=km, gear=gear, name=str(folder), joint_names=joint_names,
        sources={k: str(folder / f) for k, f in files.items()})


def current_limits(current: np.ndarray, *, rel: float = 2e-3, min_count: int = 5) -> np.ndarray:
    """Per-joint current limit ``(n,)`` detected as a plateau: ``max |i|`` if at least ``min_count`` samples lie
    within ``rel`` of it (the controller clips there), else ``inf`` (the joint never saturated)."""
    a = np.abs(np.asarray(current))
    top = a.max(axis=0)
    hits = (a >= top * (1 - rel)).sum(axis=0)
    return np.where(hits >= min_count, top * (1 - rel), np.inf)
