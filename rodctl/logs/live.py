"""The live view: a run streamed to Foxglove over its WebSocket protocol while it goes.

`rodctl simulate --live` starts a Foxglove WebSocket server on localhost (foxglove-sdk) and
waits for a client to subscribe, since a default run is over in about a second, before a
person could connect: open Foxglove, "Open connection", `ws://127.0.0.1:8765`, and the run
starts. The live channels are the MCAP log's (`rodctl.logs.mcap.CHANNELS`), with the same
official schemas and the same messages built by the same functions (`mcap.step_messages`),
so a layout made for `run.mcap` works on the live view and the other way round; a dual-arm
view (`arms=2`) serves the x0 end's `/rod/clamp` too, as a dual-arm run.mcap holds it. Message times
are the MCAP's log times (simulated time since 2000-01-01), not the wall clock.

Only clients on this machine can connect (the server binds 127.0.0.1 unless told otherwise).
What the server sends goes to clients subscribed when it is sent: a client that connects once
the run has begun misses the header, the target and the camera's place (sent at the start).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from typing import Any

from rodctl.config.logging import LoggingConfig
from rodctl.errors import UserError
from rodctl.logs import codec, schemas
from rodctl.records import RunHeader, RunSummary, StepRecord

#: Foxglove's default port: the app's "Open connection" dialog suggests ws://localhost:8765.
DEFAULT_PORT = 8765


#: `wait_for_client`: the quiet time after a viewer's latest subscription before the run
#: starts, and the longest it waits for that quiet (s).
SUBSCRIBE_QUIET_S = 0.2
SUBSCRIBE_SETTLE_S = 2.0


class LiveView:
    """A Foxglove WebSocket server with the MCAP's channels, and a sink streaming a run to it.

    Use as a context manager (the server stops on exit); `wait_for_client()` before the run;
    pass it among the episode's sinks. Closing the sink (the episode's end) does not stop the
    server: its owner does, when the viewer has had the last messages.

    Args:
        cfg: the logging config (frame rate and PNG level of the camera frames).
        host, port: where to listen; port 0 picks a free one (`port` then tells which).
        grace_s: leaving the context waits this long before stopping, if a client subscribed.
        arms: the rod's `rod.arms`; 2 also advertises `/rod/clamp` (the x0 end's pose), the
            channel run.mcap registers in dual-arm runs only. Known before the run, so the
            channel is there for a client that subscribes before the first step.
    """

    def __init__(
        self,
        cfg: LoggingConfig | None = None,
        host: str = "127.0.0.1",
        port: int = DEFAULT_PORT,
        grace_s: float = 0.0,
        arms: int = 1,
    ) -> None:
        self.cfg = cfg if cfg is not None else LoggingConfig()
        self.arms = arms
        self.grace_s = grace_s
        self.host = host
        self._requested_port = port
        self._server: Any = None
        self._context: Any = None
        self._channels: dict[str, Any] = {}
        self._subscribed = threading.Event()
        self._last_subscribe = 0.0  # monotonic time of the latest subscription
        self._header: RunHeader | None = None
        self._prev: StepRecord | None = None
        self._steps = 0
        self._last_ns = codec.LOG_EPOCH_NS
        self._views: dict = {}
        self._frames = codec.FrameSchedule(self.cfg.image_rate_hz)

    # ------------------------------------------------------------------------------ the server
    def start(self) -> LiveView:
        """Start the server and advertise every channel (once: a started view stays as is).

        Raises:
            UserError: the Foxglove SDK is not installed, or the port is taken (or cannot be
                bound), named.
        """
        if self._server is not None:
            return self
        try:
            import foxglove
            from foxglove.websocket import ServerListener
        except ImportError:
            raise UserError(
                "--live needs the Foxglove SDK: pip install 'rodctl[live]' (foxglove-sdk)"
            ) from None

        subscribed, view = self._subscribed, self

        class _Listener(ServerListener):
            def on_subscribe(self, client: Any, channel: Any) -> None:
                view._last_subscribe = time.monotonic()
                subscribed.set()

        # Kept: the server and the channels live in this context only as long as it does.
        self._context = context = foxglove.Context()
        try:
            self._server = foxglove.start_server(
                name="rodctl",
                host=self.host,
                port=self._requested_port,
                context=context,
                server_listener=_Listener(),
            )
        except Exception as exc:  # noqa: BLE001 - the SDK raises its own error types
            raise UserError(
                f"--live: cannot serve on {self.host}:{self._requested_port} ({exc}); "
                "is another live view running? Choose another port with --live-port"
            ) from None
        from rodctl.logs.mcap import CHANNELS

        channels = list(CHANNELS)
        if self.arms == 2:  # as run.mcap: registered last, in dual-arm runs only
            channels.append((codec.TOPIC_CLAMP_STATE, schemas.CLAMP_STATE))
        for topic, schema in channels:
            units = codec.UNITS.get(topic, {})
            if topic == codec.TOPIC_CLAMP_STATE:
                units = codec.CLAMP_UNITS
            self._channels[topic] = foxglove.Channel(
                topic,
                schema=foxglove.Schema(
                    name=schema["title"], encoding="jsonschema", data=schemas.schema_bytes(schema)
                ),
                message_encoding="json",
                context=context,
                metadata={f"unit.{k}": v for k, v in units.items()},
            )
        return self

    @property
    def port(self) -> int:
        """The port the server listens on."""
        return int(self._server.port) if self._server is not None else self._requested_port

    @property
    def url(self) -> str:
        return f"ws://{self.host}:{self.port}"

    def wait_for_client(
        self, timeout: float | None = None, stop: Callable[[], object] | None = None
    ) -> bool:
        """Wait until a client subscribes to a channel; False after `timeout` s or once `stop()`
        is true. Waits in short slices, so Ctrl-C gets through."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while not self._subscribed.wait(0.1):
            if stop is not None and stop():
                return False
            if deadline is not None and time.monotonic() > deadline:
                return False
        # A viewer subscribes channel by channel (the server takes them one at a time): the
        # run starts once no new subscription came for SUBSCRIBE_QUIET_S, within
        # SUBSCRIBE_SETTLE_S, so its first step reaches every channel asked for, not only
        # the first (seen on a loaded machine: the first /control message was lost).
        settle_end = time.monotonic() + SUBSCRIBE_SETTLE_S
        while time.monotonic() < settle_end:
            if time.monotonic() - self._last_subscribe >= SUBSCRIBE_QUIET_S:
                break
            time.sleep(0.02)
        return True

    def stop(self, grace_s: float = 0.0) -> None:
        """Stop the server (idempotent), after `grace_s` seconds if a client is subscribed (the
        server sends from its own thread: the last messages may still be on their way)."""
        server, self._server = self._server, None
        if server is not None:
            if grace_s > 0 and self._subscribed.is_set():
                time.sleep(grace_s)
            server.stop()
        self._context = None

    def __enter__(self) -> LiveView:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop(self.grace_s)

    # -------------------------------------------------------------------------------- the sink
    def _send(self, topic: str, t_ns: int, msg: dict[str, Any]) -> None:
        import orjson

        if topic == codec.TOPIC_CLAMP_STATE and topic not in self._channels:
            return  # a one-arm view (arms=1) fed a dual-arm run: run.mcap has /rod/clamp
        self._channels[topic].log(orjson.dumps(msg), log_time=t_ns)

    def open(self, header: RunHeader) -> None:
        """The header, the target, the camera's place and the opening log line."""
        from rodctl.logs.mcap import camera_messages, camera_views, log_message, target_scene

        if self._server is None:
            raise RuntimeError("LiveView.open before start()")
        self._header = header
        t0 = codec.LOG_EPOCH_NS
        self._views = camera_views(header.config_yaml)
        self._send(codec.TOPIC_HEADER, t0, codec.header_to_json(header))
        self._send(codec.TOPIC_TARGET_SCENE, t0, target_scene(t0, header))
        for topic, msg in camera_messages(self._views, 0, t0):
            self._send(topic, t0, msg)
        self._send(codec.TOPIC_LOG, t0, log_message(t0, *codec.open_log_line(header)))

    def write(self, record: StepRecord) -> None:
        """One step, as the MCAP writes it (frames at the same rate)."""
        from rodctl.logs.mcap import log_message, step_messages

        if self._header is None or self._server is None:
            return
        r = record
        t = codec.log_time_ns(r.sim_time)
        png = None
        if r.image is not None and self._frames.due(r):
            png = codec.FRAMES.submit(r.image, self.cfg.png_compression).result()
            self._frames.take(r)
        for topic, msg in step_messages(self._header, r, t, png, self._views):
            self._send(topic, t, msg)
        for level, text in codec.step_log_lines(self._prev, r):
            self._send(codec.TOPIC_LOG, t, log_message(t, level, text))
        self._prev = r
        self._steps += 1
        self._last_ns = max(self._last_ns, t)

    def close(self, summary: RunSummary | None, status: str) -> None:
        """The summary and the closing log line; the server keeps running (see the class)."""
        from rodctl.logs.mcap import log_message

        if self._header is None or self._server is None:
            return
        t = self._last_ns
        self._send(codec.TOPIC_SUMMARY, t, codec.summary_to_json(summary, status))
        level, text = codec.close_log_line(summary, status, self._steps)
        self._send(codec.TOPIC_LOG, t, log_message(t, level, text))
        self._header = None
