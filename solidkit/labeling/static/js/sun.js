// The sun task: mark the centre of the sun's disk on each low-exposure panorama.

import { imageUrl } from './api.js';
import { SphereView } from './sphere.js';
import { circle, wrap180 } from './frames.js';
import { $, el, fill, panelHeader, f2, formatValue, savedLine, opinionsBlock, historyBlock, button, noteBlock, reviewBlock, undoButtons, sourceText, slider } from './ui.js';

const UNC_STEPS = [0.05, 0.1, 0.15, 0.2, 0.3, 0.5, 0.75, 1, 1.5, 2, 3, 5];

export class SunTask {
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

  hidden() { return !!(this.item && this.item.blind); }

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
    else $('#draft-value', this.panel).textContent = formatValue('sun', this.value());
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
      const lab = it.label && it.label.source !== 'auto' && it.label.value;
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
      const lab = this.item.label && this.item.label.source !== 'auto' && this.item.label.value;
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
    else if (!p) auto = el('i', {}, app.campaign.has_alignment ? 'none for this capture' : 'none yet (the automatic alignment has not run)');
    else if (p.found === false) auto = el('span', {}, 'the automatic search found no sun', it.view.reason ? el('span', { class: 'muted' }, ` (${it.view.reason})`) : null);
    else auto = el('b', { id: 'auto-value' }, formatValue('sun', p));
    const rejected = it.view.candidates.filter(c => !c.chosen);
    fill(this.panel,
      ...panelHeader(app, it),
      el('p', { class: 'hint' }, 'Click the centre of the sun’s bright disk (drag your mark to adjust), A to accept the orange proposal, N if no sun is visible. Grey × marks are bright spots the automatic search ruled out. Hover the strip below to look around.'),
      el('div', { class: 'row' }, el('span', { class: 'swatch auto' }), 'Auto: ', auto),
      it.view.ephemeris && it.view.ephemeris.elevation_deg != null
        ? el('div', { class: 'row muted' }, el('span', { class: 'swatch ephem' }), `Expected sun height from the time and place: ${f2(it.view.ephemeris.elevation_deg)}° (dashed line)`) : null,
      savedLine(app, it),
      el('div', { class: 'row' }, el('span', { class: 'swatch draft' }), 'Your mark: ', el('b', { id: 'draft-value' }, this.draft ? formatValue('sun', this.value()) : 'click the sun’s centre')),
      opinionsBlock(app, it),
      reviewBlock(app, it),
      slider('unc', 'Uncertainty', 0, UNC_STEPS.length - 1, 1, nearestStep(this.unc), i => `±${UNC_STEPS[i]}°`, i => { this.unc = UNC_STEPS[i]; this.renderMarkers(); $('#draft-value', this.panel).textContent = this.draft ? formatValue('sun', this.value()) : 'click the sun’s centre'; }),
      slider('exposure', 'Exposure', -4, 8, 0.5, this.exposure, v => `${v > 0 ? '+' : ''}${v} EV`, v => { this.exposure = v; this.sphere.setExposure(v); }),
      el('div', { class: 'buttons' },
        button('Accept auto', 'A', () => this.accept(), 'btn-accept', 'primary'),
        button('Save my mark', 'S', () => this.saveDraft(), 'btn-save', 'primary'),
        button('No sun visible', 'N', () => this.app.save({ found: false }), 'btn-nosun'),
        ...undoButtons(this.app),
        button('Go to mark', 'G', () => this.goTo(), 'btn-goto'),
        button('Clear my mark', 'Esc', () => { this.draft = null; this.renderMarkers(); this.renderPanel(); }, 'btn-clear')),
      rejected.length && !this.hidden() ? el('details', { class: 'cands', open: true }, el('summary', {}, `Bright spots ruled out (${rejected.length})`),
        el('ul', {}, rejected.map(c => el('li', { onclick: () => this.sphere.lookAt(c.azimuth_deg, c.elevation_deg, 15) },
          `az ${f2(wrap180(c.azimuth_deg), 1)}°, el ${f2(c.elevation_deg, 1)}°: `, el('span', { class: 'muted' }, (c.reasons || []).join('; ')))))) : null,
      noteBlock(app, it),
      historyBlock(app, it),
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
        this.sphere.setExposure(this.exposure); const s = $('#exposure', this.panel); if (s) { s.value = this.exposure; s.dispatchEvent(new Event('input')); }
        return true;
      }
      case '-': case '=': case '+': {
        const i = Math.max(0, Math.min(UNC_STEPS.length - 1, nearestStep(this.unc) + (k === '-' ? -1 : 1)));
        const s = $('#unc', this.panel); if (s) { s.value = i; s.dispatchEvent(new Event('input')); }
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
