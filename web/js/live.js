// Live signals of whatever the bench streams (any job): one scrolling chart per axis with the drive
// u (V, left axis) and the displacement x (µm, right axis), from GET /api/bench/live?since=cursor.
// Polls fast while a job owns the bench, slowly otherwise (to notice the next job). Each chart's
// container carries data-points (samples shown), data-run and data-job for tests and scripts.
import { api } from './api.js';
import { lineChart } from './charts.js';

const WINDOW_S = 5;          // seconds of signal kept on screen
const FAST_MS = 300;         // while a job runs
const SLOW_MS = 1500;        // while the bench is idle

export function liveSignals(container, axes) {
  let cursor = null;
  let run = null;
  let timer = null;
  let stopped = false;
  const charts = {};
  const data = {};
  container.innerHTML = `<div class="grid live-grid">${axes.map((a) => `<div class="live-axis" id="live-${a}" data-axis="${a}" data-points="0"></div>`).join('')}</div>
    <p class="muted live-status" id="live-status">Waiting for a job to stream…</p>`;
  const status = container.querySelector('#live-status');

  async function draw(axis) {
    const el = container.querySelector(`#live-${axis}`);
    const d = data[axis];
    if (!charts[axis]) {
      charts[axis] = await lineChart(el, { title: `axis ${axis.toUpperCase()}`, xs: d.t, xLabel: 'time in run (s)',
        yLabel: `u_${axis} (V)`, y2Label: `x_${axis} (µm)`, height: 200,
        series: [{ label: `u_${axis} (V)`, values: d.u }, { label: `x_${axis} (µm)`, values: d.x, scale: 'y2' }] });
    } else {
      charts[axis].setData([d.t, d.u, d.x]);
    }
    el.dataset.points = String(d.t.length);
    el.dataset.run = String(run);
    const finite = (v) => v.filter((x) => x !== null);
    el.dataset.uMaxV = String(Math.max(...finite(d.u), -Infinity));
    el.dataset.xMaxUm = String(Math.max(...finite(d.x), -Infinity));
    el.dataset.tLastS = String(d.t.length ? d.t[d.t.length - 1] : 0);
  }

  function reset() {
    for (const a of axes) data[a] = { t: [], u: [], x: [] };
  }
  reset();

  let inflight = false;
  let again = false;   // asked to look again while a request was in flight
  async function poll() {
    if (stopped) return;
    if (inflight) { again = true; return; }
    inflight = true;
    again = false;
    clearTimeout(timer);
    let busy = false;
    try {
      const r = await api(`/bench/live?max_points=5000${cursor === null ? '' : `&since=${cursor}`}`);
      busy = !!r.running_job_id;
      cursor = r.cursor;
      container.dataset.job = r.running_job_id || '';
      if (r.t_s.length) {
        const last = r.runs[r.runs.length - 1];
        if (last !== run) { run = last; reset(); }
        for (let k = 0; k < r.t_s.length; k++) {
          if (r.runs[k] !== run) continue;
          for (const a of axes) {
            data[a].t.push(r.t_s[k]); data[a].u.push(r[`u_${a}_v`][k]); data[a].x.push(r[`x_${a}_um`][k]);
          }
        }
        for (const a of axes) {
          const d = data[a];
          const from = d.t.findIndex((t) => t >= d.t[d.t.length - 1] - WINDOW_S);
          if (from > 0) { d.t.splice(0, from); d.u.splice(0, from); d.x.splice(0, from); }
        }
      }
      if (r.t_s.length || !charts[axes[0]]) for (const a of axes) await draw(a);
      status.textContent = busy ? `Streaming: job ${r.running_job_id} (${r.label || 'run'} ${run}), ${Math.round(r.rate_hz)} samples/s shown, last ${WINDOW_S} s.`
        : (run ? `Bench idle: the last ${WINDOW_S} s of run ${run} (${r.label || 'run'}).` : 'Bench idle: nothing streamed yet. Start a sweep or a trajectory to see the signals here.');
    } catch (err) {
      status.textContent = `Live signals unavailable: ${err.message}`;
    }
    inflight = false;
    if (!stopped) timer = setTimeout(poll, again ? 0 : (busy ? FAST_MS : SLOW_MS));
  }
  // A job started or ended from this page (ui.runJob): look now rather than at the next slow poll.
  const now = () => setTimeout(poll, 50);
  window.addEventListener('evc:job', now);
  poll();
  return {
    stop() {
      stopped = true; clearTimeout(timer); window.removeEventListener('evc:job', now);
      for (const c of Object.values(charts)) c.destroy();
    },
  };
}
