// The seed paper's published figures, read once from GET /api/paper (service/science/paper.py is
// their only source): Table 6 per axis and the tracking cases, in the shapes the pages draw.
import { api } from './api.js';

let figures = null;

/** The figures as the API gives them (fetched on first use, then kept). */
export async function paperFigures(signal) {
  if (!figures) figures = await api('/paper', { signal });
  return figures;
}

/** Table 6 of one axis: {frequency_hz: [dynamic PI, GRPI, static PI]} (µm). */
export function table6(paper, axis) {
  const rows = paper.table6_rms_um[axis] || [];
  return Object.fromEntries(rows.map((r) => [r.frequency_hz, paper.table6_models.map((m) => r[m])]));
}

/** The tracking cases with the Trajectories form's fields: {case1: {label, max_error_y_um, …, form}}. */
export function trackingCases(paper) {
  return Object.fromEntries(Object.entries(paper.tracking_cases).map(([name, c]) => {
    const [y0, y1] = c.body.y_range_um, [z0, z1] = c.body.z_range_um;
    return [name, { label: c.label, max_error_y_um: c.max_error_um.y, max_error_z_um: c.max_error_um.z,
      relative_error_pct: c.relative_error_pct, relative_error_below_pct: c.relative_error_below_pct,
      form: { min_y_um: y0, amplitude_y_um: y1 - y0, min_z_um: z0, amplitude_z_um: z1 - z0, inclination_deg: c.body.inclination_deg } }];
  }));
}
