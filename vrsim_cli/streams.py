"""Standard streams the `vrsim` command was started without (`2>&-`, `>&-`, a daemon).

Layer 0, stdlib only. A closed descriptor 0, 1 or 2 is a trap: the next file vrsim opens
would get its number, and whatever writes to "stderr" then (a note, ffmpeg, a library's
warning) would land in the output file. And Python sets `sys.stdout`/`sys.stderr` to None
for them, which code asking `sys.stderr.isatty()` turned into a silent exit 1. So
`reopen_closed` (called first thing by `__main__.main`) points each closed descriptor at
/dev/null and remembers which were closed: what would go there is dropped, the run goes
on, and a command that needs standard output (`-o -`, `--json`) refuses with exit 2 and
says so on stderr (if that is open).
"""

from __future__ import annotations

import os
import sys

closed: frozenset = frozenset()  # the descriptors (0, 1, 2) that were closed at start-up


def reopen_closed() -> frozenset:
    """Open /dev/null on each closed standard descriptor and give Python stream objects
    for them; returns (and keeps in `closed`) the descriptors that were closed."""
    global closed
    gone = []
    for fd in (0, 1, 2):
        try:
            os.fstat(fd)
        except OSError:
            gone.append(fd)
    for fd in gone:
        new = os.open(os.devnull, os.O_RDWR)  # the lowest free number: this one
        if new != fd:
            os.dup2(new, fd)
            os.close(new)
    for fd, name, mode in ((0, "stdin", "r"), (1, "stdout", "w"), (2, "stderr", "w")):
        if fd in gone or getattr(sys, name) is None:
            setattr(sys, name, open(fd, mode, closefd=False, errors="backslashreplace"))
    closed = frozenset(gone)
    return closed


def stdout_closed() -> bool:
    """True when the command was started with standard output closed."""
    return 1 in closed
