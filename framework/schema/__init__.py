"""JSON Schemas for every YAML file a user writes, and one way to check them.

Editors can use the `.schema.json` files directly (for example with the YAML
language server's `# yaml-language-server: $schema=` comment).
"""

from __future__ import annotations

import difflib
import json
from collections.abc import Callable
from functools import cache
from importlib import resources
from typing import TYPE_CHECKING, Any

from framework.errors import Finding
from framework.yamlio import Document

if TYPE_CHECKING:  # jsonschema is imported only to explain an invalid document
    import jsonschema
    from jsonschema.exceptions import ValidationError


@cache
def schema(name: str) -> dict[str, Any]:
    """The JSON Schema `framework/schema/<name>.schema.json` as data."""
    text = resources.files(__package__).joinpath(f"{name}.schema.json").read_text("utf-8")
    return json.loads(text)


@cache
def _fast_validator(name: str) -> Callable[[Any], Any] | None:
    """fastjsonschema's compiled validator (~10x faster), or None if it is unavailable.

    It only answers "valid or not"; when a document is invalid, jsonschema
    reports every violation with its location.
    """
    try:
        import fastjsonschema
    except ImportError:  # pragma: no cover - a declared dependency
        return None
    spec = dict(schema(name))
    spec["$schema"] = "http://json-schema.org/draft-07/schema#"  # same keywords, older draft id
    return fastjsonschema.compile(spec)


def is_valid(data: Any, name: str) -> bool:
    """True if `data` follows schema `name` (fast path of `check`)."""
    fast = _fast_validator(name)
    if fast is None:
        return _validator(name).is_valid(data)
    try:
        fast(data)
    except Exception:  # fastjsonschema.JsonSchemaException (or a type it cannot handle)
        return False
    return True


@cache
def _validator(name: str) -> jsonschema.protocols.Validator:
    import jsonschema

    spec = schema(name)
    cls = jsonschema.validators.validator_for(spec)
    cls.check_schema(spec)
    return cls(spec)


_NAMES = {
    "object": "a mapping (key: value)",
    "array": "a list (- item)",
    "string": "text",
    "integer": "a whole number",
    "number": "a number",
    "boolean": "true or false",
    "null": "nothing",
}


def _kind(value: Any) -> str:
    if value is None:
        return "nothing"
    if isinstance(value, bool):
        return f"the boolean {value}"
    if isinstance(value, dict):
        return "a mapping"
    if isinstance(value, list):
        return "a list"
    if isinstance(value, str):
        return f"the text {value!r}"
    return f"the number {value!r}"


def _leaf(error: ValidationError) -> ValidationError:
    """The most telling sub-error of a oneOf/anyOf failure: not a bare type mismatch."""
    from jsonschema.exceptions import best_match

    while error.context:
        candidates = [e for e in error.context if e.validator != "type"] or list(error.context)
        error = max(candidates, key=lambda e: (len(e.absolute_path), e.validator != "oneOf"))
        if error.validator not in ("oneOf", "anyOf"):
            break
    return error if not error.context else best_match(error.context)


def _explain(error: ValidationError) -> tuple[str, str]:
    """A one-line message and a hint for one schema violation."""
    error = _leaf(error)
    if error.validator == "additionalProperties":
        allowed = sorted(error.schema.get("properties", {}))
        extra = sorted(set(error.instance) - set(allowed))
        close = difflib.get_close_matches(extra[0], allowed, n=1) if extra else []
        hint = f"did you mean {close[0]!r}?" if close else f"allowed keys: {', '.join(allowed)}"
        if extra == ["on"] and "event" in allowed:
            hint = "write `event:`; YAML 1.1 tools read `on` as the boolean true"
        return f"unknown key {', '.join(map(repr, extra))}", hint
    if error.validator == "required":
        return error.message.replace("is a required property", "is required"), ""
    if error.validator in ("minProperties", "maxProperties") and isinstance(error.instance, dict):
        allowed = sorted(error.schema.get("properties", {}))
        return (
            "needs exactly one key" if error.validator == "maxProperties" else "is empty",
            f"one of: {', '.join(allowed)}" if allowed else "",
        )
    if error.validator == "pattern":
        return f"{error.instance!r} is not a valid name here", "use letters, digits and '_'"
    if error.validator == "type":
        if error.instance is None and not error.absolute_path:
            return "the file is empty", "a statechart needs at least `statechart:` and `states:`"
        expected = error.validator_value
        wanted = (
            " or ".join(_NAMES.get(e, e) for e in expected)
            if isinstance(expected, list)
            else _NAMES.get(expected, expected)
        )
        hint = "quote it if you meant text" if isinstance(error.instance, bool) else ""
        return f"expected {wanted}, got {_kind(error.instance)}", hint
    if error.validator == "enum":
        return (f"{error.instance!r} is not one of {error.validator_value}", "")
    return error.message, ""


def check(document: Document, name: str) -> list[Finding]:
    """Every violation of schema `name` in the document, located (empty if valid)."""
    if is_valid(document.data, name):
        return []
    findings = []
    for error in _validator(name).iter_errors(document.data):
        leaf = _leaf(error)
        path = list(leaf.absolute_path)
        if leaf.validator == "additionalProperties" and isinstance(leaf.instance, dict):
            allowed = leaf.schema.get("properties", {})
            path += sorted(k for k in leaf.instance if k not in allowed)[:1]
        message, hint = _explain(error)
        findings.append(Finding("error", "schema", message, document.location(path), hint))
    findings.sort(key=lambda f: (f.location.line, f.location.column))
    return findings
