"""Safe YAML reading that remembers where every value was written.

Every fw file a user writes (statecharts, topologies, procedure data,
scenarios) is read through `load_yaml`, so every later error can name
file:line:column and the YAML path. Scalars are resolved with YAML 1.2 core
rules: `on`, `yes`, `no`, `off` stay strings, `1:30` is not sexagesimal and
`010` is ten. Duplicate keys, custom tags and non-scalar keys are refused
instead of silently accepted.

The reader is also the first line of defence against hostile files: it
builds values from the parser's event stream in one iterative pass (no
recursion, so a list nested 50,000 deep cannot crash the process) and
enforces `Limits` on file size, nesting depth, values after alias expansion
(no "billion laughs"), scalar length and integer digits. Recursive aliases,
invalid UTF-8, NUL and other control characters are refused with
file:line:column.
"""

from __future__ import annotations

import copy
import math
import re
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from framework.errors import Location, MissingFileError, YamlError
from framework.files import UnreadableFile, read_file

try:  # the C parser is ~10x faster; fall back to pure Python where libyaml is absent
    from yaml import CSafeLoader as _Loader
except ImportError:  # pragma: no cover - depends on how PyYAML was built
    from yaml import SafeLoader as _Loader  # type: ignore[assignment]

PathKey = tuple[str | int, ...]


@dataclass(frozen=True)
class Limits:
    """Bounds a file must stay within; far above any real fw file (the largest
    shipped one is ~10 kB, depth 9, ~1,000 values), far below what would hurt."""

    max_bytes: int = 4 * 1024 * 1024
    max_depth: int = 64
    max_values: int = 200_000  # after alias expansion
    max_scalar: int = 65_536  # characters in one scalar
    max_digits: int = 64  # digits in one integer


DEFAULT_LIMITS = Limits()

_NULL = {"", "~", "null", "Null", "NULL"}
_TRUE = {"true", "True", "TRUE"}
_FALSE = {"false", "False", "FALSE"}
_INT = re.compile(r"[-+]?[0-9]+\Z")
_OCT = re.compile(r"0o[0-7]+\Z")
_HEX = re.compile(r"0x[0-9a-fA-F]+\Z")
_FLOAT = re.compile(r"[-+]?(\.[0-9]+|[0-9]+(\.[0-9]*)?)([eE][-+]?[0-9]+)?\Z")
_INF = re.compile(r"[-+]?\.(inf|Inf|INF)\Z")
_NAN = re.compile(r"\.(nan|NaN|NAN)\Z")
_TAG = "tag:yaml.org,2002:"
_STANDARD_TAGS = {
    _TAG + t for t in ("str", "int", "float", "bool", "null", "map", "seq", "timestamp", "binary")
}
# YAML 1.2 printable characters (5.1) plus tab and line breaks; everything else is refused
_NOT_PRINTABLE = re.compile("[^\t\n\r\x20-\x7e\x85\xa0-\ud7ff\ue000-\ufffd\U00010000-\U0010ffff]")
_MERGE = object()  # the pending key of a `<<:` entry


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
    origins: dict[PathKey, str] = field(default_factory=dict)
    """The file a value came from where it is not `file` (a document that extends
    another: framework/topology/loader.py's `extends:`)."""
    written: dict[PathKey, PathKey] = field(default_factory=dict)
    """Values the loader wrote out of another (a topology's `ros2:` entries as components
    and connections): their path -> the path of what the user wrote, which findings
    name."""

    def location(self, path: Iterable[str | int]) -> Location:
        """Location of `path`, or of its nearest ancestor that has one; the path said is
        the user's where the value was written out of another."""
        key = tuple(path)
        probe = key
        while probe and probe not in self.marks:
            probe = probe[:-1]
        line, column = self.marks.get(probe, (1, 1))
        said = key
        for depth in range(len(key), 0, -1):
            if key[:depth] in self.written:
                said = self.written[key[:depth]]
                break
        return Location(self.origins.get(probe, self.file), line, column, format_path(said))

    def origin(self, path: Iterable[str | int]) -> str:
        """The file the value at `path` (or its nearest ancestor with a place) was
        written in."""
        probe = tuple(path)
        while probe and probe not in self.marks:
            probe = probe[:-1]
        return self.origins.get(probe, self.file)


def extend(base: Document, overlay: Document) -> Document:
    """`overlay` laid over `base`: mappings merged key by key (the overlay's value wins;
    mappings in both are merged in turn), anything else replaced. Every value keeps
    the place, and file, it was written in."""
    marks = dict(base.marks)
    origins = {key: base.origins.get(key, base.file) for key in base.marks}

    def take(path: PathKey) -> None:
        for key in [k for k in marks if k[: len(path)] == path]:
            del marks[key]
            origins.pop(key, None)
        for key, mark in overlay.marks.items():
            if key[: len(path)] == path:
                marks[key] = mark
                origins[key] = overlay.origins.get(key, overlay.file)

    def merge(under: Any, over: Any, path: PathKey) -> Any:
        if isinstance(under, dict) and isinstance(over, dict):
            out = dict(under)
            for key, value in over.items():
                out[key] = merge(under.get(key), value, (*path, key))
            if path in overlay.marks:
                marks.setdefault(path, overlay.marks[path])
            return out
        take(path)
        return over

    data = merge(base.data, overlay.data, ())
    return Document(
        data, overlay.file, marks, {k: f for k, f in origins.items() if f != overlay.file}
    )


@dataclass
class _Open:
    """A mapping or sequence whose end event has not come yet."""

    value: dict[str, Any] | list[Any]
    path: PathKey
    anchor: str | None
    counted: int  # values counted before it began (its size is the difference)
    key: Any = None  # a mapping's pending key (None: the next scalar is a key)
    key_mark: tuple[int, int] = (0, 0)
    merges: list[tuple[dict[str, Any], tuple[int, int]]] = field(default_factory=list)


class _Builder:
    """Turns the parser's events into Python data, recording marks and enforcing limits."""

    def __init__(self, file: str, limits: Limits):
        self.file = file
        self.limits = limits
        self.marks: dict[PathKey, tuple[int, int]] = {}
        self.stack: list[_Open] = []
        self.anchors: dict[str, tuple[Any, int]] = {}  # name -> (value, values in it)
        self.count = 0
        self.root: Any = None
        self.done = False

    def error(self, event: yaml.Event, message: str, path: PathKey = (), hint: str = ""):
        mark = event.start_mark
        where = Location(self.file, mark.line + 1, mark.column + 1, format_path(path))
        return YamlError(message, where, hint)

    def feed(self, event: yaml.Event) -> None:
        if isinstance(event, yaml.DocumentStartEvent) and self.done:
            raise self.error(event, "a file holds one YAML document (found a second `---`)")
        if isinstance(event, yaml.DocumentEndEvent):
            self.done = True
        elif isinstance(event, yaml.ScalarEvent):
            self.scalar(event)
        elif isinstance(event, yaml.AliasEvent):
            self.alias(event)
        elif isinstance(event, yaml.MappingStartEvent | yaml.SequenceStartEvent):
            self.begin(event)
        elif isinstance(event, yaml.MappingEndEvent | yaml.SequenceEndEvent):
            self.end()

    def _count(self, event: yaml.Event, n: int, path: PathKey) -> None:
        self.count += n
        if self.count > self.limits.max_values:
            raise self.error(
                event,
                f"more than {self.limits.max_values:,} values (after expanding aliases)",
                path,
                "is an alias repeated many times? fw files are small",
            )

    def _check_tag(self, event: yaml.NodeEvent, path: PathKey) -> None:
        tag = getattr(event, "tag", None)
        if tag not in (None, "!") and tag not in _STANDARD_TAGS:
            raise self.error(event, f"custom YAML tag {tag!r} is not allowed", path)

    def _is_key(self) -> bool:
        return (
            bool(self.stack)
            and isinstance(self.stack[-1].value, dict)
            and self.stack[-1].key is None
        )

    def _child_path(self) -> PathKey:
        if not self.stack:
            return ()
        top = self.stack[-1]
        if isinstance(top.value, list):
            return (*top.path, len(top.value))
        return (*top.path, top.key) if isinstance(top.key, str) else top.path

    def scalar(self, event: yaml.ScalarEvent) -> None:
        path = self._child_path()
        self._check_tag(event, path)
        if len(event.value) > self.limits.max_scalar:
            raise self.error(
                event,
                f"a value of {len(event.value):,} characters (at most {self.limits.max_scalar:,})",
                path,
            )
        if self._is_key():
            self.key(event)
            return
        self._count(event, 1, path)
        text, tag = event.value, event.tag
        if tag == _TAG + "str" or event.style or tag in (_TAG + "binary", _TAG + "timestamp"):
            value: Any = text  # quoted or block scalars are always strings (C parser: '' = plain)
        else:
            digits = len(text.lstrip("+-"))
            if digits > self.limits.max_digits and (
                _INT.match(text) or _HEX.match(text) or _OCT.match(text)
            ):
                raise self.error(
                    event,
                    f"an integer of {digits} digits (at most {self.limits.max_digits})",
                    path,
                    "quote it if it is an identifier",
                )
            value = resolve_plain_scalar(text)
        self.attach(event, value, event.anchor, 1)

    def key(self, event: yaml.ScalarEvent) -> None:
        top = self.stack[-1]
        mark = (event.start_mark.line + 1, event.start_mark.column + 1)
        if event.value == "<<" and not event.style and event.tag is None:
            top.key, top.key_mark = _MERGE, mark
            return
        key = event.value
        assert isinstance(top.value, dict)
        if key in top.value:
            first = self.marks.get((*top.path, key), (0, 0))[0]
            raise self.error(
                event,
                f"duplicate key {key!r} (first written at line {first})",
                (*top.path, key),
                "remove or rename one of them",
            )
        top.key, top.key_mark = key, mark
        self.marks[(*top.path, key)] = mark

    def alias(self, event: yaml.AliasEvent) -> None:
        path = self._child_path()
        if self._is_key():
            raise self.error(event, "mapping keys must be plain names, not aliases", path)
        name = event.anchor
        if any(o.anchor == name for o in self.stack):
            raise self.error(event, f"alias *{name} refers to the value that contains it", path)
        if name not in self.anchors:
            raise self.error(event, f"alias *{name} has no anchor &{name} before it", path)
        value, size = self.anchors[name]
        self._count(event, size, path)
        self.attach(event, copy.deepcopy(value), None, size)

    def begin(self, event: yaml.MappingStartEvent | yaml.SequenceStartEvent) -> None:
        path = self._child_path()
        if self._is_key():
            raise self.error(event, "mapping keys must be plain names, not collections", path)
        self._check_tag(event, path)
        if len(self.stack) >= self.limits.max_depth:
            raise self.error(event, f"nested more than {self.limits.max_depth} levels deep", path)
        self._count(event, 1, path)
        self.marks.setdefault(path, (event.start_mark.line + 1, event.start_mark.column + 1))
        value: dict[str, Any] | list[Any] = {} if isinstance(event, yaml.MappingStartEvent) else []
        self.stack.append(_Open(value, path, event.anchor, self.count - 1))

    def end(self) -> None:
        done = self.stack.pop()
        if isinstance(done.value, dict):
            for source, mark in done.merges:
                for key, item in source.items():
                    if key not in done.value:
                        done.value[key] = item
                        self.marks.setdefault((*done.path, key), mark)
        size = self.count - done.counted
        if done.anchor is not None:
            self.anchors[done.anchor] = (done.value, size)
        self.attach(None, done.value, None, size)  # its mark was set when it began

    def attach(
        self,
        event: yaml.Event | None,
        value: Any,
        anchor: str | None,
        size: int,
    ) -> None:
        """Put a finished value where it belongs: the root, a list item or a mapping value."""
        if anchor is not None:
            self.anchors[anchor] = (value, size)
        if not self.stack:
            self.root = value
            if event is not None:
                self.marks.setdefault((), (event.start_mark.line + 1, event.start_mark.column + 1))
            return
        top = self.stack[-1]
        path = self._child_path()
        if event is not None:
            self.marks.setdefault(path, (event.start_mark.line + 1, event.start_mark.column + 1))
        if isinstance(top.value, list):
            top.value.append(value)
        elif top.key is _MERGE:
            sources = value if isinstance(value, list) else [value]
            if not all(isinstance(s, dict) for s in sources):
                where = Location(self.file, *top.key_mark, format_path(top.path))
                raise YamlError("a '<<' merge needs a mapping or a list of them", where)
            top.merges.extend((s, top.key_mark) for s in sources)
            top.key = None
        else:
            top.value[top.key] = value
            top.key = None


def _check_text(text: str, file: str) -> None:
    """Refuse NUL and other characters YAML does not allow, at their line:column."""
    bad = _NOT_PRINTABLE.search(text)
    if bad is None:
        return
    start = bad.start()
    line = text.count("\n", 0, start) + 1
    column = start - (text.rfind("\n", 0, start) + 1) + 1
    char = bad.group()
    name = "NUL" if char == "\0" else f"U+{ord(char):04X}"
    raise YamlError(
        f"the character {name} is not allowed in a YAML file",
        Location(file, line, column),
        "is this a binary file, or was it saved with the wrong encoding?",
    )


def load_yaml_text(text: str, file: str = "<string>", limits: Limits = DEFAULT_LIMITS) -> Document:
    """Parse YAML text into a located `Document`; raise `YamlError` on any defect."""
    if len(text) > limits.max_bytes:
        raise YamlError(
            f"{len(text):,} characters: larger than {limits.max_bytes:,}", Location(file)
        )
    _check_text(text, file)
    builder = _Builder(file, limits)
    try:
        for event in yaml.parse(text, Loader=_Loader):
            builder.feed(event)
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line, column = (mark.line + 1, mark.column + 1) if mark else (0, 0)
        problem = exc.problem or exc.context or "invalid YAML"
        raise YamlError(f"YAML syntax: {problem}", Location(file, line, column)) from None
    except yaml.YAMLError as exc:  # pragma: no cover - the text was checked above
        raise YamlError(f"YAML syntax: {' '.join(str(exc).split())}", Location(file)) from None
    if builder.root is None and not builder.marks:
        return Document(None, file, {(): (1, 1)})
    return Document(builder.root, file, builder.marks)


def load_yaml(path: str | Path, limits: Limits = DEFAULT_LIMITS) -> Document:
    """Read and parse a YAML file; unreadable, oversized or non-UTF-8 files raise
    `YamlError` too (with the line and column of the first bad byte)."""
    name = str(path)
    try:
        raw = read_file(path, limits.max_bytes)
    except UnreadableFile as exc:
        if exc.missing:
            raise MissingFileError("file not found", Location(name)) from None
        raise YamlError(f"cannot read file: {exc.reason}", Location(name)) from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        before = raw[: exc.start]
        line = before.count(b"\n") + 1
        column = len(before[before.rfind(b"\n") + 1 :].decode("utf-8", "replace")) + 1
        raise YamlError(
            f"cannot read file: byte 0x{raw[exc.start]:02x} is not UTF-8",
            Location(name, line, column),
            "save the file as UTF-8",
        ) from None
    return load_yaml_text(text, name, limits)
