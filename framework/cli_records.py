"""`fw log` and `fw replay`: read a flight recording back, as a timeline or through
the chart again."""

from __future__ import annotations

import argparse
import json
from typing import Any

from framework.errors import FwError
from framework.timeline import line


def cmd_log(args: argparse.Namespace) -> int:
    """Print the timeline of a flight recording."""
    from framework.recorder import read_recording

    records = [r for r in read_recording(args.file) if r[0].startswith(args.topic or "")]
    # the chart records each request it makes, and the Configurator the same request with
    # its id: in text, one line per request (--json keeps both records)
    requested = {d.get("request_id") for t, _, d in records if t == "/fw/config/request"}
    t0 = None
    for topic, stamp, data in records:
        if (
            not args.json
            and topic == "/fw/chart"
            and data.get("kind") == "request"
            and (data.get("payload") or {}).get("request_id") in requested
        ):
            continue
        if (
            not args.json
            and topic == "/fw/components"
            and data.get("old") == data.get("new")
            and not data.get("reason")
        ):
            continue  # nothing changed and nothing was said: not a line of the timeline
        t0 = stamp if t0 is None else t0
        if args.json:
            print(json.dumps({"t": stamp, "topic": topic, "data": data}))
        else:
            print(f"[{stamp - t0:9.3f}] {line(topic, data)}")
    return 0


def recorded_events(path: str) -> list[tuple[float, str, dict[str, Any] | None]]:
    """(time from the start, event, payload) of every external chart event recorded."""
    from framework.recorder import read_recording

    out: list[tuple[float, str, dict[str, Any] | None]] = []
    t0 = None
    for topic, stamp, data in read_recording(path):
        t0 = stamp if t0 is None else t0
        if topic == "/fw/chart" and data.get("kind") == "event":
            payload = data.get("payload") or {}
            if payload.get("kind") == "external":
                out.append((stamp - t0, payload["event"], payload.get("payload")))
    return out


def cmd_replay(args: argparse.Namespace) -> int:
    """Feed a recording's chart events back into the chart on a simulated clock."""
    from framework.clock import SimulatedClock
    from framework.recorder import recording_metadata
    from framework.statechart.interpreter import Interpreter
    from framework.statechart.loader import load_statechart
    from framework.statechart.trace import TracePrinter

    chart_path = args.chart or recording_metadata(args.file).get("statechart")
    if not chart_path:
        raise FwError("the recording does not name its statechart; pass --chart FILE")
    chart = load_statechart(chart_path)
    clock = SimulatedClock()
    interpreter = Interpreter(chart, clock, [TracePrinter(clock, False)])
    interpreter.start()
    for at, name, payload in recorded_events(args.file):
        interpreter.advance_to(max(at, clock.now()))
        interpreter.queue(name, payload)
        interpreter.run()
    print(
        f"active: {', '.join(interpreter.leaves)}"
        + ("  [finished]" if interpreter.finished else "")
    )
    return 0


def add_commands(sub: Any) -> None:
    """Register the commands that read flight recordings."""
    raw = argparse.RawDescriptionHelpFormatter
    p = sub.add_parser(
        "log",
        help="print the timeline of a flight recording",
        description="One line per recorded chart step, configuration request and "
        "acknowledgement, component state change, refusal and deployer event (plus the "
        "port samples `fw deploy --record-samples` asked for), timed from the first.",
        epilog="examples:\n  fw log run.mcap                        (from fw deploy ... --record run.mcap)\n"
        "  fw log run.mcap --topic /fw/config     only the configurations\n"
        "  fw log run.mcap --json | jq .topic     one JSON object per line",
        formatter_class=raw,
    )
    p.add_argument("file", metavar="FILE")
    p.add_argument("--topic", help="only topics starting with this (e.g. /fw/config)")
    p.add_argument("--json", action="store_true", help="one JSON object per line")
    p.set_defaults(func=cmd_log)

    p = sub.add_parser(
        "replay",
        help="feed a flight recording's events back into the chart",
        description="Step the recorded chart (or --chart, e.g. a fixed version) through "
        "the external events of a recording, at their recorded times, on a simulated "
        "clock; prints the trace and the states it ends in.",
        epilog="examples:\n  fw replay run.mcap\n"
        "  fw replay run.mcap --chart statecharts/seeg.yaml     the same run, today's chart",
        formatter_class=raw,
    )
    p.add_argument("file", metavar="FILE")
    p.add_argument("--chart", metavar="C", help="statechart (default: the recorded one)")
    p.set_defaults(func=cmd_replay)
