"""Imports: a table another lab (or this service) recorded, parsed, segmented and stored as a dataset.

Measured data is not a command: any drive range is accepted and kept as ``drive_range_v``; the
units converted and values implausible for a piezo stage are kept as the plan's ``notes``. A
refused file (FieldError naming the field or column) stores nothing.
"""

from __future__ import annotations

from typing import BinaryIO

from service.science.data.datasets import parse_table
from service.science.data.segmentation import blocks_without_table
from service.store import DatasetRow, Store
from service.usecases.recorder import Recorder


def import_table(store: Store, handle: BinaryIO, name: str, options: dict) -> DatasetRow:
    """Parse ``handle`` (rewound) as a stream with the request's ``options`` (filename, columns,
    axis, sample_rate_hz, delimiter), find its blocks and store it; returns the dataset row.
    Blocking: run it off the event loop."""
    handle.seek(0)
    table = parse_table(
        handle,
        columns=options["columns"],
        axis=options["axis"],
        sample_rate_hz=options["sample_rate_hz"],
        delimiter=options["delimiter"],
    )
    blocks = blocks_without_table({a: table.arrays[f"u_{a}_v"] for a in table.axes}, table.sample_rate_hz)
    meta = {
        "name": name,
        "source": "import",
        "axes": table.axes,
        "sample_rate_hz": table.sample_rate_hz,
        "blocks": blocks,
        "plan": {"import": options, "drive_range_v": table.drive_range_v, "notes": table.notes},
    }
    return Recorder(store, meta).keep(table.arrays)
