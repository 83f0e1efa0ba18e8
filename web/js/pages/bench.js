// Bench: devices and their state, the hard limits, recent jobs, live signals of any job (u and x
// per axis, scrolling, from GET /api/bench/live) and the last recording.
import { api, esc, fmt, fmtErrorNm, fmtFixed, followJob } from '../api.js';
import { lineChart, destroyAll } from '../charts.js';
import { liveSignals } from '../live.js';
import { h, jobLine } from '../ui.js';

let timer = null;
let controller = null;
let following = null;
let live = null;
let onEngine = null;
let stateReadAt = new Date();
const charts = [];

export async function enter(root) {
  controller = new AbortController();
  following = null;
  const bench = await api('/bench');
  root.append(h(`<div>
    <h1>Bench <span class="muted">${esc(bench.backend)}</span></h1>
    <div class="grid">
      <div class="card"><h2>State</h2><p id="state-stale" class="bad" hidden></p><table id="state"></table>
        <div id="fault-actions" hidden><button id="reset-faults" title="POST /api/bench/reset">Reset latched faults</button>
          <span class="muted">outputs stay at 0 V; find the cause first</span></div>
        <div id="reset-result" class="muted"></div></div>
      <div class="card"><h2>Hard limits</h2><table id="limits"></table></div>
    </div>
    <div class="card"><h2>Live signals <span class="muted">(drive u and displacement x per axis, during any job)</span></h2>
      <div id="bench-job"></div>
      <div id="live"></div></div>
    <div class="card"><h2>Last recording <span class="muted" id="last-recording-name"></span></h2><div id="last-recording"></div></div>
    <div class="card"><h2>Recent jobs <span class="muted">(the running ones first)</span></h2><table id="jobs"></table></div>
  </div>`));
  renderState(root, bench);
  onEngine = (event) => { if (event.detail.status === 'degraded') markStale(root, event.detail.reason); };
  window.addEventListener('evc:engine', onEngine);
  root.querySelector('#reset-faults').addEventListener('click', async () => {
    const out = root.querySelector('#reset-result');
    try {
      const r = await api('/bench/reset', { method: 'POST' });
      out.textContent = (r.cleared.length ? `Cleared: ${r.cleared.join('; ')}.` : 'Nothing was latched.') +
        (r.remaining ? ` Still faulted (a reset cannot mend it): ${r.remaining}` : '');
      renderState(root, await api('/bench'));
    } catch (err) { out.textContent = `Reset refused: ${err.message}`; }
  });
  const axes = bench.axes;
  const lim = root.querySelector('#limits');
  lim.innerHTML = `<tr><th>axis</th><th class="num">V min (V)</th><th class="num">V max (V)</th><th class="num">slew (kV/s)</th>
    <th class="num">current (mA)</th><th class="num">C (µF)</th><th class="num">1st resonance (Hz)</th><th class="num">full-range f max (Hz)</th></tr>` +
    axes.map((a) => { const l = bench.limits[a]; return `<tr><td>${a}</td><td class="num">${fmt(l.v_min_v)}</td><td class="num">${fmt(l.v_max_v)}</td>
      <td class="num">${fmt(l.slew_limit_v_per_s / 1e3)}</td><td class="num">${fmt(l.current_limit_a * 1e3)}</td><td class="num">${fmt(l.capacitance_f * 1e6)}</td>
      <td class="num">${fmt(l.first_resonance_hz)}</td><td class="num">${fmt(l.max_frequency_hz_at_full_range)}</td></tr>`; }).join('');
  live = liveSignals(root.querySelector('#live'), axes);
  const poll = async () => {
    try {
      const b = await api('/bench');
      renderState(root, b);
      if (b.running_job_id && b.running_job_id !== following) follow(root, b.running_job_id);
    } catch (err) { if (err.status === 503) markStale(root, err.message); /* the pill shows the others */ }
  };
  timer = setInterval(poll, 1000);
  const jobs = await refreshJobs(root);
  const last = jobs.slice().sort((a, b) => String(b.created_at).localeCompare(String(a.created_at)))
    .find((j) => j.result && j.result.dataset_id);   // the newest recording, whatever runs
  if (last) await showRecording(root, last.result.dataset_id);
  else root.querySelector('#last-recording').innerHTML = '<p class="muted" id="no-recording">Nothing recorded yet: run a sweep on the <a href="#/sweeps">Sweeps</a> page, and its drive and displacement appear here.</p>';
  if (bench.running_job_id) follow(root, bench.running_job_id);
}

/** Progress of the job that owns the bench (SSE); when it ends, its recording (u and x per axis). */
async function follow(root, jobId) {
  following = jobId;
  const line = jobLine('bench job');
  root.querySelector('#bench-job').replaceChildren(line);
  try {
    const job = await followJob(jobId, (j) => line.update(j), { signal: controller.signal });
    line.update(job);
    await refreshJobs(root);
    if (job.result && job.result.dataset_id) await showRecording(root, job.result.dataset_id);
  } catch (_) { /* left the page */ }
}

async function showRecording(root, datasetId) {
  const ds = await api(`/datasets/${encodeURIComponent(datasetId)}`, { signal: controller.signal });
  const data = await api(`/datasets/${encodeURIComponent(datasetId)}/data?max_points=3000`, { signal: controller.signal });
  const axes = ds.axes.filter((a) => data[`u_${a}_v`]);
  const el = root.querySelector('#last-recording');
  const old = charts.find((c) => c.root && el.contains(c.root));
  if (old) { old.destroy(); charts.splice(charts.indexOf(old), 1); }
  root.querySelector('#last-recording-name').innerHTML = `<a href="#/datasets/${esc(ds.id)}">${esc(ds.id)}</a> · ${esc(ds.name)}${ds.partial ? ' (partial)' : ''}`;
  el.dataset.datasetId = ds.id;
  charts.push(await lineChart(el, { xs: data.t_s, xLabel: 'time (s)', yLabel: 'drive u (V)', y2Label: 'displacement x (µm)', height: 220,
    series: [...axes.map((a) => ({ label: `u_${a} (V)`, values: data[`u_${a}_v`] })),
             ...axes.map((a) => ({ label: `x_${a} (µm)`, values: data[`x_${a}_um`], scale: 'y2' }))] }));
}

/** No engine (health 503 degraded, or GET /api/bench 503): the State table keeps the last values
 *  read, marked stale with their time, and the reset (refused with 503 then) is disabled. */
function markStale(root, reason) {
  const el = root.querySelector('#state');
  if (!el) return;
  el.dataset.stale = '1';
  const note = root.querySelector('#state-stale');
  note.textContent = `Engine absent: last values read at ${stateReadAt.toISOString().slice(11, 19)} UTC, not current (${reason || 'no bench engine'}).`;
  note.hidden = false;
  root.querySelector('#reset-faults').disabled = true;
}

function renderState(root, b) {
  const el = root.querySelector('#state');
  if (!el) return;
  stateReadAt = new Date();
  delete el.dataset.stale;
  root.querySelector('#state-stale').hidden = true;
  root.querySelector('#reset-faults').disabled = false;
  el.innerHTML = `<tr><th>axis</th><th class="num">output (V)</th><th class="num">current (mA)</th><th>amplifier</th><th>sensor</th><th class="num">range (µm)</th></tr>` +
    b.axes.map((a) => { const amp = b.amplifiers[a]; const s = b.sensors[a]; return `<tr data-axis="${a}">
      <td>${a}</td><td class="num" data-output-v="${amp.output_v}">${fmtFixed(amp.output_v, 2)}</td>
      <td class="num">${fmtFixed(1000 * amp.current_a, 1)}</td>
      <td class="${amp.fault ? 'bad' : 'ok'}">${amp.fault ? esc(amp.fault_reason || 'fault') : (amp.enabled ? 'enabled' : 'disabled')}${amp.current_limited ? ' · current-limited' : ''}</td>
      <td class="${s.ok ? 'ok' : 'bad'}">${s.ok ? (s.saturated ? 'saturated' : 'ok') : esc(s.reason || 'not ok')}</td>
      <td class="num">${s.range_um.map((v) => fmt(v)).join(' … ')}</td></tr>`; }).join('') +
    `<tr><td colspan="6" class="muted" title="the job that owns the outputs; fits (identify, diagnose, discover between its sweeps) run beside the bench and are listed under Recent jobs">running bench job: <span id="running">${esc(b.running_job_id || 'none')}</span></td></tr>`;
  const faulted = b.axes.some((a) => b.amplifiers[a].fault) || Boolean(b.engine && b.engine.latched_fault);
  root.querySelector('#fault-actions').hidden = !faulted || Boolean(b.running_job_id);
}

async function refreshJobs(root) {
  // the running jobs first, however old (a discover fitting for half an hour), then the newest
  const [running, newest] = await Promise.all([api('/jobs?state=running&limit=20', { signal: controller.signal }),
    api('/jobs?limit=10', { signal: controller.signal })]);
  const jobs = [...running, ...newest.filter((j) => !running.some((r) => r.id === j.id))];
  const el = root.querySelector('#jobs');
  el.innerHTML = `<tr><th>job</th><th>kind</th><th>state</th><th class="num">progress</th><th>result / error</th><th>created</th></tr>` +
    jobs.map((j) => `<tr><td>${esc(j.id)}</td><td>${esc(j.kind)}</td><td class="state-${j.state}">${j.state}</td>
      <td class="num">${Math.round(100 * j.progress)} %</td>
      <td class="result">${j.error ? `<span class="bad">${esc(j.error)}</span>` : summary(j.result)}</td>
      <td>${esc(j.created_at)}</td></tr>`).join('');
  return jobs;
}

const link = (route) => (id) => `<a href="#/${route}/${esc(id)}">${esc(id)}</a>`;
/** What a user reads of a job's result, in order: [field, words, how to show it]; the rest (timings,
 * internals such as loop_cpu_s) stays in the job's JSON. */
const SUMMARY_FIELDS = [
  ['dataset_id', 'dataset', link('datasets')],
  ['model_id', 'model', link('models')],
  ['final_model_id', 'final model', link('models')],
  ['validation_rms_um', 'held-out RMS', (v) => fmtErrorNm(v, 4)],
  ['rms_error_um', 'RMS error', (v) => fmtErrorNm(v, 4)],
  ['relative_error_pct', 'relative error', (v) => `${fmt(v, 3)} %`],
  // a discover's reason ("max_steps"), or a run's flag: true is an early stop, false says nothing
  ['stopped', 'ended', (v) => (v === true ? 'early (stopped)' : esc(String(v).replace(/_/g, ' ')))],
];

/** A job's result in a line of words (HTML): its dataset or model, and its headline figures. */
function summary(result) {
  if (!result) return '';
  return SUMMARY_FIELDS.filter(([k]) => result[k] !== null && result[k] !== undefined && result[k] !== false
      && typeof result[k] !== 'object')
    .map(([k, words, show]) => `${words} ${show(result[k])}`).join(' · ');
}

export function leave() {
  clearInterval(timer);
  if (onEngine) window.removeEventListener('evc:engine', onEngine);
  if (live) live.stop();
  if (controller) controller.abort();
  destroyAll(charts);
}
