"""The simulated operating room as MuJoCo bodies: table, patient head, target, tools.

Only what the physics or a viewer needs: the arm comes from `components.robot.lwr4`;
trackers and cameras simulate their sensing elsewhere (they need poses, not bodies).
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
    </body>"""
