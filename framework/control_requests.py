"""What a container does with one control request: a table from the request's `op` to
its handler, run in the network thread that delivered the request.

A request is a JSON object on a component's control key
(`fw/control/<component>/<op>[/<operation>]`, so the bus's access rules judge it by
its key before it arrives). The ops are the component's remote interface: its
lifecycle (`configure`, `start`, `stop`, `cleanup`, `recover`, `state`), its wiring
(`connect`, `disconnect`, `prepare`), its properties (`get`, `set`, `set_many`), its
operations (`call`), `describe`, and the Configurator's two: `step` (one configuration
step, `Step.request()`, its kind one of `StepKind`, handled by `STEP_HANDLERS`) and
`batch` (several requests on one component in one round trip, stopping at the first
that fails). A request carrying a `deadline` (wall clock) that has passed is refused
with `LateRequest`, unrun: never applied late.
"""

from __future__ import annotations

import contextlib
import json
import logging
from collections.abc import Callable
from typing import Any, Protocol

from framework import keys
from framework.activity import Activity
from framework.clock import late
from framework.clock_offset import UNMEASURED
from framework.component import Component
from framework.errors import FwError
from framework.topology.model import StepKind

log = logging.getLogger("fw.container")


class ContainerError(FwError):
    """A container request or specification is wrong."""


class LateRequest(ContainerError):
    """A request whose deadline passed before it could run: refused, never run late."""


class RequestHost(Protocol):
    """What the requests need of the container that hosts the component
    (framework/container.py's `Container`): its wiring calls and the activities."""

    name: str
    activities: dict[str, Activity]

    def connect(
        self, component: str, port: str, key: str, policy: dict[str, Any] | None = None
    ) -> dict[str, Any]:
        """Connect a port of a hosted component to a key (its type checked)."""

    def disconnect(self, component: str, port: str, key: str | None = None) -> dict[str, Any]:
        """Disconnect a port of a hosted component."""

    def prepare(self, component: str, port: str, key: str) -> dict[str, Any]:
        """Give an input port a standby subscription to `key`."""

    def requester_now(self, wait: bool = True) -> float | None:
        """Now on the clock of the host that sets the requests' deadlines, at the latest
        it can read (None: that clock is not measured; `wait`: ask and wait briefly)."""


# lifecycle state -> operations that lead to each target state
LIFECYCLE_PATHS: dict[tuple[str, str], list[str]] = {
    ("PreOperational", "stopped"): ["configure"],
    ("PreOperational", "running"): ["configure", "start"],
    ("Stopped", "running"): ["start"],
    ("Stopped", "preoperational"): ["cleanup"],
    ("Running", "stopped"): ["stop"],
    ("Running", "preoperational"): ["stop", "cleanup"],
    ("RunTimeError", "running"): ["recover"],
    ("RunTimeError", "stopped"): ["stop"],
    ("RunTimeError", "preoperational"): ["stop", "cleanup"],
    ("Exception", "preoperational"): ["recover"],
    ("Exception", "stopped"): ["recover", "configure"],
    ("Exception", "running"): ["recover", "configure", "start"],
}
TARGET_STATES = {"running": "Running", "stopped": "Stopped", "preoperational": "PreOperational"}


def bring(
    component: Component, target: str, check: Callable[[], None] | None = None
) -> dict[str, Any]:
    """Drive a component to `running`, `stopped` or `preoperational` by the shortest
    path of lifecycle operations; ok False with the reason if a hook refuses. `check`
    runs before each operation (a request's deadline) and may raise to stop there."""
    if target not in TARGET_STATES:
        raise ContainerError(f"unknown target state {target!r} (known: {', '.join(TARGET_STATES)})")
    start = component.state.value
    if start == TARGET_STATES[target]:
        return {"ok": True, "state": start, "reason": "", "from": start}
    path = LIFECYCLE_PATHS.get((start, target))
    if path is None:
        return {
            "ok": False,
            "state": start,
            "from": start,
            "reason": f"{component.name!r} is {start}; it cannot be brought to "
            f"{TARGET_STATES[target]}",
        }
    for op in path:
        if check is not None:
            check()
        if not getattr(component, op)():
            return {
                "ok": False,
                "state": component.state.value,
                "from": start,
                "reason": f"{op} failed: {component.last_error or 'its hook returned False'}",
            }
    return {"ok": True, "state": component.state.value, "reason": "", "from": start}


Handler = Callable[["ControlRequests", Component, dict[str, Any], Callable[[], None]], Any]
"""(requests, component, request, check) -> the answer; `check()` raises `LateRequest`
once the request's deadline has passed (a long handler calls it between its parts)."""


def _lifecycle(op: str) -> Handler:
    def run(_: ControlRequests, c: Component, __: dict[str, Any], ___: Callable[[], None]) -> Any:
        ok = getattr(c, op)()
        return {"ok": ok, "state": c.state.value, "reason": c.last_error}

    return run


def _set_property(c: Component, name: str, value: Any) -> dict[str, Any]:
    old = c.get_property(name)
    return {"old": old, "value": c.set_property(name, value)}


STEP_HANDLERS: dict[StepKind, Handler] = {
    StepKind.STATE: lambda _, c, r, check: bring(c, r["target"], check),
    StepKind.CONNECT: lambda h, c, r, _: h.host.connect(
        c.name, r["target"], r["key"], r.get("policy")
    ),
    StepKind.DISCONNECT: lambda h, c, r, _: h.host.disconnect(c.name, r["target"]),
    StepKind.SET: lambda _, c, r, __: _set_property(c, r["target"], r["value"]),
    StepKind.CALL: lambda _, c, r, __: c.invoke(r["target"], r.get("args", {}), r.get("deadline")),
}
"""How a container makes each kind of configuration step (`write` is the
Configurator's own: it writes the sample itself)."""


def _step(h: ControlRequests, c: Component, r: dict[str, Any], check: Callable[[], None]) -> Any:
    try:
        kind = StepKind(r["step"])
    except ValueError:
        raise ContainerError(f"unknown step kind {r['step']!r}") from None
    handler = STEP_HANDLERS.get(kind)
    if handler is None:
        raise ContainerError(f"a {kind} step is not made by a container")
    return handler(h, c, r, check)


def _describe(h: ControlRequests, c: Component, _: dict[str, Any], __: Callable[[], None]) -> Any:
    info = c.describe()
    info["activity"] = h.host.activities[c.name].to_dict()
    info["container"] = h.host.name
    return info


def _set_many(_: ControlRequests, c: Component, r: dict[str, Any], __: Callable[[], None]) -> Any:
    c.set_properties(r["values"])
    return {k: c.get_property(k) for k in r["values"]}


HANDLERS: dict[str, Handler] = {
    **{op: _lifecycle(op) for op in ("configure", "start", "stop", "cleanup", "recover")},
    "state": lambda _, c, __, ___: {"state": c.state.value, "reason": c.last_error},
    "step": _step,
    "batch": lambda h, c, r, _: h.batch(c, r["steps"], r.get("deadline")),
    "describe": _describe,
    "connect": lambda h, c, r, _: h.host.connect(c.name, r["port"], r["key"], r.get("policy")),
    "disconnect": lambda h, c, r, _: h.host.disconnect(c.name, r["port"], r.get("key")),
    "prepare": lambda h, c, r, _: h.host.prepare(c.name, r["port"], r["key"]),
    "get": lambda _, c, r, __: c.get_property(r["property"]),
    "set": lambda _, c, r, __: c.set_property(r["property"], r["value"]),
    "set_many": _set_many,
    "call": lambda _, c, r, __: c.invoke(r["operation"], r.get("args", {}), r.get("deadline")),
}
"""Every op a component's control key answers (see the module docstring)."""


class ControlRequests:
    """Runs the control requests of one container's components (module docstring)."""

    def __init__(self, host: RequestHost):
        self.host = host

    def handle(self, component: Component, request: dict[str, Any]) -> Any:
        """Execute one control request. A request whose `deadline` (wall clock) has
        passed is refused with `LateRequest`, unrun."""
        op = request.get("op")
        deadline = request.get("deadline")

        def check() -> None:
            if not deadline:
                return
            now = self.host.requester_now()  # the deadline is on the requester's clock
            why = late(deadline, now) if now is not None else f"cannot be timed: {UNMEASURED}"
            if why:
                raise LateRequest(f"{component.name}: {op}: {why}")

        check()
        handler = HANDLERS.get(str(op))
        if handler is None:
            raise ContainerError(f"unknown request {op!r}")
        return handler(self, component, request, check)

    def batch(
        self, component: Component, steps: list[dict[str, Any]], deadline: float | None = None
    ) -> dict[str, Any]:
        """Run several requests on one component in one round trip; stop at the first
        failure (a step that would start after the batch's deadline is one, and so is a
        `state` step whose component did not get there) and say which one and why."""
        results: list[Any] = []
        for index, step in enumerate(steps):
            try:
                result = self.handle(component, {**step, "deadline": deadline})
            except (FwError, KeyError, TypeError, ValueError) as exc:
                reason = f"missing field {exc}" if isinstance(exc, KeyError) else str(exc)
                return {"results": results, "failed": index, "error": reason}
            results.append(result)
            if step.get("step") == StepKind.STATE and not result["ok"]:
                return {"results": results, "failed": index, "error": result["reason"]}
        return {"results": results, "failed": None, "error": ""}

    def on_query(self, component: Component, query: Any) -> None:
        """The body of a component's control queryable (in the bus's thread): decode,
        check the key matches the op, run, answer; every failure is the asker's answer,
        never this process's end."""
        try:
            payload = query.payload
            request = json.loads(bytes(payload.to_bytes())) if payload is not None else {}
            if not isinstance(request, dict):
                raise ContainerError("a request must be a JSON object")
            op = str(request.get("op", ""))
            expected = keys.control_request(component.name, op, str(request.get("operation", "")))
            if str(query.key_expr) != expected:  # the access rules judged it by its key
                raise ContainerError(
                    f"a {op!r} request must be sent on {expected}, not {query.key_expr}"
                )
            result = self.handle(component, request)
            query.reply(query.key_expr, json.dumps({"result": result}))
        except (FwError, KeyError, TypeError, ValueError) as exc:
            message = f"missing field {exc}" if isinstance(exc, KeyError) else str(exc)
            with contextlib.suppress(Exception):
                query.reply_err(json.dumps({"error": message, "kind": type(exc).__name__}))
        except Exception as exc:  # nothing crashes the container; logged with its traceback
            log.exception("request to %s failed", component.name)
            with contextlib.suppress(Exception):
                query.reply_err(
                    json.dumps({"error": f"internal error: {exc}", "kind": type(exc).__name__})
                )
