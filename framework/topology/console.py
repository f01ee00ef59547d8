"""What a topology's `console:` section asks of the operator console.

The console knows no procedure: it shows what the topology declares (tiles of
fields of read-only operations and of port samples, plots of port samples, buttons for the operator's
events) and what the panels it names add (a panel is a plugin from the `fw.console`
entry point group, such as SEEG's 3D view). Without a `console:` section, every
external event gets a button (or a form, when the chart declares its payload).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any

PANELS_GROUP = "fw.console"
STYLES = ("normal", "danger", "stop")


@dataclass(frozen=True)
class Source:
    """Where a tile's or plot's value comes from: the answer of a read-only operation
    polled a few times a second (`component`, `operation`, `path`: keys below it) or a
    port's samples (`key`: its bus key, `type_name`: its message type, `path`: fields
    below the sample)."""

    component: str
    operation: str = ""
    path: tuple[str, ...] = ()
    key: str = ""
    type_name: str = ""

    @property
    def polled(self) -> bool:
        """True for an operation's answer polled a few times a second (no port key)."""
        return not self.key

    @property
    def section(self) -> str:
        """The console model's section that keeps its latest value."""
        return f"call:{self.component}.{self.operation}" if self.polled else f"port:{self.key}"


@dataclass(frozen=True)
class TileSpec:
    """One value in the status row (`label`: its caption)."""

    id: str
    label: str
    source: Source
    unit: str = ""
    scale: float = 1.0
    digits: int = 3


@dataclass(frozen=True)
class PlotSpec:
    """A rolling plot of a port's numeric field (a list gives one line per element)."""

    id: str
    label: str
    source: Source
    unit: str = ""
    scale: float = 1.0
    seconds: float = 20.0


@dataclass(frozen=True)
class ButtonSpec:
    """A button that offers `event` (with a fixed `payload`) to the chart; `confirm`:
    armed by a first click, sent by a second (a RELEASE)."""

    id: str
    event: str
    label: str
    payload: dict[str, Any] = field(default_factory=dict)
    confirm: bool = False
    style: str = "normal"


@dataclass
class ConsoleSpec:
    """The whole `console:` section (defaults: no panel, tile or plot; `buttons` None:
    one per external event)."""

    panels: list[str] = field(default_factory=list)
    tiles: list[TileSpec] = field(default_factory=list)
    plots: list[PlotSpec] = field(default_factory=list)
    buttons: list[ButtonSpec] | None = None

    def all_buttons(self, external_events: list[str], with_payload: set[str]) -> list[ButtonSpec]:
        """The declared buttons, or else one per external event that carries no payload
        (`with_payload`: the events whose payload a form asks for instead)."""
        if self.buttons is not None:
            return list(self.buttons)
        return [
            ButtonSpec(id=slug(event), event=event, label=event.removeprefix("e_"))
            for event in external_events
            if event not in with_payload
        ]


def slug(text: str) -> str:
    """An HTML id from a label: 'Go to target' -> 'go-to-target'."""
    return re.sub(r"[^a-z0-9]+", "-", text.lower()).strip("-") or "x"


def installed_panels() -> dict[str, str]:
    """Panel name -> where it comes from, for every installed `fw.console` plugin
    (read from the package metadata: nothing is imported)."""
    from importlib import metadata

    return {e.name: e.value for e in metadata.entry_points(group=PANELS_GROUP)}


def parse_console(data: dict[str, Any] | None, topo: Any, loader: Any) -> ConsoleSpec:
    """The `console:` section of a topology whose components are loaded; each mistake
    (unknown component, port, panel or event; an id used twice) is a finding of
    `loader` at its place in the file."""
    spec = ConsoleSpec()
    if not data:
        return spec
    here = ("console",)
    panels = installed_panels()
    for i, name in enumerate(data.get("panels") or []):
        if name not in panels:
            loader.error(
                "console-panel",
                f"no console panel {name!r} is installed",
                (*here, "panels", i),
                loader.close(name, panels) if panels else "no package installs one",
            )
        spec.panels.append(name)
    ids: set[str] = set()

    def unique(kind: str, wanted: str, where: tuple[Any, ...]) -> str:
        if wanted in ids:
            loader.error("console-id", f"{kind} id {wanted!r} is used twice", where)
        ids.add(wanted)
        return wanted

    def source(item: dict[str, Any], where: tuple[Any, ...]) -> Source | None:
        if "call" in item:
            component, operation, *path = item["call"].split(".")
            comp = topo.components.get(component)
            if comp is None:
                loader.error(
                    "unknown-component",
                    f"unknown component {component!r}",
                    (*where, "call"),
                    loader.close(component, topo.components),
                )
                return None
            if comp.info is None:
                return Source(component=component, operation=operation, path=tuple(path))
            if operation not in comp.info.operations:
                loader.error(
                    "unknown-operation",
                    f"{component!r} has no operation {operation!r}",
                    (*where, "call"),
                    loader.close(operation, comp.info.operations),
                )
                return None
            if operation not in comp.info.readonly:
                loader.error(
                    "console-call",
                    f"{component}.{operation} changes state, so the console may not poll it",
                    (*where, "call"),
                    "poll an operation declared @operation(readonly=True)",
                )
                return None
            return Source(component=component, operation=operation, path=tuple(path))
        component, port, *path = item["port"].split(".")
        spec = topo.components.get(component)
        if spec is not None and spec.info is None and not loader.classes:
            # a client's view: the type is asked of the running component
            return Source(component=component, path=tuple(path), key=spec.output_key(port))
        comp, _, type_name = loader.port(topo, f"{component}.{port}", (*where, "port"), "out")
        if comp is None:
            return None
        return Source(
            component=component,
            path=tuple(path),
            key=topo.key_of(f"{component}.{port}"),
            type_name=type_name,
        )

    for i, item in enumerate(data.get("tiles") or []):
        where = (*here, "tiles", i)
        found = source(item, where)
        if found is not None:
            spec.tiles.append(
                TileSpec(
                    id=unique("tile", item.get("id") or slug(item["label"]), where),
                    label=item["label"],
                    source=found,
                    unit=item.get("unit", ""),
                    scale=float(item.get("scale", 1.0)),
                    digits=int(item.get("digits", 3)),
                )
            )
    for i, item in enumerate(data.get("plots") or []):
        where = (*here, "plots", i)
        found = source(item, where)
        if found is not None:
            spec.plots.append(
                PlotSpec(
                    id=unique("plot", item.get("id") or slug(item["label"]), where),
                    label=item["label"],
                    source=found,
                    unit=item.get("unit", ""),
                    scale=float(item.get("scale", 1.0)),
                    seconds=float(item.get("seconds", 20.0)),
                )
            )
    if "buttons" in data:
        spec.buttons = []
        for i, item in enumerate(data["buttons"] or []):
            where = (*here, "buttons", i)
            event = item["event"]
            if event not in topo.external_events:
                loader.error(
                    "console-button",
                    f"a button sends {event!r}, which is not one of the topology's external_events",
                    (*where, "event"),
                    loader.close(event, topo.external_events)
                    if topo.external_events
                    else "list it under external_events",
                )
            label = item.get("label") or event.removeprefix("e_")
            spec.buttons.append(
                ButtonSpec(
                    id=unique("button", item.get("id") or slug(label), where),
                    event=event,
                    label=label,
                    payload=dict(item.get("payload") or {}),
                    confirm=bool(item.get("confirm", False)),
                    style=item.get("style", "normal"),
                )
            )
    return spec
