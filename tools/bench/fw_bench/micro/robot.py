#!/usr/bin/env python3
"""Benchmark the 1 kHz robot loop pieces (a benchmark, not a test).

* one simulated-arm cycle (setpoint check + MuJoCo step of the LWR 4+ scene);
* one interpolator cycle (ruckig on the path parameter + damped-least-squares IK
  with Pinocchio) while moving.

Braking after STOP (on the MuJoCo arm, 1-10 cm/s) is in `fw bench braking`.

Budget: both cycles together well under 1 ms, so the robot process keeps real time.

    python -m fw_bench.micro robot [--quick] [--out out/bench]
"""

from __future__ import annotations

import sys
import time

import numpy as np

from components.domain.lwr4 import HOME
from components.domain.procedure import load_procedure
from components.robot.interpolator import InterpolatorCore, Phase
from components.sim.arm import SimulatedArm
from fw_bench.files import seeg_file
from fw_bench.micro.lib import bench_parser, percentiles, write_report

PROCEDURE = load_procedure(seeg_file("procedures", "seeg.yaml"))


def loop_cycles(cycles: int) -> dict[str, dict[str, float]]:
    arm = SimulatedArm()
    arm.release()
    core = InterpolatorCore(
        np.array(HOME),
        velocity=max(t.fast for t in PROCEDURE.speeds.values()),
        acceleration=PROCEDURE.acceleration,
        brake_acceleration=PROCEDURE.brake_acceleration,
    )
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


def main() -> int:
    parser = bench_parser(__doc__)
    args = parser.parse_args()
    cycles = loop_cycles(2000 if args.quick else 20000)
    total_p99 = cycles["interpolator"]["p99_us"] + cycles["arm"]["p99_us"]
    targets = {
        "interpolator + arm p99 < 1000 us": total_p99 < 1000,
    }
    lines = [
        "# Robot loop benchmark",
        "",
        "| cycle | p50 µs | p99 µs |",
        "|---|---:|---:|",
        *(f"| {k} | {v['p50_us']:.1f} | {v['p99_us']:.1f} |" for k, v in cycles.items()),
    ]
    write_report(args.out, "robot", lines, targets, {"cycles": cycles})
    return 0


if __name__ == "__main__":
    sys.exit(main())
