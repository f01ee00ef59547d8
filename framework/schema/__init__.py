"""JSON Schemas for every YAML file a user writes, and one way to check them.

Editors can use the `.schema.json` files directly (for example with the YAML
language server's `# yaml-language-server: $schema=` comment).
"""

from __future__ import annotations

import difflib
import json
import math
from collections.abc import Callable
from functools import cache
from importlib import resources
from typing import TYPE_CHECKING, Any

from framework.errors import Finding, LocatedError
from framework.yamlio import Document

if TYPE_CHECKING:  # jsonschema is imported only to explain an invalid document
    import jsonschema
    from jsonschema.exceptions import ValidationError


@cache
def schema(name: str) -> dict[str, Any]:
    """The JSON Schema `framework/schema/<name>.schema.json` as data; a name
    `package:file.schema.json` is read from that package instead (a component's
    own file kinds keep their schema next to their code)."""
    package, _, file = name.rpartition(":")
    resource = resources.files(package or __package__).joinpath(
        file if package else f"{name}.schema.json"
    )
    return json.loads(resource.read_text("utf-8"))


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


def _pattern_problem(value: Any, pattern: str) -> tuple[str, str]:
    """What a text that does not match one of the schemas' patterns should have been."""
    if "(ms|s|min|h)" in pattern:
        return f"{value!r} is not a duration", "write e.g. 2s, 500ms or 1.5min; never negative"
    if ":" in pattern:
        return f"{value!r} is not a class path", "write package.module:Class"
    if "_-]" in pattern:
        return f"{value!r} is not a valid name here", "use letters, digits, '_' and '-'"
    if r"\." in pattern:
        return f"{value!r} is not a valid name here", "use names of letters, digits and '_', dotted"
    return f"{value!r} is not a valid name here", "use letters, digits and '_'"


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
        return _pattern_problem(error.instance, str(error.validator_value))
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
    if error.validator in ("minItems", "maxItems") and isinstance(error.instance, list):
        bound = error.validator_value
        return (
            f"needs {'at least' if error.validator == 'minItems' else 'at most'} {bound} "
            f"item{'s' if bound != 1 else ''}, has {len(error.instance)}",
            "",
        )
    if error.validator in ("minimum", "exclusiveMinimum", "maximum", "exclusiveMaximum"):
        words = {
            "minimum": "at least",
            "exclusiveMinimum": "more than",
            "maximum": "at most",
            "exclusiveMaximum": "less than",
        }
        return f"{error.instance!r} must be {words[error.validator]} {error.validator_value}", ""
    if error.validator == "enum":
        return (f"{error.instance!r} is not one of {error.validator_value}", "")
    return error.message, ""


def non_finite(data: Any, path: tuple[str | int, ...] = ()) -> tuple[str | int, ...] | None:
    """The path of the first NaN or infinity in `data` (JSON Schema's `number` lets
    them through), or None."""
    stack = [(path, data)]
    while stack:
        where, value = stack.pop()
        if isinstance(value, float) and not math.isfinite(value):
            return where
        if isinstance(value, dict):
            stack.extend(((*where, k), v) for k, v in reversed(value.items()))
        elif isinstance(value, list):
            stack.extend(((*where, i), v) for i, v in reversed(list(enumerate(value))))
    return None


def require(document: Document, name: str, error: type[LocatedError], finite: bool = True) -> None:
    """Raise `error` at the first violation of schema `name` (saying how many more);
    with `finite`, a NaN or infinity anywhere is refused too."""
    problems = check(document, name)
    if finite and not problems and (where := non_finite(document.data)) is not None:
        raise error("must be a finite number", document.location(where))
    if problems:
        first = problems[0]
        more = f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""
        raise error(first.message + more, first.location, first.hint)


def refuse_retired(
    document: Document,
    section: str,
    field: str,
    error: type[LocatedError],
    why: Callable[[str], str],
) -> None:
    """Raise `error` at the first entry of `section` that still sets `field`, a field an
    earlier version read and this one would silently ignore; `why(entry)` says what
    replaced it. Checked before the schema, whose "unknown field" would not say why."""
    for entry, spec in ((document.data or {}).get(section) or {}).items():
        if isinstance(spec, dict) and field in spec:
            raise error(why(str(entry)), document.location((section, entry, field)))


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
