"""The kinds of YAML file fw reads, so `fw validate` can check any of them.

A file's kind is told by a key it must have (`topology:`, `scenario:`,
`sensors:` ... `statechart:`, tried in that order, as a topology names its
statechart and procedure too) or given with `fw validate --kind`. The
framework's own kinds are built in; a component package adds the kinds of
file its components read (a procedure, a tracker's sensors file) through the
`fw.file_kinds` entry point group, so the framework never names domain code:

    [project.entry-points."fw.file_kinds"]
    sensors = "components.domain.sensors:SENSORS_FILE"
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cache
from importlib import metadata
from pathlib import Path
from typing import Any

from framework import schema
from framework.errors import Finding, FindingsError, FwError, LocatedError, Location
from framework.yamlio import load_yaml

Check = Callable[[str], list[Finding]]


@dataclass(frozen=True)
class FileKind:
    """One kind of file: the key that marks it, its JSON Schema and its full check."""

    name: str
    key: str  # the top-level key every file of this kind has
    summary: str
    check: Check  # every finding for a file of this kind (schema, then meaning)


def findings_of(error: FwError, file: str, code: str = "error") -> list[Finding]:
    """An fw error as findings: its own if it carries them, else one located finding."""
    if isinstance(error, FindingsError):
        return list(error.findings)
    if isinstance(error, LocatedError):
        return [Finding("error", code, error.message, error.location, error.hint)]
    return [Finding("error", code, str(error), Location(file))]


def schema_then(schema_name: str, load: Callable[[str], Any], code: str) -> Check:
    """A check that runs the schema, then (only on a well-formed file) the kind's own
    loader, whose refusals become findings: the loader never sees a malformed file."""

    def check(path: str) -> list[Finding]:
        try:
            problems = schema.check(load_yaml(path), schema_name)
            if problems:
                return problems
            load(path)
        except FwError as exc:
            return findings_of(exc, path, code)
        return []

    return check


def _statechart(path: str) -> list[Finding]:
    from framework.statechart.files import validate_file

    return validate_file(path)


def _topology(path: str) -> list[Finding]:
    from framework.topology import check_topology

    return check_topology(path, files=check_file)[1]


def check_file(kind: str, path: str) -> list[Finding] | None:
    """Every finding of the file at `path` checked as a file of `kind`, or None when no
    installed package reads that kind (a topology names a file its components read)."""
    found = kinds().get(kind)
    return None if found is None else found.check(path)


def _scenario(path: str) -> list[Finding]:
    from framework.scenario import load_scenario

    try:
        load_scenario(path)
    except FwError as exc:
        return findings_of(exc, path, "scenario")
    return []


def _properties(path: str) -> list[Finding]:
    from framework.verify.properties import properties_findings

    try:
        return properties_findings(path)
    except FwError as exc:
        return findings_of(exc, path, "properties")


_STATECHART = FileKind("statechart", "statechart", "a procedure's statechart", _statechart)
BUILT_IN = (
    FileKind("topology", "topology", "a deployment: processes, components, wiring", _topology),
    FileKind("scenario", "scenario", "a scripted run with its expectations", _scenario),
    FileKind(
        "properties",
        "properties",
        "a chart's safety properties (its form; `fw verify` checks them against the chart)",
        _properties,
    ),
)


@cache
def kinds() -> dict[str, FileKind]:
    """Every kind known: the built-in ones and those installed packages declare."""
    found = {kind.name: kind for kind in BUILT_IN}
    for entry in metadata.entry_points(group="fw.file_kinds"):
        try:
            kind = entry.load()
        except Exception as exc:  # a broken plugin must not break `fw validate`
            raise FwError(
                f"file kind {entry.name!r} ({entry.value}) cannot be loaded: {exc}"
            ) from None
        if not isinstance(kind, FileKind):
            raise FwError(f"file kind {entry.name!r} ({entry.value}) is not a FileKind")
        found.setdefault(kind.name, kind)
    found.setdefault(_STATECHART.name, _STATECHART)  # last: the key every topology has too
    return found


def detect(path: str | Path) -> FileKind | None:
    """The kind of a file from its keys (None if it has none of theirs or is unreadable)."""
    try:
        data = load_yaml(path).data
    except FwError:
        return None
    if not isinstance(data, dict):
        return None
    for kind in kinds().values():
        if kind.key in data:
            return kind
    return None
