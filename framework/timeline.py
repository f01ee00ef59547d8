"""One line per flight-recording record, as `fw log` prints it and Foxglove's log panel
shows it (framework/scene.py): a chart step, a component's state, a refusal, a
configuration request and its answer."""

from __future__ import annotations

import json
from typing import Any


def line(topic: str, data: dict[str, Any]) -> str:
    """The record `data` of `topic` in words."""
    if topic == "/fw/chart":
        payload = data.get("payload") or {}
        kind = data.get("kind", "")
        if kind == "event":
            extra = f" {json.dumps(payload['payload'])}" if payload.get("payload") else ""
            return f"event      {payload.get('event')}{extra} ({payload.get('kind')})"
        if kind == "transition":
            return f"transition {payload.get('source')} -> {payload.get('target')}"
        if kind == "configuration":
            return "active     " + ", ".join(payload.get("active", []))
        if kind in ("entry", "exit"):
            return f"{kind:<10} {payload.get('state')}"
        return f"{kind:<10} {json.dumps(payload)}"
    if topic == "/fw/components":
        reason = f" ({data['reason']})" if data.get("reason") else ""
        if data.get("old") == data.get("new"):  # a refusal or report, no change of state
            return f"component  {data.get('component')}: still {data.get('new')}{reason}"
        return f"component  {data.get('component')}: {data.get('old')} -> {data.get('new')}{reason}"
    if topic == "/fw/refused":
        times = f" (x{data['count']})" if data.get("count", 1) > 1 else ""
        return f"REFUSED    {data.get('component')}.{data.get('port')}: {data.get('reason')}{times}"
    if topic == "/fw/config/request":
        return f"request    #{data.get('request_id')} {data.get('tag')}"
    if topic == "/fw/config/switched":
        verdict = "ok" if data.get("ok") else f"FAILED at {data.get('step')}: {data.get('reason')}"
        return f"switched   #{data.get('request_id')} {data.get('tag')} in {data.get('process')} {verdict}"
    if topic == "/fw/config/ack":
        verdict = "ok" if data.get("ok") else f"FAILED at {data.get('step')}: {data.get('reason')}"
        return f"ack        #{data.get('request_id')} {data.get('tag')} {verdict}"
    return f"{topic} {json.dumps(data)}"
