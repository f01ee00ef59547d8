"""The KUKA LWR 4+ from its published kinematics: one table, two consumers.

The DH table below is the single source. `mjcf()` turns it into a MuJoCo model
(physics: the simulated robot), `Kinematics` into a Pinocchio model (forward
kinematics, Jacobians, link capsules for collision distances). A test checks
that both agree on the TCP pose for random joint values.

Sources:
- Kinematics (standard DH, a = 0): d = 0.3105, 0, 0.40, 0, 0.39, 0, 0.078 m;
  alpha = [pi/2, -pi/2, -pi/2, pi/2, pi/2, -pi/2, 0]. Jubien, Gautier, Janot,
  "Dynamic identification of the Kuka LWR robot using motor torques and noise
  filtering", IEEE ICRA 2014, Table I.
- Joint position limits +-170 deg (A1, A3, A5, A7) and +-120 deg (A2, A4, A6);
  velocity limits 110, 110, 128, 128, 204, 184, 184 deg/s; torques 176, 176,
  100, 100, 100, 38, 38 N m: KUKA LBR 4+ specification (KUKA Roboter GmbH).
- Link radii and masses are approximations of the LBR 4+ outline drawing
  (total ~16 kg); they shape the collision capsules and the simulated dynamics,
  not the kinematics.

The real arm is not its model. `ArmErrors` says how the simulated arm (MuJoCo)
differs from the nominal table the controller, the interpolator and the navigator
use; `LWR4_ERRORS` are the values of the simulated OR (docs/seeg.md, "The arm").
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from components.domain.kernel import _fwkernel

D = (0.3105, 0.0, 0.40, 0.0, 0.39, 0.0, 0.078)
ALPHA = (math.pi / 2, -math.pi / 2, -math.pi / 2, math.pi / 2, math.pi / 2, -math.pi / 2, 0.0)
POSITION_LIMIT = tuple(math.radians(v) for v in (170, 120, 170, 120, 170, 120, 170))
VELOCITY_LIMIT = tuple(math.radians(v) for v in (110, 110, 128, 128, 204, 184, 184))
TORQUE_LIMIT = (176.0, 176.0, 100.0, 100.0, 100.0, 38.0, 38.0)
LINK_MASS = (4.0, 4.0, 3.0, 2.7, 1.7, 1.6, 0.3)
LINK_RADIUS = (0.07, 0.07, 0.065, 0.065, 0.06, 0.06, 0.045)
TOOL_LENGTH = 0.10
"""Flange to TCP (the tip of the needle guide), m, along the flange's z."""
JOINTS = tuple(f"a{i}" for i in range(1, 8))
ARM_CONTACT = 'contype="2" conaffinity="1"'
"""The arm's geoms touch the room's (contype 1) but not each other: the capsules
overlap at every joint, and contacts there would be forces no real arm feels."""
HOME = (0.0, -0.45, 0.0, 1.45, 0.0, -1.25, 0.0)
"""A comfortable pose above the table (rad): elbow up, tool pointing down."""


@dataclass(frozen=True)
class ArmErrors:
    """How a real arm differs from its nominal kinematics: the errors a kinematic
    calibration would identify, and the joints' elasticity.

    * `joint_offset` (rad): the link's true angle is the encoder's reading plus this
      (the zero of each joint, set when the arm was mastered);
    * `link_error` (m): added to each link length `D`;
    * `tool_error` (m): the true TCP is this far from the nominal one, in the flange frame;
    * `joint_stiffness` (N m/rad, None: rigid): the gears twist under the torque the
      motors carry (gravity included); the encoders sit on the motor side, so the
      twist is not measured.
    """

    joint_offset: tuple[float, ...] = (0.0,) * 7
    link_error: tuple[float, ...] = (0.0,) * 7
    tool_error: tuple[float, float, float] = (0.0, 0.0, 0.0)
    joint_stiffness: tuple[float, ...] | None = None

    def lengths(self) -> tuple[float, ...]:
        """The true link lengths (m)."""
        return tuple(d + e for d, e in zip(D, self.link_error, strict=True))


NOMINAL = ArmErrors()
"""An arm exactly as its model (unit tests of the physics, the model's own checks)."""

LWR4_ERRORS = ArmErrors(
    joint_offset=tuple(math.radians(v) for v in (0.06, -0.09, 0.05, 0.10, -0.08, 0.07, -0.05)),
    link_error=(0.0006, 0.0, -0.0004, 0.0, 0.0005, 0.0, -0.0003),
    tool_error=(0.0004, -0.0003, 0.0005),
    joint_stiffness=(2.0e4, 2.0e4, 1.5e4, 1.5e4, 1.0e4, 1.0e4, 1.0e4),
)
"""The simulated OR's arm: mastering offsets of 0.05-0.1 deg, link lengths within
0.6 mm, a TCP 0.7 mm off, harmonic-drive joints of 1-2 x 10^4 N m/rad. Together they
put the TCP 2-4 mm off its nominal pose over the workspace, the size of error an
uncalibrated serial arm shows (geometric errors ~90% of it: Klimchik et al.,
"Optimization of measurement configurations for geometrical calibration of
industrial robot", 2013). Assumed magnitudes, not measurements of one LWR 4+."""


def _rx(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _quat_wxyz(rotation: np.ndarray) -> tuple[float, ...]:
    from components.domain.geometry import matrix_to_quat

    return matrix_to_quat(rotation)


def link_offset(i: int) -> np.ndarray:
    """The fixed transform from joint i's rotating frame to joint i+1's (DH: Tz(d) Rx(alpha))."""
    out = np.eye(4)
    out[:3, :3] = _rx(ALPHA[i])
    out[2, 3] = D[i]
    return out


def tool_offset(errors: ArmErrors = NOMINAL) -> np.ndarray:
    """Flange (frame 7) to TCP."""
    out = np.eye(4)
    out[:3, 3] = errors.tool_error
    out[2, 3] += TOOL_LENGTH
    return out


def dh_forward(q: np.ndarray, errors: ArmErrors = NOMINAL) -> np.ndarray:
    """Base to TCP by the DH product for encoder readings `q`: the reference both models
    are checked against (with `errors`: where the real arm's TCP is, gears rigid)."""
    out = np.eye(4)
    lengths = errors.lengths()
    for i, angle in enumerate(q):
        angle += errors.joint_offset[i]
        c, s = math.cos(angle), math.sin(angle)
        rz = np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
        link = link_offset(i)
        link[2, 3] = lengths[i]
        out = out @ rz @ link
    return out @ tool_offset(errors)


def link_frames(q: object) -> list[tuple[str, str, np.ndarray]]:
    """(parent, child, transform) of each link's frame in the one before it, base ->
    link1 ... link7 -> tcp, for encoder readings `q` (nominal table): what a viewer
    draws the arm with (a topology's `record:` entry, `links:`). Their product is
    `dh_forward(q)`."""
    frames = []
    parent = "base"
    for i, angle in enumerate(np.asarray(q, dtype=float)):
        c, s = math.cos(angle), math.sin(angle)
        rz = np.array([[c, -s, 0, 0], [s, c, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]])
        child = f"link{i + 1}"
        frames.append((parent, child, rz @ link_offset(i)))
        parent = child
    frames.append((parent, "tcp", tool_offset()))
    return frames


def link_poses(q: object) -> list[tuple[str, str, tuple[float, ...], tuple[float, ...]]]:
    """`link_frames` as (parent, child, position, quaternion (w, x, y, z)): the form a
    topology's `record:` entry takes for drawing the arm (`links:`, framework/scene.py)."""
    return [
        (parent, child, tuple(float(v) for v in m[:3, 3]), _quat_wxyz(m[:3, :3]))
        for parent, child, m in link_frames(q)
    ]


def _fmt(values: object) -> str:
    return " ".join(f"{float(v):.9g}" for v in values)  # type: ignore[attr-defined]


def robot_mjcf(
    kp: float = 2500.0, kv: float = 120.0, errors: ArmErrors = NOMINAL
) -> tuple[str, str]:
    """The arm as MJCF: (its <body> tree, its <actuator> entries).

    Bodies link1..link7 sit at joint frames; each hinge turns about its body's z;
    each link's capsule runs from its joint to the next joint's origin. Joints are
    driven by position servos limited to the rated torques; gravity is compensated
    in the bodies (the KUKA controller does the same), brakes are the interface's job.
    With `errors`, the bodies are the real arm's: the joints' zero offsets are the
    simulated arm's business (`SimulatedArm`), the lengths and the tool are here.
    """
    lines: list[str] = []
    D = errors.lengths()
    tool = errors.tool_error
    indent = "    "
    for i in range(7):
        pad = indent * (i + 1)
        pos = (0.0, 0.0, 0.0) if i == 0 else (0.0, 0.0, D[i - 1])
        quat = (1.0, 0.0, 0.0, 0.0) if i == 0 else _quat_wxyz(_rx(ALPHA[i - 1]))
        lines.append(
            f'{pad}<body name="link{i + 1}" pos="{_fmt(pos)}" quat="{_fmt(quat)}" gravcomp="1">'
        )
        limit = math.degrees(POSITION_LIMIT[i])
        lines.append(
            f'{pad}  <joint name="{JOINTS[i]}" axis="0 0 1" range="{-limit:.6g} {limit:.6g}" '
            f'damping="2" armature="0.1"/>'
        )
        length = max(D[i], 0.02)
        lines.append(
            f'{pad}  <geom name="link{i + 1}_geom" type="capsule" fromto="0 0 0 0 0 {length:.6g}" '
            f'size="{LINK_RADIUS[i]}" mass="{LINK_MASS[i]}" rgba="1 0.45 0.1 1" {ARM_CONTACT}/>'
        )
    pad = indent * 8
    lines.append(f'{pad}<site name="flange" pos="0 0 {D[6]:.6g}" size="0.01"/>')
    lines.append(
        f'{pad}<geom name="tool_geom" type="capsule" fromto="0 0 {D[6]:.6g} 0 0 '
        f'{D[6] + TOOL_LENGTH:.6g}" size="0.012" mass="0.2" rgba="0.8 0.8 0.85 1" {ARM_CONTACT}/>'
    )
    lines.append(
        f'{pad}<site name="tcp" pos="{tool[0]:.6g} {tool[1]:.6g} '
        f'{D[6] + TOOL_LENGTH + tool[2]:.6g}" size="0.006"/>'
    )
    for i in reversed(range(7)):
        lines.append(f"{indent * (i + 1)}</body>")
    actuators = [
        f'    <position name="{JOINTS[i]}_servo" joint="{JOINTS[i]}" kp="{kp}" kv="{kv}" '
        f'forcerange="{-TORQUE_LIMIT[i]} {TORQUE_LIMIT[i]}" ctrlrange="{-POSITION_LIMIT[i]:.6g} '
        f'{POSITION_LIMIT[i]:.6g}"/>'
        for i in range(7)
    ]
    return "\n".join(lines), "\n".join(actuators)


def mjcf(scene_bodies: str = "", errors: ArmErrors = NOMINAL) -> str:
    """A complete MJCF document: the arm (real, with `errors`) at the world origin plus
    `scene_bodies`."""
    arm, actuators = robot_mjcf(errors=errors)
    return f"""<mujoco model="lwr4plus">
  <compiler angle="degree" autolimits="true"/>
  <option timestep="0.001" integrator="implicitfast"/>
  <worldbody>
    <light pos="0 0 3" dir="0 0 -1"/>
    <geom name="floor" type="plane" pos="0 0 -0.8" size="3 3 0.1" rgba="0.85 0.85 0.85 1"/>
    <body name="base" pos="0 0 0">
      <geom name="base_geom" type="cylinder" fromto="0 0 -0.05 0 0 0" size="0.09" rgba="0.4 0.4 0.4 1" {ARM_CONTACT}/>
{arm}
    </body>
{scene_bodies}
  </worldbody>
  <actuator>
{actuators}
  </actuator>
</mujoco>
"""


@dataclass(frozen=True)
class Capsules:
    """Segments a-b (n x 3 each) with radii (n,): the robot's collision geometry."""

    a: np.ndarray
    b: np.ndarray
    radius: np.ndarray


class Kinematics:
    """Pinocchio model of the arm: TCP pose, Jacobian, link capsules for given joints."""

    def __init__(self) -> None:
        import pinocchio as pin

        self._pin = pin
        model = pin.Model()
        parent = 0
        placement = pin.SE3.Identity()
        for i in range(7):
            limit = POSITION_LIMIT[i]
            parent = model.addJoint(
                parent,
                pin.JointModelRZ(),
                placement,
                JOINTS[i],
                np.array([TORQUE_LIMIT[i]]),
                np.array([VELOCITY_LIMIT[i]]),
                np.array([-limit]),
                np.array([limit]),
            )
            com = np.array([0.0, 0.0, D[i] / 2])
            model.appendBodyToJoint(
                parent,
                pin.Inertia.FromCylinder(LINK_MASS[i], LINK_RADIUS[i], max(D[i], 0.02)),
                pin.SE3(np.eye(3), com),
            )
            offset = link_offset(i)
            placement = pin.SE3(offset[:3, :3], offset[:3, 3])
        flange = placement
        tcp = flange * pin.SE3(np.eye(3), np.array([0.0, 0.0, TOOL_LENGTH]))
        self.tcp_frame = model.addFrame(pin.Frame("tcp", parent, tcp, pin.FrameType.OP_FRAME))
        self.model = model
        self.data = model.createData()
        self.lower = np.array([-v for v in POSITION_LIMIT])
        self.upper = np.array(POSITION_LIMIT)
        self.velocity_limit = np.array(VELOCITY_LIMIT)
        self.placements = np.ascontiguousarray(
            [model.jointPlacements[j].homogeneous for j in range(1, 8)], dtype=float
        )
        """Each joint's frame in its parent's (7 x 4 x 4), for the compiled kernel."""
        self.tool = np.ascontiguousarray(model.frames[self.tcp_frame].placement.homogeneous)
        """The TCP in the last joint's frame (4 x 4)."""
        self._flange = np.ascontiguousarray(link_offset(6), dtype=float)
        """The flange in the last joint's frame (4 x 4)."""

    def tcp(self, q: np.ndarray) -> np.ndarray:
        """Base to TCP (4x4) for joints q."""
        pin = self._pin
        pin.framesForwardKinematics(self.model, self.data, np.asarray(q, dtype=float))
        return self.data.oMf[self.tcp_frame].homogeneous.copy()

    def jacobian(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(TCP pose 4x4, 6x7 Jacobian in the base-aligned TCP frame: linear then angular)."""
        pin = self._pin
        q = np.asarray(q, dtype=float)
        pose = self.tcp(q)
        jac = pin.computeFrameJacobian(
            self.model, self.data, q, self.tcp_frame, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED
        )
        return pose, jac

    def joint_origins(self, q: np.ndarray) -> np.ndarray:
        """Positions (10 x 3) of the base, the seven joint frames' origins, the flange and
        the TCP: in the compiled kernel where it was built (one call instead of ten of
        Pinocchio's), else `joint_origins_reference`, which a spec holds it to."""
        if _fwkernel is None:
            return self.joint_origins_reference(q)
        out = np.empty((10, 3))
        _fwkernel.joint_points(
            self.placements, self.tool, self._flange, np.ascontiguousarray(q, dtype=float), out
        )
        return out

    def joint_origins_reference(self, q: np.ndarray) -> np.ndarray:
        """`joint_origins` with Pinocchio's forward kinematics."""
        pin = self._pin
        pin.framesForwardKinematics(self.model, self.data, np.asarray(q, dtype=float))
        points = [np.zeros(3)]
        points += [self.data.oMi[j].translation.copy() for j in range(1, 8)]
        flange = self.data.oMi[7].homogeneous @ link_offset(6)
        points.append(flange[:3, 3])
        points.append(self.data.oMf[self.tcp_frame].translation.copy())
        return np.array(points)

    @cached_property
    def _capsule_spec(self) -> tuple[list[tuple[int, int]], np.ndarray]:
        # (from point, to point) over joint_origins(); frames 1/2, 3/4, 5/6 coincide,
        # so the arm is base-shoulder, shoulder-elbow, elbow-wrist, wrist-flange, tool
        pairs = [(0, 2), (3, 4), (5, 6), (7, 8), (8, 9)]
        radii = np.array([LINK_RADIUS[0], LINK_RADIUS[2], LINK_RADIUS[4], LINK_RADIUS[6], 0.012])
        return pairs, radii

    @cached_property
    def _capsule_ends(self) -> tuple[np.ndarray, np.ndarray]:
        pairs, _ = self._capsule_spec
        return np.array([i for i, _ in pairs]), np.array([j for _, j in pairs])

    def capsules(self, q: np.ndarray) -> Capsules:
        """The arm's collision capsules in the base frame for joints q."""
        points = self.joint_origins(q)
        starts, ends = self._capsule_ends
        return Capsules(points[starts], points[ends], self._capsule_spec[1].copy())

    def capsules_buffer(self) -> Capsules:
        """Capsules for `capsules_into` to write (the ends zero, this arm's radii)."""
        count = len(self._capsule_spec[0])
        return Capsules(np.zeros((count, 3)), np.zeros((count, 3)), self._capsule_spec[1].copy())

    def capsules_into(self, q: Sequence[float], out: Capsules) -> Capsules:
        """`capsules(q)` written into `out` (from `capsules_buffer`), for a loop that checks
        every new envelope without allocating; q any sequence of 7 numbers (an ArmState's
        tuple as it is). One call of the compiled kernel where it was built, which a
        spec holds to `capsules`."""
        if _fwkernel is None:
            got = self.capsules(np.asarray(q, dtype=float))
            out.a[:], out.b[:] = got.a, got.b
            return out
        _fwkernel.capsule_points(
            self.placements, self.tool, self._flange, q, self._capsule_pairs, out.a, out.b
        )
        return out

    @cached_property
    def _capsule_pairs(self) -> np.ndarray:
        # the kernel's form of the capsules' point pairs: (from, to) indices as float64
        return np.array(self._capsule_spec[0], dtype=float).reshape(-1)
