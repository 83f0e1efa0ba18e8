// Datasets: the list; import (with a column-mapping preview for headerless files, parsed here from
// the first lines); one dataset's time series, hysteresis loops per frequency block, and exports.
import { api, download, esc, fmt } from '../api.js';
import { lineChart, xyChart, destroyAll } from '../charts.js';
import { renderLabels } from '../labels.js';
import { isImported, originHtml } from '../provenance.js';
import { h, showError } from '../ui.js';

const charts = [];
let controller = null;
const DELIMITERS = { comma: /,/, tab: /\t/, semicolon: /;/, whitespace: /\s+/ };
const ROLES = ['', 't', 'u', 'x', 'u_y', 'x_y', 'u_z', 'x_z', 'temp_c'];

export async function enter(root, [id]) {
  controller = new AbortController();
  if (id) return showDataset(root, id);
  root.append(h(`<div>
    <h1>Datasets</h1>
    <div class="card"><h2>Import a file</h2>
      <form id="import-form" class="inline">
        <label>file (CSV or a headerless table) <input type="file" name="file" id="import-file"></label>
        <label>delimiter <select name="delimiter" id="import-delimiter">
          <option value="">guess</option><option value="comma">comma</option><option value="tab">tab</option>
          <option value="semicolon">semicolon</option><option value="whitespace">whitespace</option></select></label>
        <label>axis (for u, x) <select name="axis" id="import-axis"><option value="y">y</option><option value="z">z</option></select></label>
        <label>sample rate (Hz, if no t column) <input name="sample_rate_hz" id="import-rate" type="number" step="any" min="0" style="width:120px"></label>
        <label>name <input name="name" id="import-name" size="16"></label>
        <button class="primary" type="submit" id="import-submit">Import</button>
      </form>
      <div id="import-preview" class="preview"></div>
      <div id="import-result"></div>
    </div>
    <div class="card"><h2>Stored datasets</h2><table id="dataset-list"></table></div>
  </div>`));
  const file = root.querySelector('#import-file');
  const delim = root.querySelector('#import-delimiter');
  file.addEventListener('change', () => preview(root));
  delim.addEventListener('change', () => preview(root));
  root.querySelector('#import-form').addEventListener('submit', (e) => { e.preventDefault(); submitImport(root); });
  await refreshList(root);
}

async function refreshList(root) {
  const rows = await api('/datasets', { signal: controller.signal });
  root.querySelector('#dataset-list').innerHTML = `<tr><th>id</th><th>name</th><th>source</th><th>axes</th>
    <th class="num">samples</th><th class="num">rate (Hz)</th><th class="num">duration (s)</th><th class="num">blocks</th><th>created</th><th title="the bench it was recorded on (a lab: see the Lab page), or the file it was imported from">origin</th></tr>` +
    rows.slice().reverse().map((d) => `<tr data-dataset-id="${esc(d.id)}"><td><a href="#/datasets/${esc(d.id)}">${esc(d.id)}</a></td>
      <td>${esc(d.name)}${d.partial ? ' <span class="warn">(partial)</span>' : ''}${(d.tags || []).map((t) => ` <span class="tag">${esc(t)}</span>`).join('')}</td><td>${esc(d.source)}</td><td>${d.axes.join(', ')}</td>
      <td class="num">${d.samples}</td><td class="num">${fmt(d.sample_rate_hz)}</td><td class="num">${fmt(d.duration_s)}</td>
      <td class="num">${d.n_blocks}</td><td>${esc(d.created_at)}</td><td class="bench origin" data-imported="${isImported(d) ? 1 : 0}">${originHtml(d)}</td></tr>`).join('');
}

// as the service guesses (service/science/data/table_reader.py): a semicolon is never a decimal mark
function guessDelimiter(lines) {
  const first = lines.find((l) => l.trim()) || '';
  if (first.includes(';')) return 'semicolon';
  if (first.includes('\t')) return 'tab';
  if (first.includes(',')) return 'comma';
  return 'whitespace';
}

let parsed = null;   // {header: [...]|null, rows: [[...]], delimiter}

async function preview(root) {
  const input = root.querySelector('#import-file');
  const out = root.querySelector('#import-preview');
  const file = input.files[0];
  parsed = null;
  out.innerHTML = '';
  if (!file) return;
  if (!root.querySelector('#import-name').value) root.querySelector('#import-name').value = file.name;
  const text = await file.slice(0, 64 * 1024).text();
  const comment = (l) => l.trim().startsWith('#') || l.trim().startsWith('%');    // and MATLAB's
  const lines = text.split(/\r?\n/).filter((l) => l.trim() && !comment(l)).slice(0, 12);
  const chosen = root.querySelector('#import-delimiter').value || guessDelimiter(lines);
  const split = (l) => l.trim().split(DELIMITERS[chosen]).map((s) => s.trim());
  let rows = lines.map(split);
  const numeric = (s) => s !== '' && Number.isFinite(Number(s));
  const header = rows.length && !rows[0].every(numeric) ? rows.shift() : null;
  rows = rows.slice(0, 10);
  const width = Math.max(0, ...rows.map((r) => r.length), header ? header.length : 0);
  parsed = { header, rows, delimiter: chosen, width };
  const roleOf = (i) => {
    if (!header) return '';
    const name = header[i];
    return ROLES.includes(name) ? name : '';
  };
  out.innerHTML = `<p class="muted">${header ? 'Header row found: the columns are named by it; pick roles to override.'
      : 'No header row: pick which column is the drive u (V), the displacement x (µm) and, if any, time t (s).'}
      Delimiter: <b id="preview-delimiter">${chosen}</b>, ${width} columns (numbered from 1 here; the API's and <code>evcbench import --columns</code>' indices count from 0), first ${rows.length} rows.</p>
    <table id="preview-table"><tr>${Array.from({ length: width }, (_, i) => `<th>
      <div class="col-number" title="numbered from 1, as labs describe their files (the API's columns count from 0: this is ${i})">col ${i + 1}${header ? ` · ${esc(header[i] ?? '')}` : ''}</div>
      <select class="col-role" data-col="${i}">${ROLES.map((r) => `<option value="${r}"${r === roleOf(i) ? ' selected' : ''}>${r || '—'}</option>`).join('')}</select>
    </th>`).join('')}</tr>
    ${rows.map((r) => `<tr>${Array.from({ length: width }, (_, i) => `<td class="num">${esc(r[i] ?? '')}</td>`).join('')}</tr>`).join('')}</table>`;
}

function mapping(root) {
  const map = {};
  root.querySelectorAll('.col-role').forEach((sel) => { if (sel.value) map[sel.value] = Number(sel.dataset.col); });
  return map;
}

async function submitImport(root) {
  const result = root.querySelector('#import-result');
  result.className = '';
  result.textContent = '';
  const file = root.querySelector('#import-file').files[0];
  if (!file) { showError(result, new Error('file: choose a file to import')); return; }
  const form = new FormData();
  form.append('file', file);
  const name = root.querySelector('#import-name').value;
  if (name) form.append('name', name);
  const map = mapping(root);
  const named = parsed && parsed.header;
  const overridden = named && Object.entries(map).some(([role, col]) => parsed.header[col] !== role);
  if (!named || overridden) {
    if (Object.keys(map).length) form.append('columns', JSON.stringify(map));
  }
  // the axis the select shows is the one sent: the service reads it only for a single-axis file (u, x),
  // whether its columns were mapped here or recognised from the header (u_V, x_um)
  form.append('axis', root.querySelector('#import-axis').value);
  const rate = root.querySelector('#import-rate').value;
  if (rate) form.append('sample_rate_hz', rate);
  const delimiter = root.querySelector('#import-delimiter').value || (parsed ? parsed.delimiter : '');
  if (delimiter) form.append('delimiter', delimiter);
  const button = root.querySelector('#import-submit');
  button.disabled = true;
  try {
    const ds = await api('/datasets', { method: 'POST', form, signal: controller.signal });
    result.innerHTML = `<p class="ok" id="import-done" data-dataset-id="${esc(ds.id)}" data-samples="${ds.samples}" data-sample-rate-hz="${ds.sample_rate_hz}">
      Imported <a href="#/datasets/${esc(ds.id)}">${esc(ds.id)}</a>: ${ds.samples} samples at ${fmt(ds.sample_rate_hz)} Hz, axes ${ds.axes.join(', ')}.</p>
      ${(ds.import_notes || []).map((n) => `<p class="muted import-note">note: ${esc(n)}</p>`).join('')}`;
    await refreshList(root);
  } catch (e) {
    showError(result, e, 'Import refused: ');
  } finally {
    button.disabled = false;
  }
}

/** A block's frequency: its own, or each axis's where they were driven at once at their own
 *  (with the one at which they repeat together, if they do). */
function blockFrequency(b) {
  if (!b.frequencies_hz) return fmt(b.frequency_hz);
  const each = Object.entries(b.frequencies_hz).map(([axis, f]) => `${esc(axis)} ${fmt(f)}`).join(' + ');
  return b.frequency_hz ? `${each} (together ${fmt(b.frequency_hz)})` : each;
}

/** " · drive −150 … 150 V (y)" from the dataset's recorded drive range, or "". */
function driveRange(ds) {
  const range = ds.drive_range_v || {};
  const parts = Object.entries(range).map(([axis, [lo, hi]]) => `${fmt(lo)} … ${fmt(hi)} V (${esc(axis)})`);
  return parts.length ? ` · <span id="drive-range">drive ${parts.join(', ')}</span>` : '';
}

/** What an imported record's block leaves out before (and, for the last block, after) it, in words. */
function trimmedText(b) {
  const t = b.trimmed;
  if (!t || (!t.before_s && !t.after_s)) return '';
  const parts = [t.before_s ? `${fmt(t.before_s)} s before` : '', t.after_s ? `${fmt(t.after_s)} s after` : ''].filter(Boolean);
  return `<span title="${esc(t.why || '')}">${parts.join(', ')}</span>`;
}

async function showDataset(root, id) {
  const ds = await api(`/datasets/${encodeURIComponent(id)}`, { signal: controller.signal });
  root.append(h(`<div>
    <h1>Dataset <span id="dataset-id">${esc(ds.id)}</span> <span class="muted" id="dataset-name">${esc(ds.name)}</span></h1>
    <div class="card" id="dataset-labels"></div>
    <div class="card"><p id="dataset-summary" data-samples="${ds.samples}" data-sample-rate-hz="${ds.sample_rate_hz}"><span id="dataset-origin">${isImported(ds) ? originHtml(ds) : `recorded on ${originHtml(ds)}`}</span> · axes ${ds.axes.join(', ')} ·
      ${ds.samples} samples at ${fmt(ds.sample_rate_hz)} Hz · ${fmt(ds.duration_s)} s · ${ds.n_blocks} blocks${driveRange(ds)}
      ${ds.partial ? ` · <span class="warn">partial: ${esc(ds.partial_reason || '')}</span>` : ''}</p>
      ${(ds.import_notes || []).length ? `<ul id="import-notes" class="muted">${ds.import_notes.map((n) => `<li>${esc(n)}</li>`).join('')}</ul>` : ''}
      <p>Export: <a id="export-csv" href="/api/datasets/${esc(ds.id)}/data?format=csv" download="${esc(ds.id)}.csv">CSV</a> ·
        <a id="export-hdf5" href="/api/datasets/${esc(ds.id)}/data?format=hdf5" download="${esc(ds.id)}.h5">HDF5</a> ·
        <a href="#/models?dataset=${esc(ds.id)}">identify a model from it</a> · <a href="#/datasets">all datasets</a></p>
      <table id="block-table"><tr><th>block</th><th>kind</th><th class="num">frequency (Hz)</th><th class="num" title="whole cycles in the block: for an imported record, counted from the first crossing of the block's mean on the way up, so the part out of rest before it and the part cycle after the last crossing are outside the block (the models still run through them)">whole cycles</th><th class="num">start (s)</th><th class="num">stop (s)</th><th>axes</th><th title="stretches in no block: a rest, a ramp, the first cycle out of a rest">outside the blocks</th></tr>
      ${ds.blocks.map((b) => `<tr><td>${b.index ?? ''}</td><td>${esc(b.kind ?? '')}</td><td class="num">${blockFrequency(b)}</td><td class="num">${fmt(b.cycles)}</td>
        <td class="num">${fmt(b.start / ds.sample_rate_hz)}</td><td class="num">${fmt(b.stop / ds.sample_rate_hz)}</td><td>${(b.axes || ds.axes).join(', ')}</td>
        <td class="trimmed">${trimmedText(b)}</td></tr>`).join('')}</table></div>
    <div class="card"><div id="ts-chart"></div></div>
    <div class="card"><h2>Hysteresis loops per frequency block</h2><div id="loops" class="grid"></div></div>
  </div>`));
  renderLabels(root.querySelector('#dataset-labels'), 'datasets', ds, { signal: controller.signal,
    onSaved: (updated) => { root.querySelector('#dataset-name').textContent = updated.name; } });
  for (const [sel, fmtName] of [['#export-csv', 'csv'], ['#export-hdf5', 'h5']]) {
    root.querySelector(sel).addEventListener('click', (e) => {
      if (!localStorage.getItem('evcbench.token')) return;   // plain link works without a token
      e.preventDefault();
      download(`/datasets/${ds.id}/data?format=${fmtName === 'h5' ? 'hdf5' : 'csv'}`, `${ds.id}.${fmtName}`).catch((err) => showError(null, err));
    });
  }
  const data = await api(`/datasets/${encodeURIComponent(id)}/data?max_points=6000`, { signal: controller.signal });
  const axes = ds.axes.filter((a) => data[`u_${a}_v`]);
  const xs = data.t_s || data[`u_${axes[0]}_v`].map((_, i) => (i * data.stride) / ds.sample_rate_hz);
  charts.push(await lineChart(root.querySelector('#ts-chart'), {
    title: 'Time series', xs, xLabel: 'time (s)', yLabel: 'drive u (V)', y2Label: 'displacement x (µm)',
    series: [...axes.map((a) => ({ label: `u_${a} (V)`, values: data[`u_${a}_v`] })),
             ...axes.map((a) => ({ label: `x_${a} (µm)`, values: data[`x_${a}_um`], scale: 'y2' }))],
  }));
  // Loops: one chart per block (per axis driven), at full resolution within the block when small.
  const loops = root.querySelector('#loops');
  const blocks = ds.blocks.length ? ds.blocks : [{ start: 0, stop: ds.samples, axes }];
  const todo = [];
  for (const [i, b] of blocks.entries()) {
    const blockAxes = (b.axes || axes).filter((a) => axes.includes(a));
    const span = b.stop - b.start;
    const want = Math.max(1, Math.ceil(span / 3000));   // about 3000 points per loop
    let arrays = data; let offset = Math.floor(b.start / data.stride);
    let count = Math.floor(span / data.stride); let step = Math.max(1, Math.round(want / data.stride));
    if (data.stride > 1 && span > 0 && b.start < ds.samples && span / data.stride < 400) {  // too coarse: fetch the block alone
      arrays = await blockData(id, b.start, b.stop); offset = 0; count = arrays.t_s.length; step = 1;
    }
    for (const a of blockAxes) {
      const u = []; const x = [];
      for (let k = offset; k < offset + count; k += step) { u.push(arrays[`u_${a}_v`][k]); x.push(arrays[`x_${a}_um`][k]); }
      const el = document.createElement('div');
      el.className = 'loop';
      el.dataset.block = String(i);
      el.dataset.axis = a;
      el.dataset.frequencyHz = String(b.frequency_hz ?? '');
      loops.append(el);
      todo.push([el, { title: `${b.frequency_hz ? `${fmt(b.frequency_hz)} Hz` : (b.kind || 'block')} · axis ${a}${b.cycles ? ` · ${fmt(b.cycles)} cycles` : ''}`,
        curves: [{ label: `x_${a} vs u_${a}`, x: u, y: x }], xLabel: `u_${a} (V)`, yLabel: `x_${a} (µm)`, height: 260 }]);
    }
  }
  for (const [el, spec] of todo) charts.push(await xyChart(el, spec));   // after layout: each knows its width
}

// One block at about 3000 points per column (the service decimates the samples start:stop).
function blockData(id, start, stop) {
  return api(`/datasets/${encodeURIComponent(id)}/data?start=${start}&stop=${stop}&max_points=3000`, { signal: controller.signal });
}

export function leave() {
  if (controller) controller.abort();
  destroyAll(charts);
}
