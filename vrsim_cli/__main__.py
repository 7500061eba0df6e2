"""The `vrsim` command's entry point; `python -m vrsim_cli` is the same command.

The signal handlers are installed before anything else is imported (click, the scene
loader, numpy): a SIGINT or SIGTERM from the first instruction of vrsim on exits cleanly
with 130 or 143 (see `vrsim_cli.interrupts`), never with a traceback or silently.
"""

import gc

from vrsim_cli import interrupts


def main() -> None:
    interrupts.install()
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
