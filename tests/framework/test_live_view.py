"""Specs of Foxglove's live view (framework/live_view.py, issue 48): a real WebSocket
client speaking Foxglove's protocol subscribes and gets the same messages a recording
holds; it is never served beyond loopback."""

from __future__ import annotations

import asyncio
import base64
import json
import struct

import pytest

from framework.live_view import LiveView, LiveViewError
from framework.messages import Pose

PROTOCOL = "foxglove.sdk.v1"


def test_it_is_never_served_beyond_loopback():
    with pytest.raises(LiveViewError, match=r"loopback only.*no authentication"):
        LiveView(0, host="0.0.0.0")


def test_a_foxglove_client_sees_the_recorded_poses_and_the_log(hub):
    """A recorder with no file feeds the live view: a client subscribed to `/tf` gets
    the pose written on a recorded key, as a FrameTransforms it decodes by the schema
    the server advertised; `/fw/log` is advertised too."""
    from mcap.records import Schema
    from mcap_protobuf.decoder import DecoderFactory

    from framework.ports import OutputPort
    from framework.recorder import FlightRecorder

    live = LiveView(0)
    recorder = FlightRecorder(None, hub, {"test/tool": "Pose"}, live=live)
    out: OutputPort[Pose] = OutputPort("tool", Pose)
    out.bus = hub
    out.connect("test/tool")

    async def watch() -> tuple[dict, bytes]:
        import websockets

        uri = f"ws://127.0.0.1:{live.port}"
        async with websockets.connect(uri, subprotocols=[PROTOCOL]) as ws:
            channels: dict[str, dict] = {}
            recorder.write("/fw/components", "fw.ComponentState", {"component": "c"})
            out.write(Pose((0.25, 0.0, 0.5), stamp=3.0))  # advertises /tf
            while "/tf" not in channels or "/fw/log" not in channels:
                message = json.loads(await asyncio.wait_for(ws.recv(), 10))
                if message.get("op") == "advertise":
                    channels.update({c["topic"]: c for c in message["channels"]})
            tf = channels["/tf"]
            await ws.send(
                json.dumps({"op": "subscribe", "subscriptions": [{"id": 7, "channelId": tf["id"]}]})
            )
            while True:
                out.write(Pose((0.25, 0.0, 0.5), stamp=3.0))
                try:
                    frame = await asyncio.wait_for(ws.recv(), 1)
                except TimeoutError:
                    continue
                if isinstance(frame, bytes) and frame[0] == 1:  # message data
                    subscription, _ = struct.unpack_from("<IQ", frame, 1)
                    assert subscription == 7
                    return tf, frame[13:]

    try:
        tf, payload = asyncio.run(watch())
    finally:
        recorder.close()
        live.close()
    data = base64.b64decode(tf["schema"])
    schema = Schema(id=1, name=tf["schemaName"], encoding="protobuf", data=data)
    message = DecoderFactory().decoder_for("protobuf", schema)(payload)
    (transform,) = message.transforms
    assert transform.child_frame_id == "test/tool"
    assert transform.translation.x == 0.25 and transform.translation.z == 0.5
