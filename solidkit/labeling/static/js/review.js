// The review task: flagged items and disagreements, biggest first.

import { el, fill, f2, TASK_NAMES, formatValue } from './ui.js';

export class ReviewTask {
  constructor(app) {
    this.app = app;
    this.root = el('div', { class: 'review-layout', id: 'review-view' });
    this.panel = el('div', { class: 'panel-body', id: 'review-panel' });
  }

  mount(view, panel) {
    if (!this.root.parentNode) { view.append(this.root); panel.append(this.panel); }
    this.root.hidden = false; this.panel.hidden = false;
  }

  empty() {}

  render(rows) {
    const th = this.app.campaign.thresholds;
    fill(this.panel,
      el('h2', {}, 'Review'),
      el('p', { class: 'hint' }, 'Flagged items first: annotators who disagree, then items align/ flagged, then labels far from the automatic value. Open one to check it; what you save there is stored as “reviewed” and settles the disagreement.'),
      el('p', { class: 'muted small' }, `Disagreement thresholds: sun ${th.sun.value}°, probe pixel ${th.probe_pixel.value} px, heading ${th.heading.value}°.`),
      el('p', { class: 'muted small' }, 'Second opinion: tick “blind” in the top bar and label the same items; your labels are compared with the first annotator’s here.'),
    );
    if (!rows.length) { this.root.replaceChildren(el('p', { class: 'empty' }, 'Nothing to review yet.')); return; }
    const size = (x, u) => (x == null ? '–' : x === 'inf' ? 'found vs none' : u === 'deg' ? `${f2(x)}°` : `${f2(x, 1)} ${u}`);
    const dis = r => size(r.disagreement, r.unit), va = r => size(r.vs_auto, r.unit);
    this.root.replaceChildren(el('table', { class: 'review', id: 'review-table' },
      el('thead', {}, el('tr', {}, ['Item', 'Task', 'Status', 'Flags', 'Labels', 'Annotators apart', 'Label vs auto'].map(h => el('th', {}, h)))),
      el('tbody', {}, rows.map(r => el('tr', { class: `${r.status}${r.open_disagreement ? ' open' : ''}`, 'data-key': `${r.kind}:${r.key}`, onclick: () => this.app.openReview(r.kind, r.key) },
        el('td', {}, r.title), el('td', {}, TASK_NAMES[r.kind]), el('td', {}, el('span', { class: `st ${r.status}` }, r.status)),
        el('td', {}, (r.flags || []).join(', ')),
        el('td', {}, Object.entries(r.opinions).map(([who, o]) => el('div', {}, `${who}: ${formatValue(r.kind, o.value)}`)),
          r.label && r.label.source !== 'annotator' ? el('div', { class: 'muted' }, `${r.label.source}: ${formatValue(r.kind, r.label.value)}`) : null),
        el('td', { class: 'num' }, dis(r)), el('td', { class: 'num' }, va(r)))))));
  }

  key() { return false; }
}
