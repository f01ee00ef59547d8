"""What `fw bench` reports: one row per measured quantity, and the markdown table.

A row holds fw's value beside the thesis' and the target; latencies are also shown
as multiples of the Zenoh hop measured in the same run.
"""

from __future__ import annotations

import platform
import statistics
import time
from dataclasses import dataclass
from typing import Any

ON_DEPLOYMENT = ("cost", "swap", "nosensor", "collision", "repeated", "motion", "ssm", "bumps")
"""Experiments measured on the running SEEG deployment (the others compute offline)."""
ACROSS_PROCESSES = ("chaos", "hosts", "ros2")
"""Experiments besides those on the deployment whose figures cross processes (they
get the Zenoh hop baseline; offline ones get only the host's speed)."""
LATENCIES = ("swap", "nosensor", "collision", "repeated", "motion")
"""Experiments whose times are latencies across processes: also shown as multiples of
the Zenoh hop measured in the same run."""


@dataclass
class Row:
    """One reported quantity."""

    experiment: str
    quantity: str
    fw: float
    thesis: float | None = None
    target: float | None = None
    unit: str = "ms"
    n: int = 0
    at_least: bool = False  # the target is a minimum (a simulation's realism), not a maximum

    @property
    def ratio(self) -> float | None:
        """fw / thesis (below 1: fw is better for a latency)."""
        return self.fw / self.thesis if self.thesis else None

    @property
    def met(self) -> bool | None:
        """Is the target met (None: no target)?"""
        if self.target is None:
            return None
        return self.fw >= self.target if self.at_least else self.fw <= self.target


def stats(values: list[float]) -> dict[str, float]:
    ordered = sorted(values)
    q = statistics.quantiles(ordered, n=4) if len(ordered) > 1 else [ordered[0]] * 3
    return {
        "p50": statistics.median(ordered),
        "iqr": q[2] - q[0],
        "p99": ordered[min(len(ordered) - 1, round(0.99 * (len(ordered) - 1)))],
        "max": ordered[-1],
    }


def _fmt(value: float | None) -> str:
    return "" if value is None else f"{value:.3g}"


def report(rows: list[Row], context: dict[str, Any], quick: bool) -> str:
    """The markdown report: thesis | fw | ratio | x hop | target."""
    hop = context.get("hop_ms")
    lines = [
        "# fw bench" + (" (quick)" if quick else ""),
        "",
        f"{time.strftime('%Y-%m-%d %H:%M')}, {platform.node()}, Python "
        f"{platform.python_version()}, {platform.machine()}. Latencies on the real "
        "multi-process SEEG deployment in real time, on a "
        + (
            "plain TCP bus (no authentication: a comparison run)"
            if context.get("bus") == "plain"
            else "mutual-TLS bus with access rules, as `fw deploy` runs it"
        )
        + "; where each timestamp is taken: `tools/bench/fw_bench/latency.py`.",
        "",
        "| experiment | quantity | thesis | fw | fw/thesis | x Zenoh hop | target | n |",
        "|---|---|---:|---:|---:|---:|---|---:|",
    ]
    for r in rows:
        times_hop = r.fw / hop if hop and r.unit == "ms" and r.experiment in LATENCIES else None
        unit = f" ({r.unit})" if r.unit else ""
        bound = ">=" if r.at_least else "<="
        target = "" if r.target is None else f"{bound} {r.target:g} {'met' if r.met else 'MISSED'}"
        lines.append(
            f"| {r.experiment} | {r.quantity}{unit} | {_fmt(r.thesis)} | {_fmt(r.fw)} | "
            f"{_fmt(r.ratio)} | {_fmt(times_hop)} | {target} | {r.n} |"
        )
    return "\n".join(lines) + "\n"
