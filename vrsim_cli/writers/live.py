"""The live view (`vrsim run --live`): the run served over the Foxglove WebSocket protocol.

Layer 6. The Foxglove SDK's server (`foxglove.start_server`) on 127.0.0.1 only: Foxglove
connects to `ws://localhost:8765` ("Open connection", "Foxglove WebSocket") and shows the
run as it is simulated. The MCAP writer (`mcap_writer.McapWriter`) logs each message to
this server's context as it logs it to the file, so the live view has the file's channels
and messages.

A client that subscribes to `/scene` after the bodies were published would see no shapes:
each such subscription asks the writer to send the current scene again, to the live view
only (the file holds each entity once).

The SDK's server accepts only the subprotocol `foxglove.sdk.v1` and turns away clients
that offer the older name of the same protocol, `foxglove.websocket.v1` (ws-protocol's
spec; older Foxglove apps and client libraries), with "handshake failed" and no reason.
So the port the user connects to is a small relay (`_Relay`) in front of the SDK's server
(which listens on another, private port): it reads each client's HTTP upgrade request,
lets `foxglove.sdk.v1` through as it is, renames an offered `foxglove.websocket.v1` to it
(and the server's answer back), and answers any other client with HTTP 400 and the reason,
which the run also prints. After the handshake it copies bytes both ways untouched.
"""

from __future__ import annotations

import re
import socket
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

    def start(self, port: int = DEFAULT_PORT, on_refused=None) -> None:
        """Listen on HOST:`port`. `on_refused(reason)` hears of each client turned away
        (from the relay's thread)."""
        import foxglove

        try:
            public = socket.create_server((HOST, port))
        except OSError as exc:
            raise InputError(f"--live: cannot serve on {HOST}:{port} ({exc.strerror or exc}); "
                             f"is another run serving there? choose a port with --live-port"
                             ) from None
        try:
            self.server = foxglove.start_server(name=f"vrsim: {self.name}", host=HOST,
                                                port=0, context=self.context,
                                                server_listener=_Listener(self))
        except RuntimeError as exc:  # the SDK reports a failure to listen as RuntimeError
            public.close()
            raise InputError(f"--live: cannot serve on {HOST} ({exc})") from None
        self.relay = _Relay(public, self.server.port, on_refused)
        self._port = public.getsockname()[1]

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
        self.relay.close()
        self.server.stop()
        self.server = None


SUBPROTOCOL = "foxglove.sdk.v1"  # what the SDK's server speaks
OLD_SUBPROTOCOL = "foxglove.websocket.v1"  # the same protocol's earlier name
MAX_HEAD = 16384  # bytes of an HTTP upgrade request or answer
_PROTOCOL_HEADER = re.compile(rb"^sec-websocket-protocol:[ \t]*([^\r\n]*?)[ \t]*(?=\r?$)",
                              re.I | re.M)


class _Relay:
    """The live view's public port: a thread accepting clients, each relayed to the SDK's
    server at 127.0.0.1:`target` (see the module docstring)."""

    def __init__(self, listener: socket.socket, target: int, on_refused=None):
        self.listener, self.target, self.on_refused = listener, target, on_refused
        self.open: set = set()
        self.lock = threading.Lock()
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        while True:
            try:
                client, _ = self.listener.accept()
            except OSError:  # closed: the run is over
                return
            threading.Thread(target=self._serve, args=(client,), daemon=True).start()

    def _serve(self, client: socket.socket) -> None:
        self._track(client)
        try:
            client.settimeout(10.0)
            head, rest = _read_head(client)
            offered = _offered(head)
            if SUBPROTOCOL in offered:
                renamed = None
            elif OLD_SUBPROTOCOL in offered:
                renamed = OLD_SUBPROTOCOL
                head = _PROTOCOL_HEADER.sub(
                    b"Sec-WebSocket-Protocol: " + SUBPROTOCOL.encode(), head, count=1)
            else:
                self._refuse(client, offered)
                return
            server = socket.create_connection((HOST, self.target), timeout=10.0)
            self._track(server)
            server.sendall(head + rest)
            answer, more = _read_head(server)
            if renamed is not None:  # the client must see the name it offered
                answer = _PROTOCOL_HEADER.sub(
                    b"Sec-WebSocket-Protocol: " + renamed.encode(), answer, count=1)
            client.sendall(answer + more)
            client.settimeout(None)
            server.settimeout(None)
            threading.Thread(target=_pump, args=(server, client), daemon=True).start()
            _pump(client, server)
        except (OSError, ValueError):
            pass  # a client that went away or spoke no HTTP: nothing to relay
        finally:
            client.close()

    def _refuse(self, client: socket.socket, offered: list) -> None:
        shown = ", ".join(offered) if offered else "none"
        reason = (f"the live view speaks the Foxglove WebSocket protocol: offer the "
                  f"subprotocol {SUBPROTOCOL} or {OLD_SUBPROTOCOL} (this client offered: "
                  f"{shown})")
        body = reason.encode("utf-8", "replace")
        if self.on_refused is not None:  # said before the reply: once the client has its
            # answer, the run may already be closing (a test read the log too early)
            self.on_refused(f"turned away a client: {reason}")
        client.sendall(b"HTTP/1.1 400 Bad Request\r\nContent-Type: text/plain; charset=utf-8"
                       b"\r\nContent-Length: " + str(len(body)).encode() +
                       b"\r\nConnection: close\r\n\r\n" + body)

    def _track(self, sock: socket.socket) -> None:
        with self.lock:
            self.open.add(sock)

    def close(self) -> None:
        self.listener.close()
        with self.lock:
            for sock in self.open:
                try:
                    sock.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass
                sock.close()


def _read_head(sock: socket.socket) -> tuple[bytes, bytes]:
    """(HTTP head up to and with its blank line, the bytes read after it)."""
    data = b""
    while b"\r\n\r\n" not in data:
        chunk = sock.recv(4096)
        if not chunk or len(data) > MAX_HEAD:
            raise ValueError("no HTTP head")
        data += chunk
    end = data.index(b"\r\n\r\n") + 4
    return data[:end], data[end:]


def _offered(head: bytes) -> list[str]:
    """The subprotocols a client's upgrade request offers, in its order."""
    return [p.strip().decode("latin-1") for m in _PROTOCOL_HEADER.finditer(head)
            for p in m.group(1).split(b",") if p.strip()]


def _pump(source: socket.socket, sink: socket.socket) -> None:
    """Copy bytes until either side closes, then close both ways."""
    try:
        while True:
            data = source.recv(65536)
            if not data:
                break
            sink.sendall(data)
    except OSError:
        pass
    for sock in (source, sink):
        try:
            sock.shutdown(socket.SHUT_RDWR)
        except OSError:
            pass
