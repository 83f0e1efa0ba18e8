"""The Lab page's "newest model" of a bench is fitted on that bench's own data: a model fitted on an
import (the dataset's bench_id is the service's, its source "import") describes the stage that recorded
the file, so it is listed apart with its origin, never as the bench's newest (a new user's walk)."""

from __future__ import annotations

import numpy as np

from service.runtime.heartbeat import register
from service.runtime.settings import Settings
from service.store import Store
from service.store.benches import latest_models
from service.usecases import lab


def _dataset(store: Store, name: str, source: str) -> str:
    arrays = {"t_s": np.arange(4) / 10.0, "u_y_v": np.zeros(4), "x_y_um": np.zeros(4)}
    plan = {"import": {"filename": "Model_Vi_Do.dat"}} if source == "import" else {}
    meta = {"name": name, "source": source, "axes": ["y"], "sample_rate_hz": 10.0, "plan": plan}
    return store.add_dataset(arrays, meta)["id"]


def _model(store: Store, datasets: list[str], rms_um: float) -> str:
    record = {"axis": "y", "kind": "static_pi", "datasets": datasets, "parameters": {"model": "x"}}
    return store.add_model(record | {"metrics": {"validation_rms_um": rms_um}})["id"]


def test_an_imported_models_is_not_the_benchs_newest(tmp_path):
    store = Store(f"sqlite:///{tmp_path / 'lab.db'}", tmp_path / "data")
    store.bench_id = "default_realtime"
    try:
        register(store.benches, Settings(bench="default", bench_id="default_realtime"), "host:1:x", "idle")
        recorded, imported = _dataset(store, "sweep 1", "sweep"), _dataset(store, "yan9a", "import")
        own = _model(store, [recorded], 0.0221)
        foreign = _model(store, [imported], 0.0092)  # newer, and its low RMS describes another stage

        latest = {(m["axis"], m["imported_data"]): m["id"] for m in latest_models(store.engine)}
        assert latest == {("y", False): own, ("y", True): foreign}
        bench = lab.benches(store)["benches"][0]
        assert bench["id"] == "default_realtime" and bench["latest_models"]["y"]["id"] == own
        # the import's bench_id is the service's, but it is not one of the bench's recordings
        assert store.get_dataset(imported)["bench_id"] == "default_realtime"
        assert (bench["datasets"], bench["imported_datasets"]) == (1, 1)
        assert bench["latest_models"]["y"]["origin"] == {"fitted_on": "this_bench", "imported": []}
        apart = bench["latest_imported_models"]["y"]
        assert apart["id"] == foreign and apart["validation_rms_um"] == 0.0092
        assert apart["origin"] == {
            "fitted_on": "imported",
            "imported": [{"dataset_id": imported, "name": "yan9a", "filename": "Model_Vi_Do.dat"}],
        }
        assert bench["latest_models"]["z"] is None and bench["latest_imported_models"]["z"] is None
    finally:
        store.close()
