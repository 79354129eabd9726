"""What ``nirc-bench methods`` says of a registered method: its parameters with their
types, defaults and help, what it needs of a scene, its equal-time knob."""

from __future__ import annotations

import inspect
from typing import Any, Literal, get_args, get_origin

from pydantic import BaseModel

from renderers.methods import METHOD_SOURCES, get_method


def _type_name(annotation: Any) -> str:
    """'int', 'one of fixed, throughput' for a Literal, 'list[int] | None', ..."""
    if get_origin(annotation) is Literal:
        return "one of " + ", ".join(map(str, get_args(annotation)))
    text = getattr(annotation, "__name__", None) if get_origin(annotation) is None else None
    return (text or str(annotation)).replace("typing.", "")


def method_info(name: str) -> dict[str, Any]:
    """The registry's entry for ``name`` as plain data (MethodError if unknown)."""
    method = get_method(name)
    defaults = method.params().model_dump(mode="json")
    params = []
    for field_name, field in method.params.model_fields.items():
        nested = isinstance(field.annotation, type) and issubclass(field.annotation, BaseModel)
        params.append({
            "name": field_name,
            "type": "object (see --json for its fields)" if nested
            else _type_name(field.annotation),
            "default": defaults.get(field_name),
            "help": field.description or ""})
    needs = inspect.getdoc(method.requires) or ""
    return {"name": name, "label": method.label or name, "description": method.description,
            "version": method.version, "source": METHOD_SOURCES.get(name, ""),
            "needs": needs.split("\n\n")[0].replace("\n", " "),
            "knob": method.knob.name if method.knob else None,
            "unbiased": method.unbiased, "params": params}
