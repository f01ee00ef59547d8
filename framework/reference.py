"""The reference of component classes: what an integrator may wire, set and call.

Built from the classes' own declarations (ports, properties, operations), so it cannot
drift from the code: `fw describe` prints it, and `docs/reference.md` is this module's
output for every class the shipped topologies use (a test keeps it current). A change
to a default, a range or an operation's access is a change of the contract, and shows
in the reference's diff.
"""

from __future__ import annotations

import inspect
from collections.abc import Iterable
from typing import Any

from framework.component import Component, In, Out, class_path, declarations
from framework.messages import type_name
from framework.ports import ConnPolicy
from framework.properties import Property

_DEFAULT_POLICY = ConnPolicy().to_dict()


def _first_paragraph(obj: Any) -> str:
    doc = inspect.getdoc(obj) or ""
    return " ".join(doc.split("\n\n")[0].split())


def _cell(text: Any) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def _range(p: Property) -> str:
    if p.choices:
        return "one of " + ", ".join(repr(c) for c in p.choices)
    low = "" if p.min is None else f"{p.min:g}"
    high = "" if p.max is None else f"{p.max:g}"
    if not (low or high):
        return ""
    return f"[{low or '-inf'}, {high or 'inf'}]"


def _signature(method: Any) -> str:
    parts = []
    for p in inspect.signature(method).parameters.values():
        if p.name == "self":
            continue
        text = p.name
        if p.annotation is not inspect.Parameter.empty:
            annotation = p.annotation
            text += f": {annotation if isinstance(annotation, str) else type_name(annotation)}"
        if p.default is not inspect.Parameter.empty:
            text += f" = {p.default!r}"
        parts.append(text)
    return "(" + ", ".join(parts) + ")"


def component_reference(cls: type[Component]) -> str:
    """One component class as Markdown: its purpose, lifecycle flags, properties, input
    and output ports, and operations (with whether they may change anything)."""
    lines = [f"## `{class_path(cls)}`", "", _first_paragraph(cls), ""]
    flags = []
    if not cls.needs_configuration:
        flags.append("starts in Stopped (no configuration needed)")
    if cls.hosts_safety_monitor:
        flags.append("may host the topology's safety monitor (`safety: monitor:`)")
    if flags:
        lines += [f"- {flag}" for flag in flags] + [""]
    declared = declarations(cls)
    properties = [(n, v) for n, v in declared if isinstance(v, Property)]
    inputs = [(n, v) for n, v in declared if isinstance(v, In)]
    outputs = [(n, v) for n, v in declared if isinstance(v, Out)]
    operations = [(n, v) for n, v in declared if hasattr(v, "__fw_operation__")]
    if properties:
        lines += [
            "| property | type | default | unit | range | |",
            "|---|---|---|---|---|---|",
        ]
        for name, p in properties:
            required = "**required**. " if p.required else ""
            kind = f"A {p.file} file (checked with the topology). " if p.file else ""
            lines.append(
                f"| `{name}` | {type_name(p.type)} | `{p.default!r}` | {_cell(p.unit)} "
                f"| {_cell(_range(p))} | {required}{kind}{_cell(p.doc)} |"
            )
        lines.append("")
    if inputs or outputs:
        lines += ["| port | direction | message | |", "|---|---|---|---|"]
        for name, port in inputs:
            policy = port.policy.to_dict()
            extra = f" (policy: {_cell(policy)})" if policy != _DEFAULT_POLICY else ""
            lines.append(f"| `{name}` | in | {type_name(port.type)} | {_cell(port.doc)}{extra} |")
        for name, port in outputs:
            lines.append(f"| `{name}` | out | {type_name(port.type)} | {_cell(port.doc)} |")
        lines.append("")
    if operations:
        lines += ["| operation | access | |", "|---|---|---|"]
        for name, method in operations:
            access = "reads only" if method.__fw_readonly__ else "may change state"
            if not method.__fw_exclusive__:
                access += ", concurrent"
            doc = _first_paragraph(method) or method.__fw_operation__
            lines.append(f"| `{name}{_cell(_signature(method))}` | {access} | {_cell(doc)} |")
        lines.append("")
    return "\n".join(lines)


def reference(classes: Iterable[type[Component]], command: str = "") -> str:
    """The reference of several classes, in the order given (each once); `command`, if
    given, is said at the top as the way to regenerate it."""
    seen: dict[str, type[Component]] = {}
    for cls in classes:
        seen.setdefault(class_path(cls), cls)
    head = ["# Component reference", ""]
    if command:
        head += [f"Generated from the classes' declarations by `{command}`: do not edit.", ""]
    body = "\n".join(component_reference(cls) for cls in seen.values())
    return "\n".join(head) + "\n" + body
