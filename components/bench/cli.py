"""`fw bench`: the thesis experiments (3.6.3, chapter 4) on fw's own deployment.

Each experiment returns a row per measured quantity: the thesis's value, fw's, and
their ratio; latencies also as multiples of the Zenoh hop measured in the same run.
The report is written as markdown (`report.md`) and JSON (`summary.json`) in --out.
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

EPILOG = """\
examples:
  fw bench --quick                         every experiment, a few trials each (< 2 min)
  fw bench swap nosensor --out docs/results full runs of two experiments
  fw bench zenoh                           just the inter-process hop baseline

experiments: zenoh, swap, nosensor (more come: repeated swaps, collision, braking,
statechart depth, people, scale). Timestamps: see components/bench/latency.py.
"""


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

    @property
    def ratio(self) -> float | None:
        """fw / thesis (below 1: fw is better for a latency)."""
        return self.fw / self.thesis if self.thesis else None

    @property
    def met(self) -> bool | None:
        """Is the target met (None: no target)?"""
        return None if self.target is None else self.fw <= self.target


def _stats(values: list[float]) -> dict[str, float]:
    ordered = sorted(values)
    q = statistics.quantiles(ordered, n=4) if len(ordered) > 1 else [ordered[0]] * 3
    return {
        "p50": statistics.median(ordered),
        "iqr": q[2] - q[0],
        "p99": ordered[min(len(ordered) - 1, round(0.99 * (len(ordered) - 1)))],
        "max": ordered[-1],
    }


def run_zenoh(quick: bool, context: dict[str, Any]) -> list[Row]:
    """Raw Zenoh inter-process hop (the baseline every latency is compared with)."""
    from components.bench.baseline import zenoh_hop

    hops = zenoh_hop(200 if quick else 2000)
    s = _stats([h * 1e3 for h in hops])
    context["hop_ms"] = s["p50"]
    return [
        Row("zenoh", "hop p50", s["p50"], n=len(hops)),
        Row("zenoh", "hop p99", s["p99"], n=len(hops)),
    ]


def _seeg(context: dict[str, Any]) -> Any:
    if "seeg" not in context:
        from components.bench.seeg_run import SeegRun

        print("deploying topologies/seeg.yaml on a private bus ...", file=sys.stderr)
        context["seeg"] = SeegRun().start()
    return context["seeg"]


def _progress(name: str) -> Callable[[int, int], None]:
    def show(done: int, total: int) -> None:
        print(f"\r{name}: {done}/{total}", end="" if done < total else "\n", file=sys.stderr)

    return show


def run_swap(quick: bool, context: dict[str, Any]) -> list[Row]:
    """Sensor Swap (eq. 3.12, Fig. 4.1): Certus occluded while moving -> Vicra in use."""
    from components.bench import latency

    trials = latency.sensor_swap(_seeg(context), 5 if quick else 50, _progress("swap"))
    ms = [t.latency * 1e3 for t in trials]
    s = _stats(ms)
    context.setdefault("series", {})["swap_ms"] = ms
    age = statistics.median(t.detail["sample_age"] * 1e3 for t in trials)
    return [
        Row("swap", "L p50", s["p50"], thesis=12.5, target=1.0, n=len(ms)),
        Row("swap", "L IQR", s["iqr"], thesis=5.9, n=len(ms)),
        Row("swap", "L p99", s["p99"], target=3.0, n=len(ms)),
        Row("swap", "age of the first Vicra sample p50", age, n=len(ms)),
    ]


def run_nosensor(quick: bool, context: dict[str, Any]) -> list[Row]:
    """No Sensor To Stop (eq. 3.13, Fig. 4.1): the only tracker occluded while moving."""
    from components.bench import latency

    trials = latency.no_sensor_to_stop(_seeg(context), 3 if quick else 50, _progress("nosensor"))
    ms = [t.latency * 1e3 for t in trials]
    s = _stats(ms)
    context.setdefault("series", {})["nosensor_ms"] = ms
    return [
        Row("nosensor", "L p50", s["p50"], thesis=7.3, target=0.5, n=len(ms)),
        Row("nosensor", "L IQR", s["iqr"], thesis=2.2, n=len(ms)),
        Row("nosensor", "L p99", s["p99"], n=len(ms)),
    ]


EXPERIMENTS: dict[str, Callable[[bool, dict[str, Any]], list[Row]]] = {
    "zenoh": run_zenoh,
    "swap": run_swap,
    "nosensor": run_nosensor,
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
        "multi-process SEEG deployment in real time; where each timestamp is taken: "
        "`components/bench/latency.py`.",
        "",
        "| experiment | quantity | thesis | fw | fw/thesis | x Zenoh hop | target | n |",
        "|---|---|---:|---:|---:|---:|---|---:|",
    ]
    for r in rows:
        times_hop = r.fw / hop if hop and r.unit == "ms" and r.experiment != "zenoh" else None
        target = "" if r.target is None else f"<= {r.target:g} {'met' if r.met else 'MISSED'}"
        lines.append(
            f"| {r.experiment} | {r.quantity} ({r.unit}) | {_fmt(r.thesis)} | {_fmt(r.fw)} | "
            f"{_fmt(r.ratio)} | {_fmt(times_hop)} | {target} | {r.n} |"
        )
    return "\n".join(lines) + "\n"


def cmd_bench(args: argparse.Namespace) -> int:
    """Run the chosen experiments and write report.md and summary.json."""
    names = args.names or list(EXPERIMENTS)
    unknown = [n for n in names if n not in EXPERIMENTS]
    if unknown:
        print(
            f"fw: unknown experiment(s) {', '.join(unknown)}: one of {', '.join(EXPERIMENTS)}",
            file=sys.stderr,
        )
        return 2
    if "zenoh" not in names:
        names.insert(0, "zenoh")  # every run carries its own baseline
    context: dict[str, Any] = {}
    rows: list[Row] = []
    try:
        for name in names:
            started = time.monotonic()
            rows += EXPERIMENTS[name](args.quick, context)
            print(f"{name}: done in {time.monotonic() - started:.1f} s", file=sys.stderr)
    finally:
        if "seeg" in context:
            context["seeg"].stop()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    text = report(rows, context, args.quick)
    (out / "report.md").write_text(text, encoding="utf-8")
    summary = {
        "quick": args.quick,
        "rows": [{**asdict(r), "ratio": r.ratio, "met": r.met} for r in rows],
        "series": context.get("series", {}),
    }
    (out / "summary.json").write_text(json.dumps(summary, indent=1), encoding="utf-8")
    print(text)
    print(f"wrote {out / 'report.md'} and {out / 'summary.json'}", file=sys.stderr)
    return 0


def add_commands(sub: Any) -> None:
    """Register `fw bench`."""
    p = sub.add_parser(
        "bench",
        help="reproduce the thesis experiments on the simulated OR (report, JSON)",
        description=__doc__,
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("names", nargs="*", metavar="NAME", help="experiments to run (default: all)")
    p.add_argument("--quick", action="store_true", help="a few trials each: a smoke run")
    p.add_argument("--out", default="out/bench", metavar="DIR", help="report folder")
    p.set_defaults(func=cmd_bench)
