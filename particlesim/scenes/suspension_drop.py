"""A planar two-mass suspension dropped onto its tyre: chassis and wheel slide on one vertical guide, a
spring-damper joins them, a one-sided tyre (with damping, so its force jumps at contact) stands under the wheel.
Released from rest above the ground, the tyre touches down, lifts off and touches down again within
``DROP["t_end"]``: the test case for derivatives across contact switches (``simulate_mechanism(...,
events=True)``).
"""

from __future__ import annotations

from ..mechanism import MechanismBuilder

__all__ = ["DROP", "suspension_drop", "drop_params"]

#: Masses [kg], suspension stiffness [N/m] and damping [N s/m], tyre stiffness, damping and radius, gravity,
#: suspension free length [m], release heights of chassis and wheel [m], time span [s].
DROP = dict(mc=250.0, mw=35.0, k=2.0e4, c=4.0e2, kt=1.5e5, ct=100.0, radius=0.3, g=9.81, free_length=0.5,
            yc0=1.15, yw0=0.7, t_end=1.3)


def suspension_drop():
    """``(mech, q0)``: the suspension at its release heights (particles ``C`` chassis, ``W`` wheel centre)."""
    d = DROP
    mb = MechanismBuilder(planar=True, gravity=(0.0, -d["g"]))
    mb.ground("G0", (0.0, 0.0))
    mb.ground("G1", (0.0, 1.0))
    mb.particle("C", (0.0, d["yc0"]))
    mb.particle("C'", (0.0, d["yc0"] + 0.2))
    mb.particle("W", (0.0, d["yw0"]))
    mb.particle("W'", (0.0, d["yw0"] + 0.05))
    mb.rod("chassis", "C", "C'", d["mc"], com=(0.0, d["yc0"]), moment=0.0, on_negative="ignore")
    mb.rod("wheel", "W", "W'", d["mw"], com=(0.0, d["yw0"]), moment=0.0, on_negative="ignore")
    mb.prismatic(("G0", "G1"), ("C", "C'"), name="chassis guide")
    mb.prismatic(("G0", "G1"), ("W", "W'"), name="wheel guide")
    mb.spring_damper("suspension", "C", "W", d["k"], d["c"], d["free_length"])
    mb.tyre("tyre", "W", d["kt"], d["ct"], d["radius"], normal=(0.0, 1.0, 0.0))
    return mb.build(dof=2)


def drop_params(mech, p):
    """``mech`` with ``p = (k, c, kt, ct, mc, mw)`` set by name (values may be traced)."""
    return mech.with_params(spring={"suspension": {"stiffness": p[0], "damping": p[1]}},
                            tyre={"tyre": {"stiffness": p[2], "damping": p[3]}},
                            body={"chassis": {"mass": p[4]}, "wheel": {"mass": p[5]}})
