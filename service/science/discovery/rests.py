"""The record's rests (the drive still at the level it starts from, 0 V as a sweep is recorded): the
gauge's own noise and any disturbance.

At rest the stage does nothing the model must draw, so what the gauge shows there is the floor any
model is judged against: its own non-repeatable noise plus whatever reaches it from outside. Each
rest stretch is read after ``SETTLE_S`` (ringing and the fastest creep after the drive stopped) with
a cubic in time taken out (the slow creep relaxation, a drift: not noise); a cubic over 0.3 s leaves
0.3 nm of a 0.36 µm relaxation of τ = 0.3 s and takes nothing of a 50 Hz line.

A **line** at rest (the mains at 50/60 Hz and their harmonics, or the strongest peaks of the rests'
spectrum) is a disturbance, not model error: with the drive at 1, 10 and 50 Hz (submultiples of the
mains) it repeats cycle to cycle and a model reads it as loop shape. A line counts when it passes the
held-out discipline of the claims: every rest stretch is cut in halves, the line (amplitude and phase
per record, its frequency refined on the rests' phase across the record) is fitted on the first halves
and scored on the second, and back; its gain over the gauge noise (z, as the description of what
remains scores a signature) must pass a one-sided threshold corrected (Bonferroni) for every frequency
looked at. A counted line is removed from the whole record (it runs on through blocks and rests) before
the model is judged. Units: µm in, nm in the texts, s, Hz. Pure numpy: no store, no HTTP.
"""

from __future__ import annotations

from dataclasses import dataclass
from statistics import NormalDist

import numpy as np

from service.science.data.steps import held_still
from service.science.data.units import fmt_nm
from service.science.discovery.signature_dictionary import MAINS_LINES_HZ, pool, pool_factor

#: a rest: the drive within this share of its span of the level it starts from, and still
REST_LEVEL_SHARE = 0.01
#: read a rest only after the drive has been still this long (s)
SETTLE_S = 0.05
#: a rest stretch shorter than this after settling is not read (s); a longer one than twice CHUNK_S is
#: read in pieces of about CHUNK_S, each with its own cubic (the emulator's creep over a 3.3 s rest left
#: 7.5 nm of a single cubic's fit against 3.0 nm of gauge noise)
MIN_STRETCH_S = 0.1
CHUNK_S = 0.3
#: the rests must hold at least this many seconds in all for a noise floor of their own
MIN_REST_S = 0.2
#: order of the polynomial in time taken out of each rest stretch
DETREND_ORDER = 3
#: family-wise false-line rate over every frequency looked at
FAMILY_ALPHA = 0.01
#: lines below this frequency are slow trends, which a stretch's cubic follows (Hz)
MIN_LINE_HZ = 10.0
#: strongest peaks of the rests' spectrum tried beside the mains
PEAKS = 3
#: phase-refinement grid: steps per 1/(time span of the rests)
REFINE_STEPS = 8


def still_mask(rec) -> np.ndarray:
    """Rows where ``rec``'s drive is held still (service.science.data.steps.held_still: the description of
    what remains and the failures read rests and holds alike). (A rate under 1 % of the record's
    95th-percentile rate took the whole 1 Hz burst of a 1…100 Hz sweep for a hold: 2π·1 Hz is under
    1 % of 2π·100 Hz.)"""
    return held_still(rec.u_v, rec.sample_rate_hz)


def at_rest_level(rec) -> np.ndarray:
    """Rows where ``rec``'s drive is within REST_LEVEL_SHARE of its span of the level it starts from (a
    record starts from a relaxed state: 0 V as a sweep is recorded, or wherever another lab's amplifier
    input or units put it, so that the diagnosis does not depend on the drive's origin or units)."""
    return np.abs(rec.u_v - rec.u_v[0]) <= REST_LEVEL_SHARE * max(float(np.ptp(rec.u_v)), 1e-12)


def rest_stretches(rec) -> list[tuple[int, int]]:
    """(start, stop) sample ranges where ``rec``'s drive rests (at the level it starts from), settled, each ≥ MIN_STRETCH_S."""
    rest = still_mask(rec) & at_rest_level(rec)
    if rec.u_other_v is not None:  # the whole stage at rest: the other axis's motion couples into this gauge
        u = rec.u_other_v
        rest &= np.abs(u - u[0]) <= REST_LEVEL_SHARE * max(float(np.ptp(u)), 1e-12)
        rest &= held_still(u, rec.sample_rate_hz)
    edges = np.flatnonzero(np.diff(np.concatenate([[0], rest.astype(np.int8), [0]])))
    settle, shortest = int(SETTLE_S * rec.sample_rate_hz), int(MIN_STRETCH_S * rec.sample_rate_hz)
    out = []
    chunk = int(CHUNK_S * rec.sample_rate_hz)
    for a, b in zip(edges[::2], edges[1::2]):
        a = a + (settle if a > 0 else 0)  # a record that starts at rest has nothing to settle from
        pieces = max(1, (b - a) // chunk)  # a long rest in pieces: a cubic follows creep over CHUNK_S, not 3 s
        for lo, hi in zip(np.linspace(a, b, pieces + 1)[:-1], np.linspace(a, b, pieces + 1)[1:]):
            if hi - lo >= shortest:
                out.append((int(lo), int(hi)))
    return out


def _projector(n: int):
    """Removes a polynomial of DETREND_ORDER in time from columns of ``n`` rows."""
    s = np.linspace(-1.0, 1.0, n)
    q = np.linalg.qr(np.polynomial.legendre.legvander(s, DETREND_ORDER))[0]
    return lambda v: v - q @ (q.T @ v)


class _Rests:
    """One record's pooled rest rows: time (s), detrended reading (µm), stretch halves (fold 0/1)."""

    def __init__(self, rec, q: int):
        self.t, self.y, self.fold, self.parts = [], [], [], []
        for a, b in rest_stretches(rec):
            x = pool(rec.x_um[a:b], q)
            t = pool(np.arange(a, b) / rec.sample_rate_hz, q)
            detrend = _projector(x.size)
            self.parts.append((len(self.y) and sum(v.size for v in self.y), x.size, detrend))
            self.t.append(t)
            self.y.append(detrend(x))
            self.fold.append((np.arange(x.size) >= x.size // 2).astype(int))
        self.rows = sum(v.size for v in self.y)
        if self.rows:
            self.t, self.y, self.fold = (np.concatenate(v) for v in (self.t, self.y, self.fold))

    def columns(self, f_hz: float) -> np.ndarray:
        """sin and cos of the line at ``f_hz``, each stretch's polynomial taken out as from the reading."""
        phase = 2 * np.pi * f_hz * self.t
        cols = np.column_stack([np.sin(phase), np.cos(phase)])
        for at, n, detrend in self.parts:
            cols[at : at + n] = detrend(cols[at : at + n])
        return cols


def _coherent_power(rests: list[_Rests], f_hz: float) -> float:
    return sum(abs(np.dot(r.y, np.exp(-2j * np.pi * f_hz * r.t))) ** 2 for r in rests if r.rows)


#: the grid's phasors are stepped by a complex multiply and taken afresh from exp() every this many points
#: (the products' rounding stays near 1e-14 of the power)
PHASOR_RESTART = 64


def _grid_power(rests: list[_Rests], start_hz: float, step_hz: float, count: int) -> np.ndarray:
    """``_coherent_power`` at ``count`` frequencies ``start_hz + k·step_hz``: each frequency's phasors are
    the last one's times the step's (a complex multiply per row, not an exponential: the refinement
    grid of a peak has ~1600 points, and this was a tenth of a diagnosis's time)."""
    power = np.zeros(count)
    for r in (r for r in rests if r.rows):
        turn, phasor = np.exp(-2j * np.pi * step_hz * r.t), None
        for k in range(count):
            if k % PHASOR_RESTART == 0:
                phasor = np.exp(-2j * np.pi * (start_hz + k * step_hz) * r.t)
            else:
                phasor = phasor * turn
            power[k] += abs(np.dot(r.y, phasor)) ** 2
    return power


def _refined_hz(rests: list[_Rests], f_hz: float, half_width_hz: float) -> float:
    """The frequency within ±``half_width_hz`` where the rests' phase-coherent power is largest: a grid
    of REFINE_STEPS per 1/(their time span), then the best point's neighbours halved twice."""
    span = max(float(r.t[-1] - r.t[0]) for r in rests if r.rows) or 1.0
    step = 1.0 / (REFINE_STEPS * span)
    count = int(np.floor((2 * half_width_hz + step / 2) / step)) + 1
    best = f_hz - half_width_hz + step * int(np.argmax(_grid_power(rests, f_hz - half_width_hz, step, count)))
    for _ in range(3):
        step /= 2
        best = max((best - step, best, best + step), key=lambda f: _coherent_power(rests, f))
    return best


def _peaks_hz(rests: list[_Rests], top_hz: float, rate_hz: float) -> tuple[list[float], int]:
    """The PEAKS strongest local maxima of the rests' power (each stretch's own Hann-windowed spectrum,
    zero-padded to one length and summed: a line need not keep its phase to be seen) between
    MIN_LINE_HZ and ``top_hz``, away from the mains; and how many frequencies were looked at.
    ``rate_hz``: the pooled rows' rate."""
    longest = max(n for r in rests for _, n, _ in r.parts)
    size = 1 << int(np.ceil(np.log2(2 * longest)))
    freqs = np.fft.rfftfreq(size, 1.0 / rate_hz)
    power = np.zeros(freqs.size)
    for r in rests:
        for at, n, _ in r.parts:
            power += np.abs(np.fft.rfft(r.y[at : at + n] * np.hanning(n), size)) ** 2
    band = np.flatnonzero((freqs >= MIN_LINE_HZ) & (freqs < top_hz))
    local = [
        k
        for k in band[1:-1]
        if power[k] >= power[k - 1]
        and power[k] >= power[k + 1]
        and all(abs(freqs[k] - m) > 2.0 for m in MAINS_LINES_HZ)
    ]
    local.sort(key=lambda k: -power[k])
    return [float(freqs[k]) for k in local[:PEAKS]], int(band.size)


def _bin_hz(rests: list[_Rests], records, q: int) -> float:
    """The spectral resolution of the shortest rest stretch (Hz): where a peak's line may lie."""
    shortest = min(n for r in rests for _, n, _ in r.parts)
    return min(rec.sample_rate_hz for rec in records) / q / shortest


def _fit(rests: list[_Rests], f_hz: float, rows_of) -> list[np.ndarray]:
    """Per record, the line's (sin, cos) coefficients (µm) fitted on the rows ``rows_of(r)`` selects."""
    out = []
    for r in rests:
        if not r.rows:
            out.append(np.zeros(2))
            continue
        m, cols = rows_of(r), r.columns(f_hz)
        out.append(np.linalg.lstsq(cols[m], r.y[m], rcond=1e-6)[0] if m.sum() > 4 else np.zeros(2))
    return out


def _held_out_z(rests: list[_Rests], f_hz: float) -> float:
    """The line's held-out gain over white noise: fitted on one half of every stretch, scored on the
    other, and back; z = Σ(y² − e²) / (2σ·√Σ(y − e)²), σ the RMS of what the line leaves (as
    remainder._gain_t scores a signature)."""
    before, after = [], []
    for k in (0, 1):
        coefs = _fit(rests, f_hz, lambda r, k=k: r.fold != k)
        for r, c in zip(rests, coefs):
            if r.rows:
                m = r.fold == k
                before.append(r.y[m])
                after.append(r.y[m] - r.columns(f_hz)[m] @ c)
    y, e = np.concatenate(before), np.concatenate(after)
    sigma = float(np.sqrt(np.mean(e**2)))
    spread = 2.0 * sigma * np.sqrt(np.sum((y - e) ** 2))
    return float(np.sum(y**2 - e**2) / spread) if spread > 0 else 0.0


def _lines_at(columns, lines: list[dict], k: int) -> np.ndarray | float:
    """The sum of ``lines`` (record ``k``'s coefficients) on the rows ``columns(f_hz)`` gives (µm)."""
    return sum((columns(line["frequency_hz"]) @ line["coefficients"][k] for line in lines), 0.0)


def _pooled_gain(f_hz: float, q: int, sample_rate_hz: float) -> float:
    """The amplitude a line keeps in means of ``q`` consecutive samples."""
    x = np.pi * f_hz / sample_rate_hz
    return float(np.sin(q * x) / (q * np.sin(x))) if q > 1 else 1.0


def remove_lines(records, rests: dict | None) -> list:
    """``records`` with the disturbance's lines (fitted on the rests) taken out of every sample's reading:
    the same records when there are none."""
    records = list(records)
    if not rests or not rests["lines"]:
        return records
    out = []
    for k, rec in enumerate(records):
        t = np.arange(rec.n_samples) / rec.sample_rate_hz

        def columns(f_hz, t=t):
            return np.column_stack([np.sin(2 * np.pi * f_hz * t), np.cos(2 * np.pi * f_hz * t)])

        out.append(rec.with_x(rec.x_um - _lines_at(columns, rests["lines"], k)))
    return out


@dataclass(frozen=True)
class LineFree:
    """Records with the rests' lines taken out (``records``) and what the rests showed (``rests``,
    ``read_rests``'s answer): what every fit, held-out figure and diagnosis of them judges the model
    on. Its owner (the discover loop, a diagnosis) makes it once per list of records, so that the
    fits that follow get the same record objects and share their columns."""

    records: list
    rests: dict | None

    @classmethod
    def of(cls, records) -> LineFree:
        """``records`` read at rest, their lines taken out."""
        rests = read_rests(records)
        return cls(remove_lines(records, rests), rests)

    @property
    def had_lines(self) -> bool:
        """Whether lines were taken out (else ``records`` are the records as recorded)."""
        return bool(self.rests and self.rests["lines"])


def _line_text(line: dict) -> str:
    source = (
        "mains pickup on the gauge or the amplifier (shield or filter it)"
        if line["mains"]
        else "a disturbance from the surroundings (a machine, a fan) or a mode it excites"
    )
    return (
        f"a {line['frequency_hz']:.4g} Hz line of {fmt_nm(line['amplitude_um'])} is on the gauge at rest: "
        f"a disturbance, not the model — {source}"
    )


def read_rests(records) -> dict | None:
    """What the rests of ``records`` show, None if they hold under MIN_REST_S: ``seconds``, ``rms_um``
    (the detrended reading at rest: noise and disturbance), ``noise_um`` (what the lines leave),
    ``lines`` [{frequency_hz, amplitude_um (RMS over records of each one's amplitude), mains, z,
    coefficients (per record, sin and cos, µm), text}], ``threshold_z``, ``tried`` (frequencies)."""
    records = list(records)
    q = pool_factor(records)
    rests = [_Rests(r, q) for r in records]
    rows = sum(r.rows for r in rests)
    seconds = sum(r.rows * q / rec.sample_rate_hz for r, rec in zip(rests, records))
    if seconds < MIN_REST_S or rows < 50:
        return None
    top_hz = min(rec.sample_rate_hz / q for rec in records) / 2.5
    mains = [f for f in sorted({m * k for m in (50.0, 60.0) for k in range(1, 6)}) if f < top_hz]
    peaks, looked = _peaks_hz(rests, top_hz, min(rec.sample_rate_hz for rec in records) / q)
    threshold = NormalDist().inv_cdf(1 - FAMILY_ALPHA / (looked + len(mains)))
    lines = []
    for f0, is_mains in [(f, True) for f in mains] + [(f, False) for f in peaks]:
        f = _refined_hz(rests, f0, 0.3 if is_mains else _bin_hz(rests, records, q))
        if any(abs(f - line["frequency_hz"]) < 1.0 for line in lines):
            continue
        z = _held_out_z(rests, f)
        if z > threshold:
            coefs = _fit(rests, f, lambda r: np.ones(r.rows, dtype=bool))
            amp = float(np.sqrt(np.mean([np.sum(c**2) for c, r in zip(coefs, rests) if r.rows])))
            line = {"frequency_hz": f, "amplitude_um": amp, "mains": is_mains, "z": z, "coefficients": coefs}
            lines.append({**line, "text": _line_text(line)})
    y = np.concatenate([r.y for r in rests if r.rows])
    left = [r.y - _lines_at(r.columns, lines, k) for k, r in enumerate(rests) if r.rows]
    dof = max(rows - sum(len(r.parts) for r in rests) * (DETREND_ORDER + 1), 1)
    for line in lines:  # the pooled rows' means attenuate a line: its amplitude at the samples
        gain = _pooled_gain(line["frequency_hz"], q, min(rec.sample_rate_hz for rec in records))
        line["coefficients"] = [c / gain for c in line["coefficients"]]
        line["amplitude_um"] /= gain
        line["text"] = _line_text(line)
    return {
        "seconds": float(seconds),
        "rms_um": float(np.sqrt(np.sum(y**2) / dof) * np.sqrt(q)),
        "noise_um": _stretch_median_noise(left, [r for r in rests if r.rows], q),
        "lines": sorted(lines, key=lambda li: -li["amplitude_um"]),
        "threshold_z": float(threshold),
        "tried": mains + peaks,
    }


def _stretch_median_noise(left: list[np.ndarray], rests: list[_Rests], q: int) -> float:
    """The gauge noise (µm) at rest: the median over rest stretches (weighted by their degrees of
    freedom) of each one's mean square after its cubic and the lines, per sample (× the pooling ``q``).
    The gauge's noise is the same in every stretch; a stretch that still moves (a stage ringing or
    relaxing in a way no cubic draws after a sweep before it) only adds, and a pooled figure moved with
    it: a discover's experiment record began with 14 nm at rest beside 2.8–3.1 nm in five other
    stretches, and the floor of every later step read 8.33 nm, then 7.06 nm, against 3.15 nm before."""
    variances, weights = [], []
    for y, r in zip(left, rests):
        for at, n, _ in r.parts:
            free = n - (DETREND_ORDER + 1)
            if free > 0:
                variances.append(float(np.sum(y[at : at + n] ** 2)) / free)
                weights.append(free)
    order = np.argsort(variances)
    cumulative = np.cumsum(np.asarray(weights, dtype=float)[order])
    middle = order[int(np.searchsorted(cumulative, 0.5 * cumulative[-1]))]
    return float(np.sqrt(variances[middle] * q))


def disturbance(rests: dict | None) -> dict | None:
    """The disturbance the rests show, for the diagnosis (None without lines): its lines (frequency Hz,
    amplitude µm, mains or not, z, sentence), the rests read (s), the RMS at rest over every rest with
    the lines and the noise floor (the median rest stretch without them, µm: two measures, named as
    such, so that a stretch still ringing after a sweep reads as what it is), and a sentence."""
    if not rests or not rests["lines"]:
        return None
    lines = [{k: v for k, v in line.items() if k != "coefficients"} for line in rests["lines"]]
    named = " and ".join(f"a {li['frequency_hz']:.4g} Hz line of {fmt_nm(li['amplitude_um'])}" for li in lines)
    return {
        "lines": lines,
        "rest_seconds": rests["seconds"],
        "rest_rms_um": rests["rms_um"],
        "rest_noise_um": rests["noise_um"],
        "removed": True,
        "text": (
            f"{named} {'are' if len(lines) > 1 else 'is'} on the gauge at rest ({rests['seconds']:.3g} s of rests: "
            f"{fmt_nm(rests['rms_um'])} RMS over them all, {fmt_nm(rests['noise_um'])} in the median rest without "
            f"{'them' if len(lines) > 1 else 'it'}, the noise floor)"
            f": a disturbance, not the model — "
            + (
                "mains pickup on the gauge or the amplifier"
                if any(li["mains"] for li in lines)
                else "from the surroundings"
            )
            + "; fitted on the rests and taken out of the whole record before the model was judged, so no "
            "loop-shape effect is claimed for it"
        ),
    }
