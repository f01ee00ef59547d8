"""A simulated Optotrak Certus (or any tracker of the synthetic world) on the bus.

The Certus's API is proprietary over Ethernet, so fw ships no driver for it: a real
one would be a component with the same two outputs (`cto`, `rto`, `Pose` in metres,
sensor frame) publishing on `certus/<tool>`; swap this class for it in the
topology. The simulation observes the synthetic world (`components.domain.rigs`)
at the rig's rate and noise (Certus: 100 Hz, 0.1 mm), inside an approximate field
of view (1.5-7 m from the sensor, +-35 deg), and takes faults by operation:
occlusion, a crash (stops publishing), corrupt (NaN) data, a bumped reference tool.
A sample carries the stamp of the arm pose it observed (`ee_pose`), as a real
tracker stamps its capture, not the time it was computed.
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from components.domain.geometry import invert, pose_matrix, rigid
from components.domain.rigs import ee_path, standard_rigs
from framework.component import Component, In, Out, operation
from framework.messages import Pose
from framework.ports import ReadStatus
from framework.properties import prop

NEAR_M, FAR_M, HALF_ANGLE = 1.5, 7.0, math.radians(35.0)


def in_certus_view(position: tuple[float, float, float]) -> bool:
    """True if a point (sensor frame, m) is inside the approximate Certus volume."""
    x, y, z = position
    distance = math.sqrt(x * x + y * y + z * z)
    return NEAR_M <= distance <= FAR_M and math.atan2(math.hypot(x, y), z) <= HALF_ANGLE


class TrackerSim(Component):
    """Publishes what one tracker of the synthetic world sees, at its rate."""

    rig = prop(str, "certus", choices=["certus", "vicra"], doc="which synthetic tracker")
    seed = prop(int, 0, doc="noise seed")
    check_view = prop(bool, True, doc="report tools outside the field of view as missing")
    ee_pose = In(Pose, doc="end-effector in the robot base frame (default: a slow path)")
    head = In(Pose, doc="the reference tool in the robot base frame, as the head moves it")
    cto = Out(Pose, doc="calibration tool optical, sensor frame")
    rto = Out(Pose, doc="reference tool optical, sensor frame")

    def configure_hook(self) -> bool:
        self.model = next(r for r in standard_rigs() if r.name == self.rig)
        self.rng = np.random.default_rng(self.seed)
        self.hidden: set[str] = set()
        self.crashed = False
        self.corrupt = False
        self.t0 = time.monotonic()
        self.frame_number = 0
        self.slip = np.eye(4)  # the reference tool moved on its mount (bump_reference)
        return True

    def update_hook(self) -> None:
        if self.crashed:
            return  # a crashed driver publishes nothing: the data goes stale
        status, ee = self.ee_pose.read()
        seen = status is not ReadStatus.NO_DATA and ee is not None
        truth = pose_matrix(ee) if seen else ee_path(time.monotonic() - self.t0)
        # the markers are seen where the arm was at the truth's stamp, so the sample
        # carries that stamp (a real tracker stamps its capture): a truth thinned to
        # fewer samples than 1 kHz then costs no accuracy, only age; on this host's
        # clock, as a real tracker's (the robot's host may run apart)
        stamp = self.local_stamp("ee_pose", ee.stamp) if seen else time.time()
        if stamp is None:
            return  # this host cannot tell the capture's time yet: no frame
        status, head = self.head.read()
        base_from_rto = (
            invert(self.model.rto_from_base)
            if status is ReadStatus.NO_DATA or head is None
            else pose_matrix(head)
        )
        self.frame_number += 1
        cto, rto = self.model.observe(
            truth, self.rng, stamp, self.frame_number, base_from_rto @ self.slip
        )
        if "cto" in self.hidden or (
            self.check_view and not in_certus_view(cto.position) and self.rig == "certus"
        ):
            cto = dataclasses.replace(cto, valid=False)
        if "rto" in self.hidden:
            rto = dataclasses.replace(rto, valid=False)
        if self.corrupt:
            cto = dataclasses.replace(cto, position=(math.nan, 0.0, 0.0))
        self.cto.write(cto)
        self.rto.write(rto)

    @operation
    def occlude(self, tool: str, hidden: bool = True) -> None:
        """Hide (or show again) `cto` or `rto`."""
        if tool not in ("cto", "rto"):
            raise ValueError(f"unknown tool {tool!r} (cto, rto)")
        (self.hidden.add if hidden else self.hidden.discard)(tool)

    @operation
    def crash(self, crashed: bool = True) -> None:
        """Stop (or resume) publishing, like a driver that died."""
        self.crashed = crashed

    @operation
    def corrupt_data(self, corrupt: bool = True) -> None:
        """Publish NaN positions."""
        self.corrupt = corrupt

    @operation
    def bump_reference(self, dx: float = 0.02) -> None:
        """Someone bumps this tracker's reference tool by `dx` metres along its x axis:
        it slips on its mount while the head, the sensor and the robot stay, so the robot's
        pose relative to it (what the calibration maps) is now wrong."""
        self.slip = self.slip @ rigid((dx, 0, 0), (0, 0, 0))
