"""Small static SVG charts for self-contained reports: axes with ticks, polylines, a shaded
horizontal band, dashed reference lines, labelled points and a legend; every text escaped.

No dependency beyond numpy, no script: a figure is a string that any browser draws (and prints
to PDF as vectors). Panels (:class:`Panel`) are laid out side by side in one ``<svg>`` by
:func:`figure`. Lengths that scale are shown in nm below 1 µm and in µm above
(:func:`length_unit`; errors and noise: service.science.data.units.fmt_nm).
"""

from __future__ import annotations

import math
from html import escape

import numpy as np

#: line colours, in order of use (colour-blind-safe Okabe–Ito)
COLOURS = ("#0072B2", "#D55E00", "#009E73", "#CC79A7", "#E69F00", "#56B4E9")
#: at most this many points per polyline (decimated evenly)
MAX_CURVE_POINTS = 1500
#: grid lines' style
GRID = 'stroke="#ddd" stroke-width="0.6"'


def length_unit(max_abs_um: float) -> tuple[float, str]:
    """(factor from µm, unit) for lengths up to ``max_abs_um``: nm below 1 µm, µm above."""
    return (1e3, "nm") if abs(max_abs_um) < 1.0 else (1.0, "µm")


#: errors and noise are in nm everywhere the user reads them (the API's texts, the dashboard, the report)
ERROR_UNIT = (1e3, "nm")


def decimate(n_samples: int, max_points: int = MAX_CURVE_POINTS) -> slice:
    """The slice that keeps at most ``max_points`` of ``n_samples`` evenly (every stride-th)."""
    return slice(None, None, max(1, math.ceil(n_samples / max_points)))


def nice_ticks(lo: float, hi: float, count: int = 5) -> list[float]:
    """About ``count`` round tick values (1, 2, 5 × 10^k steps) covering [lo, hi]."""
    if not (math.isfinite(lo) and math.isfinite(hi)) or hi <= lo:
        return [lo]
    raw = (hi - lo) / max(count, 1)
    decade = 10 ** math.floor(math.log10(raw))
    step = min((m * decade for m in (1, 2, 5, 10)), key=lambda v: abs(math.log(v / raw)))
    first = math.ceil(lo / step - 1e-9)
    return [round(k * step, 12) for k in range(first, int(math.floor(hi / step + 1e-9)) + 1)]


def log_ticks(lo: float, hi: float) -> list[float]:
    """Decades (and 2, 5 within them when fewer than three decades show) in [lo, hi], lo > 0."""
    ticks = []
    for k in range(math.floor(math.log10(lo)), math.ceil(math.log10(hi)) + 1):
        for m in (1,) if hi / lo > 1e3 else (1, 2, 5):
            v = m * 10.0**k
            if lo * (1 - 1e-9) <= v <= hi * (1 + 1e-9):
                ticks.append(v)
    return ticks


def _tick_text(v: float) -> str:
    return f"{v:.4g}"


class Panel:
    """One chart: ``width`` × ``height`` px, a title and axis labels (units in them), linear axes or
    a logarithmic y axis (``log_y``). Add curves, then ``render(x0, y0)`` into a figure."""

    margin = (58, 14, 30, 44)  # left, right, top, bottom (px)

    def __init__(
        self,
        width: int,
        height: int,
        title: str,
        x_label: str,
        y_label: str,
        log_y: bool = False,
        integer_x: bool = False,
        legend: str = "top-left",
    ):
        self.width, self.height, self.title = width, height, title
        self.x_label, self.y_label, self.log_y = x_label, y_label, log_y
        self.integer_x, self.legend_at = integer_x, legend  # whole-number x ticks; top-left | bottom-right
        self.curves: list[dict] = []
        self.bands: list[dict] = []
        self.hlines: list[dict] = []
        self.marks: list[dict] = []

    # -- content -----------------------------------------------------------------------------
    def line(self, x, y, label: str, colour: str | None = None, width: float = 1.2) -> Panel:
        """A polyline through (x, y), decimated to MAX_CURVE_POINTS."""
        x, y = np.asarray(x, dtype=float), np.asarray(y, dtype=float)
        keep = decimate(x.size)
        self.curves.append(
            {
                "x": x[keep],
                "y": y[keep],
                "label": label,
                "colour": colour or COLOURS[len(self.curves) % len(COLOURS)],
                "width": width,
            }
        )
        return self

    def band(self, y_lo: float, y_hi: float, label: str, colour: str = "#999999") -> Panel:
        """A shaded horizontal band between two y values (on a log axis y_lo may be the bottom: 0)."""
        self.bands.append({"lo": y_lo, "hi": y_hi, "label": label, "colour": colour})
        return self

    def hline(self, y: float, label: str, colour: str = "#555555") -> Panel:
        """A dashed horizontal reference line, labelled at its right end."""
        self.hlines.append({"y": y, "label": label, "colour": colour})
        return self

    def points(self, x, y, labels, colour: str = COLOURS[0]) -> Panel:
        """Markers at (x, y), each with a short label above it."""
        for xi, yi, text in zip(x, y, labels):
            self.marks.append({"x": float(xi), "y": float(yi), "label": str(text), "colour": colour})
        return self

    # -- geometry ------------------------------------------------------------------------------
    def _limits(self) -> tuple[float, float, float, float]:
        xs = [c["x"] for c in self.curves] + [np.array([m["x"] for m in self.marks])]
        ys = (
            [c["y"] for c in self.curves]
            + [np.array([m["y"] for m in self.marks])]
            + [np.array([h["y"] for h in self.hlines])]
            + [np.array([b["hi"] for b in self.bands])]
        )
        xv = np.concatenate([a for a in xs if a.size]) if any(a.size for a in xs) else np.array([0.0, 1.0])
        yv = np.concatenate([a for a in ys if a.size]) if any(a.size for a in ys) else np.array([0.0, 1.0])
        if self.log_y:
            yv = yv[yv > 0] if np.any(yv > 0) else np.array([1e-3, 1.0])
        x0, x1, y0, y1 = float(np.min(xv)), float(np.max(xv)), float(np.min(yv)), float(np.max(yv))
        if x1 <= x0 or self.marks:  # room for the markers' labels at the ends
            x0, x1 = x0 - 0.3 * max(x1 - x0, 1.0), x1 + 0.3 * max(x1 - x0, 1.0)
        if self.log_y:  # headroom for the labels above the markers
            return x0, x1, y0 / 2.5, y1 * 2.0
        pad = 0.05 * (y1 - y0) if y1 > y0 else max(abs(y0) * 0.1, 1e-12)
        return x0, x1, y0 - pad, y1 + pad

    def render(self, x_off: float = 0.0, y_off: float = 0.0) -> str:
        """The panel as an SVG ``<g>`` translated to (x_off, y_off)."""
        left, right, top, bottom = self.margin
        pw, ph = self.width - left - right, self.height - top - bottom
        x0, x1, y0, y1 = self._limits()
        ly = (lambda v: math.log10(max(v, y0 * 1e-3))) if self.log_y else (lambda v: v)
        v0, v1 = ly(y0), ly(y1)

        def sx(v):
            return left + (np.asarray(v, dtype=float) - x0) / (x1 - x0) * pw

        def sy(v):
            v = np.asarray(v, dtype=float)
            vv = np.log10(np.maximum(v, y0 * 1e-3)) if self.log_y else v
            return top + ph - (np.clip(vv, v0 - 0.02 * (v1 - v0), v1 + 0.02 * (v1 - v0)) - v0) / (v1 - v0) * ph

        out = [
            f'<g transform="translate({x_off:.0f},{y_off:.0f})" class="panel">',
            f'<text x="{left + pw / 2:.1f}" y="16" text-anchor="middle" class="title">{escape(self.title)}</text>',
            f'<rect x="{left}" y="{top}" width="{pw}" height="{ph}" fill="none" stroke="#444" stroke-width="0.8"/>',
        ]
        for b in self.bands:
            ya, yb = float(sy(b["hi"])), float(sy(b["lo"] if b["lo"] > 0 or not self.log_y else y0))
            out.append(
                f'<rect x="{left}" y="{ya:.1f}" width="{pw}" height="{max(yb - ya, 0.5):.1f}" '
                f'fill="{b["colour"]}" fill-opacity="0.25"><title>{escape(b["label"])}</title></rect>'
            )
        ticks_y = log_ticks(y0, y1) if self.log_y else nice_ticks(y0, y1)
        for t in ticks_y:
            y = float(sy(t))
            out.append(
                f'<line x1="{left - 4}" x2="{left + pw}" y1="{y:.1f}" y2="{y:.1f}" {GRID}/>'
                f'<text x="{left - 6}" y="{y + 3.5:.1f}" text-anchor="end">{_tick_text(t)}</text>'
            )
        ticks_x = nice_ticks(x0, x1, max(2, pw // 70))
        for t in [t for t in ticks_x if t == int(t)] if self.integer_x else ticks_x:
            x = float(sx(t))
            out.append(
                f'<line x1="{x:.1f}" x2="{x:.1f}" y1="{top}" y2="{top + ph + 4}" {GRID}/>'
                f'<text x="{x:.1f}" y="{top + ph + 16}" text-anchor="middle">{_tick_text(t)}</text>'
            )
        out.append(
            f'<text x="{left + pw / 2:.1f}" y="{self.height - 6}" text-anchor="middle">'
            f"{escape(self.x_label)}</text>"
            f'<text transform="translate(13,{top + ph / 2:.1f}) rotate(-90)" text-anchor="middle">'
            f"{escape(self.y_label)}</text>"
        )
        for h in self.hlines:
            y = float(sy(h["y"]))
            out.append(
                f'<line x1="{left}" x2="{left + pw}" y1="{y:.1f}" y2="{y:.1f}" stroke="{h["colour"]}" '
                f'stroke-dasharray="5 3" stroke-width="1"/><text x="{left + pw - 4}" y="{y - 4:.1f}" '
                f'text-anchor="end" fill="{h["colour"]}">{escape(h["label"])}</text>'
            )
        for c in self.curves:
            xs, ys = sx(c["x"]), sy(c["y"])
            pts = " ".join(f"{a:.1f},{b:.1f}" for a, b in zip(xs, ys))
            out.append(
                f'<polyline points="{pts}" fill="none" stroke="{c["colour"]}" stroke-width="{c["width"]}" '
                f'stroke-linejoin="round"><title>{escape(c["label"])}</title></polyline>'
            )
        if self.marks:
            xs, ys = sx([m["x"] for m in self.marks]), sy([m["y"] for m in self.marks])
            out.append(
                f'<polyline points="{" ".join(f"{a:.1f},{b:.1f}" for a, b in zip(xs, ys))}" fill="none" '
                f'stroke="{self.marks[0]["colour"]}" stroke-width="1.5"/>'
            )
            for m, a, b in zip(self.marks, xs, ys):
                out.append(
                    f'<circle cx="{a:.1f}" cy="{b:.1f}" r="3.5" fill="{m["colour"]}"/>'
                    f'<text x="{a:.1f}" y="{b - 8:.1f}" text-anchor="middle">{escape(m["label"])}</text>'
                )
        n_items = len(self.curves) + len(self.bands)
        out.append(
            self._legend(left + 8, top + 6)
            if self.legend_at == "top-left"
            else self._legend(left + pw - 170, top + ph - 8 - 13 * n_items)
        )
        out.append("</g>")
        return "".join(out)

    def _legend(self, x: float, y: float) -> str:
        items = [(c["label"], c["colour"], False) for c in self.curves]
        items += [(b["label"], b["colour"], True) for b in self.bands]
        out = []
        for i, (label, colour, filled) in enumerate(items):
            yy = y + 13 * i
            mark = (
                f'<rect x="{x:.1f}" y="{yy + 2:.1f}" width="14" height="7" fill="{colour}" fill-opacity="0.25"/>'
                if filled
                else f'<line x1="{x:.1f}" x2="{x + 14:.1f}" y1="{yy + 6:.1f}" y2="{yy + 6:.1f}" '
                f'stroke="{colour}" stroke-width="2"/>'
            )
            out.append(f'{mark}<text x="{x + 18:.1f}" y="{yy + 9.5:.1f}">{escape(label)}</text>')
        return "".join(out)


def figure(panels: list[Panel], label: str, frame: str | None = None) -> str:
    """Panels side by side in one ``<svg>`` (``label``: its accessible name, also its ``<title>``;
    ``frame``: the colour of a frame round the whole figure, none without it)."""
    width = sum(p.width for p in panels)
    height = max(p.height for p in panels)
    body, x = [], 0
    for p in panels:
        body.append(p.render(x, 0))
        x += p.width
    if frame:
        body.append(
            f'<rect x="1" y="1" width="{width - 2}" height="{height - 2}" fill="none" stroke="{frame}" '
            f'stroke-width="2.5" class="frame"/>'
        )
    return (
        f'<svg xmlns="http://www.w3.org/2000/svg" class="figure" width="{width}" height="{height}" '
        f'viewBox="0 0 {width} {height}" role="img" aria-label="{escape(label)}" font-family="sans-serif" '
        f'font-size="10.5"><title>{escape(label)}</title>{"".join(body)}</svg>'
    )
