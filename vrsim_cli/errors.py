"""Error types shared by every layer, and the exit codes the CLI maps them to.

Exit codes (the brief): 0 ok, 1 the run or a comparison failed, 2 usage or input error.
Interrupted runs exit 128 + signal number (130 for SIGINT, 143 for SIGTERM).
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass
from typing import Iterable, Sequence

EXIT_OK = 0
EXIT_RUN_FAILED = 1
EXIT_INPUT = 2


def format_key_path(path: Sequence[str | int]) -> str:
    """`('bodies', 0, 'shape', 'radius')` -> `bodies[0].shape.radius`."""
    out = ""
    for part in path:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out or "(document)"


def did_you_mean(word: str, candidates: Iterable[str]) -> str | None:
    """A hint such as `did you mean 'restitution'?`, or None when nothing is close."""
    close = difflib.get_close_matches(str(word), sorted(set(candidates)), n=1, cutoff=0.6)
    return f"did you mean '{close[0]}'?" if close else None


@dataclass(frozen=True)
class Problem:
    """One located problem in an input file. `line` and `col` are 1-based (0: unknown).
    `path` is the key path inside a scene file; None for data files without keys (CSV)."""

    file: str
    line: int
    col: int
    path: tuple[str | int, ...] | None
    message: str
    hint: str | None = None

    def __str__(self) -> str:
        where = f"{self.file}:{self.line}:{self.col}" if self.line else self.file
        if self.path is None or (not self.line and not self.path):
            text = f"{where}: {self.message}"
        else:
            text = f"{where}: {format_key_path(self.path)}: {self.message}"
        return printable(f"{text} ({self.hint})" if self.hint else text)


def printable(text: str) -> str:
    """`text` with control and other invisible characters escaped (\\x1b, \\u2028): a
    message quoting a hostile file stays one line and cannot drive the terminal."""
    if text.isprintable():
        return text
    return "".join(c if c.isprintable() else c.encode("unicode_escape").decode("ascii")
                   for c in text)


class VrsimError(Exception):
    """Base of all errors vrsim reports to the user without a traceback."""

    exit_code = EXIT_RUN_FAILED


class InputError(VrsimError):
    """Bad input (scene file, trajectory file, options). Carries every problem found."""

    exit_code = EXIT_INPUT

    def __init__(self, problems: Sequence[Problem] | str):
        if isinstance(problems, str):
            problems = [Problem(file="", line=0, col=0, path=(), message=problems)]
        self.problems = list(problems)
        super().__init__("\n".join(self.lines()))

    def lines(self) -> list[str]:
        return [str(p) if p.file else printable(p.message) for p in self.problems]


class SimulationError(VrsimError):
    """The run itself failed, e.g. a numerical blow-up. Names the body and the time."""

    exit_code = EXIT_RUN_FAILED

    def __init__(self, message: str, *, body: str | None = None, t: float | None = None):
        self.body = body
        self.t = t
        prefix = []
        if body is not None:
            prefix.append(f"body '{body}'")
        if t is not None:
            prefix.append(f"t = {t:.6g} s")
        super().__init__(f"{', '.join(prefix)}: {message}" if prefix else message)


class OutputError(VrsimError):
    """An output could not be written (disk full, permissions). The previous file is kept."""

    exit_code = EXIT_RUN_FAILED
