"""MCAP output is Foxglove-native: every message of every scenario decodes against the
Foxglove SDK's own schemas (tests/mcap_messages.py builds the decoders from
`foxglove.messages`, not from the file), the scene stands upright in a z-up world,
emitted particles appear when they are emitted, and the numpy-packed messages equal what
the SDK's own encoder makes of the same numbers."""

from __future__ import annotations

import math
import string
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import mcap_messages
from conftest import REPO, SCENARIOS
from vrsim_cli.loop import run
from vrsim_cli.maths.spatial import quat_rotate
from vrsim_cli.model.model import compile_model
from vrsim_cli.model.state import make_state
from vrsim_cli.scene.spec import load_scene, parse_scene
from vrsim_cli.tools.trajectory import read_trajectory
from vrsim_cli.writers import open_writer
from vrsim_cli.writers.foxglove_wire import FrameTransformsEncoder, StateEncoder

ALL = sorted(p.stem for p in SCENARIOS.glob("*.yaml"))


def write_mcap(model, path):
    writer = open_writer(model, path, "mcap")
    run(model, make_state(model), writer)
    writer.close()
    return path


@pytest.fixture(scope="module")
def scenario_files(tmp_path_factory):
    """name -> (model, MCAP path) of every scenario, run once."""
    folder = tmp_path_factory.mktemp("mcap")
    out = {}
    for name in ALL:
        model = compile_model(load_scene(SCENARIOS / f"{name}.yaml"))
        out[name] = model, write_mcap(model, folder / f"{name}.mcap")
    return out


def unit(q: dict) -> float:
    return math.sqrt(sum(float(q[c]) ** 2 for c in "xyzw"))


def check_entity(entity: dict, where: str) -> None:
    """What Foxglove needs of a SceneEntity beyond the schema: an id, a frame, colours in
    [0, 1], positive finite sizes, unit orientations."""
    assert entity["id"] and entity["frame_id"], where
    for kind in ("arrows", "cubes", "spheres", "cylinders", "models"):
        for prim in entity[kind]:
            rgba = [float(prim["color"][c]) for c in "rgba"]
            assert all(0.0 <= c <= 1.0 for c in rgba), where
            assert abs(unit(prim["pose"]["orientation"]) - 1.0) < 1e-9, where
            size = prim.get("size") or prim.get("scale")
            if size is not None:
                assert all(0.0 < float(size[c]) < 1e6 for c in "xyz"), where
    for prim in entity["arrows"]:
        assert prim["shaft_length"] > 0 and prim["head_length"] > 0, where


@pytest.mark.parametrize("name", ALL)
def test_every_message_decodes_with_the_sdk_schemas(name, scenario_files):
    model, path = scenario_files[name]
    messages, schemas = mcap_messages.read(path)  # decodes every message, strictly
    samples = len(messages["/vrsim/state"])
    assert samples == len(messages["/tf"]) >= 2
    assert {t for t, s in schemas.items() if s.startswith("foxglove.")} >= {"/tf", "/scene"}
    known_frames = {"world"}
    for ns, message in messages["/tf"]:
        for tf in message["transforms"]:
            assert mcap_messages.seconds(tf["timestamp"]) * 1e9 == pytest.approx(ns, abs=1)
            assert abs(unit(tf["rotation"]) - 1.0) < 1e-9
            assert all(math.isfinite(float(tf["translation"][c])) for c in "xyz")
            assert tf["parent_frame_id"] in known_frames | {tf["child_frame_id"]} or \
                tf["parent_frame_id"] == "scene"
            known_frames.add(tf["child_frame_id"])
    for topic in ("/scene", "/vrsim/contacts"):
        for ns, message in messages.get(topic, []):
            for entity in message["entities"]:
                check_entity(entity, f"{name} {topic} at {ns} ns")
                assert entity["frame_id"] in known_frames, (topic, entity["frame_id"])
    # every entity of the state has its transform at every sample where it exists
    state_names = messages["/vrsim/state"][-1][1]["entity"]
    last = {tf["child_frame_id"] for tf in messages["/tf"][-1][1]["transforms"]}
    assert last == set(state_names) | {"scene"}


def test_the_scene_stands_upright_in_a_z_up_world(scenario_files):
    """fountain is y-up (gravity -y): world -> scene turns scene +y into world +z, so its
    particles rise along world +z and gravity points along world -z."""
    model, path = scenario_files["fountain"]
    messages, _ = mcap_messages.read(path, topics=["/tf"])
    root = next(tf for tf in messages["/tf"][0][1]["transforms"]
                if tf["child_frame_id"] == "scene")
    assert root["parent_frame_id"] == "world"
    q = [float(root["rotation"][c]) for c in "wxyz"]
    assert np.allclose(quat_rotate(np.array(q), [0.0, 1.0, 0.0]), [0, 0, 1], atol=1e-15)
    g_world = quat_rotate(np.array(q), np.asarray(model.gravity, dtype=float))
    assert np.allclose(g_world, [0, 0, -9.81], atol=1e-12)


def test_output_up_z_keeps_a_z_up_scene_as_it_is(tmp_path):
    model = compile_model(parse_scene("""
vrsim: 1
duration: 0.1
frame_rate: 10
gravity: [0, 0, -9.81]
bodies: [{name: b, mass: 1, position: [0, 0, 1]}]
output: {up: z}
"""))
    messages, _ = mcap_messages.read(write_mcap(model, tmp_path / "z.mcap"), topics=["/tf"])
    root = next(tf for tf in messages["/tf"][0][1]["transforms"]
                if tf["child_frame_id"] == "scene")
    assert [float(root["rotation"][c]) for c in "wxyz"] == [1.0, 0.0, 0.0, 0.0]


def test_particles_appear_when_they_are_emitted(scenario_files):
    """fountain: particle k leaves the nozzle at k / rate = k / 100 s; its SceneEntity and
    its transform first appear at the first sample at or after that time (25 Hz)."""
    model, path = scenario_files["fountain"]
    messages, _ = mcap_messages.read(path, topics=["/tf", "/scene"])
    first_scene = {}
    for ns, message in messages["/scene"]:
        for entity in message["entities"]:
            first_scene.setdefault(entity["id"], ns / 1e9)
    first_tf = {}
    for ns, message in messages["/tf"]:
        for tf in message["transforms"]:
            first_tf.setdefault(tf["child_frame_id"], ns / 1e9)
    sample_times = np.array([ns / 1e9 for ns, _ in messages["/tf"]])
    for k in range(300):
        name = f"drop.{k:04d}"
        expected = sample_times[np.searchsorted(sample_times, k / 100 - 1e-9)]
        assert first_scene[name] == pytest.approx(expected, abs=1e-9), name
        assert first_tf[name] == pytest.approx(expected, abs=1e-9), name
    assert first_scene["basin"] == 0.0


@pytest.mark.parametrize("name", ["fountain", "bounce"])
def test_the_fountain_and_a_contact_scenario_read_back_through_the_sdk_decoders(
        name, scenario_files, tmp_path):
    """Opened with mcap's reader and decoders built from the SDK's schemas, the positions
    on /tf and the full state on /vrsim/state are the CSV output's numbers, bit for bit;
    bounce's raw contacts carry the first impact's impulse."""
    model, path = scenario_files[name]
    messages, _ = mcap_messages.read(path)
    csv_path = tmp_path / f"{name}.csv"
    writer = open_writer(model, csv_path, "csv")
    run(model, make_state(model), writer)
    writer.close()
    csv = read_trajectory(csv_path)
    for k, (ns, message) in enumerate(messages["/vrsim/state"]):
        names = message["entity"]
        pos = np.array(message["position"], dtype=float).reshape(len(names), 3)
        vel = np.array(message["velocity"], dtype=float).reshape(len(names), 3)
        for i in range(0, len(names), 37):
            track = csv.tracks[names[i]]
            assert track.t[k] == message["t"] and ns == round(message["t"] * 1e9)
            assert pos[i].tolist() == track.pos[k].tolist()
            assert vel[i].tolist() == track.vel[k].tolist()
    ns, last = messages["/tf"][-1]
    for tf in last["transforms"]:
        if tf["child_frame_id"] in csv.tracks:
            track = csv.tracks[tf["child_frame_id"]]
            assert [tf["translation"][c] for c in "xyz"] == track.pos[-1].tolist()
            assert [tf["rotation"][c] for c in "wxyz"] == track.quat[-1].tolist()
    if name == "bounce":
        hits = [c for _, m in messages["/vrsim/contacts/raw"] for c in m["contacts"]
                if c["toi"] != "NaN"]
        g = 9.81
        assert hits[0]["impulse"][1] == pytest.approx(1.8 * math.sqrt(2 * g * 1.0), rel=1e-9)


# ----------------------------------------------------------------------------- encoders

names = st.text(alphabet=string.ascii_letters + string.digits + "_.-é", min_size=1,
                max_size=70)
finite = st.floats(allow_nan=False, allow_infinity=False, width=64)


def sdk_frame_transforms(parent, children, ns, pos, quat):
    """The same transforms, encoded by the Foxglove SDK itself."""
    from foxglove.messages import FrameTransform, FrameTransforms, Quaternion, Timestamp, Vector3

    return FrameTransforms(transforms=[FrameTransform(
        timestamp=Timestamp(*divmod(ns, 1_000_000_000)), parent_frame_id=parent,
        child_frame_id=child, translation=Vector3(x=p[0], y=p[1], z=p[2]),
        rotation=Quaternion(x=q[1], y=q[2], z=q[3], w=q[0]))
        for child, p, q in zip(children, pos.tolist(), quat.tolist())]).encode()


def by_child(data: bytes) -> dict:
    decoded = mcap_messages.decode("foxglove.FrameTransforms", data)
    out = {tf["child_frame_id"]: tf for tf in decoded["transforms"]}
    assert len(out) == len(decoded["transforms"])
    return out


@settings(max_examples=60, deadline=None)
@given(children=st.lists(names, min_size=1, max_size=40, unique=True),
       ns=st.integers(0, 10 ** 13), data=st.data())
def test_packed_transforms_decode_like_the_sdks_own(children, ns, data):
    n = len(children)
    numbers = st.lists(finite, min_size=7 * n, max_size=7 * n)
    values = np.array(data.draw(numbers), dtype=float).reshape(n, 7)
    pos, quat = values[:, :3], values[:, 3:]
    rows = np.array(sorted(data.draw(st.sets(st.integers(0, n - 1), min_size=1))))
    encoder = FrameTransformsEncoder("scene", children)
    for _ in range(2):  # the second time from the cached layout
        ours = by_child(encoder.encode(ns, pos, quat, rows))
        sdk = by_child(sdk_frame_transforms("scene", [children[i] for i in rows], ns,
                                            pos[rows], quat[rows]))
        assert ours == sdk


@settings(max_examples=40, deadline=None)
@given(entity=st.lists(names, max_size=20), t=finite, step=st.integers(0, 2 ** 63),
       data=st.data())
def test_packed_state_decodes_like_the_protobuf_runtimes_own(entity, t, step, data):
    from vrsim_cli.writers.vrsim_messages import message_class

    n = len(entity)
    arrays = [np.array(data.draw(st.lists(finite, min_size=k * n, max_size=k * n)),
                       dtype=float).reshape(n, k) for k in (3, 4, 3, 3)]
    ours = StateEncoder(entity).encode(t, step, *arrays)
    reference = message_class("State")(
        t=t, step=step, entity=entity, position=arrays[0].ravel(),
        orientation=arrays[1].ravel(), velocity=arrays[2].ravel(),
        angular_velocity=arrays[3].ravel()).SerializeToString()
    assert mcap_messages.decode("vrsim.State", ours) == \
        mcap_messages.decode("vrsim.State", reference)


def test_output_cost_benchmark_runs():
    """benchmarks/output_cost.py (the 1 ms per sample budget is measured there, not here)
    runs and prints a row per format."""
    out = subprocess.run([sys.executable, str(REPO / "benchmarks" / "output_cost.py"),
                          "--bodies", "20", "--samples", "5", "--repeats", "1"],
                         capture_output=True, text=True, check=True, cwd=REPO)
    assert [line.split()[0] for line in out.stdout.splitlines()[2:]] == ["mcap", "csv", "tum"]


# ------------------------------------------------------------- files of other tools


def sdk_file(path, positions: dict, times, parent="map", json_channel=False):
    """An MCAP written by the Foxglove SDK alone, as another tool would: /tf with
    foxglove.FrameTransforms of each named frame at `times`, positions[name](t)."""
    import foxglove
    from foxglove.channels import FrameTransformsChannel
    from foxglove.messages import FrameTransform, FrameTransforms, Quaternion, Timestamp, Vector3

    context = foxglove.Context()
    with foxglove.open_mcap(path, context=context):
        channel = FrameTransformsChannel("/tf", context=context)
        other = foxglove.Channel("/odometry", context=context)  # a channel vrsim ignores
        for t in times:
            ns = round(t * 1e9)
            channel.log(FrameTransforms(transforms=[FrameTransform(
                timestamp=Timestamp(*divmod(ns, 1_000_000_000)), parent_frame_id=parent,
                child_frame_id=name, translation=Vector3(**dict(zip("xyz", f(t)))),
                rotation=Quaternion(x=0.0, y=0.0, z=math.sin(t / 2), w=math.cos(t / 2)))
                for name, f in positions.items()]), log_time=ns)
            other.log({"speed": t}, log_time=ns)
    return path


def test_info_and_compare_read_transforms_of_a_file_vrsim_did_not_write(invoke, tmp_path):
    times = [k / 10 for k in range(11)]
    robot = lambda t: (t, 2.0 - t * t, 0.5)  # noqa: E731
    arm = lambda t: (0.1, 0.2, t)  # noqa: E731
    theirs = sdk_file(tmp_path / "theirs.mcap", {"robot": robot, "arm": arm}, times)
    result = invoke("info", theirs)
    assert result.exit_code == 0, result.output
    assert result.stdout.splitlines()[0] == f"{theirs}: mcap, 2 entities, 11 samples"
    assert "entities: robot, arm" in result.stdout
    assert "tracks from /tf (transforms)" in result.stdout and "(map)" in result.stdout
    traj = read_trajectory(theirs)
    assert traj.tracks["robot"].pos.tolist() == [list(robot(t)) for t in times]
    assert np.allclose(traj.tracks["robot"].quat[:, 0], np.cos(np.array(times) / 2), atol=0)
    # the same motion as a vrsim CSV: equal positions and orientations (velocities skipped)
    rows = ["t,entity,px,py,pz,qw,qx,qy,qz,vx,vy,vz,wx,wy,wz"]
    for t in times:
        for name, f in (("robot", robot), ("arm", arm)):
            p = f(t)
            rows.append(f"{t!r},{name},{p[0]!r},{p[1]!r},{p[2]!r},{math.cos(t / 2)!r},0.0,0.0,"
                        f"{math.sin(t / 2)!r},0,0,0,0,0,0")
    ours = tmp_path / "ours.csv"
    ours.write_text("\n".join(rows) + "\n")
    same = invoke("compare", theirs, ours, "--atol", "1e-12", "--angle-tol", "1e-7")
    assert same.exit_code == 0, same.output
    moved = tmp_path / "moved.mcap"
    sdk_file(moved, {"robot": lambda t: (t, 2.0 - t * t, 0.5 + 1e-3 * t), "arm": arm}, times)
    differ = invoke("compare", moved, ours, "--atol", "1e-6", "--angle-tol", "1e-7")
    assert differ.exit_code == 1 and "robot" in differ.stdout


def test_a_file_without_trajectories_is_an_input_error_for_compare(invoke, tmp_path):
    import foxglove

    path = tmp_path / "logs.mcap"
    context = foxglove.Context()
    with foxglove.open_mcap(path, context=context):
        foxglove.Channel("/log", context=context).log({"text": "hello"}, log_time=1)
    info = invoke("info", path)
    assert info.exit_code == 1 and "0 entities" in info.stdout  # (and an error: see below)
    assert "no trajectories" in info.stdout
    result = invoke("compare", path, path)
    assert result.exit_code == 2 and "holds no trajectory" in result.stderr


# ROS 2's message definitions as rosbag2 stores them in an MCAP schema (the message, then
# each type it uses after a line of '=' and "MSG: type")
TF_MSGDEF = "\n".join([
    "geometry_msgs/TransformStamped[] transforms",
    "=" * 80, "MSG: geometry_msgs/TransformStamped",
    "std_msgs/Header header", "string child_frame_id", "geometry_msgs/Transform transform",
    "=" * 80, "MSG: std_msgs/Header", "builtin_interfaces/Time stamp", "string frame_id",
    "=" * 80, "MSG: builtin_interfaces/Time", "int32 sec", "uint32 nanosec",
    "=" * 80, "MSG: geometry_msgs/Transform",
    "geometry_msgs/Vector3 translation", "geometry_msgs/Quaternion rotation",
    "=" * 80, "MSG: geometry_msgs/Vector3", "float64 x", "float64 y", "float64 z",
    "=" * 80, "MSG: geometry_msgs/Quaternion",
    "float64 x", "float64 y", "float64 z", "float64 w"])


def ros2_bag(path, positions: dict, times):
    """An MCAP as `ros2 bag record /tf` writes it: tf2_msgs/msg/TFMessage in CDR, encoded
    by mcap-ros2-support (an implementation independent of vrsim's reader)."""
    mcap_ros2 = pytest.importorskip("mcap_ros2.writer", reason="mcap-ros2-support is in "
                                                               "the test extra")
    with open(path, "wb") as f:
        writer = mcap_ros2.Writer(f)
        schema = writer.register_msgdef("tf2_msgs/msg/TFMessage", TF_MSGDEF)
        for t in times:
            sec, nsec = divmod(round(t * 1e9), 1_000_000_000)
            writer.write_message("/tf", schema, {"transforms": [
                {"header": {"stamp": {"sec": sec, "nanosec": nsec}, "frame_id": "odom"},
                 "child_frame_id": name,
                 "transform": {"translation": dict(zip("xyz", f(t))),
                               "rotation": {"x": 0.0, "y": 0.0, "z": math.sin(t / 2),
                                            "w": math.cos(t / 2)}}}
                for name, f in positions.items()]}, log_time=round(t * 1e9) + 7)
        writer.finish()
    return path


def test_info_and_compare_read_a_ros2_tf_bag(invoke, tmp_path):
    """`info` on a ROS 2 /tf bag printed "0 entities" and exited 0. (Times from 0.1 s: a
    zero stamp counts as unset and takes the log time, as for Foxglove's messages.)"""
    times = [k / 10 for k in range(1, 12)]
    base = lambda t: (t, -t, 0.25)  # noqa: E731
    bag = ros2_bag(tmp_path / "bag.mcap", {"base_link": base, "laser": lambda t: (0, 0, t)},
                   times)
    result = invoke("info", bag)
    assert result.exit_code == 0, result.output
    assert result.stdout.splitlines()[0] == f"{bag}: mcap, 2 entities, 11 samples"
    assert "tracks from /tf (transforms)" in result.stdout and "(odom)" in result.stdout
    traj = read_trajectory(bag)
    assert traj.tracks["base_link"].pos.tolist() == [list(base(t)) for t in times]
    assert traj.tracks["base_link"].t.tolist() == [  # the header stamps, not the log times
        int(round(t * 1e9)) // 10**9 + int(round(t * 1e9)) % 10**9 * 1e-9 for t in times]
    assert np.array_equal(traj.tracks["laser"].quat[:, 3], np.sin(np.array(times) / 2))
    assert traj.frames == {"base_link": "odom", "laser": "odom"}


def test_info_on_a_file_without_trajectories_exits_1(invoke, tmp_path):
    import foxglove

    path = tmp_path / "logs.mcap"
    context = foxglove.Context()
    with foxglove.open_mcap(path, context=context):
        foxglove.Channel("/log", context=context).log({"text": "hello"}, log_time=1)
    info = invoke("info", path)
    assert info.exit_code == 1 and "0 entities" in info.stdout
    assert "no trajectory vrsim can read" in info.stderr
    assert invoke("info", path, "--json").exit_code == 1


def test_a_particle_body_and_a_point_mass_are_drawn_as_in_the_frames(tmp_path):
    """Foxglove's /scene shows planar-push's plate as its 9 particles (a 3 x 3 grid 0.5 m
    apart about the centre of mass, each 2 x 15 % x 0.5 m across) joined by a translucent
    hull (the 1 m square: every corner at |x|, |y| <= 0.5), and a point mass at 1 % of
    the scene's size (two masses 50 m apart: 0.5 m radius), not 5 cm dots."""
    model = compile_model(load_scene(SCENARIOS / "planar-push.yaml"))
    messages, _ = mcap_messages.read(write_mcap(model, tmp_path / "p.mcap"), topics=["/scene"])
    (plate,) = [e for e in messages["/scene"][0][1]["entities"] if e["id"] == "plate"]
    centres = sorted((round(float(s["pose"]["position"]["x"]), 9),
                      round(float(s["pose"]["position"]["y"]), 9)) for s in plate["spheres"])
    assert centres == sorted((x, y) for x in (-0.5, 0.0, 0.5) for y in (-0.5, 0.0, 0.5))
    assert all(float(s["size"]["x"]) == pytest.approx(0.15) for s in plate["spheres"])
    (hull,) = plate["triangles"]
    corners = np.array([[float(p[c]) for c in "xyz"] for p in hull["points"]])
    assert np.abs(corners[:, :2]).max() == pytest.approx(0.5) and float(hull["color"]["a"]) < 1
    pair = compile_model(parse_scene(
        "vrsim: 1\nduration: 0.1\nframe_rate: 10\ngravity: [0, 0, 0]\nbodies:\n"
        "  - {name: a, mass: 1, position: [0, 0, 0]}\n"
        "  - {name: b, mass: 1, position: [30, 40, 0]}\n"))
    messages, _ = mcap_messages.read(write_mcap(pair, tmp_path / "a.mcap"), topics=["/scene"])
    for entity in messages["/scene"][0][1]["entities"]:
        assert float(entity["spheres"][0]["size"]["x"]) == pytest.approx(2 * 0.01 * 50)


def test_springs_are_lines_between_their_ends_at_every_sample(tmp_path):
    """planar-push's spring on /scene: at every sample a line from the plate's point
    (-0.5, 0) (model coordinates, turned by the plate's angle theta = 2 atan2(qz, qw))
    to the world anchor (-1.5, 0), in the scene frame."""
    model = compile_model(load_scene(SCENARIOS / "planar-push.yaml"))
    path = write_mcap(model, tmp_path / "p.mcap")
    messages, _ = mcap_messages.read(path, topics=["/scene"])
    lines = {ns: e["lines"][0]["points"] for ns, msg in messages["/scene"]
             for e in msg["entities"] if e["id"] == "springs"}
    track = read_trajectory(path).tracks["plate"]
    assert len(lines) == len(track.t)
    for k, t in enumerate(track.t):
        a, b = lines[round(t * 1e9)]
        qw, qz = track.quat[k, 0], track.quat[k, 3]
        theta = 2 * math.atan2(qz, qw)
        end = track.pos[k, :2] + [-0.5 * math.cos(theta), -0.5 * math.sin(theta)]
        assert [float(a["x"]), float(a["y"])] == pytest.approx(end, abs=1e-12)
        assert (float(b["x"]), float(b["y"]), float(b["z"])) == (-1.5, 0.0, 0.0)
