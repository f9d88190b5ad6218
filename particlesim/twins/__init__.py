"""MuJoCo C and MJX twins: the same models written in MuJoCo's own terms, the independent references that tests
and benchmarks compare against. The core never imports this package; tests, benchmarks and the reports
of the main job do.

* :mod:`.urdf` — a URDF tree as an ``MjModel``/``MjSpec`` (pure rigid tree) and the joint map between MuJoCo's
  order and ours;
* :mod:`.chains`, :mod:`.quarter_car`, :mod:`.nikravesh`, :mod:`.andrews`, :mod:`.four_bar`, :mod:`.bricard`,
  :mod:`.flyball`, :mod:`.vehicle` — MJCF writers (and C rollouts) of the scenes in :mod:`particlesim.scenes`;
* :mod:`.callbacks` — passive-force callbacks evaluated at every RK4 stage (the one-sided tyre, sine torques), compiled
  in C for ``mujoco.rollout``/``mujoco.batch`` threads, and the tyre as a Python reference;
* :mod:`.mjx` — MuJoCo's RK4 around MJX's forward stages (forces evaluated per stage) and the MJX rollouts.

Modules are imported on use (``from particlesim.twins import quarter_car``): each pulls in MuJoCo, and
:mod:`.mjx` MJX.
"""

__all__ = ["urdf", "chains", "quarter_car", "nikravesh", "andrews", "four_bar", "bricard", "flyball", "vehicle",
           "callbacks", "mjx"]
