"""Issue 39: the diagnosis's texts tell one consistent story. On the default bench, a foreign import
(the real yan9a-dbo record) and a clean stage simulated outside the product: no figure states a part
larger than its whole ("11.5 nm of the remaining 10.6 nm repeats cycle to cycle" was one), every
error is in nm without an exponent, every delay in µs; the candidates are in score order (physics,
then capacity); and the answer the pages show first is one stored value that names the verdict's
effect and the remainder's leading signature. The scanner: tests/support/text_scan.py."""

from __future__ import annotations

import re
import warnings

import numpy as np
import pytest

from service.science.data.record import Record
from service.science.data.segmentation import blocks_without_table
from service.science.data.units import fmt_nm2
from service.science.discovery.composite import fit_composite
from service.science.discovery.diagnosis import diagnose
from service.science.discovery.records import records_from_arrays
from tests.support.foreign_stage import SAMPLE_RATE_HZ, drive_v, stage_um
from tests.support.realdata import MODEL_VI_DO
from tests.support.text_scan import (
    empty_clauses,
    part_whole_problems,
    repeated_part_within_whole,
    scan,
    unit_problems,
)

pytestmark = pytest.mark.slow  # three diagnoses and a refit: about 30 s on one core


def _records(source: str, sweeps) -> list[Record]:
    if source == "default":  # two blocks of the default bench's Y, recorded by its emulator
        return [sweeps("default", seed=0, frequencies_hz=(10.0, 100.0), cycles=5, axes=("y",))["y"]]
    if source == "foreign":  # another lab's record, as imported
        data = np.loadtxt(MODEL_VI_DO)
        return [Record(data[:, 0], data[:, 4], 200.0, label="yan9a", hold_out=True)]
    u = drive_v()  # a clean Bouc–Wen stage nobody here built: nothing to claim
    blocks = blocks_without_table({"y": u}, SAMPLE_RATE_HZ)
    return records_from_arrays({"u_y_v": u, "x_y_um": stage_um("clean", u)}, SAMPLE_RATE_HZ, blocks, ("y",), "clean:")[
        :1
    ]


@pytest.fixture(scope="module")
def diagnoses(sweeps):
    """Per source: the first diagnosis, and one of the model with the verdict's effect (or capacity) added."""
    out = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for source in ("default", "foreign", "clean"):
            records = _records(source, sweeps)
            first = diagnose(records)
            add = first["answer"]["missing"]
            second = diagnose(records, model=fit_composite(records, [add])) if add else None
            out[source] = [d for d in (first, second) if d is not None]
    return out


@pytest.mark.parametrize("source", ["default", "foreign", "clean"])
def test_no_part_is_larger_than_its_whole(diagnoses, source):
    for d in diagnoses[source]:
        assert scan(d, part_whole_problems) == []
        assert repeated_part_within_whole(d) == []


@pytest.mark.parametrize("source", ["default", "foreign", "clean"])
def test_one_unit_per_quantity(diagnoses, source):
    for d in diagnoses[source]:
        assert scan(d, unit_problems) == []


@pytest.mark.parametrize("source", ["default", "foreign", "clean"])
def test_no_text_has_an_empty_clause(diagnoses, source):
    """Every evidence (the hysterons row's read "before any fit: ." on every page) and every other text."""
    for d in diagnoses[source]:
        assert scan(d, empty_clauses) == []
        if source != "clean":  # the row that had one (the clean stage's diagnoses list no hysterons row)
            assert any(c["effect"] == "hysterons" for c in d["candidates"])


@pytest.mark.parametrize("source", ["default", "foreign", "clean"])
def test_each_score_prints_the_figures_it_is_the_ratio_of(diagnoses, source):
    """The score is of the test's anchored mean-square drop, not of the RMS figures beside it (issue 39:
    dynamics 0.526 above rate dependence 0.517 while its test's RMS was worse): ``score_of`` prints
    the numerator and denominator (nm²), whose ratio is the score to the printed digits."""
    for d in diagnoses[source]:
        for c in (c for c in d["candidates"] if c.get("testable", True)):
            gain, excess = (float(v) for v in re.findall(r"(-?[\d.]+) nm²", c["score_of"])[:2])
            if " raised the held-out mean square by " in c["score_of"]:  # a negative drop, worded as a rise
                gain = -gain
                assert f" raised the held-out mean square by {fmt_nm2(-c['gain_mse_um2'])} (" in c["score_of"]
                assert c["score"] == 0
            else:
                assert c["score_of"].startswith(f"{fmt_nm2(c['gain_mse_um2'])} of held-out mean square removed by ")
            assert c["score"] == pytest.approx(min(max(gain / excess, 0.0), 1.0), abs=0.01, rel=0.01), c["score_of"]
            # a 1 that is a cap is flagged, as its words say (the pages label it)
            assert c["score_capped"] == c["score_of"].endswith("the score is capped at 1"), c["score_of"]


@pytest.mark.parametrize("source", ["default", "foreign", "clean"])
def test_a_claim_prints_a_positive_removal_at_the_anchoring_it_rests_on(diagnoses, source):
    """No claim is printed beside a removal ≤ 0 ("drift claimed with score 0 and −1.15 nm² removed": the
    claim rested on the training-mean anchoring, the words printed the last training cycle's)."""
    for d in diagnoses[source]:
        for c in (c for c in d["candidates"] if c.get("claimed") and c.get("score_of")):
            assert c["gain_mse_um2"] > 0 and c["score"] > 0, (c["effect"], c["score_of"])
            assert not c["score_of"].startswith(("-", "−")), c["score_of"]


def test_the_scanner_finds_what_it_is_for():
    """The scanner's own negatives: each of the issue's examples is found."""
    assert empty_clauses("In this model's residual, before any fit: . Its test") and empty_clauses("gives ()")
    assert not empty_clauses("before any fit: the residual lags the drive by 24.1 µs. Its test: p = 0.01.")
    assert part_whole_problems("11.5 nm of the remaining 10.6 nm repeats cycle to cycle")
    assert not part_whole_problems("9.5 nm of their 10.6 nm RMS repeats cycle to cycle")
    assert part_whole_problems("(104 % of the excess above the noise floor)")
    # a score's words: numerator over denominator (the walk's "score 1" row)
    assert part_whole_problems("11300 nm² removed by its test / 8280 nm² above the noise floor")
    assert part_whole_problems(
        "11300 nm² of held-out mean square removed by its test (against the model, mean over held-out stretches, "
        "each block's level anchored at its last training cycle) / 8280 nm² of this model's held-out mean square"
    )
    assert not part_whole_problems("5150 nm² removed by its test (against the model + drift) / 8280 nm² above")
    # a negative amount "removed" is a rise, and a share below 0 % is none (the walk's "−1520000 nm² removed")
    assert part_whole_problems("−1520000 nm² of held-out mean square removed by its test (against the model)")
    assert part_whole_problems("its size, the rank's figure: -2.5 nm² of held-out mean square removed over the model")
    assert part_whole_problems("Added to this model: 10 nm → 12 nm (-20 % of the excess above the noise floor)")
    assert not part_whole_problems(
        "its test raised the held-out mean square by 1520000 nm²: nothing removed of 8280 nm²"
    )
    assert not part_whole_problems("1520000 nm² of held-out mean square removed by its test (against the model)")
    assert unit_problems("fitted delay 4.11e-05 ms") and unit_problems("0.009225 µm beside 5 nm²")
    assert unit_problems("weights sum -0.0128 µm·ms/V") and unit_problems("σ² = 4.3e+03 nm²")
    assert not unit_problems("delay 24.1 µs, resonance 481.4 Hz, 5150 nm², p = 6.9e-06, 12 nm/s")


@pytest.mark.parametrize("source", ["default", "foreign", "clean"])
def test_candidates_in_rank_order_and_the_answer_is_the_verdicts(diagnoses, source):
    for d in diagnoses[source]:
        testable = [c for c in d["candidates"] if c.get("testable", True)]
        groups = [(c["kind"] == "capacity", c["kind"] == "physical" and not c["claimed"]) for c in testable]
        assert groups == sorted(groups)  # claimed physics, the other physics, capacity
        for group in set(groups):
            # the claimed physics by their size (one figure for every claim: ranking.py), the others by score
            key = "claim_size_um2" if group == (False, False) else "score"
            figures = [c[key] for c, g in zip(testable, groups) if g == group]
            assert figures == sorted(figures, reverse=True), (group, key, figures)
        for c in testable:  # a claim's row and its rank say one figure (creep once read 40400 and 39800 nm²)
            if c["kind"] == "physical" and c["claimed"]:
                assert c["claim_size_um2"] == c["gain_mse_um2"], c["effect"]
                assert c["score_of"].startswith(fmt_nm2(c["claim_size_um2"])), c["score_of"]
        a = d["answer"]
        claimed = [c["effect"] for c in d["candidates"] if c["kind"] == "physical" and c["claimed"]]
        if d["verdict"] == "missing_effect":
            assert a["missing"] == claimed[0] and a["kind"] == "physical"
            assert d["verdict_text"].startswith(f"missing effect: {a['missing']} ")
        else:
            assert not claimed and a["kind"] != "physical"
        top = ((d["remainder"] or {}).get("signatures") or [None])[0]
        assert a["remains"] == (top and top["signature"])
        if top:  # the answer's description is the remainder's own sentence, and only the answer says it
            assert top["text"] in a["text"] and top["text"] not in d["verdict_text"]
        # the page and the report print the answer beside the verdict: no clause is said twice
        assert not clauses(a["text"]) & clauses(d["verdict_text"]), (a["text"], d["verdict_text"])


def clauses(text: str) -> set[str]:
    """A text's clauses of 30 characters or more (split at sentence ends, semicolons and colons)."""
    return {c.strip() for c in re.split(r"(?<=[.;:])\s+", text) if len(c.strip()) >= 30}


def test_the_scanner_reads_a_removal_against_its_reference():
    """A drop is printed with the reference's own held-out mean square at its anchoring (a walk read
    "10300 nm² removed" beside a reference of 92.2 nm held out, 8500 nm²: that RMS is of levels not
    anchored, the drop's whole is not); the scanner checks that form."""
    assert part_whole_problems("removed 10300 nm² of the reference's 8500 nm² at its training mean")
    assert not part_whole_problems("removed 10300 nm² of the reference's 12600 nm² at its training mean")
    assert not part_whole_problems("its size, the rank's figure: 10300 nm² of the 12600 nm² held-out mean square of")
