"""MuJoCo C driven as its engineers drive it: ``mujoco.rollout`` (the native loop, no Python per step), per-stage
forces as compiled C callbacks (:mod:`particlesim.twins.callbacks`) or MuJoCo elements, ``nthread`` 0 (the calling thread)
or more, one model per batch member when parameters differ.

:class:`Rollout` times only the native call; turning its states into observations (kinematics at the save times)
is the benchmark's post-processing and is not timed.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import mujoco
import numpy as np
from mujoco import rollout as mj_rollout

__all__ = ["Rollout", "initial_state", "sampled", "STATE"]

STATE = mujoco.mjtState.mjSTATE_FULLPHYSICS


def initial_state(m: mujoco.MjModel, d: mujoco.MjData | None = None) -> np.ndarray:
    """The full physics state ``(nstate,)`` of ``d`` (default: the model's reference pose) after ``mj_forward``."""
    d = mujoco.MjData(m) if d is None else d
    mujoco.mj_forward(m, d)
    out = np.zeros(mujoco.mj_stateSize(m, STATE))
    mujoco.mj_getState(m, d, out, STATE)
    return out


class Rollout:
    """``nstep`` RK4 steps of one model (or of one model per batch member) through ``mujoco.rollout``.

    ``observe(m, d) -> (k,)`` reads one observation from ``d`` after kinematics; :meth:`trajectory` evaluates it at
    every ``stride``-th state."""

    def __init__(self, models: mujoco.MjModel | Sequence[mujoco.MjModel], state0: np.ndarray, nstep: int, *,
                 nthread: int = 0):
        self.models = models
        self.state0 = np.atleast_2d(state0)
        self.nstep = int(nstep)
        self.nthread = nthread
        first = models if isinstance(models, mujoco.MjModel) else models[0]
        self.datas = [mujoco.MjData(first) for _ in range(max(nthread, 1))]
        self.runner = mj_rollout.Rollout(nthread=nthread)

    def __call__(self) -> np.ndarray:
        states, _ = self.runner.rollout(self.models, self.datas if self.nthread else self.datas[0], self.state0,
                                        nstep=self.nstep)
        return states

    def timed(self, repeat: int = 3) -> tuple[np.ndarray, float]:
        """``(states of the first run, least wall time over the repeats)``, timed as ours are
        (:func:`benchmarks._wp._time`)."""
        from ._wp import _time

        return _time(self, repeat, lambda o: o)

    def trajectory(self, states: np.ndarray, observe: Callable, stride: int, member: int = 0) -> np.ndarray:
        """Observations at the initial state and every ``stride``-th step of batch member ``member``."""
        m = self.models if isinstance(self.models, mujoco.MjModel) else self.models[member]
        d = mujoco.MjData(m)
        out = []
        for k in range(0, self.nstep + 1, stride):
            row = self.state0[member] if k == 0 else states[member, k - 1]
            mujoco.mj_setState(m, d, row, STATE)
            mujoco.mj_kinematics(m, d)
            out.append(np.asarray(observe(m, d), dtype=float).reshape(-1))
        return np.asarray(out)


def sampled(m: mujoco.MjModel, d: mujoco.MjData | None, t_end: float, dt: float, save_dt: float,
            observe: Callable) -> tuple[Rollout, Callable[[np.ndarray], np.ndarray]]:
    """``(rollout, to_traj)`` as :func:`benchmarks._wp.sweep_rollout` takes them: ``m`` run from ``d`` (None: its
    reference pose) for ``t_end`` in steps ``dt``; ``to_traj(states)`` observes ``observe(m, d)`` at the start and
    every ``save_dt``."""
    ro = Rollout(m, initial_state(m, d), int(round(t_end / dt)))
    stride = int(round(save_dt / dt))
    return ro, lambda states: ro.trajectory(states, observe, stride)
