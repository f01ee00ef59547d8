"""Scale: how the per-cycle costs grow with more trackers and more cameras.

* the Sensor Manager's cycle (take every new sample, evaluate) with 2-16 trackers,
  every tracker delivering a frame every cycle (the worst case) or at its own rate;
* the people detector's frame with 2-8 cameras x 16 people (`people.frame_cost`).
"""

from __future__ import annotations

import dataclasses
import statistics
import time
from typing import Any

import numpy as np

from components.domain.rigs import ee_path, sensors_config, standard_rigs
from components.tracking.sensor_manager import SensorManagerCore

TICK = 0.001


def many_rigs(n: int) -> list[Any]:
    """`n` trackers, alternately Certus-like and Vicra-like."""
    base = standard_rigs()
    return [dataclasses.replace(base[i % 2], name=f"s{i}") for i in range(n)]


def cycle_times(
    n: int, cycles: int, every_cycle: bool = True, robot_rate: float = 0.0
) -> dict[str, float]:
    """Cycle time with `n` sensors: each delivering a frame every cycle (the worst case),
    or at its own rate (Certus 100 Hz, Vicra 20 Hz) with phases spread over the period.
    With `robot_rate`, the robot's stamped poses arrive at that rate and samples carry
    their time, as in a deployment (each sample is checked against the pose of its
    time); without, one unstamped pose."""
    rigs = many_rigs(n)
    core = SensorManagerCore(sensors_config(rigs, 3))
    rng = np.random.default_rng(0)
    samples = []
    truth = ee_path(0.0)
    observed = [rig.observe(truth, rng) for rig in rigs]
    if not robot_rate:
        core.set_kinematics(truth)
    robot_period = round(1.0 / (robot_rate * TICK)) if robot_rate else 0
    periods = [round(1.0 / (rig.rate * TICK)) for rig in rigs]
    for k in range(cycles):
        now = k * TICK
        if robot_rate:  # stamps are set outside the timed part: they are the data
            observed = [
                (dataclasses.replace(cto, stamp=now), dataclasses.replace(rto, stamp=now))
                for cto, rto in observed
            ]
        t0 = time.perf_counter()  # a cycle = taking every new sample + evaluating
        if robot_period and k % robot_period == 0:
            core.set_kinematics(truth, now)
        for i, (rig, (cto, rto)) in enumerate(zip(rigs, observed, strict=True)):
            if every_cycle or (k + 7 * i) % periods[i] == 0:
                core.offer(rig.name, "cto", cto, now)
                core.offer(rig.name, "rto", rto, now)
        core.evaluate(now)
        samples.append(time.perf_counter() - t0)
    samples = sorted(samples[100:])
    return {
        "p50_us": statistics.median(samples) * 1e6,
        "p99_us": samples[int(len(samples) * 0.99)] * 1e6,
    }
