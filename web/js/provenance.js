// Where data came from: recorded on a bench of this service, or imported from another stage's file.
// A model fitted on imported data describes that other stage: this bench cannot run its
// experiments, and its figures are not comparable with the paper's device.
import { esc } from './api.js';

/** True for a dataset imported from a file (source "import"), not recorded here. */
export const isImported = (d) => d.source === 'import';

/** The ids of the imported datasets among `datasets` (a Set). */
export const importedIds = (datasets) => new Set(datasets.filter(isImported).map((d) => d.id));

/** True when `model` was fitted on at least one imported dataset. */
export const onImportedData = (model, imported) => model.datasets.some((id) => imported.has(id));

/** A dataset's origin (HTML-escaped): the bench that recorded it, or the file it was imported from (the
 * list's rows carry no plan: there the dataset's name stands for the file). */
export function originHtml(d) {
  if (!isImported(d)) return esc(d.bench_id || 'this bench');
  const file = d.plan?.import?.filename || d.name;
  return `imported from <code>${esc(file)}</code>`;
}
