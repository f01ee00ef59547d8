"""Console panels: what a procedure's package adds to the generic operator console.

A panel is a class registered under the `fw.console` entry point group (the way pytest
finds its plugins) and named in a topology's `console: panels:`. It may listen to ports
and poll operations through its `PanelHost` (the console's model), put tiles in the status row and an
alert (a dialog) in the picture, and ship scripts the page loads: each script
registers `fwPanels[name] = {init(container), render(state)}` (docs/console.md).
"""

from __future__ import annotations

import difflib
from collections.abc import Callable
from dataclasses import asdict, dataclass
from importlib import metadata
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol

from framework.errors import FwError
from framework.topology.console import PANELS_GROUP

if TYPE_CHECKING:
    from framework.topology import Topology


class PanelHost(Protocol):
    """What a panel may use of the console hosting it (framework/console/model.py's
    `ConsoleModel` is the one fw runs): the topology, its ports and operations, and the
    named sections of the picture the page gets. Its calls are thread-safe; `listen`
    handlers run in the bus's delivery thread and must be quick."""

    topology: Topology

    def listen(self, key: str, kind: type, handler: Callable[[Any], None], size: int) -> None:
        """Call `handler(sample)` for every sample of type `kind` on `key` (a queue of
        `size`)."""

    def poll(self, section: str, component: str, operation: str, **args: Any) -> None:
        """Call `component.operation(**args)` a few times a second into `section`."""

    def set(self, name: str, data: Any) -> None:
        """Put `data` in the picture's section `name`."""

    def get(self, name: str) -> Any:
        """The picture's section `name` as last set (None if never)."""


@dataclass(frozen=True)
class Tile:
    """One value in the status row: `tone` ok / warn / bad colours it, `stale` greys it
    out (its source went silent), `wide` gives it the whole row."""

    id: str
    label: str
    text: str
    tone: str = ""
    stale: bool = False
    wide: bool = False

    def view(self) -> dict[str, Any]:
        """The tile as the page gets it (a JSON object of its fields)."""
        return asdict(self)


class Panel:
    """Base of a console panel (see the module docstring). Subclasses set `name`,
    and `static` with `scripts` if the page needs code of theirs."""

    name: str = ""
    static: Path | None = None
    """The folder the page may fetch the panel's files from (/panels/<name>/<file>)."""
    scripts: tuple[str, ...] = ()
    warnings: tuple[str, ...] = ()
    """Chart events the event log shows as warnings (besides those into the safe state)."""

    def start(self, model: PanelHost) -> None:
        """Subscribe and register polls (`model.listen`, `model.poll`). Called once by
        the console's model as it starts, in the thread that starts it."""

    def tiles(self, view: dict[str, Any]) -> list[Tile]:
        """The panel's tiles for one snapshot (`view`: its sections)."""
        return []

    def alert(self, view: dict[str, Any]) -> dict[str, str] | None:
        """A dialog the operator must see ({'title', 'text'}), or None."""
        return None


def load_panels(names: list[str]) -> list[Panel]:
    """Instances of the named panels; `FwError` naming the installed ones otherwise."""
    installed = {e.name: e for e in metadata.entry_points(group=PANELS_GROUP)}
    panels = []
    for name in names:
        entry = installed.get(name)
        if entry is None:
            close = difflib.get_close_matches(name, list(installed), n=1)
            hint = f"did you mean {close[0]!r}?" if close else f"installed: {sorted(installed)}"
            raise FwError(f"no console panel {name!r} is installed ({hint})")
        try:
            panel = entry.load()()
        except Exception as exc:  # a third party's panel: any import error is said, located
            raise FwError(
                f"console panel {name!r} ({entry.value}) cannot be loaded: "
                f"{type(exc).__name__}: {exc}"
            ) from None
        if not isinstance(panel, Panel):
            raise FwError(f"console panel {name!r} ({entry.value}) is not a Panel")
        panel.name = panel.name or name
        panels.append(panel)
    return panels
