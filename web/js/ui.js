// Small DOM helpers shared by the pages: elements, the banner, job progress lines.
import { api, esc, fmt, followJob } from './api.js';

export function h(html) {
  const t = document.createElement('template');
  t.innerHTML = html.trim();
  return t.content.firstElementChild;
}

export function banner(text, kind = 'error') {
  const el = document.getElementById('banner');
  if (!text) { el.hidden = true; return; }
  el.className = kind;
  el.textContent = text;
  el.hidden = false;
}

/** Show an error in words (the API's `detail`) in `el` and the page banner. */
export function showError(el, err, prefix = '') {
  if (err && err.name === 'AbortError') return;
  const text = `${prefix}${err && err.message ? err.message : String(err)}`;
  if (el) { el.textContent = text; el.classList.add('error'); }
  else banner(text);
}

/** A progress line for a job, updated live: "<kind> <state> [=====] 42 % message". */
export function jobLine(title = '') {
  const el = h(`<div class="jobline" data-job-id="" data-state="" data-progress="0">
      <span class="jtitle">${esc(title)}</span>
      <span class="jstate"></span>
      <div class="progress"><div style="width:0%"></div></div>
      <span class="jpct">0 %</span>
      <span class="jmsg muted"></span>
    </div>`);
  el.update = (job) => {
    el.dataset.jobId = job.id;
    el.dataset.state = job.state;
    el.dataset.progress = String(job.progress ?? 0);
    el.querySelector('.jstate').textContent = job.state;
    el.querySelector('.jstate').className = `jstate state-${job.state}`;
    const pct = Math.round(100 * (job.progress ?? 0));
    el.querySelector('.progress > div').style.width = `${pct}%`;
    el.querySelector('.jpct').textContent = `${pct} %`;
    el.querySelector('.jmsg').textContent = job.error ? `error: ${job.error}` : (job.message || '');
  };
  return el;
}

/** Start a job with POST `path` and follow it with a jobLine in `container`; resolves with the final job. */
export async function runJob(container, path, body, title, { signal, onUpdate } = {}) {
  const line = jobLine(title);
  container.replaceChildren(line);
  const started = await api(path, { method: 'POST', body, signal });
  line.update({ id: started.job_id, state: started.state || 'queued', progress: 0 });
  window.dispatchEvent(new CustomEvent('evc:job', { detail: { id: started.job_id } }));
  const job = await followJob(started.job_id, (j) => { line.update(j); if (onUpdate) onUpdate(j); }, { signal });
  line.update(job);
  window.dispatchEvent(new CustomEvent('evc:job', { detail: job }));   // the top bar's bench pill refreshes
  return job;
}

export function numberInput(name, value, { step = 'any', min, max, width } = {}) {
  return `<input name="${name}" type="number" step="${step}" value="${value}"${min !== undefined ? ` min="${min}"` : ''}${max !== undefined ? ` max="${max}"` : ''}${width ? ` style="width:${width}px"` : ''}>`;
}

export { fmt, esc };
