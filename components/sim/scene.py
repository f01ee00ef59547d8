"""The simulated operating room as MuJoCo bodies: table, patient head, target, tools.

Only what the physics or a viewer needs: the arm comes from `components.domain.lwr4`;
trackers and cameras are bodies with a fixed camera each (MuJoCo can render their
view); their sensing is simulated elsewhere.
The reference tool (RTO) is a mocap body so a scenario can bump it.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Scene:
    """Where things are in the robot base frame (m)."""

    head_center: tuple[float, float, float] = (0.60, 0.0, 0.02)
    head_radius: float = 0.09
    target: tuple[float, float, float] = (0.60, 0.0, 0.13)
    critical_radius: float = 0.05
    table_top: float = -0.07
    rto: tuple[float, float, float] = (0.45, -0.30, -0.06)
    cameras: tuple[tuple[tuple[float, float, float], tuple[float, float, float]], ...] = (
        ((0.6, -2.3, 1.3), (0.6, 0.0, 0.0)),
        ((2.8, 0.4, 1.3), (0.6, 0.0, 0.0)),
    )
    """Kinect (position, looks at), as in topologies/seeg.yaml."""

    def sensors(self) -> str:
        """Bodies for the trackers (from the synthetic rigs) and the cameras: for viewers."""
        from components.domain.geometry import invert, look_at, matrix_to_quat
        from components.domain.rigs import standard_rigs

        poses = {
            rig.name: invert(rig.rto_from_base) @ invert(rig.sensor_from_rto)
            for rig in standard_rigs()
        }
        poses.update({f"kinect_{i}": look_at(*c) for i, c in enumerate(self.cameras)})
        out = []
        for name, pose in poses.items():
            x, y, z = (float(v) for v in pose[:3, 3])
            q = " ".join(f"{v:.6g}" for v in matrix_to_quat(pose[:3, :3]))
            size = "0.15 0.04 0.03" if name.startswith("kinect") else "0.3 0.06 0.05"
            out.append(
                f'    <body name="{name}" pos="{x:.4g} {y:.4g} {z:.4g}" quat="{q}">\n'
                f'      <geom name="{name}_geom" type="box" size="{size}" rgba="0.15 0.15 0.2 1" '
                f'contype="0" conaffinity="0"/>\n'
                f'      <camera name="{name}_view" mode="fixed" quat="0 1 0 0"/>\n'
                f"    </body>"
            )
        return "\n".join(out)

    def bodies(self) -> str:
        """MJCF for the worldbody (indented for `lwr4.mjcf`)."""
        hx, hy, hz = self.head_center
        tx, ty, tz = self.target
        rx, ry, rz = self.rto
        top = self.table_top
        return f"""    <body name="table" pos="0.75 0 {top - 0.025:.4g}">
      <geom name="table_geom" type="box" size="0.45 0.35 0.025" rgba="0.55 0.65 0.75 1"/>
    </body>
    <body name="head" pos="{hx:.4g} {hy:.4g} {hz:.4g}">
      <geom name="head_geom" type="sphere" size="{self.head_radius:.4g}" rgba="0.95 0.8 0.7 1"
            contype="0" conaffinity="0"/>
    </body>
    <site name="target" pos="{tx:.4g} {ty:.4g} {tz:.4g}" size="0.005" rgba="1 0 0 1"/>
    <site name="critical_area" pos="{tx:.4g} {ty:.4g} {tz:.4g}" size="{self.critical_radius:.4g}"
          rgba="1 0.6 0 0.15"/>
    <body name="rto" mocap="true" pos="{rx:.4g} {ry:.4g} {rz:.4g}">
      <geom name="rto_geom" type="box" size="0.03 0.03 0.005" rgba="0.2 0.2 0.2 1"
            contype="0" conaffinity="0"/>
    </body>
{self.sensors()}"""
