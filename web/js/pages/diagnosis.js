// The Models page's diagnosis card: the verdict, where the model fails, the ranked candidate effects
// with their evidence and "Add <effect>" buttons, and — where two candidates explain the residual
// about equally well — "Run the experiment that separates A from B": the diagnosis's ready-to-POST
// sweep, then the diagnosis again with the new dataset added (GET …/diagnosis?extra_datasets=…),
// shown beside the scores before.
import { api, esc, fmt, fmtErrorNm } from '../api.js';
import { xyChart } from '../charts.js';
import { h, runJob, showError } from '../ui.js';

function describe(value) {
  if (value === null || value === undefined) return '';
  if (typeof value === 'string') return esc(value);
  if (Array.isArray(value)) return value.map(describe).join('; ');
  if (typeof value === 'object') return Object.entries(value).map(([k, v]) => `${esc(k)}: ${typeof v === 'number' ? fmt(v) : describe(v)}`).join(', ');
  return esc(typeof value === 'number' ? fmt(value) : String(value));
}

/** {a, b, text, body} when the diagnosis offers the experiment that separates two candidates. */
export function separatingExperiment(d) {
  const amb = d && d.ambiguity;
  if (amb && amb.experiment && Array.isArray(amb.effects) && amb.effects.length >= 2) {
    return { a: amb.effects[0], b: amb.effects[1], text: amb.text, body: amb.experiment };
  }
  return null;
}

/** What tests a not-testable effect: on imported data, the stage that recorded it; where this bench
 * cannot run it (even cut to its limits), why, and no button; else the button, with the cuts made. */
function testHtml(d, u) {
  if (d.experiments_run_here === false) return `<span class="muted">On the stage that recorded the data: (${describe(u.experiment)})</span>`;
  if (!u.experiment) return `<span class="muted not-runnable">This bench cannot run the experiment that tests it: ${esc(u.not_runnable_here || 'none is named')}.</span>`;
  const cut = (u.cut_to_limits || []).length ? ` <span class="muted">(cut to this bench's limits: ${esc(u.cut_to_limits.join('; '))})</span>` : '';
  return `<button type="button" class="run-test" data-effect="${esc(u.effect)}">Run the experiment that tests ${esc(u.effect)}</button>
    <span class="muted">(${describe(u.experiment)})</span>${cut}`;
}

const candidate = (d, effect) => (d.candidates || []).find((c) => c.effect === effect) || {};
const score = (d, effect) => candidate(d, effect).score;
/** A candidate's score, labelled where it is 1 because it is capped (its test's drop exceeds the whole). */
const scoreHtml = (c) => `${fmt(c.score, 3)}${c.score_capped ? ` <span class="capped" title="its test removed more than this
  model's excess above the noise floor, a whole of another fit: the score is capped at 1">(capped)</span>` : ''}`;
/** The held-out RMS (nm) of the model with `effect`: for the loop-shape pair, its head-to-head fit (the
 *  loser is not fitted into the model, and its "added" figure is the model's own: a walk read "158 nm
 *  against 205 nm" where the head to head said 158 against 170), else what adding it gives. */
const heldOutNm = (d, effect) => {
  const c = candidate(d, effect);
  return (c.head_to_head_rms_um ?? c.expected_rms_um ?? NaN) * 1e3;
};

/** Scores of the two effects before and after the experiment, and what the user should conclude. */
function separationSummary(before, after, experiment, datasetId) {
  const { a, b } = experiment;
  const rows = [a, b].map((e) => ({ effect: e, before: score(before, e), after: score(after, e),
    nmBefore: heldOutNm(before, e), nmAfter: heldOutNm(after, e) }));
  const lead = rows.slice().sort((x, y) => (y.after ?? -1) - (x.after ?? -1) || x.nmAfter - y.nmAfter)[0];
  const other = rows.find((r) => r !== lead);
  // the service judges the ambiguity (scores and unexplained excess): told apart unless the diagnosis
  // with the experiment still finds this same pair alike (another pair is another question, named)
  const alike = (after && after.ambiguity && after.ambiguity.effects) || [];
  const separated = !(alike.includes(a) && alike.includes(b));
  const another = alike.length >= 2 && separated ? ` The diagnosis with it finds another pair alike: ${esc(alike[0])} and ${esc(alike[1])} (below).` : '';
  // the same pair alike with the separating sweep in the data: no sweep of this bench settles it
  const settled = !separated && after.ambiguity.separating_sweep_in_data ? ' No sweep of this bench tells them apart (see Separate below).' : ' A longer experiment may be needed.';
  return `<div id="separation" data-dataset-id="${esc(datasetId)}"
      data-leader="${esc(lead.effect)}" data-separated="${separated}">
    <h3>Separating experiment: result</h3>
    <p class="${separated ? 'ok' : 'warn'}">${separated
      ? `With dataset <a href="#/datasets/${esc(datasetId)}">${esc(datasetId)}</a> added, <b>${esc(lead.effect)}</b> explains the residual clearly better than ${esc(other.effect)} (held-out ${fmt(lead.nmAfter, 3)} nm against ${fmt(other.nmAfter, 3)} nm; score ${fmt(lead.after, 3)} against ${fmt(other.after, 3)}).${another}`
      : `Even with dataset <a href="#/datasets/${esc(datasetId)}">${esc(datasetId)}</a> added, ${esc(a)} and ${esc(b)} remain close.${settled}`}</p>
    <table id="separation-table"><tr><th>effect</th><th class="num">score before</th><th class="num">score with the experiment</th>
      <th class="num">held-out before (nm)</th><th class="num">held-out with the experiment (nm)</th></tr>
      ${rows.map((r) => `<tr data-effect="${esc(r.effect)}" data-before="${r.before ?? ''}" data-after="${r.after ?? ''}" data-nm-after="${r.nmAfter}"${r === lead ? ' class="best"' : ''}>
        <td>${esc(r.effect)}</td><td class="num">${scoreHtml(candidate(before, r.effect))}</td><td class="num">${scoreHtml(candidate(after, r.effect))}</td>
        <td class="num">${fmt(r.nmBefore, 3)}</td><td class="num">${fmt(r.nmAfter, 3)}</td></tr>`).join('')}</table>
    <p class="muted">The candidates below are ranked on all the data, the experiment included; "Add" refits with it.</p></div>`;
}

/** What remains, described (the diagnosis's `remainder`): each signature's sentence, its share of the
 *  unseen residual, and a figure of the residual against the signature's variable. */
function remainderHtml(r, answer) {
  if (!r || !r.signatures || !r.signatures.length) return '';
  return `<h3>What remains, described <span class="muted">(the residual on rows the model never fitted — held-out
      cycles, rests, holds — read against physical signatures; each fitted on the training rows)</span></h3>
    <ol id="remainder">${r.signatures.map((s, i) => `<li data-signature="${esc(s.signature)}" data-share="${s.share_of_excess}"${answer && answer.remains === s.signature ? ' class="in-answer" title="the description the answer above names"' : ''}>
      <b>${esc(s.signature)}</b> — ${fmt(100 * s.share_of_excess, 3)} % of the unseen residual above the noise${r.signatures.length > 1 ? ', fitted alone' : ''} (t = ${fmt(s.t, 3)}):
      ${esc(s.text)}<div class="remainder-figure" data-i="${i}"></div></li>`).join('')}</ol>
    ${r.shares_text ? `<p class="muted" id="remainder-shares" data-overlap="${r.shares_overlap ? 1 : 0}">${esc(r.shares_text)}</p>` : ''}
    <p class="muted">Tried: ${r.tried.map(esc).join(', ')}; a signature is shown when its held-out gain passes t > ${fmt(r.threshold_t, 3)}
      (1 % over all of them) and it explains at least 5 % of what remains.</p>`;
}

function drawRemainder(box, r) {
  if (!r || !r.signatures) return;
  r.signatures.forEach((s, i) => {
    const el = box.querySelector(`.remainder-figure[data-i="${i}"]`);
    if (el && s.figure) xyChart(el, { xLabel: s.figure.x_label, yLabel: 'residual (nm)', height: 200,
      curves: [{ label: `residual against ${s.signature}`, x: s.figure.x, y: s.figure.residual_nm, dots: true }] });
  });
}

/** The group a candidate row opens (claimed physics, the other physics, capacity), or ''. */
function groupRow(candidates, i) {
  const group = (c) => (c.kind === 'capacity' ? 'model capacity (not physics)' : c.claimed ? 'claimed' : 'not claimed');
  const g = group(candidates[i]);
  return i && group(candidates[i - 1]) === g ? '' : `<tr class="group" data-group="${esc(g)}"><td colspan="6" class="muted">${esc(g)}</td></tr>`;
}

/**
 * Render diagnosis `d` of `model` into `box`. `onAdd(effect, extraDatasets)` starts a refine job;
 * the Separate button runs the experiment (its progress in `jobBox`) and re-renders with the new diagnosis. `extra` names the
 * datasets the diagnosis added to the model's own; `before`/`experiment` the earlier diagnosis.
 */
export function renderDiagnosis(box, model, d, opts) {
  const { canRefine, onAdd, jobBox, extra = [], before = null, experiment = null, datasetId = null, onDiagnosis = null } = opts;
  if (onDiagnosis) onDiagnosis(d, extra);   // the page's answer reads the diagnosis shown here, never an older one
  const verdictClass = d.verdict === 'complete' ? 'ok' : 'warn';
  const candidates = (d.candidates || []).filter((c) => c.testable !== false);
  const named = d.answer ? d.answer.missing : null;       // what the verdict names: the answer's one stored value
  const leading = candidates.find((c) => c.effect === named);
  const untestable = d.not_testable || [];
  // the verdict as a label: its sentence is the answer's, on the page's first screen
  box.innerHTML = `${before ? separationSummary(before, d, experiment, datasetId) : ''}
    <p id="diagnosis-verdict" data-verdict="${esc(d.verdict)}" data-extra-datasets="${esc(extra.join(','))}" class="${verdictClass}">
      Verdict: <b>${d.verdict !== 'complete' ? 'an effect is missing'
        : d.at_noise_floor === false ? 'complete as far as the library goes, not at the noise floor' : 'complete, at the noise floor'}</b>.
      Residual RMS <b data-value="${d.residual_rms_um}">${fmtErrorNm(d.residual_rms_um, 4)}</b> · noise floor ${fmtErrorNm(d.noise_floor_um, 4)}</p>
    ${d.verdict_text ? `<p class="muted">${esc(d.verdict_text)}</p>` : ''}
    ${d.diagnosed_as ? `<p class="muted" id="diagnosed-as">Diagnosed as ${esc(d.diagnosed_as)}.</p>` : ''}
    ${(d.failures || []).length ? `<h3>Where it fails <span class="muted" id="failures-of">(worst first; shaded on the plots below; the held-out residual RMS of the diagnosis's fit${d.diagnosed_as ? ', the composite standing for this model' : ''} at each place — a whole block, a branch, the turning points, a third of the drive — so a block's figure here need not match the stored model's per-block figure in the compare table)</span></h3><ul id="failures">${d.failures.map((f) => `<li data-rms="${f.rms_um ?? ''}"${f.block ? ` data-block="${esc(f.block)}"` : ''}>${f.block
      ? `${esc(f.block)}: held-out residual RMS ${fmtErrorNm(f.rms_um)} <span class="muted">(${esc(f.record)})</span>` : (esc(f.text || '') || describe(f))}</li>`).join('')}</ul>` : ''}
    <h3>Candidate effects <span class="muted">(claimed physical effects, then the others, then model capacity; the claimed by their size: the held-out mean square each removes over its claim's reference, in the evidence; the others by score)</span></h3>
    <table id="candidates"><tr><th>#</th><th>effect</th><th class="num" title="the held-out mean square its own test removes (each block's level anchored at its last training cycle), as a share (0–1) of this model's held-out mean square above the noise floor: one scale for every candidate, the figures under it; it is not the ratio of the RMS figures beside it; whether it is claimed is the held-out test's answer, in the evidence">score <span class="muted">(of)</span></th><th class="num" title="the held-out RMS of the model the effect was tested against, then with it">its test: reference → with it</th><th class="num" title="the held-out RMS of this model with the effect added (fitted only when it is claimed)">added to this model</th><th>evidence <span class="muted">(its own test, a fit of its own: the stored model's parameters may differ)</span></th></tr>
    ${candidates.map((c, i) => `${groupRow(candidates, i)}<tr data-effect="${esc(c.effect)}" data-kind="${esc(c.kind)}" data-score="${c.score}" data-claimed="${c.claimed === true}"${c === leading ? ' class="best"' : ''}>
      <td>${i + 1}</td><td class="effect">${esc(c.effect)}${c.claimed ? ' <b class="warn">claimed</b>' : ''}${canRefine && !model.effects.includes(c.effect) ? `<br><button type="button" class="primary add-effect" data-effect="${esc(c.effect)}">Add ${esc(c.effect)}</button>` : ''}</td><td class="num score" data-capped="${c.score_capped === true}">${scoreHtml(c)}${c.score_of ? `<details class="muted score-of"><summary>of</summary>${esc(c.score_of)}</details>` : ''}</td><td class="num tested">${c.tested_rms_um === null || c.tested_rms_um === undefined ? '–' : `${fmtErrorNm(c.reference_rms_um, 4)} → ${fmtErrorNm(c.tested_rms_um, 4)}`}</td>
      <td class="num expected">${c.expected_rms_um !== d.residual_rms_um ? fmtErrorNm(c.expected_rms_um, 4) : '<span class="muted">not fitted</span>'}</td>
      <td class="evidence">${describe(c.evidence)}</td></tr>`).join('')}
    </table>
    ${d.claim_rule ? `<p class="muted" id="claim-rule">Claim rule: ${esc(d.claim_rule)}.</p>` : ''}
    ${remainderHtml(d.remainder, d.answer)}
    ${untestable.length ? `<h3>Not testable with this data</h3><ul id="not-testable">${untestable.map((u) => `<li data-effect="${esc(u.effect)}">
      <b>${esc(u.effect)}</b>: ${esc(u.reason)}. ${testHtml(d, u)}</li>`).join('')}</ul>` : ''}
    ${(d.not_tried || []).length ? `<p class="muted" id="not-tried">Not tried: ${d.not_tried.map((u) => `<span data-effect="${esc(u.effect)}"><b>${esc(u.effect)}</b> (${esc(u.reason)})</span>`).join('; ')}.</p>` : ''}
    ${d.experiments_note ? `<p class="warn" id="experiments-elsewhere">${esc(d.experiments_note)}</p>` : ''}
    <div id="separate"></div>`;
  drawRemainder(box, d.remainder);
  box.querySelectorAll('.add-effect').forEach((b) => b.addEventListener('click', () => onAdd(b.dataset.effect, extra)));
  box.querySelectorAll('.run-test').forEach((b) => b.addEventListener('click', async () => {
    const u = untestable.find((x) => x.effect === b.dataset.effect);
    b.disabled = true;
    const offer = { a: u.effect, b: u.effect, text: u.reason, body: u.experiment };
    const found = await separate(jobBox, model, offer, extra, opts.signal);
    if (found) renderDiagnosis(box, model, found.diagnosis, { ...opts, extra: found.extra });
    else b.disabled = false;
  }));
  const offered = separatingExperiment(d);
  if (!offered) {
    if (d.ambiguity && d.ambiguity.not_runnable_here) {   // an ambiguity this bench cannot separate: said, no button
      box.querySelector('#separate').innerHTML = `<h3>Separate</h3><p>${esc(d.ambiguity.text || '')}</p>
        <p class="muted" id="separate-not-here">This bench cannot run the experiment that separates them: ${esc(d.ambiguity.not_runnable_here)}.</p>`;
    } else if (d.ambiguity && d.ambiguity.separating_sweep_in_data) {   // run already and still alike: no button
      box.querySelector('#separate').innerHTML = `<h3>Separate</h3><p id="separate-in-data">${esc(d.ambiguity.text || '')}.</p>`;
    }
    return;
  }
  const sep = box.querySelector('#separate');
  if (d.experiments_run_here === false) {      // imported data: the experiment belongs to the stage that recorded it
    sep.innerHTML = `<h3>Separate</h3><p>${esc(offered.text || '')}</p>
      <p class="muted">On the stage that recorded the data: ${describe(offered.body)}.</p>`;
    return;
  }
  sep.innerHTML = `<h3>Separate</h3><p>${esc(offered.text || '')}</p>
    <p class="muted">The experiment: ${describe(offered.body)}.</p>
    <button type="button" class="primary" id="separate-run" data-a="${esc(offered.a)}" data-b="${esc(offered.b)}">Run the experiment that separates ${esc(offered.a)} from ${esc(offered.b)}</button>`;
  sep.querySelector('#separate-run').addEventListener('click', async (e) => {
    e.target.disabled = true;
    const found = await separate(jobBox, model, offered, extra, opts.signal);
    if (found) {
      renderDiagnosis(box, model, found.diagnosis, { ...opts, extra: found.extra, before: d, experiment: offered,
        datasetId: found.datasetId });
    } else {
      e.target.disabled = false;
    }
  });
}

/** Run the experiment (a sweep job), then the diagnosis with its dataset; null when either fails. */
async function separate(out, model, experiment, extra, signal) {
  try {
    // the dataset keeps what it is the experiment of, so its result is shown again after a reload
    const body = { ...experiment.body, experiment_of: { model_id: model.id, effects: [...new Set([experiment.a, experiment.b])], extra_datasets: extra } };
    const job = await runJob(out, '/sweeps', body, `separating experiment (${experiment.body.waveform || 'sweep'})`, { signal });
    if (job.state !== 'succeeded' || !job.result?.dataset_id) {
      showError(out.appendChild(document.createElement('p')), new Error(job.error || `the experiment was ${job.state}`));
      return null;
    }
    const datasetId = job.result.dataset_id;
    const all = [...extra, datasetId];
    const diagnosis = await diagnosedWith(out, model, all, `Dataset ${datasetId} recorded`, signal);
    return { diagnosis, datasetId, extra: all };
  } catch (e) {
    showError(out.appendChild(document.createElement('p')), e, 'Separating experiment failed: ');
    return null;
  }
}

/** GET the diagnosis of `model` with the datasets `extra` added, a wait line in `out` counting the seconds. */
async function diagnosedWith(out, model, extra, said, signal) {
  const wait = h(`<p class="muted" id="separate-wait">${esc(said)}. Re-running the diagnosis with it
    (every candidate is refitted on all the data): <span>0</span> s…</p>`);
  out.append(wait);
  const t0 = Date.now();
  const tick = setInterval(() => { wait.querySelector('span').textContent = String(Math.round((Date.now() - t0) / 1000)); }, 1000);
  try {
    const query = extra.map((id) => `extra_datasets=${encodeURIComponent(id)}`).join('&');
    return await api(`/models/${encodeURIComponent(model.id)}/diagnosis${query ? `?${query}` : ''}`, { signal });
  } finally {
    clearInterval(tick);
    wait.remove();
  }
}

/** The newest separating experiment run from `model`'s diagnosis: the dataset that records it
 *  (`experiment_of`: this model, two effects; not a discover run's), or null. `datasets`: oldest first. */
export function lastSeparation(model, datasets) {
  const runs = datasets.filter((d) => d.experiment_of && d.experiment_of.model_id === model.id
    && !d.experiment_of.discover_job_id && (d.experiment_of.effects || []).length === 2 && !d.partial);
  return runs.length ? runs[runs.length - 1] : null;
}

/** After a reload, the newest separating experiment's result again, from its stored dataset: the
 *  diagnosis with it beside the diagnosis that proposed it (`d` when that one added no dataset). */
export async function showLastSeparation(box, model, d, datasets, opts) {
  const ds = lastSeparation(model, datasets);
  if (!ds) return;
  const { effects: [a, b], extra_datasets: earlier = [] } = ds.experiment_of;
  const said = `The separating experiment of ${String(ds.created_at).slice(0, 16).replace('T', ' ')} (dataset ${ds.id})`;
  try {
    const before = earlier.length ? await diagnosedWith(opts.jobBox, model, earlier, said, opts.signal) : d;
    const after = await diagnosedWith(opts.jobBox, model, [...earlier, ds.id], said, opts.signal);
    renderDiagnosis(box, model, after, { ...opts, extra: [...earlier, ds.id], before, experiment: { a, b }, datasetId: ds.id });
  } catch (e) {
    showError(opts.jobBox.appendChild(document.createElement('p')), e, 'The separating experiment\'s result could not be read again: ');
  }
}
