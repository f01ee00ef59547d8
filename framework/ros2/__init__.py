"""ROS 2 topics for fw, without ROS installed (docs/ros2.md).

`rmw` is what rmw_zenoh expects on the wire (keys, liveliness tokens, attachments),
`convert` turns fw samples into ROS messages and back (CDR and type hashes from
rosbags), `link` is the bridge process's own session on the ROS network, `bridge` the
components that copy one topic each way, and `section` writes a topology's `ros2:`
section out into those components. `router` runs a Zenoh router for ROS nodes where
no rmw_zenohd runs (tests, a laptop without ROS).
"""
