"""Write ``notebooks/krang.ipynb`` without outputs; ``make notebooks`` (``notebooks/run.py``) rebuilds and executes
it in place, saving its outputs."""

from pathlib import Path

import nbformat
from nbformat.v4 import new_code_cell, new_markdown_cell, new_notebook

CELLS = [
    new_markdown_cell(
        "# Krang on fixed wheels: equations of motion and a falling-arms simulation\n\n"
        "Golem Krang with its left wheel welded to the world (the wheel joint is the base pitch). The URDF is the one "
        "that generated the lab's DART data; gravity is (0, −9.81, 0) in the world frame. We build the tree model, "
        "look at the terms of $A(q)\\,\\ddot q + C(q,\\dot q)\\,\\dot q + Q(q) + \\Gamma_f(\\dot q) = \\tau$ "
        "(Zafar, *Equations of Motion of Krang on Fixed Wheels*), then let both arms fall under gravity with viscous "
        "and smoothed Coulomb joint friction while a PD law holds the base, waist, torso and Kinect."
    ),
    new_code_cell(
        "import jax\n"
        "import jax.numpy as jnp\n"
        "import matplotlib.pyplot as plt\n"
        "import numpy as np\n\n"
        "import particlesim  # float64\n"
        "from particlesim.data import data_dir\n"
        "from particlesim.simulate import simulate\n"
        "from particlesim.io import load_urdf\n"
        "from particlesim.tree import coriolis_times_qdot, forward_dynamics, gravity_torques, mass_matrix\n\n"
        "np.set_printoptions(precision=3, suppress=True, linewidth=140)\n"
        "urdf = data_dir() / 'krang' / 'urdf' / 'krang_fixed_wheel_2018-04.urdf'\n"
        "model = load_urdf(urdf, gravity=(0.0, -9.81, 0.0))\n"
        "print(model.nq, 'joints:', ', '.join(model.joint_names))"
    ),
    new_markdown_cell("## A, C q̇ and Q at a pose\n\nA pose with the arms partly raised and some joint velocity."),
    new_code_cell(
        "names = list(model.joint_names)\n"
        "q = np.zeros(model.nq)\n"
        "q[names.index('JWaist')] = 1.2          # waist bent (the URDF range is 0..2.7 rad)\n"
        "for side, sign in (('L', 1.0), ('R', -1.0)):\n"
        "    q[names.index(side + 'J2')] = sign * 0.8\n"
        "    q[names.index(side + 'J4')] = sign * 1.0\n"
        "qd = 0.3 * np.ones(model.nq)\n"
        "A = mass_matrix(model, q)\n"
        "Cqd = coriolis_times_qdot(model, q, qd)\n"
        "Q = gravity_torques(model, q)\n"
        "print('eigenvalues of A:', np.linalg.eigvalsh(A))\n"
        "print('C(q, qd) qd     :', np.asarray(Cqd))\n"
        "print('Q(q)            :', np.asarray(Q))\n"
        "fig, ax = plt.subplots(figsize=(5.5, 4.5))\n"
        "im = ax.imshow(np.log10(np.abs(np.asarray(A)) + 1e-12), cmap='viridis')\n"
        "ax.set_xticks(range(model.nq), names, rotation=90, fontsize=7)\n"
        "ax.set_yticks(range(model.nq), names, fontsize=7)\n"
        "fig.colorbar(im, label='log10 |A_ij|  [kg m²]')\n"
        "ax.set_title('Mass matrix A(q): the two arms decouple')\n"
        "fig.tight_layout()"
    ),
    new_markdown_cell(
        "## Arms falling under gravity, with friction\n\n"
        "Friction per joint: viscous $F_v\\,\\dot q$ and Coulomb $F_c\\,\\tanh(\\dot q/\\varepsilon)$ "
        "(smooth, so the vector field is differentiable). The base pitch, waist, torso and Kinect joints are held "
        "by a PD law with gravity compensation, evaluated inside every solver stage; the 14 arm joints are free. Tsit5, adaptive steps (the smoothed Coulomb term, of slope $F_c/\\varepsilon$, is what sets the step size on the light wrist joints; an implicit solver such as `kvaerno5` would take fewer, dearer steps)."
    ),
    new_code_cell(
        "FV, FC, EPS = 1.5, 2.0, 0.05   # N m s/rad, N m, rad/s\n"
        "fmodel = model.with_params(viscous=jnp.full(model.nq, FV), coulomb=jnp.full(model.nq, FC))\n"
        "held = jnp.asarray([n in ('JLWheel', 'JWaist', 'JTorso', 'JKinect') for n in names], dtype=float)\n"
        "KP, KD = 4000.0, 400.0\n"
        "q0 = jnp.asarray(q)\n\n"
        "def dynamics(p, q, qd, tau):\n"
        "    return forward_dynamics(p, q, qd, tau, smooth_friction=EPS)\n\n"
        "def hold_body(t, q, qd, p):\n"
        "    # PD + gravity compensation on the held joints; zero torque on the arms.\n"
        "    return held * (gravity_torques(p, q) - KP * (q - q0) - KD * qd)\n\n"
        "ts = jnp.linspace(0.0, 2.0, 201)\n"
        "sol = simulate(dynamics, fmodel, q0, jnp.zeros(model.nq), 0.0, 2.0, control=hold_body, solver='tsit5',\n"
        "               rtol=1e-8, atol=1e-10, saveat_ts=ts)\n"
        "print(f'ok={bool(sol.ok)}  accepted steps={int(sol.steps)}  rejected={int(sol.rejected)}')\n"
        "print('held joints drift (max |q - q0|):', float(jnp.max(jnp.abs((sol.q - q0) * held))))"
    ),
    new_code_cell(
        "fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)\n"
        "for ax, side in zip(axes, ('L', 'R')):\n"
        "    for k, n in enumerate(names):\n"
        "        if n.startswith(side + 'J'):\n"
        "            ax.plot(ts, sol.q[:, k], label=n)\n"
        "    ax.set_xlabel('t [s]')\n"
        "    ax.set_title(('Left' if side == 'L' else 'Right') + ' arm')\n"
        "    ax.legend(fontsize=7, ncol=2)\n"
        "axes[0].set_ylabel('joint angle [rad]')\n"
        "fig.tight_layout()"
    ),
    new_markdown_cell(
        "Friction dissipates energy: without it (and without the PD hold) the same tree conserves $T+V$ to "
        "~1e-12 relative over 5 s at tight tolerances (see `tests/twins/test_krang_twin.py`), and matches MuJoCo C's "
        "RK4 twin within RK4's own error."
    ),
]


def main() -> None:
    nb = new_notebook(cells=CELLS)
    nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
    nbformat.validate(nb)
    out = Path(__file__).resolve().parent / "krang.ipynb"
    nbformat.write(nb, out)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
