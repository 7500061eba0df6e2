"""`vrsim run --live`: a WebSocket client speaking the Foxglove protocol (ws-protocol spec:
JSON `serverInfo`/`advertise`/`subscribe`, binary message data `0x01 | u32 subscription |
u64 log time | payload`) sees the file's channels and, message for message, its data."""

from __future__ import annotations

import base64
import json
import socket
import struct
import subprocess
import sys
import time

import pytest
from mcap.reader import make_reader

import mcap_messages
from conftest import REPO, SCENARIOS

websockets = pytest.importorskip("websockets.sync.client")

SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def connect(port: int, process, deadline_s: float = 30.0):
    """Connect once the server listens; fail if the run exits first."""
    start = time.monotonic()
    while True:
        try:
            return websockets.connect(f"ws://127.0.0.1:{port}", subprotocols=SUBPROTOCOLS,
                                      open_timeout=5, max_size=None)
        except OSError:
            assert process.poll() is None, process.communicate()
            assert time.monotonic() - start < deadline_s, "the live server never listened"
            time.sleep(0.05)


def test_a_client_sees_the_files_channels_and_messages(tmp_path):
    port = free_port()
    out = tmp_path / "live.mcap"
    process = subprocess.Popen(
        [sys.executable, "-m", "vrsim_cli", "run", str(SCENARIOS / "bounce.yaml"), "--live",
         "--live-port", str(port), "--duration", "0.3", "-o", str(out)],
        cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        channels, received = {}, {}
        with connect(port, process) as ws:
            ws_deadline = time.monotonic() + 60
            subscribed: set = set()
            while time.monotonic() < ws_deadline:
                try:
                    frame = ws.recv(timeout=5)
                except TimeoutError:
                    continue
                except Exception:  # noqa: BLE001 - the server closed: the run is over
                    break
                if isinstance(frame, str):
                    op = json.loads(frame)
                    if op["op"] == "advertise":
                        for ch in op["channels"]:
                            channels[ch["id"]] = ch
                    new = [cid for cid in channels if cid not in subscribed]
                    if new:  # as Foxglove does: subscribe to channels as they are advertised
                        ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                            {"id": cid, "channelId": cid} for cid in new]}))
                        subscribed.update(new)
                    continue
                opcode, sub, log_time = struct.unpack_from("<BIQ", frame)
                if opcode == 1:
                    received.setdefault(channels[sub]["topic"], []).append(
                        (log_time, bytes(frame[13:])))
        stdout, stderr = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 0, stderr
    assert "live: serving bounce on ws://localhost:" in stderr
    file_messages, file_schemas = {}, {}
    with open(out, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages():
            file_schemas[channel.topic] = schema
            file_messages.setdefault(channel.topic, []).append((message.log_time, message.data))
    # the same channels, with the SDK's schemas
    assert {ch["topic"] for ch in channels.values()} == set(file_schemas)
    for ch in channels.values():
        assert ch["encoding"] == "protobuf" and ch["schemaEncoding"] == "protobuf"
        assert ch["schemaName"] == file_schemas[ch["topic"]].name
        assert base64.b64decode(ch["schema"]) == mcap_messages.reference_schema(ch["schemaName"])
    # and message for message the file's data (a client that subscribed before the run)
    assert received == file_messages
    assert len(received["/tf"]) == 31  # 0.3 s at the output rate of 100 Hz, both ends
    for _, data in received["/tf"]:
        mcap_messages.decode("foxglove.FrameTransforms", data)


def test_live_refuses_a_taken_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        result = subprocess.run([sys.executable, "-m", "vrsim_cli", "run",
                                 str(SCENARIOS / "projectile.yaml"), "--live", "--live-port",
                                 str(port)], cwd=REPO, capture_output=True, text=True,
                                timeout=60)
    assert result.returncode == 2
    assert "--live: cannot serve on 127.0.0.1" in result.stderr and "Traceback" not in \
        result.stderr


def test_a_client_that_subscribes_to_scene_later_gets_the_scene_again():
    """The file holds each shape once; the live view re-sends the scene as it stands to a
    client subscribing to /scene in the middle of a run (it would see no shapes)."""
    from vrsim_cli.model.model import compile_model
    from vrsim_cli.model.state import make_state
    from vrsim_cli.scene.spec import load_scene
    from vrsim_cli.writers.live import LiveServer
    from vrsim_cli.writers.mcap_writer import McapWriter

    model = compile_model(load_scene(SCENARIOS / "fountain.yaml"))
    writer = McapWriter(model, None, live=LiveServer("fountain"))
    sent = []
    writer.live_outlet.log = lambda topic, data, ns: sent.append((topic, ns, data))
    state = make_state(model)
    writer.write(state)
    writer.write(state.replace(step=50, t=0.1))  # particles 1..10 appear
    scenes = [data for topic, _, data in sent if topic == "/scene"]
    assert len(scenes) == 2
    writer.live.scene_wanted.set()
    writer.write(state.replace(step=100, t=0.2))
    scenes = [(ns, data) for topic, ns, data in sent if topic == "/scene"]
    resent = mcap_messages.decode("foxglove.SceneUpdate", scenes[-1][1])
    ids = {e["id"] for e in resent["entities"]}
    # the whole scene up to now: the basin and every particle emitted by t = 0.2 s
    assert ids == {"basin"} | {f"drop.{k:04d}" for k in range(21)}
    writer.close()


def _serve_nothing():
    from vrsim_cli.writers.live import LiveServer

    refused = []
    server = LiveServer("x")
    server.start(0, on_refused=refused.append)
    return server, refused


@pytest.mark.parametrize("offered", [["foxglove.websocket.v1"], ["foxglove.sdk.v1"],
                                     ["foxglove.websocket.v1", "foxglove.sdk.v1"]])
def test_clients_of_either_subprotocol_name_are_served(offered):
    """The SDK's server alone turned away clients offering only the protocol's older
    name with "handshake failed"; the relay in front of it serves them under that name."""
    server, refused = _serve_nothing()
    try:
        with websockets.connect(f"ws://127.0.0.1:{server.port}", subprotocols=offered,
                                open_timeout=5) as ws:
            assert ws.subprotocol == ("foxglove.sdk.v1" if "foxglove.sdk.v1" in offered
                                      else "foxglove.websocket.v1")
            hello = json.loads(ws.recv(timeout=5))
            assert hello["op"] == "serverInfo" and hello["name"] == "vrsim: x"
    finally:
        server.close(linger=False)
    assert refused == []


@pytest.mark.parametrize("offered", [None, ["json"]])
def test_other_clients_are_told_why(offered):
    from websockets.exceptions import InvalidStatus

    server, refused = _serve_nothing()
    try:
        with pytest.raises(InvalidStatus) as turned:
            websockets.connect(f"ws://127.0.0.1:{server.port}", subprotocols=offered,
                               open_timeout=5)
    finally:
        server.close(linger=False)
    response = turned.value.response
    assert response.status_code == 400
    reason = bytes(response.body).decode()
    assert "offer the subprotocol foxglove.sdk.v1 or foxglove.websocket.v1" in reason
    assert f"this client offered: {'json' if offered else 'none'}" in reason
    assert refused == [f"turned away a client: {reason}"]  # the run prints it too


def test_live_without_o_writes_no_file_and_serves_an_old_client(tmp_path):
    """--live without -o: nothing written (the scene's output.file stays as it was), a note
    says so; the run is served to a client that knows only foxglove.websocket.v1."""
    import shutil

    shutil.copy(SCENARIOS / "projectile.yaml", tmp_path / "projectile.yaml")
    (tmp_path / "projectile.mcap").write_bytes(b"an earlier run")
    port = free_port()
    process = subprocess.Popen(
        [sys.executable, "-m", "vrsim_cli", "run", "projectile.yaml", "--live",
         "--live-port", str(port), "--duration", "0.05"],
        cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        start, got = time.monotonic(), 0
        while True:
            try:
                ws = websockets.connect(f"ws://127.0.0.1:{port}",
                                        subprotocols=["foxglove.websocket.v1"], open_timeout=5)
                break
            except OSError:
                assert process.poll() is None, process.communicate()
                assert time.monotonic() - start < 60, "the live server never listened"
                time.sleep(0.05)
        with ws:
            while True:
                try:
                    frame = ws.recv(timeout=20)
                except Exception:  # noqa: BLE001 - the server closed: the run is over
                    break
                if isinstance(frame, str) and json.loads(frame)["op"] == "advertise":
                    ws.send(json.dumps({"op": "subscribe", "subscriptions": [
                        {"id": ch["id"], "channelId": ch["id"]}
                        for ch in json.loads(frame)["channels"]]}))
                elif not isinstance(frame, str):
                    got += 1
        stdout, stderr = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 0, stderr
    assert got > 0  # messages reached the old client
    assert (tmp_path / "projectile.mcap").read_bytes() == b"an earlier run"
    assert "note: --live writes no file; output.file 'projectile.mcap' is left alone" in stderr
    assert "(no output: use -o FILE)" in stdout
