// The review task (reviewers): the agreement summary, then flagged items and disagreements,
// biggest first, with the annotators' notes, skips and earlier verdicts.

import { api } from './api.js';
import { el, fill, f2, TASK_NAMES, formatValue, flagText } from './ui.js';

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

  async render(rows) {
    const th = this.app.campaign.thresholds;
    fill(this.panel,
      el('h2', {}, 'Review'),
      el('p', { class: 'hint' }, 'Annotators who disagree come first, then items the automatic checks flagged, then labels far from the automatic value. Open one: accept an annotator’s value (it becomes the reviewed label), reject it with a comment (it goes back to them), or mark your own value and save it as reviewed.'),
      el('p', { class: 'muted small' }, `Disagreement thresholds: sun ${th.sun.value}°, probe pixel ${th.probe_pixel.value} px, heading ${th.heading.value}°.`),
    );
    const agreement = await api.agreement().catch(() => null);
    const size = (x, u) => (x == null ? '–' : x === 'inf' ? 'found vs none' : u === 'deg' ? `${f2(x)}°` : `${f2(x, 1)} ${u}`);
    const stat = (st, u) => (!st || !st.n ? '–' : `${size(st.median, u)} / ${size(st.p95, u)} (${st.n}${st.mismatch ? `, ${st.mismatch} found vs none` : ''})`);
    const agreeRows = [];
    for (const [kind, a] of Object.entries(agreement || {})) {
      agreeRows.push(el('tr', { class: 'task-row' }, el('td', {}, TASK_NAMES[kind]), el('td', {}, 'all'),
        el('td', { class: 'num' }, stat(a.task.vs_others, a.unit)), el('td', { class: 'num' }, stat(a.task.vs_reviewed, a.unit)), el('td', {}, ''), el('td', {}, '')));
      for (const [who, s] of Object.entries(a.annotators)) {
        agreeRows.push(el('tr', { 'data-agree': `${kind}:${who}` }, el('td', {}, ''), el('td', {}, who),
          el('td', { class: 'num' }, stat(s.vs_others, a.unit)), el('td', { class: 'num' }, stat(s.vs_reviewed, a.unit)),
          el('td', { class: 'num' }, String(s.rejected)), el('td', { class: 'num' }, String(s.skipped))));
      }
    }
    const agreeTable = agreeRows.length ? [el('h3', {}, 'Agreement (median / 95th percentile apart, number of comparisons)'),
      el('table', { class: 'review agreement', id: 'agreement-table' },
        el('thead', {}, el('tr', {}, ['Task', 'Annotator', 'vs other annotators', 'vs reviewed label', 'Rejected', 'Skipped'].map(h => el('th', {}, h)))),
        el('tbody', {}, agreeRows))] : [];
    if (!rows.length) { this.root.replaceChildren(...agreeTable, el('p', { class: 'empty' }, 'Nothing to review yet.')); return; }
    const dis = r => size(r.disagreement, r.unit), va = r => size(r.vs_auto, r.unit);
    this.root.replaceChildren(...agreeTable, el('h3', {}, 'Items'), el('table', { class: 'review', id: 'review-table' },
      el('thead', {}, el('tr', {}, ['Item', 'Task', 'Status', 'Flags', 'Labels', 'Annotators apart', 'Label vs auto'].map(h => el('th', {}, h)))),
      el('tbody', {}, rows.map(r => el('tr', { class: `${r.status}${r.open_disagreement ? ' open' : ''}`, 'data-key': `${r.kind}:${r.key}`, onclick: () => this.app.openReview(r.kind, r.key) },
        el('td', {}, r.title), el('td', {}, TASK_NAMES[r.kind]), el('td', {}, el('span', { class: `st ${r.status}` }, r.status)),
        el('td', { title: (r.flags || []).join('\n') }, (r.flags || []).map(flagText).join(', ')),
        el('td', {}, Object.entries(r.opinions).map(([who, o]) => el('div', {}, `${who}: ${formatValue(r.kind, o.value)}`)),
          r.label && r.label.source !== 'annotator' ? el('div', { class: 'muted' }, `${r.label.source === 'auto' ? 'automatic' : r.label.source}: ${formatValue(r.kind, r.label.value)}`) : null,
          Object.entries(r.notes || {}).map(([who, n]) => el('div', { class: 'muted' }, `${who} ${n.skip ? 'skipped' : 'noted'}: ${n.text}`)),
          (r.verdicts || []).slice(-2).map(v => el('div', { class: 'muted' }, `${v.reviewer} ${v.verdict}ed ${v.annotator}${v.comment ? ': ' + v.comment : ''}`))),
        el('td', { class: 'num' }, dis(r)), el('td', { class: 'num' }, va(r)))))));
  }

  key() { return false; }
}
