#!/usr/bin/env python3
"""Benchmark the Sensor Manager (a benchmark, not a test).

* cycle time (taking every new sample + evaluating) with 2, 8 and 16 sensors, every
  sensor delivering a new frame in every cycle (the worst case; target p99 <= 100 us
  at 16 sensors);
* detection latency per fault cause, in the faulty sensor's sample periods
  (target <= 2), on a simulated clock;
* false alarms over one simulated hour of nominal noisy tracking (target 0).

    python -m fw_bench.micro tracking [--quick] [--out out/bench]
"""

from __future__ import annotations

import dataclasses
import math
import os
import platform
import statistics
import sys
import time

import numpy as np

from components.domain.geometry import rigid
from components.domain.rigs import ee_path, sensors_config, standard_rigs
from components.tracking.sensor_manager import SensorManagerCore
from fw_bench.micro.lib import bench_parser, write_report
from fw_bench.scale import cycle_times

TICK = 0.001


def detection_latency(cause: str, trials: int) -> list[float]:
    """Periods of the faulty sensor between the fault and its detection."""
    out = []
    for trial in range(trials):
        rigs = standard_rigs()
        core = SensorManagerCore(sensors_config(rigs, 3))
        rng = np.random.default_rng(trial)
        frames = {r.name: 0 for r in rigs}
        fault_at, detected = 0.3 + trial * 0.0013, None
        t = 0.0
        while t < 1.0 and detected is None:
            t += TICK
            truth = ee_path(t)
            core.set_kinematics(truth)
            for rig in rigs:
                frame = int(t * rig.rate + 1e-9)
                if frame == frames[rig.name]:
                    continue
                frames[rig.name] = frame
                faulty = rig.name == "certus" and t >= fault_at
                if faulty and cause == "stale":
                    continue
                cto, rto = rig.observe(truth, rng, t)
                if faulty and cause == "cto_missing":
                    cto = dataclasses.replace(cto, valid=False)
                if faulty and cause == "corrupt":
                    cto = dataclasses.replace(cto, position=(math.nan, 0.0, 0.0))
                if faulty and cause == "calibration":
                    bumped = dataclasses.replace(
                        rig, sensor_from_rto=rig.sensor_from_rto @ rigid((0.01, 0, 0), (0, 0, 0))
                    )
                    _, rto = bumped.observe(truth, rng, t)
                core.offer(rig.name, "cto", cto, t)
                core.offer(rig.name, "rto", rto, t)
            decision = core.evaluate(t)
            if t >= fault_at and decision.health["certus"].cause == cause:
                detected = t
        if detected is not None:
            out.append((detected - fault_at) * 100.0)  # Certus periods (100 Hz)
    return out


def false_alarms(seconds: float) -> tuple[int, int]:
    """(false alarms, cycles) over `seconds` of nominal tracking at 1 kHz."""
    rigs = standard_rigs()
    core = SensorManagerCore(sensors_config(rigs, 3))
    rng = np.random.default_rng(42)
    frames = {r.name: 0 for r in rigs}
    alarms, cycles, t = 0, 0, 0.0
    steps = round(seconds / TICK)
    for k in range(1, steps + 1):
        t = k * TICK
        truth = ee_path(t)
        core.set_kinematics(truth)
        for rig in rigs:
            frame = int(t * rig.rate + 1e-9)
            if frame != frames[rig.name]:
                frames[rig.name] = frame
                cto, rto = rig.observe(truth, rng, t)
                core.offer(rig.name, "cto", cto, t)
                core.offer(rig.name, "rto", rto, t)
        decision = core.evaluate(t)
        if t > 0.2:
            cycles += 1
            alarms += sum(not h.ok for h in decision.health.values())
    return alarms, cycles


def main() -> int:
    parser = bench_parser(__doc__, quick="fewer cycles, one minute")
    parser.add_argument(
        "--hours",
        type=float,
        default=1.0,
        help="simulated hours for the false-alarm run (1 h takes ~6 min)",
    )
    args = parser.parse_args()
    cycles = 2000 if args.quick else 20000
    results: dict[str, object] = {}
    for n in (2, 8, 16):
        print(f"cycle time, {n} sensors ...", file=sys.stderr)
        results[f"cycle_{n}_sensors"] = cycle_times(n, cycles)
        results[f"cycle_{n}_sensors_at_rate"] = cycle_times(n, cycles, every_cycle=False)
        results[f"cycle_{n}_sensors_stamped"] = cycle_times(n, cycles, robot_rate=200.0)
    latency = {}
    for cause in ("cto_missing", "stale", "corrupt", "calibration"):
        print(f"detection latency: {cause} ...", file=sys.stderr)
        periods = detection_latency(cause, 10 if args.quick else 50)
        latency[cause] = {
            "n": len(periods),
            "median_periods": statistics.median(periods),
            "max_periods": max(periods),
        }
    results["detection_latency"] = latency
    simulated = 60.0 if args.quick else args.hours * 3600.0
    print(f"false alarms over {simulated:g} simulated s ...", file=sys.stderr)
    alarms, evaluated = false_alarms(simulated)
    results["false_alarms"] = {"simulated_s": simulated, "cycles": evaluated, "alarms": alarms}
    c16 = results["cycle_16_sensors"]
    targets = {
        "cycle p99 <= 100 us at 16 sensors (worst case)": c16["p99_us"] <= 100,  # type: ignore[index]
        "cycle p99 <= 100 us at 16 sensors (at rate)": results["cycle_16_sensors_at_rate"][  # type: ignore[index]
            "p99_us"
        ]
        <= 100,
        "detection <= 2 periods for every cause": all(
            v["max_periods"] <= 2 for v in latency.values()
        ),
        "no false alarm": alarms == 0,
    }
    lines = [
        f"# Tracking benchmark ({time.strftime('%Y-%m-%d %H:%M')}, Python "
        f"{platform.python_version()}, {os.cpu_count()} cores)",
        "",
        "Cycle = taking the new samples + evaluating, 1 kHz. Worst case: every sensor "
        "delivers a frame in every cycle; at rate: Certus 100 Hz, Vicra 20 Hz.",
        "",
        "| sensors | worst p50 µs | worst p99 µs | at rate p50 µs | at rate p99 µs |",
        "|---:|---:|---:|---:|---:|",
    ]
    for n in (2, 8, 16):
        worst, at_rate = results[f"cycle_{n}_sensors"], results[f"cycle_{n}_sensors_at_rate"]
        lines.append(
            f"| {n} | {worst['p50_us']:.1f} | {worst['p99_us']:.1f} "  # type: ignore[index]
            f"| {at_rate['p50_us']:.1f} | {at_rate['p99_us']:.1f} |"  # type: ignore[index]
        )
    lines += [
        "",
        "With the robot's stamped poses at 200 Hz and stamped samples (the deployment's "
        "path: each sample checked against the pose of its time), worst case:",
        "",
        "| sensors | p50 µs | p99 µs |",
        "|---:|---:|---:|",
    ]
    for n in (2, 8, 16):
        stamped = results[f"cycle_{n}_sensors_stamped"]
        lines.append(f"| {n} | {stamped['p50_us']:.1f} | {stamped['p99_us']:.1f} |")  # type: ignore[index]
    lines += ["", "| fault | trials | median periods | max periods |", "|---|---:|---:|---:|"]
    lines += [
        f"| {c} | {v['n']} | {v['median_periods']:.2f} | {v['max_periods']:.2f} |"
        for c, v in latency.items()
    ]
    lines += [
        "",
        f"False alarms: {alarms} in {evaluated} cycles ({simulated:g} simulated s of "
        "nominal noisy tracking, Certus 0.1 mm and Vicra 0.25 mm RMS)",
    ]
    write_report(args.out, "tracking", lines, targets, {"results": results})
    return 0


if __name__ == "__main__":
    sys.exit(main())
