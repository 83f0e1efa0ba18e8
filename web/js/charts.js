// Charts: time series on uPlot (installed by npm into web/node_modules) with units on both axes
// and shaded x ranges; x–y loops and ellipses on a plain canvas (points in recorded order) ("where the model fails"). Each chart's container
// carries data attributes (data-points, data-series) with what it shows, for tests and scripts.

let loader = null;
export function loadUPlot() {
  if (!loader) {
    loader = import('../node_modules/uplot/dist/uPlot.esm.js').then((m) => m.default).catch(() => {
      throw new Error('the charting library is not installed: run `make run` (it runs npm ci in web/)');
    });
  }
  return loader;
}

export const COLORS = ['#1f6feb', '#d9480f', '#2b8a3e', '#7048e8', '#c2255c', '#0b7285', '#5c940d', '#e67700'];

function size(el, height) {
  const width = Math.max(320, Math.floor(el.clientWidth || el.parentElement?.clientWidth || 600) - 4);
  return { width, height };
}

function shadePlugin(ranges, color = 'rgba(220, 40, 40, 0.14)') {
  return {
    hooks: {
      drawClear: [(u) => {
        if (!ranges || !ranges.length) return;
        const { ctx, bbox } = u;
        ctx.save();
        ctx.fillStyle = color;
        for (const [a, b] of ranges) {
          const x0 = u.valToPos(a, 'x', true);
          const x1 = u.valToPos(b, 'x', true);
          ctx.fillRect(Math.min(x0, x1), bbox.top, Math.max(2, Math.abs(x1 - x0)), bbox.height);
        }
        ctx.restore();
      }],
    },
  };
}

function frame(el, title) {
  el.innerHTML = '';
  el.classList.add('chart');
  if (title) {
    const t = document.createElement('div');
    t.className = 'title';
    t.textContent = title;
    el.append(t);
  }
  const body = document.createElement('div');
  el.append(body);
  return body;
}

/**
 * A time series: x = xs, one line per entry of `series` ({label, values, color?, scale?}).
 * `xLabel`/`yLabel` carry units; `y2Label` names a second y axis for series with scale 'y2'.
 * `shade`: [[x0, x1], ...] ranges drawn behind the lines. `liveLegend: false`: the legend names the
 * series alone (no x row, no values under the cursor: "label: --" until hovered), for a chart whose
 * values are printed beside it.
 */
export async function lineChart(el, { title, xs, series, xLabel, yLabel, y2Label, height = 260, shade = [],
                                      points = false, yRange = null, integerX = false, liveLegend = true }) {
  const uPlot = await loadUPlot();
  const body = frame(el, title);
  const axes = [{ label: xLabel, ...(integerX ? { incrs: [1, 2, 5, 10, 20, 50, 100, 200, 500] } : {}) },
                { label: yLabel, scale: 'y', size: 60 }];
  if (y2Label) axes.push({ label: y2Label, scale: 'y2', side: 1, grid: { show: false }, size: 60 });
  const opts = {
    ...size(el, height),
    scales: { x: integerX ? { time: false, range: integerRange } : { time: false }, y: yRange ? { auto: false, range: yRange } : { auto: true }, ...(y2Label ? { y2: { auto: true } } : {}) },
    axes,
    series: [{ label: xLabel }, ...series.map((s, i) => ({
      label: s.label, stroke: s.color || COLORS[i % COLORS.length], width: s.width || 1.25,
      scale: s.scale || 'y', points: { show: points || !!s.points, size: 6 },
    }))],
    plugins: [shadePlugin(shade)],
    legend: { live: liveLegend },
    // the x range drawn, for a reader (and a test) of the page
    hooks: { setScale: [(u, key) => { if (key === 'x') el.dataset.xRange = JSON.stringify([u.scales.x.min, u.scales.x.max]); }] },
  };
  const chart = new uPlot(opts, [xs, ...series.map((s) => s.values)], body);
  el.dataset.series = JSON.stringify(series.map((s) => s.label));
  el.dataset.length = String(xs.length);
  return chart;
}

/** An integer x axis (steps, periods) spans the values there are, half a step either side: uPlot widens a
 * single value to 0–100 before the range function sees it, so the range is of the data, not of lo/hi. */
function integerRange(u) {
  const xs = u.data[0];
  if (!xs.length) return [-0.5, 0.5];
  return [xs.reduce((a, b) => Math.min(a, b)) - 0.5, xs.reduce((a, b) => Math.max(a, b)) + 0.5];
}

function niceTicks(lo, hi, n = 6) {
  if (!(hi > lo)) { hi = lo + 1; lo -= 1; }
  const raw = (hi - lo) / n;
  const mag = 10 ** Math.floor(Math.log10(raw));
  const step = [1, 2, 2.5, 5, 10].map((m) => m * mag).find((s) => s >= raw);
  const ticks = [];
  for (let v = Math.ceil(lo / step) * step; v <= hi + step * 1e-9; v += step) ticks.push(Number(v.toPrecision(12)));
  return ticks;
}

/**
 * X–Y curves (hysteresis loops, ellipses) on a plain canvas, points joined in their recorded
 * order: `curves` = [{label, x: [...], y: [...], color?}]. Axis labels carry units.
 */
export async function xyChart(el, { title, curves, xLabel, yLabel, height = 300, square = false, xShade = [] }) {
  const body = frame(el, title);
  const { width } = size(el, height);
  const dpr = window.devicePixelRatio || 1;
  const canvas = document.createElement('canvas');
  canvas.width = width * dpr; canvas.height = height * dpr;
  canvas.style.width = `${width}px`; canvas.style.height = `${height}px`;
  body.append(canvas);
  const legend = document.createElement('div');
  legend.className = 'xy-legend';
  legend.innerHTML = curves.map((c, i) => `<span><i style="background:${c.color || COLORS[i % COLORS.length]}"></i>${c.label}</span>`).join(' ');
  body.append(legend);
  const ctx = canvas.getContext('2d');
  ctx.scale(dpr, dpr);
  const finite = (a) => a.filter((v) => v !== null && Number.isFinite(v));
  const xs = curves.flatMap((c) => finite(c.x)); const ys = curves.flatMap((c) => finite(c.y));
  let [x0, x1] = [Math.min(...xs), Math.max(...xs)]; let [y0, y1] = [Math.min(...ys), Math.max(...ys)];
  const padX = (x1 - x0 || 1) * 0.04; const padY = (y1 - y0 || 1) * 0.06;
  x0 -= padX; x1 += padX; y0 -= padY; y1 += padY;
  const m = { l: 64, r: 12, t: 8, b: 44 };
  let pw = width - m.l - m.r; let ph = height - m.t - m.b;
  if (square) {   // equal µm per pixel on both axes
    const k = Math.min(pw / (x1 - x0), ph / (y1 - y0));
    const cx = (x0 + x1) / 2; const cy = (y0 + y1) / 2;
    x0 = cx - pw / k / 2; x1 = cx + pw / k / 2; y0 = cy - ph / k / 2; y1 = cy + ph / k / 2;
  }
  const px = (v) => m.l + ((v - x0) / (x1 - x0)) * pw;
  const py = (v) => m.t + ph - ((v - y0) / (y1 - y0)) * ph;
  ctx.fillStyle = 'rgba(220, 40, 40, 0.14)';
  for (const [a, b] of xShade) {
    const l = px(Math.max(a, x0)); const r = px(Math.min(b, x1));
    if (r > l) ctx.fillRect(l, m.t, r - l, ph);
  }
  ctx.font = '12px system-ui, sans-serif';
  ctx.strokeStyle = '#e3e6eb'; ctx.fillStyle = '#333'; ctx.lineWidth = 1;
  ctx.textAlign = 'center'; ctx.textBaseline = 'top';
  for (const t of niceTicks(x0, x1)) {
    if (t < x0 || t > x1) continue;
    ctx.beginPath(); ctx.moveTo(px(t), m.t); ctx.lineTo(px(t), m.t + ph); ctx.stroke();
    ctx.fillText(String(t), px(t), m.t + ph + 4);
  }
  ctx.textAlign = 'right'; ctx.textBaseline = 'middle';
  for (const t of niceTicks(y0, y1)) {
    if (t < y0 || t > y1) continue;
    ctx.beginPath(); ctx.moveTo(m.l, py(t)); ctx.lineTo(m.l + pw, py(t)); ctx.stroke();
    ctx.fillText(String(t), m.l - 4, py(t));
  }
  ctx.strokeStyle = '#999'; ctx.strokeRect(m.l, m.t, pw, ph);
  ctx.font = 'bold 12px system-ui, sans-serif'; ctx.textAlign = 'center'; ctx.textBaseline = 'bottom';
  ctx.fillText(xLabel, m.l + pw / 2, height - 2);
  ctx.save(); ctx.translate(12, m.t + ph / 2); ctx.rotate(-Math.PI / 2); ctx.textBaseline = 'top';
  ctx.fillText(yLabel, 0, 0); ctx.restore();
  ctx.save();
  ctx.beginPath(); ctx.rect(m.l, m.t, pw, ph); ctx.clip();
  curves.forEach((c, i) => {
    if (c.dots) {   // a scatter: one dot per point (a residual against a variable)
      ctx.fillStyle = c.color || COLORS[i % COLORS.length];
      for (let k = 0; k < c.x.length; k++) {
        if (c.x[k] !== null && c.y[k] !== null) ctx.fillRect(px(c.x[k]) - 1.5, py(c.y[k]) - 1.5, 3, 3);
      }
      return;
    }
    ctx.strokeStyle = c.color || COLORS[i % COLORS.length]; ctx.lineWidth = c.width || 1.25;
    ctx.beginPath();
    let pen = false;
    for (let k = 0; k < c.x.length; k++) {
      if (c.x[k] === null || c.y[k] === null) { pen = false; continue; }
      if (pen) ctx.lineTo(px(c.x[k]), py(c.y[k])); else ctx.moveTo(px(c.x[k]), py(c.y[k]));
      pen = true;
    }
    ctx.stroke();
  });
  ctx.restore();
  el.dataset.series = JSON.stringify(curves.map((c) => c.label));
  el.dataset.length = String(curves.reduce((n, c) => n + c.x.length, 0));
  return { root: el, destroy() { el.innerHTML = ''; }, setData() {} };
}

/** Destroy every uPlot inside `root` (when a page is left). */
export function destroyAll(charts) {
  for (const c of charts) { try { c.destroy(); } catch (_) { /* gone */ } }
  charts.length = 0;
}
