"""The Workspace People Detector as a component: camera ports in, people out.

Cameras come from a YAML file (any number, no code change):

    master: k0
    base_from_master: {position: [x, y, z], quaternion: [w, x, y, z]}   # eq. 3.10
    area: {center: [0.0, 0.0], radius: 1.5}                             # around the table
    cameras:
      k0: {}                                                            # the master
      k1: {calibration: {position: [...], quaternion: [...]},           # eq. 3.8
           verified: true}   # agreed with the master at calibration (fw calibrate-cameras)

Each camera is named as its component, and arrives on the detector's input port
`camera_<name>`, which the topology's `connections:` wire (usually from `<name>.users`).

A camera whose data stops (no new frame) simply contributes nothing; robot link
capsules join with the SEEG robot model (Pinocchio forward kinematics).
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from components.domain.geometry import as_matrix
from components.domain.skeleton import body_center
from components.people.detector import CameraConfig, DetectorConfig, PeopleDetectorCore
from components.people.kinect_sim import from_message
from framework import schema
from framework.component import Component, FileInput, In, Out, operation
from framework.errors import LocatedError
from framework.filekinds import FileKind, schema_then
from framework.messages import Envelopes, EventMessage, JointState, Scalar, Skeletons
from framework.ports import InputPort, ReadStatus
from framework.properties import prop
from framework.yamlio import load_yaml

SCHEMA = "components.people:cameras.schema.json"
MAX_FRAME_DELAY = 0.5
"""s: the most a frame's age moves the tracker's time back (a camera whose clock is
off, or a garbage stamp, cannot hold the tracker's time still)."""


class CameraConfigError(LocatedError):
    """A cameras file is wrong (file:line:column and the field)."""


def load_cameras(path: str) -> DetectorConfig:
    """The detector configuration, from YAML."""
    doc = load_yaml(path)
    schema.refuse_retired(
        doc,
        "cameras",
        "key",
        CameraConfigError,
        lambda name: (
            f"camera {name!r}: 'key' is no longer read: the topology wires the "
            f"detector's port camera_{name} (connections:), so fw validate and fw ls "
            "see it; delete 'key' here"
        ),
    )
    schema.require(doc, SCHEMA, CameraConfigError)
    data = doc.data
    master = data.get("master", next(iter(data["cameras"])))
    if master not in data["cameras"]:
        raise CameraConfigError(f"master {master!r} is not a camera", doc.location(("master",)))
    cameras = []
    for name, spec in data["cameras"].items():
        spec = spec or {}
        try:
            calibration = as_matrix(spec.get("calibration", np.eye(4).tolist()))
        except ValueError as exc:
            raise CameraConfigError(
                str(exc), doc.location(("cameras", name, "calibration"))
            ) from None
        cameras.append(
            CameraConfig(
                name,
                calibration,
                float(spec.get("lateral_noise", 0.01)),
                spec.get("verified", False),
            )
        )
    cameras.sort(key=lambda c: c.name != master)  # the master first
    try:
        base_from_master = as_matrix(data.get("base_from_master", np.eye(4).tolist()))
    except ValueError as exc:
        raise CameraConfigError(str(exc), doc.location(("base_from_master",))) from None
    area = data.get("area") or {}
    try:
        config = DetectorConfig(
            cameras,
            base_from_master,
            matcher=data.get("matcher", "hungarian"),
            area_center=tuple(area.get("center", (0.0, 0.0))),  # type: ignore[arg-type]
            area_radius=float(area.get("radius", 1.5)),
        )
    except (TypeError, ValueError) as exc:
        raise CameraConfigError(str(exc), doc.location(("area",))) from None
    return config


CAMERAS_FILE = FileKind(
    "cameras",
    "cameras",
    "the people detector's cameras, calibration and area around the table",
    schema_then(SCHEMA, load_cameras, "cameras"),
)


def _camera_inputs(config: DetectorConfig, file: str) -> dict[str, FileInput]:
    """Every camera's input port, by camera name."""
    return {
        camera.name: FileInput(
            f"camera_{camera.name}",
            Skeletons,
            f"{file}: cameras.{camera.name}",
            f"{camera.name}.users",
        )
        for camera in config.cameras
    }


class WorkspacePeopleDetector(Component):
    """Feeds `PeopleDetectorCore` from the cameras' ports and publishes people."""

    cameras_file = prop(
        str, "", doc="cameras YAML (cameras, calibration, area)", required=True, file="cameras"
    )
    people = Out(EventMessage, doc="tracks: id, confirmed, cameras, torso position")
    users_near = Out(Scalar, doc="confirmed people inside the area around the table")
    min_distance = Out(Scalar, doc="closest robot-person distance (m; inf without a robot)")
    envelopes = Out(
        Envelopes,
        doc="capsules the robot keeps its distance from, stamped with their oldest camera frame",
    )
    joints = In(JointState, doc="robot joints: link capsules by Pinocchio forward kinematics")

    @classmethod
    def file_inputs(cls, properties: dict[str, Any]) -> list[FileInput]:
        """A `camera_<name>` Skeletons input per camera of the cameras file (the topology
        connects it, usually from the camera's `users`)."""
        file = str(properties.get("cameras_file", ""))
        return list(_camera_inputs(load_cameras(file), file).values())

    def __init__(self, name: str):
        super().__init__(name)
        self.last: dict[str, Any] = {}
        """The latest frame, as `current` reports it."""
        self.robot: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
        """The robot's link capsules (p, q, radius), as last received."""
        self._people: list[Any] = []
        """The people of the latest frame (their envelopes: `envelopes`)."""

    def configure_hook(self) -> bool:
        config = load_cameras(self.cameras_file)
        ports = {port.name: port for port in self.file_ports()}
        self.core = PeopleDetectorCore(config)
        self.camera_ports: dict[str, InputPort[Skeletons]] = {
            name: ports[wanted.port]
            for name, wanted in _camera_inputs(config, self.cameras_file).items()
        }
        self.last = {}
        self.kinematics: Any = None
        self.robot = None
        self._people = []
        self._seen_at = 0.0  # the oldest camera frame of the latest that arrived
        self._observed_at = -math.inf
        return True

    def _observed(self, stamps: list[float]) -> float:
        """The time the cameras saw this frame, on the component's clock: now, less how
        long ago the newest frame was taken. The tracker counts how long someone lasted
        in the time they were seen, so frames that a busy host delivers late do not
        stretch a ghost into a lasting detection; never earlier than the last frame's."""
        now = self.clock.now()
        if stamps:
            now -= min(max(time.time() - max(stamps), 0.0), MAX_FRAME_DELAY)
        self._observed_at = max(now, self._observed_at)
        return self._observed_at

    def update_hook(self) -> None:
        users, stamps = {}, []
        for name, port in self.camera_ports.items():
            status, message = port.read()
            if status is ReadStatus.NEW:  # a stopped camera contributes nothing
                users[name] = from_message(message)
                stamps.append(message.stamp)
        if stamps:
            self._seen_at = min(stamps)
        status, joints = self.joints.read()
        if status is ReadStatus.NEW:
            if self.kinematics is None:
                from components.domain.lwr4 import Kinematics

                self.kinematics = Kinematics()
            capsules = self.kinematics.capsules(np.asarray(joints.position))
            self.robot = (capsules.a, capsules.b, capsules.radius)
        frame = self.core.process(users, self._observed(stamps), self.robot)
        self._people = list(frame.people)
        stamp = time.time()
        # the safety-relevant values go out first: the robot keeps its distance from the
        # envelopes (their age is what it was seen, not now), the Supervisor stops on
        # the distance
        a, b, radius = frame.envelopes
        self.envelopes.write(
            Envelopes(
                self._seen_at,
                tuple(a.ravel().tolist()),
                tuple(b.ravel().tolist()),
                tuple(radius.tolist()),
            )
        )
        self.min_distance.write(Scalar(stamp, frame.min_distance))
        self.users_near.write(Scalar(stamp, float(frame.users_near)))
        self.last = {
            "people": [
                {
                    "id": t.id,
                    "cameras": sorted(t.cameras),
                    "torso": [round(float(v), 3) for v in np.nan_to_num(body_center(t.joints))],
                }
                for t in frame.people
            ],
            "tentative": len(frame.tracks) - len(frame.people),
            "users_near": frame.users_near,
            "disagreements": {f"{a}->{b}": n for (a, b), n in self.core.disagreements.items()},
            "suspects": len(frame.suspects),
            "unverified": sorted(set(self.core.cameras) - self.core.verified),
        }
        self.people.write(EventMessage(stamp, "people", self.name, self.last))

    @operation(readonly=True)
    def scene(self) -> dict[str, Any]:
        """The geometry of the last frame, robot base frame (m): the robot's link capsules
        and each confirmed person's envelope capsules, each as [ax, ay, az, bx, by, bz,
        radius]; what the console draws."""
        from components.domain.skeleton import envelope

        def rows(a: Any, b: Any, r: Any) -> list[list[float]]:
            return [
                [round(float(v), 4) for v in (*p, *q, radius)]
                for p, q, radius in zip(a, b, np.broadcast_to(r, (len(a),)), strict=True)
            ]

        robot = rows(*self.robot) if self.robot is not None else []
        people = []
        for track in self._people:
            p, q, radius = envelope(track.joints, track.sigma)
            people.append({"id": track.id, "capsules": rows(p, q, radius)})
        return {"robot": robot, "people": people}

    @operation(readonly=True)
    def current(self) -> dict[str, Any]:
        """The latest frame: confirmed people, tentative count, users near, disagreements."""
        return dict(
            self.last or {"people": [], "tentative": 0, "users_near": 0, "disagreements": {}}
        )
