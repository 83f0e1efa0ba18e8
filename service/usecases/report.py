"""The model report (GET /api/models/{id}/report): gathers what service.render.model_report draws.

The model's datasets are read once: the same records feed the diagnosis and the per-block
figures, and of each record only its blocks' held-out cycles, decimated, are kept for the page.
"""

from __future__ import annotations

import numpy as np

from service.render.model_report import BlockCurves, block_figure, history_figure, render_report
from service.render.reproduce import commands
from service.render.svg import decimate
from service.science.data.record import Record
from service.science.discovery.loop_shape import role_in_model
from service.science.discovery.parameters import parameter_units
from service.science.fitting.metrics import rms
from service.store import Store, utc_now
from service.usecases.discover import block_title, diagnose_model, history
from service.usecases.identify import load_model, load_records, require_fit_memory
from service.usecases.lab import discovered_parameters

#: dataset row fields the report shows
DATASET_FIELDS = (
    "id",
    "name",
    "source",
    "axes",
    "samples",
    "sample_rate_hz",
    "blocks",
    "plan",
    "partial",
    "partial_reason",
    "tags",
    "notes",
)


def block_curves(record: Record, predicted, dataset_id: str) -> list[BlockCurves]:
    """Per block that drives the record's axis: its held-out cycles, decimated, with the block's
    training and held-out RMS over every sample."""
    out = []
    for s in record.splits_of(own_axis_only=True):
        a, b = s.held_out
        if b <= a:
            continue
        keep = decimate(b - a)
        x, p, u = record.x_um[a:b], predicted[a:b], record.u_v[a:b]
        train = slice(*s.train)
        out.append(
            BlockCurves(
                title=block_title(record.axis or "y", s, record.sample_rate_hz),
                dataset_id=dataset_id,
                block_index=s.block.get("index"),
                frequency_hz=s.block.get("frequency_hz"),
                t_s=np.arange(b - a)[keep] / record.sample_rate_hz,
                u_v=u[keep].copy(),
                x_um=x[keep].copy(),
                x_model_um=p[keep].copy(),
                held_out_rms_um=rms(x - p),
                train_rms_um=rms(record.x_um[train] - predicted[train]) if s.train[1] > s.train[0] else None,
            )
        )
    return out


def _gather(store: Store, model_id: str, bench_fit=None) -> dict:
    """What the report and its figures are drawn from: the model's row, lineage, dataset rows,
    diagnosis and per-block curves (NotFoundError for an unknown id)."""
    row = store.get_model(model_id)
    steps = history(store, model_id)
    dataset_rows = [store.get_dataset(d) for d in row["datasets"]]
    require_fit_memory(store, list(row["datasets"]), field="model_id")
    records = load_records(store, row["datasets"], row["axis"])
    diagnosis = diagnose_model(store, model_id, records=records, bench_fit=bench_fit)
    model = load_model(row)
    blocks = []
    for i, (dataset_id, record) in enumerate(zip(row["datasets"], records)):
        blocks += block_curves(record, model.predict(record), dataset_id)
        records[i] = None  # this record's arrays are no longer needed
    return {
        "row": row,
        "steps": steps,
        "dataset_rows": dataset_rows,
        "diagnosis": diagnosis,
        "model": model,
        "blocks": blocks,
    }


def worst_block(blocks: list[BlockCurves]) -> int | None:
    """The index in ``blocks`` of the block with the largest held-out RMS, the figure each block's title
    prints (the stored model's; the diagnosis's failures are of its own fit and places, issue 39)."""
    rms_of = [b.held_out_rms_um if b.held_out_rms_um is not None else -1.0 for b in blocks]
    return int(np.argmax(rms_of)) if blocks else None


def model_report(store: Store, model_id: str, bench_fit=None) -> str:
    """The report of a stored model as HTML text (NotFoundError for an unknown id); ``bench_fit`` as
    for service.usecases.discover.diagnose_model."""
    g = _gather(store, model_id, bench_fit)
    row, steps, dataset_rows = g["row"], g["steps"], g["dataset_rows"]
    description = g["model"].describe() if hasattr(g["model"], "describe") else {}
    root = store.get_model(steps[0]["model_id"])
    return render_report(
        row,
        description,
        [{k: r.get(k) for k in DATASET_FIELDS} for r in dataset_rows],
        steps,
        g["diagnosis"],
        g["blocks"],
        commands(dataset_rows, steps, root),
        utc_now(),
        worst_block(g["blocks"]),
        physical_with_units(row),
    )


def physical_with_units(row: dict) -> dict:
    """The stored model's effect parameters, each with its unit, and the effect's role in the model
    ("physical", or "capacity" for a loop-shape effect on a base that draws any loop shape):
    ``{effect: {"role": role, "values": {name: (value, unit)}}}``."""
    out = {}
    for effect, values in discovered_parameters(row).items():
        units = parameter_units(effect, values)
        if values:
            out[effect] = {
                "role": role_in_model(effect, row["effects"]),
                "values": {name: (value, units[name]) for name, value in values.items()},
            }
    return out


def model_figures(store: Store, model_id: str) -> dict:
    """The report's figures alone, for a page to inline: the error history and, per block, its name,
    held-out and training RMS (µm), whether its held-out RMS is the largest (worst), and its SVG."""
    g = _gather(store, model_id)
    d, blocks = g["diagnosis"], g["blocks"]
    worst = worst_block(blocks)
    return {
        "model_id": model_id,
        "axis": g["row"]["axis"],
        "noise_floor_um": d.get("noise_floor_um"),
        "verdict": d.get("verdict"),
        "worst_block": worst,
        "history_svg": history_figure(g["steps"], d.get("noise_floor_um")),
        "blocks": [
            {
                "title": b.title,
                "dataset_id": b.dataset_id,
                "block_index": b.block_index,
                "frequency_hz": b.frequency_hz,
                "held_out_rms_um": b.held_out_rms_um,
                "train_rms_um": b.train_rms_um,
                "worst": i == worst,
                "svg": block_figure(b, g["row"]["axis"], worst=i == worst),
            }
            for i, b in enumerate(blocks)
        ],
    }
