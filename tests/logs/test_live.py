"""`simulate --live`: a Foxglove WebSocket client on loopback receives the run as it goes, the
same messages as run.mcap, and the server is gone when the test is done."""

from __future__ import annotations

import json
import struct
import threading

import pytest
from mcap.reader import make_reader
from paths import REPO
from websockets.sync.client import connect

from rodctl.config import load_config
from rodctl.logs.live import LiveView
from rodctl.logs.mcap import CHANNELS
from rodctl.simulate import simulate

TIMEOUT_S = 120.0  # generous: the machine may be loaded
SUBPROTOCOL = "foxglove.sdk.v1"  # the SDK's; Foxglove also offers foxglove.websocket.v1


def _small_config():
    return load_config(
        REPO / "configs/default.yaml",
        [
            "feature.type=bezier",
            "rod.segments=20",
            "run.max_steps=12",
            "run.expect=null",
            "logging.rerun=false",
            "logging.figures=false",
        ],
    )


def _advertised(ws) -> dict[int, str]:
    """channel id -> topic, from the server's first messages (serverInfo, advertise...)."""
    channels: dict[int, str] = {}
    while len(channels) < len(CHANNELS):
        msg = json.loads(ws.recv(timeout=TIMEOUT_S))
        if msg["op"] == "advertise":
            channels.update({c["id"]: c["topic"] for c in msg["channels"]})
    return channels


def test_a_live_run_reaches_a_foxglove_websocket_client(tmp_path):
    cfg = _small_config()
    received: list[tuple[str, int, bytes]] = []
    with LiveView(cfg.logging, port=0) as view:
        with connect(view.url, subprotocols=[SUBPROTOCOL], open_timeout=TIMEOUT_S) as ws:
            assert ws.subprotocol == SUBPROTOCOL
            channels = _advertised(ws)
            assert set(channels.values()) == {topic for topic, _ in CHANNELS}
            subs = [{"id": i, "channelId": c} for i, c in enumerate(channels)]
            ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
            topic_of = {s["id"]: channels[s["channelId"]] for s in subs}
            assert view.wait_for_client(timeout=TIMEOUT_S)

            def listen() -> None:
                while True:
                    data = ws.recv(timeout=TIMEOUT_S)
                    if isinstance(data, str):
                        continue  # status / (un)advertise text messages
                    assert data[0] == 0x01  # message data: opcode, subscription, log time
                    sub, log_time = struct.unpack_from("<IQ", data, 1)
                    received.append((topic_of[sub], log_time, bytes(data[13:])))
                    if topic_of[sub] == "/run/summary":
                        return

            listener = threading.Thread(target=listen, daemon=True)
            listener.start()
            result = simulate(cfg, tmp_path, live=view)
            listener.join(TIMEOUT_S)
            assert not listener.is_alive(), "the summary never arrived"
    with pytest.raises(OSError):  # the server is stopped: nothing listens on its port any more
        connect(view.url, open_timeout=5).close()
    # What the client saw, message for message, is what run.mcap holds.
    with open(result.run.path / "run.mcap", "rb") as fh:
        logged = [(c.topic, m.log_time, m.data) for _, c, m in make_reader(fh).iter_messages()]
    steps = json.loads((result.run.path / "summary.json").read_text())["steps"]
    live_steps = [m for m in received if m[0] == "/rod/state"]
    assert len(live_steps) == steps + 1  # the initial observation and every step
    for topic in ("/rod/state", "/control", "/world/rod", "/tf", "/camera/calibration"):
        mine = [m for m in received if m[0] == topic]
        assert mine == [m for m in logged if m[0] == topic], topic


def test_a_taken_port_is_one_clear_error():
    from rodctl.errors import UserError

    with LiveView(port=0) as first:
        with pytest.raises(UserError, match=f"127.0.0.1:{first.port}.*--live-port"):
            LiveView(port=first.port).start()
