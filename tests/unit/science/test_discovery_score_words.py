"""A score's words (issue 39): "11300 nm² removed by its test / 8280 nm² above the noise floor", score 1,
stated a part larger than its whole. The two figures are of different fits (its test against its
reference, levels anchored at the last training cycle; this model's held-out RMS² − σ², not anchored):
each is labelled, and where the drop is the larger the words say the score is capped at 1."""

from __future__ import annotations

from service.science.discovery.verdict import score_capped, score_words
from tests.support.text_scan import part_whole_problems


def test_a_drop_larger_than_the_excess_is_not_printed_as_its_part():
    words = score_words(11300e-6, 8280e-6, ("drift",))
    assert part_whole_problems(words) == [], words
    assert words.startswith("11300 nm² of held-out mean square removed by its test (against the model + drift")
    assert "more than 8280 nm² of this model's held-out mean square above the noise floor" in words
    assert words.endswith("the score is capped at 1") and score_capped(11300e-6, 8280e-6)
    assert "anchored at its last training cycle" in words and "levels not anchored" in words


def test_a_drop_within_the_excess_is_its_numerator_over_its_denominator():
    words = score_words(5150e-6, 8280e-6)
    assert part_whole_problems(words) == [] and "capped" not in words
    assert "5150 nm² of held-out mean square removed by its test (against the model, " in words
    assert " / 8280 nm² of this model's held-out mean square above the noise floor" in words
    # equal at the printed digits: a whole, not "more than"
    assert "capped" not in score_words(8280.4e-6, 8280e-6)
    assert not score_capped(8280.4e-6, 8280e-6) and not score_capped(5150e-6, 8280e-6)


def test_a_claim_at_the_training_mean_prints_that_anchorings_figure():
    """A claim rests on the anchoring its p is of: drift claimed at its training mean (142 nm²) printed the
    last training cycle's −1.15 nm² and score 0 beside its claim."""
    from service.science.discovery.candidate_rows import claimed_size

    test = {"gain_mse_um2": -1.15e-6, "gain_trend_mse_um2": 142e-6, "p": 5.3e-4, "p_anchor": "training_mean"}
    test.update(reference_mse_um2=900e-6, reference_trend_mse_um2=1000e-6)
    assert claimed_size(test, True) == (142e-6, "training_mean", 1000e-6)  # with the whole at its anchoring
    assert claimed_size(test, False) == (-1.15e-6, "last_cycle", 900e-6)  # not claimed: as every row's
    gain, anchor, _ = claimed_size(test, True)
    words = score_words(gain, 8280e-6, ("creep",), anchor)
    assert words.startswith("142 nm² of held-out mean square removed by adding it (against the model + creep")
    assert "anchored at its training mean, the anchoring its claim rests on" in words and "−1.15" not in words


def test_a_negative_drop_is_worded_as_a_rise_not_a_removal():
    """A test whose fit did worse on the held-out cycles (gain −1.52 µm²) printed "−1520000 nm² … removed by
    its test": a negative removal is a rise of the held-out mean square, said so, with score 0."""
    from service.science.discovery.ranking import size_words
    from service.science.discovery.verdict import share_words

    words = score_words(-1.52, 8280e-6, ("drift",))
    assert part_whole_problems(words) == [], words
    assert words.startswith("its test raised the held-out mean square by 1520000 nm² (against the model + drift")
    assert "removed by its test" not in words and words.endswith("score 0")
    assert "nothing removed of 8280 nm² of this model's held-out mean square above the noise floor" in words
    # a drop that prints as 0 is not a rise
    assert score_words(-1e-13, 8280e-6).startswith("0 nm² of held-out mean square removed by its test")
    size = size_words(-2.5e-6, ("creep",))
    assert "raised by 2.5 nm² over the model + creep" in size and part_whole_problems(size) == []
    assert share_words(0.734) == "73 % of the excess above the noise floor"
    assert share_words(-0.003) == "0 % of the excess above the noise floor"  # not "-0 %"
    assert share_words(-0.2) == "none of the excess above the noise floor removed: the held-out RMS rises"
    assert part_whole_problems(f"Added to this model: 10 nm → 12 nm ({share_words(-0.2)}).") == []


def test_a_capped_score_says_so_in_the_evidence_sentence_too():
    """The Discover card shows the evidence's score sentence alone: a walk read "the score, 1, is its own
    test's share" for a score the table marked "(capped)"."""
    from service.science.discovery.candidate_rows import score_sentence

    assert "1 (capped: its test removed more than this model's excess" in score_sentence(1.0, "training_mean", True)
    assert "capped" not in score_sentence(0.52, "training_mean")
