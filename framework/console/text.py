"""The console's essentials as text, for a terminal (`fw status --watch`, over SSH)."""

from __future__ import annotations

from typing import Any

LOG_LINES = 8


def render_text(snapshot: dict[str, Any], width: int = 78) -> str:
    """One screen: status, chart, what the operator can send, components, recent log."""
    s = snapshot["status"]
    distance = s.get("min_distance")
    closest = "-" if distance is None else f"{distance * 100:.0f} cm"
    chart = ((snapshot.get("chart") or {}).get("data")) or {}
    takeable = ((snapshot.get("takeable") or {}).get("data")) or []
    lines = [
        f"fw {snapshot['topology']}".ljust(width),
        "",
        f"operation  {s['operation'].upper()}",
        f"area       {s.get('area') or '-'}",
        f"tracker    {s['tracker']}",
        f"robot      {s.get('robot') or '-'}"[:width],
        f"people     {s.get('people_near') if s.get('people_near') is not None else '-'} near,"
        f" closest {closest}",
        "",
        "chart      " + ", ".join(p.rsplit(".", 1)[-1] for p in chart.get("active", [])),
        "can send   " + (", ".join(takeable) or "-"),
    ]
    if s.get("setup_failed"):
        lines.append(f"SETUP FAILED ({s.get('failure') or 'see the log'}): the robot will not move")
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
