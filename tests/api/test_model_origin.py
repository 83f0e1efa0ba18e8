"""A model fitted on imported data says so: its ``origin`` names the file (GET /api/models and
/api/models/{id}), and a trajectory run with it as feedforward is warned that it describes
another stage (issue 39: it was stored and offered as if it were this bench's)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from tests.support.foreign_stage import SAMPLE_RATE_HZ, drive_v, stage_um


def test_a_model_on_imported_data_is_marked_imported_and_warned_on_a_trajectory(tmp_path):
    from service.http.app import create_app
    from service.runtime.settings import Settings
    from service.usecases.track import foreign_models
    from tests.support.api_client import authed_client, wait_job

    u = drive_v(frequencies_hz=(1,), cycles=(6,))
    x = stage_um("clean", u)
    lines = ["t_s,u_V,x_um"] + [f"{i / SAMPLE_RATE_HZ!r},{float(u[i])!r},{float(x[i])!r}" for i in range(u.size)]
    app = create_app(Settings(data_dir=tmp_path, seed=0))
    with authed_client(app) as http:
        r = http.post(
            "/api/datasets",
            files={"file": ("other_lab.csv", "\n".join(lines).encode(), "text/csv")},
            data={"name": "foreign", "columns": '{"t": "t_s", "u": "u_V", "x": "x_um"}', "axis": "y"},
        )
        assert r.status_code == 201, r.text
        dataset = r.json()["id"]
        job = wait_job(http, http.post("/api/models", json={"axis": "y", "datasets": [dataset]}).json()["job_id"])
        model_id = job["result"]["model_id"]
        origin = http.get(f"/api/models/{model_id}").json()["origin"]
        assert origin["fitted_on"] == "imported"
        assert origin["imported"] == [{"dataset_id": dataset, "name": "foreign", "filename": "other_lab.csv"}]
        listed = {m["id"]: m for m in http.get("/api/models").json()}
        assert listed[model_id]["origin"]["fitted_on"] == "imported"
        bench, store = SimpleNamespace(axes=("y", "z")), app.state.store
        said = foreign_models(store, bench, {"feedforward_model_y": model_id})
        assert len(said) == 1 and said[0].startswith(f"Y: feedforward model {model_id} was fitted on imported data")
        assert "other_lab.csv" in said[0] and "another stage" in said[0]
        # named by the dataset's name as stored now, its file beside it (the walk: the old name stayed)
        assert http.patch(f"/api/datasets/{dataset}", json={"name": "stage B"}).status_code == 200
        assert http.get(f"/api/models/{model_id}").json()["origin"]["imported"][0]["name"] == "stage B"
        said = foreign_models(store, bench, {"feedforward_model_y": model_id})
        assert "fitted on imported data (“stage B” from the file other_lab.csv)" in said[0], said
        assert foreign_models(store, bench, {}) == []


def _dataset(store, source: str) -> str:
    u = np.linspace(0.0, 1.0, 8)
    meta = {"name": source, "source": source, "axes": ["y"], "sample_rate_hz": 10.0, "blocks": []}
    return store.add_dataset({"t_s": u, "u_y_v": u, "x_y_um": u}, meta)["id"]


def test_origin_is_this_bench_mixed_or_imported_from_the_datasets_sources(store):
    """provenance.model_origin reads each dataset's source: a sweep's model is this bench's and gets no
    trajectory warning; one import among sweeps makes it mixed, and warned."""
    from service.usecases.provenance import foreign_model_warning, model_origin

    swept, imported = _dataset(store, "sweep"), _dataset(store, "import")
    here = model_origin(store, [swept])
    assert here == {"fitted_on": "this_bench", "imported": []} and foreign_model_warning("y", "md_1", here) is None
    mixed = model_origin(store, [swept, imported])
    assert mixed["fitted_on"] == "mixed" and [i["dataset_id"] for i in mixed["imported"]] == [imported]
    assert "fitted on imported data (import)" in foreign_model_warning("z", "md_1", mixed)
    assert model_origin(store, [imported])["fitted_on"] == "imported"
