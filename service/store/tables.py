"""The metadata schema (SQLAlchemy Core): datasets, models, jobs and the quarantine.

Timestamps are ISO-8601 UTC strings so that SQLite and PostgreSQL return identical values;
structured fields are JSON. Sample arrays are not here: they live in checksummed files.
"""

from __future__ import annotations

from sqlalchemy import JSON, Boolean, Column, Float, Integer, MetaData, String, Table, Text

metadata = MetaData()

datasets = Table(
    "datasets",
    metadata,
    Column("id", String(40), primary_key=True),
    Column("name", Text, nullable=False),
    Column("source", String(20), nullable=False),  # sweep | import
    Column("axes", JSON, nullable=False),  # ["y", "z"]
    Column("samples", Integer, nullable=False),
    Column("sample_rate_hz", Float, nullable=False),
    Column("blocks", JSON, nullable=False),  # block table, see service.science.data.datasets
    Column("plan", JSON, nullable=True),  # the sweep plan (or import options)
    Column("config", JSON, nullable=True),  # bench configuration snapshot
    Column("units", JSON, nullable=False),  # column -> unit
    Column("software_version", String(40), nullable=False),
    Column("partial", Boolean, nullable=False, default=False),
    Column("partial_reason", Text, nullable=True),
    Column("job_id", String(40), nullable=True),
    Column("file", Text, nullable=False),  # path relative to the data dir
    Column("sha256", String(64), nullable=False),
    Column("started_at", String(40), nullable=True),  # acquisition start (sweeps)
    Column("finished_at", String(40), nullable=True),  # acquisition end (sweeps)
    Column("created_at", String(40), nullable=False),
    # added after the first release (service.store.schema upgrades older databases): a user's labels
    Column("tags", JSON, nullable=True),  # ["calibration", …]
    Column("notes", Text, nullable=True),
    # a lab (issue 21): the bench it was recorded on (or imported at); NULL in rows from before
    Column("bench_id", String(40), nullable=True),
)

models = Table(
    "models",
    metadata,
    Column("id", String(40), primary_key=True),
    Column("axis", String(4), nullable=False),
    Column("kind", String(40), nullable=False),  # static_pi | dynamic_pi | grpi
    Column("effects", JSON, nullable=False),
    Column("parent_id", String(40), nullable=True),
    Column("datasets", JSON, nullable=False),
    Column("options", JSON, nullable=True),  # n_operators, …
    Column("parameters", JSON, nullable=False),  # model.to_dict()
    Column("parameters_sha256", String(64), nullable=False),
    Column("metrics", JSON, nullable=False),
    Column("software_version", String(40), nullable=False),
    Column("job_id", String(40), nullable=True),
    Column("created_at", String(40), nullable=False),
    # added after the first release (service.store.schema upgrades older databases): a user's labels
    Column("name", Text, nullable=True),
    Column("tags", JSON, nullable=True),
    Column("notes", Text, nullable=True),
    Column("bench_id", String(40), nullable=True),  # the bench its datasets came from (issue 21)
)

jobs = Table(
    "jobs",
    metadata,
    Column("id", String(40), primary_key=True),
    Column("kind", String(40), nullable=False),  # sweep | identify | …
    Column("needs_bench", Boolean, nullable=False),
    Column("state", String(20), nullable=False),  # queued|running|succeeded|failed|cancelled
    Column("progress", Float, nullable=False, default=0.0),
    Column("message", Text, nullable=True),
    Column("params", JSON, nullable=True),
    Column("result", JSON, nullable=True),
    Column("error", Text, nullable=True),
    Column("created_at", String(40), nullable=False),
    Column("started_at", String(40), nullable=True),
    Column("finished_at", String(40), nullable=True),
    Column("bench_id", String(40), nullable=True),  # the bench whose service runs it (issue 21)
)

#: Rows known to be damaged, set aside by ``evcbench store repair`` instead of being deleted (see
#: service.store.quarantine): a dataset whose array is missing or corrupt, a dangling reference.
quarantine = Table(
    "quarantine",
    metadata,
    Column("record_id", String(40), primary_key=True),  # the dataset or model
    Column("kind", String(40), primary_key=True),  # missing_array | corrupt_array | dangling_reference
    Column("detail", Text, nullable=False),
    Column("moved_to", Text, nullable=True),  # a damaged file moved aside, relative to the data dir
    Column("created_at", String(40), nullable=False),
)
