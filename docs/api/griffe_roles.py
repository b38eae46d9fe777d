"""A griffe extension that shows Sphinx cross-reference roles as inline code.

Some docstrings name other objects the Sphinx way, ``:func:`name``` or ``:meth:`~a.b.c```.
MkDocs renders those literally, colons and all. This extension rewrites each role to inline
code of the name (``name``; the last component when Sphinx's ``~`` asks for the short form),
which reads the same and cannot break the strict build the way an unresolved link would.
"""

from __future__ import annotations

import re
from typing import Any

import griffe

_ROLE = re.compile(r":(?:py:)?(?:func|meth|class|attr|data|mod|obj|exc|const):`(~?)([^`]+)`")


def _as_code(match: re.Match[str]) -> str:
    short, name = match.groups()
    return f"``{name.rsplit('.', 1)[-1] if short else name}``"


def _objects(obj: griffe.Object, seen: set[str]) -> list[griffe.Object]:
    if obj.path in seen:
        return []
    seen.add(obj.path)
    found = [obj]
    for member in obj.members.values():
        if not member.is_alias and isinstance(member, griffe.Object):
            found.extend(_objects(member, seen))
    return found


class SphinxRoles(griffe.Extension):
    """Rewrite ``:role:`name``` in every docstring of the package to inline code."""

    def on_package(self, *, pkg: griffe.Module, **kwargs: Any) -> None:
        """Rewrite the docstrings once the whole package is loaded."""
        for obj in _objects(pkg, set()):
            if obj.docstring is not None:
                obj.docstring.value = _ROLE.sub(_as_code, obj.docstring.value)
