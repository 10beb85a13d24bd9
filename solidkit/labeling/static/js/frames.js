// The one conversion between solidkit's panorama angles and Photo Sphere Viewer's.
//
// solidkit (docs/conventions.md §3): azimuth in [-180°, 180°), 0 at the image centre,
// positive to the right; elevation positive up. Photo Sphere Viewer: yaw in [0, 2π) radians,
// 0 at the image centre, increasing to the right; pitch positive up. Checked end to end by
// tests/test_labeling_browser.py (markers drawn at known directions, clicked in the browser).

const D2R = Math.PI / 180;

export function wrap180(deg) {
  return ((((deg + 180) % 360) + 360) % 360) - 180;
}

export function toViewer(azimuthDeg, elevationDeg) {
  const yaw = ((azimuthDeg * D2R) % (2 * Math.PI) + 2 * Math.PI) % (2 * Math.PI);
  return { yaw, pitch: elevationDeg * D2R };
}

export function fromViewer(position) {
  return { azimuth_deg: wrap180(position.yaw / D2R), elevation_deg: position.pitch / D2R };
}

// Points of a small circle of angular radius `radiusDeg` around (azimuth, elevation), for
// polygon markers (exact on the sphere; a pixel circle would be wrong near the zenith).
export function circle(azimuthDeg, elevationDeg, radiusDeg, n = 48) {
  const a = azimuthDeg * D2R, e = elevationDeg * D2R, r = radiusDeg * D2R;
  // centre and two tangent vectors in solidkit's frame (x right, y down, z forward)
  const c = [Math.cos(e) * Math.sin(a), -Math.sin(e), Math.cos(e) * Math.cos(a)];
  const east = [Math.cos(a), 0, -Math.sin(a)];
  const north = [-Math.sin(e) * Math.sin(a), -Math.cos(e), -Math.sin(e) * Math.cos(a)];
  const pts = [];
  for (let i = 0; i < n; i++) {
    const t = (2 * Math.PI * i) / n;
    const d = [0, 1, 2].map(k => Math.cos(r) * c[k] + Math.sin(r) * (Math.cos(t) * east[k] + Math.sin(t) * north[k]));
    const az = Math.atan2(d[0], d[2]) / D2R, el = Math.asin(Math.max(-1, Math.min(1, -d[1]))) / D2R;
    const v = toViewer(az, el);
    pts.push([v.yaw, v.pitch]);
  }
  return pts;
}

// Great-circle distance in degrees between two directions given in degrees.
export function angularDistance(a1, e1, a2, e2) {
  const p1 = e1 * D2R, p2 = e2 * D2R, dl = (a2 - a1) * D2R;
  const s = Math.sin((p2 - p1) / 2) ** 2 + Math.cos(p1) * Math.cos(p2) * Math.sin(dl / 2) ** 2;
  return (2 * Math.asin(Math.min(1, Math.sqrt(s)))) / D2R;
}
