#!/usr/bin/env python3
"""Benchmark the 1 kHz robot loop pieces (a benchmark, not a test).

* one simulated-arm cycle (setpoint check + MuJoCo step of the LWR 4+ scene);
* one interpolator cycle (ruckig on the path parameter + damped-least-squares IK
  with Pinocchio) while moving;
* the braking distance after STOP at 1 to 10 cm/s and the error of the return to
  the STOP point (commanded path, brake deceleration from procedures/seeg.yaml).

Budget: both cycles together well under 1 ms, so the robot process keeps real time.

    python tools/bench_robot.py [--quick] [--out out/bench]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from benchlib import percentiles, write_report

from components.robot.arm import SimulatedArm
from components.robot.interpolator import InterpolatorCore, Phase
from components.robot.lwr4 import HOME
from components.supervisor.procedure import load_procedure

PROCEDURE = load_procedure(Path(__file__).resolve().parents[1] / "procedures" / "seeg.yaml")


def loop_cycles(cycles: int) -> dict[str, dict[str, float]]:
    arm = SimulatedArm()
    arm.release()
    core = InterpolatorCore(np.array(HOME), brake_acceleration=PROCEDURE.brake_acceleration)
    core.go_to(PROCEDURE.target)
    arm_t, interp_t = [], []
    for _ in range(cycles):
        if core.phase is Phase.REACHED:  # back and forth between home and target
            at_target = np.allclose(core.pose, PROCEDURE.target)
            core.go_to(PROCEDURE.goals["home"] if at_target else PROCEDURE.target)
        t0 = time.perf_counter()
        q = core.step()
        t1 = time.perf_counter()
        arm.command(q)
        arm.step()
        t2 = time.perf_counter()
        interp_t.append(t1 - t0)
        arm_t.append(t2 - t1)
    return {"interpolator": percentiles(interp_t[100:]), "arm": percentiles(arm_t[100:])}


def braking(speed: float) -> dict[str, float]:
    """Overshoot past the STOP point and the return error, at cruise `speed`."""
    core = InterpolatorCore(
        np.array(HOME), velocity=speed, brake_acceleration=PROCEDURE.brake_acceleration
    )
    core.go_to(PROCEDURE.target)
    while core.speed < speed - 1e-9:
        core.step()
    core.stop()
    asserted = core.pose[:3, 3].copy()
    farthest = 0.0
    while core.phase is not Phase.STOPPED:
        core.step()
        farthest = max(farthest, float(np.linalg.norm(core.pose[:3, 3] - asserted)))
    return {
        "speed_cm_s": speed * 100,
        "overshoot_mm": farthest * 1e3,
        "return_error_mm": float(np.linalg.norm(core.pose[:3, 3] - asserted)) * 1e3,
    }


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--out", default="out/bench")
    args = parser.parse_args()
    cycles = loop_cycles(2000 if args.quick else 20000)
    stops = [braking(v) for v in (0.01, 0.025, 0.05, 0.075, 0.10)]
    total_p99 = cycles["interpolator"]["p99_us"] + cycles["arm"]["p99_us"]
    targets = {
        "interpolator + arm p99 < 1000 us": total_p99 < 1000,
        "overshoot <= 0.3 mm at 1 cm/s": stops[0]["overshoot_mm"] <= 0.3,
        "overshoot <= 5 mm at 10 cm/s": stops[-1]["overshoot_mm"] <= 5,
        "return to the STOP point < 0.1 mm": all(s["return_error_mm"] < 0.1 for s in stops),
    }
    lines = [
        "# Robot loop benchmark",
        "",
        "| cycle | p50 µs | p99 µs |",
        "|---|---:|---:|",
        *(f"| {k} | {v['p50_us']:.1f} | {v['p99_us']:.1f} |" for k, v in cycles.items()),
        "",
        f"STOP at {PROCEDURE.brake_acceleration} m/s² (commanded path):",
        "",
        "| speed cm/s | overshoot mm | return error mm |",
        "|---:|---:|---:|",
        *(
            f"| {s['speed_cm_s']:.1f} | {s['overshoot_mm']:.3f} | {s['return_error_mm']:.2e} |"
            for s in stops
        ),
    ]
    write_report(args.out, "robot", lines, targets, {"cycles": cycles, "stops": stops})
    return 0


if __name__ == "__main__":
    sys.exit(main())
