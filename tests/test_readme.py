"""The README's quickstarts run as written, and the documentation keeps its promises about itself.

Each quickstart is the ```python block after a ``<!-- quickstart: NAME -->`` comment in ``README.md``; it is
executed in a fresh namespace with the repository root as working directory, and its results are then checked
against something the block itself does not compute:

* robot: the rollout finished, and the reverse-mode gradient of the block's loss equals a central difference of
  the same loss (the same compiled rollout at payload ±h);
* mechanism: executed and checked once, by ``tests/mechanism/test_planar.py`` (the same marked block): against a
  body-coordinate solution, the loop-closure residuals of every saved state at round-off, and the damped four-bar's
  total energy never rising.

Also: the README stays a front door (at most 8 KB), and every ``docs/*.md`` page says what regenerates its figures
(a line starting ``Regenerate:``).
"""

import os
import re
from pathlib import Path

import numpy as np
import pytest

import particlesim  # noqa: F401  (enables float64)

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"
DOCS = ROOT / "docs"

README_MAX_BYTES = 8192
#: Lines of code a quickstart may have (blank lines and comment-only lines not counted).
QUICKSTART_MAX_LINES = 15
#: Reverse-mode gradient against a central difference of the same loss, relative. The discrete adjoint holds the
#: step sizes the controller chose, the difference sees them move: at rtol 1e-10 they agree to ~1e-7-1e-9.
GRAD_RTOL = 1e-5
#: Payload step of the central difference [kg]: truncation ~h^2 |f'''|, well below GRAD_RTOL.
FD_STEP = 1e-4


def quickstart(name: str) -> str:
    text = README.read_text()
    m = re.search(rf"<!-- quickstart: {name} -->\s*(?:<!--.*?-->\s*)*```python\n(.*?)```", text, re.S)
    assert m, f"README.md has no ```python block marked <!-- quickstart: {name} -->"
    return m.group(1)


def run_block(name: str) -> dict:
    block = quickstart(name)
    code = [ln for ln in block.splitlines() if ln.strip() and not ln.strip().startswith("#")]
    assert len(code) <= QUICKSTART_MAX_LINES, f"the {name} quickstart has {len(code)} lines of code"
    env: dict = {"__name__": f"readme_quickstart_{name}"}
    cwd = os.getcwd()
    os.chdir(ROOT)
    try:
        exec(compile(block, f"README.md quickstart: {name}", "exec"), env)  # noqa: S102 (our own README)
    finally:
        os.chdir(cwd)
    return env


def test_readme_is_a_front_door():
    size = README.stat().st_size
    assert size <= README_MAX_BYTES, f"README.md is {size} bytes, more than {README_MAX_BYTES}"


def test_every_docs_page_says_what_regenerates_its_figures():
    pages = sorted(DOCS.glob("*.md"))
    assert pages, "docs/ has no pages"
    missing = [p.name for p in pages if not any(ln.startswith("Regenerate:") for ln in p.read_text().splitlines())]
    assert not missing, f"docs pages without a 'Regenerate:' line: {missing}"


def test_robot_quickstart_gradient_equals_central_difference():
    env = run_block("robot")
    sol, loss, dloss = env["sol"], env["loss"], float(env["dloss"])
    assert bool(sol.ok)
    assert np.all(np.isfinite(np.asarray(sol.q))) and np.any(np.asarray(sol.q[-1]) != 0.0)  # it moved
    assert np.isfinite(dloss) and dloss != 0.0
    central = (float(loss(FD_STEP)) - float(loss(-FD_STEP))) / (2 * FD_STEP)
    assert dloss == pytest.approx(central, rel=GRAD_RTOL)

def test_mechanism_quickstart_is_the_block_the_planar_tests_run():
    """The mechanism quickstart is executed (once) and checked by ``tests/mechanism/test_planar.py``: against a
    body-coordinate solution, its loop closure and its energy. Here only that it is that block and short enough."""
    text = README.read_text()
    assert re.search(r"<!-- quickstart: mechanism -->\s*<!-- planar-four-bar", text), \
        "the mechanism quickstart must carry the planar-four-bar marker that tests/mechanism/test_planar.py runs"
    code = [ln for ln in quickstart("mechanism").splitlines() if ln.strip() and not ln.strip().startswith("#")]
    assert len(code) <= QUICKSTART_MAX_LINES
