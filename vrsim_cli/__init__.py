"""vrsim: a command-line scenario runner for real-time animation and simulation in VR.

The package follows the loop of lecture chapter 5 (slide 5.0): read sensors, simulate,
update the scene graph and render. Importing it is cheap: numpy and the heavy optional
libraries (trimesh, fcl, OpenGL, matplotlib) are imported by the stage that needs them.

The Python API (`vrsim_cli.load`, `vrsim_cli.simulate`, ...; docs/api.md) lives in
`vrsim_cli.api`, imported on first use of one of its names (PEP 562 `__getattr__`), so
`import vrsim_cli` and `vrsim --help` still import no numpy.
"""

__version__ = "0.1.0"

# Names of the API module reachable from the package; nothing inside vrsim imports them
# from here (tests/test_architecture.py checks the lazy import stays the only one).
API = ("load", "simulate", "Simulation", "Trajectory", "read_trajectory", "state_hash",
       "Model", "State")


def __getattr__(name: str):
    if name in API:
        from vrsim_cli import api

        return getattr(api, name)
    raise AttributeError(f"module 'vrsim_cli' has no attribute '{name}'")


def __dir__():
    return sorted(list(globals()) + list(API))
