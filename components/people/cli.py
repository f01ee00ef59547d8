"""`fw calibrate-cameras`: the RGB-D camera calibration protocol (thesis 3.4.3, Fig. 4.4).

For every camera of a topology's simulated OR (its `KinectSim` components):

* camera-master: a chessboard (5 x 6 squares, 640 x 560 mm) held in a few poses
  where both cameras see all its inner corners from the front; the rigid least
  squares fit of the corners (`kinect_to_kinect`) gives master_from_camera (eq. 3.8);
* master-robot: a marker on the end-effector seen by the master in the tracking
  protocol's robot poses; hand-eye (`kinect_to_robot`, the trackers' solver) gives
  camera_from_base, written as base_from_master (eq. 3.10).

A camera whose board residuals are small agreed with the master on a shared object:
it is written `verified: true`, so the detector trusts its lone users from the first
frame (runtime disagreement still revokes that trust). The simulated world frame is
the robot base frame (the scene puts the base at the origin), so the output also
reports the error against the simulation's truth.
"""

from __future__ import annotations

import argparse
import functools
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from components.domain.calibration import protocol_poses
from components.domain.geometry import look_at, matrix_to_quat, norm, rigid, rotation_angle
from components.people.calibration import chessboard_corners, kinect_to_kinect, kinect_to_robot
from components.people.kinect_sim import KinectModel
from framework.errors import FwError, YamlError
from framework.yamlio import load_yaml

EPILOG = """\
examples:
  fw calibrate-cameras topologies/seeg.yaml -o procedures/seeg/cameras.yaml
  fw calibrate-cameras topologies/people.yaml --master kinect_0 --board-poses 8 -o /tmp/c.yaml

An existing output file keeps its other settings (area, matcher, lateral_noise).
A camera whose median board residual exceeds --max-residual is written with
`verified: false` and a warning: its lone users stay suspects until it agrees
with the master on someone at run time.
"""

KINECT_CLASS = "components.people.kinect_sim:KinectSim"
FACING = np.radians(60.0)  # corners are found only on a board facing the camera this much


class CameraCalibrationError(FwError):
    """The camera protocol cannot run (no cameras, no shared view, too few poses)."""


@dataclass
class SimulatedCamera:
    """A camera of the topology: its name and (simulated) optics."""

    name: str
    model: KinectModel


def cameras_of(topology_path: str) -> list[SimulatedCamera]:
    """The topology's simulated cameras, in the order they are declared."""
    from framework.topology import load_topology

    topology = load_topology(topology_path)
    out = []
    for spec in topology.components.values():
        if spec.class_path != KINECT_CLASS:
            continue
        props = spec.properties
        position = tuple(props.get("position", (0.0, -2.5, 2.2)))
        target = tuple(props.get("target", (0.0, 0.0, 1.0)))
        out.append(SimulatedCamera(spec.name, KinectModel(spec.name, look_at(position, target))))
    if not out:
        raise CameraCalibrationError(f"{topology_path}: no {KINECT_CLASS} components to calibrate")
    return out


def _sees_board(camera: KinectModel, world: np.ndarray, normal: np.ndarray) -> bool:
    points = camera.to_camera(world)
    if not camera.in_view(points).all():
        return False
    towards = camera.world_from_camera[:3, 3] - world.mean(axis=0)
    return float(normal @ towards) / norm(towards) >= np.cos(FACING)


def board_poses(
    a: KinectModel, b: KinectModel, count: int, rng: np.random.Generator
) -> list[np.ndarray]:
    """`count` board poses (world_from_board) where both cameras see every inner corner
    from the front: held between them, facing the bisector of their directions."""
    corners = chessboard_corners()
    eye_a, eye_b = a.world_from_camera[:3, 3], b.world_from_camera[:3, 3]
    ahead = [c.world_from_camera[:3, 3] + 2.0 * c.world_from_camera[:3, 2] for c in (a, b)]
    middle = (ahead[0] + ahead[1]) / 2
    poses: list[np.ndarray] = []
    for _ in range(2000 * count):
        center = middle + rng.uniform(-0.6, 0.6, 3)
        facing = (eye_a - center) / norm(eye_a - center)
        facing += (eye_b - center) / norm(eye_b - center)
        z = facing / norm(facing)
        x = np.cross([0.0, 0.0, 1.0], z)
        if norm(x) < 1e-6:
            continue
        x /= norm(x)
        board = np.eye(4)
        board[:3, :3] = np.stack([x, np.cross(z, x), z], axis=1)
        board[:3, :3] = board[:3, :3] @ rigid((0, 0, 0), tuple(rng.normal(0, 0.15, 3)))[:3, :3]
        board[:3, 3] = center
        world = corners @ board[:3, :3].T + center
        normal = board[:3, 2]
        if _sees_board(a, world, normal) and _sees_board(b, world, normal):
            poses.append(board)
            if len(poses) == count:
                return poses
    raise CameraCalibrationError(
        f"cameras {a.name} and {b.name} share too little view to hold a board in "
        f"{count} poses both see from the front"
    )


@functools.lru_cache(maxsize=8)
def reachable_poses(count: int, seed: int = 0) -> list[np.ndarray]:
    """`count` end-effector poses for the marker protocol that the robot reaches (IK
    from home): the tracking protocol's pattern over a 0.3 m cube, twice the trackers'
    (a Kinect is ten times noisier than an optical tracker, the lever arm must grow)."""
    from components.domain.ik import DifferentialIK
    from components.domain.lwr4 import HOME

    ik = DifferentialIK()
    kept = []
    for pose in protocol_poses(4 * count, seed, half=0.15):
        q = ik.solve(np.array(HOME), pose, 3000)
        error = ik.error(q, pose)
        if norm(error[:3]) < 1e-3 and norm(error[3:]) < 1e-2:
            kept.append(pose)
            if len(kept) == count:
                break
    return kept


def workspace_error(estimate: np.ndarray, truth: np.ndarray, area: dict[str, Any]) -> float:
    """Median distance (m) between where a master-camera point is placed with the
    estimated and with the true base_from_master, over the volume people occupy
    (the area around the table, floor to 1.8 m)."""
    cx, cy = area.get("center", (0.0, 0.0))
    r = float(area.get("radius", 1.5))
    xs, ys, zs = np.meshgrid(
        np.linspace(cx - r, cx + r, 9), np.linspace(cy - r, cy + r, 9), np.linspace(-0.8, 1.0, 4)
    )
    grid = np.stack([xs, ys, zs], axis=-1).reshape(-1, 3)
    in_camera = grid @ np.linalg.inv(truth)[:3, :3].T + np.linalg.inv(truth)[:3, 3]
    placed = in_camera @ estimate[:3, :3].T + estimate[:3, 3]
    return float(np.median(np.linalg.norm(placed - grid, axis=1)))


def _transform(t: np.ndarray) -> dict[str, list[float]]:
    return {
        "position": [round(float(v), 6) for v in t[:3, 3]],
        "quaternion": [round(float(v), 9) for v in matrix_to_quat(t[:3, :3])],
    }


def _error(fit: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    return {
        "mm": round(norm(fit[:3, 3] - truth[:3, 3]) * 1e3, 1),
        "deg": round(float(np.degrees(rotation_angle(fit[:3, :3].T @ truth[:3, :3]))), 2),
    }


def run(
    cameras: list[SimulatedCamera],
    master: str,
    board: int,
    robot: int,
    seed: int,
    max_residual: float,
    area: dict[str, Any],
) -> tuple[dict[str, Any], dict[str, Any]]:
    """Calibrate every camera against `master` and the master against the robot: the
    cameras-file content (without area/matcher) and a report with residuals."""
    rng = np.random.default_rng(seed)
    by_name = {c.name: c for c in cameras}
    if master not in by_name:
        raise CameraCalibrationError(f"master {master!r} is not one of {sorted(by_name)}")
    main = by_name[master].model
    main.rng = rng
    corners = chessboard_corners()

    # master-robot: the marker's pose seen by the master in the tracking protocol's poses
    ee_from_marker = rigid((0.0, 0.0, 0.02), (0.0, 0.0, 0.0))
    marker_in_camera, ee_in_base = [], []
    for ee in reachable_poses(robot):
        marker = main.to_camera(np.array([(ee @ ee_from_marker)[:3, 3]]))
        if not main.in_view(marker).all():
            continue
        seen = np.linalg.inv(main.world_from_camera) @ ee @ ee_from_marker
        seen[:3, 3] += main.noise(marker)[0]
        seen[:3, :3] = (
            seen[:3, :3] @ rigid((0, 0, 0), tuple(rng.normal(0, np.radians(1.0), 3)))[:3, :3]
        )
        marker_in_camera.append(seen)
        ee_in_base.append(ee)
    if len(marker_in_camera) < 4:
        raise CameraCalibrationError(
            f"the master {master} sees the end-effector marker in {len(marker_in_camera)} of "
            f"{robot} robot poses; hand-eye needs at least 4"
        )
    robot_fit = kinect_to_robot(marker_in_camera, ee_in_base)
    base_from_master = np.linalg.inv(robot_fit.x)
    report: dict[str, Any] = {
        "robot": {
            "poses": robot_fit.poses,
            "translation_rms_mm": round(norm(robot_fit.translation_residual) * 1e3, 1),
            "truth_error": {
                **_error(base_from_master, main.world_from_camera),
                "workspace_mm": round(
                    workspace_error(base_from_master, main.world_from_camera, area) * 1e3, 1
                ),
            },
        }
    }
    entries: dict[str, Any] = {master: {}}
    for camera in cameras:
        if camera.name == master:
            continue
        other = camera.model
        other.rng = rng
        seen_master, seen_other = [], []
        for pose in board_poses(main, other, board, rng):
            world = corners @ pose[:3, :3].T + pose[:3, 3]
            for model, out in ((main, seen_master), (other, seen_other)):
                points = model.to_camera(world)
                out.append(points + model.noise(points))
        fit, residuals = kinect_to_kinect(seen_master, seen_other)
        median = float(np.median(residuals))
        truth = np.linalg.inv(main.world_from_camera) @ other.world_from_camera
        entries[camera.name] = {
            "calibration": _transform(fit),
            "verified": median <= max_residual,
        }
        report[camera.name] = {
            "board_poses": board,
            "corners": len(residuals),
            "residual_mm": {
                "median": round(median * 1e3, 1),
                "p25": round(float(np.percentile(residuals, 25)) * 1e3, 1),
                "p75": round(float(np.percentile(residuals, 75)) * 1e3, 1),
                "p90": round(float(np.percentile(residuals, 90)) * 1e3, 1),
                "max": round(float(residuals.max()) * 1e3, 1),
            },
            "truth_error": {
                **_error(fit, truth),
                "workspace_mm": round(
                    workspace_error(main.world_from_camera @ fit, other.world_from_camera, area)
                    * 1e3,
                    1,
                ),
            },
        }
    doc = {"master": master, "base_from_master": _transform(base_from_master), "cameras": entries}
    return doc, report


def _previous_settings(path: Path) -> dict[str, Any]:
    """Settings of an existing cameras file that calibration does not produce."""
    if not path.exists():
        return {}
    try:
        old = load_yaml(path).data or {}
    except YamlError as exc:
        raise CameraCalibrationError(f"cannot keep its settings: {exc}") from None
    if not isinstance(old, dict):
        return {}
    kept = {k: old[k] for k in ("area", "matcher") if k in old}
    for name, spec in (old.get("cameras") or {}).items():
        if isinstance(spec, dict) and "lateral_noise" in spec:
            kept.setdefault("lateral_noise", {})[name] = spec["lateral_noise"]
    return kept


def cmd_calibrate_cameras(args: argparse.Namespace) -> int:
    """Run the protocol on the topology's cameras and write the cameras YAML."""
    cameras = cameras_of(args.topology)
    master = args.master or cameras[0].name
    out = Path(args.output)
    kept = _previous_settings(out)
    area = kept.get("area", {"center": [0.0, 0.0], "radius": 1.5})
    doc, report = run(
        cameras,
        master,
        args.board_poses,
        args.robot_poses,
        args.seed,
        args.max_residual / 1e3,
        area,
    )
    noise = kept.pop("lateral_noise", {})
    for name, value in noise.items():
        if name in doc["cameras"]:
            doc["cameras"][name]["lateral_noise"] = value
    doc = {
        "master": doc["master"],
        "base_from_master": doc["base_from_master"],
        "area": area,
        **({"matcher": kept["matcher"]} if "matcher" in kept else {}),
        "cameras": doc["cameras"],
    }
    header = (
        f"# Written by `fw calibrate-cameras {args.topology}` (simulation; thesis 3.4.3).\n"
        f"# base_from_master (eq. 3.10): hand-eye on the master's end-effector marker, "
        f"{report['robot']['poses']} poses, error vs truth {report['robot']['truth_error']}.\n"
        "# calibration = master_from_camera (eq. 3.8): chessboard corners, rigid least squares.\n"
    )
    for name, row in report.items():
        if name != "robot":
            header += (
                f"#   {name}: {row['corners']} corners in {row['board_poses']} board poses, "
                f"residual [mm] {row['residual_mm']}, error vs truth {row['truth_error']}\n"
            )
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(
        header + yaml.safe_dump(doc, sort_keys=False, default_flow_style=None), encoding="utf-8"
    )
    robot = report["robot"]
    print(
        f"{master:<10} master -> robot: {robot['poses']} marker poses, "
        f"error vs truth {robot['truth_error']}"
    )
    for name, row in report.items():
        if name == "robot":
            continue
        verdict = "verified" if doc["cameras"][name]["verified"] else "NOT verified"
        print(
            f"{name:<10} -> {master}: residual [mm] {row['residual_mm']}  "
            f"error vs truth {row['truth_error']}  {verdict}"
        )
        if verdict != "verified":
            print(
                f"fw: warning: {name}'s median residual exceeds {args.max_residual:g} mm: "
                "written unverified (check the board poses or the camera mount)",
                file=sys.stderr,
            )
    print(f"wrote {out}", file=sys.stderr)
    return 0


def add_commands(sub: Any) -> None:
    """Register `fw calibrate-cameras`."""
    p = sub.add_parser(
        "calibrate-cameras",
        help="RGB-D camera calibration protocol (simulation)",
        description="Calibrate a topology's cameras to the master camera (chessboard) and "
        "the master to the robot (end-effector marker, hand-eye); write the cameras YAML "
        "the Workspace People Detector reads.",
        epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("topology", metavar="TOPOLOGY", help="topology YAML with KinectSim cameras")
    p.add_argument("-o", "--output", required=True, metavar="FILE", help="cameras YAML to write")
    p.add_argument("--master", metavar="NAME", help="master camera (default: the first)")
    p.add_argument(
        "--board-poses", type=int, default=4, metavar="N", help="chessboard poses (default 4)"
    )
    p.add_argument(
        "--robot-poses", type=int, default=16, metavar="N", help="robot poses (default 16)"
    )
    p.add_argument(
        "--max-residual",
        type=float,
        default=50.0,
        metavar="MM",
        help="median board residual above which a camera is not verified (default 50)",
    )
    p.add_argument("--seed", type=int, default=0, help="noise seed")
    p.set_defaults(func=cmd_calibrate_cameras)
