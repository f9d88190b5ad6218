"""The documentation site (``mkdocs.yml``, ``docs/api/``) documents the public API and leaves no page out.

* Every name in a public module's ``__all__`` has an entry in the API reference. A public module is one under
  ``particlesim/`` with no path component starting with ``_``. A name is documented by an explicit
  ``::: module.name`` block, or by its module's ``::: module`` block: with ``filters: public`` mkdocstrings renders
  exactly the names in ``__all__``, except submodules (``show_submodules: false``), which need blocks of their own.
  A block's own ``members:`` option narrows it to the names listed.
* The nav lists every page under ``docs/`` and every notebook, and names no file that does not exist.

Imports the modules and reads text only: no mkdocs build (``make docs`` builds the site with ``--strict``).
"""

import importlib
import pkgutil
import re
import types
from pathlib import Path

import particlesim

ROOT = Path(__file__).resolve().parent.parent
DOCS = ROOT / "docs"
API = DOCS / "api"
MKDOCS = ROOT / "mkdocs.yml"

#: ``::: identifier`` and the indented option lines under it.
BLOCK = re.compile(r"^::: *([\w.]+) *\n((?:[ \t]+\S.*\n?)*)", re.M)


def public_modules() -> list[str]:
    names = ["particlesim"] + [m.name for m in pkgutil.walk_packages(particlesim.__path__, "particlesim.")]
    return [n for n in names if not any(part.startswith("_") for part in n.split("."))]


def blocks() -> dict[str, list[str] | None]:
    """Identifier of every ``:::`` block in docs/api/ -> the members it is narrowed to (None: all it renders)."""
    found: dict[str, list[str] | None] = {}
    for page in sorted(API.glob("**/*.md")):
        for ident, options in BLOCK.findall(page.read_text()):
            members = None
            if m := re.search(r"^\s*members:\s*(.*)$", options, re.M):
                value = m.group(1).strip()
                if value.lower() == "false" or value == "[]":
                    members = []
                elif value.startswith("["):
                    members = [v.strip().strip("'\"") for v in value.strip("[]").split(",") if v.strip()]
                elif not value:  # a YAML list on the following lines
                    rest = options[m.end():]
                    members = re.findall(r"^\s*-\s*['\"]?([\w]+)", rest, re.M)
            found[ident] = members
    return found


def nav_entries() -> list[str]:
    text = MKDOCS.read_text()
    m = re.search(r"^nav:\n((?:[ \t]+.*\n?|\n)*)", text, re.M)
    assert m, "mkdocs.yml has no nav"
    return re.findall(r"([\w./-]+\.(?:md|ipynb))\s*$", m.group(1), re.M)


def test_config_renders_what_this_test_assumes():
    """The documented-name rule below holds for these handler options only."""
    text = MKDOCS.read_text()
    assert re.search(r"^\s+filters:\s*public\s*$", text, re.M), "mkdocs.yml: mkdocstrings must use filters: public"
    assert re.search(r"^\s+show_submodules:\s*false\s*$", text, re.M), \
        "mkdocs.yml: mkdocstrings must use show_submodules: false"
    assert re.search(r"^\s+members_order:\s*\[?\s*__all__", text, re.M), \
        "mkdocs.yml: mkdocstrings must order members by __all__"


def test_every_public_name_has_an_api_entry():
    documented = blocks()
    modules = public_modules()
    missing = []
    for name in modules:
        module = importlib.import_module(name)
        if name not in documented:
            missing.append(f"{name} (no '::: {name}' block)")
        members = documented.get(name)
        for export in getattr(module, "__all__", ()):
            if f"{name}.{export}" in documented:
                continue
            if isinstance(getattr(module, export, None), types.ModuleType):
                missing.append(f"{name}.{export} (a submodule: needs its own block)")
            elif name not in documented or (members is not None and export not in members):
                missing.append(f"{name}.{export}")
    assert not missing, f"names in __all__ without an entry in docs/api/: {missing}"


def test_nav_lists_every_page_and_notebook():
    nav = nav_entries()
    pages = sorted(p.relative_to(DOCS).as_posix() for p in DOCS.glob("**/*.md"))
    notebooks = sorted(p.relative_to(ROOT).as_posix() for p in (ROOT / "notebooks").glob("*.ipynb"))
    orphans = [p for p in pages + notebooks if p not in nav]
    assert not orphans, f"pages missing from the nav in mkdocs.yml: {orphans}"
    dangling = [p for p in nav if not (DOCS / p).exists() and not (ROOT / p).exists()]
    assert not dangling, f"nav entries in mkdocs.yml with no file: {dangling}"
