"""README keeps exactly two set-up commands, and CI runs the README's test command."""

from __future__ import annotations

import re

from conftest import REPO


def setup_commands() -> list[str]:
    text = (REPO / "README.md").read_text()
    section = text.split("## Set up", 1)[1].split("\n## ", 1)[0]
    return re.findall(r"```sh\n(.*?)\n```", section, flags=re.S)


def test_readme_has_exactly_two_setup_commands():
    commands = setup_commands()
    assert len(commands) == 2
    assert "vrsim run scenarios/" in commands[0]
    assert "pytest" in commands[1]


def test_ci_runs_the_readme_test_command():
    ci = (REPO / ".ci" / "run").read_text()
    assert 'grep -m1 -E "^python3 -m venv .* pytest" README.md' in ci
    lines = [l for l in (REPO / "README.md").read_text().splitlines()
             if re.match(r"^python3 -m venv .* pytest", l)]
    assert lines == [setup_commands()[1]]
