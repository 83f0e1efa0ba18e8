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


def _sweep(frequencies_hz, cycles: int):
    """One Y record of 1-second-ish sine blocks at ``frequencies_hz``, ``cycles`` each, 20 kHz."""
    import numpy as np

    from service.science.data.record import Record

    fs, parts, blocks, start = 20000.0, [], [], 0
    for i, f in enumerate(frequencies_hz):
        n = int(round(cycles * fs / f))
        parts.append(60.0 * (1.0 - np.cos(2 * np.pi * f * np.arange(n) / fs)))
        blocks.append(
            {"index": i, "start": start, "stop": start + n, "kind": "sine", "cycles": cycles, "frequency_hz": f}
        )
        start += n
    u = np.concatenate(parts)
    return Record(u, 0.06 * u, fs, blocks=blocks, axis="y", hold_out=True)


def test_a_separating_sweep_already_in_the_data_is_not_proposed_again():
    """A walk ran the Separate sweep for asymmetry and the gauge's bow (1–200 Hz, 10 cycles); the pair
    still explained the residual alike, and the answer still said "a guess until the experiment that
    separates them is run" while the report proposed the same sweep. With that sweep in the data the
    ambiguity is said, with no sweep, and the answer says no sweep of this bench settles it."""
    from service.science.discovery.ambiguity import ambiguity

    claimed = [{**LEAD, "claimed": True}, {**OTHER, "claimed": True}]
    before = ambiguity(claimed, [_sweep([1.0, 10.0, 50.0, 100.0], 5)], 0.00315)
    assert before["experiment"]["frequencies_hz"] == [1.0, 10.0, 50.0, 100.0, 200.0]
    after = ambiguity(
        claimed, [_sweep([1.0, 10.0, 50.0, 100.0], 5), _sweep([1.0, 10.0, 50.0, 100.0, 200.0], 10)], 0.00315
    )
    assert after["experiment"] is None and after["separating_sweep_in_data"]["cycles"] == 10
    assert "in the data already" in after["text"]
    answer = diagnosis_answer(claimed, [], 0.1473, 0.00315, False, None, None, after)
    assert "until the experiment" not in answer["text"] and "in the data already" in answer["text"]
    # fewer cycles than it asks for are not that sweep
    short = ambiguity(claimed, [_sweep([1.0, 10.0, 50.0, 100.0, 200.0], 5)], 0.00315)
    assert short["experiment"] is not None


def test_a_leading_claim_that_another_claim_would_undercut_added_alone_says_why_it_leads():
    """A walk read "adding asymmetry, the leading claim, … to about 93.41 nm" beside rate_dependence's
    90.75 nm added alone, with nothing saying why; the answer now says what the claims rank by."""
    from service.science.discovery.answer import diagnosis_answer

    lead = {"effect": "asymmetry", "expected_rms_um": 0.09341}
    lower = {"effect": "rate_dependence", "expected_rms_um": 0.09075}
    higher = {"effect": "dynamics", "expected_rms_um": 0.120}
    text = diagnosis_answer([lead, higher, lower], [], 0.1473, 0.00315, False, None)["text"]
    assert "rate_dependence, added alone, would leave less (90.75 nm)" in text and "asymmetry removes the most" in text
    assert "added alone" not in diagnosis_answer([lead, higher], [], 0.1473, 0.00315, False, None)["text"]
