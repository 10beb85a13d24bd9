// The probe-pixel task: where each probe stood in the scene's photo.

import { FlatView } from './flat.js';
import { $, el, fill, panelHeader, f2, formatValue, savedLine, opinionsBlock, historyBlock, button, noteBlock, reviewBlock, undoButtons, sourceText } from './ui.js';

export class PixelTask {
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

  hidden() { return !!(this.item && this.item.blind); }

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
    $('#draft-value', this.panel).textContent = formatValue('probe_pixel', this.draft);
  }

  renderMarkers() {
    const it = this.item, ms = [];
    if (!this.hidden()) {
      for (const [probe, v] of Object.entries(it.siblings)) if (probe !== it.probe && v) ms.push({ x: v.x, y: v.y, cls: 'dim', label: probe });
      if (it.proposal) ms.push({ ...it.proposal, cls: 'auto', label: sourceText(it.view.proposal_source) });
      if (it.view.geometry) ms.push({ x: it.view.geometry[0], y: it.view.geometry[1], cls: 'geometry', label: 'geometry' });
      if (it.label && it.label.source !== 'auto') ms.push({ ...it.label.value, cls: 'saved', label: it.probe });
    }
    if (this.hidden() && it.mine && it.mine.value) ms.push({ ...it.mine.value, cls: 'saved', label: `${it.probe} (saved)` });
    if (this.draft) ms.push({ ...this.draft, cls: 'draft', label: `${it.probe} (yours)` });
    this.flat.setMarkers(ms);
  }

  renderPanel() {
    const app = this.app, it = this.item, v = it.view;
    fill(this.panel,
      ...panelHeader(app, it),
      el('p', { class: 'hint' }, `Click where position ${it.probe} is in the photo (the point on the ground under the camera tripod). Wheel to zoom, drag to pan.`),
      v.note ? el('div', { class: 'row' }, 'Field note: ', el('i', {}, v.note)) : null,
      el('div', { class: 'row' }, el('span', { class: 'swatch auto' }), `Auto (${sourceText(v.proposal_source)}): `,
        this.hidden() ? el('i', {}, 'hidden') : el('b', { id: 'auto-value' }, it.proposal ? formatValue('probe_pixel', it.proposal) : 'none')),
      v.geometry && !this.hidden() ? el('div', { class: 'row muted' }, el('span', { class: 'swatch geometry' }), `Camera geometry puts it at ${formatValue('probe_pixel', { x: v.geometry[0], y: v.geometry[1] })}, ${f2(v.geometry_error_px, 1)} px away`) : null,
      savedLine(app, it),
      el('div', { class: 'row' }, el('span', { class: 'swatch draft' }), 'Your mark: ', el('b', { id: 'draft-value' }, this.draft ? formatValue('probe_pixel', this.draft) : 'click the photo')),
      opinionsBlock(app, it),
      reviewBlock(app, it),
      el('div', { class: 'buttons' },
        button('Accept auto', 'A', () => this.accept(), 'btn-accept', 'primary'),
        button('Save my mark', 'S', () => this.saveDraft(), 'btn-save', 'primary'),
        ...undoButtons(this.app),
        button('Zoom to mark', 'Z', () => this.zoomTo(), 'btn-zoom'),
        button('Fit photo', '0', () => this.flat.fit(), 'btn-fit')),
      el('div', { class: 'muted small' }, `Photo ${v.photo.image.width}×${v.photo.image.height} px; coordinates are full-resolution pixels (pixel centres at integers).`),
      noteBlock(app, it),
      historyBlock(app, it),
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
