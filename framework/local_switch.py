"""Local switches: a process rewires its own prepared ports the moment the chart asks.

A configuration that begins by switching input ports of one process between keys
those ports keep standby subscriptions to (`prepare:`, a tracker swap) needs no
round trip through the Configurator: the process hears the Coordinator's request
itself and makes those first steps at once, in the network thread that delivered
the request, then says what it did on `fw/config/switched/<process>`. The
Configurator waits for that report, records the switch as its own steps (undone
like them if a later step fails) and applies the rest of the configuration; the
chart's `config.done` still comes from its ack. So the chart keeps the decision,
the swap costs one hop (Coordinator -> this process), and the flight recording has
the request, the switch and the ack.

Only a request marked `alone` (nothing else the Coordinator asked for is still
being applied) is switched here: configurations never overtake each other. The
bus's access rules let only `control` publish requests (framework/access.py).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

from framework import keys, messages
from framework.bus import Bus
from framework.clock import late
from framework.clock_offset import UNMEASURED
from framework.errors import FwError
from framework.messages import ConfigAck, ConfigRequest
from framework.ports import InputPort, OutputPort, PortError
from framework.topology.model import StepKind

if TYPE_CHECKING:
    from framework.topology import Step, Topology

log = logging.getLogger("fw.local_switch")

PortLookup = Callable[[str, str], "InputPort[Any] | OutputPort[Any]"]
"""(component, port) -> that port of a component of this process; `KeyError` if there
is no such component (`Container.find_port`). All the switches know of their process."""


def switch_spec(topology: Topology, process: str) -> dict[str, list[dict[str, Any]]]:
    """Configuration tag -> the steps `process` switches by itself (for its container)."""
    out = {}
    for tag in topology.configurations:
        where, steps = topology.local_switch(tag)
        if where == process:
            out[tag] = [_step_spec(step) for step in steps]
    return out


def _step_spec(step: Step) -> dict[str, Any]:
    """The step as its container gets it: the request a container runs for it
    (`Step.request`), with its component and its label for the report."""
    return {**step.request(), "component": step.component, "label": step.describe()}


class LocalSwitches:
    """Applies a container's local switches on the Coordinator's requests."""

    def __init__(
        self,
        bus: Bus,
        process: str,
        find_port: PortLookup,
        switches: dict[str, list[dict[str, Any]]],
        requester_now: Callable[[], float | None] = time.time,
    ):
        self.find_port = find_port
        self.switches = switches
        self.requester_now = requester_now
        """Now on the Coordinator's clock, at the latest (its requests' deadlines use
        it; `Container.requester_now`); None while that clock is not measured."""
        self.done: list[ConfigAck] = []
        """What this process switched, newest last (the last 64)."""
        self._publisher = bus.publisher(keys.config_switched(process), cache=False)
        self._subscriber = bus.subscribe(keys.CONFIG_REQUESTS, self._on_request, history=False)

    def _on_request(self, sample: Any) -> None:
        try:
            request, _, _ = messages.decode(sample.payload.to_bytes(), ConfigRequest)
        except messages.CodecError as exc:
            log.warning("a configuration request that is not one: %s", exc)
            return
        steps = self.switches.get(request.tag)
        if not steps or not request.alone:
            return  # the Configurator applies it
        # never switched late: the deadline is on the Coordinator's clock
        now = self.requester_now() if request.deadline else time.time()
        why = late(request.deadline, now) if now is not None else f"cannot be timed: {UNMEASURED}"
        if why:  # said at once: the request fails now, not when the wait for a report ends
            report = ConfigAck(
                time.time(), request.request_id, False, request.tag, steps[0]["label"], why
            )
        else:
            report = self.apply(request, steps)
        self.done = [*self.done[-63:], report]
        try:
            self._publisher.put(messages.encode(report, ConfigAck))
        except Exception as exc:  # a closing session; the Configurator times out
            log.warning("cannot report the local switch of %s: %s", request.tag, exc)

    def apply(self, request: ConfigRequest, steps: list[dict[str, Any]]) -> ConfigAck:
        """Make `steps` in order; stop at the first that fails and say which and why."""
        for step in steps:
            try:
                self._make(step)
            except (FwError, KeyError) as exc:
                return ConfigAck(
                    time.time(), request.request_id, False, request.tag, step["label"], str(exc)
                )
        return ConfigAck(time.time(), request.request_id, True, request.tag)

    def _make(self, step: dict[str, Any]) -> None:
        port = self.find_port(step["component"], step["target"])
        if not isinstance(port, InputPort):
            raise PortError(f"{port.full_name} is not an input port")
        if step["step"] == StepKind.DISCONNECT:
            port.disconnect()
        elif step["key"] in port.prepared:  # its type was checked when it was prepared
            port.connect(step["key"], step["policy"])
        else:
            raise PortError(f"{port.full_name} has no standby subscription to {step['key']}")

    def close(self) -> None:
        """Stop listening for requests."""
        for declared in (self._subscriber, self._publisher):
            try:
                declared.undeclare()
            except Exception as exc:  # the session may be closed already
                log.debug("undeclare: %s", exc)
