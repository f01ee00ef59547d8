"""A container: one process hosting components on the bus, controllable from anywhere.

For every component it hosts, a container declares a liveliness token, a
control queryable (lifecycle, connect/disconnect, properties, operations,
introspection) and publishes every state change. It shuts down in order on
SIGTERM/SIGINT: stop, cleanup, close the Zenoh session (an unclosed session
can hang the process). Processes are started with `spawn_container`, a fresh
interpreter (never fork: Zenoh sessions are not fork-safe): framework/container_main.py
is the process around it. The requests themselves: framework/control_requests.py.
"""

from __future__ import annotations

import contextlib
import json
import logging
import threading
import time
from typing import Any

from framework import keys, messages
from framework.activity import Activity, RealTimeExecutor, SteppedExecutor
from framework.bus import Bus, BusError
from framework.clock_offset import OffsetEstimate
from framework.component import Component, Heartbeat, LifecycleError, Refusal, StateChange
from framework.control_requests import ContainerError, ControlRequests
from framework.errors import FwError
from framework.local_switch import LocalSwitches
from framework.messages import EventMessage, Scalar
from framework.peer_clocks import PeerClocks, answer_clock
from framework.ports import ConnPolicy, InputPort, OutputPort, PortError
from framework.routes import RouteWatch
from framework.safety import ProcessHeartbeat, SafetyMonitor, SafetySpec

log = logging.getLogger("fw.container")

FIRST_CLOCK_WAIT = 2.0
"""How long a request may wait for the first measurement of its requester's clock (s):
a process's first requests come right after it started, while the control host is
busy starting the others; with 0.5 s one deployment of 14 on five hosts failed its
setup ("stamped by a host whose clock offset is not measured yet"). Well inside a
configuration step's 5 s."""


class Container:
    """Hosts components in this process and serves their remote interface."""

    def __init__(
        self,
        name: str,
        bus: Bus,
        executor: RealTimeExecutor | SteppedExecutor | None = None,
        beat: float | None = None,
    ):
        """With `beat` (s), the process proves it is scheduled on its heartbeat key (the
        safety monitor's hang detection, see framework/safety.py)."""
        self.name = name
        self.bus = bus
        self.executor = executor or RealTimeExecutor()
        self.beat = ProcessHeartbeat(bus, name, beat) if beat else None
        self.components: dict[str, Component] = {}
        self.activities: dict[str, Activity] = {}
        self._declared: list[Any] = []
        self._type_queryables: dict[str, Any] = {}
        self._key_types: dict[str, str] = {}
        self._state_publishers: dict[str, Any] = {}
        self._refusal_publishers: dict[str, Any] = {}
        self._lock = threading.RLock()
        self._closed = False
        self.requests = ControlRequests(self)
        """Runs the control requests of the hosted components (framework/control_requests.py)."""
        self._declared.append(bus.queryable(keys.container(name), self._on_container_query))
        self._declared.append(answer_clock(bus, name))
        self.clocks: PeerClocks | None = None
        """Other hosts' clocks, measured (set by `build` from the topology's hosts)."""
        self.key_hosts: dict[str, str] = {}
        """Which other host writes each key this process may read (`build`)."""
        self.requester_host: str | None = None
        """The host of the Configurator and the Coordinator when it is another one (its
        clock is among `clocks`): the host whose clock their requests' deadlines use."""
        self.local_switches: LocalSwitches | None = None
        """Configurations whose first steps this process switches itself (see
        framework/local_switch.py); set by `build` from the topology."""
        self.routes: RouteWatch | None = None
        """Finds routes the bus lost after a partition and reopens it (framework/routes.py);
        started by `build` in every process but the hub."""

    # -- hosting -------------------------------------------------------------------
    def add(
        self,
        component: Component,
        activity: Activity | None = None,
        properties: dict[str, Any] | None = None,
        outputs: dict[str, str] | None = None,
        heartbeat: float | None = None,
        safety: SafetySpec | None = None,
    ) -> Component:
        """Host a component: attach its ports, publish outputs on their default keys,
        declare its control queryable and liveliness token; with `heartbeat` (s), it
        proves it runs on its heartbeat key; with `safety`, it hosts the safety monitor."""
        name = component.name
        if name in self.components:
            raise ContainerError(f"container {self.name!r} already hosts {name!r}")
        activity = activity or Activity()
        if properties:
            component.set_properties(properties)
        with contextlib.suppress(FwError):  # a file that cannot be read fails configure
            component.file_ports()  # wired like the class's own inputs
        activity.check(component)
        component.bus = self.bus
        component.clock = self.executor.clock
        component.peer_clocks = self.peer_clock
        if heartbeat:
            port: OutputPort[Any] = OutputPort("heartbeat", Scalar, "proof of life")
            port.owner, port.bus = name, self.bus
            port.connect(keys.heartbeat(name))
            component.heartbeat = Heartbeat(port, heartbeat, component.clock)
        if safety is not None:
            if not component.hosts_safety_monitor:
                raise ContainerError(
                    f"{name} ({type(component).__name__}) cannot host the safety monitor"
                )
            # checked by the component's own cycle, which takes the arrivals itself
            component.safety = SafetyMonitor(safety, component.clock, self.name).attach(
                self.bus, name, polled=True
            )
        for port in (*component.inputs.values(), *component.outputs.values()):
            port.bus = self.bus
        for port in component.outputs.values():
            key = (outputs or {}).get(port.name, keys.default_output(name, port.name))
            self._connect_output(component, port.name, key)
        publisher = self.bus.publisher(keys.state(name))
        self._state_publishers[name] = publisher
        component.add_state_listener(self._publish_state)
        self._refusal_publishers[name] = self.bus.publisher(keys.refused(name))
        component.add_refusal_listener(self._publish_refusal)
        self.components[name] = component
        self.activities[name] = activity
        self.executor.add(component, activity)
        self._declared.append(
            self.bus.queryable(
                f"{keys.control(name)}/**", lambda q, c=component: self.requests.on_query(c, q)
            )
        )
        self._declared.append(self.bus.token(keys.alive(name)))
        self._publish_state(StateChange(name, component.state, component.state, "", time.time()))
        return component

    def start(self) -> None:
        """Start the executor (components still need configure/start) and the beat: in
        a process with a real-time loop, beaten by that loop between its cycles (no
        other thread of ordinary priority to hold the interpreter it waits for)."""
        driven = self.beat is not None and getattr(self.executor, "has_loop", lambda: False)()
        if driven:
            self.executor.between_cycles.append(self.beat.poll)
        self.executor.start()
        if self.beat is not None:
            self.beat.start(driven=driven)

    def _publish_state(self, change: StateChange) -> None:
        payload = {"old": change.old.value, "new": change.new.value, "reason": change.reason}
        self._announce(self._state_publishers, change.component, "state", payload, change.stamp)

    def _publish_refusal(self, refusal: Refusal) -> None:
        payload = {"port": refusal.port, "reason": refusal.reason, "count": refusal.count}
        self._announce(
            self._refusal_publishers, refusal.component, "refused", payload, refusal.stamp
        )

    def _announce(
        self, publishers: dict[str, Any], component: str, kind: str, payload: Any, stamp: float
    ) -> None:
        """Publish what a component says of itself (never raises: a closing bus)."""
        publisher = publishers.get(component)
        if publisher is None or self.bus.closed:
            return
        with contextlib.suppress(Exception):
            publisher.put(
                messages.encode(EventMessage(stamp, kind, component, payload), EventMessage)
            )

    # -- connections ---------------------------------------------------------------
    def connect_output(self, component: str, port: str, key: str, rate: float = 0.0) -> None:
        """Publish an output port of a hosted component on `key` too, thinned to `rate`
        Hz if given (a connection's `rate:`)."""
        comp = self._component(component)
        if port not in comp.outputs:
            raise PortError(f"{component} has no output port {port!r}")
        self._connect_output(comp, port, key, rate)

    def _connect_output(
        self, component: Component, port_name: str, key: str, rate: float = 0.0
    ) -> None:
        port = component.outputs[port_name]
        port.connect(key, rate)
        if key not in self._type_queryables:
            kind = port.type_name
            writer = port.full_name

            def answer(query: Any, kind: str = kind, writer: str = writer) -> None:
                query.reply(query.key_expr, json.dumps({"type": kind, "writer": writer}))

            self._type_queryables[key] = self.bus.queryable(keys.port_type(key), answer)

    def connect(
        self, component: str, port: str, key: str, policy: dict[str, Any] | None = None
    ) -> dict[str, Any]:
        """Connect a port of a hosted component to a key (checking the key's type)."""
        comp = self._component(component)
        if comp.file_error and port not in comp.inputs and port not in comp.outputs:
            # a port its unreadable file would declare: wired when configure reads it
            comp.await_connection(port, key, ConnPolicy.from_spec(policy) if policy else None)
            return {"port": f"{component}.{port}", "key": key, "awaiting": comp.file_error}
        target = comp.port(port)
        if isinstance(target, InputPort):
            self._check_type(target, key)
            target.connect(key, ConnPolicy.from_spec(policy) if policy else None)
        else:
            if policy:
                raise PortError(
                    f"{target.full_name} is an output port: a policy belongs to the input side"
                )
            self._connect_output(comp, port, key)
        return {"port": target.full_name, "key": key}

    def _check_type(self, port: InputPort[Any], key: str) -> None:
        """Refuse a key whose writers carry another type. The answer is cached per key
        (a key's type does not change while its writers live), so switching between
        keys already checked costs no network round trip."""
        if self._key_types.get(key) == port.type_name:
            return
        try:
            replies = self.bus.query(keys.port_type(key), timeout=0.5)
        except BusError:
            return  # nobody writes the key yet: samples are type-checked on arrival
        for raw in replies:
            info = json.loads(raw)
            if info["type"] != port.type_name:
                raise PortError(
                    f"cannot connect {port.full_name} ({port.type_name}) to key "
                    f"{key!r}: it carries {info['type']} (written by "
                    f"{info['writer']})"
                )
        if replies:
            self._key_types[key] = port.type_name

    def prepare(self, component: str, port: str, key: str) -> dict[str, Any]:
        """Give an input port a standby subscription to `key` (instant later switch)."""
        target = self._component(component).port(port)
        if not isinstance(target, InputPort):
            raise PortError(f"{target.full_name} is an output port: only inputs can prepare")
        self._check_type(target, key)
        target.prepare(key)
        return {"port": target.full_name, "prepared": target.prepared}

    def disconnect(self, component: str, port: str, key: str | None = None) -> dict[str, Any]:
        """Disconnect a port (an output port from `key`, or from every key)."""
        target = self._component(component).port(port)
        if isinstance(target, InputPort):
            target.disconnect()
        else:
            target.disconnect(key)
        return {"port": target.full_name}

    def find_port(self, component: str, port: str) -> InputPort[Any] | OutputPort[Any]:
        """A port of a component of this process (`ContainerError` if there is no such
        component, `PortError` if it has no such port): what the local switches need."""
        return self._component(component).port(port)

    def _component(self, name: str) -> Component:
        component = self.components.get(name)
        if component is None:
            known = ", ".join(sorted(self.components)) or "none"
            raise ContainerError(
                f"container {self.name!r} has no component {name!r} (hosted: {known})"
            )
        return component

    # -- the container's own query -----------------------------------------------
    def requester_now(self, wait: bool = True) -> float | None:
        """Now on the requester's clock (`requester_host`), at the latest it can read:
        a request's deadline judged by it is never found later than it is. This host's
        clock when the requester runs here; None when its host is not measured (with
        `wait`, asked at once and waited for, briefly: its first requests come right
        after start; without, for a caller in the bus's thread)."""
        now = time.time()
        if self.requester_host is None or self.clocks is None:
            return now
        estimate = self.clocks.of(self.requester_host)
        if estimate is None:
            return now
        if wait and not estimate.measured:
            self.clocks.wait_measured(self.requester_host, FIRST_CLOCK_WAIT)
        return estimate.peer_now(time.time())

    def holds_bus(self) -> str:
        """Why this process must not reopen its bus now ('' if it may): the first of
        its components that says why (`Component.holds_bus`). Runs in the route
        watch's thread."""
        for name, component in list(self.components.items()):
            try:
                why = component.holds_bus()
            except Exception as exc:  # a component's own code: it cannot stop the probes
                log.warning("%s: holds_bus raised %s: %s", name, type(exc).__name__, exc)
                continue
            if why:
                return f"{name}: {why}"
        return ""

    def peer_clock(self, key: str | None) -> OffsetEstimate | None:
        """The measured offset of the host that writes `key`, if another host does."""
        host = self.key_hosts.get(key) if key is not None else None
        if host is None or self.clocks is None:
            return None
        return self.clocks.of(host)

    def _on_container_query(self, query: Any) -> None:
        try:
            body = bytes(query.payload.to_bytes()) if query.payload is not None else b"{}"
            op = json.loads(body or b"{}").get("op", "list")
            if op == "list":
                result: Any = {n: c.state.value for n, c in self.components.items()}
            else:  # a container is stopped by its deployer's signal, never by a request
                raise ContainerError(f"unknown container request {op!r}")
            query.reply(keys.container(self.name), json.dumps({"result": result}))
        except Exception as exc:  # any failure is the asker's answer, never this process's end
            with contextlib.suppress(Exception):
                query.reply_err(json.dumps({"error": str(exc), "kind": type(exc).__name__}))

    # -- shutdown --------------------------------------------------------------------
    def shutdown(self) -> None:
        """Stop and clean up every component, undeclare everything, close the bus."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
        if self.beat is not None:
            self.beat.stop()
        if self.clocks is not None:
            self.clocks.stop()
        if self.routes is not None:
            self.routes.stop()
        if self.local_switches is not None:
            self.local_switches.close()
        for component in reversed(list(self.components.values())):
            with contextlib.suppress(LifecycleError):
                component.stop()
            with contextlib.suppress(LifecycleError):
                component.cleanup()
        self.executor.stop()
        for component in self.components.values():
            for port in component.inputs.values():
                with contextlib.suppress(Exception):
                    port.close()
            for port in component.outputs.values():
                with contextlib.suppress(Exception):
                    port.disconnect()
            if component.heartbeat is not None:
                with contextlib.suppress(Exception):
                    component.heartbeat.port.disconnect()
            if component.safety is not None:
                with contextlib.suppress(Exception):
                    component.safety.close()
        for entity in [
            *self._declared,
            *self._type_queryables.values(),
            *self._state_publishers.values(),
        ]:
            with contextlib.suppress(Exception):
                entity.undeclare()
        self.bus.close()
