"""`python -m vrsim_cli` is the same as the `vrsim` command."""

from vrsim_cli.cli import main

if __name__ == "__main__":
    main()
