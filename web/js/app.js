// The dashboard shell: hash routing between pages, the always-visible emergency stop, the bench
// pill (which job owns the bench), and the API token in the settings corner.
import { api, fmtFixed, getToken, pressStop, setToken } from './api.js';
import { banner } from './ui.js';

const PAGES = {
  bench: () => import('./pages/bench.js'),
  sweeps: () => import('./pages/sweeps.js'),
  datasets: () => import('./pages/datasets.js'),
  models: () => import('./pages/models.js'),
  trajectories: () => import('./pages/trajectories.js'),
  lab: () => import('./pages/lab.js'),
};

let current = null;

async function route() {
  const [path, search = ''] = location.hash.replace(/^#\/?/, '').split('?');
  const [name = 'bench', ...rest] = path.split('/');
  const query = Object.fromEntries(new URLSearchParams(search));
  const page = PAGES[name] ? name : 'bench';
  document.querySelectorAll('#nav a').forEach((a) => a.classList.toggle('active', a.dataset.page === page));
  if (current && current.leave) current.leave();
  const root = document.getElementById('page');
  root.innerHTML = '';
  root.dataset.page = page;
  root.dataset.ready = '0';
  banner(null);
  try {
    const module = await PAGES[page]();
    current = module;
    await module.enter(root, rest.filter(Boolean).map(decodeURIComponent), query);
  } catch (err) {
    if (err && err.name !== 'AbortError') banner(err.message || String(err));
  } finally {
    root.dataset.ready = '1';
  }
}

/** The engine's stop port and the bench it stops, as the last GET /api/bench named them (the
 *  pill's polling keeps them current). */
let stopPort = null;
let benchId = '';

async function emergencyStop() {
  const button = document.getElementById('estop');
  button.disabled = true;
  try {
    const r = await pressStop(stopPort, benchId);
    const volts = Object.entries(r.output_v || {}).map(([a, v]) => `${a} ${fmtFixed(v, 2)} V`).join(', ');
    banner(`Emergency stop (${r.door || 'service route'}): outputs at ${volts || '0 V'}` +
           (r.cancelled_job_id ? `; job ${r.cancelled_job_id} cancelled` : '; no bench job was running') +
           ((r.cancelled_queued_job_ids || []).length ? `; queued bench jobs cancelled too: ${r.cancelled_queued_job_ids.join(', ')}.` : '.') +
           (r.cancelled_queued_job_ids === null ? ' Queued bench jobs: cancelled by the service (the bench runs none until it has).' : ''), 'info');
    document.getElementById('banner').dataset.stopped = JSON.stringify(r);
  } catch (err) {
    banner(`Emergency stop FAILED: ${err.message}`);
  } finally {
    button.disabled = false;
  }
}

/** The bench engine's state from GET /api/health (no token needed): a red strip while it is absent
 *  or restarting (503 "degraded", with the reason), an amber one while a restart's fault is latched
 *  (until Reset latched faults on the Bench page), none otherwise; the health goes out as the window
 *  event 'evc:engine'. */
async function refreshEngineState() {
  const strip = document.getElementById('engine-state');
  if (!strip) return;   // the document is no longer the dashboard (replaced while a refresh was due)
  let health = null;
  try {
    const response = await fetch('/api/health');
    health = await response.json();
  } catch (err) {
    health = { status: 'degraded', engine: 'unreachable', reason: `cannot reach the service (${err.message})` };
  }
  if (health.status === 'degraded') {
    strip.dataset.state = 'degraded';
    strip.textContent = `Bench engine ${health.engine}: ${health.reason}. Outputs are driven to 0 V; bench jobs are refused until a fresh engine is up.`;
    strip.hidden = false;
  } else if (health.latched_fault) {
    strip.dataset.state = 'latched';
    strip.textContent = `Latched fault: ${health.latched_fault}. Reset latched faults (Bench page) before the bench runs again.`;
    strip.hidden = false;
  } else {
    strip.dataset.state = '';
    strip.hidden = true;
  }
  window.dispatchEvent(new CustomEvent('evc:engine', { detail: health }));  // the Bench page marks its state stale
}

async function refreshPill() {
  refreshEngineState();
  const pill = document.getElementById('bench-pill');
  if (!pill) return;
  try {
    const bench = await api('/bench');
    stopPort = (bench.engine && bench.engine.stop_port) || null;
    benchId = bench.bench_id;
    pill.textContent = bench.running_job_id ? `bench busy: ${bench.running_job_id}` : `bench idle · ${bench.backend}`;
    pill.dataset.runningJob = bench.running_job_id || '';
  } catch (err) {
    pill.textContent = err.status === 401 ? 'bench: API token needed' : `bench: ${err.message}`;
  }
}

/** A link may carry the token in its fragment (#/page?token=evc_…): store it, drop it from the address. */
function takeTokenFromAddress() {
  const [path, search = ''] = location.hash.split('?');
  const query = new URLSearchParams(search);
  if (!query.has('token')) return;
  setToken(query.get('token'));
  query.delete('token');
  const rest = query.toString();
  history.replaceState(null, '', `${location.pathname}${location.search}${path}${rest ? `?${rest}` : ''}`);
}

/** The API answered 401: open the settings with the token field and say what to paste (once,
 *  until a token is saved: the bench pill's polling must not steal the focus every 2 s). */
let askedForToken = false;
function askForToken(event) {
  if (askedForToken) return;
  askedForToken = true;
  document.getElementById('settings').open = true;
  document.getElementById('token').focus();
  banner(event.detail);
}

function setup() {
  takeTokenFromAddress();
  document.getElementById('estop').addEventListener('click', emergencyStop);
  const token = document.getElementById('token');
  token.value = getToken();
  window.addEventListener('evc:unauthorized', askForToken);
  document.getElementById('token-save').addEventListener('click', async () => {
    setToken(token.value.trim());
    askedForToken = false;
    document.getElementById('settings').open = false;   // saved: out of the page's way (a 401 opens it again)
    await route();
    banner('API token saved in this browser.', 'info');
    refreshPill();
  });
  window.addEventListener('hashchange', route);
  refreshPill();
  setInterval(refreshPill, 2000);
  window.addEventListener('evc:job', refreshPill);
  route();
}

setup();
