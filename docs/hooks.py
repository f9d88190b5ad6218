"""mkdocs hooks: pages that live outside ``docs/`` join the site at their repository paths.

The notebooks (``notebooks/*.ipynb``, rendered by mkdocs-jupyter with their saved outputs) and
``benchmarks/README.md`` stay where they are in the repository and are read in place; no copy is kept under
``docs/``. Relative links are written for the repository (``docs/trees.md`` links ``../benchmarks/README.md``), so
links between ``.md`` pages are mapped from repository paths to site paths before mkdocs resolves them: a link
that works on a repository browser works on the site.
"""

from __future__ import annotations

import posixpath
import re
from pathlib import Path

from mkdocs.plugins import event_priority
from mkdocs.structure.files import File

ROOT = Path(__file__).resolve().parent.parent
#: Repository files outside docs/ that the site includes (glob patterns, relative to the repository root).
OUTSIDE = ("benchmarks/README.md", "notebooks/*.ipynb")
#: A relative link to a page, with an optional anchor: ``](path.md#anchor)``.
LINK = re.compile(r"\]\((?![a-z]+:)([^)\s#]+\.(?:md|ipynb))(#[^)\s]*)?\)")

_outside: set[str] = set()


@event_priority(100)  # before mkdocs-jupyter turns .ipynb files into pages
def on_files(files, config):
    for pattern in OUTSIDE:
        for path in sorted(ROOT.glob(pattern)):
            uri = path.relative_to(ROOT).as_posix()
            files.append(File(uri, src_dir=str(ROOT), dest_dir=config.site_dir,
                              use_directory_urls=config.use_directory_urls))
            _outside.add(uri)
    return files


def _repo_path(src_uri: str) -> str:
    return src_uri if src_uri in _outside else posixpath.join("docs", src_uri)


def on_page_markdown(markdown, page, config, files):
    here = page.file.src_uri
    if not here.endswith(".md"):
        return markdown
    base = posixpath.dirname(_repo_path(here))

    def to_site(m: re.Match) -> str:
        target = posixpath.normpath(posixpath.join(base, m.group(1)))
        if target.startswith("docs/"):
            uri = target[len("docs/"):]
        elif target in _outside:
            uri = target
        else:
            return m.group(0)  # left for mkdocs to judge
        return f"]({posixpath.relpath(uri, posixpath.dirname(here) or '.')}{m.group(2) or ''})"

    return LINK.sub(to_site, markdown)
