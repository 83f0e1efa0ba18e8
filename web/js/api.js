// REST client of the dashboard: JSON in and out, the API token (if set) as a Bearer header,
// errors carrying the API's own `detail` in words, and job progress from the SSE stream.
// A 401 answer fires the window event 'evc:unauthorized' (the shell then asks for a token).

const TOKEN_KEY = 'evcbench.token';

export function getToken() { return localStorage.getItem(TOKEN_KEY) || ''; }
export function setToken(value) {
  if (value) localStorage.setItem(TOKEN_KEY, value); else localStorage.removeItem(TOKEN_KEY);
}

export class ApiError extends Error {
  constructor(status, detail, field) {
    super(detail);
    this.status = status;
    this.field = field || null;
  }
}

function headers(extra = {}) {
  const h = { ...extra };
  const token = getToken();
  if (token) h.Authorization = `Bearer ${token}`;
  return h;
}

/** Call /api + path. `body` is sent as JSON, `form` (FormData) as multipart. */
export async function api(path, { method = 'GET', body, form, signal } = {}) {
  const init = { method, signal, headers: headers() };
  if (body !== undefined) {
    init.headers['Content-Type'] = 'application/json';
    init.body = JSON.stringify(body);
  } else if (form) {
    init.body = form;
  }
  let response;
  try {
    response = await fetch(`/api${path}`, init);
  } catch (err) {
    if (err.name === 'AbortError') throw err;
    throw new ApiError(0, `cannot reach the service (${err.message})`);
  }
  return readAnswer(response);
}

const STOP_PORT_TIMEOUT_MS = 2000;

/** The emergency stop: on the bench engine's own stop port when the service names one (GET
 *  /api/bench's engine.stop_port and bench_id; it waits for nothing the service's web process
 *  does); if this browser cannot reach that port or it does not stop this bench (any answer but
 *  200: not ready yet, another bench's port), POST /api/bench/stop on the service itself. */
export async function pressStop(stopPort, benchId) {
  if (stopPort) {
    try {
      const url = `${location.protocol}//${location.hostname}:${stopPort}/api/bench/stop?bench_id=${encodeURIComponent(benchId)}`;
      // The port answers within milliseconds; a firewall that drops packets must not hold the stop up.
      const response = await fetch(url, { method: 'POST', headers: headers(), signal: AbortSignal.timeout(STOP_PORT_TIMEOUT_MS) });
      if (response.status === 200) return response.json();
    } catch (_) { /* unreachable from here (a firewall): the service's own route below */ }
  }
  return api('/bench/stop', { method: 'POST' });
}

/** The JSON of an answer, or an ApiError with the API's `detail` and `field`. */
async function readAnswer(response) {
  if (!response.ok) {
    let detail = `${response.status} ${response.statusText}`;
    let field = null;
    try {
      const payload = await response.json();
      if (payload.detail !== undefined) {
        detail = typeof payload.detail === 'string' ? payload.detail : JSON.stringify(payload.detail);
      }
      field = payload.field || null;
    } catch (_) { /* not JSON */ }
    if (response.status === 401) {
      detail = `${detail}. Paste an API token under Settings (top right); on the service's machine it is in ` +
               '<data dir>/admin.token.';
      window.dispatchEvent(new CustomEvent('evc:unauthorized', { detail }));
    }
    throw new ApiError(response.status, detail, field);
  }
  if (response.status === 204) return null;
  return response.json();
}

/** Download an API file (CSV/HDF5) with the token, as the browser's own download. */
export async function download(path, filename) {
  const response = await fetch(`/api${path}`, { headers: headers() });
  if (!response.ok) throw new ApiError(response.status, `download failed: ${response.status}`);
  const blob = await response.blob();
  const url = URL.createObjectURL(blob);
  const a = Object.assign(document.createElement('a'), { href: url, download: filename });
  document.body.append(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(url), 1000);
}

let openapiPaths = null;
/** The set of "METHOD /path" the service offers (from its OpenAPI document), so pages can tell
 *  whether an endpoint exists without probing it. */
export async function capabilities() {
  if (!openapiPaths) {
    openapiPaths = (async () => {
      const response = await fetch('/openapi.json', { headers: headers() });
      const doc = response.ok ? await response.json() : { paths: {} };
      const set = new Set();
      for (const [path, ops] of Object.entries(doc.paths || {})) {
        for (const method of Object.keys(ops)) set.add(`${method.toUpperCase()} ${normalise(path)}`);
      }
      return set;
    })();
  }
  return openapiPaths;
}
const normalise = (path) => path.replace(/\{[^}]*\}/g, '{}');
/** Does the service offer e.g. 'GET /api/models/{id}/diagnosis'? (parameter names do not matter) */
export async function has(methodAndPath) {
  const [method, path] = methodAndPath.split(' ');
  return (await capabilities()).has(`${method} ${normalise(path)}`);
}

const TERMINAL = new Set(['succeeded', 'failed', 'cancelled']);
export const isTerminal = (job) => TERMINAL.has(job.state);

/** Follow a job until it ends: onUpdate(job) on every progress event; resolves with the final job.
 *  Reads GET /api/jobs/{id}/events (SSE, via fetch so the token header is sent); polls if the
 *  stream breaks or ends with an `error` event (a revoked token: the poll then gets the 401). */
export async function followJob(jobId, onUpdate = () => {}, { signal } = {}) {
  try {
    const response = await fetch(`/api/jobs/${jobId}/events`, { headers: headers(), signal });
    if (!response.ok || !response.body) throw new Error('no stream');
    const reader = response.body.getReader();
    const decoder = new TextDecoder();
    let buffer = '';
    let last = null;
    for (;;) {
      const { value, done } = await reader.read();
      if (done) break;
      buffer += decoder.decode(value, { stream: true });
      let cut;
      while ((cut = buffer.indexOf('\n\n')) >= 0) {
        const chunk = buffer.slice(0, cut);
        buffer = buffer.slice(cut + 2);
        let event = 'message';
        const data = [];
        for (const line of chunk.split('\n')) {
          if (line.startsWith('event:')) event = line.slice(6).trim();
          else if (line.startsWith('data:')) data.push(line.slice(5).trim());
        }
        if (!data.length) continue;
        if (event === 'error') {  // the token was revoked meanwhile: the poll below meets the 401
          reader.cancel().catch(() => {});
          throw new Error(JSON.parse(data.join('\n')).detail);
        }
        last = JSON.parse(data.join('\n'));
        onUpdate(last);
        if (event === 'end' || isTerminal(last)) {
          reader.cancel().catch(() => {});
          return last;
        }
      }
    }
    if (last && isTerminal(last)) return last;
  } catch (err) {
    if (err.name === 'AbortError') throw err;
  }
  // Fallback: poll.
  for (;;) {
    const job = await api(`/jobs/${jobId}`, { signal });
    onUpdate(job);
    if (isTerminal(job)) return job;
    await new Promise((r) => setTimeout(r, 300));
  }
}

export const fmt = (v, digits = 4) => (v === null || v === undefined || Number.isNaN(Number(v))) ? '–'
  : String(Number(Number(v).toPrecision(digits)));
/** A reading at a fixed number of decimals (volts, milliamps): a figure that rounds to zero prints
 * unsigned ("0.0", not the "-0.0" of a signed zero or of -0.01 mA). */
export const fmtFixed = (v, decimals) => {
  const text = Number(v).toFixed(decimals);
  return Number(text) === 0 ? (0).toFixed(decimals) : text;
};
/** An error or noise figure given in µm, printed in nm: the one unit for errors and noise across the
 * API's texts, the dashboard and the report (0.002945 → "2.95 nm", 1.2 → "1200 nm"). */
export const fmtErrorNm = (um, digits = 3) => (um === null || um === undefined || !Number.isFinite(Number(um))) ? '–'
  : `${fmt(um * 1e3, digits)} nm`;
export const esc = (s) => String(s ?? '').replace(/[&<>"']/g, (c) => ({ '&': '&amp;', '<': '&lt;', '>': '&gt;', '"': '&quot;', "'": '&#39;' }[c]));
