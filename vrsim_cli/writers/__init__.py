"""Layer 6: trajectory writers. They read the model and states, never the loop.

Every writer takes samples one at a time (`write(state)`), then `close()` finalises the
file atomically, or `abort()` leaves any previous file untouched. The entities of a
sample are the bodies, in model order, then the observer.
"""

from __future__ import annotations

from pathlib import Path

from vrsim_cli.errors import OutputError
from vrsim_cli.model.model import Model
from vrsim_cli.writers.entities import CSV_COLUMNS, OBSERVER, entity_arrays, entity_names

__all__ = ["CSV_COLUMNS", "OBSERVER", "entity_arrays", "entity_names", "open_writer"]


def open_writer(model: Model, path: Path, fmt: str):
    """The writer for `fmt` ('csv', 'mcap', 'tum') writing to `path`."""
    if fmt == "csv":
        from vrsim_cli.writers.csv_writer import CsvWriter
        return CsvWriter(model, path)
    if fmt == "mcap":
        from vrsim_cli.writers.mcap_writer import McapWriter
        return McapWriter(model, path)
    if fmt == "tum":
        from vrsim_cli.writers.tum_writer import TumWriter
        return TumWriter(model, path)
    raise OutputError(f"unknown output format '{fmt}'")
