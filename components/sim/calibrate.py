"""`fw calibrate`: the robot-tracker calibration protocol (thesis 3.3.2, Table 3.4).

The robot stands at each protocol pose by its own model (the joints an inverse
kinematics finds for it); the trackers of the synthetic tracking world
(`components.domain.rigs`) see where the simulated OR's real arm
(`lwr4.LWR4_ERRORS`) puts its tool then, a few millimetres away: the fit absorbs
what is common to all poses, the residuals show the rest, as a real run's would.
Because this is a simulation, the output also gives the error against the truth.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from components.domain.calibration import (
    hand_eye,
    pivot_calibration,
    pivot_poses,
    protocol_poses,
    tracker_to_tracker,
)
from components.domain.geometry import invert, matrix_to_quat, norm, pose_matrix, rotation_angle
from components.domain.ik import DifferentialIK
from components.domain.lwr4 import HOME, LWR4_ERRORS
from components.domain.rigs import standard_rigs
from components.sim.arm import resting_tcp

EPILOG = """\
examples:
  fw calibrate -o procedures/seeg/sensors.yaml           8 poses per tracker (the thesis)
  fw calibrate --poses 20 --seed 3 -o /tmp/calibration.yaml
"""


PIVOT_POSES = 40
"""Tool poses of the pivot calibration (a hand pivots the tool for a few seconds)."""


def _transform(t: np.ndarray) -> dict[str, list[float]]:
    return {
        "position": [round(float(v), 7) for v in t[:3, 3]],
        "quaternion": [round(float(v), 9) for v in matrix_to_quat(t[:3, :3])],
    }


def run(poses: int, seed: int) -> dict[str, Any]:
    """Calibrate every simulated tracker; the sensors file content plus a report."""
    rigs = standard_rigs()
    rng = np.random.default_rng(seed)
    robot = protocol_poses(poses, seed)
    ik = DifferentialIK()
    real = [resting_tcp(ik.solve(np.array(HOME), pose), LWR4_ERRORS) for pose in robot]
    results = {}
    references = {}
    pivots = {}
    pivot_rng = np.random.default_rng([seed, 1])  # its own draws: the hand-eye's stay as they were
    for rig in rigs:
        # the tool pivoted by hand in a divot: its tip in the CTO frame, whatever the arm
        seen = [rig.observe(tip, pivot_rng)[0] for tip in pivot_poses(PIVOT_POSES, seed)]
        pivots[rig.name] = pivot_calibration([pose_matrix(cto) for cto in seen])
        a, seen = [], []
        for pose in real:
            cto, rto = rig.observe(pose, rng)
            a.append(invert(pose_matrix(rto)) @ pose_matrix(cto))
            seen.append(pose_matrix(rto))
        results[rig.name] = hand_eye(a, robot, noise=math.sqrt(2.0) * rig.noise)
        # the reference tool stood still: its mean pose places the robot base in the
        # tracker's frame (S = T_RTO X), the tracker's own calibration to the robot
        reference = seen[0].copy()
        reference[:3, 3] = np.mean([t[:3, 3] for t in seen], axis=0)
        references[rig.name] = reference
    master = rigs[0]
    sensors: dict[str, Any] = {}
    report: dict[str, Any] = {}
    for priority, rig in enumerate(rigs, start=1):
        fit = results[rig.name]
        c = tracker_to_tracker(results[master.name].x, fit.x)
        sensors[rig.name] = {
            "priority": priority,
            "rate": rig.rate,
            # stale after 4 periods and at least 50 ms: a Python host under load can miss a
            # 10 ms frame without the tracker being at fault
            "stale_periods": max(4, math.ceil(0.05 * rig.rate)),
            # what the robot may do while navigated by this sensor: the procedure's
            # speeds are capped by these (the slower, noisier sensor allows less)
            "limits": {
                "max_velocity": 0.10 if priority == 1 else 0.05,
                "max_acceleration": 0.5 if priority == 1 else 0.25,
            },
            "calibration": {
                "C": _transform(c),
                "X": _transform(fit.x),
                "Y": _transform(fit.y),
                "S": _transform(references[rig.name] @ fit.x),
                "tip": [round(float(v), 7) for v in pivots[rig.name].tip],
            },
        }
        report[rig.name] = {
            "poses": fit.poses,
            "translation_residual_m": [round(float(v), 6) for v in fit.translation_residual],
            "rotation_residual_deg": [round(float(v), 4) for v in fit.rotation_residual_deg],
            "pivot": {"poses": PIVOT_POSES, "rms_mm": round(pivots[rig.name].rms * 1e3, 3)},
            "simulation_truth_error": {
                "X_mm": round(norm(fit.x[:3, 3] - rig.rto_from_base[:3, 3]) * 1e3, 3),
                "X_deg": round(
                    float(np.degrees(rotation_angle(fit.x[:3, :3].T @ rig.rto_from_base[:3, :3]))),
                    4,
                ),
                "Y_mm": round(norm(fit.y[:3, 3] - rig.ee_from_cto[:3, 3]) * 1e3, 3),
                "tip_mm": round(
                    norm(pivots[rig.name].tip - invert(rig.ee_from_cto)[:3, 3]) * 1e3,
                    3,
                ),
                "S_mm": round(
                    norm((references[rig.name] @ fit.x)[:3, 3] - rig.sensor_from_base[:3, 3]) * 1e3,
                    3,
                ),
            },
        }
    return {
        "master": master.name,
        "hysteresis": 5,
        "sensors": sensors,
        "calibration_report": report,
    }


def cmd_calibrate(args: argparse.Namespace) -> int:
    """Run the protocol and write the calibration YAML."""
    result = run(args.poses, args.seed)
    report = result.pop("calibration_report")
    out = Path(args.output)
    out.parent.mkdir(parents=True, exist_ok=True)
    header = (
        "# Written by `fw calibrate` (simulation, hand-eye AX=YB per tracker, eq. 3.3; the\n"
        "# TCP in the calibration tool by pivoting it in a divot, thesis Fig. 3.10).\n"
        "# Residuals per axis, like the thesis's Table 3.4:\n"
    )
    for name, row in report.items():
        header += (
            f"#   {name}: {row['poses']} poses, translation residual [m] "
            f"{row['translation_residual_m']}, rotation residual [deg] "
            f"{row['rotation_residual_deg']}; pivot {row['pivot']['poses']} poses, "
            f"{row['pivot']['rms_mm']} mm RMS; error vs simulation truth: "
            f"{row['simulation_truth_error']}\n"
        )
    out.write_text(header + yaml.safe_dump(result, sort_keys=False), encoding="utf-8")
    for name, row in report.items():
        print(
            f"{name:<8} translation residual [m] {row['translation_residual_m']}  "
            f"rotation residual [deg] {row['rotation_residual_deg']}  "
            f"truth error {row['simulation_truth_error']}"
        )
    print(f"wrote {out}", file=sys.stderr)
    return 0


def add_commands(sub: Any) -> None:
    """Register `fw calibrate`."""
    p = sub.add_parser(
        "calibrate",
        help="robot-tracker calibration protocol (simulation)",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "-o",
        "--output",
        required=True,
        metavar="FILE",
        help="sensors YAML to write (priorities, keys, limits, calibration)",
    )
    p.add_argument("--poses", type=int, default=8, help="robot poses per tracker (default 8)")
    p.add_argument("--seed", type=int, default=0, help="noise seed")
    p.set_defaults(func=cmd_calibrate)
