"""Words and tables for people: counts with the right plural, columns that line up.

Layer 0, nothing but the standard library: every command's text output uses it, so "1 body"
reads right, a long entity name widens its column instead of pushing the row out of line,
and a long run, sweep or bench shows a progress bar on a terminal.
"""

from __future__ import annotations

import sys
import time

IRREGULAR = {"body": "bodies", "entity": "entities"}


def plural(n: int, word: str, many: str | None = None) -> str:
    """'1 body', '2 bodies', '0 steps': `n` and the word, plural unless n is 1."""
    if n == 1:
        return f"{n} {word}"
    return f"{n} {many or IRREGULAR.get(word) or word + 's'}"


def table(header: list[str], rows: list[list], right: set[int] | None = None,
          indent: str = "") -> list[str]:
    """Lines of a text table: each column as wide as its widest cell, two spaces apart;
    columns whose index is in `right` are right-aligned (numbers)."""
    right = right or set()
    cells = [[str(c) for c in header]] + [[str(c) for c in row] for row in rows]
    widths = [max(len(row[i]) for row in cells) for i in range(len(header))]
    lines = []
    for row in cells:
        parts = [cell.rjust(w) if i in right else cell.ljust(w)
                 for i, (cell, w) in enumerate(zip(row, widths))]
        lines.append(indent + "  ".join(parts).rstrip())
    return lines


def significant(x: float, digits: int = 2) -> str:
    """`x` to `digits` significant digits, never in exponent form for the factors a run
    prints: 5.93 -> '5.9', 0.0123 -> '0.012', 1234 -> '1200', 0 -> '0'. Very large or
    small values fall back to '1.2e+09' style, which stays short."""
    if x != x or x in (float("inf"), float("-inf")):
        return str(x)
    if x == 0:
        return "0"
    from math import floor, log10

    x = float(f"{x:.{digits}g}")  # rounded first: 0.0996 -> 0.1 has one digit more
    exponent = floor(log10(abs(x)))
    if not -6 <= exponent < 9:
        return f"{x:.{digits - 1}e}"
    return f"{x:.{max(digits - 1 - exponent, 0)}f}"


def duration(seconds: float) -> str:
    """A wall time for people: '12.3 ms', '1.25 s', '10.1 s', '2 min 05 s', '1 h 02 min'
    (never '1.01e+04 ms')."""
    if seconds != seconds:
        return "? s"
    if seconds < 1.0:
        return f"{1e3 * seconds:.3g} ms"
    if seconds < 60.0:
        return f"{seconds:.3g} s"
    whole = int(round(seconds))
    if whole < 3600:
        return f"{whole // 60} min {whole % 60:02d} s"
    return f"{whole // 3600} h {whole % 3600 // 60:02d} min"


PROGRESS_AFTER_S = 2.0  # work shorter than this shows no bar: it would only flicker
PROGRESS_EVERY_S = 0.2  # redraw at most this often


class Progress:
    """A one-line progress bar on standard error, for a person watching a terminal:
    `[######        ]  42%  t = 4.2 / 10 s, 1.3x real time, 5.8 s left`.

    Drawn only when the stream is a terminal, once the work has taken `after` seconds, and
    never when `enabled` is false (-q, --json, a pipe, a file). A missing or closed stream
    (`sys.stderr` is None under `2>&-`) or a failed write switches it off silently: a
    progress bar must never stop the work it reports on. `update(done, detail)` with
    `done` out of `total`; `clear()` before printing anything else on the terminal."""

    def __init__(self, total: float, *, enabled: bool = True, stream=None,
                 after: float | None = None, clock=time.monotonic, bar: int = 20):
        self.stream = sys.stderr if stream is None else stream
        self.total = float(total)
        self.after = PROGRESS_AFTER_S if after is None else after
        self.clock, self.bar = clock, bar
        self.start = clock()
        self.last = -float("inf")
        self.width = 0  # of the line on screen (0: nothing shown)
        self.enabled = enabled and _is_terminal(self.stream)

    def update(self, done: float, detail: str = "") -> None:
        if not self.enabled:
            return
        now = self.clock()
        elapsed = now - self.start
        if elapsed < self.after or now - self.last < PROGRESS_EVERY_S:
            return
        self.last = now
        frac = min(max(done / self.total, 0.0), 1.0) if self.total > 0 else 0.0
        filled = int(self.bar * frac)
        parts = [detail] if detail else []
        if frac > 0:  # a constant rate from here on: the simplest honest guess
            parts.append(f"{duration(elapsed * (1.0 - frac) / frac)} left")
        line = f"[{'#' * filled}{' ' * (self.bar - filled)}] {100 * frac:3.0f}%  " + \
            ", ".join(parts)
        self._write("\r" + line.ljust(self.width))
        self.width = len(line)

    def clear(self) -> None:
        """Erase the bar (before other output, and at the end)."""
        if self.enabled and self.width:
            self._write("\r" + " " * self.width + "\r")
            self.width = 0

    def _write(self, text: str) -> None:
        try:
            self.stream.write(text)
            self.stream.flush()
        except (OSError, ValueError, AttributeError):  # closed, gone, or a broken pipe
            self.enabled = False


def _is_terminal(stream) -> bool:
    try:
        return bool(stream is not None and stream.isatty())
    except (OSError, ValueError, AttributeError):  # closed, or not a file at all
        return False
