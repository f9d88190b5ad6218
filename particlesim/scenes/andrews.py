"""Andrews' squeezing mechanism (IFToMM benchmark A03), as a particle mechanism.

Seven bodies, ten revolute joints, two closed loops, a constant motor torque on the crank and a spring; no gravity.
Data and the reference state at t = 0.03 s: ``shared/reference/mbs-benchmarks.md`` (the constants of the IVP test
set; Hairer and Wanner's joint-angle formulation). Particle layout (choices of this package):

* crank OF (body 1): a planar set O (ground), F and a third particle beside the crank (the motor torque needs a
  body that can carry one);
* links FE, EG, EH (bodies 2, 4, 6): rods, their centres of mass lie on their joint lines;
* triangle B-D-E (body 3): a planar set B (ground), E and the spring point D;
* links GA and HA (bodies 5, 7): planar sets with a third particle (their centres of mass are off the joint line);
* the revolute joints are the shared particles (E is shared by four bodies; A by two, fixed to the ground).

The data give only the polar moment of each body; a planar set needs the in-plane split, chosen as ``J/2, J/2``
(it does not enter planar motion). The directions of the off-line centres of mass of bodies 3, 5 and 7 do not enter
the dynamics (each turns about a fixed point, without gravity; only the distance does); the directions used here
are a choice of this package. The mechanism lives in 3-D: nothing excites the out-of-plane freedoms, and
the out-of-plane coordinates stay zero.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from ..inertia import RigidInertia
from ..mechanism import MechanismBuilder

__all__ = ["CONST", "Q0", "REFERENCE_T", "REFERENCE_Q", "REFERENCE_QD", "andrews_mechanism", "joint_angles",
           "angles_from_points"]

#: The constants of the benchmark (masses kg, inertias about the CoM kg m^2, lengths m, c0 N/m, mom N m).
CONST = dict(
    m1=.04325, m2=.00365, m3=.02373, m4=.00706, m5=.07050, m6=.00706, m7=.05498,
    I1=2.194e-6, I2=4.410e-7, I3=5.255e-6, I4=5.667e-7, I5=1.169e-5, I6=5.667e-7, I7=1.912e-5,
    xa=-.06934, ya=-.00227, xb=-.03635, yb=.03273, xc=.014, yc=.072,
    d=28e-3, da=115e-4, e=2e-2, ea=1421e-5, rr=7e-3, ra=92e-5, l0=7785e-5,
    ss=35e-3, sa=1874e-5, sb=1043e-5, sc=18e-3, sd=2e-2, ta=2308e-5, tb=916e-5,
    u=4e-2, ua=1228e-5, ub=449e-5, zf=2e-2, zt=4e-2, fa=1421e-5, c0=4530.0, mom=0.033)
#: Initial joint angles (beta, Theta, gamma, Phi, delta, Omega, epsilon), at rest.
Q0 = np.array([-0.0617138900142764496358948458001, 0.0, 0.455279819163070380255912382449,
               0.222668390165885884674473185609, 0.487364979543842550225598953530,
               -0.222668390165885884674473185609, 1.23054744454982119249735015568])
#: The published reference (PSIDE, rtol = atol = 1e-14) at t = 0.03 s: joint angles and their rates.
REFERENCE_T = 0.03
REFERENCE_Q = np.array([0.1581077119629904e+02, -0.1575637105984298e+02, 0.4082224013073101e-01,
                        -0.5347301163226948e+00, 0.5244099658805304e+00, 0.5347301163226948e+00,
                        0.1048080741042263e+01])
REFERENCE_QD = np.array([0.1139920302151208e+04, -0.1424379294994111e+04, 0.1103291221937134e+02,
                         0.1929337464421385e+02, 0.5735699284790808e+00, -0.1929337464421385e+02,
                         0.3231791658026955e+00])


def _rot(a: float) -> np.ndarray:
    return np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])


def _points(q) -> dict[str, np.ndarray]:
    """Joint points and centres of mass in the plane from the joint angles (the benchmark's kinematics)."""
    c = CONST
    beta, theta, gamma, phi, delta, omega, eps = q
    o = np.zeros(2)
    a, b, cc = np.array([c["xa"], c["ya"]]), np.array([c["xb"], c["yb"]]), np.array([c["xc"], c["yc"]])
    f = c["rr"] * np.array([np.cos(beta), np.sin(beta)])
    e = f - c["d"] * np.array([np.cos(beta + theta), np.sin(beta + theta)])
    g = e + c["e"] * np.array([-np.sin(phi + delta), np.cos(phi + delta)])
    h = e - c["zf"] * np.array([np.cos(omega + eps), np.sin(omega + eps)])
    rg = _rot(gamma)
    pts = {
        "O": o, "A": a, "B": b, "C": cc, "F": f, "E": e, "G": g, "H": h,
        "D": b + rg @ np.array([c["sd"], -c["sc"]]),
        "com1": c["ra"] * f / c["rr"],
        "com2": f + c["da"] * (e - f) / c["d"],
        "com3": b + rg @ np.array([c["sa"], -c["sb"]]),
        "com4": e + c["ea"] * (g - e) / c["e"],
        "com5": a + _rot(delta) @ np.array([c["ta"], c["tb"]]),
        "com6": e + c["fa"] * (h - e) / c["zf"],
        "com7": a + _rot(eps) @ np.array([-c["ub"], c["ua"]]),
    }
    # third particles of the planar crank and links GA, HA: beside the joint line, in the plane
    for name, p0, p1 in (("P1", o, f), ("P5", a, g), ("P7", a, h)):
        v = p1 - p0
        pts[name] = p0 + 0.5 * v + 0.5 * np.array([-v[1], v[0]])
    return pts


def _lamina(m: float, com2: np.ndarray, j: float) -> RigidInertia:
    return RigidInertia(m, (*com2, 0.0), np.diag([j / 2, j / 2, j]))


def _rod(m: float, com2: np.ndarray, j: float, p: np.ndarray, q: np.ndarray) -> RigidInertia:
    return RigidInertia.slender_rod(m, (*p, 0.0), (*q, 0.0), com=(*com2, 0.0), moment=j)


def andrews_mechanism(q0=Q0, planar: bool = False):
    """Build the mechanism at joint angles ``q0`` (at rest); returns the mechanism and its particle state. ``planar=True`` builds it as a
    planar mechanism (:class:`~particlesim.mechanism.MechanismBuilder` ``planar``: one degree of freedom, no
    out-of-plane freedoms); by default it lives in 3-D, as the benchmarks time it."""
    c = CONST
    pts = _points(np.asarray(q0, dtype=float))
    xyz = {k: np.append(v, 0.0) for k, v in pts.items()}
    mb = MechanismBuilder(gravity=(0.0, 0.0, 0.0), planar=planar)
    for g in ("O", "A", "B", "C"):
        mb.ground(g, xyz[g])
    for p in ("F", "E", "G", "H", "D", "P1", "P5", "P7"):
        mb.particle(p, xyz[p])
    kw = dict(on_negative="ignore")
    mb.body("crank", _lamina(c["m1"], pts["com1"], c["I1"]), ["O", "F", "P1"], **kw)
    mb.body("FE", _rod(c["m2"], pts["com2"], c["I2"], pts["F"], pts["E"]), ["F", "E"], **kw)
    mb.body("BDE", _lamina(c["m3"], pts["com3"], c["I3"]), ["B", "E", "D"], **kw)
    mb.body("EG", _rod(c["m4"], pts["com4"], c["I4"], pts["E"], pts["G"]), ["E", "G"], **kw)
    mb.body("GA", _lamina(c["m5"], pts["com5"], c["I5"]), ["A", "G", "P5"], **kw)
    mb.body("EH", _rod(c["m6"], pts["com6"], c["I6"], pts["E"], pts["H"]), ["E", "H"], **kw)
    mb.body("HA", _lamina(c["m7"], pts["com7"], c["I7"]), ["A", "H", "P7"], **kw)
    mb.spring_damper("spring", "D", "C", c["c0"], 0.0, c["l0"])
    mb.applied_torque("motor", "crank", _Motor(c["mom"]))
    return mb.build(dof=1 if planar else None)


class _Motor:
    """Constant torque about +z (hashable and equal by value, so rebuilt mechanisms share compiled code)."""

    def __init__(self, mom: float):
        self.mom = float(mom)

    def __call__(self, t, q, qd):
        return jnp.array([0.0, 0.0, self.mom])

    def __eq__(self, other):
        return isinstance(other, _Motor) and other.mom == self.mom

    def __hash__(self):
        return hash(("andrews motor", self.mom))


def _angle(v):
    return np.arctan2(v[..., 1], v[..., 0])


def _rate(v, vd):
    return (v[..., 0] * vd[..., 1] - v[..., 1] * vd[..., 0]) / np.sum(v * v, axis=-1)


def joint_angles(mech, qs, qds):
    """The benchmark's joint angles and rates ``(n, 7)`` each from particle states ``(n, 3F)`` (a time series
    from the start, so that the crank angles are unwrapped continuously)."""
    qs, qds = np.atleast_2d(np.asarray(qs)), np.atleast_2d(np.asarray(qds))
    return angles_from_points(*(qs[:, mech.free_slice(n)][:, :2] for n in "FEGH"),
                              *(qds[:, mech.free_slice(n)][:, :2] for n in "FEGH"))


def angles_from_points(f, e, g, h, fd, ed, gd, hd):
    """Joint angles and rates ``(n, 7)`` from time series ``(n, 2)`` of the joint points F, E, G, H and their
    velocities in the plane (the ground points A, B are the benchmark's)."""
    a = np.array([CONST["xa"], CONST["ya"]])
    b = np.array([CONST["xb"], CONST["yb"]])
    rot90 = lambda v: np.stack([v[..., 1], -v[..., 0]], axis=-1)  # noqa: E731  angle(rot90(v)) = angle(v) - pi/2
    vecs = [  # (vector, its rate) whose polar angle gives each absolute angle
        (f, fd),  # beta
        (f - e, fd - ed),  # beta + Theta
        (rot90(b - e), rot90(-ed)),  # gamma: B - E = ss (-sin g, cos g)
        (rot90(g - e), rot90(gd - ed)),  # Phi + delta
        (g - a, gd),  # delta
        (e - h, ed - hd),  # Omega + epsilon
        (rot90(a - h), rot90(-hd)),  # epsilon
    ]
    ang = np.stack([np.unwrap(_angle(v)) for v, _ in vecs], axis=1)
    rate = np.stack([_rate(v, vd) for v, vd in vecs], axis=1)
    for j in range(7):  # each series on the branch of its initial angle
        ang[:, j] += 2 * np.pi * np.round((_sum_start(j) - ang[0, j]) / (2 * np.pi))
    q = np.stack([ang[:, 0], ang[:, 1] - ang[:, 0], ang[:, 2], ang[:, 3] - ang[:, 4], ang[:, 4],
                  ang[:, 5] - ang[:, 6], ang[:, 6]], axis=1)
    qd = np.stack([rate[:, 0], rate[:, 1] - rate[:, 0], rate[:, 2], rate[:, 3] - rate[:, 4], rate[:, 4],
                   rate[:, 5] - rate[:, 6], rate[:, 6]], axis=1)
    return q, qd


def _sum_start(j: int) -> float:
    """Initial value of each series of :func:`joint_angles` (the absolute angles the vectors give)."""
    beta, theta, gamma, phi, delta, omega, eps = Q0
    return [beta, beta + theta, gamma, phi + delta, delta, omega + eps, eps][j]
