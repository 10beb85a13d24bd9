// solidkit labeling: the page. The queue, saving with optimistic concurrency (a conflict never
// loses the annotator's value), shortcuts; each task lives in its own module.

import { api, ApiError } from './api.js';
import { $, el, fill, TASK_NAMES, STATUS_TEXT, formatValue, flagText } from './ui.js';
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
    this.blind = localStorage.getItem('solidkit.blind') === '1'; // a preference; who you are comes from the server
    this.user = null;
    this.controllers = {};
    this.redo = {}; // `kind:key` -> values undone, newest last
  }

  get annotator() { return this.user ? this.user.name : ''; }

  // blind: other labels and the proposal hidden (the server leaves them out); never for reviewers
  isBlind() { return !!this.user && this.user.role !== 'reviewer' && (this.blind || !!(this.campaign && this.campaign.blind_forced)); }

  async start() {
    api.onUnauthorized = () => this.login();
    const s = await api.session();
    if (!s.authenticated) await this.login(s);
    else this.user = s.user;
    this.campaign = await api.campaign();
    this.user = this.campaign.user;
    $('#campaign').textContent = this.campaign.name;
    $('#campaign').title = this.campaign.name;
    this.renderWho();
    if (this.campaign.problems.length) this.toast(`${this.campaign.problems.length} campaign file(s) missing or refused: ${this.campaign.problems[0]}`, 'warn', 8000);
    this.bindChrome();
    const hash = new URLSearchParams(location.hash.slice(1));
    await this.switchTask(hash.get('task') || 'sun', hash.get('key'));
  }

  renderWho() {
    $('#annotator').textContent = this.user.name;
    $('#role').textContent = this.user.role;
    const reviewer = this.user.role === 'reviewer';
    $('#tab-review').hidden = !reviewer;
    $('#blind-box').hidden = reviewer;
    $('#blind').checked = this.isBlind();
    $('#blind').disabled = !!this.campaign.blind_forced;
    $('#blind-box').title = this.campaign.blind_forced ? 'blind labeling is on for this campaign: other labels and the proposal are hidden'
      : 'second opinion: hide other labels and the automatic proposal';
  }

  // the login form (name, and the token when the server asks for one); resolves once logged in.
  // Called at start and whenever the server answers 401 (a restart): what is on screen stays.
  login(state = null) {
    if (this._login) return this._login;
    this._login = (async () => {
      state = state || await api.session().catch(() => ({ token_required: false, users: [] }));
      const d = $('#login');
      $('#login-token-row').hidden = !state.token_required;
      $('#login-title').textContent = this.user ? 'Log in again' : 'Who is labeling?';
      $('#login-why').textContent = this.user
        ? 'The server was restarted or your session ended. Your unsaved mark is kept: log in and it is saved.'
        : (state.team ? 'Log in with the name you were registered under (solidkit label users list shows them).' : 'Your name is stored with every label you save.');
      const list = $('#login-names');
      list.replaceChildren(...(state.users || []).map(n => el('option', { value: n })));
      const name = $('#login-name');
      if (this.user) name.value = this.user.name;
      d.hidden = false;
      document.body.dataset.login = '1';
      (state.token_required && !$('#login-token').value ? $('#login-token') : name).focus();
      await new Promise(resolve => {
        $('#login-form').onsubmit = async e => {
          e.preventDefault();
          try {
            const res = await api.login(name.value.trim(), $('#login-token').value);
            this.user = res.user;
            d.hidden = true;
            delete document.body.dataset.login;
            $('#login-error').textContent = '';
            resolve();
          } catch (err) {
            $('#login-error').textContent = err.status === 401 ? 'Wrong token.' : err.status === 429 ? err.message : String(err.message);
          }
        };
      });
    })();
    return this._login.finally(() => { this._login = null; });
  }

  async logout() {
    await api.logout().catch(() => null);
    location.reload();
  }

  bindChrome() {
    for (const b of document.querySelectorAll('#tabs button')) b.onclick = () => this.switchTask(b.dataset.task);
    $('#annotator-btn').onclick = () => this.logout();
    $('#blind').onchange = e => { this.blind = e.target.checked; localStorage.setItem('solidkit.blind', this.blind ? '1' : '0'); this.refreshQueue().then(() => this.reload()); };
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
    if (!TASK_NAMES[task] || (task === 'review' && this.user.role !== 'reviewer')) task = 'sun';
    if (task === 'review') this.setReviewing(false);
    delete document.body.dataset.item;
    this.task = task;
    for (const b of document.querySelectorAll('#tabs button')) b.classList.toggle('active', b.dataset.task === task);
    const view = $('#view'), panel = $('#panel');
    // views are put out of sight, not out of the layout: a panorama viewer sized 0x0 draws its
    // markers at NaN (console errors), and would come back at the wrong size
    for (const c of view.children) c.classList.add('off');
    for (const c of panel.children) c.hidden = true;
    const ctl = this.controller(task);
    ctl.mount(view, panel);
    ctl.root.hidden = false;
    ctl.root.classList.remove('off');
    document.body.dataset.task = task;
    await this.refreshQueue();
    if (task === 'review') { await ctl.render(this.queue); document.body.dataset.item = 'review'; return; }
    this.showGuide(task);
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
    if (this.task === 'review') { box.textContent = `${this.progress.review ? this.progress.review.open : 0} to review`; return; }
    const mine = this.user.role === 'reviewer' ? '' : ' (yours)';
    fill(box,
      el('span', { class: 'st done' }, `${p.done} done`), ' · ',
      p.returned ? el('span', { class: 'st returned' }, `${p.returned} returned · `) : null,
      el('span', { class: 'st flagged' }, `${p.flagged} flagged`), ' · ',
      el('span', { class: 'st left' }, `${p.left} left${mine}`),
      el('progress', { max: p.total || 1, value: p.done }),
    );
  }

  renderQueue() {
    const list = $('#queue-list');
    list.replaceChildren();
    this.queue.forEach((q, i) => {
      if (this.filter !== 'all' && q.status !== this.filter) return;
      const title = this.task === 'review' ? `${TASK_NAMES[q.kind]}: ${q.title}` : q.title;
      const why = [STATUS_TEXT[q.status] || q.status, ...(q.flags || []).map(flagText), q.comment ? `reviewer: ${q.comment}` : null, q.skipped ? `skipped: ${q.skipped}` : null].filter(Boolean);
      const li = el('li', {
        class: `q ${q.status}${i === this.pos ? ' current' : ''}`, 'data-key': q.key, title: `${title}\n${why.join('\n')}`,
        onclick: () => (this.task === 'review' ? this.openReview(q.kind, q.key) : this.open(i)),
      }, el('span', { class: 'dot' }), el('span', { class: 'qt' }, title),
      q.flags && q.flags.length ? el('span', { class: 'qf', 'aria-label': 'flagged' }, '⚑') : null);
      list.append(li);
    });
    const cur = list.querySelector('.current');
    if (cur) cur.scrollIntoView({ block: 'nearest' });
    const counts = {};
    for (const q of this.queue) counts[q.status] = (counts[q.status] || 0) + 1;
    $('#queue-legend').replaceChildren(...['left', 'flagged', 'returned', 'done'].map(s => el('li', { class: `q ${s}`, title: STATUS_TEXT[s] },
      el('span', { class: 'dot' }), el('span', {}, `${STATUS_TEXT[s]} (${counts[s] || 0})`))),
      el('li', { class: 'q' }, el('span', { class: 'qf' }, '⚑'), el('span', {}, 'flagged by the automatic checks')));
  }

  async open(pos) {
    if (pos < 0 || pos >= this.queue.length) return;
    this.pos = pos;
    const q = this.queue[pos], task = this.task, ticket = (this._ticket = (this._ticket || 0) + 1);
    history.replaceState(null, '', `#task=${task}&key=${encodeURIComponent(q.key)}`);
    delete document.body.dataset.item;
    const item = await api.item(task, q.key, this.isBlind());
    if (ticket !== this._ticket) return; // another item was opened meanwhile
    this.item = item;
    this.renderQueue();
    await this.controller(task).load(item);
    if (ticket === this._ticket) document.body.dataset.item = `${task}:${q.key}`; // loaded (tests wait for it)
  }

  async reload() {
    if (this.task === 'review') return this.switchTask('review');
    if (this.item) {
      this.item = await api.item(this.task, this.item.key, this.isBlind());
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
  async save(value, { advance = true, expected = null, redo = false } = {}) {
    const it = this.item;
    const body = {
      kind: it.kind, key: it.key, value, blind: this.isBlind(),
      expected_version: expected ?? it.version, source: this.reviewing && this.user.role === 'reviewer' ? 'reviewed' : 'annotator',
    };
    try {
      const res = await api.put(body);
      if (!redo) delete this.redo[`${it.kind}:${it.key}`];
      this.toast(`saved ${it.title} (v${res.version})`, 'ok');
      await this.refreshQueue();
      if (advance && !this.reviewing) await this.next(1, true);
      else await this.reload();
      document.body.dataset.saved = `${it.kind}:${it.key}:${res.version}`; // stored, and the page moved on
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
    const before = it.blind ? it.mine && it.mine.value : it.label && it.label.source !== 'auto' && it.label.value;
    try {
      const res = await api.undo({ kind: it.kind, key: it.key, expected_version: it.version });
      if (before) (this.redo[`${it.kind}:${it.key}`] = this.redo[`${it.kind}:${it.key}`] || []).push(before);
      this.toast(it.blind ? `undone (v${res.version})` : `undone: ${res.label ? formatValue(it.kind, res.label.value) : 'no label'} (v${res.version})`, 'ok');
      await this.refreshQueue();
      await this.reload();
    } catch (err) {
      if (err instanceof ApiError && err.status === 409) { this.toast('changed by someone else meanwhile; reloaded', 'warn'); await this.reload(); }
      else this.toast(err.message, 'error');
    }
  }

  canRedo() { const r = this.item && this.redo[`${this.item.kind}:${this.item.key}`]; return !!(r && r.length); }

  // save again the value the last undo removed
  async redoLast() {
    const k = `${this.item.kind}:${this.item.key}`, stack = this.redo[k];
    if (!stack || !stack.length) { this.toast('nothing to redo', 'warn'); return; }
    const value = stack.pop();
    if (!(await this.save(value, { advance: false, redo: true }))) stack.push(value);
  }

  // the annotator's note on the open item, or "skip: can't tell" with the reason
  async saveNote(text, skip) {
    const it = this.item;
    if (skip && !text.trim()) { this.toast('say why you cannot tell (clouds, the sun hidden, …)', 'warn'); return false; }
    try {
      await api.note({ kind: it.kind, key: it.key, text, skip });
      this.toast(skip ? `skipped ${it.title}` : 'note saved', 'ok');
      await this.refreshQueue();
      if (skip) await this.next(1, true); else await this.reload();
      document.body.dataset.noted = `${it.kind}:${it.key}`; // stored, and the page moved on
      return true;
    } catch (err) { this.toast(err.message, 'error', 6000); return false; }
  }

  // reviewers: accept or reject one annotator's value (reject says why; the item goes back to them)
  async verdict(annotator, verdict, comment) {
    const it = this.item;
    if (verdict === 'reject' && !comment.trim()) { this.toast('say what is wrong: the annotator sees your comment', 'warn'); return false; }
    try {
      const res = await api.verdict({ kind: it.kind, key: it.key, annotator, verdict, comment, expected_version: it.version });
      this.toast(`${verdict === 'accept' ? 'accepted' : 'rejected'} ${annotator}’s ${TASK_NAMES[it.kind].toLowerCase()} label`, 'ok');
      await this.refreshQueue();
      await this.reload();
      document.body.dataset.verdict = `${it.kind}:${it.key}:${annotator}:${verdict}:${res.version}`;
      return true;
    } catch (err) {
      if (err instanceof ApiError && err.status === 409) { this.toast('changed meanwhile; reloaded', 'warn'); await this.reload(); }
      else this.toast(err.message, 'error', 6000);
      return false;
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

  // a short guide per task, opened the first time the task is used (and from the panel's "guide")
  showGuide(task, force = false) {
    const seen = `solidkit.guide.${task}`;
    if (!force && localStorage.getItem(seen)) return;
    const g = GUIDES[task];
    if (!g) return;
    localStorage.setItem(seen, '1');
    $('#guide-title').textContent = `${TASK_NAMES[task]}: how to label`;
    $('#guide-body').replaceChildren(...g.text.map(t => el('p', {}, t)), g.img ? el('img', { src: `/static/guide/${g.img}`, alt: `the ${TASK_NAMES[task]} task` }) : null);
    $('#guide').hidden = false;
    $('#guide-close').onclick = () => this.closeGuide();
  }

  closeGuide() { $('#guide').hidden = true; }

  onKey(e) {
    if (!$('#login').hidden || !$('#guide').hidden && e.key !== 'Escape') return;
    if (!$('#guide').hidden) { this.closeGuide(); return; }
    if (!$('#conflict').hidden) return;
    const tag = (e.target.tagName || '').toLowerCase();
    if ((tag === 'input' && e.target.type !== 'range' && e.target.type !== 'checkbox') || tag === 'textarea' || tag === 'select') {
      if (e.key === 'Escape') e.target.blur();
      return;
    }
    if (e.ctrlKey || e.metaKey) {
      if (e.key.toLowerCase() === 's') { e.preventDefault(); this.controller(this.task).saveDraft?.(); }
      if (e.key.toLowerCase() === 'z' && this.task !== 'review') { e.preventDefault(); if (e.shiftKey) this.redoLast(); else this.undo(); }
      if (e.key.toLowerCase() === 'y' && this.task !== 'review') { e.preventDefault(); this.redoLast(); }
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
      if (k === 'U' || k === 'r') { this.redoLast(); return; }
    }
    if (this.controller(this.task).key(e)) e.preventDefault();
  }
}

const GUIDES = {
  sun: { img: 'sun.jpg', text: [
    'Each item is one position’s dark sun frame: the sun is the small bright disk. Click its centre (not the glare around it), drag the mark to adjust, then S to save. N if no sun is visible; “Skip: can’t tell” with a reason if you cannot decide.',
    'The strip below the view is the whole panorama: hover it to look there. The orange ring is the automatic proposal (A accepts it); grey × marks are bright spots the automatic search ruled out, with the reason in the panel.',
  ] },
  probe_pixel: { img: 'probe_pixel.jpg', text: [
    'Click the point on the ground where the camera tripod stood for this position (the field note says where). Wheel to zoom, drag to pan, Z zooms to your mark. S saves.',
  ] },
  heading: { img: 'heading.jpg', text: [
    'Turn the photo’s frame (cyan, the photo drawn inside it) until the photo lines up with the panorama: drag inside the frame, Shift+drag anywhere, or ←/→. F looks through the photo, O hides it.',
    'Line up distant things (building tops, the skyline, far poles): near objects shift when the camera stood somewhere else.',
  ] },
};

const app = new App();
window.solidkitApp = app; // for the browser tests and the console
app.start().catch(err => { console.error(err); app.toast(String(err.message || err), 'error', 10000); });
