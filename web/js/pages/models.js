// Models — the discovery story: Identify (a form); Compare (measured vs model over time and as a
// loop, the residual, a per-frequency table in the layout of the paper's Table 6); Diagnosis (where
// it fails, shaded on the plots; ranked candidate effects with their evidence); Add effect (a refine
// job; the error-history chart of validation RMS per model version); Separate (the experiment that
// tells two candidates apart, where the diagnosis offers one).
import { api, download, esc, fmt, fmtErrorNm, has } from '../api.js';
import { lineChart, xyChart, destroyAll } from '../charts.js';
import { h, runJob, showError } from '../ui.js';
import { renderLabels } from '../labels.js';
import { renderEffects } from '../effects.js';
import { paperFigures, table6 } from '../paper.js';
import { importedIds, isImported, modelBenchHtml, modelOriginHtml, onImportedData } from '../provenance.js';
import { renderDiagnosis, showLastSeparation } from './diagnosis.js';
import { renderDiscover } from './discover.js';

const charts = [];
let controller = null;


export async function enter(root, [modelId], query = {}) {
  controller = new AbortController();
  const signal = controller.signal;
  const [models, datasets, effects] = await Promise.all(
    [api('/models', { signal }), api('/datasets', { signal }), api('/effects', { signal })]);
  const chosen = firstChoice(identifiable(datasets), query.dataset, models.find((m) => m.id === modelId));
  root.append(h(`<div>
    <h1>Models</h1>
    <div class="grid-1-2">
      <div class="card"><h2>Identify</h2>
        <form id="identify-form" class="inline">
          <label>axis <select name="axis"><option>y</option><option>z</option></select></label>
          <label>model <select name="model"><option value="static_pi">static PI</option><option value="dynamic_pi">dynamic PI</option><option value="grpi">GRPI</option>
            <option value="composite" title="hysteresis with the effects the tracking recipe's feedforward models have (GET /api/trajectories/recipe)">composite (the tracking recipe's effects)</option>
            <option value="hysterons" title="a wider rate-independent base than play operators: draws loops Prandtl–Ishlinskii cannot">hysterons (wider base)</option></select></label>
          <label>operators <input name="n_operators" type="number" min="1" max="100" step="1" value="10"></label>
          <label>datasets (Ctrl-click for several) <select name="datasets" id="identify-datasets" multiple size="4" style="min-width:320px">
            ${identifiable(datasets).map((d) => `<option value="${esc(d.id)}"${chosen.has(d.id) ? ' selected' : ''}${d.experiment_of ? ' data-experiment="1"' : ''}>${esc(d.id)} · ${esc(d.name)}${d.experiment_of ? ' (an experiment)' : ''}</option>`).join('')}
          </select></label>
          <button class="primary" type="submit" id="identify-start">Identify</button>
        </form>
        <div id="identify-job"></div><div id="identify-error"></div>
      </div>
      <div class="card"><h2>Stored models</h2><div class="scroll-list"><table id="model-list"></table></div></div>
    </div>
    <div id="effects"></div>
    <div id="model-detail"></div>
  </div>`));
  renderModelList(root.querySelector('#model-list'), models, modelId);
  renderEffects(root.querySelector('#effects'), effects);
  root.querySelector('#identify-form').addEventListener('submit', (e) => { e.preventDefault(); identify(root); });
  if (modelId) await showModel(root.querySelector('#model-detail'), modelId, query);
}

/** The datasets a model can be identified on, newest first: those with blocks (a tracking run's
 * record has none, so it is not offered, nor selected first). */
const identifiable = (datasets) => datasets.slice().reverse().filter((d) => d.n_blocks > 0);

/** The ids Identify selects first among `offered` (newest first): the dataset the address names, else
 *  the datasets of the model in view, else the newest the user made (a sweep or an import, not an
 *  experiment a diagnosis or a discover run made), else the newest. */
function firstChoice(offered, named, model) {
  if (named) return new Set([named]);
  const ids = new Set(offered.map((d) => d.id));
  const own = model ? model.datasets.filter((id) => ids.has(id)) : [];
  if (own.length) return new Set(own);
  const made = offered.find((d) => !d.experiment_of) || offered[0];
  return new Set(made ? [made.id] : []);
}

function renderModelList(table, models, modelId) {
  table.innerHTML = `<tr><th>model</th><th>axis</th><th>kind</th><th>effects</th><th>parent</th>
    <th class="num" title="the mean of per-block held-out RMS (the fit's own training RMS is on the model's page)">held-out RMS</th><th title="the bench its data were recorded on; imported data: another stage (the bench that stores it in brackets)">recorded on</th><th title="the stage its data were recorded on">fitted on</th></tr>` + models.slice().reverse().map((m) => `
    <tr data-model-id="${esc(m.id)}"${m.id === modelId ? ' class="best"' : ''}><td><a href="#/models/${esc(m.id)}">${esc(m.id)}</a>${m.name ? ` <span class="model-name" title="${esc(m.name)}">“${esc(m.name)}”</span>` : ''}${(m.tags || []).map((t) => ` <span class="tag">${esc(t)}</span>`).join('')}</td><td>${m.axis}</td><td>${esc(m.kind)}</td>
      <td>${m.effects.map(esc).join(' + ')}</td><td class="parent">${esc(m.parent_id || '')}</td>
      <td class="num">${fmtErrorNm(m.metrics.validation_rms_um, 4)}</td>
      <td class="bench" data-recorded-here="${(m.origin?.fitted_on || 'this_bench') === 'this_bench' ? 1 : 0}">${modelBenchHtml(m)}</td><td class="origin" data-fitted-on="${esc(m.origin?.fitted_on || '')}">${modelOriginHtml(m)}</td></tr>`).join('');
}

async function identify(root) {
  const form = root.querySelector('#identify-form');
  const f = new FormData(form);
  const err = root.querySelector('#identify-error');
  err.textContent = '';
  const body = { axis: f.get('axis'), model: f.get('model'), n_operators: Number(f.get('n_operators')),
                 datasets: f.getAll('datasets'), effects: ['hysteresis'] };
  const button = root.querySelector('#identify-start');
  button.disabled = true;
  try {
    if (body.model === 'composite') body.effects = (await api('/trajectories/recipe', { signal: controller.signal })).effects;
    const job = await runJob(root.querySelector('#identify-job'), '/models', body, 'identify', { signal: controller.signal });
    if (job.state === 'succeeded') {
      const id = job.result.model_id;
      root.querySelector('#identify-job').append(h(`<p class="ok" id="identify-done" data-model-id="${esc(id)}">Model
        <a href="#/models/${esc(id)}">${esc(id)}</a> identified: held-out RMS ${fmtErrorNm(job.result.validation_rms_um, 4)}.</p>`));
      openModel(id);
    } else showError(err, new Error(job.error || `identification ${job.state}`));
  } catch (e) {
    showError(err, e);
  } finally {
    button.disabled = false;
  }
}

/** Move the page to model `id` (a job's new model): its route, and so its page, rendered anew. */
function openModel(id) {
  const target = `#/models/${id}`;
  if (location.hash === target) window.dispatchEvent(new HashChangeEvent('hashchange'));   // the same route: render it again
  else location.hash = target;
}

async function showModel(el, modelId, query) {
  const signal = controller.signal;
  const model = await api(`/models/${encodeURIComponent(modelId)}`, { signal });
  const datasetId = query.dataset && model.datasets.includes(query.dataset) ? query.dataset : (query.dataset || model.datasets[0]);
  const [canDiagnose, canRefine, canHistory] = await Promise.all([
    has('GET /api/models/{model_id}/diagnosis'), has('POST /api/models/{model_id}/refine'), has('GET /api/models/{model_id}/history')]);
  el.append(h(`<div>
    <div class="card"><h2>Model <span id="model-id">${esc(model.id)}</span> <span id="model-name">${model.name ? `“${esc(model.name)}”` : ''}</span> <span class="muted">axis ${model.axis} · ${esc(model.kind)} ·
      ${model.effects.map(esc).join(' + ')}${model.parent_id ? ` · refined from <a href="#/models/${esc(model.parent_id)}">${esc(model.parent_id)}</a>` : ''}</span></h2>
      <p id="model-origin" data-fitted-on="${esc(model.origin?.fitted_on || '')}">Fitted on ${modelOriginHtml(model)}${onImportedData(model) ? ' — it may not describe this bench' : ''}.</p>
      <p><span title="the mean over the model's blocks of each block's held-out RMS, every block counting equally">Mean of per-block held-out RMS</span>${blockCount(model) ? ` <span class="muted" id="model-validation-blocks">(the stored model's, over the ${blockCount(model)} blocks it was evaluated on)</span>` : ''} <b id="model-validation-rms" data-value="${model.metrics.validation_rms_um}">${fmtErrorNm(model.metrics.validation_rms_um, 4)}</b>
        · training RMS ${fmtErrorNm(model.metrics.train_rms_um, 4)}${withoutLines(model.metrics.without_lines)} · datasets ${model.datasets.map((d) => `<a href="#/datasets/${esc(d)}">${esc(d)}</a>`).join(', ')}</p>
      <div class="row"><label>compare with dataset <select id="compare-dataset"></select></label>
        <button id="report-download" title="one self-contained HTML file: data, lineage, diagnosis, parameters, figures, the commands that reproduce it; print it for a PDF">Report (HTML)</button>
        <span id="report-status" class="muted"></span></div>
      <div id="model-answer" class="answer"><p class="muted">Diagnosing…</p></div>
      <p class="muted jump">On this page: <a href="#diagnosis-card" data-jump>diagnosis</a> · <a href="#discover" data-jump>discover</a> ·
        <a href="#history-chart" data-jump>error history</a> · <a href="#compare-table" data-jump>compare with the measurements</a></p>
      <details id="model-labels-box"><summary>name, tags, notes</summary><div id="model-labels"></div></details>
    </div>
    <div id="discover"></div>
    <div class="grid-1-2">
      <div class="card"><h2>Error history <span class="muted">(held-out RMS per lineage step; step 0 is the first model)</span></h2><div id="history-chart"></div><div id="history-table"></div></div>
      <div class="card" id="diagnosis-card"><h2>Diagnosis</h2><div id="diagnosis"></div><div id="refine-job"></div><div id="separate-job"></div></div>
    </div>
    <div class="card"><h2>Compare: measured vs model</h2><div id="compare-table"></div>
      <div id="compare-time"></div><div class="grid"><div id="compare-loop"></div><div id="compare-residual"></div></div></div>
  </div>`));
  const select = el.querySelector('#compare-dataset');
  const all = await api('/datasets', { signal });
  select.innerHTML = all.filter((d) => d.axes.includes(model.axis)).reverse().map((d) =>
    `<option value="${esc(d.id)}"${d.id === datasetId ? ' selected' : ''}>${esc(d.id)} · ${esc(d.name)}${model.datasets.includes(d.id) ? ' (fitted)' : ''}</option>`).join('');
  select.addEventListener('change', () => { location.hash = `#/models/${model.id}?dataset=${select.value}`; });
  el.querySelector('#report-download').addEventListener('click', () => downloadReport(el, model.id));
  el.querySelectorAll('a[data-jump]').forEach((a) => a.addEventListener('click', (e) => {   // in-page, not a route
    e.preventDefault();
    el.querySelector(a.getAttribute('href'))?.scrollIntoView({ behavior: 'smooth', block: 'start' });
  }));
  renderLabels(el.querySelector('#model-labels'), 'models', model, { signal, onSaved: async (updated) => {
    el.querySelector('#model-name').textContent = updated.name ? `“${updated.name}”` : '';
    const list = document.querySelector('#model-list');
    if (list) renderModelList(list, await api('/models', { signal }), model.id);
  } });
  if (await has('POST /api/models/{model_id}/discover')) {
    const imported = onImportedData(model, importedIds(all));
    renderDiscover(el.querySelector('#discover'), model, { signal, imported, onModels: async () => {
      const list = document.querySelector('#model-list');
      if (list) renderModelList(list, await api('/models', { signal }), model.id);
    } });
  }

  // Diagnosis first (its failure ranges shade the compare plots), then history and compare.
  let diagnosis = null;
  if (canDiagnose) {
    el.querySelector('#diagnosis').innerHTML = '<p class="muted" id="diagnosis-wait">Diagnosing: every candidate effect is fitted in turn on the held-out cycles…</p>';
    try {
      diagnosis = await api(`/models/${encodeURIComponent(model.id)}/diagnosis${datasetId ? `?dataset=${encodeURIComponent(datasetId)}` : ''}`, { signal });
      // the answer on the first screen follows the diagnosis shown (after a Separate, the one with its data)
      const opts = { canRefine, signal, jobBox: el.querySelector('#separate-job'), onAdd: (effect, extra) => refine(el, model, effect, extra),
        onDiagnosis: (shown, extra) => renderAnswer(el.querySelector('#model-answer'), model, shown, extra) };
      renderDiagnosis(el.querySelector('#diagnosis'), model, diagnosis, opts);
      await showLastSeparation(el.querySelector('#diagnosis'), model, diagnosis, all, opts);   // its result kept over a reload
    } catch (e) { showError(el.querySelector('#diagnosis'), e, 'Diagnosis failed: '); }
  } else {
    el.querySelector('#diagnosis').innerHTML = '<p class="muted">This service does not offer a diagnosis yet (GET /api/models/{id}/diagnosis).</p>';
  }
  if (!diagnosis) renderAnswer(el.querySelector('#model-answer'), model, null);
  await renderHistory(el, model, canHistory);
  if (datasetId) await renderCompare(el, model, datasetId, diagnosis);
}

/** How many blocks the stored held-out mean covers (its datasets' blocks it was evaluated on), or 0. */
/** The held-out RMS with the lines the gauge showed at rest taken out (the figure the diagnosis and a
 * discover step give), labelled as such; nothing where the rests showed no line. */
const withoutLines = (w) => (w ? ` · <span id="model-validation-without-lines" data-value="${w.validation_rms_um}">held-out RMS
  <b>${fmtErrorNm(w.validation_rms_um, 4)}</b> <span class="muted">with the ${(w.lines_hz || []).map((f) => `${fmt(f, 4)} Hz`).join(', ')}
  line${(w.lines_hz || []).length === 1 ? '' : 's'} seen at rest taken out: the records the diagnosis and discover judge on</span></span>` : '');

const blockCount = (model) => (model.metrics.per_dataset || []).reduce((n, d) => n + (d.blocks || []).length, 0);

/** The page's answer on its first screen: how far the model is from the noise floor, then the
 *  diagnosis's answer (one stored value: what is missing and the error it should fall to, and what
 *  remains described), the same value the verdict and the remainder's section read. */
function renderAnswer(box, model, d, extra = []) {
  if (!d || !d.answer) { box.innerHTML = '<p class="muted">No diagnosis: see the compare table below.</p>'; return; }
  const ratio = d.noise_floor_um ? d.residual_rms_um / d.noise_floor_um : null;
  const a = d.answer;
  // after a Separate, the diagnosis shown is of the model's data and the experiment's: say so, beside the
  // stored model's own figure (a walk read 205.5 nm here under a header of 147.3 nm, nothing joining them)
  const on = extra.length ? ` <span class="muted" id="model-answer-extra">on the model's datasets and the experiment's ${esc(extra.join(', '))};
    the stored model's own held-out RMS, on its own datasets, is ${fmtErrorNm(model.metrics.validation_rms_um, 4)}</span>` : '';
  const where = `Held-out RMS ${fmtErrorNm(d.residual_rms_um, 4)}${d.residual_of ? ` <span class="muted" id="model-answer-of">(${esc(d.residual_of)})</span>` : ''}${on}${ratio ? `, ${fmt(ratio, 3)}× the noise floor (${fmtErrorNm(d.noise_floor_um, 4)})` : ''}.`;
  const how = !a.missing ? '' : (a.ambiguous_with
    ? ` The diagnosis below offers the experiment that separates them; “Add ${esc(a.missing)}” adds the leading claim, and Discover stops here unless “at an ambiguity, add the leading effect and go on” is ticked.`
    : ` Use “Add ${esc(a.missing)}” in the diagnosis, or Discover.`);
  box.innerHTML = `<p id="model-answer-text" data-ratio="${ratio ?? ''}" data-effect="${esc(a.missing || '')}"
    data-remains="${esc(a.remains || '')}">${where} ${esc(a.text)}${how}</p>`;
}

/** Where the diagnosis says the model fails, as plot ranges: time ranges of the failing blocks (for
 *  the time plots; the block the failure names by index, else the first at its frequency) and drive
 *  ranges (for the loop), from the failure's fields or words. */
function failureRanges(diagnosis, compared, datasetBlocks) {
  const time = []; const drive = [];
  if (!diagnosis || !Array.isArray(diagnosis.failures)) return { time, drive };
  const rate = compared.sample_rate_hz;
  // the dataset's block table: it also holds the other axis's blocks, where the diagnosis may name coupling
  const blocks = datasetBlocks || compared.metrics.per_block || [];
  for (const f of diagnosis.failures) {
    if (!f || typeof f !== 'object') continue;
    if (f.dataset_id && f.dataset_id !== compared.dataset_id) continue;
    const where = String(f.where || f.text || '');
    const named = where.match(/\bds_[0-9a-f]+/);
    if (named && named[0] !== compared.dataset_id) continue;   // a place in another dataset
    const t0 = f.t_start_s ?? f.start_s; const t1 = f.t_stop_s ?? f.stop_s;
    if (t0 !== undefined && t1 !== undefined) { time.push([t0, t1]); continue; }
    const hz = f.frequency_hz ?? (where.match(/([0-9.]+) Hz block/) || [])[1];
    if (hz !== undefined) {
      // the block the failure names (a sweep of both axes one after the other has two blocks per frequency)
      const block = (f.block_index ?? null) !== null ? blocks.find((b) => b.index === f.block_index)
        : blocks.find((b) => Math.abs(b.frequency_hz - Number(hz)) < 1e-9);
      if (block && block.start !== undefined) time.push([block.start / rate, block.stop / rate]);
      continue;
    }
    const above = where.match(/u > ([0-9.]+) V/); const below = where.match(/u < ([0-9.]+) V/);
    if (above) drive.push([Number(above[1]), Infinity]);
    if (below) drive.push([-Infinity, Number(below[1])]);
  }
  return { time, drive };
}

/** Save GET /api/models/{id}/report as <id>-report.html (fetched with the token; it runs a diagnosis). */
async function downloadReport(el, modelId) {
  const button = el.querySelector('#report-download');
  const status = el.querySelector('#report-status');
  button.disabled = true;
  status.classList.remove('error');
  status.textContent = 'building the report (it runs a diagnosis)…';
  try {
    await download(`/models/${encodeURIComponent(modelId)}/report?download=true`, `${modelId}-report.html`);
    status.textContent = `saved ${modelId}-report.html (print it from the browser for a PDF)`;
  } catch (e) { showError(status, e, 'Report failed: '); } finally { button.disabled = false; }
}

async function refine(el, model, effect, datasets = []) {
  const out = el.querySelector('#refine-job');
  el.querySelectorAll('.add-effect').forEach((b) => { b.disabled = true; });
  try {
    const job = await runJob(out, `/models/${encodeURIComponent(model.id)}/refine`,
      datasets.length ? { add: effect, datasets } : { add: effect }, `add ${effect}`, { signal: controller.signal });
    if (job.state === 'succeeded') {
      const child = job.result.model_id;
      out.append(h(`<p class="ok" id="refined" data-model-id="${esc(child)}">Added ${esc(effect)}: model <a href="#/models/${esc(child)}">${esc(child)}</a>.</p>`));
      openModel(child);   // the new model's page: its diagnosis, its error history, its row marked in the list
    } else {
      showError(out.appendChild(document.createElement('p')), new Error(job.error || `refine ${job.state}`));
    }
  } catch (e) {
    showError(out.appendChild(document.createElement('p')), e);
  } finally {
    el.querySelectorAll('.add-effect').forEach((b) => { b.disabled = false; });
  }
}

async function lineage(model, canHistory) {
  if (canHistory) {
    const r = await api(`/models/${encodeURIComponent(model.id)}/history`, { signal: controller.signal });
    const steps = Array.isArray(r) ? r : (r.history || r.lineage || r.steps || r.models || []);
    // the API names each step's change, a refit on more data too (its held-out RMS is over other cycles)
    // like for like: every step scored on the last model's data (refitted there after a step added data)
    return steps.map((s) => ({ id: s.model_id || s.id, effects: s.effects || [],
      rms: s.validation_rms_um ?? s.metrics?.validation_rms_um, same: s.like_for_like_rms_um ?? null, change: s.change || null }));
  }
  // Without the endpoint: walk parent_id.
  const steps = [];
  let m = model;
  while (m) {
    steps.unshift({ id: m.id, effects: m.effects, rms: m.metrics.validation_rms_um });
    m = m.parent_id ? await api(`/models/${encodeURIComponent(m.parent_id)}`, { signal: controller.signal }) : null;
  }
  return steps;
}

async function renderHistory(el, model, canHistory) {
  let steps;
  try { steps = await lineage(model, canHistory); } catch (e) { showError(el.querySelector('#history-table'), e); return; }
  const chartEl = el.querySelector('#history-chart');
  if (!chartEl || !chartEl.isConnected) return;  // the user left the page while the lineage was computed
  chartEl.dataset.values = JSON.stringify(steps.map((s) => s.rms));
  chartEl.dataset.likeForLike = JSON.stringify(steps.map((s) => s.same));
  chartEl.dataset.models = JSON.stringify(steps.map((s) => s.id));
  chartEl.dataset.points = String(steps.length);
  const old = charts.find((c) => c.root && chartEl.contains(c.root));
  if (old) { old.destroy(); charts.splice(charts.indexOf(old), 1); }
  charts.push(await lineChart(chartEl, { xs: steps.map((_, i) => i), xLabel: 'lineage step (0: the first model)',
    yLabel: 'held-out RMS (nm)', series: [
      { label: 'like for like: every step on the same data (nm)', values: steps.map((s) => (s.same ?? s.rms) * 1e3), points: true, width: 2 },
      ...(steps.some((s) => s.same !== null && s.same !== s.rms)
        ? [{ label: 'as fitted, on the data of its step (nm)', values: steps.map((s) => s.rms * 1e3), points: true, width: 1 }] : [])],
    height: 220, points: true, integerX: true, liveLegend: false }));   // the values: the table below
  const table = el.querySelector('#history-table');
  if (!table) return;
  table.innerHTML = `<table id="history"><tr><th title="0: the lineage's first model, as a discover run's step 0 is the model it starts from">step</th><th>model</th><th>change</th><th class="num">held-out RMS</th><th class="num">like for like</th></tr>
    ${steps.map((s, i) => `<tr data-rms="${s.rms}" data-like-for-like="${s.same ?? ''}" title="${esc((s.effects || []).join(' + '))}"><td>${i}</td><td><a href="#/models/${esc(s.id)}">${esc(s.id)}</a></td>
      <td>${esc(s.change || (i ? '' : 'first fit'))}</td><td class="num">${fmtErrorNm(s.rms, 4)}</td><td class="num">${fmtErrorNm(s.same, 4)}</td></tr>`).join('')}</table>`;
}

/** Where the largest |error| falls (the compare's `max_abs_at_s`, over every sample, not the decimated
 * arrays): a start transient's figure (13070 nm at the first sample of an import whose held-out max is
 * 929 nm) reads as one. */
function whereMax(o) {
  const t = o.max_abs_at_s;
  if (t === null || t === undefined) return '';
  return ` <span class="muted" id="compare-max-at" data-t-s="${t}">(at t = ${fmt(t, 4)} s${t === 0 ? ', the first sample' : ''})</span>`;
}

async function renderCompare(el, model, datasetId, diagnosis) {
  const signal = controller.signal;
  let c;
  try {
    c = await api(`/models/${encodeURIComponent(model.id)}/compare?dataset=${encodeURIComponent(datasetId)}&max_points=4000`, { signal });
  } catch (e) { showError(el.querySelector('#compare-table'), e, 'Compare failed: '); return; }
  const ds = await api(`/datasets/${encodeURIComponent(datasetId)}`, { signal });
  // per_block rows carry no sample range: take it from the dataset's blocks (same index).
  for (const b of c.metrics.per_block) {
    const block = ds.blocks.find((x) => x.index === b.index);
    if (block) { b.start = block.start; b.stop = block.stop; }
  }
  const ranges = failureRanges(diagnosis, c, ds.blocks);
  const axis = model.axis;
  // Table 6 (RMS µm: dynamic PI / GRPI / static PI) is the paper's device: beside data recorded here, not an import
  const showPaper = !isImported(ds);
  const paper = showPaper ? table6(await paperFigures(signal), axis) : {};
  const nm = (um) => (um === null || um === undefined ? '–' : fmt(um * 1e3));  // errors in nm, the one unit for them
  const paperCells = (p) => (showPaper ? p.concat([null, null, null]).slice(0, 3).map((v) => `<td class="num paper">${nm(v)}</td>`).join('') : '');
  const o = c.metrics.overall;
  el.querySelector('#compare-table').innerHTML = `<p>Dataset <a href="#/datasets/${esc(datasetId)}">${esc(datasetId)}</a>
    (${c.used_in_fit ? 'used in the fit: the held-out cycles are unseen' : 'not used in the fit: all of it is unseen'}) ·
    RMS over every sample of the blocks that drive ${axis.toUpperCase()} (training and held-out cycles; the table's held-out figures are per block) <b id="compare-overall-rms" data-value="${o.rms_um}">${fmtErrorNm(o.rms_um, 4)}</b> · max |e| <b id="compare-max-abs" data-value="${o.max_abs_um}">${fmtErrorNm(o.max_abs_um, 4)}</b>${whereMax(o)} · fit ${fmt(o.fit_pct, 4)} %</p>
    <table id="table6"><tr><th rowspan="2">axis</th><th rowspan="2" class="num">frequency (Hz)</th>
      <th colspan="4">this model (${esc(model.kind)}${model.effects.length > 1 ? ' + ' + model.effects.filter((e) => e !== 'hysteresis').map(esc).join(' + ') : ''})</th>
      ${showPaper ? '<th colspan="3">paper, Table 6: RMS (nm)</th>' : ''}</tr>
      <tr><th class="num">held-out RMS (nm)</th><th class="num">training RMS (nm)</th><th class="num">max |e| (nm)</th><th class="num">fit (%)</th>
      ${showPaper ? '<th class="num">dynamic PI</th><th class="num">GRPI</th><th class="num">static PI</th>' : ''}</tr>
      ${c.metrics.per_block.map((b) => { const p = paper[b.frequency_hz] || []; const held = b.validation || b.heldout || b.train; return `<tr data-frequency-hz="${b.frequency_hz}" data-rms="${held?.rms_um}">
        <td>${axis.toUpperCase()}</td><td class="num">${fmt(b.frequency_hz)}</td>
        <td class="num rms">${nm(held?.rms_um)}</td><td class="num">${nm(b.train?.rms_um)}</td><td class="num">${nm(held?.max_abs_um)}</td><td class="num">${fmt(held?.fit_pct, 4)}</td>
        ${paperCells(p)}</tr>`; }).join('')}
    </table>${showPaper ? '' : '<p class="muted" id="table6-omitted">Imported data: the paper\'s Table 6 describes its own device, so it is not shown beside another stage\'s record.</p>'}${ranges.time.length + ranges.drive.length ? `<p class="warn" id="failure-shading" data-time-ranges="${ranges.time.length}" data-drive-ranges="${ranges.drive.length}" data-time-spans-s="${esc(JSON.stringify(ranges.time))}">Shaded red: where the diagnosis says the model fails (${ranges.time.length} block${ranges.time.length === 1 ? '' : 's'} in time, ${ranges.drive.length} drive range${ranges.drive.length === 1 ? '' : 's'} on the loop).</p>` : ''}`;
  charts.push(await lineChart(el.querySelector('#compare-time'), { title: 'Displacement over time', xs: c.t_s, xLabel: 'time (s)',
    yLabel: `x_${axis} (µm)`, series: [{ label: 'measured (µm)', values: c.x_measured_um }, { label: 'model (µm)', values: c.x_predicted_um }],
    shade: ranges.time, height: 260 }));
  charts.push(await xyChart(el.querySelector('#compare-loop'), { title: 'Loop: displacement vs drive', xLabel: `u_${axis} (V)`, yLabel: `x_${axis} (µm)`,
    curves: [{ label: 'measured', x: c.u_v, y: c.x_measured_um }, { label: 'model', x: c.u_v, y: c.x_predicted_um }], height: 280,
    xShade: ranges.drive }));
  charts.push(await lineChart(el.querySelector('#compare-residual'), { title: 'Residual (measured − model)', xs: c.t_s, xLabel: 'time (s)',
    yLabel: 'residual (nm)', series: [{ label: 'residual (nm)', values: c.residual_um.map((v) => v * 1e3), color: '#c2255c' }], shade: ranges.time, height: 280 }));
}

export function leave() {
  if (controller) controller.abort();
  destroyAll(charts);
}
