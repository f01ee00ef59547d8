"""What every benchmark in tools/ shares: percentiles and the report it writes."""

from __future__ import annotations

import argparse
import json
import statistics
from pathlib import Path
from typing import Any


def bench_parser(
    doc: str | None, quick: str | None = "fewer samples (a smoke run)"
) -> argparse.ArgumentParser:
    """The command line every benchmark shares: its docstring as help, `--out`, and
    `--quick` unless `quick` is None; scripts add their own options."""
    out = argparse.ArgumentParser(
        description=doc, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    if quick is not None:
        out.add_argument("--quick", action="store_true", help=quick)
    out.add_argument("--out", default="out/bench", help="folder for the .md and .json")
    return out


def percentiles(samples: list[float]) -> dict[str, float]:
    """Count, median and p99 of durations given in seconds, in microseconds."""
    ordered = sorted(samples)
    if not ordered:
        return {"n": 0, "p50_us": float("nan"), "p99_us": float("nan")}
    return {
        "n": len(ordered),
        "p50_us": statistics.median(ordered) * 1e6,
        "p99_us": ordered[min(len(ordered) - 1, int(len(ordered) * 0.99))] * 1e6,
    }


def write_report(
    out_dir: str, name: str, lines: list[str], targets: dict[str, bool], data: dict[str, Any]
) -> str:
    """Add the targets to the markdown lines, print the report and write
    `<out_dir>/<name>.md` and `<name>.json` (data plus targets)."""
    lines = [
        *lines,
        "",
        "Targets:",
        *(f"- [{'x' if ok else ' '}] {t}" for t, ok in targets.items()),
    ]
    report = "\n".join(lines) + "\n"
    print(report)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{name}.md").write_text(report, encoding="utf-8")
    (out / f"{name}.json").write_text(
        json.dumps({**data, "targets": targets}, indent=2, default=float), encoding="utf-8"
    )
    return report
