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
    return {
        "effects": [a["effect"], b["effect"]],
        "excess_ratio": ratio,
        "text": f"{a['effect']} and {b['effect']} explain the residual about equally well "
        f"(held-out {fmt_nm(a['expected_rms_um'])} and "
        f"{fmt_nm(b['expected_rms_um'])}); {why}",
        "experiment": experiment_body(records, axes, **body),
    }
