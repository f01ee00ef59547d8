"""`fw bench`: the thesis experiments (3.6.3, chapter 4) on fw's own deployment.

Each experiment returns a row per measured quantity: the thesis's value, fw's, and
their ratio; latencies also as multiples of the Zenoh hop measured in the same run.
The report is written as markdown (`report.md`), JSON (`summary.json`) and PNG
figures in --out. A full run takes about 6 minutes; where each timestamp is taken
and what every experiment does: docs/bench.md.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any

from fw_bench.experiments import EXPERIMENTS, OPT_IN
from fw_bench.report import ACROSS_PROCESSES, ON_DEPLOYMENT, Row, report
from fw_bench.seeg_run import BenchError

EPILOG = """\
examples:
  fw bench --quick                         every experiment, a few trials each (< 2 min)
  fw bench swap nosensor --out docs/results full runs of two experiments
  fw bench zenoh                           just the inter-process hop baseline
  fw bench cost --load 3                   what the simulated OR costs on a busy host
  fw bench people --suite                  people detection on 40 scenes (MOTA, IDF1)
  fw bench people --suite --variant 7      40 other scenes of the same kinds

experiments:
  zenoh       the raw inter-process Zenoh hop (the baseline of every run that crosses
              processes; the host's speed in every run)
  cost        cores per process braked and moving, the 1 kHz loop's real-time factor
              and cycle intervals (with --load N busy loops on the host)
  swap        Sensor Swap x50 (Fig. 4.1)          nosensor   No Sensor To Stop x50
  collision   Collision Reaction x50 (Fig. 4.5)    repeated   30 x 50 swaps (Fig. 4.3)
  motion      swaps during the approach (Fig. 4.2)
  braking     STOP on the MuJoCo arm at 1-10 cm/s (Fig. 4.6-4.8)
  navigation  the real arm's error on targets on the patient (joints alone, Certus,
              Vicra), a 5 mm head bump, a swap during motion at 7.5 and 10 cm/s;
              with it, bumps: 5 mm head bumps on the deployed system, each tracker
              steering (--quick: 4 each; else 60), false faults and swaps, and a
              real reference-tool slip's detection
  statechart  transition latency vs depth, beside sismic (Fig. 3.8)
  verify      fw verify on SEEG's whole state space with its properties (target 10 s)
  people      Tables 4.1/4.2, Kinect calibration (Fig. 4.4)
  scale       2-16 trackers, 2-8 cameras x 16 people
  chaos       every process x {KILL, STOP 2 s, STOP 0.3 s} while moving: time to the
              first braking cycle and to standstill, motion before RELEASE; exit 1 if
              any case ends unbraked or moves (only when named; --quick: once each,
              about 4 min; default 6 times each); with --hosts, every host of
              seeg_hosts.yaml cut off or lossy instead (network namespaces, root)
  hosts       SEEG on five hosts (network namespaces, root) beside one: hop per link
              bare and with a LAN's delay (--lan-delay), sensor swap and collision
              across hosts with it, bytes and packets per link (only when named)
  ros2        seeg_ros2.yaml seen by an rmw_zenoh peer (zenoh-ros2-sdk) through a
              router: /joint_states rate and content, a ROS pose's way onto fw's bus
              (only when named)
Timestamps: docs/bench.md. Figures (PNG) need matplotlib: pip install -e tools/bench.
"""


def _rounded(value: Any) -> Any:
    """Floats to 6 significant digits (the series are long; noise is far coarser)."""
    if isinstance(value, float):
        return float(f"{value:.6g}")
    if isinstance(value, dict):
        return {k: _rounded(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_rounded(v) for v in value]
    return value


def _compact_json(summary: dict[str, Any]) -> str:
    """The rows one per line (readable diffs), the series compact."""
    rows = ",\n  ".join(json.dumps(_rounded(r)) for r in summary["rows"])
    series = json.dumps(_rounded(summary["series"]), separators=(",", ":"))
    return f'{{"quick": {json.dumps(summary["quick"])},\n "rows": [\n  {rows}\n ],\n "series": {series}}}\n'


def cmd_bench(args: argparse.Namespace) -> int:
    """Run the chosen experiments and write report.md and summary.json."""
    names = args.names or [n for n in EXPERIMENTS if n not in OPT_IN]
    unknown = [n for n in names if n not in EXPERIMENTS]
    if unknown:
        print(
            f"fw: unknown experiment(s) {', '.join(unknown)}: one of {', '.join(EXPERIMENTS)}",
            file=sys.stderr,
        )
        return 2
    # the Zenoh hops only where a figure is read against them (8 s, --quick)
    hops = any(n == "zenoh" or n in ON_DEPLOYMENT or n in ACROSS_PROCESSES for n in names)
    if "zenoh" not in names:
        names.insert(0, "zenoh")  # every run carries its own baseline (the host's speed)
    if "navigation" in names and "bumps" not in names:
        names.append("bumps")  # navigation's head bumps on the deployed system
    # the deployment's experiments first; it is shut down before the compute-only
    # ones, so its load does not disturb them
    names.sort(key=lambda n: (n != "zenoh", n not in ON_DEPLOYMENT, n != "cost"))
    context: dict[str, Any] = {
        "quick": args.quick,
        "repetitions": args.repetitions,
        "chaos_repetitions": args.chaos_repetitions,
        "hosts": args.hosts,
        "lan_delay": args.lan_delay / 1e3,
        "host_faults": args.host_faults,
        "suite": args.suite,
        "variant": args.variant,
        "bus": args.bus,
        "load": args.load,
        "hops": hops,
    }
    rows: list[Row] = []
    try:
        for i, name in enumerate(names):
            started = time.monotonic()
            try:
                rows += EXPERIMENTS[name](args.quick, context)
            except BenchError as exc:  # said, and the other experiments still run
                context.setdefault("failed", []).append(f"{name}: {exc}")
                print(f"{name}: could not run: {exc}", file=sys.stderr)
                continue
            rows += context.pop("extra_rows", [])
            if "seeg" in context and not any(n in ON_DEPLOYMENT for n in names[i + 1 :]):
                context.pop("seeg").stop()
            print(f"{name}: done in {time.monotonic() - started:.1f} s", file=sys.stderr)
    finally:
        if "seeg" in context:
            context["seeg"].stop()
    rows.sort(key=lambda r: r.experiment != "zenoh")  # the baselines first
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    text = report(rows, context, args.quick)
    (out / "report.md").write_text(text, encoding="utf-8")
    summary = {
        "quick": args.quick,
        "rows": [{**asdict(r), "ratio": r.ratio, "met": r.met} for r in rows],
        "series": context.get("series", {}),
    }
    (out / "summary.json").write_text(_compact_json(summary), encoding="utf-8")
    try:
        from fw_bench.figures import draw
    except ImportError:
        print("no figures: matplotlib is missing (pip install -e tools/bench)", file=sys.stderr)
    else:
        for path in draw(summary["series"], out):
            print(f"wrote {path}", file=sys.stderr)
    print(text)
    print(f"wrote {out / 'report.md'} and {out / 'summary.json'}", file=sys.stderr)
    for failure in context.get("failed", []):
        print(f"FAILED {failure}", file=sys.stderr)
    return 1 if context.get("failed") else 0


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
    p.add_argument(
        "--load",
        type=int,
        default=0,
        metavar="N",
        help="`cost`: N busy loops on the host while it measures (a shared machine)",
    )
    p.add_argument("--out", default="out/bench", metavar="DIR", help="report folder")
    p.add_argument(
        "--repetitions",
        type=int,
        default=30,
        metavar="N",
        help="repetitions of 50 swaps in `repeated` (thesis: 30; ~4 s each here)",
    )
    p.add_argument(
        "--chaos-repetitions",
        type=int,
        default=6,
        metavar="N",
        help="times each process x fault case runs in `chaos` (6: 108 faults, ~25 min)",
    )
    p.add_argument(
        "--hosts",
        action="store_true",
        help="`chaos`: instead, every host of topologies/seeg_hosts.yaml (as network "
        "namespaces of this machine; root) x {partition 2 s, 30%% loss, 100 ms delay "
        "(netem, else fw's wire: framework/netns_delay.py)}, --chaos-repetitions times "
        "(~40 s a case)",
    )
    p.add_argument(
        "--lan-delay",
        type=float,
        default=0.2,
        metavar="MS",
        help="`hosts`: delay on what each host on the bridge sends, as a LAN's (ms; 0: "
        "bare links; netem, else fw's wire)",
    )
    p.add_argument(
        "--host-faults",
        nargs="+",
        choices=("partition", "loss", "delay"),
        metavar="KIND",
        help="`chaos --hosts`: only these kinds of link fault (partition, loss, delay)",
    )
    p.add_argument(
        "--suite",
        action="store_true",
        help="`people`: also the 40-scene suite (tools/bench/fw_bench/scenes.py), a row per "
        "scene and the worst, median and best scene (~5 min on 2 cores)",
    )
    p.add_argument(
        "--variant",
        type=int,
        default=0,
        metavar="N",
        help="`people --suite`: 0 plays the documented 40 scenes; any other N draws 40 "
        "other scenes of the same kinds (other seeds, people and cameras), to check "
        "that a result generalises",
    )
    p.add_argument(
        "--bus",
        choices=("mtls", "plain"),
        default="mtls",
        help="the deployment's bus: mutual TLS with access rules, as fw deploy runs it "
        "(default), or plain TCP, to measure what security costs (docs/security.md)",
    )
    p.set_defaults(func=cmd_bench)
