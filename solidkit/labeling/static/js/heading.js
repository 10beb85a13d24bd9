// The heading task: turn the photo's frame on a capture's panorama until the photo lines up.

import { imageUrl } from './api.js';
import { SphereView } from './sphere.js';
import { wrap180 } from './frames.js';
import { $, el, fill, panelHeader, f2, formatValue, savedLine, opinionsBlock, historyBlock, button, noteBlock, reviewBlock, undoButtons, sourceText, slider } from './ui.js';

export class HeadingTask {
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

  hidden() { return !!(this.item && this.item.blind); }

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
    const v = $('#draft-value', this.panel);
    if (v) v.textContent = formatValue('heading', { yaw_deg: this.yaw });
    if (!dragging) { const i = $('#yaw-input', this.panel); if (i) i.value = +this.yaw.toFixed(2); }
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
      if (it.label && it.label.source !== 'auto') ms.push({ id: 'saved', polygon: this.outline(it.label.value.yaw_deg), style: { fill: 'none', stroke: '#4ade80', strokeWidth: '2px' } });
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
      el('p', { class: 'hint' }, 'Turn the photo’s frame (cyan, with the photo drawn inside it) until the photo lines up with the panorama: drag inside the frame, Shift+drag anywhere, or ←/→. O toggles the photo. Line up distant things (building tops, skyline): near objects shift with the position.'),
      el('div', { class: 'row' }, el('span', { class: 'swatch auto' }), 'Auto: ',
        this.hidden() ? el('i', {}, 'hidden') : el('b', { id: 'auto-value' }, it.proposal ? formatValue('heading', it.proposal) : 'none'),
        v.residual_deg != null && !this.hidden() ? el('span', { class: 'muted' }, ` (the automatic clues agree within ${f2(v.residual_deg)}°)`) : null),
      savedLine(app, it),
      el('div', { class: 'row' }, el('span', { class: 'swatch draft' }), 'Yours: ', el('b', { id: 'draft-value' }, formatValue('heading', { yaw_deg: this.yaw }))),
      el('label', { class: 'slider' }, el('span', {}, 'Yaw (°)'),
        el('input', { type: 'number', id: 'yaw-input', step: 0.1, value: +this.yaw.toFixed(2), onchange: e => this.setYaw(+e.target.value) })),
      opinionsBlock(app, it),
      reviewBlock(app, it),
      slider('overlay', 'Photo overlay', 0, 1, 0.05, this.overlay, x => `${Math.round(x * 100)} %`, x => { this.overlay = x; this.renderMarkers(); }),
      slider('exposure-h', 'Exposure', -4, 8, 0.5, this.exposure, x => `${x > 0 ? '+' : ''}${x} EV`, x => { this.exposure = x; this.sphere.setExposure(x); }),
      el('div', { class: 'buttons' },
        button('Accept auto', 'A', () => this.accept(), 'btn-accept', 'primary'),
        button('Save my yaw', 'S', () => this.saveDraft(), 'btn-save', 'primary'),
        button('Look through photo', 'F', () => this.lookThrough(), 'btn-look'),
        ...undoButtons(this.app)),
      v.photo.pose_assumed ? el('div', { class: 'row warn' }, 'Photo pitch/roll unknown: assumed level.') : null,
      v.photo.outline ? null : el('div', { class: 'row warn' }, 'No lens data for this photo: its frame cannot be drawn.'),
      cues.length && !this.hidden() ? el('details', { class: 'cands' }, el('summary', {}, `Automatic clues (${cues.length})`),
        el('ul', {}, cues.map(([n, c]) => el('li', {}, `${n}: ${c.yaw_deg == null ? '–' : f2(c.yaw_deg) + '°'} `, el('span', { class: 'muted' }, `${c.ok ? 'used' : 'not used'}`))))) : null,
      noteBlock(app, it),
      historyBlock(app, it),
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
        const s = $('#overlay', this.panel);
        this.overlayOn = this.overlay > 0 ? this.overlay : (this.overlayOn || 0.5);
        if (s) { s.value = this.overlay > 0 ? 0 : this.overlayOn; s.dispatchEvent(new Event('input')); }
        return true;
      }
      case 'ArrowLeft': this.setYaw(this.yaw + step); return true;
      case 'ArrowRight': this.setYaw(this.yaw - step); return true;
      case '[': case ']': {
        this.exposure = Math.max(-4, Math.min(8, this.exposure + (k === ']' ? 0.5 : -0.5)));
        const s = $('#exposure-h', this.panel); if (s) { s.value = this.exposure; s.dispatchEvent(new Event('input')); }
        return true;
      }
      default: return false;
    }
  }
}
