#!/usr/bin/env python3
"""Benchmark the hand-eye calibration on synthetic data with known truth (not a test).

Noise 0.25 mm (3-D RMS) and 0.1 deg on every measured pose, 8 and 20 robot poses,
many trials; reports the errors of X (RTO_X_base) and Y (ee_Y_CTO) against the
truth. Target: X within 0.6 mm and 0.05 deg with 8 poses.

    python -m fw_bench.micro calibration [--trials 100] [--out out/bench]
"""

from __future__ import annotations

import sys
import time

import numpy as np

from components.domain.calibration import hand_eye, protocol_poses
from components.domain.geometry import rigid, rotation_angle
from components.domain.rigs import standard_rigs
from fw_bench.micro.lib import bench_parser, write_report


def trial(rig, poses: int, seed: int) -> tuple[float, float, float, float, float]:
    rng = np.random.default_rng(seed)
    robot = protocol_poses(poses, seed)
    measured = []
    for b in robot:
        noise = rigid(
            tuple(rng.normal(0, 0.25e-3 / np.sqrt(3), 3)),
            tuple(rng.normal(0, np.radians(0.1) / np.sqrt(3), 3)),
        )
        measured.append(rig.rto_from_base @ b @ rig.ee_from_cto @ noise)
    t0 = time.perf_counter()
    fit = hand_eye(measured, robot)
    seconds = time.perf_counter() - t0
    x_mm = np.linalg.norm(fit.x[:3, 3] - rig.rto_from_base[:3, 3]) * 1e3
    x_deg = np.degrees(rotation_angle(fit.x[:3, :3].T @ rig.rto_from_base[:3, :3]))
    y_mm = np.linalg.norm(fit.y[:3, 3] - rig.ee_from_cto[:3, 3]) * 1e3
    y_deg = np.degrees(rotation_angle(fit.y[:3, :3].T @ rig.ee_from_cto[:3, :3]))
    return x_mm, float(x_deg), y_mm, float(y_deg), seconds


def main() -> int:
    parser = bench_parser(__doc__, quick=None)
    parser.add_argument("--trials", type=int, default=100)
    args = parser.parse_args()
    rig = standard_rigs()[1]
    rows = {}
    for poses in (8, 20):
        data = np.array([trial(rig, poses, seed) for seed in range(args.trials)])
        rows[poses] = {
            name: {
                "median": float(np.median(data[:, i])),
                "p95": float(np.percentile(data[:, i], 95)),
            }
            for i, name in enumerate(["X_mm", "X_deg", "Y_mm", "Y_deg", "solve_s"])
        }
    eight = rows[8]
    targets = {
        "X <= 0.6 mm with 8 poses (median)": eight["X_mm"]["median"] <= 0.6,
        "X <= 0.05 deg with 8 poses (median)": eight["X_deg"]["median"] <= 0.05,
    }
    lines = [
        f"# Calibration benchmark ({args.trials} trials, 0.25 mm / 0.1 deg noise)",
        "",
        "| poses | X mm (median / p95) | X deg | Y mm | Y deg | solve ms |",
        "|---:|---:|---:|---:|---:|---:|",
    ]
    for poses, r in rows.items():
        lines.append(
            f"| {poses} | {r['X_mm']['median']:.3f} / {r['X_mm']['p95']:.3f} | "
            f"{r['X_deg']['median']:.4f} / {r['X_deg']['p95']:.4f} | "
            f"{r['Y_mm']['median']:.3f} / {r['Y_mm']['p95']:.3f} | "
            f"{r['Y_deg']['median']:.4f} / {r['Y_deg']['p95']:.4f} | "
            f"{r['solve_s']['median'] * 1e3:.1f} |"
        )
    write_report(args.out, "calibration", lines, targets, {"rows": rows})
    return 0


if __name__ == "__main__":
    sys.exit(main())
