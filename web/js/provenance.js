// Where data came from: recorded on a bench of this service, or imported from another stage's file.
// A model fitted on imported data describes that other stage: this bench cannot run its
// experiments, and its figures are not comparable with the paper's device.
import { esc } from './api.js';

/** True for a dataset imported from a file (source "import"), not recorded here. */
export const isImported = (d) => d.source === 'import';

/** The ids of the imported datasets among `datasets` (a Set). */
export const importedIds = (datasets) => new Set(datasets.filter(isImported).map((d) => d.id));

/** True when `model` was fitted on at least one imported dataset (the service's `origin`, else the
 * ids of `imported`). */
export const onImportedData = (model, imported) => (model.origin
  ? model.origin.fitted_on !== 'this_bench' : model.datasets.some((id) => imported?.has(id)));

/** An imported dataset of a model's origin (`{dataset_id, name, filename}`): by its name as stored now,
 * the file it came from beside it where the name is another ("“stage B” from the file b.csv"; the file
 * had named it until a rename); the file alone where the name is still the file's. Text, unless `text`
 * and `file` render the name and the file name otherwise (HTML). */
export function importedDataName(i, { text = (s) => s, file = text } = {}) {
  const name = i.name || i.dataset_id;
  return i.filename && i.filename !== name ? `“${text(name)}” from the file ${file(i.filename)}` : file(name);
}

/** What a model describes (HTML-escaped): this bench's data, or the data another stage recorded. */
export function modelOriginHtml(model) {
  const o = model.origin;
  if (!o || o.fitted_on === 'this_bench') return 'this bench’s data';
  const files = o.imported.map((i) => importedDataName(i, { text: esc, file: (f) => `<code>${esc(f)}</code>` })).join(', ');
  return `${o.fitted_on === 'mixed' ? 'partly ' : ''}imported data (${files}): another stage`;
}

/** A dataset's origin (HTML-escaped): the bench that recorded it, or the file it was imported from and
 * when, alike in the list and on its page. No name: the import record keeps none (the dataset's name is
 * a label, renamed at will, shown beside it). */
export function originHtml(d) {
  if (!isImported(d)) return esc(d.bench_id || 'this bench');
  const file = d.import_filename || d.plan?.import?.filename;
  const at = d.created_at ? ` on <time datetime="${esc(d.created_at)}" title="${esc(d.created_at)}">${esc(String(d.created_at).slice(0, 16).replace('T', ' '))}${String(d.created_at).endsWith('Z') ? ' UTC' : ''}</time>` : '';
  return `imported${file ? ` from <code>${esc(file)}</code>` : ''}${at}`;
}

/** The bench a model's data were recorded on (HTML-escaped): its bench for this bench's data; for imported
 * data another stage, the bench that stores it named apart (an import's bench_id is the service's own). */
export function modelBenchHtml(model) {
  const bench = esc(model.bench_id || '—');
  const fittedOn = model.origin?.fitted_on || 'this_bench';
  if (fittedOn === 'this_bench') return bench;
  const stored = `<span class="muted">(stored by ${bench})</span>`;
  return fittedOn === 'mixed' ? `${bench} and another stage ${stored}` : `another stage ${stored}`;
}
