"""IFToMM multibody benchmark problems as particle mechanisms (``shared/reference/mbs-benchmarks.md``).

A03 (Andrews' squeezing mechanism) lives in :mod:`particlesim.scenes.andrews`.

* :func:`a01_pendulum` — A01, the simple pendulum: a 1 kg point mass on a massless 1 m link hinged at the origin,
  released at rest from the horizontal (+1, 0), gravity 9.81 along −y, 2000 s. As particles: a rod body whose
  whole mass sits at its tip (its particle masses solve to 0 at the pivot and the midpoint, 1 kg at the tip).
* :func:`a02_four_bar` — A02, the N-four-bar: a row of N unit squares (N + 1 cranks, N couplers, 1 m and 1 kg
  uniform rods) with B0 moving at +1 m/s, gravity along −y, 20 s. Twice per revolution the linkage lies flat, where
  the constraint Jacobian loses N ranks; it is built with least-squares multipliers to cross those positions. As
  particles: one rod per link; the ground pivots ``A{i}`` and the crank tops ``B{i}`` are the particles, the
  couplers share them (revolute joints in the plane; the out-of-plane freedoms are never excited).
  :func:`a02_reduced` is the one-coordinate model of the parallelogram motion (for checks).
* :func:`a04_bricard` — A04, Bricard's linkage: five 1 m, 1 kg square-section rods (0.1 m × 0.1 m), six revolute
  joints whose axes are each perpendicular to both rods at the joint, gravity along −y, from rest. Its 24 particle
  constraint rows have rank 23 everywhere (Grübler counts 0 freedoms, the linkage has 1): built with least-squares
  multipliers. As particles: each rod is a spatial set of four primaries, the two particles of the joint axis at
  each end (axis particles ``P{i}`` and ``P{i}a``, ``AXIS_OFFSET`` apart); neighbouring rods share them.
* :func:`a05_flyball` — A05, the flyball governor: a free vertical shaft spinning at 2π rad/s, a slider on it
  (prismatic), two rods hinged at the shaft top carrying 5 kg balls, and two stiff spring-dampers (k = 8e5 N/m,
  c = 4e4 N s/m) from the slider to the rods' midpoints; stiff, for the implicit solvers. Shaft axis z, gravity
  along −z.
* :func:`slider_crank` — the slider-crank of the IVP Test Set's "crank" problem with a **rigid** connecting rod:
  crank (0.15 m, 0.36 kg), rod (0.30 m, 0.151104 kg), slider block (0.075552 kg), no gravity, the crank driven at
  Ω = 150 rad/s (a driving constraint, fully driven: 0 degrees of freedom). The published reference belongs to the
  flexible rod (four elastic coordinates), which a rigid-body model cannot represent; the rigid model is checked
  against the closed-form slider-crank kinematics and its driving torque against the energy balance.
  ``J1``, ``J2`` of the source are read as moments about the crank's pivot and the rod's crank-pin end (``J2`` equals
  ``m2 l2^2/3 + m2 h^2/12`` for the 8 mm section to all its digits, which confirms that reading).
"""

from __future__ import annotations

import numpy as np

from ..inertia import RigidInertia
from ..mechanism import MechanismBuilder, scalar_mass_matrix

__all__ = ["A01", "a01_pendulum", "A02", "a02_four_bar", "a02_reduced", "A04", "a04_bricard", "AXIS_OFFSET",
           "A05", "a05_flyball", "flyball_slider_height", "angular_momentum_z", "CRANK", "slider_crank",
           "slider_crank_exact"]

#: A01 data: mass [kg], length [m], gravity [m/s^2], time span [s], output samples.
A01 = dict(mass=1.0, length=1.0, g=9.81, t_end=2000.0, outputs=4000)


def a01_pendulum(mass: float = A01["mass"], length: float = A01["length"], g: float = A01["g"]):
    """The A01 pendulum; returns ``(mech, q0)`` (q0: the bob at (length, 0, 0), the link horizontal)."""
    mb = MechanismBuilder(gravity=(0.0, -g, 0.0))
    mb.ground("O", (0.0, 0.0, 0.0))
    mb.particle("P1", (length, 0.0, 0.0))
    mb.body("bob", RigidInertia(mass, (length, 0.0, 0.0), np.zeros((3, 3)), degenerate_ok=True, name="bob"),
            ["O", "P1"])
    return mb.build(dof=2)  # in 3-D: the swing and the out-of-plane swing (never excited)


#: A02 data: links per row (the benchmark's N), link length [m] and mass [kg], gravity, time span, outputs.
A02 = dict(n=40, length=1.0, mass=1.0, g=9.81, t_end=20.0, outputs=400)


def a02_four_bar(n: int = A02["n"], g: float = A02["g"]):
    """The A02 N-four-bar at t = 0; returns ``(mech, q0, qd0)`` (every crank top moving at +1 m/s along x).

    Unit squares: ground pivots ``A{i} = (i, 0)``, crank tops ``B{i} = (i, 1)``, ``i = 0..n``; crank ``i`` is the rod
    ``A{i}-B{i}``, coupler ``i`` (1..n) the rod ``B{i-1}-B{i}``."""
    if int(n) != n or n < 1:
        raise ValueError(f"a02_four_bar: n must be a positive integer, got {n!r}")
    n = int(n)
    mb = MechanismBuilder(gravity=(0.0, -g, 0.0))
    for i in range(n + 1):
        mb.ground(f"A{i}", (float(i), 0.0, 0.0))
        mb.particle(f"B{i}", (float(i), 1.0, 0.0))
        mb.body(f"crank{i}", RigidInertia.slender_rod(1.0, (i, 0.0, 0.0), (i, 1.0, 0.0), name=f"crank{i}"),
                [f"A{i}", f"B{i}"])
    for i in range(1, n + 1):
        mb.body(f"coupler{i}", RigidInertia.slender_rod(1.0, (i - 1, 1.0, 0.0), (i, 1.0, 0.0), name=f"coupler{i}"),
                [f"B{i - 1}", f"B{i}"])
    mech, q0 = mb.build(dof=1 + (n + 1), multipliers="least_squares")  # in-plane 1, out-of-plane one per crank top
    qd0 = np.tile([1.0, 0.0, 0.0], n + 1)
    return mech, q0, qd0


def a02_reduced(n: int = A02["n"], g: float = A02["g"]) -> tuple[float, float]:
    """The parallelogram motion in its one coordinate θ (crank angle from the upward vertical, clockwise positive;
    B0 = (sin θ, cos θ)): ``I θ̈ = c sin θ`` with ``I = (n + 1)/3 + n`` (cranks about their pivots, couplers
    translating) and ``c = g ((n + 1)/2 + n)``; returns ``(I, c)``. Energy ``I θ̇²/2 + c cos θ``."""
    return (n + 1) / 3.0 + n, g * ((n + 1) / 2.0 + n)


#: A04 data: rod length [m], mass [kg], square section side [m], gravity, time span [s].
A04 = dict(length=1.0, mass=1.0, side=0.1, g=9.81, t_end=10.0)
#: Distance between the two particles that carry a joint axis [m] (a choice of this package).
AXIS_OFFSET = 0.1
_BRICARD_P = np.array([[0, 0, 0], [1, 0, 0], [1, -1, 0], [1, -1, 1], [0, -1, 1], [0, 0, 1]], dtype=float)
_BRICARD_AXES = np.eye(3)[[1, 2, 0, 1, 2, 0]]  # P1 y, P2 z, P3 x, P4 y, P5 z, P6 x


def a04_bricard(g: float = A04["g"]):
    """Bricard's linkage (A04) at rest in its initial position; returns ``(mech, q0)``. Joint ``i`` (1..6) sits at
    ``P{i}`` with axis particle ``P{i}a = P{i} + AXIS_OFFSET * axis``; rod ``i`` runs ``P{i} -> P{i+1}``; joints 1 and
    6 are on the ground. P3, the point the benchmark reports, is the particle ``P3``."""
    c = A04
    mb = MechanismBuilder(gravity=(0.0, -g, 0.0))
    for i, (p, a) in enumerate(zip(_BRICARD_P, _BRICARD_AXES), start=1):
        add = mb.ground if i in (1, 6) else mb.particle
        add(f"P{i}", p)
        add(f"P{i}a", p + AXIS_OFFSET * a)
    side, m, ell = c["side"], c["mass"], c["length"]
    axial, transverse = m * (2 * side**2) / 12, m * (ell**2 + side**2) / 12
    for i in range(1, 6):
        p, q = _BRICARD_P[i - 1], _BRICARD_P[i]
        u = (q - p) / np.linalg.norm(q - p)
        inertia = transverse * (np.eye(3) - np.outer(u, u)) + axial * np.outer(u, u)
        mb.body(f"rod{i}", RigidInertia(m, (p + q) / 2, inertia, name=f"rod{i}"),
                [f"P{i}", f"P{i}a", f"P{i + 1}", f"P{i + 1}a"], on_negative="ignore")
    return mb.build(dof=1, multipliers="least_squares")


#: A05 data (the OpenSim port's values): prism density [kg/m^3], shaft/rod length and section [m], slider cube side,
#: ball mass [kg], pivot offset from the shaft axis [m], spring constants, initial slider height [m] and rod angle
#: below the horizontal [rad], shaft rate [rad/s], gravity, time span [s]; the spec's derived initial I_z and H_z.
A05 = dict(density=3000.0, length=1.0, section=0.01, cube=0.1, ball=5.0, offset=0.05, stiffness=8e5,
           damping=4e4, free_length=0.5, s0=0.5, alpha0=np.pi / 6, omega0=2 * np.pi, g=9.81, t_end=10.0,
           iz0=8.573517, hz0=53.868999)


def _prism(mass, sides, axis):
    """Inertia about the centre of a uniform box with edge lengths ``sides`` along the orthonormal ``axis`` rows."""
    a, b, c = sides
    mom = mass / 12 * np.array([b * b + c * c, a * a + c * c, a * a + b * b])
    axes = np.asarray(axis, dtype=float)
    return axes.T @ np.diag(mom) @ axes


def a05_flyball(g: float = A05["g"]):
    """The A05 flyball governor at t = 0; returns ``(mech, q0, qd0)`` (everything turning with the shaft at 2π rad/s).

    Particles: the shaft holds ground particles ``O`` (bottom) and ``T`` (top) on its axis and the pin particles
    ``P1``, ``P1y`` of rod 1's hinge (``P1`` = (0.05, 0, 1), ``P1y`` one offset along the pin axis y); rod 2 is hinged
    at the shaft points ``S2``/``S2y`` (a cut joint and a point on the pin line). Each rod: pin particles, tip
    ``E{i}`` (with the ball) and ``K{i}`` beside the pivot in the rods' plane; midpoints ``M{i}``. The slider: ``B0``,
    ``B1`` on the axis, ``Bx``, ``By`` beside it, on a prismatic joint along the shaft (``O``, ``T``, ``P1``);
    springs ``Bx``-``M1`` and ``Bm``-``M2`` (``Bm`` the slider point at -0.05 along x)."""
    c = A05
    rho, ell, a, off = c["density"], c["length"], c["section"], c["offset"]
    m_prism = rho * ell * a * a
    m_cube = rho * c["cube"] ** 3
    mb = MechanismBuilder(gravity=(0.0, 0.0, -g))
    z, s0, al = ell, c["s0"], c["alpha0"]
    mb.ground("O", (0.0, 0.0, 0.0))
    mb.ground("T", (0.0, 0.0, z))
    mb.particle("P1", (off, 0.0, z))
    mb.particle("P1y", (off, off, z))
    mb.body("shaft", RigidInertia(m_prism, (0.0, 0.0, ell / 2), _prism(m_prism, (a, a, ell), np.eye(3)),
                                  name="shaft"), ["O", "T", "P1", "P1y"], on_negative="ignore")
    mb.point("S2", "shaft", (-off, 0.0, z))
    mb.point("S2y", "shaft", (-off, off, z))
    for i, sgn in ((1, 1.0), (2, -1.0)):
        pivot = np.array([sgn * off, 0.0, z])
        d = np.array([sgn * np.cos(al), 0.0, -np.sin(al)])
        n = np.array([sgn * np.sin(al), 0.0, np.cos(al)])
        tip, mid = pivot + ell * d, pivot + ell / 2 * d
        if i == 2:
            mb.particle("P2", pivot)
            mb.particle("P2y", pivot + (0.0, off, 0.0))
        mb.particle(f"E{i}", tip)
        mb.particle(f"K{i}", pivot + off * n)
        mass = m_prism + c["ball"]
        com = (m_prism * mid + c["ball"] * tip) / mass
        rod = _prism(m_prism, (ell, a, a), np.stack([d, (0.0, 1.0, 0.0), n]))
        inertia = rod + m_prism * _shift(mid - com) + c["ball"] * _shift(tip - com)
        mb.body(f"rod{i}", RigidInertia(mass, com, inertia, name=f"rod{i}"), [f"P{i}", f"P{i}y", f"E{i}", f"K{i}"],
                on_negative="ignore")
        mb.point(f"M{i}", f"rod{i}", mid)
    mb.cut_joint("P2", "S2", name="rod2 hinge")
    mb.on_line("P2y", "S2", ("S2", "S2y"), "T", name="rod2 hinge axis")
    h = c["cube"] / 2
    mb.particle("B0", (0.0, 0.0, s0 - h))
    mb.particle("B1", (0.0, 0.0, s0 + h))
    mb.particle("Bx", (off, 0.0, s0))
    mb.particle("By", (0.0, off, s0))
    mb.body("slider", RigidInertia(m_cube, (0.0, 0.0, s0), _prism(m_cube, (2 * h,) * 3, np.eye(3)), name="slider"),
            ["B0", "B1", "Bx", "By"], on_negative="ignore")
    mb.point("Bm", "slider", (-off, 0.0, s0))
    mb.prismatic(("O", "T", "P1"), ("B0", "B1", "Bx"), name="slider on shaft")
    for i, at in ((1, "Bx"), (2, "Bm")):
        mb.spring_damper(f"spring{i}", at, f"M{i}", c["stiffness"], c["damping"], c["free_length"])
    mech, q0 = mb.build(dof=4)
    w = c["omega0"]
    xyz = np.asarray(q0).reshape(-1, 3)
    qd0 = (w * np.stack([-xyz[:, 1], xyz[:, 0], np.zeros(len(xyz))], axis=1)).reshape(-1)
    return mech, q0, qd0


def _shift(r):
    """Parallel-axis term ``|r|^2 I - r r^T`` (per unit mass)."""
    r = np.asarray(r, dtype=float)
    return (r @ r) * np.eye(3) - np.outer(r, r)


def flyball_slider_height(mech, q):
    """The slider's centre height ``s`` from states ``q`` ``(..., 3F)``."""
    import jax.numpy as jnp

    q = jnp.asarray(q)
    b0, b1 = q[..., mech.free_slice("B0")], q[..., mech.free_slice("B1")]
    return 0.5 * (b0[..., 2] + b1[..., 2])


def angular_momentum_z(mech, q, qd):
    """Angular momentum about the z axis through the origin, ``sum_ij M_ij (x_i v_yj - y_i v_xj)`` over the
    particles (exact for the equivalent particle sets, whose momenta equal the bodies'); ground particles are at
    rest and on the axis here."""
    import jax.numpy as jnp

    m = scalar_mass_matrix(mech)[np.ix_(mech.free, mech.free)]
    r, v = jnp.asarray(q).reshape(-1, 3), jnp.asarray(qd).reshape(-1, 3)
    return jnp.sum(m * (r[:, None, 0] * v[None, :, 1] - r[:, None, 1] * v[None, :, 0]))


#: The crank problem's rigid data: lengths [m], masses [kg], moments about the pivot / crank-pin end [kg m^2],
#: crank speed [rad/s], time span [s], slider block length (ours: the block is a rod along the guide) [m].
CRANK = dict(l1=0.15, l2=0.30, m1=0.36, m2=0.151104, m3=0.075552, j1=0.002727, j2=0.0045339259, omega=150.0,
             t_end=0.1, block=0.05)


def slider_crank(omega: float = CRANK["omega"]):
    """The driven rigid slider-crank (planar); returns ``(mech, q0)`` at ``t = 0`` (crank along +x, the dead
    centre). The crank turns as ``omega * t`` (driver ``"crank"``); the slider's block is a rod along the guide
    (``B``–``B'``) with the block's mass at ``B``."""
    c = CRANK
    l1, l2 = c["l1"], c["l2"]
    mb = MechanismBuilder(planar=True, gravity=(0.0, 0.0))
    mb.ground("O", (0.0, 0.0))
    mb.ground("guide", (1.0, 0.0))
    mb.particle("A", (l1, 0.0))
    mb.particle("B", (l1 + l2, 0.0))
    mb.particle("B'", (l1 + l2 + c["block"], 0.0))
    mb.rod("crank", "O", "A", c["m1"], moment=c["j1"] - c["m1"] * (l1 / 2) ** 2)
    mb.rod("rod", "A", "B", c["m2"], moment=c["j2"] - c["m2"] * (l2 / 2) ** 2)
    mb.rod("slider", "B", "B'", c["m3"], com=(l1 + l2, 0.0), moment=0.0, on_negative="ignore")
    mb.prismatic(("O", "guide"), ("B", "B'"), name="slide")
    mb.drive_angle("crank", "crank", lambda t: omega * t)
    return mb.build(dof=0)


def slider_crank_exact(t, omega: float = CRANK["omega"]):
    """Closed-form rigid slider-crank (for checks): ``(phi1, phi2, x3)`` and the kinetic energy at time ``t``
    (crank angle ``omega t``, rod angle ``phi2`` from ``l1 sin phi1 + l2 sin phi2 = 0``, slider at
    ``x3 = l1 cos phi1 + l2 cos phi2``). JAX-traceable, so derivatives in ``t`` give velocities and power."""
    import jax.numpy as jnp

    c = CRANK
    l1, l2 = c["l1"], c["l2"]
    phi1 = omega * t
    phi2 = jnp.arcsin(-l1 * jnp.sin(phi1) / l2)
    x3 = l1 * jnp.cos(phi1) + l2 * jnp.cos(phi2)
    # velocities by the chain rule of the closed form
    w2 = -l1 * jnp.cos(phi1) * omega / (l2 * jnp.cos(phi2))
    v3 = -l1 * jnp.sin(phi1) * omega - l2 * jnp.sin(phi2) * w2
    # the rod about its crank-pin end A: T = 1/2 m v_A^2 + m v_A . (w x r_c) + 1/2 J_A w^2
    va = l1 * omega * jnp.stack([-jnp.sin(phi1), jnp.cos(phi1)])
    rc = 0.5 * l2 * jnp.stack([jnp.cos(phi2), jnp.sin(phi2)])
    w_x_rc = w2 * jnp.stack([-rc[1], rc[0]])
    t_rod = 0.5 * c["m2"] * va @ va + c["m2"] * va @ w_x_rc + 0.5 * c["j2"] * w2**2
    energy = 0.5 * c["j1"] * omega**2 + t_rod + 0.5 * c["m3"] * v3**2
    return phi1, phi2, x3, energy
