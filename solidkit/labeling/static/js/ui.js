// Small DOM helpers and the panel pieces every task uses.

import { wrap180 } from './frames.js';

export const $ = (sel, root = document) => root.querySelector(sel);
export const el = (tag, attrs = {}, ...children) => {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs)) {
    if (k === 'class') e.className = v;
    else if (k.startsWith('on')) e.addEventListener(k.slice(2), v);
    else if (v !== null && v !== undefined && v !== false) e.setAttribute(k, v === true ? '' : v);
  }
  for (const c of children.flat()) if (c !== null && c !== undefined) e.append(c.nodeType ? c : document.createTextNode(String(c)));
  return e;
};
// replaceChildren with null/undefined entries left out
export const fill = (node, ...kids) => node.replaceChildren(...kids.flat().filter(k => k !== null && k !== undefined && k !== false));
export const f2 = (x, d = 2) => (x === null || x === undefined ? '–' : Number(x).toFixed(d));
export const TASK_NAMES = { sun: 'Sun', probe_pixel: 'Probe pixels', heading: 'Heading', review: 'Review' };

export function formatValue(kind, v) {
  if (!v) return '–';
  if (kind === 'sun') return v.found === false ? 'no sun visible' : `az ${f2(wrap180(v.azimuth_deg))}°, el ${f2(v.elevation_deg)}°` + (v.uncertainty_deg != null ? ` ±${f2(v.uncertainty_deg)}°` : '');
  if (kind === 'probe_pixel') return `x ${f2(v.x, 1)}, y ${f2(v.y, 1)} px`;
  if (kind === 'heading') return v.yaw_deg == null ? 'unknown' : `yaw ${f2(v.yaw_deg)}°`;
  return JSON.stringify(v);
}

export function panelHeader(app, item) {
  const flags = (item.review.flags || []).map(f => el('span', { class: 'chip' }, f));
  return [
    el('h2', {}, item.title),
    flags.length ? el('div', { class: 'chips' }, flags) : null,
  ];
}

export function savedLine(app, item) {
  if (app.blind && !app.reviewing) return el('div', { class: 'row muted' }, 'blind mode: other labels hidden');
  const lab = item.label;
  return el('div', { class: 'row' }, el('span', { class: 'swatch saved' }), 'Stored: ',
    lab ? el('b', { id: 'saved-value' }, formatValue(item.kind, lab.value)) : el('i', {}, 'none'),
    lab ? el('span', { class: 'muted' }, ` — ${lab.annotator} (${lab.source}), v${lab.version}`) : null);
}

export function opinionsBlock(app, item) {
  const ops = item.review.opinions || {};
  const names = Object.keys(ops);
  if (names.length < 2 || (app.blind && !app.reviewing)) return null;
  const u = item.review.unit;
  return el('div', { class: 'opinions' },
    el('div', { class: 'row' }, `Annotators (${names.length}) are `, el('b', {}, item.review.disagreement === 'inf' ? 'found vs none' : u === 'deg' ? `${f2(item.review.disagreement)}°` : `${f2(item.review.disagreement, 1)} ${u}`), ' apart'),
    el('ul', {}, names.map(n => el('li', {}, `${n}: ${formatValue(item.kind, ops[n].value)}`))));
}

export function historyBlock(app, item) {
  // blind: only the annotator's own changes (another's value, or align's, would tell them the answer)
  const blind = app.blind && !app.reviewing;
  const rows = blind ? item.history.filter(h => h.actor === app.annotator) : item.history;
  if (!rows.length) return null;
  const title = blind ? `Your history (${rows.length}; others hidden in blind mode)` : `History (${rows.length})`;
  return el('details', { class: 'history' }, el('summary', {}, title),
    el('ol', {}, rows.slice().reverse().map(h => el('li', {},
      `v${h.version} ${h.op}${h.applied ? '' : ' (not applied)'} by ${h.actor}: `,
      h.value ? formatValue(item.kind, h.value) : 'removed',
      el('span', { class: 'muted' }, ` ${h.source || ''} · ${h.time.slice(0, 19).replace('T', ' ')}`)))));
}

export function button(label, key, onclick, id, cls = '') {
  return el('button', { id, class: cls, onclick, title: key ? `shortcut: ${key}` : null }, label, key ? el('kbd', {}, key) : null);
}

export function slider(id, label, min, max, step, value, fmt, oninput) {
  const out = el('span', { class: 'val', id: `${id}-val` }, fmt(value));
  const input = el('input', { type: 'range', id, min, max, step, value });
  input.addEventListener('input', () => { out.textContent = fmt(+input.value); oninput(+input.value); });
  return el('label', { class: 'slider' }, el('span', {}, label), input, out);
}
