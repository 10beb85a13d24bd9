// A flat image view (the scene's photo) with wheel zoom, drag pan and markers, in the image's
// full-resolution pixel coordinates (OpenCV pixel centres: the image spans [-0.5, W - 0.5]).
// It shows the server's preview and, once zoomed past it, a full-resolution crop of the
// visible region only.

import { imageUrl } from './api.js';

export class FlatView {
  constructor(container, { onPick = null, onDrag = null, dragTest = null } = {}) {
    this.container = container;
    this.canvas = document.createElement('canvas');
    this.canvas.className = 'flat-canvas';
    container.append(this.canvas);
    this.ctx = this.canvas.getContext('2d');
    this.info = null;
    this.preview = null;
    this.crop = null;
    this.markers = [];
    this.s = 1; this.ox = 0; this.oy = 0;
    Object.assign(this, { onPick, onDrag, dragTest });
    new ResizeObserver(() => this._resize()).observe(container);
    this.canvas.addEventListener('wheel', e => this._wheel(e), { passive: false });
    this.canvas.addEventListener('mousedown', e => this._down(e));
    this._cropTimer = null;
  }

  async show(info) {
    this.container.dataset.ready = '0';
    if (!this.info || this.info.id !== info.id) {
      this.info = info;
      this.crop = null;
      this.preview = await loadImage(imageUrl.preview(info.id));
      this.fit();
    }
    this.container.dataset.ready = '1';
  }

  fit() {
    const { w, h } = this._size();
    if (!this.info || !w) return;
    this.s = Math.min(w / this.info.width, h / this.info.height);
    this.ox = (w - this.info.width * this.s) / 2;
    this.oy = (h - this.info.height * this.s) / 2;
    this._changed();
  }

  // centre the view on full-res pixel (x, y) at `scale` screen px per image px
  centerOn(x, y, scale = null) {
    const { w, h } = this._size();
    if (scale) this.s = scale;
    this.ox = w / 2 - (x + 0.5) * this.s;
    this.oy = h / 2 - (y + 0.5) * this.s;
    this._changed();
  }

  toScreen(x, y) { return { x: this.ox + (x + 0.5) * this.s, y: this.oy + (y + 0.5) * this.s }; }
  toImage(sx, sy) { return { x: (sx - this.ox) / this.s - 0.5, y: (sy - this.oy) / this.s - 0.5 }; }

  setMarkers(list) { this.markers = list; this.draw(); }

  zoomBy(f, sx = null, sy = null) {
    const { w, h } = this._size();
    sx = sx ?? w / 2; sy = sy ?? h / 2;
    const p = this.toImage(sx, sy);
    this.s = Math.max(0.02, Math.min(40, this.s * f));
    this.ox = sx - (p.x + 0.5) * this.s;
    this.oy = sy - (p.y + 0.5) * this.s;
    this._changed();
  }

  _size() { const r = this.container.getBoundingClientRect(); return { w: r.width, h: r.height }; }

  _resize() {
    const { w, h } = this._size();
    const dpr = window.devicePixelRatio || 1;
    this.canvas.width = Math.max(1, Math.round(w * dpr));
    this.canvas.height = Math.max(1, Math.round(h * dpr));
    this.canvas.style.width = `${w}px`;
    this.canvas.style.height = `${h}px`;
    if (this.info && this.s === 1 && this.ox === 0) this.fit(); else this.draw();
  }

  _changed() { this.draw(); clearTimeout(this._cropTimer); this._cropTimer = setTimeout(() => this._loadCrop(), 120); }

  async _loadCrop() {
    if (!this.info) return;
    const { w, h } = this._size();
    const W = this.info.width, H = this.info.height;
    if (this.s * W / this.info.preview_width <= 1.1) { this.crop = null; this.draw(); return; }
    const g = 64;
    const a = this.toImage(0, 0), b = this.toImage(w, h);
    const x0 = Math.max(0, Math.floor((a.x + 0.5) / g) * g), y0 = Math.max(0, Math.floor((a.y + 0.5) / g) * g);
    const x1 = Math.min(W, Math.ceil((b.x + 0.5) / g) * g), y1 = Math.min(H, Math.ceil((b.y + 0.5) / g) * g);
    if (x1 <= x0 || y1 <= y0) return;
    const out = Math.min(2048, Math.ceil(w * (window.devicePixelRatio || 1)), x1 - x0);
    const key = `${this.info.id}:${x0},${y0},${x1},${y1},${out}`;
    if (this.crop && this.crop.key === key) return;
    const img = await loadImage(imageUrl.crop(this.info.id, x0, y0, x1 - x0, y1 - y0, out)).catch(() => null);
    if (img && this.info) { this.crop = { key, img, x0, y0, x1, y1 }; this.draw(); }
  }

  draw() {
    const c = this.ctx, dpr = window.devicePixelRatio || 1;
    c.setTransform(dpr, 0, 0, dpr, 0, 0);
    const { w, h } = this._size();
    c.fillStyle = '#1b1d21';
    c.fillRect(0, 0, w, h);
    if (!this.preview) return;
    const W = this.info.width, H = this.info.height;
    c.imageSmoothingEnabled = this.s < 2;
    c.drawImage(this.preview, this.ox, this.oy, W * this.s, H * this.s);
    if (this.crop && this.crop.key.startsWith(this.info.id)) {
      const k = this.crop;
      c.drawImage(k.img, this.ox + k.x0 * this.s, this.oy + k.y0 * this.s, (k.x1 - k.x0) * this.s, (k.y1 - k.y0) * this.s);
    }
    for (const m of this.markers) drawMarker(c, this.toScreen(m.x, m.y), m);
  }

  _wheel(e) {
    e.preventDefault();
    const r = this.canvas.getBoundingClientRect();
    this.zoomBy(Math.pow(1.2, -e.deltaY / 100), e.clientX - r.left, e.clientY - r.top);
  }

  _down(e) {
    if (e.button !== 0 || !this.info) return;
    const r = this.canvas.getBoundingClientRect();
    const start = { x: e.clientX, y: e.clientY, ox: this.ox, oy: this.oy };
    const dragging = this.dragTest && this.dragTest(this.toImage(e.clientX - r.left, e.clientY - r.top), e);
    let moved = false;
    const move = ev => {
      const dx = ev.clientX - start.x, dy = ev.clientY - start.y;
      if (Math.abs(dx) + Math.abs(dy) > 3) moved = true;
      if (dragging) this.onDrag(this.toImage(ev.clientX - r.left, ev.clientY - r.top), 'move');
      else if (moved) { this.ox = start.ox + dx; this.oy = start.oy + dy; this._changed(); }
    };
    const up = ev => {
      window.removeEventListener('mousemove', move);
      window.removeEventListener('mouseup', up);
      const p = this.toImage(ev.clientX - r.left, ev.clientY - r.top);
      if (dragging) this.onDrag(p, 'end');
      else if (!moved && this.onPick) this.onPick(p);
    };
    window.addEventListener('mousemove', move);
    window.addEventListener('mouseup', up);
    e.preventDefault();
  }
}

export function loadImage(url) {
  return new Promise((resolve, reject) => {
    const img = new Image();
    img.onload = () => resolve(img);
    img.onerror = () => reject(new Error(`could not load ${url}`));
    img.src = url;
  });
}

const COLORS = { draft: '#22d3ee', saved: '#4ade80', auto: '#fb923c', other: '#e5e7eb', geometry: '#c084fc', dim: '#9ca3af' };

function drawMarker(c, p, m) {
  const col = COLORS[m.cls] || m.color || '#fff';
  c.save();
  c.lineWidth = 2;
  c.strokeStyle = 'rgba(0,0,0,0.7)';
  const shape = () => {
    c.beginPath();
    if (m.cls === 'auto' || m.cls === 'geometry') c.arc(p.x, p.y, 9, 0, 2 * Math.PI);
    else if (m.cls === 'other' || m.cls === 'dim') { c.rect(p.x - 4, p.y - 4, 8, 8); }
    else { c.moveTo(p.x - 12, p.y); c.lineTo(p.x - 3, p.y); c.moveTo(p.x + 3, p.y); c.lineTo(p.x + 12, p.y);
           c.moveTo(p.x, p.y - 12); c.lineTo(p.x, p.y - 3); c.moveTo(p.x, p.y + 3); c.lineTo(p.x, p.y + 12); }
  };
  c.lineWidth = 4; shape(); c.stroke();
  c.strokeStyle = col; c.lineWidth = 2; shape(); c.stroke();
  if (m.label) {
    c.font = '12px system-ui, sans-serif';
    c.lineWidth = 3; c.strokeStyle = 'rgba(0,0,0,0.8)'; c.strokeText(m.label, p.x + 11, p.y - 9);
    c.fillStyle = col; c.fillText(m.label, p.x + 11, p.y - 9);
  }
  c.restore();
}
