// Sweeps: a characterisation plan (axes, frequencies, cycles, voltages, waveform), its progress bar,
// and the resulting dataset with its time series.
import { api, esc, fmt } from '../api.js';
import { lineChart, destroyAll } from '../charts.js';
import { liveSignals } from '../live.js';
import { h, runJob, showError } from '../ui.js';

const charts = [];
let controller = null;
let live = null;

export async function enter(root) {
  controller = new AbortController();
  root.append(h(`<div>
    <h1>Sweeps</h1>
    <div class="card"><h2>New sweep</h2>
      <form id="sweep-form" class="inline">
        <label>axes <span class="row"><label class="check"><input type="checkbox" name="axis" value="y" checked>Y</label>
          <label class="check"><input type="checkbox" name="axis" value="z">Z</label></span></label>
        <label>waveform <select name="waveform"><option>sine</option><option>step</option><option>chirp</option><option>multisine</option></select></label>
        <label>frequencies (Hz, comma-separated) <input name="frequencies" value="1,10,50,100" size="16"></label>
        <label>cycles per frequency <input name="cycles" type="number" min="1" step="1" value="5"></label>
        <label>V min (V) <input name="v_min" type="number" step="any" min="0" value="0" title="the bench's limits (GET /api/bench) bound it"></label>
        <label>V max (V) <input name="v_max" type="number" step="any" min="0" value="120" title="the paper's 0–120 V by default; up to the bench's limit (150 V on the default bench)"></label>
        <label>name <input name="name" placeholder="(automatic)" size="14"></label>
        <button class="primary" type="submit" id="sweep-start">Start sweep</button>
      </form>
      <div id="sweep-plan" class="muted"></div>
      <div id="sweep-job"></div>
      <div id="sweep-error"></div>
    </div>
    <div class="card" id="sweep-live-card" hidden><h2>Live signals <span class="muted">(drive u and displacement x per axis)</span></h2><div id="sweep-live"></div></div>
    <div class="card" id="sweep-result" hidden><h2>Resulting dataset</h2><div id="sweep-summary"></div><div id="sweep-chart"></div></div>
  </div>`));
  root.querySelector('#sweep-form').addEventListener('submit', (e) => { e.preventDefault(); start(root); });
}

async function start(root) {
  const form = root.querySelector('#sweep-form');
  const err = root.querySelector('#sweep-error');
  err.textContent = '';
  const f = new FormData(form);
  const frequencies = String(f.get('frequencies')).split(/[\s,;]+/).filter(Boolean).map(Number);
  const body = {
    axes: f.getAll('axis'), waveform: f.get('waveform'), frequencies_hz: frequencies,
    cycles: Number(f.get('cycles')), v_min: Number(f.get('v_min')), v_max: Number(f.get('v_max')),
  };
  if (f.get('name')) body.name = f.get('name');
  if (frequencies.some((x) => !Number.isFinite(x))) { showError(err, new Error('frequencies: give numbers in Hz, e.g. 1,10,50,100')); return; }
  const button = root.querySelector('#sweep-start');
  button.disabled = true;
  try {
    if (!live) {
      const { axes } = await api('/bench', { signal: controller.signal });
      root.querySelector('#sweep-live-card').hidden = false;
      live = liveSignals(root.querySelector('#sweep-live'), axes);
    }
    const job = await runJob(root.querySelector('#sweep-job'), '/sweeps', body, 'sweep', { signal: controller.signal });
    if (job.state === 'succeeded' || job.result?.dataset_id) await showDataset(root, job);
    if (job.state === 'failed') showError(err, new Error(job.error || 'the sweep failed'));
    if (job.state === 'cancelled') root.querySelector('#sweep-plan').textContent = 'The sweep was cancelled; the output is at 0 V and the samples so far are kept as a partial dataset.';
  } catch (e) {
    showError(err, e);
  } finally {
    button.disabled = false;
  }
}

async function showDataset(root, job) {
  const id = job.result.dataset_id;
  const ds = await api(`/datasets/${id}`, { signal: controller.signal });
  root.querySelector('#sweep-result').hidden = false;
  root.querySelector('#sweep-summary').innerHTML = `<p id="sweep-dataset" data-dataset-id="${esc(id)}">
    <a href="#/datasets/${esc(id)}">${esc(id)}</a> · ${esc(ds.name)} · ${ds.samples} samples at ${fmt(ds.sample_rate_hz)} Hz ·
    ${fmt(ds.duration_s)} s · ${ds.n_blocks} blocks${ds.partial ? ` · <span class="warn">partial: ${esc(ds.partial_reason || '')}</span>` : ''}</p>`;
  const data = await api(`/datasets/${id}/data?max_points=4000`, { signal: controller.signal });
  const axes = ds.axes.filter((a) => data[`u_${a}_v`]);
  destroyAll(charts);
  charts.push(await lineChart(root.querySelector('#sweep-chart'), {
    title: 'Drive and displacement', xs: data.t_s, xLabel: 'time (s)', yLabel: 'drive u (V)', y2Label: 'displacement x (µm)',
    series: [...axes.map((a) => ({ label: `u_${a} (V)`, values: data[`u_${a}_v`] })),
             ...axes.map((a) => ({ label: `x_${a} (µm)`, values: data[`x_${a}_um`], scale: 'y2' }))],
  }));
}

export function leave() {
  if (controller) controller.abort();
  if (live) { live.stop(); live = null; }
  destroyAll(charts);
}
