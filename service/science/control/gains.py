"""The PID gains a tracking request names ("auto", a preset, or its own), chosen and judged: their
predicted margins on each axis's identified plant (service.science.control.tuning), with warnings
for a target missed and a refusal (ControlRefused) for gains predicted unstable or the paper's.
"""

from __future__ import annotations

from service.science.control.loop import PIDGains
from service.science.control.safety import ControlRefused
from service.science.control.stability import AxisPlant, LoopMargins, loop_margins
from service.science.control.tuning import DESIGN_FREQUENCY_HZ, Targets, tune, worst_failures


def pid_gains(p) -> PIDGains:
    """A preset's or a request's gains as PIDGains: a tuple (kp V/µm, ki V/(µm·s), kd V·s/µm, tf_s s
    [, damping section]) or anything with those attributes."""
    if isinstance(p, tuple):
        return PIDGains(float(p[0]), float(p[1]), float(p[2]), float(p[3]), p[4] if len(p) > 4 else None)
    return PIDGains(p.kp, p.ki, p.kd, p.tf_s, p.damping)


def _auto_gains(
    axis: str, plant: AxisPlant | None, targets: Targets, frequency_hz: float, damp: bool, field: str
) -> PIDGains:
    """ "auto": gains tuned on the axis's plant (ControlRefused naming ``field`` without one)."""
    if plant is None:
        raise ControlRefused(
            field,
            f'"auto" tunes on the plant identified on the bench: give '
            f"controller.feedforward_model_{axis} (its largest slope is the {axis.upper()} gain)",
        )
    try:
        return tune(plant, targets, frequency_hz, damp=damp).gains()
    except ValueError as exc:
        raise ControlRefused(field, f"{axis.upper()}: {exc}") from None


def _gains_words(axis: str, g: PIDGains, margins: LoopMargins, plant: AxisPlant) -> str:
    """One axis's gains, damping section and predicted margins on ``plant``, in words."""
    section = (
        ""
        if g.damping is None
        else (
            f", mode damping {g.damping.gain_v_per_um:.3g} V/µm at "
            f"{g.damping.frequency_hz:.0f} Hz ζ {g.damping.damping_ratio:g}"
        )
    )
    return (
        f"{axis.upper()} kp {g.kp:.4g} V/µm, ki {g.ki:.4g} V/(µm·s), kd {g.kd:.4g} V·s/µm{section}: "
        f"{'stable' if margins.stable else 'UNSTABLE'}, phase margin {margins.phase_margin_deg:.1f}°, gain "
        f"margin {margins.gain_margin_db:.1f} dB, delay margin {margins.delay_margin_s * 1e6:.0f} µs "
        f"(on {plant.gain_um_per_v:.3g} µm/V, {plant.resonance_hz:.1f} Hz ζ {plant.damping_ratio:.3g}, "
        f"{plant.delay_s * 1e6:.0f} µs delay)"
    )


def _judge_axis(
    axis: str, g: PIDGains, plant: AxisPlant | None, targets: Targets, name: str
) -> tuple[dict, list[str], list[str]]:
    """(report entry, warnings, refusals) of one axis's gains: their predicted margins on ``plant``
    (none without a plant) and, without the flexure mode, what they would miss."""
    entry = {
        "kp": g.kp,
        "ki": g.ki,
        "kd": g.kd,
        "tf_s": g.tf_s,
        "damping": None if g.damping is None else g.damping.as_dict(),
        "plant": None,
        "margins": None,
        "failures": [],
    }
    if plant is None:
        return entry, [f"{axis.upper()} PID margins not predicted: no feedforward model gives the plant"], []
    warnings, refusals = [], []
    margins = loop_margins(g.kp, g.ki, g.kd, g.tf_s, plant, damping=g.damping)
    fails = targets.failures(margins)
    entry.update(plant=plant.as_dict(), margins=margins.as_dict(), failures=fails)
    said = _gains_words(axis, g, margins, plant)
    without_mode = [f for f in worst_failures(targets, g, plant) if f.endswith("without the flexure mode")]
    entry["failures_without_mode"] = without_mode
    if name == "paper" or not margins.stable:
        refusals.append(said + (f"; fails: {', '.join(fails)}" if fails else ""))
    elif fails:
        warnings.append(said + f"; misses: {', '.join(fails)}")
    if without_mode and name != "paper":
        warnings.append(
            f"{axis.upper()}: if the stage's mode is not where the bench declares it: " + ", ".join(without_mode)
        )
    return entry, warnings, refusals


def _refuse(name: str, refusals: list[str], field: str) -> None:
    """ControlRefused naming ``field``: the paper's gains, or gains predicted unstable, and why."""
    why = (
        "the paper's gains (eq. 19 units) are refused: " if name == "paper" else "these gains are predicted unstable: "
    )
    raise ControlRefused(
        field,
        why + "; ".join(refusals) + ' (use "auto", or set controller.force to run '
        "them anyway; the divergence watch trips the run to 0 V)",
    )


def choose_pid(
    spec,
    plants: dict,
    presets: dict,
    targets: Targets = Targets(),
    force: bool = False,
    frequency_hz: float = DESIGN_FREQUENCY_HZ,
    field: str = "controller.pid",
    damped_axes: frozenset = frozenset(),
) -> tuple[dict, dict, list[str]]:
    """The gains per axis a request's ``spec`` names ("auto", a key of ``presets`` (axis → PIDGains-like),
    or axis → (kp, ki, kd, tf_s)), with their predicted margins on ``plants`` (axis → AxisPlant, or
    None where no identified model gives the plant); "auto" tunes for a trajectory at ``frequency_hz``,
    with a PPF section on the mode of the ``damped_axes`` (``tune(damp=True)``: for axes whose
    feedforward inverts the flexure's dynamics, ``feedforward_inverts_mode``).

    Returns (axis → PIDGains, report, warnings); report = {"pid": spec name, "targets", "axes": {axis:
    {gains, "damping", "plant", "margins", "failures"}}}. Raises ControlRefused naming ``field``:
    "auto" without a plant; "paper" unless ``force`` (its predicted margins in the reason); any gain
    set predicted unstable unless ``force`` (the failing margin in the reason). A stable set that
    misses a target only warns."""
    name = spec if isinstance(spec, str) else "custom"
    gains, report, warnings, refusals = {}, {"pid": name, "targets": targets.as_dict(), "axes": {}}, [], []
    for axis, plant in plants.items():
        if name == "auto":
            gains[axis] = _auto_gains(axis, plant, targets, frequency_hz, axis in damped_axes, field)
        else:
            gains[axis] = pid_gains(presets[name][axis] if name in presets else spec[axis])
        report["axes"][axis], said, refused = _judge_axis(axis, gains[axis], plant, targets, name)
        warnings += said
        refusals += refused
    if name == "paper" and not force and not refusals:
        refusals.append("the paper's gains cannot be judged without a feedforward model per axis")
    if refusals and not force:
        _refuse(name, refusals, field)
    warnings.extend(refusals)
    return gains, report, warnings
