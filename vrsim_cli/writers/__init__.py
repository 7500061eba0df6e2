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


def open_writer(model: Model, path: Path | None, fmt: str | None, live=None):
    """The writer for `fmt` ('csv', 'mcap', 'tum') writing to `path`; with `live` (a
    `live.LiveServer`) the run is also served to Foxglove. None when there is neither."""
    if live is not None:
        from vrsim_cli.writers.mcap_writer import McapWriter
        if fmt == "mcap":  # one writer, two sinks: the same channels in file and live view
            return McapWriter(model, path, live=live)
        shown = McapWriter(model, None, live=live)
        return shown if path is None else Tee(open_writer(model, path, fmt), shown)
    if path is None:
        return None
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


class Tee:
    """Several writers as one: each sample, input record, close and abort goes to all."""

    def __init__(self, *writers):
        self.writers = writers

    def write(self, state) -> None:
        for w in self.writers:
            w.write(state)

    def write_input(self, inputs) -> None:
        for w in self.writers:
            if hasattr(w, "write_input"):
                w.write_input(inputs)

    def close(self) -> None:
        for w in self.writers:
            w.close()

    def abort(self) -> None:
        for w in self.writers:
            w.abort()
