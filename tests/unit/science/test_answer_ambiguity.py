"""The diagnosis's answer where the data cannot tell its leading claim from a look-alike
(service.science.discovery.answer): a walk's model page said "Missing: asymmetry … Use 'Add
asymmetry'" while a discover on the same model stopped at once, "adding either would be a guess the
data cannot back". The answer must name both and call adding the leading one a guess."""

from __future__ import annotations

from service.science.discovery.answer import diagnosis_answer

LEAD = {"effect": "asymmetry", "expected_rms_um": 0.0934}
OTHER = {"effect": "sensor_nonlinearity", "expected_rms_um": 0.0981}


def test_an_ambiguous_claim_names_its_look_alike_and_says_adding_it_is_a_guess():
    pair = {"effects": ["asymmetry", "sensor_nonlinearity"], "text": "they explain the residual alike"}
    answer = diagnosis_answer([LEAD, OTHER], [], 0.1473, 0.00315, False, None, None, pair)
    assert answer["missing"] == "asymmetry" and answer["ambiguous_with"] == "sensor_nonlinearity"
    assert answer["text"].startswith("Missing: asymmetry or sensor_nonlinearity; the data cannot tell them apart.")
    assert "147.3 nm" in answer["text"] and "93.4 nm" in answer["text"] and "a guess" in answer["text"]


def test_an_answer_without_a_look_alike_is_unchanged():
    unrelated = {"effects": ["creep", "drift"], "text": "…"}
    for pair in (None, unrelated):
        answer = diagnosis_answer([LEAD], [], 0.1473, 0.00315, False, None, None, pair)
        assert answer["ambiguous_with"] is None
        assert (
            answer["text"]
            == "Missing: asymmetry. Adding it should bring the held-out error from 147.3 nm to about 93.4 nm."
        )
