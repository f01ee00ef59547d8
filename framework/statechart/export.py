"""Draw a statechart: Graphviz DOT (rendered to SVG/PNG by `dot`), PlantUML, Mermaid.

Composite states become clusters; initial states get a black dot; active
states (for example from a running Coordinator) can be highlighted.
"""

from __future__ import annotations

import re
import shutil
import subprocess
from collections.abc import Callable, Iterable
from pathlib import Path

from framework.errors import FwError
from framework.statechart.model import Kind, State, Statechart, Transition

FORMATS = (".dot", ".gv", ".svg", ".png", ".puml", ".mmd")


class ExportError(FwError):
    """The chart could not be drawn (unknown format, Graphviz missing or failing)."""


def _ident(state: State) -> str:
    return "s_" + (re.sub(r"\W", "_", state.path) if state.path else "root")


def _quote(text: str) -> str:
    escaped = text.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n")
    return '"' + escaped + '"'


def _details(state: State) -> list[str]:
    lines = []
    if state.configure is not None:
        lines.append(f"configure: {state.configure.tag}")
    for label, actions in (("entry", state.entry), ("do", state.do), ("exit", state.exit)):
        if actions:
            lines.append(f"{label}: " + ", ".join(_action_text(a) for a in actions))
    return lines


def _action_text(action) -> str:
    kind = action.kind
    if kind in ("raise", "send"):
        return f"{kind} {action.event}"
    if kind == "configure":
        return f"configure {action.tag}"
    if kind == "set":
        return "set " + ", ".join(action.assignments)
    if kind == "write":
        return f"write {action.port}"
    if kind == "call":
        return f"call {action.operation}"
    return "log"


def _edge_label(t: Transition) -> str:
    label = t.label()
    if t.effect:
        label += " / " + ", ".join(_action_text(a) for a in t.effect)
    return label


def to_dot(chart: Statechart, active: Iterable[str] = ()) -> str:
    """Graphviz DOT text of the chart; states in `active` are highlighted."""
    on = set(active)
    out = [
        "digraph statechart {",
        "  compound=true; rankdir=TB; fontname=Helvetica;",
        "  node [fontname=Helvetica, fontsize=11]; edge [fontname=Helvetica, fontsize=9];",
        f"  label={_quote(chart.name)}; labelloc=t;",
    ]
    anchors: dict[State, str] = {}

    def emit(state: State, indent: str) -> None:
        ident = _ident(state)
        highlighted = state.path in on
        if state.is_composite:
            out.append(f"{indent}subgraph cluster_{ident} {{")
            title = state.name + (" (parallel)" if state.kind is Kind.PARALLEL else "")
            label = "\n".join([title, *_details(state)])
            style = "rounded"
            fill = "white"
            out.append(
                f"{indent}  label={_quote(label)}; style={_quote(style)}; "
                f"fillcolor={_quote(fill)}; "
                f"color={'darkgreen' if highlighted else 'gray40'}; "
                f"penwidth={2 if highlighted else 1};"
            )
            anchor = f"{ident}__anchor"
            anchors[state] = anchor
            out.append(f"{indent}  {anchor} [shape=point, style=invis, width=0.01];")
            if state.initial is not None:
                out.append(f"{indent}  {ident}__init [shape=point, width=0.12];")
            for child in state.children:
                emit(child, indent + "  ")
            out.append(f"{indent}}}")
            return
        if state.kind is Kind.FINAL:
            shape = f'shape=doublecircle, width=0.25, label="", xlabel={_quote(state.name)}'
        elif state.kind is Kind.JUNCTION:
            shape = f'shape=diamond, width=0.25, height=0.25, label="", xlabel={_quote(state.name)}'
        elif state.kind in (Kind.SHALLOW_HISTORY, Kind.DEEP_HISTORY):
            mark = "H*" if state.kind is Kind.DEEP_HISTORY else "H"
            shape = f"shape=circle, width=0.3, label={_quote(mark)}"
        else:
            label = "\n".join([state.name, *_details(state)])
            shape = f"shape=box, style={_quote('rounded,filled')}, label={_quote(label)}"
            shape += ", fillcolor=" + ('"#9be58a", penwidth=2' if highlighted else '"#f4f4f4"')
        out.append(f"{indent}{ident} [{shape}];")

    for child in chart.root.children:
        emit(child, "  ")
    if chart.root.initial is not None:
        out.append("  s_root__init [shape=point, width=0.12];")

    def endpoint(state: State) -> tuple[str, str]:
        if state in anchors:
            return anchors[state], f"cluster_{_ident(state)}"
        return _ident(state), ""

    def edge(src: str, dst: str, label: str, ltail: str = "", lhead: str = "") -> None:
        attrs = [f"label={_quote(label)}"] if label else []
        if ltail:
            attrs.append(f"ltail={ltail}")
        if lhead:
            attrs.append(f"lhead={lhead}")
        out.append(f"  {src} -> {dst}" + (f" [{', '.join(attrs)}]" if attrs else "") + ";")

    for state in chart.root.walk():
        if state.initial is not None:
            dst, lhead = endpoint(state.initial)
            edge(f"{_ident(state)}__init", dst, "", "", lhead)
        for t in state.transitions:
            src, ltail = endpoint(state)
            if t.target is None:
                edge(src, src, _edge_label(t), ltail, ltail)
                continue
            dst, lhead = endpoint(t.target)
            edge(src, dst, _edge_label(t), ltail, lhead)
    out.append("}")
    return "\n".join(out) + "\n"


def _nested_body(state: State, indent: str, out: list[str], emit: Callable[..., None]) -> None:
    """Children of a composite in PlantUML/Mermaid syntax (same for both), closing brace."""
    if state.initial is not None:
        out.append(f"{indent}  [*] --> {_ident(state.initial)}")
    for i, child in enumerate(state.children):
        if state.kind is Kind.PARALLEL and i:
            out.append(f"{indent}  --")
        emit(child, indent + "  ")
    out.append(f"{indent}}}")


def to_plantuml(chart: Statechart, active: Iterable[str] = ()) -> str:
    """PlantUML state-diagram text of the chart."""
    on = set(active)
    out = ["@startuml", f"title {chart.name}", "hide empty description"]

    def emit(state: State, indent: str) -> None:
        ident = _ident(state)
        color = " #9be58a" if state.path in on else ""
        stereo = {
            Kind.JUNCTION: " <<choice>>",
            Kind.SHALLOW_HISTORY: " <<history>>",
            Kind.DEEP_HISTORY: " <<history*>>",
            Kind.FINAL: " <<end>>",
        }.get(state.kind, "")
        if state.is_composite:
            out.append(f'{indent}state "{state.name}" as {ident}{color} {{')
            _nested_body(state, indent, out, emit)
        else:
            out.append(f'{indent}state "{state.name}" as {ident}{stereo}{color}')
        for line in _details(state):
            out.append(f"{indent}{ident} : {line}")

    for child in chart.root.children:
        emit(child, "")
    if chart.root.initial is not None:
        out.append(f"[*] --> {_ident(chart.root.initial)}")
    for t in chart.transitions():
        target = t.target or t.source
        label = _edge_label(t)
        out.append(f"{_ident(t.source)} --> {_ident(target)}" + (f" : {label}" if label else ""))
    out.append("@enduml")
    return "\n".join(out) + "\n"


def to_mermaid(chart: Statechart, active: Iterable[str] = ()) -> str:
    """Mermaid `stateDiagram-v2` text of the chart."""
    on = set(active)
    out = ["stateDiagram-v2", f"  %% {chart.name}"]

    def emit(state: State, indent: str) -> None:
        ident = _ident(state)
        if state.kind is Kind.JUNCTION:
            out.append(f"{indent}state {ident} <<choice>>")
        else:
            out.append(f'{indent}state "{state.name}" as {ident}')
        if state.is_composite:
            out.append(f"{indent}state {ident} {{")
            _nested_body(state, indent, out, emit)
        if state.kind is Kind.FINAL:
            out.append(f"{indent}{ident} --> [*]")

    for child in chart.root.children:
        emit(child, "  ")
    if chart.root.initial is not None:
        out.append(f"  [*] --> {_ident(chart.root.initial)}")
    for t in chart.transitions():
        target = t.target or t.source
        label = _edge_label(t).replace(":", "")
        out.append(f"  {_ident(t.source)} --> {_ident(target)}" + (f" : {label}" if label else ""))
    out.append("  classDef active fill:#9be58a,stroke:#2a7a1a,stroke-width:2px")
    for path in sorted(on):
        if path in chart.states:
            out.append(f"  class {_ident(chart.states[path])} active")
    return "\n".join(out) + "\n"


def render(chart: Statechart, output: str | Path, active: Iterable[str] = ()) -> Path:
    """Write the chart to `output`; the suffix picks the format (see FORMATS)."""
    path = Path(output)
    suffix = path.suffix.lower()
    if suffix not in FORMATS:
        raise ExportError(
            f"unknown output format {suffix or '(none)'!r}; use one of {', '.join(FORMATS)}"
        )
    if suffix == ".puml":
        text = to_plantuml(chart, active)
    elif suffix == ".mmd":
        text = to_mermaid(chart, active)
    else:
        text = to_dot(chart, active)
    path.parent.mkdir(parents=True, exist_ok=True)
    if suffix in (".svg", ".png"):
        dot = shutil.which("dot")
        if dot is None:
            raise ExportError(
                "Graphviz `dot` is not installed; install it (Debian: apt-get "
                "install graphviz) or write .dot/.puml/.mmd instead"
            )
        try:
            result = subprocess.run(
                [dot, f"-T{suffix[1:]}", "-o", str(path)],
                input=text.encode(),
                capture_output=True,
                timeout=60,
            )
        except subprocess.TimeoutExpired:
            raise ExportError("Graphviz `dot` took longer than 60 s") from None
        if result.returncode != 0:
            raise ExportError(f"Graphviz failed: {result.stderr.decode(errors='replace').strip()}")
    else:
        path.write_text(text, encoding="utf-8")
    return path
