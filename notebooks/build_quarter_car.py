"""Write ``notebooks/quarter_car.ipynb`` without outputs; ``make notebooks`` (``notebooks/run.py``) rebuilds and executes
it in place, saving its outputs."""

from pathlib import Path

import nbformat
from nbformat.v4 import new_code_cell, new_markdown_cell, new_notebook

CELLS = [
    new_markdown_cell(
        "# The quarter car in particle coordinates\n\n"
        "The double-wishbone quarter car of Attia's paper (§3): chassis on a vertical slider, lower and upper "
        "A-arms, knuckle, wheel, a steering rod, a spring-damper between chassis and lower arm and a vertical tyre. "
        "Every body is a set of equivalent particles; joints are shared particles; the loops are closed by a cut "
        "joint and a massless link. The assumptions that fill the paper's gaps are listed in "
        "`particlesim/scenes/quarter_car.py` (A1–A6)."
    ),
    new_code_cell(
        "import warnings\n\n"
        "import jax\n"
        "import jax.numpy as jnp\n"
        "import matplotlib.pyplot as plt\n"
        "import numpy as np\n\n"
        "import particlesim  # float64\n"
        "from particlesim.mechanism import residuals, simulate_mechanism\n"
        "from particlesim.particles import balanced_primaries, equivalent_particles\n"
        "from particlesim.scenes import quarter_car as qc\n\n"
        "np.set_printoptions(precision=4, suppress=True, linewidth=120)"
    ),
    new_markdown_cell(
        "## How the particle layout was chosen\n\n"
        "A body's particles must (i) sit where its joints are, so neighbours can share them, and (ii) reproduce "
        "its mass, centre of mass and inertia (Attia eqs. (1)–(8)). With the primaries at the joints the masses "
        "follow uniquely, and may come out negative when the joints are close together compared with the body's "
        "radii of gyration. The dynamics stay exact (the kinetic energy of every rigid motion is right); only the "
        "physical interpretation is lost. The *balanced* layout shows what a free choice of placement gives."
    ),
    new_code_cell(
        "bodies = qc.bodies()\n"
        "joint = qc.joint_primaries()\n"
        "kinds = {'chassis': 'spatial', 'lower_arm': 'planar', 'upper_arm': 'planar', 'knuckle': 'spatial',\n"
        "         'wheel': 'spatial'}\n"
        "with warnings.catch_warnings():\n"
        "    warnings.simplefilter('ignore')\n"
        "    for name, body in bodies.items():\n"
        "        at_joints = equivalent_particles(body, joint[name], name=name)\n"
        "        balanced = equivalent_particles(body, balanced_primaries(body, kinds[name]), name=name)\n"
        "        print(f'{name:10s} {at_joints.kind:8s} joints: {np.asarray(at_joints.masses)}')\n"
        "        print(f'{\"\":10s} {\"\":8s} balanced: {np.asarray(balanced.masses)}')"
    ),
    new_markdown_cell("## The mechanism\n\nThirteen free particles, their rigid distances, the joints, and 3 degrees "
                      "of freedom (chassis heave, suspension travel, wheel spin)."),
    new_code_cell(
        "mech, q0 = qc.quarter_car()\n"
        "print('free particles:', mech.n_free, ' constraints:', residuals(mech, q0, 0 * q0)[0].shape[0])\n"
        "for b, name in enumerate(mech.topo.body_names):\n"
        "    print(f'{name:10s} {mech.topo.body_kind(b):8s}', [mech.particle_names[i] for i in mech.topo.body_particles[b]])\n"
        "print([lab for lab in mech.topo.row_labels() if not lab.startswith('body')])"
    ),
    new_markdown_cell("## Free response from rest\n\nReleased in the assembly configuration with the spring and tyre "
                      "unloaded, it falls and settles. The constraints are projected after every step, so they "
                      "hold to round-off."),
    new_code_cell(
        "ts = np.linspace(0.0, 2.0, 201)\n"
        "run = lambda m, q: simulate_mechanism(m, q, jnp.zeros_like(q), 0.0, 2.0, solver='dopri5', rtol=1e-8,\n"
        "                                      atol=1e-10, saveat_ts=ts)  # compiled once, reused for new values\n"
        "sol = run(mech, jnp.asarray(q0))\n"
        "k = mech.point_index('centre')\n"
        "z = np.asarray(jax.vmap(lambda q: mech.point_positions(mech.all_positions(q))[k, 2])(sol.q))\n"
        "res = np.asarray(jax.vmap(lambda q, qd: jnp.abs(residuals(mech, q, qd)[0]).max())(sol.q, sol.qd))\n"
        "fig, (a1, a2) = plt.subplots(1, 2, figsize=(11, 3.5))\n"
        "a1.plot(ts, z - z[0]); a1.set_xlabel('t [s]'); a1.set_ylabel('chassis displacement [m]')\n"
        "a2.semilogy(ts, np.maximum(res, 1e-18)); a2.set_xlabel('t [s]'); a2.set_ylabel('max |constraint|')\n"
        "plt.tight_layout(); plt.show()\n"
        "print('steps', int(sol.steps), ' final displacement', z[-1] - z[0], ' worst residual', res.max())"
    ),
    new_markdown_cell("## Sensitivity to the spring\n\nParameters are array leaves: a stiffer spring is the same "
                      "compiled program with another value."),
    new_code_cell(
        "import equinox as eqx\n"
        "for k_spring in (3e4, 5.11e4, 8e4):\n"
        "    m2 = mech.with_params(spring={'suspension': {'stiffness': k_spring}})\n"
        "    s2 = run(m2, jnp.asarray(q0))\n"
        "    z2 = np.asarray(jax.vmap(lambda q: m2.point_positions(m2.all_positions(q))[k, 2])(s2.q))\n"
        "    plt.plot(ts, z2 - z2[0], label=f'k = {k_spring:.3g} N/m')\n"
        "plt.xlabel('t [s]'); plt.ylabel('chassis displacement [m]'); plt.legend(); plt.show()"
    ),
]


def main() -> None:
    nb = new_notebook(cells=CELLS)
    nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
    path = Path(__file__).resolve().parent / "quarter_car.ipynb"
    nbformat.write(nb, path)
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
