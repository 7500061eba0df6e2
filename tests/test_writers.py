"""Trajectory writers: CSV columns and exact values, MCAP read back with the mcap reader,
TUM files, atomic replacement."""

from __future__ import annotations

import csv

import numpy as np
import pytest
from mcap.reader import make_reader

import mcap_messages

from vrsim_cli.errors import OutputError
from vrsim_cli.loop import run
from vrsim_cli.model.model import compile_model
from vrsim_cli.model.state import make_state
from vrsim_cli.scene.spec import load_scene
from vrsim_cli.tools.trajectory import read_trajectory
from vrsim_cli.writers import CSV_COLUMNS, open_writer
from vrsim_cli.writers.atomic import AtomicFile

SCENE = """
vrsim: 1
name: writers
duration: 0.5
frame_rate: 20
dt: 0.01
integrator: rk4
bodies:
  - {name: ball, mass: 1, shape: {type: sphere, radius: 0.1}, position: [0, 2, 0],
     velocity: [1, 0, 0], color: [1, 0, 0]}
  - {name: crate, mass: 2, shape: {type: box, size: [1, 2, 3]}, euler_deg: [0, 90, 0]}
  - {name: pole, type: static, shape: {type: capsule, radius: 0.1, length: 1}}
  - {name: floor, type: static, shape: {type: plane, normal: [0, 1, 0], offset: -1}}
  - {name: dot, mass: 1}
"""


def run_to(write_scene, tmp_path, name: str, fmt: str):
    model = compile_model(load_scene(write_scene(SCENE)))
    writer = open_writer(model, tmp_path / name, fmt)
    result = run(model, make_state(model), writer)
    writer.close()
    return model, result


def test_csv_has_exactly_the_documented_columns_and_exact_values(write_scene, tmp_path):
    model, result = run_to(write_scene, tmp_path, "out.csv", "csv")
    with open(tmp_path / "out.csv", newline="") as f:
        rows = list(csv.reader(f))
    assert tuple(rows[0]) == CSV_COLUMNS == ("t", "entity", "px", "py", "pz", "qw", "qx", "qy",
                                             "qz", "vx", "vy", "vz", "wx", "wy", "wz")
    samples = 11  # 0.5 s at 20 Hz, both ends
    assert len(rows) == 1 + samples * model.n_body
    assert [r[1] for r in rows[1:6]] == ["ball", "crate", "pole", "floor", "dot"]
    last_ball = rows[-5]
    assert float(last_ball[0]) == result.state.t
    # shortest round-trip repr: reading back gives the identical float64
    assert [float(x) for x in last_ball[2:5]] == result.state.body_pos[0].tolist()
    crate_q = [float(x) for x in rows[2][5:9]]
    assert crate_q == pytest.approx([np.sqrt(0.5), 0, np.sqrt(0.5), 0])


def test_mcap_reads_back_with_the_foxglove_sdk_schemas(write_scene, tmp_path):
    model, result = run_to(write_scene, tmp_path, "out.mcap", "mcap")
    messages, schemas = mcap_messages.read(tmp_path / "out.mcap")
    assert schemas == {"/tf": "foxglove.FrameTransforms", "/scene": "foxglove.SceneUpdate",
                       "/vrsim/state": "vrsim.State"}
    with open(tmp_path / "out.mcap", "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert all(ci.compression == "lz4" for ci in summary.chunk_indexes)
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
    assert len(messages["/tf"]) == len(messages["/vrsim/state"]) == 11
    assert len(messages["/scene"]) == 1
    t_ns, last_tf = messages["/tf"][-1]
    assert t_ns == 500_000_000
    frames = {tf["child_frame_id"]: tf for tf in last_tf["transforms"]}
    # world is z-up; the y-up scene hangs under it turned +90 degrees about x
    root = frames["scene"]
    assert root["parent_frame_id"] == "world"
    assert [root["rotation"][k] for k in "wxyz"] == [np.sqrt(0.5), np.sqrt(0.5), 0.0, 0.0]
    ball = frames["ball"]
    assert ball["parent_frame_id"] == "scene"
    assert [ball["translation"][k] for k in "xyz"] == result.state.body_pos[0].tolist()
    assert mcap_messages.seconds(ball["timestamp"]) == 0.5
    entities = {e["id"]: e for e in messages["/scene"][0][1]["entities"]}
    assert entities["ball"]["spheres"][0]["size"] == {"x": 0.2, "y": 0.2, "z": 0.2}
    assert entities["ball"]["spheres"][0]["color"] == {"r": 1.0, "g": 0.0, "b": 0.0, "a": 1.0}
    assert entities["crate"]["cubes"][0]["size"] == {"x": 1.0, "y": 2.0, "z": 3.0}
    assert len(entities["pole"]["cylinders"]) == 1 and len(entities["pole"]["spheres"]) == 2
    assert entities["floor"]["frame_id"] == "scene"
    assert entities["floor"]["cubes"][0]["pose"]["position"]["y"] == -1.0
    assert entities["ball"]["frame_locked"] is True
    state = messages["/vrsim/state"][-1][1]
    assert state["t"] == result.state.t and int(state["step"]) == 50
    assert state["entity"] == list(model.body_name)
    assert state["velocity"][0] == 1.0
    assert "name: writers" in metadata["vrsim"]["scene"]
    assert metadata["vrsim"]["integrator"] == "rk4" and metadata["vrsim"]["up"] == "y"


def test_tum_folder_has_one_file_per_entity(write_scene, tmp_path):
    model, result = run_to(write_scene, tmp_path, "tum", "tum")
    files = sorted(p.name for p in (tmp_path / "tum").iterdir())
    assert files == sorted(f"{n}.tum" for n in model.body_name)
    lines = (tmp_path / "tum" / "crate.tum").read_text().splitlines()
    assert len(lines) == 11
    t, tx, ty, tz, qx, qy, qz, qw = map(float, lines[0].split())
    assert (qx, qy, qz, qw) == pytest.approx((0, np.sqrt(0.5), 0, np.sqrt(0.5)))


@pytest.mark.parametrize("name,fmt", [("out.csv", "csv"), ("out.mcap", "mcap"), ("tum", "tum")])
def test_every_format_reads_back_to_the_same_positions(write_scene, tmp_path, name, fmt):
    model, result = run_to(write_scene, tmp_path, name, fmt)
    traj = read_trajectory(tmp_path / name)
    assert list(traj.tracks) == sorted(model.body_name) if fmt == "tum" else \
        list(traj.tracks) == list(model.body_name)
    ball = traj.tracks["ball"]
    assert len(ball.t) == 11 and ball.t[-1] == result.state.t
    assert ball.pos[-1].tolist() == result.state.body_pos[0].tolist()


def test_atomic_file_replaces_only_on_commit(tmp_path):
    target = tmp_path / "data.csv"
    target.write_text("old")
    out = AtomicFile(target)
    out.write(b"new")
    assert target.read_text() == "old"
    out.commit()
    assert target.read_text() == "new"
    out = AtomicFile(target)
    out.write(b"newer")
    out.discard()
    assert target.read_text() == "new"
    assert [p.name for p in tmp_path.iterdir()] == ["data.csv"]


def test_atomic_file_in_a_missing_folder(tmp_path):
    with pytest.raises(OutputError, match="does not exist"):
        AtomicFile(tmp_path / "nope" / "x.csv")
