"""Dynamics: a flexure resonance after the hysteresis — every column passes through
ωn²/(s² + 2ζωn s + ωn²) (unit DC gain, bilinear with prewarping at fn). fn (Hz) and ζ come
from a grid search refined locally; the weights stay linear."""

from __future__ import annotations

import numpy as np

from drivers.jit import njit
from service.science.data.units import plain
from service.science.effects.base import Effect
from service.science.effects.harmonics import projected_costs
from service.science.effects.rules import growth_words, two_rates
from service.science.fitting.lsq import SMALLEST_NORMAL

#: flexure resonances are lightly damped; a heavily damped 2nd-order lag would only mimic a delay
ZETAS = (0.01, 0.03, 0.1, 0.3)
MAX_ZETA = 0.5
#: the lightest damping a fit may give a mode
MIN_ZETA = 0.003
#: the harmonic search: resonance frequencies per decade and damping ratios of its coarse pass
FN_PER_DECADE = 230  # 1 % steps
COARSE_ZETAS = (0.01, 0.03, 0.1, 0.3)
#: "no mode": where a composite's searches start; filtering with it is the identity (shows_mode)
NO_MODE = {"fn_hz": 1e12, "zeta": 1.0}
#: the searches' grids of fn are spaced up to GRID_SHARE of the sample rate and go on at that spacing
#: up to SEARCH_SHARE, where the clamp puts the highest mode (a 700 Hz mode sampled at 2 kHz was never searched)
GRID_SHARE, SEARCH_SHARE = 0.3, 0.45


def up_to_search_share(grid_hz: np.ndarray, fs_hz: float) -> np.ndarray:
    """A geometric grid of resonance frequencies (Hz) that ends at GRID_SHARE·fs, continued at its own
    ratio up to SEARCH_SHARE·fs."""
    if grid_hz.size < 2:
        return grid_hz
    ratio = grid_hz[-1] / grid_hz[-2]
    more = int(np.floor(np.log(SEARCH_SHARE * fs_hz / grid_hz[-1]) / np.log(ratio) + 1e-9))
    return np.concatenate([grid_hz, grid_hz[-1] * ratio ** np.arange(1, max(more, 0) + 1)])


def shows_mode(fn_hz: float, fs_hz: float) -> bool:
    """Whether a mode at ``fn_hz`` acts on samples taken at ``fs_hz``: below half the sample rate
    (above it the bilinear prewarp's tan is meaningless, and the mode is none)."""
    return fn_hz < 0.5 * fs_hz


@njit(cache=True, nogil=True)
def _biquad_about_first_row(b, a, x, rows, out):
    """Direct form II transposed (as scipy's lfilter) down each column of ``x`` (n, m), about its
    first row, in row order (the columns share each sample's pass through memory), writing only the
    rows ``rows`` (rising, unique) to ``out`` (len(rows), m) and stopping after the last of them."""
    n, m = x.shape
    z1, z2 = np.zeros(m), np.zeros(m)
    r = 0
    for k in range(n):
        if r == rows.size:
            break
        take = rows[r] == k
        for j in range(m):
            xi = x[k, j] - x[0, j]
            y = b[0] * xi + z1[j]
            z1[j] = b[1] * xi - a[1] * y + z2[j]
            z2[j] = b[2] * xi - a[2] * y
            if abs(z1[j]) < SMALLEST_NORMAL:  # a column at rest decays into subnormals: 25x slower
                z1[j] = 0.0  # in this loop and in every Gram and QR of the design
            if abs(z2[j]) < SMALLEST_NORMAL:
                z2[j] = 0.0
            if take:
                out[r, j] = y + x[0, j]
        if take:
            r += 1


def resonance_filter(
    columns: np.ndarray, fs_hz: float, fn_hz: float, zeta: float, rows: np.ndarray | None = None
) -> np.ndarray:
    """Every column (n_samples,) or (n_samples, m) through the resonance, starting at rest at its
    first sample (so a constant column passes unchanged); at ``rows`` only (rising sample indices)
    when given: the filter still runs over every sample up to the last of them, but a fit's design
    needs its training rows alone (a twentieth of a sweep's samples). A mode at or above half the
    sample rate passes every column unchanged (the identity a fit starts from: fn = 1e12 Hz; the
    prewarp's tan there is meaningless and scipy's bilinear then returned one numerator coefficient,
    so the kernel read two more past the array: garbage, now and then huge)."""
    x = np.ascontiguousarray(columns, dtype=float)
    flat = x.reshape(x.shape[0], -1)
    if rows is None:
        at = np.arange(x.shape[0])
    else:
        at = np.asarray(rows, dtype=np.int64)
        if at.size > 1 and np.any(np.diff(at) <= 0):
            raise ValueError("rows must rise strictly")
    if not shows_mode(fn_hz, fs_hz):  # NO_MODE, a composite's identity
        return x[at].copy()
    from scipy.signal import bilinear  # imported when used: scipy.signal costs a service 0.7 s of start-up

    wn = 2.0 * fs_hz * np.tan(np.pi * fn_hz / fs_hz)  # prewarped
    b, a = bilinear([wn * wn], [1.0, 2.0 * zeta * wn, wn * wn], fs_hz)
    if b.size != 3 or a.size != 3:  # scipy drops coefficients it finds negligible; the kernel reads three
        raise ValueError(
            f"resonance at {fn_hz:g} Hz, damping {zeta:g}, has no second-order digital form at "
            f"{fs_hz:g} Hz (coefficients {b}, {a})"
        )
    out = np.empty((at.size, flat.shape[1]))
    _biquad_about_first_row(b / a[0], a / a[0], flat, at, out)
    return out.reshape((at.size,) + x.shape[1:])


def digital_response(frequency_hz: np.ndarray, fs_hz: float, fn_hz: np.ndarray, zeta: np.ndarray) -> np.ndarray:
    """Steady-state response of ``resonance_filter`` at ``frequency_hz`` (broadcast over fn, ζ):
    the bilinear map s = 2·fs·j·tan(πf/fs), with ωn prewarped as in the filter."""
    s = 2j * fs_hz * np.tan(np.pi * frequency_hz / fs_hz)
    wn = 2.0 * fs_hz * np.tan(np.pi * fn_hz / fs_hz)
    return wn * wn / (s * s + 2.0 * zeta * wn * s + wn * wn)


class Dynamics(Effect):
    name = "dynamics"
    stage = "transform"
    signature = (
        "the residual grows steeply with drive frequency (about as f²) and is in phase with "
        "the acceleration of the output: a resonance above the drive band"
    )

    def grid(self, fs_hz, min_period_s, max_frequency_hz):
        lo, hi = 1.5 * max_frequency_hz, GRID_SHARE * fs_hz
        fn = (
            up_to_search_share(np.logspace(np.log10(lo), np.log10(hi), 14), fs_hz)
            if hi > lo
            else np.logspace(np.log10(lo), np.log10(SEARCH_SHARE * fs_hz), 4)
        )
        return [{"fn_hz": float(f), "zeta": z} for f in fn for z in ZETAS]

    def apply(self, columns, fs_hz, theta):
        return resonance_filter(columns, fs_hz, theta["fn_hz"], theta["zeta"])

    def apply_rows(self, columns, fs_hz, theta, rows):
        return resonance_filter(columns, fs_hz, theta["fn_hz"], theta["zeta"], rows)

    def harmonic_search(self, data, fs_hz: float, max_frequency_hz: float) -> dict | None:
        """Best (fn, ζ) against the periodic blocks' harmonics with every weight refitted per
        candidate (variable projection), coarse then fine; None without enough harmonics.
        A lightly damped mode is a narrow valley in fn that a coarse grid would step over."""
        if data.empty or data.frequency_hz.size <= data.a.shape[1] + 2:
            return None
        lo = 1.2 * max_frequency_hz
        if SEARCH_SHARE * fs_hz <= lo:
            return None
        f = data.frequency_hz[None, :]

        def best_of(fn, zeta):
            fn, zeta = np.broadcast_arrays(fn, zeta)
            costs = projected_costs(digital_response(f, fs_hz, fn.ravel()[:, None], zeta.ravel()[:, None]), data)
            i = int(np.argmin(costs))
            return float(fn.ravel()[i]), float(zeta.ravel()[i])

        hi = max(GRID_SHARE * fs_hz, lo * 1.01)
        coarse = up_to_search_share(np.geomspace(lo, hi, int(np.log10(hi / lo) * FN_PER_DECADE) + 2), fs_hz)
        fn0, z0 = best_of(*np.meshgrid(coarse, COARSE_ZETAS))
        fn1, z1 = best_of(
            *np.meshgrid(fn0 * np.linspace(0.97, 1.03, 31), np.geomspace(z0 / 4, min(4 * z0, MAX_ZETA), 25))
        )
        fn2, z2 = best_of(*np.meshgrid(fn1 * np.linspace(0.995, 1.005, 21), z1 * np.geomspace(0.85, 1.0 / 0.85, 15)))
        return {"fn_hz": fn2, "zeta": min(z2, MAX_ZETA)}

    def clamp(self, theta, fs_hz):
        """ζ within [MIN_ZETA, MAX_ZETA], the mode below SEARCH_SHARE·fs (the bilinear map's prewarp)."""
        return {
            "fn_hz": float(np.clip(theta["fn_hz"], 1.0, SEARCH_SHARE * fs_hz)),
            "zeta": float(np.clip(theta["zeta"], MIN_ZETA, MAX_ZETA)),
        }

    def refine(self, theta, cost, fine: bool = False, bracket=None):
        """Coordinate steps in fn and ζ while the exact cost falls (``fine``: only 0.3 % steps,
        after the harmonic search); a 2-D grid has no bracket."""
        best, best_cost = dict(theta), cost(theta)
        for factor in (1.003,) if fine else (1.025, 1.005):
            for _ in range(2):
                improved = False
                steps = (("fn_hz", factor), ("fn_hz", 1 / factor), ("zeta", factor**3), ("zeta", factor**-3))
                for key, mult in steps:
                    trial = dict(best, **{key: best[key] * mult})
                    trial["zeta"] = float(np.clip(trial["zeta"], MIN_ZETA, MAX_ZETA))
                    c = cost(trial)
                    if c < best_cost:
                        best, best_cost, improved = trial, c, True
                if not improved:
                    break
        return best

    def describe(self, theta, values):
        return f"resonance {plain(theta['fn_hz'], 4)} Hz, damping ratio {plain(theta['zeta'])}"

    def parameters(self, theta, values, scales, sign):
        return {"resonance_hz": float(theta["fn_hz"]), "damping_ratio": float(theta["zeta"])}

    units = {"fn_hz": "Hz", "zeta": "1", "resonance_hz": "Hz", "damping_ratio": "1"}
    rule = "at least two drive rates a factor 2 apart: at one rate a resonance is one fixed loop shape"
    inverse = "response"
    emulator_bench = "dynamics"
    separated_from = {
        "rate_dependence": (
            "a higher-frequency sine sweep: a resonance's gain rises as f², rate dependence widens the loop",
            {"waveform": "sine", "rate_multiples": [1.0, 1.5, 2.0], "cycles": 10},
        )
    }

    identity = NO_MODE

    def untestable(self, records):
        return two_rates(self.name, records)

    def response(self, frequency_hz, fs_hz, theta):
        """The mode's digital response (1 where it does not act on samples at ``fs_hz``)."""
        if not shows_mode(theta["fn_hz"], fs_hz):
            return np.ones(np.shape(frequency_hz), dtype=complex)
        return digital_response(np.asarray(frequency_hz), fs_hz, theta["fn_hz"], theta["zeta"])

    def evidence(self, sig, floor):
        return (
            f"{growth_words(sig)}; a resonance above the drive band adds a part that grows as f² (the output's "
            "acceleration), which the held-out test weighs: dynamics"
        )
