"""The live view (`vrsim run --live`): the run served over the Foxglove WebSocket protocol.

Layer 6. The Foxglove SDK's server (`foxglove.start_server`) on 127.0.0.1 only: Foxglove
connects to `ws://localhost:8765` ("Open connection", "Foxglove WebSocket") and shows the
run as it is simulated. The MCAP writer (`mcap_writer.McapWriter`) logs each message to
this server's context as it logs it to the file, so the live view has the file's channels
and messages.

A client that subscribes to `/scene` after the bodies were published would see no shapes:
each such subscription asks the writer to send the current scene again, to the live view
only (the file holds each entity once).
"""

from __future__ import annotations

import threading
import time

from vrsim_cli.errors import InputError

DEFAULT_PORT = 8765  # Foxglove's default for WebSocket connections
HOST = "127.0.0.1"  # never beyond this machine
SETTLE_S = 0.5  # after the first subscription, time for a client's other subscriptions
LINGER_S = 1.0  # after the run, time for the last messages to reach the clients


class _Listener:
    """Server callbacks (on the SDK's thread): note subscriptions."""

    def __init__(self, server: "LiveServer"):
        self.server = server

    def on_subscribe(self, client, channel) -> None:
        self.server.subscribed.set()
        if channel.topic == "/scene":
            self.server.scene_wanted.set()

    def on_unsubscribe(self, client, channel) -> None:
        pass


class LiveServer:
    """A Foxglove WebSocket server on 127.0.0.1. Its `context` takes the run's channels
    first; `start(port)` then listens (0: any free port, see `.port`), so a client that
    connects at once is told of every channel in one advertisement."""

    def __init__(self, name: str):
        import foxglove

        self.name = name
        self.context = foxglove.Context()
        self.subscribed = threading.Event()
        self.scene_wanted = threading.Event()
        self.server = None
        self._port = None

    def start(self, port: int = DEFAULT_PORT) -> None:
        import foxglove

        try:
            self.server = foxglove.start_server(name=f"vrsim: {self.name}", host=HOST,
                                                port=port, context=self.context,
                                                server_listener=_Listener(self))
        except RuntimeError as exc:  # the SDK reports a taken port as a RuntimeError
            raise InputError(f"--live: cannot serve on {HOST}:{port} ({exc}); is another "
                             f"run serving there? choose a port with --live-port") from None
        self._port = self.server.port

    @property
    def port(self) -> int:
        return self._port

    @property
    def url(self) -> str:
        return f"ws://localhost:{self.port}"

    def wait_for_client(self, should_stop) -> bool:
        """Block until a client subscribes (then SETTLE_S more), or `should_stop()`.
        True when a client is there."""
        while not self.subscribed.wait(0.1):
            if should_stop():
                return False
        time.sleep(SETTLE_S)
        self.scene_wanted.clear()  # the run publishes the scene at its first sample
        return True

    def take_scene_request(self) -> bool:
        """True once after each subscription to /scene."""
        if self.scene_wanted.is_set():
            self.scene_wanted.clear()
            return True
        return False

    def resend_scene(self, writer, ns: int) -> None:
        """Send the scene as it stands to the live view only."""
        import foxglove.messages

        if writer.entities:
            update = foxglove.messages.SceneUpdate(entities=list(writer.entities.values()))
            writer.live_outlet.log("/scene", update.encode(), ns)

    def close(self, linger: bool = True) -> None:
        if self.server is None:
            return
        if linger:
            time.sleep(LINGER_S)
        self.server.stop()
        self.server = None
