"""Control a component in any process of the deployment, as if it were local.

    robot = RemoteComponent(bus, "robot")
    robot.configure(); robot.start()
    robot.connect("setpoints", "interpolator/setpoints", policy={"type": "data"})
    robot.call("brake", timeout=0.5, hard=True)

Every failure is a `RemoteError` whose message names the component and the
cause: no answer (the process is gone or busy), a refused request (wrong
state, unknown port, bad value), or an operation that raised.
"""

from __future__ import annotations

import json
import time
from typing import Any

from framework import keys
from framework.bus import Bus, BusError
from framework.errors import FwError

ROUTE_RETRY = 0.05
"""s between two asks of a component that is alive but that the bus has no route to yet."""


ALIVE_WAIT = 0.5
"""s at most for the liveliness check. Zenoh answers it from the session's own table
(0.1 ms here, whether or not the token exists), so this bounds only a starved host."""


class RemoteError(FwError):
    """A remote request failed; `kind` is the remote error class name."""

    def __init__(self, message: str, kind: str = ""):
        super().__init__(message)
        self.kind = kind


class RemoteComponent:
    """A handle on a component hosted by some container on the bus."""

    def __init__(self, bus: Bus, name: str, timeout: float = 2.0):
        self.bus, self.name, self.timeout = bus, name, timeout

    def request(
        self, op: str, timeout: float | None = None, deadline: float | None = None, **fields: Any
    ) -> Any:
        """Send one control request and return its result. It carries its deadline (wall
        clock, s: now + timeout unless given): the container refuses it, unrun, if it
        arrives or would start later (a process that was busy or hung). A component
        whose process is alive but that the bus has no route to yet (just after a link
        came back) is asked again until the deadline; one nobody hosts fails at once."""
        wait = self.timeout if timeout is None else timeout
        now = time.time()
        deadline = now + wait if deadline is None else min(deadline, now + wait)
        wait = max(deadline - now, 0.001)
        body = json.dumps({"op": op, **fields, "deadline": deadline}).encode()
        key = keys.control_request(self.name, op, str(fields.get("operation", "")))
        while True:
            asked = time.monotonic()
            replies = self._ask(key, body, wait, op, fields)
            if replies:
                return json.loads(replies[0])["result"]
            what = f"operation {fields['operation']!r}" if op == "call" else f"{op!r}"
            if time.monotonic() - asked >= wait / 2:
                raise RemoteError(
                    f"no answer from component {self.name!r} to {what} within "
                    f"{wait:g} s (is its process running?)",
                    "Timeout",
                )
            # The bus knew nobody to ask. Unless the component is alive (a route not
            # made yet after a link came back, eclipse-zenoh/zenoh#588, #2517), say so.
            wait = deadline - time.time() - ROUTE_RETRY
            if wait <= ROUTE_RETRY or not self._alive(min(wait, ALIVE_WAIT)):
                raise RemoteError(
                    f"no answer from component {self.name!r} to {what}: nothing on the bus "
                    "takes it (is its process running? may this session ask it?)",
                    "Timeout",
                )
            time.sleep(ROUTE_RETRY)

    def _ask(self, key: str, body: bytes, wait: float, op: str, fields: dict[str, Any]) -> list:
        """One query: its replies, or a `RemoteError` for an error reply or a timeout."""
        try:
            return self.bus.query(key, body, wait)
        except BusError as exc:
            try:
                info = json.loads(str(exc))
            except json.JSONDecodeError:
                if "timeout" in str(exc).lower():
                    what = f"operation {fields.get('operation')!r}" if op == "call" else repr(op)
                    raise RemoteError(
                        f"{what} of component {self.name!r} timed out after "
                        f"{wait:g} s (it may still complete)",
                        "Timeout",
                    ) from None
                raise RemoteError(f"{self.name}: {exc}") from None
            raise RemoteError(f"{self.name}: {info['error']}", info.get("kind", "")) from None

    def _alive(self, wait: float) -> bool:
        """Is the component's liveliness token on the bus (its process runs and is linked)?"""
        try:
            return bool(self.bus.alive(keys.alive(self.name), timeout=wait))
        except BusError:
            return False

    def configure(self) -> dict[str, Any]:
        """Remote `configure()`; the result says whether the hook succeeded and why not."""
        return self.request("configure")

    def start(self) -> dict[str, Any]:
        """Remote `start()`."""
        return self.request("start")

    def stop(self) -> dict[str, Any]:
        """Remote `stop()`."""
        return self.request("stop")

    def cleanup(self) -> dict[str, Any]:
        """Remote `cleanup()`."""
        return self.request("cleanup")

    def recover(self) -> dict[str, Any]:
        """Remote `recover()`."""
        return self.request("recover")

    def state(self) -> str:
        """The component's lifecycle state name."""
        return self.request("state")["state"]

    def describe(self) -> dict[str, Any]:
        """Ports, properties, operations, state (see `Component.describe`)."""
        return self.request("describe")

    def connect(self, port: str, key: str, policy: dict[str, Any] | None = None) -> None:
        """Connect one of its ports to a key (input ports: type-checked, optional policy)."""
        self.request("connect", port=port, key=key, policy=policy)

    def prepare(self, port: str, key: str) -> None:
        """Give one of its input ports a standby subscription to `key` (instant switch)."""
        self.request("prepare", port=port, key=key)

    def disconnect(self, port: str, key: str | None = None) -> None:
        """Disconnect one of its ports."""
        self.request("disconnect", port=port, key=key)

    def get(self, prop: str) -> Any:
        """A property value."""
        return self.request("get", property=prop)

    def set(self, prop: str, value: Any) -> Any:
        """Set a property (validated remotely); returns the stored value."""
        return self.request("set", property=prop, value=value)

    def call(self, operation: str, timeout: float | None = None, **args: Any) -> Any:
        """Call an operation with keyword arguments."""
        return self.request("call", timeout=timeout, operation=operation, args=args)
