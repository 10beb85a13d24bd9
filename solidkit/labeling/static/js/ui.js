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
export const STATUS_TEXT = { left: 'to do', flagged: 'to do, flagged', returned: 'returned to you', done: 'done' };

// what each check's flag means, for the annotator (the raw flag stays in the tooltip)
const FLAG_TEXT = {
  no_photo: 'no photo of this scene', no_intrinsics: 'photo without lens data: its frame is estimated',
  no_photo_heading: 'the photo has no compass heading', no_camera_position: 'the camera position is unknown',
  clock_mismatch: 'the capture’s clock disagrees with the photo’s', focal_refined: 'the photo’s focal length was refined',
  photo_pose_disagrees: 'the photo’s tilt estimates disagree', photo_match_failed: 'the photo could not be matched automatically',
  photo_pose_unknown: 'the photo’s tilt is unknown (assumed level)', no_normal_shot: 'no normally exposed shot',
  no_panorama: 'no panorama for this position', label_differs: 'a label differs from the automatic value',
  features_failed: 'image matching failed', yaw_from_street_lines: 'heading guessed from street lines only',
  yaw_from_compasses: 'heading from the compasses only', yaw_from_sky: 'heading from the sky only',
  no_yaw: 'no automatic heading', single_cue: 'the heading rests on one clue only', no_agreement: 'the heading clues disagree',
  pixel_from_geometry: 'position estimated from the geometry', no_pixel: 'no automatic position',
  pixel_disagrees: 'the marked position and the geometry disagree', pixel_outside_photo: 'the position lies outside the photo',
  sun_candidates_rejected: 'several bright spots: check which is the sun', auto_differs: 'the automatic values disagree',
  disagrees_with_scene: 'disagrees with the scene’s other positions', position_disagrees: 'this position disagrees with the others',
  no_sun_found: 'no sun found automatically', no_sun: 'no sun found automatically', ephemeris_disagrees: 'the sun is not where the time and place put it',
  ephemeris_azimuth_disagrees: 'the sun’s direction is not where the time and place put it', sun_off_ephemeris: 'the sun is off its expected height',
  sun_frame_conflict: 'the sun frames disagree', no_ephemeris: 'no expected sun position (time or place unknown)',
  single_position: 'only one position in the scene', photo_pitch_roll_assumed_zero: 'the photo is assumed level',
  no_sun_frame: 'no sun frame', sun_frame_not_a_panorama: 'the sun frame is not a panorama',
  annotators_disagree: 'annotators disagree', differs_from_auto: 'the label differs from the automatic value',
  low_confidence: 'the automatic value is uncertain', ambiguous: 'ambiguous', glint: 'a reflection may look like the sun',
  'no photo intrinsics': 'photo without lens data: the frame cannot be drawn',
};

export function flagText(flag) {
  const code = String(flag).split(':')[0].trim();
  return FLAG_TEXT[code] || code.replace(/_/g, ' ');
}

// where an automatic proposal came from, in plain words
export function sourceText(src) {
  if (!src) return 'none';
  if (src === 'field_notes') return 'from the field notes';
  if (/geometry/.test(src)) return 'from the camera geometry';
  return 'automatic';
}

export function formatValue(kind, v) {
  if (!v) return '–';
  if (kind === 'sun') return v.found === false ? 'no sun visible' : `az ${f2(wrap180(v.azimuth_deg))}°, el ${f2(v.elevation_deg)}°` + (v.uncertainty_deg != null ? ` ±${f2(v.uncertainty_deg)}°` : '');
  if (kind === 'probe_pixel') return `x ${f2(v.x, 1)}, y ${f2(v.y, 1)} px`;
  if (kind === 'heading') return v.yaw_deg == null ? 'unknown' : `yaw ${f2(v.yaw_deg)}°`;
  return JSON.stringify(v);
}

export function panelHeader(app, item) {
  const reviewer = app.user && app.user.role === 'reviewer';
  const flags = (item.review.flags || []).map(f => el('span', { class: 'chip', title: reviewer ? f : null }, flagText(f)));
  const v = item.mine && item.mine.verdict;
  return [
    el('h2', { class: 'item-title' }, item.title),
    flags.length ? el('div', { class: 'chips' }, flags) : null,
    v && v.verdict === 'reject' ? el('div', { class: 'returned-box', id: 'returned' },
      el('b', {}, `Returned by ${v.reviewer}: `), v.comment, el('div', { class: 'muted small' }, 'Look again and save a new mark.')) : null,
  ];
}

export function savedLine(app, item) {
  const mine = item.mine;
  const yours = mine ? el('div', { class: 'row' }, el('span', { class: 'swatch saved' }), 'Yours: ',
    el('b', { id: 'mine-value' }, formatValue(item.kind, mine.value))) : null;
  if (item.blind) return [yours, el('div', { class: 'row muted' }, 'blind mode: other labels and the proposal are hidden')];
  const lab = item.label;
  if (lab && lab.source === 'auto') { // an automatic value in the store is a proposal, not a finished label
    return [yours, el('div', { class: 'row auto-stored', id: 'stored-auto' }, el('span', { class: 'swatch auto' }),
      'Automatic value (no person has checked it yet): ', formatValue(item.kind, lab.value))];
  }
  return [yours, el('div', { class: 'row' }, el('span', { class: 'swatch saved' }), 'Stored: ',
    lab ? el('b', { id: 'saved-value' }, formatValue(item.kind, lab.value)) : el('i', {}, 'none'),
    lab ? el('span', { class: 'muted' }, ` — ${lab.annotator}${lab.source === 'reviewed' ? ' (reviewed)' : ''}, v${lab.version}`) : null)];
}

// undo / redo of the label's changes (redo: the value the last undo removed)
export function undoButtons(app) {
  return [button('Undo', 'U', () => app.undo(), 'btn-undo'),
    el('button', { id: 'btn-redo', title: 'shortcut: R (or Shift+U)', onclick: () => app.redoLast(), disabled: !app.canRedo() }, 'Redo', el('kbd', {}, 'R'))];
}

// a note on the item, or "skip: can't tell" with the reason
export function noteBlock(app, item) {
  const n = item.note;
  const text = el('textarea', { id: 'note-text', rows: 2, maxlength: 500, placeholder: 'a note for the reviewer, or why you cannot tell' });
  text.value = n ? n.text : '';
  return el('details', { class: 'note', open: !!n },
    el('summary', {}, n ? (n.skip ? `Skipped: ${n.text}` : `Your note: ${n.text}`) : 'Note · skip: can’t tell'),
    text,
    el('div', { class: 'buttons' },
      el('button', { id: 'btn-note', onclick: () => app.saveNote(text.value, false) }, 'Save note'),
      el('button', { id: 'btn-skip', onclick: () => app.saveNote(text.value, true) }, 'Skip: can’t tell')));
}

// reviewers: each annotator's value with accept / reject (a rejection needs a comment)
export function reviewBlock(app, item) {
  if (!app.user || app.user.role !== 'reviewer') return null;
  const own = Object.entries(item.own || {});
  const notes = Object.entries(item.notes || {});
  if (!own.length && !notes.length) return null;
  const comment = el('input', { id: 'verdict-comment', maxlength: 500, placeholder: 'comment (needed to reject)' });
  return el('div', { class: 'review-box', id: 'review-box' },
    el('div', { class: 'row' }, el('b', {}, 'Review'), el('span', { class: 'muted' }, ' — accept one value (it becomes the reviewed label) or send it back with a comment')),
    comment,
    el('ul', {}, own.map(([who, o]) => el('li', { 'data-annotator': who },
      el('b', {}, `${who}: `), formatValue(item.kind, o.value),
      o.verdict ? el('span', { class: `muted verdict ${o.verdict.verdict}` }, ` (${o.verdict.verdict}ed${o.verdict.comment ? ': ' + o.verdict.comment : ''})`) : null,
      el('span', { class: 'vbtns' },
        el('button', { class: 'accept', onclick: () => app.verdict(who, 'accept', comment.value) }, 'Accept'),
        el('button', { class: 'reject', onclick: () => app.verdict(who, 'reject', comment.value) }, 'Reject'))))),
    notes.length ? el('ul', { class: 'notes' }, notes.map(([who, n]) => el('li', {}, `${who} ${n.skip ? 'skipped' : 'noted'}: ${n.text}`))) : null);
}

export function opinionsBlock(app, item) {
  const ops = item.review.opinions || {};
  const names = Object.keys(ops);
  if (names.length < 2 || item.blind) return null;
  const u = item.review.unit;
  return el('div', { class: 'opinions' },
    el('div', { class: 'row' }, `Annotators (${names.length}) are `, el('b', {}, item.review.disagreement === 'inf' ? 'found vs none' : u === 'deg' ? `${f2(item.review.disagreement)}°` : `${f2(item.review.disagreement, 1)} ${u}`), ' apart'),
    el('ul', {}, names.map(n => el('li', {}, `${n}: ${formatValue(item.kind, ops[n].value)}`))));
}

export function historyBlock(app, item) {
  // blind: only the annotator's own changes (another's value, or align's, would tell them the answer)
  const blind = item.blind;
  const rows = blind ? item.history.filter(h => h.actor === app.annotator) : item.history;
  if (!rows.length) return null;
  const title = blind ? `Your history (${rows.length}; others hidden in blind mode)` : `History (${rows.length})`;
  return el('details', { class: 'history' }, el('summary', {}, title),
    el('ol', {}, rows.slice().reverse().map(h => el('li', {},
      `v${h.version} ${h.op === 'kept' ? 'automatic value not applied' : h.op}${h.applied || h.op === 'kept' ? '' : ' (not applied)'} by ${h.actor === 'align' ? 'the automatic alignment' : h.actor}: `,
      h.value ? formatValue(item.kind, h.value) : 'removed',
      el('span', { class: 'muted' }, ` ${h.source === 'auto' ? 'automatic' : h.source || ''} · ${h.time.slice(0, 19).replace('T', ' ')}`)))));
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
