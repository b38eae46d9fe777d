"""A griffe extension that gives ``equinox.Module`` classes their generated ``__init__``.

Equinox turns every ``eqx.Module`` subclass into a dataclass through its metaclass, so its
constructor takes the annotated fields. Griffe reads source statically and only recognises
``@dataclass``: without this extension an ``eqx.Module`` has no signature in the API pages and
the ``Parameters`` section of its docstring (which documents the fields, as numpydoc asks for a
constructor) is reported as naming parameters that do not exist.

The rules follow ``dataclasses`` as equinox applies them: fields are the annotated class
attributes of the class and of its ``eqx.Module`` bases (bases first); a class attribute
annotated ``ClassVar``, a property or an ``eqx.field(init=False)`` is no parameter; a class
that defines ``__init__`` itself, or inherits one from a module base, keeps it.
"""

from __future__ import annotations

from typing import Any

import griffe

_MODULE_PATHS = frozenset({"equinox.Module", "equinox._module.Module"})
_FIELD_PATHS = frozenset({"equinox.field", "equinox._module.field", "dataclasses.field"})


def _resolved_bases(class_: griffe.Class) -> list[griffe.Class]:
    bases = []
    for base in class_.resolved_bases:
        if isinstance(base, griffe.Class):
            bases.append(base)
    return bases


def _is_module(class_: griffe.Class) -> bool:
    for base in class_.bases:
        if isinstance(base, griffe.Expr) and base.canonical_path in _MODULE_PATHS:
            return True
    return any(_is_module(base) for base in _resolved_bases(class_))


def _defines_init(class_: griffe.Class) -> bool:
    if "__init__" in class_.members:
        return True
    return any(_defines_init(base) for base in _resolved_bases(class_) if _is_module(base))


def _field_arguments(attribute: griffe.Attribute) -> dict[str, Any]:
    value = attribute.value
    if isinstance(value, griffe.ExprCall) and value.canonical_path in _FIELD_PATHS:
        return {
            argument.name: argument.value
            for argument in value.arguments
            if isinstance(argument, griffe.ExprKeyword)
        }
    return {}


def _own_fields(class_: griffe.Class) -> list[griffe.Parameter]:
    parameters = []
    for member in class_.members.values():
        if not isinstance(member, griffe.Attribute) or member.annotation is None:
            continue
        if not member.runtime:  # declared under `if TYPE_CHECKING:`: a subclass's field
            continue
        if "property" in member.labels or (
            "class-attribute" in member.labels and "instance-attribute" not in member.labels
        ):
            continue
        arguments = _field_arguments(member)
        if str(arguments.get("init", "True")) == "False":
            continue
        if "default_factory" in arguments:
            default: str | griffe.Expr | None = griffe.ExprCall(
                function=arguments["default_factory"], arguments=[]
            )
        elif arguments:
            default = arguments.get("default")
        else:
            default = member.value
        parameters.append(
            griffe.Parameter(
                member.name,
                annotation=member.annotation,
                kind=griffe.ParameterKind.positional_or_keyword,
                default=default,
                docstring=member.docstring,
            )
        )
    return parameters


def _fields(class_: griffe.Class) -> list[griffe.Parameter]:
    inherited = [
        field for base in _resolved_bases(class_) if _is_module(base) for field in _fields(base)
    ]
    by_name = {field.name: field for field in [*inherited, *_own_fields(class_)]}
    return list(by_name.values())


def _add_init(class_: griffe.Class) -> None:
    self_parameter = griffe.Parameter(
        "self", annotation=None, kind=griffe.ParameterKind.positional_or_keyword
    )
    init = griffe.Function(
        "__init__",
        lineno=0,
        endlineno=0,
        parent=class_,
        parameters=griffe.Parameters(self_parameter, *_fields(class_)),
        returns="None",
    )
    class_.set_member("__init__", init)


def _classes(obj: griffe.Module | griffe.Class, seen: set[str]) -> list[griffe.Class]:
    if obj.path in seen:
        return []
    seen.add(obj.path)
    found = [obj] if isinstance(obj, griffe.Class) else []
    for member in obj.members.values():
        if not member.is_alias and isinstance(member, griffe.Module | griffe.Class):
            found.extend(_classes(member, seen))
    return found


class EquinoxModules(griffe.Extension):
    """Create the ``__init__`` that equinox generates for each ``eqx.Module`` subclass."""

    def on_package(self, *, pkg: griffe.Module, **kwargs: Any) -> None:
        """Add the generated constructors once the whole package is loaded.

        Which classes need one is decided before any is added, so that a generated
        constructor is never taken for one a base class wrote.
        """
        generated = [
            class_
            for class_ in _classes(pkg, set())
            if _is_module(class_) and not _defines_init(class_)
        ]
        for class_ in generated:
            _add_init(class_)
