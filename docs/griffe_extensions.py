"""griffe extensions for the API reference (mkdocstrings reads the package through griffe).

* ``SphinxRoles``: the docstrings cross-reference with Sphinx roles (``:func:`~.forces.potential_energy```), which
  Markdown would show as literal text. Each becomes a link to the object's entry, resolved as Sphinx does
  (the enclosing class, module and packages, then absolute; a leading ``~`` shows the last name only). A target
  without an entry (a private helper, another package's object) is shown as code; a relative or bare name that
  resolves to nothing is a stale reference and is logged as a warning (which fails the strict build).
"""

from __future__ import annotations

import re

import griffe

ROLE = re.compile(r":(?:func|class|meth|attr|data|mod|exc|obj|const):`(~?)(\.?)([\w.]+)`")


class SphinxRoles(griffe.Extension):
    def on_package(self, *, pkg, loader, **kwargs) -> None:
        objects = loader.modules_collection

        def canonical(path: str) -> str | None:
            try:
                return objects[path].canonical_path
            except (KeyError, ValueError, griffe.AliasResolutionError, griffe.CyclicAliasError):
                return None

        def resolve(name: str, obj) -> str | None:
            scopes = []
            while obj is not None:  # the object itself (a class's methods), its class, module, packages
                scopes.append(obj.path)
                obj = obj.parent
            for candidate in [f"{scope}.{name}" for scope in scopes] + [name]:
                if (path := canonical(candidate)) is not None:
                    return path
            return None

        def link(match: re.Match, obj) -> str:
            short, name = match.group(1), match.group(3)
            shown = name.rsplit(".", 1)[-1] if short else name  # [\w.]+: nothing to escape
            path = resolve(name, obj)
            if path is None:
                if match.group(2) or "." not in name:
                    griffe.logger.warning(f"{obj.path}: {match.group(0)} names nothing")
                return f"<code>{shown}</code>"
            return f'<autoref identifier="{path}" optional><code>{shown}</code></autoref>'

        def visit(obj) -> None:
            if obj.is_alias:
                return
            if obj.docstring is not None:
                obj.docstring.value = ROLE.sub(lambda m: link(m, obj), obj.docstring.value)
            for member in obj.members.values():
                visit(member)

        visit(pkg)
