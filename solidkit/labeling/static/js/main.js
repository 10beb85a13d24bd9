// solidkit labeling: the page. Tasks (sun, probe pixel, heading, review), the queue, saving
// with optimistic concurrency (a conflict never loses the annotator's value), shortcuts.

import { api, ApiError, imageUrl } from './api.js';
import { SphereView } from './sphere.js';
import { FlatView } from './flat.js';
import { circle, wrap180 } from './frames.js';

const $ = (sel, root = document) => root.querySelector(sel);
const el = (tag, attrs = {}, ...children) => {
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
const fill = (node, ...kids) => node.replaceChildren(...kids.flat().filter(k => k !== null && k !== undefined && k !== false));
const f2 = (x, d = 2) => (x === null || x === undefined ? '–' : Number(x).toFixed(d));
const TASK_NAMES = { sun: 'Sun', probe_pixel: 'Probe pixels', heading: 'Heading', review: 'Review' };

export function formatValue(kind, v) {
  if (!v) return '–';
  if (kind === 'sun') return v.found === false ? 'no sun visible' : `az ${f2(wrap180(v.azimuth_deg))}°, el ${f2(v.elevation_deg)}°` + (v.uncertainty_deg != null ? ` ±${f2(v.uncertainty_deg)}°` : '');
  if (kind === 'probe_pixel') return `x ${f2(v.x, 1)}, y ${f2(v.y, 1)} px`;
  if (kind === 'heading') return v.yaw_deg == null ? 'unknown' : `yaw ${f2(v.yaw_deg)}°`;
  return JSON.stringify(v);
}

// ---------------------------------------------------------------------------- app
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

// ---------------------------------------------------------------------------- shared panel bits
function panelHeader(app, item) {
  const flags = (item.review.flags || []).map(f => el('span', { class: 'chip' }, f));
  return [
    el('h2', {}, item.title),
    flags.length ? el('div', { class: 'chips' }, flags) : null,
  ];
}

function savedLine(app, item) {
  if (app.blind && !app.reviewing) return el('div', { class: 'row muted' }, 'blind mode: other labels hidden');
  const lab = item.label;
  return el('div', { class: 'row' }, el('span', { class: 'swatch saved' }), 'Stored: ',
    lab ? el('b', { id: 'saved-value' }, formatValue(item.kind, lab.value)) : el('i', {}, 'none'),
    lab ? el('span', { class: 'muted' }, ` — ${lab.annotator} (${lab.source}), v${lab.version}`) : null);
}

function opinionsBlock(app, item) {
  const ops = item.review.opinions || {};
  const names = Object.keys(ops);
  if (names.length < 2 || (app.blind && !app.reviewing)) return null;
  const u = item.review.unit;
  return el('div', { class: 'opinions' },
    el('div', { class: 'row' }, `Annotators (${names.length}) are `, el('b', {}, item.review.disagreement === 'inf' ? 'found vs none' : u === 'deg' ? `${f2(item.review.disagreement)}°` : `${f2(item.review.disagreement, 1)} ${u}`), ' apart'),
    el('ul', {}, names.map(n => el('li', {}, `${n}: ${formatValue(item.kind, ops[n].value)}`))));
}

function historyBlock(item) {
  if (!item.history.length) return null;
  return el('details', { class: 'history' }, el('summary', {}, `History (${item.history.length})`),
    el('ol', {}, item.history.slice().reverse().map(h => el('li', {},
      `v${h.version} ${h.op}${h.applied ? '' : ' (not applied)'} by ${h.actor}: `,
      h.value ? formatValue(item.kind, h.value) : 'removed',
      el('span', { class: 'muted' }, ` ${h.source || ''} · ${h.time.slice(0, 19).replace('T', ' ')}`)))));
}

function button(label, key, onclick, id, cls = '') {
  return el('button', { id, class: cls, onclick, title: key ? `shortcut: ${key}` : null }, label, key ? el('kbd', {}, key) : null);
}

function slider(id, label, min, max, step, value, fmt, oninput) {
  const out = el('span', { class: 'val', id: `${id}-val` }, fmt(value));
  const input = el('input', { type: 'range', id, min, max, step, value });
  input.addEventListener('input', () => { out.textContent = fmt(+input.value); oninput(+input.value); });
  return el('label', { class: 'slider' }, el('span', {}, label), input, out);
}

// ---------------------------------------------------------------------------- sun
const UNC_STEPS = [0.05, 0.1, 0.15, 0.2, 0.3, 0.5, 0.75, 1, 1.5, 2, 3, 5];

class SunTask {
  constructor(app) {
    this.app = app;
    this.root = el('div', { class: 'sun-layout', id: 'sun-view' });
    this.sphereBox = el('div', { class: 'sphere', id: 'sun-sphere' });
    this.overview = el('div', { class: 'overview', id: 'sun-overview' });
    this.ovImg = el('img', { alt: 'whole panorama' });
    this.ovCanvas = el('canvas');
    this.overview.append(this.ovImg, this.ovCanvas);
    this.root.append(this.sphereBox, this.overview);
    this.panel = el('div', { class: 'panel-body', id: 'sun-panel' });
    this.sphere = new SphereView(this.sphereBox, {
      onPick: d => this.place(d),
      dragTest: e => this.nearDraft(e),
      onDrag: (d, phase) => { this.place(d, phase !== 'end'); },
    });
    this.sphereBox.addEventListener('viewchange', () => this.drawOverview());
    this.exposure = 0;
    this.bindOverview();
  }

  mount(view, panel) {
    if (!this.root.parentNode) { view.append(this.root); panel.append(this.panel); }
    this.root.hidden = false; this.panel.hidden = false;
  }

  empty() { fill(this.panel, el('p', {}, 'No sun frames in this campaign.')); }

  hidden() { return this.app.blind && !this.app.reviewing; }

  async load(item) {
    this.item = item;
    const lab = item.label && item.label.value;
    const prop = !this.hidden() && item.proposal && item.proposal.found ? item.proposal : null;
    this.unc = (lab && lab.uncertainty_deg) || (prop && prop.uncertainty_deg) || 0.3;
    this.draft = null;
    const target = (!this.hidden() && lab && lab.found && lab) || prop || null;
    const ephem = item.view.ephemeris;
    const look = target ? [target.azimuth_deg, target.elevation_deg, 20] : [0, ephem && ephem.elevation_deg != null ? ephem.elevation_deg : 20, 90];
    this.ovImg.src = imageUrl.preview(item.view.image.id);
    this.renderPanel();
    await this.sphere.show(item.view.image, { azimuth_deg: look[0], elevation_deg: look[1], fov: look[2] });
    this.sphere.setExposure(this.exposure);
    this.renderMarkers();
  }

  place(d, dragging = false) {
    this.draft = { found: true, azimuth_deg: +d.azimuth_deg.toFixed(4), elevation_deg: +d.elevation_deg.toFixed(4) };
    this.renderMarkers();
    if (!dragging) this.renderPanel();
    else $('#draft-value').textContent = formatValue('sun', this.value());
  }

  value() { return this.draft ? { ...this.draft, uncertainty_deg: this.unc } : null; }

  nearDraft(e) {
    if (!this.draft) return false;
    const p = this.sphere.screenOf(this.draft.azimuth_deg, this.draft.elevation_deg);
    if (!p) return false;
    const r = this.sphereBox.getBoundingClientRect();
    return Math.hypot(e.clientX - r.left - p.x, e.clientY - r.top - p.y) < 14;
  }

  renderMarkers() {
    const it = this.item, ms = [];
    if (!this.hidden()) {
      it.view.candidates.forEach((c, i) => {
        if (!c.chosen) ms.push({ id: `cand${i}`, azimuth_deg: c.azimuth_deg, elevation_deg: c.elevation_deg, cls: 'rejected', size: 18 });
      });
      if (it.proposal && it.proposal.found) {
        const p = it.proposal;
        ms.push({ id: 'auto', azimuth_deg: p.azimuth_deg, elevation_deg: p.elevation_deg, cls: 'auto', size: 30 });
        if (p.uncertainty_deg) ms.push({ id: 'auto-unc', polygonRad: circle(p.azimuth_deg, p.elevation_deg, p.uncertainty_deg), style: { fill: 'none', stroke: '#fb923c', strokeWidth: '1.5px', strokeDasharray: '4 3' } });
      }
      for (const [who, op] of Object.entries(it.review.opinions || {})) {
        if (op.value && op.value.found && (!it.label || who !== it.label.annotator)) ms.push({ id: `op-${who}`, azimuth_deg: op.value.azimuth_deg, elevation_deg: op.value.elevation_deg, cls: 'other', size: 14 });
      }
      const lab = it.label && it.label.value;
      if (lab && lab.found) {
        ms.push({ id: 'saved', azimuth_deg: lab.azimuth_deg, elevation_deg: lab.elevation_deg, cls: 'saved', size: 26 });
        if (lab.uncertainty_deg) ms.push({ id: 'saved-unc', polygonRad: circle(lab.azimuth_deg, lab.elevation_deg, lab.uncertainty_deg), style: { fill: 'none', stroke: '#4ade80', strokeWidth: '1.5px' } });
      }
    }
    if (this.draft) {
      ms.push({ id: 'draft', azimuth_deg: this.draft.azimuth_deg, elevation_deg: this.draft.elevation_deg, cls: 'draft', size: 30, z: 20 });
      ms.push({ id: 'draft-unc', polygonRad: circle(this.draft.azimuth_deg, this.draft.elevation_deg, this.unc), style: { fill: 'rgba(34,211,238,0.12)', stroke: '#22d3ee', strokeWidth: '2px' }, z: 19 });
    }
    this.sphere.setMarkers(ms);
    this.drawOverview();
  }

  bindOverview() {
    const at = e => {
      const r = this.ovCanvas.getBoundingClientRect();
      return { azimuth_deg: ((e.clientX - r.left) / r.width) * 360 - 180, elevation_deg: 90 - ((e.clientY - r.top) / r.height) * 180 };
    };
    this.ovCanvas.addEventListener('mousemove', e => {
      if (!this.sphere.viewer) return;
      if (!this.saved) this.saved = this.sphere.view();
      const d = at(e);
      this.sphere.lookAt(d.azimuth_deg, d.elevation_deg);
    });
    this.ovCanvas.addEventListener('mouseleave', () => {
      if (this.saved) { this.sphere.lookAt(this.saved.azimuth_deg, this.saved.elevation_deg); this.saved = null; }
    });
    this.ovCanvas.addEventListener('click', e => {
      const d = at(e);
      this.saved = null;
      this.sphere.lookAt(d.azimuth_deg, d.elevation_deg, Math.min(this.sphere.view().fov, 30));
    });
  }

  drawOverview() {
    const c = this.ovCanvas, r = this.overview.getBoundingClientRect();
    const w = Math.round(r.width), h = Math.round(r.height);
    if (!w || !this.item) return;
    if (c.width !== w || c.height !== h) { c.width = w; c.height = h; }
    const g = c.getContext('2d');
    g.clearRect(0, 0, w, h);
    const X = az => ((az + 180) / 360) * w, Y = e => ((90 - e) / 180) * h;
    const ephem = this.item.view.ephemeris;
    if (ephem && ephem.elevation_deg != null) {
      g.strokeStyle = 'rgba(250,204,21,0.6)'; g.setLineDash([6, 4]); g.beginPath();
      g.moveTo(0, Y(ephem.elevation_deg)); g.lineTo(w, Y(ephem.elevation_deg)); g.stroke(); g.setLineDash([]);
    }
    const dot = (az, e, col, rad) => { g.strokeStyle = col; g.lineWidth = 2; g.beginPath(); g.arc(X(az), Y(e), rad, 0, 2 * Math.PI); g.stroke(); };
    if (!this.hidden()) {
      for (const cnd of this.item.view.candidates) if (!cnd.chosen) dot(cnd.azimuth_deg, cnd.elevation_deg, '#9ca3af', 4);
      const p = this.item.proposal;
      if (p && p.found) dot(p.azimuth_deg, p.elevation_deg, '#fb923c', 6);
      const lab = this.item.label && this.item.label.value;
      if (lab && lab.found) dot(lab.azimuth_deg, lab.elevation_deg, '#4ade80', 5);
    }
    if (this.draft) dot(this.draft.azimuth_deg, this.draft.elevation_deg, '#22d3ee', 7);
    if (this.sphere.viewer) {
      const v = this.sphere.view();
      g.strokeStyle = 'rgba(255,255,255,0.8)'; g.lineWidth = 1;
      const hw = (v.fov * 0.8 / 360) * w, hh = (v.fov / 2 / 180) * h;
      g.strokeRect(X(v.azimuth_deg) - hw, Y(v.elevation_deg) - hh, 2 * hw, 2 * hh);
    }
  }

  renderPanel() {
    const app = this.app, it = this.item, p = it.proposal;
    let auto;
    if (this.hidden()) auto = el('i', {}, 'hidden (blind mode)');
    else if (!p) auto = el('i', {}, app.campaign.has_alignment ? 'none for this capture' : 'none (run solidkit align)');
    else if (p.found === false) auto = el('span', {}, 'align found no sun', it.view.reason ? el('span', { class: 'muted' }, ` (${it.view.reason})`) : null);
    else auto = el('b', { id: 'auto-value' }, formatValue('sun', p));
    const rejected = it.view.candidates.filter(c => !c.chosen);
    fill(this.panel,
      ...panelHeader(app, it),
      el('p', { class: 'hint' }, 'Click the centre of the sun’s bright disk (drag your mark to adjust), A to accept the orange proposal, N if no sun is visible. Grey × marks are candidates align/ rejected. Hover the strip below to look around.'),
      el('div', { class: 'row' }, el('span', { class: 'swatch auto' }), 'Auto: ', auto),
      it.view.ephemeris && it.view.ephemeris.elevation_deg != null
        ? el('div', { class: 'row muted' }, el('span', { class: 'swatch ephem' }), `pvlib sun elevation ${f2(it.view.ephemeris.elevation_deg)}° (dashed line)`) : null,
      savedLine(app, it),
      el('div', { class: 'row' }, el('span', { class: 'swatch draft' }), 'Your mark: ', el('b', { id: 'draft-value' }, this.draft ? formatValue('sun', this.value()) : 'click the sun’s centre')),
      opinionsBlock(app, it),
      slider('unc', 'Uncertainty', 0, UNC_STEPS.length - 1, 1, nearestStep(this.unc), i => `±${UNC_STEPS[i]}°`, i => { this.unc = UNC_STEPS[i]; this.renderMarkers(); $('#draft-value').textContent = this.draft ? formatValue('sun', this.value()) : 'click the sun’s centre'; }),
      slider('exposure', 'Exposure', -4, 8, 0.5, this.exposure, v => `${v > 0 ? '+' : ''}${v} EV`, v => { this.exposure = v; this.sphere.setExposure(v); }),
      el('div', { class: 'buttons' },
        button('Accept auto', 'A', () => this.accept(), 'btn-accept', 'primary'),
        button('Save my mark', 'S', () => this.saveDraft(), 'btn-save', 'primary'),
        button('No sun visible', 'N', () => this.app.save({ found: false }), 'btn-nosun'),
        button('Undo last change', 'U', () => this.app.undo(), 'btn-undo'),
        button('Go to mark', 'G', () => this.goTo(), 'btn-goto'),
        button('Clear my mark', 'Esc', () => { this.draft = null; this.renderMarkers(); this.renderPanel(); }, 'btn-clear')),
      rejected.length && !this.hidden() ? el('details', { class: 'cands', open: true }, el('summary', {}, `Rejected candidates (${rejected.length})`),
        el('ul', {}, rejected.map(c => el('li', { onclick: () => this.sphere.lookAt(c.azimuth_deg, c.elevation_deg, 15) },
          `az ${f2(wrap180(c.azimuth_deg), 1)}°, el ${f2(c.elevation_deg, 1)}°: `, el('span', { class: 'muted' }, (c.reasons || []).join('; ')))))) : null,
      historyBlock(it),
    );
  }

  accept() {
    const p = this.item.proposal;
    if (this.hidden() || !p) { this.app.toast('no automatic proposal to accept', 'warn'); return; }
    if (p.found === false) return this.app.save({ found: false });
    return this.app.save({ found: true, azimuth_deg: p.azimuth_deg, elevation_deg: p.elevation_deg, uncertainty_deg: p.uncertainty_deg ?? this.unc });
  }

  saveDraft() {
    if (!this.draft) { this.app.toast('click the sun first (or A to accept the auto proposal, N for no sun)', 'warn'); return; }
    return this.app.save(this.value());
  }

  goTo() {
    const t = this.draft || (this.item.label && this.item.label.value.found && this.item.label.value) || (this.item.proposal && this.item.proposal.found && this.item.proposal);
    if (t) this.sphere.lookAt(t.azimuth_deg, t.elevation_deg, 8);
  }

  key(e) {
    const k = e.key, step = e.shiftKey ? 0.2 : 0.02;
    const nudge = (da, de) => { if (this.draft) this.place({ azimuth_deg: wrap180(this.draft.azimuth_deg + da), elevation_deg: Math.max(-90, Math.min(90, this.draft.elevation_deg + de)) }); };
    switch (k) {
      case 'a': case 'A': case 'Enter': this.accept(); return true;
      case 's': case 'S': this.saveDraft(); return true;
      case 'n': case 'N': this.app.save({ found: false }); return true;
      case 'g': this.goTo(); return true;
      case 'Escape': this.draft = null; this.renderMarkers(); this.renderPanel(); return true;
      case 'ArrowLeft': nudge(-step, 0); return true;
      case 'ArrowRight': nudge(step, 0); return true;
      case 'ArrowUp': nudge(0, step); return true;
      case 'ArrowDown': nudge(0, -step); return true;
      case '[': case ']': {
        this.exposure = Math.max(-4, Math.min(8, this.exposure + (k === ']' ? 0.5 : -0.5)));
        this.sphere.setExposure(this.exposure); const s = $('#exposure'); if (s) { s.value = this.exposure; s.dispatchEvent(new Event('input')); }
        return true;
      }
      case '-': case '=': case '+': {
        const i = Math.max(0, Math.min(UNC_STEPS.length - 1, nearestStep(this.unc) + (k === '-' ? -1 : 1)));
        const s = $('#unc'); if (s) { s.value = i; s.dispatchEvent(new Event('input')); }
        return true;
      }
      default: return false;
    }
  }
}

function nearestStep(u) {
  let best = 0;
  UNC_STEPS.forEach((s, i) => { if (Math.abs(Math.log(s / u)) < Math.abs(Math.log(UNC_STEPS[best] / u))) best = i; });
  return best;
}

// ---------------------------------------------------------------------------- probe pixel
class PixelTask {
  constructor(app) {
    this.app = app;
    this.root = el('div', { class: 'flat-layout', id: 'pixel-view' });
    this.panel = el('div', { class: 'panel-body', id: 'pixel-panel' });
    this.flat = new FlatView(this.root, {
      onPick: p => this.place(p),
      dragTest: p => this.draft && Math.hypot(p.x - this.draft.x, p.y - this.draft.y) * this.flat.s < 12,
      onDrag: p => this.place(p),
    });
  }

  mount(view, panel) {
    if (!this.root.parentNode) { view.append(this.root); panel.append(this.panel); }
    this.root.hidden = false; this.panel.hidden = false;
    this.flat._resize();
  }

  empty() { fill(this.panel, el('p', {}, 'No probe positions with a photo in this campaign.')); }

  hidden() { return this.app.blind && !this.app.reviewing; }

  async load(item) {
    this.item = item;
    this.draft = null;
    this.renderPanel();
    await this.flat.show(item.view.photo.image);
    this.renderMarkers();
  }

  place(p) {
    const info = this.item.view.photo.image;
    this.draft = { x: +Math.max(-0.5, Math.min(info.width - 0.5, p.x)).toFixed(2), y: +Math.max(-0.5, Math.min(info.height - 0.5, p.y)).toFixed(2) };
    this.renderMarkers();
    $('#draft-value').textContent = formatValue('probe_pixel', this.draft);
  }

  renderMarkers() {
    const it = this.item, ms = [];
    if (!this.hidden()) {
      for (const [probe, v] of Object.entries(it.siblings)) if (probe !== it.probe && v) ms.push({ x: v.x, y: v.y, cls: 'dim', label: probe });
      if (it.proposal) ms.push({ ...it.proposal, cls: 'auto', label: it.view.proposal_source || 'auto' });
      if (it.view.geometry) ms.push({ x: it.view.geometry[0], y: it.view.geometry[1], cls: 'geometry', label: 'geometry' });
      if (it.label) ms.push({ ...it.label.value, cls: 'saved', label: it.probe });
    }
    if (this.draft) ms.push({ ...this.draft, cls: 'draft', label: `${it.probe} (yours)` });
    this.flat.setMarkers(ms);
  }

  renderPanel() {
    const app = this.app, it = this.item, v = it.view;
    fill(this.panel,
      ...panelHeader(app, it),
      el('p', { class: 'hint' }, `Click where probe ${it.probe} stood in the photo (the point on the ground under the Theta). Wheel to zoom, drag to pan.`),
      v.note ? el('div', { class: 'row' }, 'Field note: ', el('i', {}, v.note)) : null,
      el('div', { class: 'row' }, el('span', { class: 'swatch auto' }), `Auto (${v.proposal_source || 'none'}): `,
        this.hidden() ? el('i', {}, 'hidden') : el('b', { id: 'auto-value' }, it.proposal ? formatValue('probe_pixel', it.proposal) : 'none')),
      v.geometry && !this.hidden() ? el('div', { class: 'row muted' }, el('span', { class: 'swatch geometry' }), `Geometry check: ${formatValue('probe_pixel', { x: v.geometry[0], y: v.geometry[1] })}, ${f2(v.geometry_error_px, 1)} px away`) : null,
      savedLine(app, it),
      el('div', { class: 'row' }, el('span', { class: 'swatch draft' }), 'Your mark: ', el('b', { id: 'draft-value' }, this.draft ? formatValue('probe_pixel', this.draft) : 'click the photo')),
      opinionsBlock(app, it),
      el('div', { class: 'buttons' },
        button('Accept auto', 'A', () => this.accept(), 'btn-accept', 'primary'),
        button('Save my mark', 'S', () => this.saveDraft(), 'btn-save', 'primary'),
        button('Undo last change', 'U', () => this.app.undo(), 'btn-undo'),
        button('Zoom to mark', 'Z', () => this.zoomTo(), 'btn-zoom'),
        button('Fit photo', '0', () => this.flat.fit(), 'btn-fit')),
      el('div', { class: 'muted small' }, `Photo ${v.photo.image.width}×${v.photo.image.height} px; coordinates are full-resolution pixels (pixel centres at integers).`),
      historyBlock(it),
    );
  }

  accept() {
    if (this.hidden() || !this.item.proposal) { this.app.toast('no automatic proposal to accept', 'warn'); return; }
    return this.app.save({ x: this.item.proposal.x, y: this.item.proposal.y });
  }

  saveDraft() {
    if (!this.draft) { this.app.toast('click the probe’s position first', 'warn'); return; }
    return this.app.save(this.draft);
  }

  zoomTo() {
    const t = this.draft || (this.item.label && this.item.label.value) || this.item.proposal;
    if (t) this.flat.centerOn(t.x, t.y, Math.max(this.flat.s, 2));
  }

  key(e) {
    const k = e.key, step = e.shiftKey ? 5 : 0.5;
    const nudge = (dx, dy) => { if (this.draft) this.place({ x: this.draft.x + dx, y: this.draft.y + dy }); };
    switch (k) {
      case 'a': case 'A': case 'Enter': this.accept(); return true;
      case 's': case 'S': this.saveDraft(); return true;
      case 'z': this.zoomTo(); return true;
      case '0': this.flat.fit(); return true;
      case '+': case '=': this.flat.zoomBy(1.5); return true;
      case '-': this.flat.zoomBy(1 / 1.5); return true;
      case 'Escape': this.draft = null; this.renderMarkers(); this.renderPanel(); return true;
      case 'ArrowLeft': nudge(-step, 0); return true;
      case 'ArrowRight': nudge(step, 0); return true;
      case 'ArrowUp': nudge(0, -step); return true;
      case 'ArrowDown': nudge(0, step); return true;
      default: return false;
    }
  }
}

// ---------------------------------------------------------------------------- heading
class HeadingTask {
  constructor(app) {
    this.app = app;
    this.root = el('div', { class: 'heading-layout', id: 'heading-view' });
    this.sphereBox = el('div', { class: 'sphere', id: 'heading-sphere' });
    this.photoBox = el('div', { class: 'photo-ref' }, el('img', { id: 'heading-photo', alt: 'the scene photo' }), el('div', { class: 'cap' }, 'the photo (its frame is outlined on the panorama)'));
    this.root.append(this.sphereBox, this.photoBox);
    this.panel = el('div', { class: 'panel-body', id: 'heading-panel' });
    this.exposure = 0;
    this.overlay = 0.5;
    this.sphere = new SphereView(this.sphereBox, {
      onPick: null,
      dragTest: e => e.shiftKey || this.insideFrame(e),
      onDrag: (d, phase) => {
        if (phase === 'start') { this.drag0 = { az: d.azimuth_deg, yaw: this.yaw }; return; }
        this.setYaw(this.drag0.yaw - wrap180(d.azimuth_deg - this.drag0.az), phase !== 'end');
      },
    });
  }

  mount(view, panel) {
    if (!this.root.parentNode) { view.append(this.root); panel.append(this.panel); }
    this.root.hidden = false; this.panel.hidden = false;
  }

  empty() { fill(this.panel, el('p', {}, 'No captures with a photo in this campaign.')); }

  hidden() { return this.app.blind && !this.app.reviewing; }

  async load(item) {
    this.item = item;
    const lab = !this.hidden() && item.label && item.label.value;
    const auto = !this.hidden() && item.proposal && item.proposal.yaw_deg != null ? item.proposal.yaw_deg : null;
    this.yaw = lab ? lab.yaw_deg : auto ?? 0;
    this.touched = false;
    $('#heading-photo').src = imageUrl.preview(item.view.photo.image.id);
    this.renderPanel();
    const ph = item.view.photo;
    await this.sphere.show(item.view.image, { azimuth_deg: wrap180(-this.yaw), elevation_deg: ph.pitch_deg || 0, fov: this.photoFov() * 1.6 });
    this.sphere.setExposure(this.exposure);
    this.renderMarkers();
  }

  photoFov() {
    const ph = this.item.view.photo;
    if (!ph.K) return 60;
    return (2 * Math.atan(ph.image.height / 2 / ph.K[1][1]) * 180) / Math.PI;
  }

  outline(yaw) {
    return (this.item.view.photo.outline || []).map(([a, e]) => [wrap180(a - yaw), e]);
  }

  setYaw(y, dragging = false) {
    this.yaw = +wrap180(y).toFixed(3);
    this.touched = true;
    this.renderMarkers();
    const v = $('#draft-value');
    if (v) v.textContent = formatValue('heading', { yaw_deg: this.yaw });
    if (!dragging) { const i = $('#yaw-input'); if (i) i.value = +this.yaw.toFixed(2); }
  }

  insideFrame(e) {
    const pts = this.outline(this.yaw).map(([a, el_]) => this.sphere.screenOf(a, el_));
    if (!pts.length || pts.some(p => !p)) return false;
    const r = this.sphereBox.getBoundingClientRect(), x = e.clientX - r.left, y = e.clientY - r.top;
    let inside = false;
    for (let i = 0, j = pts.length - 1; i < pts.length; j = i++) {
      const a = pts[i], b = pts[j];
      if ((a.y > y) !== (b.y > y) && x < ((b.x - a.x) * (y - a.y)) / (b.y - a.y) + a.x) inside = !inside;
    }
    return inside;
  }

  renderMarkers() {
    const it = this.item, ms = [];
    if (!it.view.photo.outline) { this.sphere.setMarkers([]); return; }
    const pitch = it.view.photo.pitch_deg || 0;
    if (!this.hidden()) {
      if (it.proposal && it.proposal.yaw_deg != null) ms.push({ id: 'auto', polygon: this.outline(it.proposal.yaw_deg), style: { fill: 'none', stroke: '#fb923c', strokeWidth: '2px', strokeDasharray: '8 5' } });
      if (it.label) ms.push({ id: 'saved', polygon: this.outline(it.label.value.yaw_deg), style: { fill: 'none', stroke: '#4ade80', strokeWidth: '2px' } });
    }
    const ol = this.outline(this.yaw), n = ol.length / 4;
    if (this.overlay > 0) ms.push({ id: 'photo', imageLayer: imageUrl.preview(it.view.photo.image.id), corners: [ol[0], ol[n], ol[2 * n], ol[3 * n]], opacity: this.overlay, z: 5 });
    ms.push({ id: 'draft', polygon: this.outline(this.yaw), style: { fill: 'rgba(34,211,238,0.08)', stroke: '#22d3ee', strokeWidth: '2.5px' }, z: 20 });
    ms.push({ id: 'draft-centre', azimuth_deg: wrap180(-this.yaw), elevation_deg: pitch, cls: 'centre', size: 18, z: 21 });
    this.sphere.setMarkers(ms);
  }

  renderPanel() {
    const app = this.app, it = this.item, v = it.view;
    const cues = Object.entries(v.cues || {});
    fill(this.panel,
      ...panelHeader(app, it),
      el('p', { class: 'hint' }, 'Turn the photo’s frame (cyan, with the photo drawn inside it) until the photo lines up with the panorama: drag inside the frame, Shift+drag anywhere, or ←/→. O toggles the photo.'),
      el('div', { class: 'row' }, el('span', { class: 'swatch auto' }), 'Auto: ',
        this.hidden() ? el('i', {}, 'hidden') : el('b', { id: 'auto-value' }, it.proposal ? formatValue('heading', it.proposal) : 'none'),
        v.residual_deg != null && !this.hidden() ? el('span', { class: 'muted' }, ` (cue residual ${f2(v.residual_deg)}°)`) : null),
      savedLine(app, it),
      el('div', { class: 'row' }, el('span', { class: 'swatch draft' }), 'Yours: ', el('b', { id: 'draft-value' }, formatValue('heading', { yaw_deg: this.yaw }))),
      el('label', { class: 'slider' }, el('span', {}, 'Yaw (°)'),
        el('input', { type: 'number', id: 'yaw-input', step: 0.1, value: +this.yaw.toFixed(2), onchange: e => this.setYaw(+e.target.value) })),
      opinionsBlock(app, it),
      slider('overlay', 'Photo overlay', 0, 1, 0.05, this.overlay, x => `${Math.round(x * 100)} %`, x => { this.overlay = x; this.renderMarkers(); }),
      slider('exposure-h', 'Exposure', -4, 8, 0.5, this.exposure, x => `${x > 0 ? '+' : ''}${x} EV`, x => { this.exposure = x; this.sphere.setExposure(x); }),
      el('div', { class: 'buttons' },
        button('Accept auto', 'A', () => this.accept(), 'btn-accept', 'primary'),
        button('Save my yaw', 'S', () => this.saveDraft(), 'btn-save', 'primary'),
        button('Look through photo', 'F', () => this.lookThrough(), 'btn-look'),
        button('Undo last change', 'U', () => this.app.undo(), 'btn-undo')),
      v.photo.pose_assumed ? el('div', { class: 'row warn' }, 'Photo pitch/roll unknown: assumed level.') : null,
      v.photo.outline ? null : el('div', { class: 'row warn' }, `No photo intrinsics (${v.photo.K_source}); the frame cannot be drawn.`),
      cues.length && !this.hidden() ? el('details', { class: 'cands' }, el('summary', {}, `Align cues (${cues.length})`),
        el('ul', {}, cues.map(([n, c]) => el('li', {}, `${n}: ${c.yaw_deg == null ? '–' : f2(c.yaw_deg) + '°'} `, el('span', { class: 'muted' }, `${c.ok ? 'ok' : 'not used'} ${c.detail || ''}`))))) : null,
      historyBlock(it),
    );
  }

  lookThrough() {
    this.sphere.lookAt(wrap180(-this.yaw), this.item.view.photo.pitch_deg || 0, this.photoFov());
  }

  accept() {
    const p = this.item.proposal;
    if (this.hidden() || !p || p.yaw_deg == null) { this.app.toast('no automatic alignment to accept', 'warn'); return; }
    return this.app.save({ yaw_deg: p.yaw_deg });
  }

  saveDraft() { return this.app.save({ yaw_deg: this.yaw }); }

  key(e) {
    const k = e.key, step = e.shiftKey ? 2 : 0.2;
    switch (k) {
      case 'a': case 'A': case 'Enter': this.accept(); return true;
      case 's': case 'S': this.saveDraft(); return true;
      case 'f': this.lookThrough(); return true;
      case 'o': {
        const s = $('#overlay');
        this.overlayOn = this.overlay > 0 ? this.overlay : (this.overlayOn || 0.5);
        if (s) { s.value = this.overlay > 0 ? 0 : this.overlayOn; s.dispatchEvent(new Event('input')); }
        return true;
      }
      case 'ArrowLeft': this.setYaw(this.yaw + step); return true;
      case 'ArrowRight': this.setYaw(this.yaw - step); return true;
      case '[': case ']': {
        this.exposure = Math.max(-4, Math.min(8, this.exposure + (k === ']' ? 0.5 : -0.5)));
        const s = $('#exposure-h'); if (s) { s.value = this.exposure; s.dispatchEvent(new Event('input')); }
        return true;
      }
      default: return false;
    }
  }
}

// ---------------------------------------------------------------------------- review
class ReviewTask {
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

const app = new App();
window.solidkitApp = app; // for the browser tests and the console
app.start().catch(err => {
  if (err instanceof ApiError && err.status === 401) app.showLogin();
  else { console.error(err); app.toast(String(err.message || err), 'error', 10000); }
});
