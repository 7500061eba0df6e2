"""The `vrsim` command's entry point; `python -m vrsim_cli` is the same command.

The signal handlers are installed before anything else is imported (click, the scene
loader, numpy): a SIGINT or SIGTERM from the first instruction of vrsim on exits cleanly
with 130 or 143 (see `vrsim_cli.interrupts`), never with a traceback or silently. The
first two lines below cover the imports of `interrupts` itself (signal, enum, threading:
~3 ms) with a handler from the C module, which start-up has loaded already. Before them
only Python's own start-up runs (~20 ms, site and .pth files), where a Ctrl-C is Python's
to report: no program can install a handler earlier.
"""

import _signal  # noqa: I001 - first: built in, loaded, no imports of its own
import os


def _early(signum, _frame):  # nothing is written yet: say so and leave at once
    try:
        os.write(2, b"interrupted by %s; nothing was written\n"
                 % (b"SIGINT" if signum == _signal.SIGINT else b"SIGTERM"))
    except OSError:
        pass
    os._exit(128 + signum)


_signal.signal(_signal.SIGINT, _early)
_signal.signal(_signal.SIGTERM, _early)

import gc  # noqa: E402

from vrsim_cli import interrupts, streams  # noqa: E402


def main() -> None:
    interrupts.install()
    streams.reopen_closed()  # before anything opens a file (it could get fd 1 or 2)
    # Start-up (numpy, numba and its target: ~10^6 objects that live as long as the
    # process) triggers the cyclic collector dozens of times, ~15 % of a small run's
    # start-up CPU time, to find nothing. `cli.start_collector` turns it back on, with
    # those objects frozen out of its passes, once the command's set-up is done.
    gc.disable()
    try:
        from vrsim_cli.cli import main as cli_main

        cli_main()
    except interrupts.Interrupted as exc:  # during the import of the command itself
        import sys

        if sys.stderr is not None:  # None under `2>&-`
            sys.stderr.write(f"interrupted by {interrupts.name(exc.signum)}; nothing was "
                             f"written\n")
        sys.exit(exc.exit_code)


if __name__ == "__main__":
    main()
