"""A held-out test with no segment to test on says so (issue 39: "p = 1 over 0 held-out segments" read
as a test that found nothing), and an import is named by its file and its name alike in the dataset
list and on its page."""

from __future__ import annotations

from service.http.datasets import dataset_view
from service.science.discovery.verdict import p_words


def test_no_segments_is_not_printed_as_a_p_value():
    words = p_words(1.0, 0)
    assert words.startswith("no held-out segments to test on") and "p = " not in words
    assert "too few to test" in p_words(1.0, 1) and "p = " not in p_words(1.0, 1)
    assert p_words(3.2e-5, 48, " at the training mean") == "p = 3.2e-05 at the training mean over 48 held-out segments"


def _row(source: str, plan: dict | None) -> dict:
    keys = ("id", "name", "axes", "samples", "sample_rate_hz", "partial", "partial_reason", "created_at")
    row = dict.fromkeys(keys) | {"id": "ds_1", "name": "yan9a", "source": source, "samples": 100}
    row |= {"sample_rate_hz": 200.0, "started_at": None, "finished_at": None, "job_id": None, "tags": []}
    row |= {"notes": None, "bench_id": "default_realtime", "blocks": [], "plan": plan, "config": None}
    return row | {"units": {}, "software_version": "x", "file": "f", "sha256": "0"}


def test_an_imports_file_is_in_the_list_and_on_its_page():
    row = _row("import", {"import": {"filename": "Model_Vi_Do.dat"}})
    assert dataset_view(row, full=False)["import_filename"] == "Model_Vi_Do.dat"
    assert dataset_view(row, full=True)["import_filename"] == "Model_Vi_Do.dat"
    assert dataset_view(_row("sweep", {"drive_range_v": [0, 120]}), full=False)["import_filename"] is None
