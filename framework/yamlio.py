"""Safe YAML reading that remembers where every value was written.

All fw files (statecharts, topologies, procedure data) are read through
`load_yaml`, so every later error can name file:line:column and the YAML
path. Scalars are resolved with YAML 1.2 core rules: `on`, `yes`, `no`, `off`
stay strings, `1:30` is not sexagesimal and `010` is ten. Duplicate keys,
custom tags and non-scalar keys are refused instead of silently accepted.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from framework.errors import Location, YamlError

try:  # the C parser is ~10x faster; fall back to pure Python where libyaml is absent
    from yaml import CSafeLoader as _Loader
except ImportError:  # pragma: no cover - depends on how PyYAML was built
    from yaml import SafeLoader as _Loader  # type: ignore[assignment]

PathKey = tuple[str | int, ...]

_NULL = {"", "~", "null", "Null", "NULL"}
_TRUE = {"true", "True", "TRUE"}
_FALSE = {"false", "False", "FALSE"}
_INT = re.compile(r"[-+]?[0-9]+\Z")
_OCT = re.compile(r"0o[0-7]+\Z")
_HEX = re.compile(r"0x[0-9a-fA-F]+\Z")
_FLOAT = re.compile(r"[-+]?(\.[0-9]+|[0-9]+(\.[0-9]*)?)([eE][-+]?[0-9]+)?\Z")
_INF = re.compile(r"[-+]?\.(inf|Inf|INF)\Z")
_NAN = re.compile(r"\.(nan|NaN|NAN)\Z")
_STANDARD_TAGS = {
    "tag:yaml.org,2002:" + t
    for t in ("str", "int", "float", "bool", "null", "map", "seq", "timestamp", "binary")
}


def resolve_plain_scalar(text: str) -> Any:
    """Resolve an unquoted scalar with the YAML 1.2 core schema."""
    if text in _NULL:
        return None
    if text in _TRUE:
        return True
    if text in _FALSE:
        return False
    if _INT.match(text):
        return int(text)
    if _OCT.match(text):
        return int(text[2:], 8)
    if _HEX.match(text):
        return int(text[2:], 16)
    if _FLOAT.match(text):
        return float(text)
    if _INF.match(text):
        return -math.inf if text.startswith("-") else math.inf
    if _NAN.match(text):
        return math.nan
    return text


def format_path(path: Iterable[str | int]) -> str:
    """Render a YAML path as `states[1].transitions[0].target`."""
    out = ""
    for part in path:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += f".{part}" if out else str(part)
    return out


@dataclass
class Document:
    """A loaded YAML file: plain Python data plus the position of every value."""

    data: Any
    file: str
    marks: dict[PathKey, tuple[int, int]] = field(default_factory=dict)

    def location(self, path: Iterable[str | int]) -> Location:
        """Location of `path`, or of its nearest ancestor that has one."""
        key = tuple(path)
        probe = key
        while probe and probe not in self.marks:
            probe = probe[:-1]
        line, column = self.marks.get(probe, (1, 1))
        return Location(self.file, line, column, format_path(key))


class _Builder:
    """Turns a composed YAML node graph into Python data, recording marks."""

    def __init__(self, file: str):
        self.file = file
        self.marks: dict[PathKey, tuple[int, int]] = {}

    def error(self, node: yaml.Node, path: PathKey, message: str, hint: str = "") -> YamlError:
        mark = node.start_mark
        return YamlError(
            message, Location(self.file, mark.line + 1, mark.column + 1, format_path(path)), hint
        )

    def build(self, node: yaml.Node, path: PathKey) -> Any:
        mark = node.start_mark
        self.marks.setdefault(path, (mark.line + 1, mark.column + 1))
        if node.tag not in _STANDARD_TAGS:
            raise self.error(node, path, f"custom YAML tag {node.tag!r} is not allowed")
        if isinstance(node, yaml.ScalarNode):
            return self.scalar(node, path)
        if isinstance(node, yaml.SequenceNode):
            return [self.build(item, (*path, i)) for i, item in enumerate(node.value)]
        if isinstance(node, yaml.MappingNode):
            return self.mapping(node, path)
        raise self.error(node, path, "unsupported YAML node")  # pragma: no cover

    def scalar(self, node: yaml.ScalarNode, path: PathKey) -> Any:
        if node.style:  # quoted or block scalars are always strings (C parser: '' = plain)
            return node.value
        if node.tag in ("tag:yaml.org,2002:binary", "tag:yaml.org,2002:timestamp"):
            return node.value
        return resolve_plain_scalar(node.value)

    def key_of(self, node: yaml.Node, path: PathKey) -> str:
        if not isinstance(node, yaml.ScalarNode):
            raise self.error(node, path, "mapping keys must be plain names, not collections")
        return node.value

    def mapping(self, node: yaml.MappingNode, path: PathKey) -> dict[str, Any]:
        result: dict[str, Any] = {}
        merged: dict[str, Any] = {}
        for key_node, value_node in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                merged.update(self._merge_source(value_node, path))
                continue
            key = self.key_of(key_node, path)
            child = (*path, key)
            if key in result:
                first = self.marks.get(child, (0, 0))[0]
                raise self.error(
                    key_node,
                    child,
                    f"duplicate key {key!r} (first written at line {first})",
                    "remove or rename one of them",
                )
            self.marks[child] = (key_node.start_mark.line + 1, key_node.start_mark.column + 1)
            result[key] = self.build(value_node, child)
        for key, value in merged.items():
            result.setdefault(key, value)
        return result

    def _merge_source(self, node: yaml.Node, path: PathKey) -> dict[str, Any]:
        sources = node.value if isinstance(node, yaml.SequenceNode) else [node]
        merged: dict[str, Any] = {}
        for source in sources:
            if not isinstance(source, yaml.MappingNode):
                raise self.error(source, path, "a '<<' merge needs a mapping or a list of them")
            for key, value in self.mapping(source, path).items():
                merged.setdefault(key, value)
        return merged


def load_yaml_text(text: str, file: str = "<string>") -> Document:
    """Parse YAML text into a located `Document`; raise `YamlError` on any defect."""
    try:
        node = yaml.compose(text, Loader=_Loader)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line, column = (mark.line + 1, mark.column + 1) if mark else (0, 0)
        problem = exc.problem or exc.context or "invalid YAML"
        raise YamlError(f"YAML syntax: {problem}", Location(file, line, column)) from None
    except yaml.YAMLError as exc:  # e.g. ReaderError: control characters, bad encoding
        raise YamlError(f"YAML syntax: {' '.join(str(exc).split())}", Location(file)) from None
    if node is None:
        return Document(None, file, {(): (1, 1)})
    builder = _Builder(file)
    data = builder.build(node, ())
    return Document(data, file, builder.marks)


def load_yaml(path: str | Path) -> Document:
    """Read and parse a YAML file; unreadable files raise `YamlError` too."""
    name = str(path)
    try:
        text = Path(path).read_text(encoding="utf-8")
    except FileNotFoundError:
        raise YamlError("file not found", Location(name)) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise YamlError(f"cannot read file: {exc}", Location(name)) from None
    return load_yaml_text(text, name)
