"""The shares of "what remains" are of one whole (the unseen residual above the noise), each signature
fitted alone: 99.2 % and 11.3 % were printed side by side as if parts of it. Where they sum to more than
100 % they are labelled as overlapping, and the scanner finds an unlabelled sum above the whole."""

from __future__ import annotations

from service.science.discovery.remainder import shares_words
from tests.support.text_scan import part_whole_problems, repeated_part_within_whole


def _diagnosis(shares: list[float], **labels) -> dict:
    signatures = [{"signature": f"s{i}", "share_of_excess": s} for i, s in enumerate(shares)]
    return {
        "repeatable_rms_um": 0.001,
        "repeated_cycles_rms_um": 0.002,
        "remainder": {"signatures": signatures, **labels},
    }


def test_shares_above_the_whole_are_labelled_as_overlapping():
    words = shares_words([0.992, 0.113])
    assert "the shares sum to 110.5 %, more than the whole; they are not parts of it" in words
    assert "fitted alone" in words and "overlap" in words and part_whole_problems(words) == []
    assert shares_words([0.4, 0.2]).endswith("(the shares sum to 60.0 %).") and shares_words([0.7]) == ""


def test_the_scanner_finds_an_unlabelled_sum_above_the_whole():
    assert repeated_part_within_whole(_diagnosis([0.992, 0.113])) == [
        "remainder shares of one whole sum to 110.5 %, not labelled as overlapping"
    ]
    labelled = _diagnosis([0.992, 0.113], shares_overlap=True, shares_text=shares_words([0.992, 0.113]))
    assert repeated_part_within_whole(labelled) == [] and repeated_part_within_whole(_diagnosis([0.6, 0.3])) == []
