"""Scene lighting: Mitsuba's ``sunsky`` (Hosek-Wilkie sky + sun) and real HDR panoramas.

Everything is an HDR panorama in the **scene frame** (docs/conventions.md panorama mapping,
x right, y down, z forward; see :mod:`solidkit.synth.scene`) plus a rotation ``R`` (content at
``d`` moves to ``R d``, conventions §4), rendered through Mitsuba's ``envmap`` emitter.

Mitsuba's envmap maps a local direction ``l`` to ``u = atan2(l_x, -l_z) / 2pi``,
``v = acos(l_y) / pi`` (+y up). Substituting ``l = M0 d`` with ``M0 = diag(-1, -1, 1)`` (a
180° turn about z) gives exactly our ``u = (phi + pi) / 2pi``, ``v = (pi/2 - theta) / pi``: a
panorama in our convention is a Mitsuba bitmap whose content at our direction ``d`` sits at
local ``M0 d``. Hence the emitter's ``to_world = R M0``. ``tests/synth/test_conventions.py``
renders a bright spot through :mod:`solidkit.synth.plugins`' equirect sensor and checks it
lands on the pixel of :func:`solidkit.envmap.coords_from_direction`.

- ``sunsky``: the sky (``sun_scale = 0``) is evaluated on a 256x128 grid of our directions
  (as ``A_SKY d``: Mitsuba's sunsky has its zenith on local +z, measured), upsampled to the
  working resolution, and the sun is added as one pixel holding the sun disk's full energy
  ``L_sun * Omega_sun`` (uniform disk of ``sun_aperture`` degrees), so irradiance is exact
  whatever the resolution.
- HDR maps (``solidkit/assets/hdr_panoramas``, CC0) are turned about the vertical by an angle
  drawn uniformly in [0°, 60°]: our reading of the paper's "rotate along the latitude
  direction" (shifting the map along its parallels, i.e. changing the sun azimuth; a tilt
  would tip the horizon). The sun is the luminance-weighted centroid of the pixels above half
  the maximum, when the maximum exceeds 50x the median (else ``sun = None``, overcast).

Exposure: every lighting is scaled so that the irradiance on an upward-facing surface is
``pi * E`` with ``E`` drawn in [0.6, 1.2] (a white Lambertian ground then has radiance ~E).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from solidkit.envmap import (
    angles_from_direction,
    coords_from_direction,
    direction_from_angles,
    direction_grid,
    luminance,
    read_panorama,
    rotation_y,
    solid_angle,
    spherical_centroid,
)
from solidkit.errors import InputError
from solidkit.synth.mitsuba_variant import is_vectorized, mitsuba, variant

__all__ = ["M0", "HDR_DIR", "Lighting", "sunsky", "hdr", "random_lighting", "horizontal_irradiance", "find_sun"]

M0 = np.diag([-1.0, -1.0, 1.0])
HDR_DIR = Path(__file__).resolve().parents[1] / "assets" / "hdr_panoramas"
UP = np.array([0.0, -1.0, 0.0])
# scene frame -> Mitsuba sunsky's local frame, whose zenith is +z (measured: the 3.9 sky is 0 for z < 0)
A_SKY = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])


@dataclass
class Lighting:
    """An environment: ``panorama (H, 2H, 3)`` linear float32 (scene frame before ``rotation``).

    rotation: ``(3, 3)``, content at ``d`` appears at ``rotation @ d`` in the scene frame;
    sun: unit sun direction in the scene frame (after rotation) or None; meta: JSON-ready
    description (kind, turbidity, file, rotation angle in degrees, exposure scale).
    """

    panorama: np.ndarray
    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    sun: np.ndarray | None = None
    meta: dict[str, Any] = field(default_factory=dict)

    def emitter(self) -> dict[str, Any]:
        """Mitsuba ``envmap`` plugin dict (``to_world = rotation @ M0``)."""
        mi = mitsuba()
        m = np.eye(4)
        m[:3, :3] = self.rotation @ M0
        return {
            "type": "envmap",
            "bitmap": mi.Bitmap(np.ascontiguousarray(self.panorama, dtype=np.float32)),
            "to_world": mi.ScalarTransform4f(m.tolist()),
        }


def horizontal_irradiance(pano: np.ndarray) -> float:
    """Luminance irradiance (Rec.709 weights) on an upward-facing plane, ``sum L max(0, up.d) Omega``."""
    h = pano.shape[0]
    d = direction_grid(h)
    cos = np.clip(d @ UP, 0.0, None)
    lum = luminance(pano, np.float64)
    return float(np.sum(lum * cos * solid_angle(h)))


def find_sun(pano: np.ndarray, ratio: float = 50.0) -> np.ndarray | None:
    """Sun direction of a panorama or None if no peak: the spherical centroid
    (:func:`solidkit.envmap.sun.spherical_centroid`) of the pixels above half the peak luminance,
    when the peak exceeds ``ratio`` times the median."""
    lum = luminance(pano, np.float64)
    peak = float(lum.max())
    if not np.isfinite(peak) or peak <= ratio * max(float(np.median(lum)), 1e-9):
        return None
    return spherical_centroid(lum, lum >= 0.5 * peak)


def _normalise(pano: np.ndarray, rng: np.random.Generator) -> tuple[np.ndarray, float]:
    target = math.pi * float(rng.uniform(0.6, 1.2))
    scale = target / max(horizontal_irradiance(pano), 1e-12)
    return (pano * scale).astype(np.float32), scale


def sunsky(
    sun: np.ndarray,
    turbidity: float = 3.0,
    *,
    height: int = 512,
    rng: np.random.Generator | None = None,
    sun_aperture_deg: float = 0.5358,
    normalise: bool = True,
) -> Lighting:
    """Mitsuba's Hosek-Wilkie sun and sky for a unit ``sun`` direction (scene frame, y down).

    Returns a :class:`Lighting` with a ``(height, 2 height, 3)`` panorama (sky evaluated at
    256x128 and upsampled; the sun one pixel with the disk's energy).
    """
    import drjit as dr

    mi = mitsuba()
    sun = np.asarray(sun, float) / np.linalg.norm(sun)
    if -sun[1] <= 0.0:
        raise InputError("sunsky: the sun must be above the horizon (y < 0 in the scene frame)")
    sun_mi = (A_SKY @ sun).tolist()
    props = {"type": "sunsky", "sun_direction": sun_mi, "turbidity": float(turbidity), "sun_aperture": sun_aperture_deg}
    sky = mi.load_dict({**props, "sun_scale": 0.0})
    sun_only = mi.load_dict({**props, "sky_scale": 0.0})
    hs = int(min(128, max(16, height // 4)))  # the sky is smooth; small grids keep scalar variants fast
    dirs = (direction_grid(hs) @ A_SKY.T).reshape(-1, 3)

    def evaluate(em: Any, d: np.ndarray) -> np.ndarray:
        if is_vectorized():
            si = dr.zeros(mi.SurfaceInteraction3f, len(d))
            si.wi = mi.Vector3f(-d[:, 0], -d[:, 1], -d[:, 2])
            a = np.array(em.eval(si))
            return a.T if a.shape == (3, len(d)) and len(d) != 3 else a.reshape(len(d), 3)
        out = np.empty((len(d), 3))
        for i, v in enumerate(d):
            si = dr.zeros(mi.SurfaceInteraction3f)
            si.wi = mi.Vector3f(-v[0], -v[1], -v[2])
            out[i] = np.array(em.eval(si))
        return out

    sky_px = np.clip(evaluate(sky, dirs).reshape(hs, 2 * hs, 3), 0.0, None).astype(np.float32)
    pano = cv2.resize(sky_px, (2 * height, height), interpolation=cv2.INTER_LINEAR)
    l_sun = evaluate(sun_only, np.asarray([sun_mi]))[0]
    omega_sun = 2 * math.pi * (1 - math.cos(math.radians(sun_aperture_deg) / 2))
    x, y = coords_from_direction(sun, height)
    u, v = int(x) % (2 * height), min(int(y), height - 1)
    pano[v, u] += (l_sun * omega_sun / solid_angle(height)[v, u]).astype(np.float32)
    scale = 1.0
    if normalise:
        pano, scale = _normalise(pano, rng or np.random.default_rng(0))
    az, el = angles_from_direction(sun)
    meta = {
        "kind": "sunsky",
        "turbidity": float(turbidity),
        "sun_azimuth_deg": math.degrees(az),
        "sun_elevation_deg": math.degrees(el),
        "sun_aperture_deg": sun_aperture_deg,
        "scale": scale,
    }
    return Lighting(pano, np.eye(3), sun, meta)


def hdr(
    path: str | Path, rotation_deg: float = 0.0, *, rng: np.random.Generator | None = None, normalise: bool = True
) -> Lighting:
    """A real HDR panorama turned about the vertical by ``rotation_deg`` (moves the sun to the right)."""
    pano = read_panorama(path)
    scale = 1.0
    if normalise:
        pano, scale = _normalise(pano, rng or np.random.default_rng(0))
    R = rotation_y(math.radians(rotation_deg))
    sun = find_sun(pano)
    sun = None if sun is None else R @ sun
    meta = {"kind": "hdr", "file": Path(path).name, "rotation_deg": float(rotation_deg), "scale": scale}
    if sun is not None:
        az, el = angles_from_direction(sun)
        meta.update(sun_azimuth_deg=math.degrees(az), sun_elevation_deg=math.degrees(el))
    return Lighting(pano, np.asarray(R), sun, meta)


def random_lighting(
    rng: np.random.Generator,
    *,
    p_sunsky: float = 0.5,
    height: int = 512,
    hdr_dir: Path = HDR_DIR,
    exclude: tuple[str, ...] = (),
    files: Sequence[Path] | None = None,
) -> Lighting:
    """Draw a lighting: sunsky (elevation 5-75°, any azimuth, turbidity 2-6) or an HDR map turned by 0-60°.

    ``exclude``: HDR map names (stems) not to draw, e.g. those held out for a real test. ``files``: the HDR
    maps (EXR or Radiance HDR) to draw from instead of ``hdr_dir``'s EXRs (``exclude`` still applies).
    """
    pool = sorted(Path(hdr_dir).glob("*.exr")) if files is None else list(files)
    files = [f for f in pool if f.stem not in set(exclude)]
    if rng.random() < p_sunsky or not files:
        az = rng.uniform(-math.pi, math.pi)
        el = math.radians(rng.uniform(5.0, 75.0))
        sun = np.asarray(direction_from_angles(np.float64(az), np.float64(el)))
        turbidity = float(rng.uniform(2.0, 6.0))
        if _has_sunsky() or not files:
            return sunsky(sun, turbidity, height=height, rng=rng)
    return hdr(files[int(rng.integers(len(files)))], float(rng.uniform(0.0, 60.0)), rng=rng)


def _has_sunsky() -> bool:
    """Whether the installed Mitsuba has the ``sunsky`` emitter (3.6 and later)."""
    return _has_sunsky_in(variant())


@functools.cache
def _has_sunsky_in(name: str) -> bool:
    try:
        mitsuba().load_dict({"type": "sunsky"})
    except Exception:  # older Mitsuba: unknown plugin
        return False
    return True
