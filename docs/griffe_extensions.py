"""griffe extensions for the API reference (mkdocstrings reads the package through griffe).

* ``UnpackedConstants``: module constants bound by unpacking (``A, B = 1.2, 0.5``). griffe's static analysis
  makes attributes of plain assignments only, so such a name in ``__all__`` would be missing from its page; each
  becomes a module attribute with its own value.
* ``SphinxRoles``: the docstrings cross-reference with Sphinx roles (``:func:`~.forces.potential_energy```), which
  Markdown would show as literal text. Each becomes a link to the object's entry, resolved as Sphinx does
  (the enclosing class, module and packages, then absolute; a leading ``~`` shows the last name only). A target
  without an entry (a private helper, another package's object) is shown as code.
"""

from __future__ import annotations

import ast
import html
import re

import griffe

ROLE = re.compile(r":(?:func|class|meth|attr|data|mod|exc|obj|const):`(~?)(\.?)([\w.]+)`")


class UnpackedConstants(griffe.Extension):
    def on_attribute_node(self, *, node, agent, **kwargs) -> None:
        mod = agent.current
        if not (mod.kind is griffe.Kind.MODULE and isinstance(node, ast.Assign) and len(node.targets) == 1):
            return
        targets, values = node.targets[0], node.value
        if not (isinstance(targets, ast.Tuple) and isinstance(values, ast.Tuple)
                and len(targets.elts) == len(values.elts)):
            return
        for target, value in zip(targets.elts, values.elts):
            if isinstance(target, ast.Name) and target.id not in mod.members:
                attr = griffe.Attribute(target.id, lineno=node.lineno, endlineno=node.end_lineno,
                                        value=griffe.safe_get_expression(value, parent=mod, parse_strings=False))
                attr.labels.add("module-attribute")
                mod.set_member(target.id, attr)


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
            shown = html.escape(name.rsplit(".", 1)[-1] if short else name)
            path = resolve(name, obj)
            if path is None:
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
