// A panorama view (Photo Sphere Viewer, rectilinear projection) speaking solidkit's angles.
// The base texture is the server's downscaled preview; full-resolution tiles load as the
// annotator zooms in (EquirectangularTilesAdapter), so the whole file is never sent.

import { Viewer } from '@photo-sphere-viewer/core';
import { MarkersPlugin } from '@photo-sphere-viewer/markers-plugin';
import { EquirectangularTilesAdapter } from '@photo-sphere-viewer/equirectangular-tiles-adapter';
import { imageUrl } from './api.js';
import { fromViewer, toViewer, angularDistance } from './frames.js';

// the closest view: the 0.53° sun is a tenth of it, still a precise click (at 1° it filled the view)
const MIN_FOV = 5, MAX_FOV = 110;

export class SphereView {
  // onPick({azimuth_deg, elevation_deg}): a click; onDrag(dir, phase): a drag that
  // dragTest(event) accepted at mousedown ('start' | 'move' | 'end').
  constructor(container, { onPick = null, onDrag = null, dragTest = null } = {}) {
    this.container = container;
    this.host = document.createElement('div');
    this.host.className = 'psv-host';
    container.append(this.host);
    this.viewer = null;
    this.imageId = null;
    this.exposure = 0;
    this.onPick = onPick;
    this.onDrag = onDrag;
    this.dragTest = dragTest;
    container.addEventListener('mousedown', e => this._maybeDrag(e), true);
  }

  // show a panorama; calls are queued (a second call while the first loads waits for it)
  show(info, opts = {}) {
    this._queue = (this._queue || Promise.resolve()).then(() => this._show(info, opts), () => this._show(info, opts));
    return this._queue;
  }

  async _show(info, { azimuth_deg = 0, elevation_deg = 0, fov = 75 } = {}) {
    this.container.dataset.ready = '0';
    const panorama = {
      width: info.width, cols: info.tiles.cols, rows: info.tiles.rows,
      baseUrl: imageUrl.preview(info.id),
      tileUrl: (col, row) => imageUrl.tile(info.id, col, row),
    };
    const position = toViewer(azimuth_deg, elevation_deg);
    if (!this.viewer) {
      this.viewer = new Viewer({
        container: this.host,
        adapter: [EquirectangularTilesAdapter, { baseBlur: false, showErrorTile: true }],
        panorama, plugins: [[MarkersPlugin, {}]],
        navbar: false, keyboard: false, moveInertia: false, minFov: MIN_FOV, maxFov: MAX_FOV,
        defaultYaw: position.yaw, defaultPitch: position.pitch, loadingTxt: 'loading…',
        defaultZoomLvl: Math.max(0, Math.min(100, ((MAX_FOV - fov) / (MAX_FOV - MIN_FOV)) * 100)),
      });
      this.markers = this.viewer.getPlugin(MarkersPlugin);
      this.viewer.addEventListener('click', e => {
        if (!e.data.rightclick && this.onPick) this.onPick(fromViewer(e.data));
      });
      this.viewer.addEventListener('position-updated', () => this.container.dispatchEvent(new Event('viewchange')));
      this.viewer.addEventListener('zoom-updated', () => this.container.dispatchEvent(new Event('viewchange')));
      await new Promise(resolve => this.viewer.addEventListener('panorama-loaded', resolve, { once: true }));
    } else if (this.imageId !== info.id) {
      await this.viewer.setPanorama(panorama, {
        transition: false, showLoader: true, position, zoom: this.viewer.dataHelper.fovToZoomLevel(fov),
      });
    } else {
      this.lookAt(azimuth_deg, elevation_deg, fov);
    }
    this.imageId = info.id;
    this.setExposure(this.exposure);
    this.container.dataset.ready = '1';
  }

  // exposure in stops, applied to the displayed (sRGB) pixels
  setExposure(ev) {
    this.exposure = ev;
    const canvas = this.host.querySelector('.psv-canvas-container');
    if (canvas) canvas.style.filter = ev === 0 ? '' : `brightness(${Math.pow(2, ev / 2.2).toFixed(3)})`;
  }

  lookAt(azimuth_deg, elevation_deg, fov = null) {
    if (!this.viewer) return;
    this.viewer.rotate(toViewer(azimuth_deg, elevation_deg));
    if (fov) this.viewer.zoom(this.viewer.dataHelper.fovToZoomLevel(fov));
  }

  view() {
    const p = this.viewer.getPosition();
    return { ...fromViewer(p), fov: this.viewer.dataHelper.zoomLevelToFov(this.viewer.getZoomLevel()) };
  }

  // screen position (px, relative to the view) of a direction, or null when out of sight
  screenOf(azimuth_deg, elevation_deg) {
    if (!this.viewer) return null;
    const v = this.view();
    if (angularDistance(v.azimuth_deg, v.elevation_deg, azimuth_deg, elevation_deg) > 0.8 * Math.max(v.fov, 1) + 5) return null;
    return this.viewer.dataHelper.sphericalCoordsToViewerCoords(toViewer(azimuth_deg, elevation_deg));
  }

  directionAt(clientX, clientY) {
    const r = this.host.getBoundingClientRect();
    return fromViewer(this.viewer.dataHelper.viewerCoordsToSphericalCoords({ x: clientX - r.left, y: clientY - r.top }));
  }

  // markers: [{id, azimuth_deg, elevation_deg, cls, size, label}] (html points) and
  // [{id, polygon|polyline: [[az, el], ...], style}] (shapes on the sphere)
  setMarkers(list) {
    if (!this.markers) return;
    const out = [];
    for (const m of list) {
      // markers never take the pointer: a click on (or inside) one marks that spot (the
      // common case: the sun right under align's proposal); what they mean is in the panel
      const base = { id: m.id, zIndex: m.z || 10, style: { pointerEvents: 'none' } };
      if (m.imageLayer) out.push({ ...base, imageLayer: m.imageLayer, opacity: m.opacity ?? 1, position: m.corners.map(([a, e]) => toViewer(a, e)) });
      else if (m.polygon) out.push({ ...base, polygon: m.polygon.map(([a, e]) => { const v = toViewer(a, e); return [v.yaw, v.pitch]; }), svgStyle: m.style });
      else if (m.polygonRad) out.push({ ...base, polygon: m.polygonRad, svgStyle: m.style });
      else if (m.polyline) out.push({ ...base, polyline: m.polyline.map(([a, e]) => { const v = toViewer(a, e); return [v.yaw, v.pitch]; }), svgStyle: m.style });
      else {
        const s = m.size || 22;
        out.push({
          ...base, position: toViewer(m.azimuth_deg, m.elevation_deg), size: { width: s, height: s },
          anchor: 'center center', html: `<div class="mk ${m.cls || ''}">${m.label || ''}</div>`,
        });
      }
    }
    this.markers.setMarkers(out);
  }

  _maybeDrag(e) {
    if (e.button !== 0 || !this.viewer || !this.dragTest || !this.dragTest(e)) return;
    e.stopPropagation();
    e.preventDefault();
    const move = ev => this.onDrag(this.directionAt(ev.clientX, ev.clientY), 'move', ev);
    const up = ev => {
      window.removeEventListener('mousemove', move, true);
      window.removeEventListener('mouseup', up, true);
      this.onDrag(this.directionAt(ev.clientX, ev.clientY), 'end', ev);
    };
    window.addEventListener('mousemove', move, true);
    window.addEventListener('mouseup', up, true);
    this.onDrag(this.directionAt(e.clientX, e.clientY), 'start', e);
  }
}
