"""Declared component properties: type, unit, range or choices, default, documentation.

A property is validated every time it is set (from code, from YAML or from
another process) and a bad value is refused with an error that names the
property, what it expects and what it got.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from framework.errors import FwError


class PropertyError(FwError):
    """A property value was refused, or the property does not exist."""


_TYPES: dict[str, type] = {
    "float": float,
    "int": int,
    "bool": bool,
    "str": str,
    "list": list,
    "dict": dict,
}


@dataclass(frozen=True)
class Property:
    """The declaration of one property (the value lives in the component)."""

    type: type
    default: Any
    unit: str = ""
    doc: str = ""
    min: float | None = None
    max: float | None = None
    choices: tuple[Any, ...] | None = None
    name: str = ""
    required: bool = False
    file: str = ""
    """The kind of YAML file the value names (`fw validate --kinds`), "" if none: a
    topology's check then checks that file too."""

    def missing(self, value: Any) -> bool:
        """True if a required property still holds nothing (empty or None)."""
        return self.required and (value is None or value in ("", [], {}))

    def validate(self, value: Any, owner: str = "") -> Any:
        """The value, converted where lossless (int -> float), or `PropertyError`."""
        label = f"property {owner + '.' if owner else ''}{self.name}"
        kind = self.type
        if kind is float and isinstance(value, int) and not isinstance(value, bool):
            value = float(value)
        if not isinstance(value, kind) or (isinstance(value, bool) and kind is not bool):
            raise PropertyError(
                f"{label} expects {kind.__name__}, got {type(value).__name__} {value!r}"
            )
        if kind is float and not math.isfinite(value):
            raise PropertyError(f"{label} must be a finite number, got {value!r}")
        if self.min is not None and value < self.min:
            raise PropertyError(f"{label} must be >= {self.min}{self._unit}, got {value!r}")
        if self.max is not None and value > self.max:
            raise PropertyError(f"{label} must be <= {self.max}{self._unit}, got {value!r}")
        if self.choices is not None and value not in self.choices:
            raise PropertyError(f"{label} must be one of {list(self.choices)}, got {value!r}")
        return value

    def __set_name__(self, owner: type, name: str) -> None:
        object.__setattr__(self, "name", name)

    def __get__(self, obj: Any, owner: type | None = None) -> Any:
        if obj is None:
            return self
        return obj._values[self.name]

    def __set__(self, obj: Any, value: Any) -> None:
        obj.set_property(self.name, value)

    @property
    def _unit(self) -> str:
        return f" {self.unit}" if self.unit else ""

    def describe(self, value: Any) -> dict[str, Any]:
        """Plain data for introspection."""
        return {
            "name": self.name,
            "type": self.type.__name__,
            "value": value,
            "default": self.default,
            "unit": self.unit,
            "doc": self.doc,
            "min": self.min,
            "max": self.max,
            "choices": list(self.choices) if self.choices else None,
            "required": self.required,
            "file": self.file or None,
        }


def prop(
    kind: type | str,
    default: Any,
    *,
    unit: str = "",
    doc: str = "",
    min: float | None = None,
    max: float | None = None,
    choices: list[Any] | tuple[Any, ...] | None = None,
    required: bool = False,
    file: str = "",
) -> Property:
    """Declare a property on a Component class: `rate = prop(float, 100.0, unit="Hz")`.
    `required`: configure fails, naming the property, while it is empty. `file`: the
    value names a YAML file of this kind (`procedure`, `sensors`...), which checking
    the topology checks too."""
    kind = _TYPES[kind] if isinstance(kind, str) else kind
    declared = Property(
        kind,
        default,
        unit,
        doc,
        min,
        max,
        tuple(choices) if choices is not None else None,
        required=required,
        file=file,
    )
    declared.validate(default, "(default)")
    return declared


def load_property_file(path: Any, declared: dict[str, Property], owner: str = "") -> dict[str, Any]:
    """Read `name: value` pairs from a YAML file and validate each against `declared`.

    Every error names file:line:column and the property, like every other fw file;
    nothing is applied unless the whole file is valid.
    """
    from framework.errors import Finding, FindingsError
    from framework.yamlio import load_yaml

    doc = load_yaml(path)
    if doc.data is None:
        return {}
    if not isinstance(doc.data, dict):
        raise FindingsError(
            [
                Finding(
                    "error",
                    "properties",
                    "a property file is a mapping of name: value",
                    doc.location(()),
                )
            ]
        )
    values, findings = {}, []
    for name, value in doc.data.items():
        where = doc.location((name,))
        declaration = declared.get(name)
        if declaration is None:
            known = ", ".join(sorted(declared)) or "none"
            findings.append(
                Finding(
                    "error",
                    "unknown-property",
                    f"{owner or 'the component'} has no property {name!r}",
                    where,
                    f"known: {known}",
                )
            )
            continue
        try:
            values[name] = declaration.validate(value, owner)
        except PropertyError as exc:
            findings.append(Finding("error", "property-value", str(exc), where))
    if findings:
        raise FindingsError(findings)
    return values
