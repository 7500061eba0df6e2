"""Words and tables for people: counts with the right plural, columns that line up.

Layer 0, no imports: every command's text output uses it, so "1 body" reads right and a
long entity name widens its column instead of pushing the row out of line.
"""

from __future__ import annotations

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
