// The Trajectories page's guided path, run by the service as one job (POST /api/trajectories/prepare):
// the first sweep and models where an axis has none, then the span sweeps this ellipse needs and models
// on them. The job goes on when the tab closes; on entering the page, the newest prepare job is found
// again (GET /api/jobs?kind=prepare): followed while it runs, its models selected once it has ended.
import { api, esc, fmtErrorNm, followJob, isTerminal } from './api.js';
import { h, jobLine } from './ui.js';

// the form's ellipse fields a prepare job's params hold (its models are fitted on that ellipse's span)
const ELLIPSE_FIELDS = ['min_y_um', 'amplitude_y_um', 'min_z_um', 'amplitude_z_um', 'inclination_deg', 'frequency_hz', 'cycles'];

/** The steps a prepare job has done (its partial result while it runs), one line each. */
function renderSteps(list, job) {
  const steps = (job.result && job.result.steps) || [];
  list.replaceChildren(...steps.map((s) => h(`<li class="prep-step" data-step="${esc(s.step)}" data-axis="${esc(s.axes.join('+'))}">
    ${esc(s.what)}: ${s.step === 'model'
      ? `model <a href="#/models/${encodeURIComponent(s.model_id)}">${esc(s.model_id)}</a>, held-out RMS ${fmtErrorNm(s.validation_rms_um)}`
      : `dataset <a href="#/datasets/${encodeURIComponent(s.dataset_id)}">${esc(s.dataset_id)}</a>`}</li>`)));
}

/** Follow prepare job `jobId` in `out` (its progress line and steps) until it ends; the final job. */
async function follow(out, jobId, signal) {
  const line = jobLine('prepare');
  const list = h('<ol class="prep-steps"></ol>');
  out.replaceChildren(line, list);
  const update = (job) => { line.update(job); renderSteps(list, job); };
  update(await api(`/jobs/${encodeURIComponent(jobId)}`, { signal }));
  const job = await followJob(jobId, update, { signal });
  update(job);
  return job;
}

/** The ellipse a prepare job prepared for, back in the form (its models are fitted on that span). */
function restoreEllipse(form, job) {
  for (const key of ELLIPSE_FIELDS) {
    if (job.params && job.params[key] !== null && job.params[key] !== undefined) form.elements[key].value = job.params[key];
  }
  const restored = new Event('input');
  restored.restored = true;  // not the user's edit (resumePrepare tells the two apart)
  form.dispatchEvent(restored);  // as if typed: what reads the fields (the preset) follows
}

/** Put an ended prepare job's outcome in the form: its ellipse, its models and the controller the
 * recipe recommends (succeeded), or its error (failed, cancelled) beside the steps it did. */
function apply(root, job, selectModel) {
  const form = root.querySelector('#traj-form');
  const out = root.querySelector('#traj-span');
  const result = job.result || {};
  restoreEllipse(form, job);
  if (job.state !== 'succeeded') {
    out.append(h(`<p class="error" id="traj-prepare-failed">The prepare job ${esc(job.id)} ${esc(job.state)}: ${esc(job.error || job.message || '')}.
      ${result.steps && result.steps.length ? 'The steps above were done; press “Prepare the models it needs” to go on from their models.' : ''}</p>`));
    for (const axis of ['y', 'z']) if (result[`feedforward_model_${axis}`]) selectModel(form, axis, result[`feedforward_model_${axis}`]);
    return;
  }
  for (const axis of ['y', 'z']) selectModel(form, axis, result[`feedforward_model_${axis}`]);
  form.elements.pid.value = result.controller.pid;
  form.elements.ilc.checked = Boolean(result.controller.ilc);
  root.querySelector('#traj-gains').hidden = true;
  // the recommendation, not what a later run used: the form may be changed before each run
  out.append(h(`<p class="ok" id="traj-prepared">Models ready and selected (prepare job ${esc(job.id)}); recommended:
    PID ${esc(result.controller.pid)}${result.controller.ilc ? ' with ILC' : ''}<span class="run-hint">, set in the form: press Run</span>.
    <span class="muted">Why these: ${esc(result.why)}.</span></p>`));
}

/** Start the guided path for the form's ellipse (`body`, a POST /api/trajectories body) and follow it. */
export async function startPrepare(root, body, signal, selectModel) {
  const started = await api('/trajectories/prepare', { method: 'POST', body, signal });
  window.dispatchEvent(new CustomEvent('evc:job', { detail: { id: started.job_id } }));
  apply(root, await follow(root.querySelector('#traj-span'), started.job_id, signal), selectModel);
}

/** On entering the page: the newest prepare job, followed while it runs, its outcome put in the form. */
export async function resumePrepare(root, signal, selectModel) {
  // the user's edits made while the newest job is fetched or followed win over that job's ellipse and
  // models (a user who picked a case before it arrived saw the page put the last job's case back)
  const form = root.querySelector('#traj-form');
  let edited = false;
  const mark = (e) => { if (!e.restored) edited = true; };
  form.addEventListener('input', mark);
  form.addEventListener('change', mark);
  const [last] = await api('/jobs?kind=prepare&limit=1', { signal });
  if (!last) return;
  if (!edited) restoreEllipse(form, last);
  const button = root.querySelector('#traj-span-sweep');
  button.disabled = !isTerminal(last);
  // an ended job's models are selected only while they are stored (listed in the form)
  const listed = (form, axis, id) => {
    if ([...form.elements[`feedforward_model_${axis}`].options].some((o) => o.value === id)) selectModel(form, axis, id);
  };
  try {
    const job = isTerminal(last) ? last : await follow(root.querySelector('#traj-span'), last.id, signal);
    if (isTerminal(last)) renderSteps(root.querySelector('#traj-span').appendChild(h('<ol class="prep-steps"></ol>')), job);
    // an ended job's outcome only where the user has not started on the form; a followed one's always
    if (!edited || !isTerminal(last)) apply(root, job, isTerminal(last) ? listed : selectModel);
  } finally {
    button.disabled = false;
    form.removeEventListener('input', mark);
    form.removeEventListener('change', mark);
  }
}
