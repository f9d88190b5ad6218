"""Write ``notebooks/identify_arm.ipynb`` without outputs; ``make notebooks`` (``notebooks/run.py``) rebuilds and executes
it in place, saving its outputs."""

from pathlib import Path

import nbformat

cells = [
    nbformat.v4.new_markdown_cell(
        "# Identifying Krang's left arm\n\nPhysically consistent identification (log-Cholesky pseudo-inertias, "
        "positive rotor inertia and friction) of the 7-joint arm from the hardware runs, scored on the test run. "
        "For speed the training run is subsampled (every 3rd row) and one LM start is used; "
        "`python -m particlesim.reports.identify_arm` runs the full version."),
    nbformat.v4.new_code_cell(
        "import tempfile\nfrom pathlib import Path\n"
        "from particlesim.reports.identify_arm import identify_arm\n"
        "out = Path(tempfile.mkdtemp())\nres = identify_arm(out, step=3, starts=1, max_steps=1000, verbose=False)"),
    nbformat.v4.new_code_cell(
        "from IPython.display import Markdown\nMarkdown((out / 'identify_arm.md').read_text())"),
    nbformat.v4.new_markdown_cell("Measured vs predicted test torque per joint (black: measured, grey: URDF, red: ours)."),
    nbformat.v4.new_code_cell(
        "from IPython.display import Image\nImage(filename=str(out / 'identify_arm.png'))  # the report's figure"),
    nbformat.v4.new_code_cell(
        "print('pseudo-inertia min eigenvalues:', res['pseudo_inertia_min_eig'])\n"
        "print('check_inertia passed:', res['check_inertia_passed'])\n"
        "assert all(res['check_inertia_passed'])"),
]
nb = nbformat.v4.new_notebook(cells=cells)
nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
nbformat.write(nb, Path(__file__).with_name("identify_arm.ipynb"))
