"""What is running on the bus: containers, components, states, ports, connections.

The `fw ls` and `fw status` commands and the console are built on this; it
only asks (containers' and components' queryables) and never changes anything.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from typing import Any

from framework import keys
from framework.bus import Bus
from framework.remote import RemoteComponent, RemoteError


@dataclass
class Connection:
    """One data path: a writer port, the key, a reader port (either may be missing)."""

    key: str
    writers: list[str] = field(default_factory=list)
    readers: list[str] = field(default_factory=list)


@dataclass
class Snapshot:
    """Everything discovered in one pass."""

    containers: dict[str, list[str]]
    components: dict[str, dict[str, Any]]
    connections: list[Connection]
    unreachable: list[str]


def containers(bus: Bus, timeout: float = 3.0) -> dict[str, list[str]]:
    """Container name -> names of the components it hosts. (A query returns as soon as
    every container answered; the timeout only bounds a starved machine.)"""
    out: dict[str, list[str]] = {}
    replies = bus.session.get(keys.container("*"), payload=b'{"op": "list"}', timeout=timeout)
    for reply in replies:
        if reply.ok is None:
            continue
        name = str(reply.ok.key_expr).rsplit("/", 1)[-1]
        out[name] = sorted(json.loads(bytes(reply.ok.payload.to_bytes()))["result"])
    return dict(sorted(out.items()))


def discover(bus: Bus, patience: float = 10.0) -> dict[str, list[str]]:
    """`containers`, asked again until someone answers or `patience` runs out: a session
    that has just joined may not reach every process yet (gossip is still connecting),
    and "nothing is running" must not be concluded from one early, empty answer."""
    deadline = time.monotonic() + patience
    found = containers(bus)
    while not found and time.monotonic() < deadline:
        time.sleep(0.2)
        found = containers(bus)
    return found


def snapshot(bus: Bus, timeout: float = 3.0) -> Snapshot:
    """Discover containers, describe every component and derive the connections."""
    found = discover(bus) if bus.peers() else {}
    described: dict[str, dict[str, Any]] = {}
    unreachable = []
    for names in found.values():
        for name in names:
            try:
                described[name] = RemoteComponent(bus, name, timeout).describe()
            except RemoteError:
                unreachable.append(name)
    by_key: dict[str, Connection] = {}
    for name, info in described.items():
        for port in info["outputs"]:
            for key in port["keys"]:
                by_key.setdefault(key, Connection(key)).writers.append(f"{name}.{port['name']}")
        for port in info["inputs"]:
            if port["key"]:
                by_key.setdefault(port["key"], Connection(port["key"])).readers.append(
                    f"{name}.{port['name']}"
                )
    connections = [by_key[k] for k in sorted(by_key)]
    return Snapshot(found, described, connections, sorted(unreachable))
