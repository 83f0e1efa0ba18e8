"""The loop-shape pair (the stack's asymmetry and the gauge's bow) in a diagnosis: whether the
measured loop is point-symmetric is tested without a model (service.science.discovery.symmetry); if
it is not, the two are fitted head to head on the model, and the one that fits the held-out cycles
better is claimed, or the pair is an ambiguity with its separating sweep. On a base that draws any
rate-independent loop shape both are capacity. Units: µm, µm² (nm in the texts)."""

from __future__ import annotations

from service.science.data.units import fmt_nm
from service.science.discovery.ambiguity import separating
from service.science.discovery.candidate_rows import Judged, candidate_row, claimed_size
from service.science.discovery.decision import NOISE_MULTIPLE, claimed, held_out_improvement
from service.science.discovery.identifiability import experiment_body
from service.science.discovery.ranking import claim_size, size_words
from service.science.discovery.symmetry import asymmetry_test
from service.science.effects import EFFECTS

#: the loop-shape pair: a stack that is not point-symmetric, and a gauge that bows what it reads
LOOP_SHAPE = ("asymmetry", "sensor_nonlinearity")


def base_draws_any_loop_shape(effects) -> bool:
    """Whether a model of ``effects`` (a stored model's list names "hysteresis", the base, too) has a
    base that draws any rate-independent loop shape (issue 37's wider base): on it the loop-shape pair
    is that base's shape, not physics."""
    return any(e in EFFECTS and getattr(EFFECTS[e], "draws_any_loop_shape", False) for e in effects)


def role_in_model(effect: str, effects) -> str:
    """What ``effect`` is in a model of ``effects``: its library kind ("physical" or "capacity"), except
    the loop-shape pair on a base that draws any loop shape, which is capacity there (as the diagnosis
    offered it: ``loop_shape_as_capacity``)."""
    if effect in LOOP_SHAPE and base_draws_any_loop_shape(effects):
        return "capacity"
    return EFFECTS[effect].kind


def loop_shape_as_capacity(judged: Judged) -> list[dict]:
    """The loop-shape pair on a base that draws any rate-independent loop shape (issue 37's wider
    base): what either still explains is that base's shape, so each is offered as capacity (validated
    against the model itself, never claimed as physics). The stack's asymmetry and the gauge's bow
    are named as physics only while the base is point-symmetric, where they can be told apart."""
    fits, records, v0 = judged.fits, judged.records, judged.v0
    _, res0, _ = fits.get(())
    rows = []
    for name in LOOP_SHAPE:
        _, res, _ = fits.get((name,))
        test = held_out_improvement(records, res0, res)
        how = (
            f"the base draws any rate-independent loop shape, so what {name}'s columns add is that base's "
            f"shape, offered as capacity and not as physics (p = {test['p']:.2g} against the model itself)"
        )
        is_claimed = claimed(test, 0.0)
        gain, anchor, whole = claimed_size(test, is_claimed)
        rows.append(
            candidate_row(
                name,
                judged,
                is_claimed,
                test["p"],
                gain,
                (),
                v0,
                how,
                kind="capacity",
                anchor=anchor,
                whole_um2=whole,
            )
        )
    return rows


def loop_shape_pair(judged: Judged, alpha: float) -> tuple[list[dict], dict | None]:
    """Asymmetry and sensor_nonlinearity, neither in the model. Whether the measured loop is
    point-symmetric is tested without a model (a point-symmetric stack of any family has no even
    part; symmetry.py); if it is not, the stack's asymmetry (a function of the drive and the loop's
    state) and the gauge's curvature (a function of x) are fitted head to head, each on the model:
    the one that fits the held-out cycles significantly better (the claim rule's p) is claimed; if
    neither does, the better one is claimed and the pair is returned as an ambiguity."""
    # the model's residual where the model draws a point-symmetric loop itself (then its even part is
    # the measurement's less the transients the model draws, a mode's ring-down); else the measurement
    # (or a base that draws any loop shape, issue 37: an asymmetric loop it draws is the base's, not physics)
    fits, records, noise, v0 = judged.fits, judged.records, judged.noise, judged.v0
    if base_draws_any_loop_shape(fits.model.effects):
        return loop_shape_as_capacity(judged), None
    symmetric = all(EFFECTS[e].point_symmetric for e in fits.model.effects)
    test = asymmetry_test(records, fits.get(())[1] if symmetric else [r.x_um for r in records], noise, alpha)
    even2 = (test["even_rms_um"] or 0.0) ** 2
    shape = (
        f"the mean cycles' even part (what a point-symmetric loop of any family cannot have) is "
        f"{fmt_nm(test['even_rms_um'] or 0.0)} RMS over {test['blocks']} blocks (p = {test['p']:.2g}, "
        f"noise σ = {fmt_nm(noise)})"
    )
    if not test["claimed"]:
        gauge = (
            shape + "; a gauge's bow would show there, so there is none to see (its S-bend alone is a loop "
            "shape the flexible base draws)"
        )
        return [
            candidate_row("asymmetry", judged, False, test["p"], even2, (), v0, shape),
            candidate_row("sensor_nonlinearity", judged, False, 1.0, 0.0, (), v0, gauge),
        ], None
    _, res_a, v_a = fits.get(("asymmetry",))
    _, res_s, v_s = fits.get(("sensor_nonlinearity",))
    gauge_better = held_out_improvement(records, res_a, res_s)
    stack_better = held_out_improvement(records, res_s, res_a)
    if claimed(gauge_better, 0.0, alpha) or claimed(stack_better, 0.0, alpha):
        winner, separated = ("sensor_nonlinearity" if claimed(gauge_better, 0.0, alpha) else "asymmetry"), True
    else:
        winner, separated = ("sensor_nonlinearity" if v_s < v_a else "asymmetry"), False
    h2h = (
        f"head to head on the model, the stack's asymmetry leaves {fmt_nm(v_a)} held out and the gauge's "
        f"curvature {fmt_nm(v_s)} (p = {stack_better['p']:.2g} that the stack fits better, "
        f"{gauge_better['p']:.2g} that the gauge does, over {gauge_better['segments']} segments)"
    )
    size, whole = claim_size(records, fits.get(())[1], res_a if winner == "asymmetry" else res_s)
    # the claim rule's size: an even part that is there but that the winner's fit does not take out of
    # the held-out cycles (an imported static PI: 3.16 → 3.19 nm "with it") is no missing effect
    lowers = size >= NOISE_MULTIPLE * noise**2
    if not lowers:
        h2h += (
            f"; added to the model, {winner} does not lower the held-out error by the noise's σ² "
            f"({size_words(size, (), whole)}): neither is claimed"
        )
    rows = [
        candidate_row(
            name,
            judged,
            name == winner and lowers,
            test["p"] if name == winner else (stack_better if name == "asymmetry" else gauge_better)["p"],
            size if name == winner else 0.0,
            (),
            v0,
            f"{shape}; {h2h}",
            anchor="training_mean" if name == winner else "last_cycle",
            whole_um2=whole if name == winner else None,
        )
        for name in LOOP_SHAPE
    ]
    for row in rows:  # the pair's own figures, each fitted with the model: what a separation compares
        row["head_to_head_rms_um"] = v_a if row["effect"] == "asymmetry" else v_s
    if separated or not lowers:
        return rows, None
    other = next(n for n in LOOP_SHAPE if n != winner)
    why, body = separating()[frozenset(LOOP_SHAPE)]
    axes = sorted({r.axis for r in records if r.axis}) or ["y"]
    return rows, {
        "effects": [winner, other],
        "excess_ratio": None,
        "text": (
            f"the loop is not point-symmetric, and {winner} and {other} explain it about equally well "
            f"(held-out {fmt_nm(min(v_a, v_s))} and {fmt_nm(max(v_a, v_s))}); {why}"
        ),
        "experiment": experiment_body(records, axes, **body),
    }
