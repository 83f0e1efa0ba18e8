// The effects library (GET /api/effects): every effect discovery may add, with where it came from
// (built-in, an entry point or a plug-in file), its parameters with units and its rule; and the
// plug-ins the service refused at start-up, each with its error.
import { esc } from './api.js';

/** A collapsible card listing `catalogue` ({effects, failed}) in `el`. */
export function renderEffects(el, catalogue) {
  const plugins = catalogue.effects.filter((e) => e.origin !== 'builtin').length;
  const rows = catalogue.effects.map((e) => `<tr data-effect="${esc(e.name)}"><td>${esc(e.name)}</td>
    <td>${esc(e.kind)}</td><td class="origin">${esc(e.origin)}</td>
    <td>${e.parameters.map((p) => `${esc(p.name)} [${esc(p.unit)}]`).join(', ')}</td><td>${esc(e.rule)}</td></tr>`).join('');
  const failed = catalogue.failed.map((f) => `<li class="error" data-failed="${esc(f.name)}"><b>${esc(f.name)}</b>
    (${esc(f.origin)}): ${esc(f.error)}</li>`).join('');
  el.innerHTML = `<details class="card" id="effects-library"><summary><h2 style="display:inline">Effects library</h2>
    ${catalogue.effects.length} effects, ${plugins} plug-in${plugins === 1 ? '' : 's'}${catalogue.failed.length ? `, <span class="error">${catalogue.failed.length} refused</span>` : ''}</summary>
    <div class="scroll-list"><table><tr><th>effect</th><th>kind</th><th>origin</th><th>parameters</th><th>what the data must contain</th></tr>${rows}</table></div>
    ${failed ? `<h3>Refused plug-ins</h3><ul id="effects-failed">${failed}</ul>` : ''}</details>`;
}
