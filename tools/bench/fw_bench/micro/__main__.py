"""`python -m fw_bench.micro NAME [options]`: one micro-benchmark of fw's pieces.

The experiments of `fw bench` measure the deployed system against the thesis; these
measure one piece each on its own (a port hop, a Sensor Manager cycle, a hand-eye
solve, the console's round trip...), the figures the experiments build on. Each prints
median/p99 and writes NAME.md and NAME.json in --out (default out/bench).
"""

from __future__ import annotations

import importlib
import sys

BENCHMARKS = {
    "runtime": "port hops, rewiring, remote calls and liveliness against raw Zenoh",
    "coordination": "event -> configuration request -> the Configurator's ack (toy)",
    "robot": "one simulated-arm cycle and one interpolator cycle",
    "tracking": "the Sensor Manager's cycle, fault detection latency, false alarms",
    "calibration": "hand-eye calibration errors against truth",
    "console": "the console's command round trip and change-to-page latency (toy)",
    "console_load": "the console under hostile load on the SEEG deployment",
}


def main(argv: list[str]) -> int:
    """Run the named micro-benchmark with the rest of the arguments."""
    if not argv or argv[0] in ("-h", "--help") or argv[0] not in BENCHMARKS:
        if argv and argv[0] not in ("-h", "--help"):
            print(f"fw_bench.micro: no benchmark named {argv[0]!r}", file=sys.stderr)
        print(__doc__.split("\n\n")[0].split(": ", 1)[0] + "\n\nbenchmarks:")
        for name, what in BENCHMARKS.items():
            print(f"  {name:<13} {what}")
        print("\n`python -m fw_bench.micro NAME --help` gives its options.")
        return 0 if not argv or argv[0] in ("-h", "--help") else 2
    module = importlib.import_module(f"fw_bench.micro.{argv[0]}")
    sys.argv = [f"python -m fw_bench.micro {argv[0]}", *argv[1:]]
    return int(module.main() or 0)


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
