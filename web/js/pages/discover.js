// Models page, the discovery story in one place (issue 20 §2): the Discover job (POST
// /api/models/{id}/discover) followed step by step over its event stream; the report's own figures
// (GET /api/models/{id}/report/figures: the error history and the per-block loop and residual,
// the block with the largest held-out RMS marked) inlined; and two models of the lineage compared block
// by block (GET /api/models/{id}/compare?arrays=false on each dataset).
import { api, esc, fmt, fmtErrorNm } from '../api.js';
import { h, runJob, showError } from '../ui.js';

// The form's checkboxes by the API parameter each sets: the job's texts name the parameters, the page
// shows the labels a user ticks (the parameter kept in brackets).
const CHECKBOXES = {
  allow_experiments: 'run the experiments it needs on the bench',
  continue_past_ambiguity: 'at an ambiguity, add the leading effect and go on',
};

/** `text` (HTML-escaped) with each API parameter a checkbox sets shown as “its label” ticked. */
export const pageWords = (text) => esc(text).replace(/\b(allow_experiments|continue_past_ambiguity)\b/g,
  (name) => `“${CHECKBOXES[name]}” ticked <span class="muted">(${name})</span>`);

/** The Discover, Figures and Compare cards for `model`, appended to `el`. */
export function renderDiscover(el, model, { signal, imported = false, onModels = () => {} }) {
  // A model of imported data describes another stage: its experiments run there, never on this bench.
  const experiments = imported
    ? '<span class="muted" id="experiments-elsewhere-note">the data was recorded on another stage: the experiments it needs are shown to run there</span>'
    : `<label class="check"><input type="checkbox" name="allow_experiments"> ${CHECKBOXES.allow_experiments}</label>`;
  const box = h(`<div>
    <div class="card" id="discover-card"><h2>Discover <span class="muted">(diagnose, add the top claimed effect, refit; until the
      verdict is complete, then more capacity while it validates and the model is not at the noise floor)</span></h2>
      <form id="discover-form" class="inline">
        <label>max steps <input name="max_steps" type="number" min="1" max="16" step="1" value="12"></label>
        ${experiments}
        <label class="check" title="Without it the loop stops where two look-alike effects explain the data equally well, and names the sweep that tells them apart"><input type="checkbox" name="continue_past_ambiguity"> ${CHECKBOXES.continue_past_ambiguity}</label>
        <button class="primary" type="submit" id="discover-start">Discover from ${esc(model.id)}</button>
        <button type="button" id="discover-cancel" hidden title="the fit at work stops at its next solve; the steps done are kept">Cancel the run</button>
      </form>
      <div id="discover-job"></div>
      <div id="discover-run"></div>
    </div>
    <div class="card" id="figures-card"><h2>Figures <span class="muted" id="figures-of"></span></h2>
      <div class="row"><button type="button" id="figures-load">Show the figures of ${esc(model.id)}</button>
        <span class="muted" id="figures-status"></span></div>
      <div id="figures-history"></div><div id="figures-blocks" class="small-multiples"></div>
    </div>
    <div class="card" id="lineage-compare"><h2>Compare two models of the lineage, block by block</h2>
      <div class="row"><label>model A <select id="compare-a"></select></label><label>model B <select id="compare-b"></select></label>
        <button type="button" id="compare-run">Compare</button></div>
      <div id="compare-models"></div>
    </div>
  </div>`);
  el.append(box);
  const state = { figures: null, steps: [], start: model.id };
  const figures = (id) => showFigures(box, id, state, signal);
  box.querySelector('#figures-load').addEventListener('click', () => figures(model.id));
  box.querySelector('#discover-form').addEventListener('submit', (e) => {
    e.preventDefault();
    discover(box, model, state, { signal, imported, onModels, figures });
  });
  box.querySelector('#compare-run').addEventListener('click', () => compareModels(box, state, signal));
  box.querySelector('#discover-run').addEventListener('click', (e) => {
    const b = e.target.closest('button[data-figures]');
    if (b) figures(b.dataset.figures);
  });
  // the lineage up to the last run's final model (this model's later steps too), else up to this model
  const lineage = (id) => fillLineage(box, id, state, signal).catch((e) => {
    if (id === model.id) showError(box.querySelector('#compare-models'), e);
    else return lineage(model.id);   // the run's final model is gone: this model's own lineage
  });
  restoreLastRun(box, model, { signal, imported })
    .catch((e) => { showError(box.querySelector('#discover-run'), e); return null; })
    .then((job) => { if (!signal?.aborted && !state.ran) return lineage(job?.result?.final_model_id || model.id); });
}

/** The last discover run that started from `model` or ended at it (GET /api/jobs?kind=discover&model_id=,
 * this model's runs alone), else the run that stored it (a middle step: its `job_id`), shown again after a
 * reload or a visit to another page: a run's answer outlives the page that started it. A run still queued
 * has no steps yet: the newest with steps is shown. */
async function restoreLastRun(box, model, { signal, imported }) {
  const jobs = await api(`/jobs?kind=discover&model_id=${encodeURIComponent(model.id)}&limit=5`, { signal });
  let job = jobs.find((j) => j.result?.steps);
  if (!job && model.job_id) {
    const own = await api(`/jobs/${encodeURIComponent(model.job_id)}`, { signal }).catch(() => null);
    if (own?.kind === 'discover' && own.result?.steps) job = own;
  }
  const out = box.querySelector('#discover-run');
  if (!job || signal?.aborted || out.childElementCount) return null;   // none, or a run started here meanwhile
  renderRun(out, job.result, { signal, imported });
  const when = job.finished_at || job.started_at || job.created_at;
  out.prepend(h(`<p class="muted" id="discover-restored" data-job-id="${esc(job.id)}">The last discover run from
    ${esc(job.params?.model_id || '')} (job ${esc(job.id)}, ${esc(job.state)}${when ? `, ${esc(when)}` : ''}).</p>`));
  return job;
}

async function discover(box, model, state, { signal, imported, onModels, figures }) {
  const f = new FormData(box.querySelector('#discover-form'));
  const body = { max_steps: Number(f.get('max_steps')), allow_experiments: f.get('allow_experiments') === 'on',
    continue_past_ambiguity: f.get('continue_past_ambiguity') === 'on' };
  const button = box.querySelector('#discover-start');
  const cancel = box.querySelector('#discover-cancel');
  cancel.disabled = false;
  cancel.textContent = 'Cancel the run';
  const out = box.querySelector('#discover-run');
  state.ran = true;   // this run fills the lineage selects when it ends, not the restored one
  button.disabled = true;
  out.replaceChildren();
  out.classList.remove('error');
  try {
    const job = await runJob(box.querySelector('#discover-job'), `/models/${encodeURIComponent(model.id)}/discover`, body,
      'discover', { signal, onUpdate: (j) => { offerCancel(cancel, j); if (j.result?.steps) renderRun(out, j.result, { signal, imported }); } });
    if (job.result?.steps) renderRun(out, job.result, { signal, imported });
    if (job.state !== 'succeeded') {
      showError(out.appendChild(document.createElement('p')), new Error(job.error || `discover ${job.state}`));
    }
    const last = job.result?.final_model_id;
    if (last) {
      await onModels();  // awaited: a refresh cut short by leaving the page is caught below
      await fillLineage(box, last, state, signal);
      await figures(last);
    }
  } catch (e) {
    showError(out.appendChild(document.createElement('p')), e, 'Discover failed: ');
  } finally {
    button.disabled = false;
    cancel.hidden = true;
  }
}

/** The Cancel button beside a running discover job `job` (DELETE /api/jobs/{id}): the run stops after
 *  the fit at work's next solve, its steps done kept (a walk found no way to stop a run from the page). */
function offerCancel(cancel, job) {
  cancel.hidden = !['queued', 'running'].includes(job.state);
  cancel.onclick = async () => {
    cancel.disabled = true;
    try {
      await api(`/jobs/${encodeURIComponent(job.id)}`, { method: 'DELETE' });
      cancel.textContent = 'Cancel requested: the fit at work stops at its next solve; the steps done are kept';
    } catch (e) {
      cancel.disabled = false;
      showError(cancel.parentElement.appendChild(document.createElement('p')), e, 'Cancel failed: ');
    }
  };
}

/** A parameter's unit after its value (" nm", " Hz"); none for a ratio (unit "1") or an unknown one. */
const unitText = (unit) => (unit && unit !== '1' ? ` ${esc(unit)}` : '');

const ratio = (r) => (r === null || r === undefined ? '–' : `${fmt(r, 3)}×`);

/** Whether the run's experiment that added dataset `id` was one recorded before for its model (joined, not run again). */
const reusedBefore = (r, id) => (r.experiments || []).some((x) => x.dataset_id === id && x.recorded_before);

/** The run so far (the job's partial result while it runs, then its result). `imported`: the model's
 * data came from another stage, so a suggested experiment is shown as the sweep to run there, with no button. */
function renderRun(out, r, { signal, imported }) {
  const steps = r.steps || [];
  const found = r.effects_found || [];
  const rem = r.remains;
  const suggested = r.suggested_experiments || [];
  const done = r.stopped && r.stopped !== 'running';
  out.innerHTML = `<h3>Steps</h3>
    <table id="discover-steps"><tr><th title="0: the model the run starts from, as the lineage's step 0 is its first model">step</th><th>added</th><th>model</th><th>effects</th><th class="num">held-out RMS</th>
      <th class="num" title="this step's effects refitted on every dataset the run has now (the experiments' too), scored on the same held-out cycles as every other step">like for like</th>
      <th class="num" title="the like-for-like fit (this step's effects refitted on every dataset the run has now) scored on the held-out cycles of the data the run started from: not the step's own fit, so it can differ from its held-out RMS on the same data">like for like, on the original data</th>
      <th class="num">noise floor</th><th class="num">× noise floor</th><th>verdict</th><th></th></tr>
    ${steps.map((s) => `<tr data-step="${s.step}" data-model-id="${esc(s.model_id)}" data-added="${esc(s.added || '')}" data-rms="${s.validation_rms_um}">
      <td>${s.step}</td><td>${s.replaced ? `<b>${esc(s.added)}</b> <span class="muted">in place of ${esc(s.replaced)} (the base's grid, compared at the loop's end)</span>` : s.added ? `<b>+${esc(s.added)}</b>` : (s.experiment_dataset_id ? `+data ${esc(s.experiment_dataset_id)} <span class="muted">(${reusedBefore(r, s.experiment_dataset_id) ? 'recorded before as this model\'s experiment, not run again; ' : ''}held-out RMS over more data; like for like beside it)</span>` : (s.step ? 'refit' : 'start'))}${!s.step && s.fit ? `<div class="muted step-fit">figures of ${esc(s.fit)}</div>` : ''}</td>
      <td><a href="#/models/${esc(s.model_id)}">${esc(s.model_id)}</a></td><td>${s.effects.map(esc).join(' + ')}</td>
      <td class="num">${fmtErrorNm(s.validation_rms_um)}</td>
      <td class="num like-for-like" data-rms="${s.like_for_like_rms_um ?? ''}">${fmtErrorNm(s.like_for_like_rms_um)}</td>
      <td class="num">${fmtErrorNm(s.original_data_rms_um)}</td><td class="num">${fmtErrorNm(s.noise_floor_um)}</td>
      <td class="num">${ratio(s.ratio_to_noise_floor)}</td><td>${esc(s.verdict)}${s.ambiguous ? ` <span class="warn">(${s.ambiguous.map(esc).join(' or ')}?)</span>` : ''}</td>
      <td><button type="button" data-figures="${esc(s.model_id)}">figures</button></td></tr>
      ${(s.not_kept || []).map((x) => `<tr class="not-kept" data-effect="${esc(x.effect)}"><td></td><td colspan="10" class="warn">tried next:
        ${esc(x.text)} (model <a href="#/models/${esc(x.model_id)}">${esc(x.model_id)}</a>)</td></tr>`).join('')}`).join('')}
    </table>
    ${(r.experiments || []).length ? `<p class="muted">Like for like: every step refitted and scored on ${esc((r.like_for_like_datasets || []).join(', '))};
      the same fits on the original data: ${esc((r.original_datasets || []).join(', '))}. Each step's own held-out RMS is of its own fit, on the data it had.</p>` : ''}
    ${done ? `<p id="discover-stopped" data-stopped="${esc(r.stopped)}">Stopped: <b>${esc(r.stopped.replace(/_/g, ' '))}</b>${r.stop_reason ? ` — ${pageWords(r.stop_reason)}` : ''}</p>` : '<p class="muted">running…</p>'}
    ${found.length ? `<h3>Effects found</h3><table id="discover-found"><tr><th>effect</th><th title="what the diagnosis offered it as when the run added it: physics, or model capacity (a loop-shape effect on a base that draws any loop shape). The report's parameter table gives its role in the final model, which a later wider base can change">added as</th><th>added at step</th><th>fitted parameters <span class="muted">(the stored model's)</span></th><th>evidence <span class="muted">(from the diagnosis's held-out test, a fit of its own)</span></th></tr>
      ${found.map((e) => `<tr data-effect="${esc(e.effect)}"><td><b>${esc(e.effect)}</b></td><td class="added-as">${esc(e.kind === 'capacity' ? 'model capacity' : 'physics')}</td><td>${e.added_at_step}</td>
        <td>${Object.entries(e.parameters || {}).map(([k, v]) => `<code>${esc(k)}</code> = ${Array.isArray(v) ? v.map((x) => fmt(x)).join(', ') : fmt(v)}${unitText(e.units?.[k])}`).join('<br>') || '–'}</td>
        <td class="evidence">${esc(e.evidence)}</td></tr>`).join('')}</table>` : ''}
    ${rem ? `<h3>What remains</h3><p id="discover-remains" data-ratio="${rem.ratio_to_noise_floor ?? ''}">Held-out RMS <b>${fmtErrorNm(rem.validation_rms_um)}</b>
      against a noise floor of ${fmtErrorNm(rem.noise_floor_um)}: ${ratio(rem.ratio_to_noise_floor)}${rem.at_noise_floor ? ', at the noise floor' : ''}.
      <span class="muted">${esc(rem.verdict_text || '')}</span></p>` : ''}
    ${suggested.length ? `<h3>${!r.needed_experiment ? 'Experiments it suggested' : r.stopped === 'needs_experiment' ? 'The experiment it needs' : 'The experiment that settles its guess'}</h3><ul id="discover-experiments">
      ${suggested.map((x, i) => `<li data-effects="${esc(x.effects.join(','))}">after step ${x.after_step}: ${pageWords(x.reason || '')}
        ${imported ? `<span class="muted">Run this sweep on the stage that recorded the data, then import the record and refine with it:</span>`
          : `<span class="muted">(not run: ${pageWords(x.not_run_because || '')})</span>`}
        ${x.experiment ? `<pre>${imported ? '' : 'POST /api/sweeps '}${esc(JSON.stringify(x.experiment))}</pre>` : ''}
        ${(x.cut_to_bench || []).length && !imported ? `<span class="muted">(cut to this bench's limits: ${esc(x.cut_to_bench.join('; '))})</span>` : ''}
        ${!x.experiment && x.not_runnable_here ? `<span class="muted">This bench cannot run it: ${pageWords(x.not_runnable_here)}.</span>` : ''}
        ${imported || x.skipped || !x.experiment ? '' : `<button type="button" class="run-experiment" data-i="${i}">Run this experiment (${esc(x.effects.join(' vs '))})</button>
        <div class="experiment-job"></div>`}</li>`).join('')}</ul>` : ''}`;
  out.querySelectorAll('.run-experiment').forEach((b) => b.addEventListener('click', async () => {
    const x = suggested[Number(b.dataset.i)];
    const jobBox = b.nextElementSibling;
    b.disabled = true;
    try {
      // its dataset keeps the model whose diagnosis proposed it (Identify does not preselect an experiment's)
      const by = (steps.find((s) => s.step === x.after_step) || {}).model_id;
      const body = by ? { ...x.experiment, experiment_of: { model_id: by, effects: x.effects.slice(0, 2) } } : x.experiment;
      const job = await runJob(jobBox, '/sweeps', body, `experiment for ${x.effects.join(', ')}`, { signal });
      const ds = job.result?.dataset_id;
      if (job.state === 'succeeded' && ds) {
        jobBox.append(h(`<p class="ok">Dataset <a href="#/datasets/${esc(ds)}">${esc(ds)}</a> recorded: refine with it, or
          Discover again with "run the experiments it needs" to fit on it.</p>`));
      } else showError(jobBox.appendChild(document.createElement('p')), new Error(job.error || `the sweep ${job.state}`));
    } catch (e) { showError(jobBox.appendChild(document.createElement('p')), e); } finally { b.disabled = false; }
  }));
}

/** Our own SVG (the report's figures), parsed as SVG and stripped of anything active before it joins the page. */
function safeSvg(text) {
  const doc = new DOMParser().parseFromString(text, 'image/svg+xml');
  const svg = doc.documentElement;
  if (svg.nodeName !== 'svg') throw new Error('the figure is not an SVG');
  svg.querySelectorAll('script, foreignObject, iframe').forEach((n) => n.remove());
  for (const n of [svg, ...svg.querySelectorAll('*')]) {
    for (const a of [...n.attributes]) {
      if (/^on/i.test(a.name) || (/href$/i.test(a.name) && !a.value.startsWith('#'))) n.removeAttribute(a.name);
    }
  }
  return document.importNode(svg, true);
}

async function showFigures(box, modelId, state, signal) {
  const status = box.querySelector('#figures-status');
  const button = box.querySelector('#figures-load');
  button.disabled = true;
  status.classList.remove('error');
  status.textContent = `drawing the figures of ${modelId} (it runs a diagnosis)…`;
  try {
    const f = await api(`/models/${encodeURIComponent(modelId)}/report/figures`, { signal });
    const [of, history, blocks] = ['#figures-of', '#figures-history', '#figures-blocks'].map((q) => box.querySelector(q));
    // the user left the page, or the panel was drawn again (a restored run), while the figures were drawn
    if (!box.isConnected || !of || !history || !blocks) return;
    state.figures = f;
    of.textContent = `of ${modelId} · noise floor ${fmtErrorNm(f.noise_floor_um)} · verdict ${f.verdict}`;
    history.replaceChildren(safeSvg(f.history_svg));
    history.dataset.modelId = modelId;
    blocks.replaceChildren(...f.blocks.map((b) => {
      const cell = h(`<div class="block-figure${b.worst ? ' worst' : ''}" data-dataset-id="${esc(b.dataset_id)}" data-block-index="${b.block_index ?? ''}"
        data-rms="${b.held_out_rms_um ?? ''}"><h3>${b.worst ? '<span class="bad">▲ worst block (largest held-out RMS)</span> · ' : ''}${esc(b.title)}
        <span class="muted">· held-out RMS ${fmtErrorNm(b.held_out_rms_um)} · ${esc(b.dataset_id)}</span></h3></div>`);
      cell.append(safeSvg(b.svg));
      return cell;
    }));
    status.textContent = '';
    // the button draws the start model's again: say so once another model's figures are shown
    button.textContent = `Show the figures of ${state.start}${modelId === state.start ? '' : ' (the start model)'}`;
  } catch (e) { showError(status, e, 'Figures failed: '); } finally { button.disabled = false; }
}

/** The lineage of `modelId` in the two selects (A: its parent, B: it). */
async function fillLineage(box, modelId, state, signal) {
  const r = await api(`/models/${encodeURIComponent(modelId)}/history`, { signal });
  state.steps = r.steps;
  const options = r.steps.map((s, i) => `<option value="${esc(s.model_id)}">step ${s.step ?? i}: ${esc(s.model_id)} · ${esc(s.change || 'first fit')}</option>`).join('');
  const a = box.querySelector('#compare-a');
  const b = box.querySelector('#compare-b');
  a.innerHTML = options;
  b.innerHTML = options;
  a.selectedIndex = Math.max(0, r.steps.length - 2);
  b.selectedIndex = r.steps.length - 1;
}

/** Per-block held-out RMS of models A and B on the datasets either was fitted on, the difference, and their effects. */
async function compareModels(box, state, signal) {
  const out = box.querySelector('#compare-models');
  const ids = [box.querySelector('#compare-a').value, box.querySelector('#compare-b').value];
  out.classList.remove('error');
  out.innerHTML = '<p class="muted">comparing…</p>';
  try {
    const [ma, mb] = await Promise.all(ids.map((id) => api(`/models/${encodeURIComponent(id)}`, { signal })));
    const datasets = [...new Set([...ma.datasets, ...mb.datasets])];
    const per = await Promise.all([ma, mb].map((m) => Promise.all(datasets.map((d) =>
      api(`/models/${encodeURIComponent(m.id)}/compare?dataset=${encodeURIComponent(d)}&arrays=false`, { signal })))));
    const names = new Map((state.figures?.blocks || []).map((b) => [`${b.dataset_id}/${b.block_index}`, b.title]));
    const rows = [];
    datasets.forEach((d, k) => {
      per[0][k].metrics.per_block.forEach((blockA, j) => {
        const blockB = per[1][k].metrics.per_block[j];
        const a = blockA.validation?.rms_um; const b = blockB?.validation?.rms_um;
        const name = names.get(`${d}/${blockA.index}`) || `${ma.axis.toUpperCase()} ${blockA.frequency_hz ? `${fmt(blockA.frequency_hz)} Hz ` : ''}${blockA.kind || 'block'} (block ${blockA.index})`;
        const unseen = [per[0][k], per[1][k]].some((c) => !c.used_in_fit);
        rows.push(`<tr data-dataset-id="${esc(d)}" data-block-index="${blockA.index}" data-a="${a}" data-b="${b}">
          <td>${esc(name)}${unseen ? ' <span class="muted">(not fitted by both: whole block unseen)</span>' : ''}</td><td>${esc(d)}</td>
          <td class="num">${fmtErrorNm(a)}</td><td class="num">${fmtErrorNm(b)}</td>
          <td class="num ${b < a ? 'ok' : 'bad'}">${fmtErrorNm(b - a)}</td><td class="num">${a ? `${fmt(100 * (b - a) / a, 3)} %` : '–'}</td></tr>`);
      });
    });
    const effects = (m) => m.effects.map(esc).join(' + ');
    out.innerHTML = `<table id="compare-blocks"><tr><th>block</th><th>dataset</th><th class="num">A: held-out RMS</th><th class="num">B: held-out RMS</th>
        <th class="num">B − A</th><th class="num">change</th></tr>${rows.join('')}
      <tr class="best"><td>the model's held-out RMS (on its own datasets)</td><td></td><td class="num">${fmtErrorNm(ma.metrics.validation_rms_um)}</td>
        <td class="num">${fmtErrorNm(mb.metrics.validation_rms_um)}</td><td class="num">${fmtErrorNm(mb.metrics.validation_rms_um - ma.metrics.validation_rms_um)}</td><td></td></tr></table>
      <table id="compare-effects"><tr><th></th><th>model</th><th>effects</th><th>only in it</th></tr>
        ${[[ma, mb, 'A'], [mb, ma, 'B']].map(([m, o, tag]) => `<tr data-model-id="${esc(m.id)}"><td>${tag}</td><td><a href="#/models/${esc(m.id)}">${esc(m.id)}</a></td>
          <td>${effects(m)}</td><td>${m.effects.filter((e) => !o.effects.includes(e)).map(esc).join(', ') || '–'}</td></tr>`).join('')}</table>`;
  } catch (e) { showError(out, e, 'Compare failed: '); }
}
