"""Hysteresis stages built without the product's code (issue 37), recorded as labs record them.

Materials (every one rate-independent, in µm for a drive in V):
- ``bouc_wen_um``: x = d·u − H·z, dz/du = (A − (β·sgn(u̇)·|z|^(n−1)·z + γ·|z|^n)) / U, integrated
  along the drive by RK4 sub-steps (β < γ, β = γ, β > γ and n ≠ 1 draw loops whose reversal curves
  are not the initial loading curve scaled by two: no Masing rule);
- ``preisach_um``: a Preisach plane with a correlated bivariate Gaussian density in (centre, half
  width) of the relays, evaluated exactly through its Everett function and the wiping-out memory of
  alternating extrema (congruency holds, Masing does not);
- ``maxwell_slip_um``: elasto-slip elements (a sum of stop operators: a family a PI can draw);
- Jiles–Atherton, Coleman–Hodgdon and Krasnosel'skii–Pokrovskii materials (tests.support.hysteresis_families).

Recording: 20 kHz, gauge noise (default 2 nm); either one record per block ("one CSV per block",
each from rest at 0 V) or one long record with rests between the blocks. Blocks: 1/10/50/100 Hz
sines of 5 cycles, biased (0…u_max) or bipolar (±u_max), and a step-hold.
The block tables are cut by the product's importer (service.science.data.segmentation), as an
imported CSV's are; nothing else of the product is used here.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from tests.support.hysteresis_families import (
    coleman_hodgdon_um,
    jiles_atherton_um,
    krasnoselskii_pokrovskii_um,
)

SAMPLE_RATE_HZ = 20000.0
FREQUENCIES_HZ = (1.0, 10.0, 50.0, 100.0)
REST_S = 0.2


# -- drives ---------------------------------------------------------------------------------------
def sine_block_v(f_hz: float, cycles: int = 5, u_max_v: float = 120.0, bipolar: bool = False, fs=SAMPLE_RATE_HZ):
    """Whole cycles of a sine from rest (V): 0…u_max (biased: u_max/2·(1 − cos)) or ±u_max (sin)."""
    t = np.arange(int(round(cycles / f_hz * fs)) + 1) / fs
    if bipolar:
        return u_max_v * np.sin(2 * np.pi * f_hz * t)
    return 0.5 * u_max_v * (1.0 - np.cos(2 * np.pi * f_hz * t))


def step_hold_v(u_max_v: float = 120.0, bipolar: bool = False, hold_s: float = 0.5, fs=SAMPLE_RATE_HZ):
    """Steps between levels (shares of the range), each held ``hold_s`` (V)."""
    shares = (0.8, 0.2, 1.0, 0.4, 0.7, 0.0)
    lo = -u_max_v if bipolar else 0.0
    levels = [lo + s * (u_max_v - lo) for s in shares]
    return np.concatenate([np.full(int(hold_s * fs), v) for v in levels])


def blocks_v(
    u_max_v: float = 120.0, bipolar: bool = False, frequencies_hz=FREQUENCIES_HZ, cycles: int = 5, fs=SAMPLE_RATE_HZ
):
    """Each block's drive (V), each from rest at 0 V and ending at rest: the sines, then a step-hold."""
    rest = np.zeros(int(REST_S * fs))
    out = [np.concatenate([rest, sine_block_v(f, cycles, u_max_v, bipolar, fs), rest]) for f in frequencies_hz]
    return out + [np.concatenate([rest, step_hold_v(u_max_v, bipolar, fs=fs), rest])]


# -- materials ------------------------------------------------------------------------------------
@njit(cache=True)
def _bouc_wen_z(u, a, beta, gamma, n, scale_v, substep_v):
    z = np.zeros(u.size)
    s = 0.0
    for i in range(1, u.size):
        du = u[i] - u[i - 1]
        if du == 0.0:
            z[i] = s
            continue
        sign = 1.0 if du > 0 else -1.0
        k = int(abs(du) / substep_v) + 1
        h = du / k
        for _ in range(k):
            k1 = (a - beta * sign * abs(s) ** (n - 1) * s - gamma * abs(s) ** n) / scale_v
            s2 = s + 0.5 * h * k1
            k2 = (a - beta * sign * abs(s2) ** (n - 1) * s2 - gamma * abs(s2) ** n) / scale_v
            s3 = s + 0.5 * h * k2
            k3 = (a - beta * sign * abs(s3) ** (n - 1) * s3 - gamma * abs(s3) ** n) / scale_v
            s4 = s + h * k3
            k4 = (a - beta * sign * abs(s4) ** (n - 1) * s4 - gamma * abs(s4) ** n) / scale_v
            s += h * (k1 + 2 * k2 + 2 * k3 + k4) / 6.0
        z[i] = s
    return z


def bouc_wen_um(u_v, beta=0.5, gamma=0.5, n=1.0, a=1.0, scale_v=25.0, d_um_per_v=0.1, h_um=1.5):
    """Bouc–Wen stack x = d·u − H·z (µm), z dimensionless with dz/du as in the module docstring;
    ``scale_v`` the drive travel (V) over which z approaches its bound."""
    u = np.ascontiguousarray(u_v, dtype=float)
    z = _bouc_wen_z(u, float(a), float(beta), float(gamma), float(n), float(scale_v), 0.05)
    return d_um_per_v * u - h_um * z


def everett_table(lo_v, hi_v, centre_v, half_width_v, sd_centre_v, sd_half_v, rho, grid=400):
    """(nodes V, F) of a Preisach density ∝ a bivariate Gaussian in (c = (α+β)/2, r = (α−β)/2)
    with correlation ``rho``, on α ≥ β in [lo, hi]: F[i, j] = mass of relays β_j ≤ β ≤ α ≤ α_i,
    normalised to a total of 1."""
    nodes = np.linspace(lo_v, hi_v, grid)
    mid = 0.5 * (nodes[1:] + nodes[:-1])
    alpha, beta = np.meshgrid(mid, mid, indexing="ij")
    c = (0.5 * (alpha + beta) - centre_v) / sd_centre_v
    r = (0.5 * (alpha - beta) - half_width_v) / sd_half_v
    dens = np.exp(-0.5 * (c * c - 2 * rho * c * r + r * r) / (1 - rho * rho)) * (alpha >= beta)
    dens /= dens.sum()
    # F over cells with alpha index < i and beta index ≥ j (node i is the cells' upper edge)
    cum = np.cumsum(np.cumsum(dens[:, ::-1], axis=1)[:, ::-1], axis=0)
    table = np.zeros((grid, grid))
    table[1:, : grid - 1] = cum
    return nodes, table


@njit(cache=True)
def _everett(nodes, table, a, b):
    """F(a, b) by bilinear interpolation on the table (a = α upper limit, b = β lower limit)."""
    lo, step, g = nodes[0], nodes[1] - nodes[0], nodes.size
    x = min(max((a - lo) / step, 0.0), g - 1.000001)
    y = min(max((b - lo) / step, 0.0), g - 1.000001)
    i, j = int(x), int(y)
    fx, fy = x - i, y - j
    return (
        table[i, j] * (1 - fx) * (1 - fy)
        + table[i + 1, j] * fx * (1 - fy)
        + table[i, j + 1] * (1 - fx) * fy
        + table[i + 1, j + 1] * fx * fy
    )


@njit(cache=True)
def _preisach(u, nodes, table):
    lo, hi = nodes[0], nodes[-1]
    stack = np.empty(u.size + 2)
    stack[0] = lo  # negative saturation: the first point is a minimum
    top = 1
    out = np.empty(u.size)
    total = _everett(nodes, table, hi, lo)
    prev = min(max(u[0], lo), hi)
    for t in range(u.size):
        v = min(max(u[t], lo), hi)
        rising = top % 2 == 1  # the last stored point is a minimum
        if (rising and v < prev) or (not rising and v > prev):
            stack[top] = prev
            top += 1
            rising = not rising
        while top >= 3 and ((rising and v >= stack[top - 2]) or (not rising and v <= stack[top - 2])):
            top -= 2
        if top == 1 and not rising:  # cannot happen: a minimum at the bottom
            rising = True
        f = -total
        for i in range(1, top + 1, 2):
            m_at = stack[i] if i < top else v
            f += 2 * _everett(nodes, table, m_at, stack[i - 1])
            if i + 1 < top:
                f -= 2 * _everett(nodes, table, m_at, stack[i + 1])
            elif i + 1 == top:
                f -= 2 * _everett(nodes, table, m_at, v)
        out[t] = f
        prev = v
    return out


def preisach_um(u_v, lo_v=-10.0, hi_v=130.0, rho=0.6, d_um_per_v=0.07, h_um=2.5, **density):
    """A Preisach stack x = d·u + H·(f + 1)/2 (µm), f ∈ [−1, 1] the relays' mean output for a
    correlated Gaussian density (``density``: centre_v, half_width_v, sd_centre_v, sd_half_v)."""
    span = hi_v - lo_v
    dens = {
        "centre_v": lo_v + 0.55 * span,
        "half_width_v": 0.08 * span,
        "sd_centre_v": 0.3 * span,
        "sd_half_v": 0.08 * span,
        **density,
    }
    nodes, table = everett_table(lo_v, hi_v, rho=rho, **dens)
    f = _preisach(np.ascontiguousarray(u_v, dtype=float), nodes, table)
    return d_um_per_v * np.asarray(u_v) + h_um * 0.5 * (f + 1.0)


@njit(cache=True)
def _stops(u, widths):
    out = np.zeros((u.size, widths.size))
    s = np.zeros(widths.size)
    for t in range(u.size):
        for k in range(widths.size):
            s[k] = min(max(s[k] + (u[t] - (u[t - 1] if t else 0.0)), -widths[k]), widths[k])
            out[t, k] = s[k]
    return out


def maxwell_slip_um(u_v, widths_v=(3.0, 9.0, 17.0, 28.0, 44.0), stiffness_um_per_v=(0.02, 0.015, 0.01, 0.008, 0.006)):
    """Elasto-slip elements (each element's slip bounded by ±width, V) against the stack's free
    stroke: x = 0.1·u − Σ k_i·slip_i(u) (µm), so that the displacement lags the drive."""
    stops = _stops(np.ascontiguousarray(u_v, dtype=float), np.asarray(widths_v, dtype=float))
    return 0.1 * np.asarray(u_v) - stops @ np.asarray(stiffness_um_per_v)


#: the families of issue 37's matrix: name -> material (u_v, bipolar -> x_um); a bipolar drive
#: spans twice the range, so the material's voltage scales double with it
WORLDS = {
    "bw_beta_lt_gamma": lambda u, bp: bouc_wen_um(u, beta=0.25, gamma=0.75, scale_v=50.0 if bp else 25.0),
    "bw_beta_eq_gamma": lambda u, bp: bouc_wen_um(u, beta=0.5, gamma=0.5, scale_v=50.0 if bp else 25.0),
    "bw_beta_gt_gamma": lambda u, bp: bouc_wen_um(u, beta=0.75, gamma=0.25, scale_v=50.0 if bp else 25.0),
    "bw_n2": lambda u, bp: bouc_wen_um(u, beta=0.6, gamma=0.4, n=2.0, scale_v=50.0 if bp else 25.0),
    "preisach_gauss": lambda u, bp: preisach_um(u, lo_v=-130.0 if bp else -10.0),
    "maxwell_slip": lambda u, bp: maxwell_slip_um(u, widths_v=tuple(w * (2 if bp else 1) for w in (3, 9, 17, 28, 44))),
    "jiles_atherton": lambda u, bp: jiles_atherton_um(u, scale_v=80.0 if bp else 40.0),
    "coleman_hodgdon": lambda u, bp: coleman_hodgdon_um(u),
    "krasnoselskii_pokrovskii": lambda u, bp: krasnoselskii_pokrovskii_um(u, lo_v=-140.0 if bp else -20.0),
    # a Duhem stack with a wide loop (±1.5 µm on a 7.2 µm line over 120 V) and a flat anhysteretic
    # curve: the rate-independent stage a new user's walk wrote (x = 0.06·u + h, dh = 0.03·du − 0.02·|du|·h)
    "duhem_wide": lambda u, bp: (
        0.06 * np.asarray(u, dtype=float)
        + coleman_hodgdon_um(u, alpha_per_v=0.01 if bp else 0.02, a_um_per_v=0.0, b_um_per_v=0.03)
    ),
}


# -- recording ------------------------------------------------------------------------------------
#: the amplifier of the "slew" stage: 40 mA into a 1.8 µF stack moves it at most I/C (V/s)
SLEW_V_PER_S = 0.04 / 1.8e-6
#: the "hum" stage's lines on the gauge: (frequency Hz, amplitude µm, phase rad), t from each record's start
HUM_LINES = ((50.0, 0.012, 0.4), (150.0, 0.004, 1.1))
#: the "gainfade" stage's gain: falls this share per second from each record's start
GAIN_FADE_PER_S = 0.001
#: the effects ``hidden`` may name
HIDDEN = ("creep", "delay", "slew", "hum", "gainfade")


@njit(cache=True)
def _slewed(u, step_v):
    out = np.empty(u.size)
    y = u[0]
    for k in range(u.size):
        y += min(max(u[k] - y, -step_v), step_v)
        out[k] = y
    return out


def stage_drive_v(effect: str | None, u_v: np.ndarray, fs: float) -> np.ndarray:
    """The drive the stack sees: the plan, or ("slew") the plan through an amplifier whose output moves at
    most SLEW_V_PER_S (its current limit into the stack's capacitance)."""
    if effect == "slew":
        return _slewed(np.ascontiguousarray(u_v, dtype=float), SLEW_V_PER_S / fs)
    return u_v


def hidden_um(effect: str | None, u_v: np.ndarray, x_um: np.ndarray, fs: float) -> np.ndarray:
    """The stage's output with one physical effect behind (or beside) the material: "creep" (the drive
    through first-order lags of 0.3 and 3 s, 0.003 µm/V each), "delay" (0.3 ms, linear interpolation),
    "hum" (HUM_LINES on the gauge), "gainfade" (the gain falls GAIN_FADE_PER_S); "slew" acts on the
    drive (``stage_drive_v``), not here."""
    if effect is None or effect == "slew":
        return x_um
    t = np.arange(x_um.size) / fs
    if effect == "hum":
        return x_um + sum(a * np.sin(2 * np.pi * f * t + p) for f, a, p in HUM_LINES)
    if effect == "gainfade":
        return x_um * (1.0 - GAIN_FADE_PER_S * t)
    if effect == "creep":
        from scipy import signal

        for tau_s in (0.3, 3.0):
            pole = np.exp(-1.0 / (fs * tau_s))
            x_um = x_um + 0.003 * signal.lfilter([1 - pole], [1, -pole], u_v)
        return x_um
    if effect == "delay":
        t = np.arange(x_um.size) / fs
        return np.interp(t - 3e-4, t, x_um)
    raise ValueError(effect)


def material_blocks(world, u_max_v=120.0, bipolar=False, fs=SAMPLE_RATE_HZ, hidden=None):
    """[(u_v, x_um)] the material's own output per block (no gauge effect, no noise), each block from
    rest at 0 V and from the material's virgin state, as the "one CSV per block" form records them."""
    material = WORLDS[world]
    return [(u, material(stage_drive_v(hidden, u, fs), bipolar)) for u in blocks_v(u_max_v, bipolar, fs=fs)]


def record_blocks(
    world, noise_um=0.002, seed=0, u_max_v=120.0, bipolar=False, fs=SAMPLE_RATE_HZ, hidden=None, stroke_scale=1.0
):
    """[(u_v, x_um)] one per block, each from rest (the "one CSV per block" form); ``stroke_scale``
    multiplies the stage's motion (a smaller or larger stage behind the same gauge noise)."""
    rng = np.random.default_rng(seed)
    return [
        (u, stroke_scale * hidden_um(hidden, u, x, fs) + rng.normal(0.0, noise_um, u.size))
        for u, x in material_blocks(world, u_max_v, bipolar, fs, hidden)
    ]


def record_long(
    world, noise_um=0.002, seed=0, u_max_v=120.0, bipolar=False, fs=SAMPLE_RATE_HZ, hidden=None, stroke_scale=1.0
):
    """(u_v, x_um) of every block one after the other, with their rests, in one record
    (``stroke_scale`` as in ``record_blocks``)."""
    u = np.concatenate(blocks_v(u_max_v, bipolar, fs=fs))
    x = stroke_scale * hidden_um(hidden, u, WORLDS[world](stage_drive_v(hidden, u, fs), bipolar), fs)
    return u, x + np.random.default_rng(seed).normal(0.0, noise_um, u.size)


def record_cut(world, noise_um=0.002, seed=0, u_max_v=120.0, bipolar=False, fs=SAMPLE_RATE_HZ, **effect):
    """[(u_v, x_um)] the long record cut into one file per block, as a lab saves a session block by
    block: each file holds its block with the rests either side, starts where the last one ended
    (the stage's state carried over: the remnant displacement at 0 V, the memory of the last block's
    extremes), and its own t = 0; ``effect``: hidden and stroke_scale, as in ``record_long``."""
    u, x = record_long(world, noise_um, seed, u_max_v, bipolar, fs, **effect)
    bounds = np.cumsum([0] + [b.size for b in blocks_v(u_max_v, bipolar, fs=fs)])
    return [(u[a:b], x[a:b]) for a, b in zip(bounds, bounds[1:])]


#: the record forms: one file per block from the virgin state, one long record, the long record cut
FORMS = {"blocks": record_blocks, "long": lambda *a, **k: [record_long(*a, **k)], "cut": record_cut}


def records(world: str, form: str = "blocks", noise_um: float = 0.002, seed: int = 0, **drive):
    """Held-out product Records of the world, imported as a lab's CSVs would be (blocks cut by the
    importer): ``form`` "blocks" (one record per block, each from the material's virgin state),
    "long" (one record) or "cut" (the long record cut into one file per block, each starting in the
    state the last left); ``drive``: u_max_v, bipolar, fs (Hz), hidden (an effect of ``hidden_um``)
    and stroke_scale."""
    if form not in FORMS:
        raise ValueError(f"unknown form {form!r}: one of {', '.join(FORMS)}")
    return imported_records(
        FORMS[form](world, noise_um, seed, **drive), drive.get("fs", SAMPLE_RATE_HZ), f"{world}:{form}"
    )


def imported_records(pairs, fs: float, label: str) -> list:
    """Held-out product Records (axis y) of [(u_v, x_um)] pairs sampled at ``fs`` (Hz), one per pair
    (labelled ``<label><k>:y``), their blocks cut by the product's importer as an imported CSV's are."""
    from service.science.data.segmentation import blocks_without_table
    from service.science.discovery.records import records_from_arrays

    out = []
    for k, (u, x) in enumerate(pairs):
        table = blocks_without_table({"y": u}, fs)
        out += records_from_arrays({"u_y_v": u, "x_y_um": x}, fs, table, ("y",), f"{label}{k}:")
    return out
