// Lab: every bench whose service shares this store (state, online or offline, running job, datasets,
// newest model per axis), refreshed every 2 s; and one axis's newest models compared across the
// benches: effects, held-out RMS, noise floor and the physical parameters discovery fitted.
import { api, esc, fmt, fmtErrorNm } from '../api.js';
import { importedDataName } from '../provenance.js';
import { h, showError } from '../ui.js';

const REFRESH_MS = 2000;
const AXES = ['y', 'z'];
/** Column titles of the physical parameters (service/science/effects/*: units in the names). */
const PARAMETER_TITLES = {
  resonance_hz: 'resonance (Hz)', damping_ratio: 'resonance damping ζ', creep_pct_per_decade: 'creep (%/decade)',
  creep_nm_per_decade: 'creep (nm/decade)', creep_step_v: 'creep step (V)', delay_us: 'delay (µs)',
  drift_nm_per_s: 'drift (nm/s)', coupling_ratio: 'coupling (µm/µm)',
  asymmetry_u2_nm: 'asymmetry u² (nm)', asymmetry_u3_nm: 'asymmetry u³ (nm)', asymmetry_s2_nm: 'asymmetry S² (nm)',
  asymmetry_us_nm: 'asymmetry u·S (nm)',
};

let timer = null;
let controller = null;

export async function enter(root, _rest, query) {
  controller = new AbortController();
  const axis = AXES.includes(query.axis) ? query.axis : 'y';
  root.append(h(`<div>
    <h1>Lab <span class="muted">every bench on this store</span></h1>
    <div class="card"><h2>Benches</h2>
      <p class="muted">A bench is offline once its service stopped or its heartbeat has been silent for
        <span id="lab-offline-after">3</span> intervals; its datasets and models stay in the store.</p>
      <table id="lab-benches"></table></div>
    <div class="card"><h2>Newest model per bench, compared</h2>
      <form class="inline" id="lab-compare-form" onsubmit="return false">
        <label>axis <select id="lab-axis">${AXES.map((a) => `<option value="${a}"${a === axis ? ' selected' : ''}>${a.toUpperCase()}</option>`).join('')}</select></label>
        <button type="button" id="lab-compare-refresh">Refresh</button>
      </form>
      <table id="lab-compare"></table></div>
  </div>`));
  root.querySelector('#lab-axis').addEventListener('change', () => refreshCompare(root));
  root.querySelector('#lab-compare-refresh').addEventListener('click', () => refreshCompare(root));
  await Promise.all([refreshBenches(root), refreshCompare(root)]);
  timer = setInterval(() => refreshBenches(root).catch((err) => showError(null, err)), REFRESH_MS);
}

export function leave() {
  if (timer) clearInterval(timer);
  timer = null;
  if (controller) controller.abort();
}

/** online → its state; stopped → "stopped"; otherwise offline, with how long it has been silent. */
function status(b) {
  if (b.online) return { key: 'online', text: b.state, cls: b.state === 'busy' ? 'state-running' : 'ok' };
  if (b.state === 'stopped') return { key: 'stopped', text: 'OFFLINE · stopped', cls: 'bad' };
  return { key: 'offline', text: `OFFLINE · silent ${fmt(b.heartbeat_age_s, 3)} s (last ${b.state})`, cls: 'bad' };
}

/** The data an imported model was fitted on (its origin): each dataset by its name now, with its file. */
export function originWords(origin) {
  const files = (origin?.imported || []).map((i) => importedDataName(i));
  const what = origin?.fitted_on === 'mixed' ? 'partly imported data' : 'imported data';
  return `${what}${files.length ? `: ${files.join(', ')}` : ''}, recorded on another stage`;
}

/** Where a model came from when that is not a finished job: a step of a discover that was cancelled or failed. */
function madeBy(job) {
  if (!job || job.state === 'succeeded' || job.state === 'running' || job.state === 'queued') return '';
  return `<div class="muted made-by" data-job-state="${esc(job.state)}">a step of ${esc(job.kind)} job ${esc(job.job_id)}, which was ${esc(job.state)}</div>`;
}

/** A bench's newest model of one axis fitted on its own data; under it, apart and marked, its newest
 *  fitted on imported data (that model describes the stage that recorded the file, not this bench). */
function modelCell(m, imported) {
  const other = imported ? `<div class="muted imported-model" data-model-id="${esc(imported.id)}" data-origin="${esc(imported.origin?.fitted_on || 'imported')}">
    not this bench's: <a href="#/models/${esc(imported.id)}">${esc(imported.id)}</a> on ${esc(originWords(imported.origin))}</div>` : '';
  if (!m) return `<td class="muted">none${other}</td>`;
  return `<td data-model-id="${esc(m.id)}" data-validation-rms-um="${m.validation_rms_um ?? ''}">
    <a href="#/models/${esc(m.id)}">${esc(m.id)}</a><br><span class="muted">${esc(m.effects.join(' + '))}</span>
    · held-out ${fmtErrorNm(m.validation_rms_um)}${m.noise_floor_um ? ` · floor ${fmtErrorNm(m.noise_floor_um)}` : ''}${madeBy(m.made_by)}${other}</td>`;
}

async function refreshBenches(root) {
  const lab = await api('/lab/benches', { signal: controller.signal });
  root.querySelector('#lab-offline-after').textContent = lab.offline_after_heartbeats;
  root.querySelector('#lab-benches').innerHTML = `<tr><th>bench</th><th>config</th><th>status</th>
    <th class="num">last heartbeat</th><th>running job</th><th class="num" title="the datasets it recorded; imports it stores are counted apart (another stage recorded them)">datasets recorded</th>
    ${AXES.map((a) => `<th>newest ${a.toUpperCase()} model</th>`).join('')}<th>service</th></tr>` +
    lab.benches.map((b) => {
      const s = status(b);
      return `<tr data-bench-id="${esc(b.id)}" data-online="${b.online}" data-state="${esc(b.state)}" class="${b.online ? '' : 'offline'}">
        <td><b>${esc(b.id)}</b>${b.id === lab.this_bench_id ? ' <span class="muted">(this service)</span>' : ''}</td>
        <td>${esc(b.name)}</td>
        <td class="status ${s.cls}" data-status="${s.key}">${esc(s.text)}</td>
        <td class="num" title="${esc(b.heartbeat_at)}">${fmt(b.heartbeat_age_s, 2)} s ago</td>
        <td class="running-job">${b.running_job_id ? esc(b.running_job_id) : '<span class="muted">–</span>'}</td>
        <td class="num datasets" data-recorded="${b.datasets}" data-imported="${b.imported_datasets || 0}">${b.datasets}${b.imported_datasets
          ? `<br><span class="muted">+ ${b.imported_datasets} imported (recorded on another stage)</span>` : ''}</td>
        ${AXES.map((a) => modelCell(b.latest_models[a], (b.latest_imported_models || {})[a])).join('')}
        <td><a href="${esc(b.url)}/web/" target="_blank" rel="noopener">${esc(b.url)}</a></td></tr>`;
    }).join('');
}

/** A compared model's cells: id, effects, held-out RMS, noise floor and each physical parameter. */
function comparedCells(m, names) {
  const cells = names.map((n) => {
    const [effect, parameter] = n.split('.');
    const value = (m.parameters[effect] || {})[parameter];
    return value === undefined || value === null ? `<td class="num muted" data-parameter="${esc(n)}">–</td>`
      : `<td class="num" data-parameter="${esc(n)}" data-value="${value}">${fmt(value, 4)}</td>`;
  }).join('');
  return `<td><a href="#/models/${esc(m.id)}">${esc(m.id)}</a><br><span class="muted">${esc(m.kind)}, ${esc(m.created_at)}</span></td>
    <td class="effects">${esc(m.effects.join(' + '))}</td>
    <td class="num">${fmtErrorNm(m.validation_rms_um)}</td><td class="num">${fmtErrorNm(m.noise_floor_um)}</td>${cells}`;
}

/** "creep (%/decade)" for a known parameter, else "effect · parameter". */
function parameterTitle(name) {
  const [effect, parameter] = name.split('.');
  return esc(PARAMETER_TITLES[parameter] || `${effect} · ${parameter}`);
}

async function refreshCompare(root) {
  const axis = root.querySelector('#lab-axis').value;
  const table = root.querySelector('#lab-compare');
  try {
    const c = await api(`/lab/compare?axis=${axis}`, { signal: controller.signal });
    table.dataset.axis = c.axis;
    table.innerHTML = `<tr><th>bench</th><th>status</th><th>model</th><th>effects</th><th class="num">held-out RMS</th>
      <th class="num">noise floor</th>${c.parameter_names.map((n) => `<th class="num">${parameterTitle(n)}</th>`).join('')}</tr>` +
      c.benches.map((b) => {
        const m = b.model;
        const s = status(b);
        if (!m) {
          return `<tr data-bench-id="${esc(b.id)}" data-model-id=""><td><b>${esc(b.id)}</b></td><td class="${s.cls}">${esc(s.key)}</td>
            <td class="muted" colspan="${4 + c.parameter_names.length}">no ${axis.toUpperCase()} model yet</td></tr>`;
        }
        return `<tr data-bench-id="${esc(b.id)}" data-model-id="${esc(m.id)}" data-validation-rms-um="${m.validation_rms_um ?? ''}">
          <td><b>${esc(b.id)}</b></td><td class="${s.cls}">${esc(s.key)}</td>${comparedCells(m, c.parameter_names)}</tr>`;
      }).join('') +
      (c.imported || []).map((x) => `<tr data-bench-id="" data-stored-by="${esc(x.bench_id)}" data-model-id="${esc(x.model.id)}" data-origin="${esc(x.model.origin?.fitted_on || 'imported')}"
          data-validation-rms-um="${x.model.validation_rms_um ?? ''}" class="imported-model">
          <td colspan="2"><b>${esc(originWords(x.model.origin))}</b><br><span class="muted">not a bench of this lab; stored by ${esc(x.bench_id)}</span></td>
          ${comparedCells(x.model, c.parameter_names)}</tr>`).join('');
  } catch (err) {
    showError(table, err);
  }
}
