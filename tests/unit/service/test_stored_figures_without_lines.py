"""A stored model's held-out figure on a record whose gauge shows lines at rest (issue 39): the
diagnosis and a discover step judge the model with those lines taken out, while the stored
``metrics.validation_rms_um`` is on the record as recorded. The stored model carries the line-free
figure too (``metrics.without_lines``), equal to what its diagnosis prints, so the two labels on the
Models page and the discover table each trace to a stored value."""

from __future__ import annotations

import warnings

import pytest

from service.render.model_report import _model_section
from service.science.data.units import fmt_nm
from service.science.discovery.composite import CompositeModel
from service.science.discovery.diagnosis import diagnose_line_free
from service.science.discovery.rests import LineFree
from service.store import Store
from service.usecases.identify import store_model
from tests.support.disturbed_stages import HUM_LINES, records

FS = 5000.0  # Hz


@pytest.fixture(autouse=True)
def _quiet():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        yield


def test_a_model_stored_from_a_hummed_record_keeps_the_diagnosis_figure_beside_its_own(tmp_path):
    recs = records("bw_beta_lt_gamma", "hum", "long", fs=FS)
    line_free = LineFree.of(recs)
    assert line_free.had_lines
    model = CompositeModel(["hysterons"]).fit(line_free.records)  # as a discover step fits it
    store = Store(f"sqlite:///{tmp_path}/evcbench.db", tmp_path)
    row = store_model(store, model, recs, "y", ["ds_hum"], model.effects, 10, None, None, line_free=line_free)
    stored = store.get_model(row["id"])["metrics"]
    judged = diagnose_line_free(line_free, model)
    assert stored["without_lines"]["validation_rms_um"] == pytest.approx(judged["residual_rms_um"], rel=1e-9)
    assert sorted(round(f) for f in stored["without_lines"]["lines_hz"]) == [f for f, _, _ in HUM_LINES]
    # the hum (12 and 4 nm) is in the figure as recorded, and out of the diagnosis's
    assert stored["validation_rms_um"] > 2.0 * stored["without_lines"]["validation_rms_um"]
    # the report prints both, each under its own label, each to 4 significant figures of its stored value
    section = _model_section(store.get_model(row["id"]), {}, {})
    assert fmt_nm(stored["validation_rms_um"], 4) in section
    assert "lines seen at rest taken out" in section and fmt_nm(judged["residual_rms_um"], 4) in section
    # the play operators as the parameters hold them: the wider base doubles the 10 asked for
    assert len(row["parameters"]["thresholds_v"]) == 20 and "20 (10 asked; hysterons multiplies them)" in section


def test_a_model_stored_from_a_quiet_record_has_one_figure(tmp_path):
    recs = records("bw_beta_lt_gamma", "clean", "long", fs=FS)
    model = CompositeModel([]).fit(recs)
    store = Store(f"sqlite:///{tmp_path}/evcbench.db", tmp_path)
    row = store_model(store, model, recs, "y", ["ds_quiet"], [], 10, None, None)
    assert "without_lines" not in store.get_model(row["id"])["metrics"]
