"""A container that reads from another host whose clock is measured at a given offset,
without that host: what `fw deploy` and `framework/peer_clocks.py` set up on several
hosts, for specs of what a component does with stamps from another host."""

from __future__ import annotations

import time
from typing import Any

from framework.clock_offset import Exchange
from framework.peer_clocks import PeerClocks


def from_host_apart(
    container: Any, host: str, process: str, offset: float | None, keys: tuple[str, ...] = ()
) -> None:
    """`container` reads `keys` from `host` (answered for by `process`), whose clock is
    `offset` s ahead of this one as measured by a 1 ms round trip (None: not measured
    yet)."""
    clocks = PeerClocks(container.bus, {host: process})
    if offset is not None:
        now = time.time()
        clocks.estimates[host].add(Exchange(now - 0.001, now - 0.0005 + offset, now))
    container.clocks = clocks
    container.key_hosts = dict.fromkeys(keys, host)
