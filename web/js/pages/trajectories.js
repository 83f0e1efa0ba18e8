// Trajectories: an ellipse and a controller (inverse-model feedforward, PID, ILC); the live error
// per period while ILC learns; the reference and actual ellipse; the errors beside the paper's.
import { api, esc, fmt, fmtErrorNm, has } from '../api.js';
import { lineChart, xyChart, destroyAll } from '../charts.js';
import { paperFigures, trackingCases } from '../paper.js';
import { startPrepare, resumePrepare } from '../prepare.js';
import { onImportedData } from '../provenance.js';
import { h, runJob, showError } from '../ui.js';

const charts = [];
let controller = null;

// The paper's tracking cases (GET /api/paper), read on entering the page.
let PAPER = null;
// PID: "auto" (the service tunes each axis on the plant its feedforward model gives, with this
// bench's first resonance and loop delay, for a 60° phase margin), "tuned" (what auto gives on the
// default bench), "paper" (refused with its predicted margins unless forced), or custom gains per
// axis (kp V/µm, ki V/(µm·s), kd V·s/µm), refused when predicted unstable. The result reports the gains and their predicted margins.
const GAINS = ['kp_y', 'ki_y', 'kd_y', 'kp_z', 'ki_z', 'kd_z'];

export async function enter(root) {
  controller = new AbortController();
  const signal = controller.signal;
  const [available, models, paper] = await Promise.all([has('POST /api/trajectories'), api('/models', { signal }),
    paperFigures(signal)]);
  PAPER = trackingCases(paper);
  const option = (m) => `<option value="${esc(m.id)}">${esc(m.id)}${m.name ? ` “${esc(m.name)}”` : ''} · ${esc(m.kind)} · ${m.effects.map(esc).join('+')} · ${fmtErrorNm(m.metrics.validation_rms_um)}</option>`;
  // Models of this bench only; those fitted on another stage's imported data (their low held-out RMS
  // describes that stage, not this one) are in the list, marked apart, only while the toggle is ticked:
  // a hidden, disabled optgroup was still listed by the browser's drop-down.
  const options = (axis, showImported = false) => {
    const mine = models.filter((m) => m.axis === axis).reverse();
    const here = mine.filter((m) => !onImportedData(m));
    const elsewhere = mine.filter((m) => onImportedData(m));
    return `<option value="">none</option>` + here.map(option).join('') +
      (elsewhere.length && showImported ? `<optgroup label="fitted on imported data (another stage)" class="imported-models">${elsewhere.map(option).join('')}</optgroup>` : '');
  };
  root.append(h(`<div>
    <h1>Trajectories</h1>
    ${available ? '' : '<p class="card warn" id="no-trajectories">This service does not offer trajectory tracking yet (POST /api/trajectories).</p>'}
    <div class="card"><h2>Ellipse and controller</h2>
      <form id="traj-form" class="inline">
        <label>preset <select id="traj-preset"><option value="">—</option><option value="case1">paper case 1</option><option value="case2">paper case 2</option></select></label>
        <label>Y min (µm) <input name="min_y_um" type="number" step="any" min="0" value="1"></label>
        <label>Y peak-to-peak (µm) <input name="amplitude_y_um" type="number" step="any" min="0" value="5"></label>
        <label>Z min (µm) <input name="min_z_um" type="number" step="any" min="0" value="1"></label>
        <label>Z peak-to-peak (µm) <input name="amplitude_z_um" type="number" step="any" min="0" value="10"></label>
        <label>inclination (°) <input name="inclination_deg" type="number" step="any" value="0"></label>
        <label>frequency (Hz) <input name="frequency_hz" type="number" step="any" min="0" value="100"></label>
        <label>periods <input name="cycles" type="number" step="1" min="1" value="50"></label>
        <label>feedforward model Y <select name="feedforward_model_y">${options('y')}</select></label>
        <label>feedforward model Z <select name="feedforward_model_z">${options('z')}</select></label>
        <label class="check" title="models fitted on data recorded on another stage (imported): they describe that stage, not this bench"><input type="checkbox" id="traj-show-imported">show models fitted on other stages' data</label>
        <label>PID <select name="pid" id="traj-pid"><option value="">none</option>
          <option value="auto">auto (tuned per axis on its feedforward model and this bench's resonance)</option>
          <option value="tuned">tuned (auto on the default bench)</option>
          <option value="paper">paper gains (Y ${paperGains(paper, 'y')}, Z ${paperGains(paper, 'z')})</option>
          <option value="custom">custom…</option></select></label>
        <span id="traj-gains" hidden>${GAINS.map((g) => `<label>${g} <input name="${g}" type="number" step="any" min="0" value="0" style="width:80px"></label>`).join('')}</span>
        <label class="check" title="run PID gains refused by their predicted margins (the divergence watch trips them to 0 V)"><input type="checkbox" name="force">force</label>
        <label class="check"><input type="checkbox" name="ilc" checked>ILC (learned periodic correction)</label>
        <label class="check" title="run a range beyond the axis's stroke with the command clamped at the axis's voltage limits"><input type="checkbox" name="allow_saturation">allow saturation</label>
        <button class="primary" type="submit" id="traj-start"${available ? '' : ' disabled'}>Run</button>
        <button type="button" id="traj-span-sweep" title="the recommended path: a first sweep and models for each axis whose feedforward model is left empty above (a model chosen there is the start), then sweeps over the voltages this ellipse needs (± 5 V) and models on them, selected for the run"${available ? '' : ' disabled'}>Prepare the models it needs</button>
      </form>
      <div id="traj-job"></div><div id="traj-error"></div><div id="traj-warnings"></div><div id="traj-pid-report"></div><div id="traj-span"></div>
    </div>
    <div class="grid">
      <div class="card"><h2>Error per period</h2><div id="period-chart"></div></div>
      <div class="card"><h2>Reference and actual ellipse</h2><div id="ellipse-chart"></div></div>
    </div>
    <div class="card"><h2>Errors beside the paper's</h2><table id="traj-errors"></table>
      <p class="muted" id="traj-relative-note"></p></div>
  </div>`));
  const form = root.querySelector('#traj-form');
  root.querySelector('#traj-show-imported').addEventListener('change', (e) => {
    for (const axis of ['y', 'z']) {   // rebuilt: the models added since (just identified) and the choice kept
      const select = form.elements[`feedforward_model_${axis}`];
      const added = [...select.options].filter((o) => o.dataset.added);
      const chosen = select.value;
      select.innerHTML = options(axis, e.target.checked);
      select.append(...added);
      select.value = [...select.options].some((o) => o.value === chosen) ? chosen : '';
    }
  });
  root.querySelector('#traj-pid').addEventListener('change', (e) => {
    root.querySelector('#traj-gains').hidden = e.target.value !== 'custom';
  });
  root.querySelector('#traj-preset').addEventListener('change', (e) => {
    const preset = PAPER[e.target.value];
    if (preset) for (const [k, v] of Object.entries(preset.form)) form.elements[k].value = v;
  });
  // the preset names the case the ellipse fields hold, whoever set them (typing, a reloaded prepare
  // job's ellipse: web/js/prepare.js sends the same event)
  form.addEventListener('input', (e) => { if (e.target.id !== 'traj-preset') showPreset(root); });
  form.addEventListener('submit', (e) => { e.preventDefault(); run(root); });
  root.querySelector('#traj-span-sweep').addEventListener('click', () => prepareModels(root));
  renderErrors(root, null);
  // a prepare job started before (in another tab, or before a reload): followed, its models selected
  resumePrepare(root, signal, selectModel).catch((e) => showError(root.querySelector('#traj-error'), e));
}

/** Show in the preset list the paper case whose ellipse the form holds, or "—" for none. */
function showPreset(root) {
  const form = root.querySelector('#traj-form');
  const same = (a, b) => Math.abs(Number(a) - Number(b)) <= 1e-9 * Math.max(1, Math.abs(Number(b)));
  const match = Object.entries(PAPER).find(([, p]) => Object.entries(p.form).every(([k, v]) => same(form.elements[k].value, v)));
  root.querySelector('#traj-preset').value = match ? match[0] : '';
}

/** The paper's PID gains of one axis as 'kp/ki/kd' (V/µm, V/(µm·s), V·s/µm). */
function paperGains(paper, axis) {
  const g = paper.pid_gains[axis];
  return `${g.kp}/${g.ki}/${g.kd}`;
}

/** The per-period errors of a job (in progress or done): the first array whose key names periods. */
function perPeriod(job) {
  for (const source of [job.result, job.live, job.data, job]) {
    if (!source || typeof source !== 'object') continue;
    for (const [k, v] of Object.entries(source)) {
      if (/period/.test(k) && Array.isArray(v) && v.length && (typeof v[0] === 'number' || typeof v[0] === 'object')) {
        return v.map((p) => (typeof p === 'number' ? p : p.rms_error_um ?? p.max_error_um ?? p.error_um ?? p.rms_um));
      }
    }
  }
  return null;
}

// The tracking request the form describes.
function formBody(root) {
  const f = new FormData(root.querySelector('#traj-form'));
  const ctl = { ilc: f.get('ilc') === 'on' };
  if (f.get('allow_saturation') === 'on') ctl.allow_saturation = true;
  if (f.get('feedforward_model_y')) ctl.feedforward_model_y = f.get('feedforward_model_y');
  if (f.get('feedforward_model_z')) ctl.feedforward_model_z = f.get('feedforward_model_z');
  const pid = f.get('pid');
  if (pid === 'custom') ctl.pid = Object.fromEntries(GAINS.map((g) => [g, Number(f.get(g))]));
  else if (pid) ctl.pid = pid;
  if (f.get('force') === 'on') ctl.force = true;
  return { shape: 'ellipse', amplitude_y_um: Number(f.get('amplitude_y_um')), amplitude_z_um: Number(f.get('amplitude_z_um')),
    min_y_um: Number(f.get('min_y_um')), min_z_um: Number(f.get('min_z_um')),
    inclination_deg: Number(f.get('inclination_deg')), frequency_hz: Number(f.get('frequency_hz')), cycles: Number(f.get('cycles')), controller: ctl };
}

// The guided path (GET /api/trajectories/recipe) as one service job (web/js/prepare.js): a failed step
// stops the path and says why, in the page's words.
async function prepareModels(root) {
  const err = root.querySelector('#traj-error');
  err.textContent = '';
  root.querySelector('#traj-warnings').innerHTML = '';   // an earlier run's, not this path's
  const button = root.querySelector('#traj-span-sweep');
  button.disabled = true;
  try {
    await startPrepare(root, formBody(root), controller.signal, selectModel);
  } catch (e) {
    showError(err, inPageWords(root.querySelector('#traj-form'), e));
  } finally {
    button.disabled = false;
  }
}

/** A refusal in the page's words: the API names its fields by their body paths
 * ("controller.feedforward_model_y"); each one the form has a control for is named by that control's
 * label ("feedforward model Y"), and the control the refusal is about is marked. */
function inPageWords(form, e) {
  if (!form || !e || !e.message) return e;
  const labelOf = (name) => {
    const control = form.elements[name];
    const label = control && control.closest ? control.closest('label') : null;
    return label ? [...label.childNodes].filter((n) => n.nodeType === 3).map((n) => n.textContent).join('').trim() : null;
  };
  // a body path (controller.pid) or a snake_case field (feedforward_model_y); plain words stay as they are
  const text = e.message.replace(/\b(?:(?:controller|trajectory)\.([a-z][a-z0-9_]*)|([a-z][a-z0-9]*_[a-z0-9_]+))\b/g,
    (whole, path, snake) => {
      const name = path || snake;
      const words = form.elements[name] ? labelOf(name) : null;
      return words ? `“${words}”` : whole;
    });
  const named = e.field ? form.elements[e.field.split('.').pop()] : null;
  if (named && named.classList) {
    named.classList.add('invalid');
    named.addEventListener('change', () => named.classList.remove('invalid'), { once: true });
  }
  const out = new Error(text);
  out.field = e.field;
  return out;
}

/** Select model `id` for `axis` in the form (a new option if the list does not have it yet). */
function selectModel(form, axis, id) {
  const select = form.elements[`feedforward_model_${axis}`];
  if (![...select.options].some((o) => o.value === id)) {
    const added = new Option(`${id} · just identified`, id);
    added.dataset.added = '1';
    select.append(added);
  }
  select.value = id;
}

async function run(root) {
  const err = root.querySelector('#traj-error');
  err.textContent = '';
  const prepared = root.querySelector('#traj-prepared .run-hint');
  if (prepared) prepared.remove();   // "press Run" is done; which models and why stay
  root.querySelector('#traj-warnings').innerHTML = '';
  root.querySelector('#traj-pid-report').innerHTML = '';
  const body = formBody(root);
  const button = root.querySelector('#traj-start');
  button.disabled = true;
  destroyAll(charts);
  let shown = -1;
  let periodChart = null;
  const drawPeriods = async (values) => {
    if (!values || values.length === shown) return;
    shown = values.length;
    const el = root.querySelector('#period-chart');
    el.dataset.values = JSON.stringify(values);
    el.dataset.points = String(values.length);
    const xs = values.map((_, i) => i + 1);
    const nm = values.map((v) => v * 1e3);   // data-values keep the API's µm; the chart draws nm
    if (!periodChart) {   // a promise, so that updates arriving while it is made wait for it
      periodChart = lineChart(el, { xs, xLabel: 'period', yLabel: 'tracking error (nm)',
        series: [{ label: 'error per period (nm)', values: nm, points: true, width: 2 }], height: 240, integerX: true });
      charts.push(await periodChart);
    } else {
      (await periodChart).setData([xs, nm]);
    }
  };
  const live = [];   // error per period from the progress messages ("period 7/56: error 312.4 nm RMS")
  let lastMessage = '';
  try {
    const job = await runJob(root.querySelector('#traj-job'), '/trajectories', body, 'trajectory', {
      signal: controller.signal, onUpdate: (j) => {
        const m = /error ([0-9.eE+-]+) nm/.exec(j.message || '');
        if (m && j.message !== lastMessage) {
          live.push(Number(m[1]) / 1000);
          root.querySelector('#period-chart').dataset.livePoints = String(live.length);
          drawPeriods(live.slice());
        }
        lastMessage = j.message || '';
      } });
    if (job.state === 'succeeded') {
      const result = job.result;
      if (result.warnings && result.warnings.length) {
        root.querySelector('#traj-warnings').innerHTML = `<div class="warn">${result.warnings.map((w) => `<p>${esc(w)}</p>`).join('')}</div>`;
      }
      if (result.pid) renderPid(root, result.pid);
      await drawPeriods(perPeriod({ result }));
      renderErrors(root, result, body);
      await drawEllipse(root, result, body);
    } else {
      showError(err, new Error(job.error || `the trajectory run was ${job.state}`));
    }
  } catch (e) {
    showError(err, inPageWords(root.querySelector('#traj-form'), e));
  } finally {
    button.disabled = false;
  }
}

/** Reference and actual ellipse: the last two periods of the traces the run stored as a dataset. */
async function drawEllipse(root, r, body) {
  const el = root.querySelector('#ellipse-chart');
  if (!r.dataset_id) { el.innerHTML = '<p class="muted">The run stored no traces.</p>'; return; }
  const d = await api(`/datasets/${encodeURIComponent(r.dataset_id)}/data`, { signal: controller.signal });
  const n = d.x_y_um.length;
  const period = Math.round(d.sample_rate_hz / body.frequency_hz);
  // The traces ramp in and out over a few periods: draw two steady periods before the ramp-out.
  const end = n > 8 * period ? n - 4 * period : n;
  const from = Math.max(0, end - 2 * period);
  const tail = (k) => d[k].slice(from, end);
  el.dataset.datasetId = r.dataset_id;
  charts.push(await xyChart(el, { xLabel: 'Y (µm)', yLabel: 'Z (µm)', height: 300, square: true,
    curves: [{ label: 'reference', x: tail('ref_y_um'), y: tail('ref_z_um'), color: '#2b8a3e', width: 2 },
             { label: 'actual (2 steady periods)', x: tail('x_y_um'), y: tail('x_z_um'), color: '#d9480f' }] }));
}

/** What the service's relative_error_pct is (service/science/control/session.py, metrics). */
const RELATIVE_ERROR = 'the larger over Y and Z of (max |error| on the axis ÷ the reference\'s peak-to-peak on that axis over one steady period), × 100';

function renderErrors(root, r, body) {
  // errors in nm (the one unit for errors; the API's fields are in µm), the relative error in %
  const shown = (key, v) => (v === undefined || v === null ? '–' : key.endsWith('_um') ? fmt(v * 1e3) : fmt(v));
  const paperCell = (c, key) => `<td class="num">${c[key] !== undefined ? shown(key, c[key]) : '–'}</td>`;
  const row = (label, key, unit, title = '') => `<tr data-key="${key}"><td${title ? ` title="${esc(title)}"` : ''}>${label} (${unit})</td>
    <td class="num" data-value="${r ? r[key] ?? '' : ''}">${r ? shown(key, r[key]) : '–'}</td>
    ${paperCell(PAPER.case1, key)}${paperCell(PAPER.case2, key)}</tr>`;
  root.querySelector('#traj-errors').innerHTML = `<tr><th>error</th><th class="num">this run${body ? ` (${fmt(body.frequency_hz)} Hz, ${fmt(body.inclination_deg)}°)` : ''}</th>
      <th class="num">${PAPER.case1.label}</th><th class="num">${PAPER.case2.label}</th></tr>` +
    row('max error Y', 'max_error_y_um', 'nm') + row('max error Z', 'max_error_z_um', 'nm') +
    row('RMS error', 'rms_error_um', 'nm') + row('relative error', 'relative_error_pct', '%', RELATIVE_ERROR) +
    (r && r.error_per_period_um ? `<tr><td>error per period, first → last (nm)</td><td class="num">${fmt(r.error_per_period_um[0] * 1e3)} → ${fmt(r.error_per_period_um[r.error_per_period_um.length - 1] * 1e3)}</td><td></td><td></td></tr>` : '');
  const periods = r && r.evaluated_periods ? `${r.evaluated_periods} steady period${r.evaluated_periods === 1 ? '' : 's'}` : 'steady periods (up to 5)';
  root.querySelector('#traj-relative-note').textContent = `Relative error: ${RELATIVE_ERROR}; the max errors and RMS are over the run's last ${periods}, after the ramp. The paper's columns are its measured max errors and the relative error they give by this definition (its text states one bound, < ${fmt(PAPER.case1.relative_error_below_pct)} %, for both cases).`;
}

export function leave() {
  if (controller) controller.abort();
  destroyAll(charts);
}

// The PID the run used, per axis: gains, the mode damping section beside them and the margins
// predicted on the identified plant.
function renderPid(root, report) {
  const num = (v, unit) => (v === null || v === undefined ? '—' : `${fmt(v)} ${unit}`);
  // the PPF section's own tuning, not the mode: it sits above the mode the feedforward model's plant has
  const damping = (d, plant) => (d ? `PPF section tuned to ${fmt(d.frequency_hz)} Hz${plant && plant.resonance_hz
    ? ` (${fmt(d.frequency_hz / plant.resonance_hz, 3)}× the ${fmt(plant.resonance_hz)} Hz mode the tuning assumed${plant.resonance_of ? `: ${esc(plant.resonance_of)}` : ''})` : ''}, ζ ${fmt(d.damping_ratio)}, ${fmt(d.gain_v_per_um)} V/µm` : 'none');
  const rows = Object.entries(report.axes).map(([axis, a]) => {
    const m = a.margins || {};
    return `<tr><td>${esc(axis.toUpperCase())}</td><td>${fmt(a.kp)}</td><td>${fmt(a.ki)}</td><td>${fmt(a.kd)}</td>
      <td class="mode-damping">${damping(a.damping, a.plant)}</td>
      <td>${a.margins ? (m.stable ? 'stable' : 'unstable') : 'not predicted'}</td><td>${num(m.phase_margin_deg, '°')}</td>
      <td>${num(m.gain_margin_db, 'dB')}</td><td>${m.delay_margin_s != null ? fmt(m.delay_margin_s * 1e6) + ' µs' : '—'}</td></tr>`;
  }).join('');
  root.querySelector('#traj-pid-report').innerHTML = `<table id="traj-pid-table"><caption>PID: ${esc(report.pid)}</caption>
    <tr><th>axis</th><th>kp (V/µm)</th><th>ki (V/(µm·s))</th><th>kd (V·s/µm)</th><th title="positive position feedback on the flexure mode, beside the PID">mode damping</th><th>loop</th><th>phase margin</th>
    <th>gain margin</th><th>delay margin</th></tr>${rows}</table>`;
}
