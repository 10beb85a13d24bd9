// solidkit labeling: the page. The queue, saving with optimistic concurrency (a conflict never
// loses the annotator's value), shortcuts; each task lives in its own module.

import { api, ApiError } from './api.js';
import { $, el, TASK_NAMES, formatValue } from './ui.js';
import { SunTask } from './sun.js';
import { PixelTask } from './pixel.js';
import { HeadingTask } from './heading.js';
import { ReviewTask } from './review.js';

class App {
  constructor() {
    this.task = 'sun';
    this.queue = [];
    this.filter = 'all';
    this.pos = -1;
    this.item = null;
    this.reviewing = false;
    this.blind = localStorage.getItem('solidkit.blind') === '1';
    this.annotator = localStorage.getItem('solidkit.annotator') || '';
    this.controllers = {};
  }

  async start() {
    const s = await api.session();
    if (s.token_required && !s.authenticated) return this.showLogin();
    if (!this.annotator) await this.askAnnotator();
    this.campaign = await api.campaign();
    $('#campaign').textContent = this.campaign.name;
    $('#annotator').textContent = this.annotator;
    $('#blind').checked = this.blind;
    if (this.campaign.problems.length) this.toast(`${this.campaign.problems.length} campaign file(s) missing or refused: ${this.campaign.problems[0]}`, 'warn', 8000);
    this.bindChrome();
    const hash = new URLSearchParams(location.hash.slice(1));
    await this.switchTask(hash.get('task') || 'sun', hash.get('key'));
  }

  showLogin() {
    const d = $('#login');
    d.hidden = false;
    $('#login-token').focus();
    $('#login-form').addEventListener('submit', async e => {
      e.preventDefault();
      try {
        await api.login($('#login-token').value);
        d.hidden = true;
        this.start();
      } catch (err) {
        $('#login-error').textContent = err.status === 401 ? 'Wrong token.' : String(err.message);
      }
    });
  }

  askAnnotator() {
    return new Promise(resolve => {
      const d = $('#who');
      d.hidden = false;
      const input = $('#who-name');
      input.value = this.annotator || '';
      input.focus();
      $('#who-form').onsubmit = e => {
        e.preventDefault();
        const name = input.value.trim();
        if (!name) return;
        this.annotator = name;
        localStorage.setItem('solidkit.annotator', name);
        $('#annotator').textContent = name;
        d.hidden = true;
        resolve();
      };
    });
  }

  bindChrome() {
    for (const b of document.querySelectorAll('#tabs button')) b.onclick = () => this.switchTask(b.dataset.task);
    $('#annotator-btn').onclick = () => this.askAnnotator();
    $('#blind').onchange = e => { this.blind = e.target.checked; localStorage.setItem('solidkit.blind', this.blind ? '1' : '0'); this.reload(); };
    $('#help-btn').onclick = () => this.toggleHelp();
    $('#queue-filter').onchange = e => { this.filter = e.target.value; this.renderQueue(); };
    $('#review-exit').onclick = () => this.setReviewing(false);
    document.addEventListener('keydown', e => this.onKey(e));
  }

  setReviewing(on) {
    this.reviewing = on;
    $('#review-badge').hidden = !on;
  }

  controller(task) {
    if (!this.controllers[task]) {
      const C = { sun: SunTask, probe_pixel: PixelTask, heading: HeadingTask, review: ReviewTask }[task];
      this.controllers[task] = new C(this);
    }
    return this.controllers[task];
  }

  async switchTask(task, key = null) {
    if (!TASK_NAMES[task]) task = 'sun';
    if (task === 'review') this.setReviewing(false);
    delete document.body.dataset.item;
    this.task = task;
    for (const b of document.querySelectorAll('#tabs button')) b.classList.toggle('active', b.dataset.task === task);
    const view = $('#view'), panel = $('#panel');
    for (const c of view.children) c.hidden = true;
    for (const c of panel.children) c.hidden = true;
    const ctl = this.controller(task);
    ctl.mount(view, panel);
    document.body.dataset.task = task;
    await this.refreshQueue();
    if (task === 'review') { ctl.render(this.queue); document.body.dataset.item = 'review'; return; }
    let pos = key ? this.queue.findIndex(q => q.key === key) : -1;
    if (pos < 0) pos = this.queue.findIndex(q => q.status !== 'done');
    if (pos < 0) pos = 0;
    if (this.queue.length) await this.open(pos);
    else ctl.empty();
  }

  async refreshQueue() {
    const q = await api.queue(this.task);
    this.queue = q.items;
    this.progress = q.progress;
    this.renderQueue();
    this.renderProgress();
  }

  renderProgress() {
    const p = this.progress[this.task] || this.progress.sun;
    const box = $('#progress');
    if (this.task === 'review') { box.textContent = `${this.progress.review.open} to review`; return; }
    box.replaceChildren(
      el('span', { class: 'st done' }, `${p.done} done`), ' · ',
      el('span', { class: 'st flagged' }, `${p.flagged} flagged`), ' · ',
      el('span', { class: 'st left' }, `${p.left} left`),
      el('progress', { max: p.total || 1, value: p.done }),
    );
  }

  renderQueue() {
    const list = $('#queue-list');
    list.replaceChildren();
    this.queue.forEach((q, i) => {
      if (this.filter !== 'all' && q.status !== this.filter) return;
      const li = el('li', {
        class: `q ${q.status}${i === this.pos ? ' current' : ''}`, 'data-key': q.key, title: (q.flags || []).join(', '),
        onclick: () => (this.task === 'review' ? this.openReview(q.kind, q.key) : this.open(i)),
      }, el('span', { class: 'dot' }), el('span', { class: 'qt' }, this.task === 'review' ? `${TASK_NAMES[q.kind]}: ${q.title}` : q.title),
      q.flags && q.flags.length ? el('span', { class: 'qf' }, '⚑') : null);
      list.append(li);
    });
    const cur = list.querySelector('.current');
    if (cur) cur.scrollIntoView({ block: 'nearest' });
  }

  async open(pos) {
    if (pos < 0 || pos >= this.queue.length) return;
    this.pos = pos;
    const q = this.queue[pos], task = this.task, ticket = (this._ticket = (this._ticket || 0) + 1);
    history.replaceState(null, '', `#task=${task}&key=${encodeURIComponent(q.key)}`);
    delete document.body.dataset.item;
    const item = await api.item(task, q.key);
    if (ticket !== this._ticket) return; // another item was opened meanwhile
    this.item = item;
    this.renderQueue();
    await this.controller(task).load(item);
    if (ticket === this._ticket) document.body.dataset.item = `${task}:${q.key}`; // loaded (tests wait for it)
  }

  async reload() {
    if (this.task === 'review') return this.switchTask('review');
    if (this.item) {
      this.item = await api.item(this.task, this.item.key);
      await this.controller(this.task).load(this.item);
    }
  }

  async openReview(kind, key) {
    await this.switchTask(kind, key);
    this.setReviewing(true);
  }

  // the next (step 1) or previous (-1) item shown by the filter; `unfinished`: skip done items
  async next(step = 1, unfinished = false) {
    const n = this.queue.length;
    if (!n) return;
    const shown = q => this.filter === 'all' || q.status === this.filter;
    let p = this.pos, found = -1;
    for (let i = 1; i <= n; i++) {
      const c = (this.pos + i * step + n * n) % n;
      if (shown(this.queue[c]) && (!unfinished || this.queue[c].status !== 'done')) { found = c; break; }
      if (p === this.pos && shown(this.queue[c])) p = c;
    }
    await this.open(found >= 0 ? found : p);
  }

  // save `value` for the open item; true when stored. A conflict opens the conflict dialog and
  // keeps `value` until the annotator chooses.
  async save(value, { advance = true, expected = null } = {}) {
    const it = this.item;
    const body = {
      kind: it.kind, key: it.key, value, annotator: this.annotator,
      expected_version: expected ?? it.version, source: this.reviewing ? 'reviewed' : 'annotator',
    };
    try {
      const res = await api.put(body);
      this.toast(`saved ${it.title} (v${res.version})`, 'ok');
      document.body.dataset.saved = `${it.kind}:${it.key}:${res.version}`;
      await this.refreshQueue();
      if (advance && !this.reviewing) await this.next(1, true);
      else await this.reload();
      return true;
    } catch (err) {
      if (err instanceof ApiError && err.status === 409) return this.conflict(value, err.body);
      this.toast(err.message, 'error', 6000);
      return false;
    }
  }

  conflict(mine, body) {
    const it = this.item, d = $('#conflict');
    const theirs = body.current;
    $('#conflict-text').textContent = theirs
      ? `${theirs.annotator} (${theirs.source}) saved this label while you were working on it (now version ${body.version}).`
      : `This label changed while you were working on it (now version ${body.version}).`;
    $('#conflict-mine').textContent = formatValue(it.kind, mine);
    $('#conflict-theirs').textContent = theirs ? formatValue(it.kind, theirs.value) : 'no label (undone)';
    d.hidden = false;
    document.body.dataset.conflict = '1';
    return new Promise(resolve => {
      $('#conflict-keep-mine').onclick = async () => {
        d.hidden = true; delete document.body.dataset.conflict;
        resolve(await this.save(mine, { expected: body.version }));
      };
      $('#conflict-take-theirs').onclick = async () => {
        d.hidden = true; delete document.body.dataset.conflict;
        await this.reload();
        resolve(false);
      };
    });
  }

  async undo() {
    const it = this.item;
    try {
      const res = await api.undo({ kind: it.kind, key: it.key, annotator: this.annotator, expected_version: it.version });
      this.toast(`undone: ${res.label ? formatValue(it.kind, res.label.value) : 'no label'} (v${res.version})`, 'ok');
      await this.refreshQueue();
      await this.reload();
    } catch (err) {
      if (err instanceof ApiError && err.status === 409) { this.toast('changed by someone else meanwhile; reloaded', 'warn'); await this.reload(); }
      else this.toast(err.message, 'error');
    }
  }

  toast(msg, kind = 'ok', ms = 2500) {
    const t = $('#toast');
    t.textContent = msg;
    t.className = `toast ${kind}`;
    t.hidden = false;
    clearTimeout(this._toast);
    this._toast = setTimeout(() => { t.hidden = true; }, ms);
  }

  toggleHelp(force = null) {
    const h = $('#help');
    h.hidden = force === null ? !h.hidden : !force;
  }

  onKey(e) {
    if (!$('#login').hidden || !$('#who').hidden) return;
    if (!$('#conflict').hidden) return;
    const tag = (e.target.tagName || '').toLowerCase();
    if ((tag === 'input' && e.target.type !== 'range' && e.target.type !== 'checkbox') || tag === 'textarea' || tag === 'select') {
      if (e.key === 'Escape') e.target.blur();
      return;
    }
    if (e.ctrlKey || e.metaKey) {
      if (e.key.toLowerCase() === 's') { e.preventDefault(); this.controller(this.task).saveDraft?.(); }
      return;
    }
    const k = e.key;
    if (k === '?') { this.toggleHelp(); return; }
    if (k === 'Escape' && !$('#help').hidden) { this.toggleHelp(false); return; }
    if (['1', '2', '3', '4'].includes(k)) { this.switchTask(['sun', 'probe_pixel', 'heading', 'review'][+k - 1]); return; }
    if (this.task !== 'review') {
      if (k === 'j' || k === 'PageDown') { e.preventDefault(); this.next(1); return; }
      if (k === 'k' || k === 'PageUp') { e.preventDefault(); this.next(-1); return; }
      if (k === 'u') { this.undo(); return; }
    }
    if (this.controller(this.task).key(e)) e.preventDefault();
  }
}

const app = new App();
window.solidkitApp = app; // for the browser tests and the console
app.start().catch(err => {
  if (err instanceof ApiError && err.status === 401) app.showLogin();
  else { console.error(err); app.toast(String(err.message || err), 'error', 10000); }
});
