"""Docs as tests: every block of README.md and docs/*.md marked runnable is run, and
every number it quotes as a result is checked against what the command prints.

A block is runnable when the line before its opening fence is an HTML comment (invisible
on GitHub):

    <!-- runnable -->                      run it; each command must exit 0
    <!-- runnable: rtol=1e-3 -->           numbers agree to this relative tolerance
    <!-- runnable: vary=wall \\S+ s -->     text that differs from run to run (a regex)

- a ```sh block is a list of commands (a trailing backslash continues a line; `#`
  starts a comment): each must exit 0;
- a ```text block holds `$ COMMAND` lines, each followed by the output it prints: every
  line shown must appear in the actual output (stdout and stderr together, in order;
  lines the doc leaves out are allowed), its words equal and its numbers equal within the
  tolerance: by default 1e-9 relative (results vrsim prints are deterministic, the state
  hash included), except where the block says otherwise. Wall times and real-time factors
  differ on every run: blocks that show them name them in `vary` (`wall \\S+ s`,
  `\\S+x real time`, `[0-9.]+ (ms|s),`), and only those are not compared.

Commands run in a temporary folder holding a copy of scenarios/ and the goldens, with the
`vrsim` of this interpreter first on PATH. Blocks are kept short (seconds each): the whole
file must stay cheap.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest

from conftest import REPO

MARK = re.compile(r"^<!-- runnable(?::\s*(.*?))?\s*-->$")
NUMBER = re.compile(r"[-+]?(?:\d+\.\d*|\.\d+|\d+)(?:[eE][-+]?\d+)?")
DEFAULT_RTOL = 1e-9
BLOCK_TIMEOUT_S = 300


@dataclass
class Block:
    file: str
    line: int  # of the opening fence, 1-based
    kind: str  # sh or text
    lines: list
    rtol: float = DEFAULT_RTOL
    vary: list = field(default_factory=list)

    @property
    def id(self) -> str:
        return f"{self.file}:{self.line}"


def _options(text: str | None) -> dict:
    """`rtol=1e-3 vary=REGEX` (vary may repeat, and is the rest of its `;`-part)."""
    options = {"vary": []}
    for part in (text or "").split(";"):
        key, _, value = part.strip().partition("=")
        if key == "vary":
            options["vary"].append(value.strip())
        elif key == "rtol":
            options["rtol"] = float(value)
        elif key:
            raise ValueError(f"unknown runnable option '{key}'")
    return options


def blocks_of(path: Path) -> list[Block]:
    lines = path.read_text(encoding="utf-8").splitlines()
    found = []
    for i, line in enumerate(lines):
        mark = MARK.match(line.strip())
        if not mark:
            continue
        fence = lines[i + 1] if i + 1 < len(lines) else ""
        assert fence.startswith("```") and fence[3:].strip() in ("sh", "text"), \
            f"{path.name}:{i + 1}: a runnable mark must precede a ```sh or ```text block"
        end = next(j for j in range(i + 2, len(lines)) if lines[j].startswith("```"))
        options = _options(mark.group(1))
        found.append(Block(str(path.relative_to(REPO)), i + 2, fence[3:].strip(),
                           lines[i + 2:end], options.get("rtol", DEFAULT_RTOL),
                           options["vary"]))
    return found


def all_blocks() -> list[Block]:
    files = [REPO / "README.md"] + sorted((REPO / "docs").glob("*.md"))
    return [b for f in files for b in blocks_of(f)]


def commands_of(block: Block) -> list[tuple[str, list[str]]]:
    """(command, expected output lines) of a block."""
    if block.kind == "sh":
        out, pending = [], ""
        for line in block.lines:
            line = line.split(" #", 1)[0].rstrip() if not line.lstrip().startswith("#") \
                else ""
            if line.endswith("\\"):
                pending += line[:-1] + " "
                continue
            if (pending + line).strip():
                out.append(((pending + line).strip(), []))
            pending = ""
        return out
    out = []
    for line in block.lines:
        if line.startswith("$ "):
            out.append((line[2:], []))
        elif out and line.strip():
            out[-1][1].append(line)
    return out


def _shape(line: str, vary: list) -> tuple[str, list[float]]:
    """(the line's words with numbers as '#', its numbers), after `vary` text is cut."""
    for pattern in vary:
        line = re.sub(pattern, "<varies>", line)
    numbers = [float(m) for m in NUMBER.findall(line)]
    return " ".join(NUMBER.sub("#", line).split()), numbers


def matches(expected: str, actual: str, rtol: float, vary: list) -> bool:
    words_e, nums_e = _shape(expected, vary)
    words_a, nums_a = _shape(actual, vary)
    return words_e == words_a and len(nums_e) == len(nums_a) and all(
        abs(a - e) <= rtol * max(abs(e), abs(a)) for e, a in zip(nums_e, nums_a))


def missing_lines(expected: list[str], actual: list[str], rtol: float, vary: list) -> list:
    """The expected lines not found in `actual`, in order (a subsequence)."""
    missing, k = [], 0
    for line in expected:
        j = next((j for j in range(k, len(actual))
                  if matches(line, actual[j], rtol, vary)), None)
        if j is None:
            missing.append(line)
        else:
            k = j + 1
    return missing


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    """A folder like a checkout's: scenarios/ and tests/golden/ copied (never the repo)."""
    folder = tmp_path_factory.mktemp("docs")
    shutil.copytree(REPO / "scenarios", folder / "scenarios")
    shutil.copytree(REPO / "tests" / "golden", folder / "tests" / "golden")
    return folder


BLOCKS = all_blocks()


def test_docs_have_runnable_blocks():
    """The test below cannot pass by finding nothing."""
    files = {b.file for b in BLOCKS}
    assert len(BLOCKS) >= 5 and "README.md" in files and "docs/sweep.md" in files


@pytest.mark.parametrize("block", BLOCKS, ids=[b.id for b in BLOCKS])
def test_runnable_block(block, workdir):
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}{os.pathsep}"
                                f"{os.environ.get('PATH', '')}", COLUMNS="200")
    for command, expected in commands_of(block):
        done = subprocess.run(["bash", "-c", command], cwd=workdir, env=env, text=True,
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                              timeout=BLOCK_TIMEOUT_S)
        if not expected or block.kind == "sh":
            assert done.returncode == 0, f"{block.id}: $ {command}\n{done.stdout}"
        missing = missing_lines(expected, done.stdout.splitlines(), block.rtol, block.vary)
        assert not missing, (f"{block.id}: $ {command}: these lines of the doc are not in "
                             f"the output (rtol {block.rtol:g}):\n" + "\n".join(missing)
                             + "\n--- output:\n" + done.stdout)


def test_the_comparison_can_fail():
    """Negative witnesses: a number off by more than the tolerance, another word, a
    missing line, and a varying part that is not declared."""
    line = "projectile: simulated 1.5 s in 1500 steps of 0.001 s, wall 0.254 s, 5.9x real time"
    vary = [r"wall \S+ s", r"\S+x real time"]
    assert matches(line, line.replace("0.254", "9.9").replace("5.9x", "0.1x"), 1e-9, vary)
    assert not matches(line, line.replace("1500", "1501"), 1e-9, vary)
    assert matches(line, line.replace("1500", "1501"), 1e-3, vary)
    assert not matches(line, line.replace("steps", "step"), 1e-9, vary)
    assert not matches(line, line.replace("0.254", "9.9"), 1e-9, [])
    assert missing_lines(["a 1", "b 2"], ["b 2", "a 1"], 1e-9, []) == ["b 2"]


def _table_keys(section: str) -> set[str]:
    return set(re.findall(r"^\| `([a-z_]+)` \|", section, flags=re.M))


def test_scene_format_tables_list_every_collision_key():
    """The `impacts` key was missing from the collision table: every key the schema
    allows in the top-level and per-body collision blocks has its row."""
    import json

    schema = json.loads((REPO / "vrsim_cli" / "scene" / "scene.schema.json").read_text())
    text = (REPO / "docs" / "scene-format.md").read_text()
    top = text.split("Top level `collision`:", 1)[1].split("Per body `collision`:", 1)
    assert _table_keys(top[0]) == set(schema["$defs"]["collision"]["properties"])
    per_body = top[1].split("\n\n", 2)[1]
    assert _table_keys(per_body) == set(schema["$defs"]["body_collision"]["properties"])


def test_bench_quick_promises_no_time():
    """`bench --quick` promised "under a minute" and took 94 s: its help promises none."""
    from click.testing import CliRunner

    from vrsim_cli.cli import cli

    help_text = CliRunner().invoke(cli, ["bench", "--help"]).output
    assert "--quick" in help_text and "minute" not in help_text
