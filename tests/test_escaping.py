"""Everything vrsim prints from a scene or a trajectory file is escaped (issue 19, item 8):
names, topics, schema names, metadata, file names, in run summaries, validate, info,
compare and errors. A hostile file cannot drive the terminal (OSC 0 retitles it, CSI 2J
clears it, a bare CR overwrites the line before): control and other invisible characters
print as \\x1b, \\r, \\u2028."""

from __future__ import annotations

import json

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vrsim_cli.writers.entities import CSV_COLUMNS

HOSTILE = "\x1b]0;pwned\x07\x1b[2J\r\u2028\x9b1m\x00"
ESCAPED = "\\x1b]0;pwned\\x07\\x1b[2J\\r\\u2028\\x9b1m\\x00"
HOSTILE_CSV = "\x1b]0;pwned\x07\x1b[2J\u2028\x9b1m"  # no CR, LF or NUL: one CSV field


def printable_lines(text: str) -> None:
    for line in text.splitlines():
        assert line.isprintable(), repr(line)


def test_the_scene_name_is_escaped_in_the_run_summary_and_validate(invoke, tmp_path):
    scene = tmp_path / "scene.yaml"
    scene.write_text("vrsim: 1\nduration: 0.1\nname: " + json.dumps(HOSTILE) + "\n"
                     "bodies: [{name: a, mass: 1}]\n", encoding="utf-8")
    result = invoke("run", scene, "-o", tmp_path / "o.csv")
    assert result.exit_code == 0, result.output
    printable_lines(result.output)
    assert result.stdout.startswith(ESCAPED + ": simulated 0.1 s")
    result = invoke("validate", scene)
    assert result.exit_code == 0
    printable_lines(result.output)


def test_a_file_name_with_control_characters_is_escaped(invoke, tmp_path):
    scene = tmp_path / "sc\x1b[2Jene.yaml"
    scene.write_text("vrsim: 1\nduration: 0.1\nbodies: [{name: a, mass: 1}]\n")
    for args in (["validate", scene], ["run", scene, "-o", tmp_path / "o\x1b[2J.csv"]):
        result = invoke(*args)
        assert result.exit_code == 0, result.output
        printable_lines(result.output)
        assert "\\x1b[2J" in result.output


def hostile_csv(path, names) -> None:
    rows = [",".join(CSV_COLUMNS)]
    for t in (0.0, 0.1):
        rows += [f"{t},{name},0,0,0,1,0,0,0,0,0,0,0,0,0" for name in names]
    path.write_text("\n".join(rows) + "\n", encoding="utf-8", newline="")


@settings(max_examples=40, deadline=None, derandomize=True)
@given(names=st.lists(st.text(st.characters(codec="utf-8", exclude_characters=",\"\n\r"),
                              min_size=1, max_size=12), min_size=1, max_size=4, unique=True))
def test_info_and_compare_escape_entity_names_from_a_file(tmp_path_factory, names):
    """Any entity names a CSV holds (control characters, C1, separators, bidi marks)."""
    from click.testing import CliRunner

    from vrsim_cli.cli import cli

    folder = tmp_path_factory.mktemp("names")
    a, b = folder / "a.csv", folder / "b.csv"
    hostile_csv(a, names)
    hostile_csv(b, names[:1] + [n + HOSTILE_CSV for n in names[1:]])
    runner = CliRunner()
    for args in (["info", a], ["compare", a, b], ["compare", a, b, "--all"]):
        result = runner.invoke(cli, [str(x) for x in args], catch_exceptions=False)
        assert result.exit_code in (0, 1, 2), result.output  # 2: a NUL the csv module refuses
        printable_lines(result.output)


def test_info_escapes_topics_schema_names_and_metadata_of_an_mcap(invoke, tmp_path):
    """An MCAP made by someone else: every string vrsim prints from it is escaped."""
    from mcap.writer import Writer

    path = tmp_path / "hostile.mcap"
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start(profile="", library="x")
        schema = writer.register_schema("vrsim.State" + HOSTILE, "jsonschema", b"{}")
        channel = writer.register_channel("/vrsim/state", "json", schema)
        other = writer.register_channel("/evil" + HOSTILE, "json", schema)
        entity = {"name": "e" + HOSTILE, **{c: 0.0 for c in CSV_COLUMNS[2:]}}
        writer.add_message(channel, log_time=0, publish_time=0,
                           data=json.dumps({"t": 0.0, "step": 0, "entities": [entity]}).encode())
        writer.add_message(other, log_time=0, publish_time=0, data=b"{}")
        writer.add_metadata("vrsim", {"version": "1" + HOSTILE, "scene_file": HOSTILE,
                                      "dt": HOSTILE, "integrator": HOSTILE})
        writer.finish()
    result = invoke("info", path)
    assert result.exit_code == 0, result.output
    printable_lines(result.output)
    assert ESCAPED in result.output
    data = json.loads(invoke("info", path, "--json").output)  # JSON escapes by itself
    assert data["entities"] == ["e" + HOSTILE]


@pytest.mark.parametrize("text", [
    "vrsim: 1\nduration: 1\n" + json.dumps(HOSTILE) + ": 1\n",  # an unknown key
    "vrsim: 1\nduration: 1\nintegrator: " + json.dumps(HOSTILE) + "\n",  # a bad value
    "vrsim: 1\nduration: 1\nbodies: [{name: " + json.dumps(HOSTILE) + ", mass: 1}]\n",
    "vrsim: 1\nduration: 1\noutput: {file: " + json.dumps("o" + HOSTILE[:-1] + ".txt") + "}\n",
])
def test_error_messages_quoting_the_scene_are_escaped(invoke, write_scene, text):
    result = invoke("validate", write_scene(text))
    assert result.exit_code == 2
    printable_lines(result.output)
    assert "\\x1b" in result.output


def test_sweep_regress_and_plot_escape_file_and_entity_names(invoke, tmp_path):
    """Scene file names (sweep, regress) and entity names read from a trajectory (plot)
    reach the terminal escaped, including in regress's per-entity comparison table."""
    folder = tmp_path / "scenes"
    folder.mkdir()
    scene = folder / "sc\x1b[2Jene.yaml"
    scene.write_text("vrsim: 1\nduration: 0.1\nbodies: [{name: a, mass: 1}]\n")
    result = invoke("sweep", scene, "--set", "dt=0.01,0.005", "--jobs", "1",
                    "-o", tmp_path / "sweep")
    assert result.exit_code == 0, result.output
    printable_lines(result.output)
    assert "\\x1b[2J" in result.output
    golden = tmp_path / "golden"
    assert invoke("regress", folder, "--golden", golden, "--update", "--jobs", "1"
                  ).exit_code == 0
    scene.write_text("vrsim: 1\nduration: 0.1\nbodies: [{name: a, mass: 1, "
                     "velocity: [1, 0, 0]}]\n")  # now differs from its golden
    result = invoke("regress", folder, "--golden", golden, "--jobs", "1")
    assert result.exit_code == 1, result.output
    printable_lines(result.output)
    assert "\\x1b[2J" in result.output
    pytest.importorskip("matplotlib", reason="vrsim plot needs the plot extra")
    csv = tmp_path / "t.csv"
    hostile_csv(csv, ["e" + HOSTILE_CSV])
    result = invoke("plot", csv, "-o", tmp_path / "p.png")
    assert result.exit_code == 0, result.output
    printable_lines(result.output)
