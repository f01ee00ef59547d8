"""The console's essentials as text, for a terminal (`fw status --watch`, over SSH)."""

from __future__ import annotations

from typing import Any

LOG_LINES = 8


def robot_line(report: dict[str, Any]) -> str:
    """The robot side in one line, from the `report` of the component that hosts the
    safety monitor (its contract: `braked`, `latched`, `reason`, `problems`): released,
    braked (why), or a latched safety stop and whether a RELEASE would be taken now
    (every safety input healthy). The terminal's live screen and the console say the
    same words."""
    if not report:
        return "-"
    if report.get("latched"):
        problems = report.get("problems") or []
        release = "RELEASE possible" if not problems else "not yet: " + "; ".join(problems[:2])
        return f"SAFETY STOP: {report.get('reason')} ({release})"
    if report.get("braked"):
        return f"braked ({report.get('reason') or 'power on'})"
    return "released"


def render_text(snapshot: dict[str, Any], width: int = 78) -> str:
    """One screen: the tiles, the chart, what the operator can send, an alert, the
    components and the recent log."""
    chart = ((snapshot.get("chart") or {}).get("data")) or {}
    takeable = ((snapshot.get("takeable") or {}).get("data")) or []
    lines = [f"fw {snapshot['topology']}".ljust(width), ""]
    tiles = snapshot.get("tiles") or []
    if tiles:
        column = min(max(len(t["label"]) for t in tiles), 32) + 2
        for tile in tiles:
            text = tile["text"] + ("  (stale)" if tile.get("stale") else "")
            lines.append(f"{tile['label'][:32]:<{column}} {text}"[:width])
        lines.append("")
    lines += [
        "chart      " + ", ".join(p.rsplit(".", 1)[-1] for p in chart.get("active", [])),
        "can send   " + (", ".join(takeable) or "-"),
    ]
    alert = snapshot.get("alert")
    if alert:
        lines.append(f"{alert['title'].upper()}: {alert['text']}")
    health = ((snapshot.get("health") or {}).get("data")) or {}
    if health:
        lines.append("")
        for name, h in health.items():
            state = (h.get("state") or "?") if h.get("alive") else "LOST"
            lines.append(f"  {name:<20} {h.get('process', ''):<16} {state}")
    log = [entry for entry in snapshot.get("log", []) if entry["severity"] != "debug"]
    if log:
        lines.append("")
        lines += [f"  [{e['severity']}] {e['text']}"[:width] for e in log[-LOG_LINES:]]
    return "\n".join(lines)
