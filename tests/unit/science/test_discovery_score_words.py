"""A score's words (issue 39): "11300 nm² removed by its test / 8280 nm² above the noise floor", score 1,
stated a part larger than its whole. The two figures are of different fits (its test against its
reference, levels anchored at the last training cycle; this model's held-out RMS² − σ², not anchored):
each is labelled, and where the drop is the larger the words say the score is capped at 1."""

from __future__ import annotations

from service.science.discovery.diagnosis import score_words
from tests.support.text_scan import part_whole_problems


def test_a_drop_larger_than_the_excess_is_not_printed_as_its_part():
    words = score_words(11300e-6, 8280e-6, ("drift",))
    assert part_whole_problems(words) == [], words
    assert words.startswith("11300 nm² of held-out mean square removed by its test (against the model + drift")
    assert "more than 8280 nm² of this model's held-out mean square above the noise floor" in words
    assert words.endswith("the score is capped at 1")
    assert "anchored at its last training cycle" in words and "levels not anchored" in words


def test_a_drop_within_the_excess_is_its_numerator_over_its_denominator():
    words = score_words(5150e-6, 8280e-6)
    assert part_whole_problems(words) == [] and "capped" not in words
    assert "5150 nm² of held-out mean square removed by its test (against the model, " in words
    assert " / 8280 nm² of this model's held-out mean square above the noise floor" in words
    # equal at the printed digits: a whole, not "more than"
    assert "capped" not in score_words(8280.4e-6, 8280e-6)
