"""`simulate --live`: a Foxglove WebSocket client on loopback receives the run as it goes, the
same messages as run.mcap, and the server is gone when the test is done."""

from __future__ import annotations

import json
import signal
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


def _small_config(arms: int = 1):
    return load_config(
        REPO / "configs/default.yaml",
        [
            "feature.type=bezier",
            "rod.segments=20",
            f"rod.arms={arms}",
            "run.max_steps=12",
            "run.expect=null",
            "logging.rerun=false",
            "logging.figures=false",
        ],
    )


def _advertised(ws, extra: int = 0) -> dict[int, str]:
    """channel id -> topic, from the server's first messages (serverInfo, advertise...);
    `extra`: channels beyond the MCAP's common ones (dual-arm: /rod/clamp)."""
    channels: dict[int, str] = {}
    while len(channels) < len(CHANNELS) + extra:
        msg = json.loads(ws.recv(timeout=TIMEOUT_S))
        if msg["op"] == "advertise":
            channels.update({c["id"]: c["topic"] for c in msg["channels"]})
    return channels


@pytest.mark.parametrize("arms", [1, 2])
def test_a_live_run_reaches_a_foxglove_websocket_client(tmp_path, arms):
    """One arm, and dual-arm (q = 6), whose live view serves /rod/clamp as run.mcap has it."""
    cfg = _small_config(arms)
    received: list[tuple[str, int, bytes]] = []
    clamp = ["/rod/clamp"] if arms == 2 else []
    with LiveView(cfg.logging, port=0, arms=arms) as view:
        url = view.url  # the port it chose (once stopped, a view knows only the one asked for)
        with connect(url, subprotocols=[SUBPROTOCOL], open_timeout=TIMEOUT_S) as ws:
            assert ws.subprotocol == SUBPROTOCOL
            channels = _advertised(ws, len(clamp))
            assert set(channels.values()) == {topic for topic, _ in CHANNELS} | set(clamp)
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
    _wait_until_refused(url)  # the server is stopped: nothing listens on its port any more
    # What the client saw, message for message, is what run.mcap holds.
    with open(result.run.path / "run.mcap", "rb") as fh:
        logged = [(c.topic, m.log_time, m.data) for _, c, m in make_reader(fh).iter_messages()]
    steps = json.loads((result.run.path / "summary.json").read_text())["steps"]
    live_steps = [m for m in received if m[0] == "/rod/state"]
    assert len(live_steps) == steps + 1  # the initial observation and every step
    assert {m[0] for m in logged} >= set(clamp)  # run.mcap has /rod/clamp in dual-arm runs
    for topic in ("/rod/state", "/control", "/world/rod", "/tf", "/camera/calibration", *clamp):
        mine = [m for m in received if m[0] == topic]
        assert mine == [m for m in logged if m[0] == topic], topic


def test_the_live_sink_of_the_registry_serves_a_run_chosen_by_config(tmp_path):
    """`logging.sinks: [{type: "live", port: P, wait_s: ...}]`: the same view selected by the
    config (rodctl/logs/sinks.py); it waits for the viewer before the first step, the client
    gets every step as run.mcap has it, and the server is stopped when the run ends."""
    import time

    port = _free_port()
    cfg = _small_config()
    cfg.logging.sinks = [{"type": "live", "port": port, "wait_s": TIMEOUT_S}]
    received: list[tuple[str, bytes]] = []

    def client() -> None:
        deadline = time.monotonic() + TIMEOUT_S
        while True:  # the server starts with the run
            try:
                ws = connect(f"ws://127.0.0.1:{port}", subprotocols=[SUBPROTOCOL], open_timeout=5)
                break
            except OSError:
                assert time.monotonic() < deadline, "the live sink never listened"
                time.sleep(0.1)
        with ws:
            channels = _advertised(ws)
            subs = [{"id": i, "channelId": c} for i, c in enumerate(channels)]
            ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
            topic_of = {s["id"]: channels[s["channelId"]] for s in subs}
            while True:
                data = ws.recv(timeout=TIMEOUT_S)
                if isinstance(data, str):
                    continue
                sub, _ = struct.unpack_from("<IQ", data, 1)
                received.append((topic_of[sub], bytes(data[13:])))
                if topic_of[sub] == "/run/summary":
                    return

    listener = threading.Thread(target=client, daemon=True)
    listener.start()
    result = simulate(cfg, tmp_path)
    listener.join(TIMEOUT_S)
    assert not listener.is_alive(), "the summary never arrived"
    with open(result.run.path / "run.mcap", "rb") as fh:
        logged = [(c.topic, m.data) for _, c, m in make_reader(fh).iter_messages()]
    for topic in ("/rod/state", "/control"):
        assert [m for m in received if m[0] == topic] == [m for m in logged if m[0] == topic]
    _wait_until_refused(f"ws://127.0.0.1:{port}")  # stopped with the run


def _wait_until_refused(url: str, timeout_s: float = 10.0) -> None:
    """Connections to `url` are refused within `timeout_s`: the server's listener closes as it
    stops (a connection in that window is accepted and dropped: retried)."""
    import time

    from websockets.exceptions import WebSocketException

    deadline = time.monotonic() + timeout_s
    while True:
        try:
            connect(url, open_timeout=5).close()
        except OSError:
            return
        except WebSocketException:
            pass  # the listener still closing
        assert time.monotonic() < deadline, f"{url} still served after the run"


def test_a_taken_port_is_one_clear_error():
    from rodctl.errors import UserError

    with LiveView(port=0) as first:
        with pytest.raises(UserError, match=f"127.0.0.1:{first.port}.*--live-port"):
            LiveView(port=first.port).start()


# --- Rerun: `simulate --live-rerun URL` ---------------------------------------------------------


def _free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow
def test_a_rerun_viewer_receives_the_recording_run_rrd_holds(tmp_path):
    """A Rerun server on loopback (the `rerun` CLI the SDK ships, saving what it receives, as a
    headless stand-in for the viewer) gets the same recording as the run's own run.rrd:
    `rerun rrd compare` finds no difference."""
    import os
    import shutil
    import subprocess
    import sys
    import time
    from pathlib import Path

    from typer.testing import CliRunner

    from rodctl.cli import app

    rerun_cli = shutil.which("rerun", path=str(Path(sys.executable).parent))
    assert rerun_cli, "rerun-sdk ships the `rerun` command"
    port = _free_port()
    received = tmp_path / "received.rrd"
    server = subprocess.Popen(
        [rerun_cli, "--bind", "127.0.0.1", "--port", str(port), "--save", str(received)],
        stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        env={**os.environ, "RUST_LOG": "warn"},
        start_new_session=True,  # its own group: the `rerun` wrapper starts the server binary
    )  # fmt: skip
    try:
        url = f"rerun+http://127.0.0.1:{port}/proxy"
        from rodctl.logs.rerun import check_viewer

        deadline = time.monotonic() + TIMEOUT_S
        while True:  # wait for the server to listen
            try:
                check_viewer(url, timeout=1.0)
                break
            except Exception:
                assert time.monotonic() < deadline and server.poll() is None, "no rerun server"
                time.sleep(0.1)
        args = ["simulate", str(REPO / "configs/default.yaml"), "-q", "-o", str(tmp_path / "runs"),
                "--live-rerun", url, "--set", "feature.type=bezier", "--set", "rod.segments=20",
                "--set", "run.max_steps=12", "--set", "run.expect=null",
                "--set", "logging.figures=false"]  # fmt: skip
        res = CliRunner().invoke(app, args)
        assert res.exit_code == 0, res.output
        run_rrd = Path(res.stdout.strip().splitlines()[-1]) / "run.rrd"
        deadline = time.monotonic() + TIMEOUT_S
        while True:  # the server writes what it received as it comes
            same = subprocess.run(
                [rerun_cli, "rrd", "compare", str(run_rrd), str(received)],
                capture_output=True, text=True, timeout=TIMEOUT_S,
            )  # fmt: skip
            if same.returncode == 0 or time.monotonic() > deadline:
                break
            time.sleep(0.5)
        assert same.returncode == 0, same.stdout + same.stderr
        assert received.stat().st_size > 0.5 * run_rrd.stat().st_size > 10_000  # a real run
    finally:
        # The group, not the wrapper alone: terminating the wrapper left the server binary
        # running after the test (one per run of the suite).
        os.killpg(server.pid, signal.SIGTERM)
        server.wait(timeout=30)


def test_live_rerun_without_a_viewer_says_so(tmp_path):
    from typer.testing import CliRunner

    from rodctl.cli import app

    url = f"rerun+http://127.0.0.1:{_free_port()}/proxy"
    res = CliRunner().invoke(
        app,
        ["simulate", str(REPO / "configs/default.yaml"), "-o", str(tmp_path), "--live-rerun", url],
    )
    assert res.exit_code == 2 and "no Rerun viewer listens there" in res.output, res.output
    assert not list(tmp_path.iterdir())  # bad input creates nothing
    res = CliRunner().invoke(
        app, ["simulate", str(REPO / "configs/default.yaml"), "--live-rerun", "http://x/"]
    )
    assert res.exit_code == 2 and "expected a Rerun gRPC url" in res.output
