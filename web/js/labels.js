// Name, tags and notes of a dataset or a model (PATCH /api/datasets/{id} or /api/models/{id}): the
// data and parameters never change. Stored values are shown as text, never as markup.
import { api, esc } from './api.js';
import { h, showError } from './ui.js';

/** The labels card of `record` (a dataset or a model; `kind` is 'datasets' or 'models'), appended to `el`.
 * `onSaved(updated)` runs after a successful save. */
export function renderLabels(el, kind, record, { signal, onSaved = () => {} } = {}) {
  const box = h(`<form class="labels inline" id="labels-form" data-kind="${esc(kind)}">
    <label>name <input name="name" maxlength="200" value="${esc(record.name || '')}" placeholder="${kind === 'models' ? 'unnamed' : ''}"></label>
    <label>tags (comma-separated) <input name="tags" maxlength="3000" value="${esc((record.tags || []).join(', '))}"></label>
    <label class="notes">notes <textarea name="notes" rows="2" cols="60" maxlength="20000">${esc(record.notes || '')}</textarea></label>
    <button type="submit" id="labels-save">Save labels</button>
    <span class="muted" id="labels-status"></span>
  </form>`);
  el.append(box);
  box.addEventListener('submit', async (e) => {
    e.preventDefault();
    const f = new FormData(box);
    const name = String(f.get('name') || '').trim();
    const notes = String(f.get('notes') || '');
    const body = {
      tags: String(f.get('tags') || '').split(',').map((t) => t.trim()).filter(Boolean),
      notes: notes.trim() ? notes : null,
    };
    // a model's name may be cleared (null); a dataset always keeps one
    if (name || kind === 'models') body.name = name || null;
    const status = box.querySelector('#labels-status');
    status.classList.remove('error');
    status.textContent = 'saving…';  // set at once, so a second save is never read as the first's 'saved'
    let updated;
    try {
      updated = await api(`/${kind}/${encodeURIComponent(record.id)}`, { method: 'PATCH', body, signal });
    } catch (err) { showError(status, err, 'Not saved: '); return; }
    try {
      await onSaved(updated);  // awaited, so that a refresh cut short by leaving the page is not uncaught
      status.textContent = 'saved';  // once the page shows the new labels too (a loaded test read the old list)
    } catch (err) { showError(status, err, 'Saved; the page did not refresh: '); }
  });
  return box;
}
