"""Two claimed effects that look alike on the data at hand and explain the residual about equally
well: the ambiguity, and the sweep that tells them apart (from each effect's ``separated_from``).
Units: µm in, nm in the words."""

from __future__ import annotations

from service.science.data.units import fmt_nm
from service.science.discovery.identifiability import experiment_body
from service.science.effects import EFFECTS


def separating() -> dict[frozenset, tuple[str, dict]]:
    """Pairs of effects that look alike on a sine sweep -> (how to tell them apart in words, the
    /api/sweeps body that does), from every registered effect's ``separated_from``."""
    return {
        frozenset((name, other)): told for name, eff in EFFECTS.items() for other, told in eff.separated_from.items()
    }


#: two leading candidates are told apart when the runner-up leaves at least this many times the
#: unexplained excess (held-out RMS² above the noise floor²) of the leader
SEPARATED_EXCESS_RATIO = 2.0


def remaining_excess(candidate: dict, noise: float) -> float:
    """What a candidate leaves unexplained above the noise floor (µm²), never below (σ/10)²."""
    return max(candidate["expected_rms_um"] ** 2 - noise**2, (0.1 * noise) ** 2)


def ambiguity(physical: list[dict], records, noise: float = 0.0) -> dict | None:
    """Two leading claimed candidates that are look-alikes (a pair of ``separating()``: their residual
    signatures coincide on the data at hand) and explain the residual about equally well (the
    runner-up leaving less than twice the leader's unexplained excess), with the experiment that
    separates them. Two claimed effects that do not look alike are both present, not alternatives:
    the loop adds the larger and the next diagnosis tests the other."""
    if len(physical) < 2 or not (physical[0]["claimed"] and physical[1]["claimed"]):
        return None
    a, b = physical[0], physical[1]
    pair = frozenset((a["effect"], b["effect"]))
    ratio = remaining_excess(b, noise) / remaining_excess(a, noise)
    pairs = separating()
    if pair not in pairs or ratio >= SEPARATED_EXCESS_RATIO:
        return None
    why, body = pairs[pair]
    axes = sorted({r.axis for r in records if r.axis}) or ["y"]
    experiment = experiment_body(records, axes, **body)
    text = (
        f"{a['effect']} and {b['effect']} explain the residual about equally well "
        f"(held-out {fmt_nm(a['expected_rms_um'])} and {fmt_nm(b['expected_rms_um'])}); {why}"
    )
    if not in_the_data(experiment, records):
        return {"effects": [a["effect"], b["effect"]], "excess_ratio": ratio, "text": text, "experiment": experiment}
    return {  # run already (a Separate, a discover's experiment): proposing it again would change nothing
        "effects": [a["effect"], b["effect"]],
        "excess_ratio": ratio,
        "text": text + ". The sweep that separates them is in the data already "
        f"({', '.join(f'{f:g}' for f in experiment['frequencies_hz'])} Hz, {experiment.get('cycles', 1)} cycles), "
        "and they still explain it alike: no sweep of this bench tells them apart",
        "experiment": None,
        "separating_sweep_in_data": experiment,
    }


def in_the_data(experiment: dict, records) -> bool:
    """Whether ``records`` already hold a sine sweep's every frequency (Hz, to 1e-6) on their own axis,
    each in a block of at least its ``cycles`` (a step sweep or any other: never)."""
    if experiment.get("waveform") != "sine" or not experiment.get("frequencies_hz"):
        return False
    held = [
        (s.block["frequency_hz"], s.block.get("cycles") or 0)
        for r in records
        for s in r.splits_of(own_axis_only=True)
        if s.block.get("frequency_hz")
    ]
    need = experiment.get("cycles") or 1
    return all(
        any(abs(f - float(asked)) <= 1e-6 * float(asked) and cycles >= need for f, cycles in held)
        for asked in experiment["frequencies_hz"]
    )
