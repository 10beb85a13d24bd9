"""Which way is up in a dual-fisheye frame: the layout's roll (0 or ±90°) from the scene itself.

Cameras store their image circles upright (content up = image up) or turned by ±90° (the sensor
lies across the body: Ricoh's own dual-fisheye files and live/video frames, phone screenshots of a
live view), and a profile for one layout unwarps the other into a sideways panorama. The overlap
cannot tell: a roll of the whole camera about its front axis keeps both lenses' views consistent.
The scene can, through three cues, each scored for the rolls 0, +90° and -90° of the panorama
(``p0``: as it is, ``p90``: turned by 90° about the forward axis +z):

- **vertical edges** (walls, poles, doors, trees): in an upright panorama they lie on great circles
  through the zenith. OpenCV's LSD segments (von Gioi et al. 2012) within 60° of the horizon whose
  great circle passes within 2° of the frame's zenith are binned by that circle's azimuth (6° bins);
  the count of well-filled bins, plus the length of segments on the horizon itself (a sea or field
  horizon), is ``e0`` for ``p0`` and ``e90`` for ``p90``; score ``±log((e0 + 1) / (e90 + 1))``;
- **the bright half** (sky, ceiling lights): mean log luminance of the upper minus the lower
  hemisphere (``ud``), weight 2;
- **where the brightest light is**: the mean direction of the brightest 10 % of the panorama
  (sky, sun, lamps) projected on each roll's up direction, weight 2;
- **the busy half**: median gradient magnitude of the lower 40 % of rows minus the upper 40 %
  (ground, floor and furniture are busier than sky and ceilings).

The roll with the highest sum wins; it is *confident* when it leads the next by
:data:`CONFIDENT_MARGIN` (``capture unwarp`` warns only then). Measured (benchmarks/results/selfcal.md,
each panorama as it is and turned by ±90°): 11 of 12 right on the real
HDR panoramas city, courtyard, sunrise (8-bit, tonemapped) and the real Theta S kitchen, none wrong
*and* confident (sunrise turned by +90°: wrong, margin 0.13, no warning); courtyard (a covered yard:
bright floor, dark busy roof) is right but not confident. Through the lenses in ``calibrate
fisheye`` (clipped sky kept bright): 7 of 7 layouts right on the rendered families. An upside-down
camera is not told apart (not a candidate).

The result is the roll ``rho`` (degrees, about the camera's front axis +z) by which the camera
frame of the profile must turn so that the panorama is upright: unwarping with every lens rotation
replaced by ``R_z(rho) R_lens`` gives an upright panorama.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass

import cv2
import numpy as np

from solidkit.envmap.coords import direction_from_coords, direction_grid, rotation_z
from solidkit.envmap.resample import rotate

#: The chosen roll's score must lead the next by this much for a confident answer.
CONFIDENT_MARGIN = 0.5
#: Weights of the cues (edges, bright half, brightest light, busy half) in the score.
WEIGHTS = (0.5, 1.0, 2.0, 1.0)
BRIGHT_FRACTION = 0.1

__all__ = [
    "CONFIDENT_MARGIN",
    "UprightEstimate",
    "estimate_upright",
    "upright_of_panorama",
    "upright_from_panoramas",
    "panorama_from_lenses",
]


@dataclass(frozen=True)
class UprightEstimate:
    """``roll_deg`` in {0, 90, -90}; ``vertical_edges`` the edge evidence ``(e0, e90)``;
    ``up_down_log`` upper minus lower hemisphere mean log luminance at the chosen roll; ``cue``
    ``"edges"`` when the edge score alone outweighs the brightness cues twice, else
    ``"edges+brightness"``; ``confident`` and ``margin``: the lead over the next roll (module docstring)."""

    roll_deg: float
    vertical_edges: tuple[float, float]
    up_down_log: float
    cue: str
    confident: bool
    margin: float = 0.0

    def to_json(self) -> dict:
        d = asdict(self)
        d["vertical_edges"] = [round(v, 1) for v in self.vertical_edges]
        d["up_down_log"] = round(self.up_down_log, 3)
        d["margin"] = round(self.margin, 3)
        return d


def panorama_from_lenses(
    sample: Callable[[np.ndarray], np.ndarray], height: int = 128, roll_deg: float = 0.0
) -> np.ndarray:
    """``(height, 2 height)`` panorama of ``sample(d_cam (N, 3)) -> (N,)`` with the camera rolled by ``roll_deg``."""
    d = direction_grid(height).reshape(-1, 3)
    R = np.asarray(rotation_z(math.radians(roll_deg)), np.float64)
    return np.asarray(sample(d @ R), np.float32).reshape(height, 2 * height)  # d_cam = R^T d


def _vertical_edge_length(
    pano: np.ndarray, max_offset_deg: float = 2.0, max_elevation_deg: float = 60.0, bin_deg: float = 6.0
) -> float:
    """Evidence for a vertical vanishing point at the frame's zenith: LSD segments whose great circle
    passes within ``max_offset_deg`` of the zenith, counted by the azimuth of that great circle
    (``bin_deg`` bins over 180°): the number of bins holding a tenth of the image height of
    segments. A horizon (one great circle) then counts once or twice; walls, poles and trees at
    many azimuths count many times. Segments on the frame's horizon (great circle normal within
    ``max_offset_deg`` of the zenith: a sea or field horizon, level in an upright frame) add their
    length in the same units, up to 4."""
    x = np.nan_to_num(pano, nan=float(np.nanmin(pano)) if np.isfinite(pano).any() else 0.0)
    lo, hi = np.percentile(x, [1, 99])
    gray = (np.clip((x - lo) / max(hi - lo, 1e-6), 0, 1) * 255 + 0.5).astype(np.uint8)
    lines = cv2.createLineSegmentDetector(cv2.LSD_REFINE_STD).detect(gray)[0]
    if lines is None:
        return 0.0
    x1, y1, x2, y2 = lines.reshape(-1, 4).astype(np.float64).T
    h = pano.shape[0]
    lim = h / 2 * (1 - max_elevation_deg / 90.0)
    length = np.hypot(x2 - x1, y2 - y1)
    keep = (np.minimum(y1, y2) >= lim) & (np.maximum(y1, y2) <= h - lim) & (length >= max(4.0, h / 32))
    d1 = np.asarray(direction_from_coords(x1[keep], y1[keep], h), np.float64)
    d2 = np.asarray(direction_from_coords(x2[keep], y2[keep], h), np.float64)
    n = np.cross(d1, d2)
    norm = np.linalg.norm(n, axis=-1)
    ok = norm > 1e-9
    n, length = n[ok] / norm[ok, None], length[keep][ok]
    through_zenith = np.abs(n[:, 1]) < math.sin(math.radians(max_offset_deg))
    az = np.degrees(np.arctan2(n[through_zenith, 0], n[through_zenith, 2])) % 180.0
    bins = np.bincount((az // bin_deg).astype(int), weights=length[through_zenith], minlength=int(180 / bin_deg))
    on_horizon = length[np.abs(n[:, 1]) > math.cos(math.radians(max_offset_deg))].sum()
    return float(np.count_nonzero(bins >= h / 10.0)) + min(float(on_horizon) / (h / 10.0), 4.0)


def _up_minus_down(pano: np.ndarray) -> float:
    h = pano.shape[0]
    w = np.cos((np.arange(h) + 0.5) / h * math.pi - math.pi / 2)[:, None] * np.ones((1, 2 * h))  # solid angle per row
    ok = np.isfinite(pano)
    up, down = slice(0, h // 2), slice(h - h // 2, h)

    def mean(rows: slice) -> float:
        m = ok[rows]
        return float((np.where(m, pano[rows], 0) * w[rows]).sum() / max((w[rows] * m).sum(), 1e-9))

    return mean(up) - mean(down)


def estimate_upright(sample: Callable[[np.ndarray], np.ndarray], height: int = 256) -> UprightEstimate:
    """The roll that makes a dual-fisheye camera's panorama upright (module docstring).

    ``sample(d_cam (N, 3)) -> (N,)``: log luminance the camera sees in camera-frame directions
    (NaN where no lens sees), e.g. both lenses through a candidate profile.
    """
    return upright_from_panoramas(panorama_from_lenses(sample, height, 0.0), panorama_from_lenses(sample, height, 90.0))


def upright_of_panorama(pano: np.ndarray, height: int = 256) -> UprightEstimate:
    """:func:`estimate_upright` of an equirect panorama ``(H, 2H[, C])`` (uint8 sRGB or linear float):
    is it upright, or turned by ±90° about its forward axis (+z)?"""
    img = np.asarray(pano)
    k = img.shape[0] // (2 * height)
    if k > 1:  # decimate first: the area reduction then reads 1/k² of the pixels
        img = img[::k, ::k]
    if img.shape[0] > height:
        img = cv2.resize(
            np.ascontiguousarray(img[..., :3] if img.ndim == 3 else img),
            (2 * height, height),
            interpolation=cv2.INTER_AREA,
        )
    x = (img[..., :3].mean(axis=-1) if img.ndim == 3 else img).astype(np.float32)
    if img.dtype == np.uint8:
        x = (x / 255.0) ** 2.2  # close enough to linear for a log-luminance comparison
    pos = x[np.isfinite(x) & (x > 0)]
    eps = 0.01 * float(np.median(pos)) if pos.size else 1e-4
    p0 = np.log(np.maximum(x, 0.0) + max(eps, 1e-6)).astype(np.float32)
    p90 = np.asarray(rotate(p0, rotation_z(math.pi / 2)), np.float32)  # out(d) = in(R^T d)
    return upright_from_panoramas(p0, p90)


def _bright_direction(pano: np.ndarray, frac: float = BRIGHT_FRACTION) -> np.ndarray:
    """Mean direction (unit, panorama frame) of the brightest ``frac`` of the panorama's pixels (sky, sun, lamps)."""
    h = pano.shape[0]
    d = direction_grid(h)
    w = np.cos((np.arange(h) + 0.5) / h * math.pi - math.pi / 2)[:, None] * np.ones((1, 2 * h))
    ok = np.isfinite(pano)
    if not ok.any():
        return np.zeros(3)
    sel = ok & (pano >= np.quantile(pano[ok], 1 - frac))
    m = (d[sel] * w[sel][:, None]).sum(axis=0)
    n = float(np.linalg.norm(m))
    return m / n if n > 0 else m


def _texture_below_minus_above(pano: np.ndarray) -> float:
    """Median gradient magnitude of the lower 40 % of rows minus the upper 40 % (log luminance): ground
    and furniture are busier than sky and ceilings."""
    h = pano.shape[0]
    x = np.nan_to_num(pano, nan=float(np.nanmedian(pano)) if np.isfinite(pano).any() else 0.0).astype(np.float32)
    g = np.hypot(cv2.Sobel(x, cv2.CV_32F, 1, 0, ksize=3), cv2.Sobel(x, cv2.CV_32F, 0, 1, ksize=3))
    return float(np.median(g[int(0.6 * h) :]) - np.median(g[: int(0.4 * h)]))


def upright_from_panoramas(p0: np.ndarray, p90: np.ndarray) -> UprightEstimate:
    """The decision of :func:`estimate_upright` from the log-luminance panorama as it is (``p0``) and
    turned by 90° about the forward axis (``p90``): the roll with the highest sum of the three cues'
    scores (module docstring), confident when it leads the next by :data:`CONFIDENT_MARGIN`."""
    e0, e90 = _vertical_edge_length(p0), _vertical_edge_length(p90)
    ud0, ud90 = _up_minus_down(p0), _up_minus_down(p90)
    m = _bright_direction(p0)
    t0, t90 = _texture_below_minus_above(p0), _texture_below_minus_above(p90)
    edges = math.log((e0 + 1.0) / (e90 + 1.0))
    # up in p0's frame for the roll rho: R_z(rho)^T (0, -1, 0) = (0, -1, 0), (-1, 0, 0), (1, 0, 0)
    we, wu, wm, wt = WEIGHTS
    scores = {
        0.0: we * edges + wu * ud0 - wm * m[1] + wt * t0,
        90.0: -we * edges + wu * ud90 - wm * m[0] + wt * t90,
        -90.0: -we * edges - wu * ud90 + wm * m[0] - wt * t90,
    }
    ranked = sorted(scores, key=scores.__getitem__, reverse=True)
    roll = ranked[0]
    margin = scores[roll] - scores[ranked[1]]
    cue = "edges" if abs(edges) >= 2.0 * abs(scores[roll] - (edges if roll == 0.0 else -edges)) else "edges+brightness"
    ud = ud0 if roll == 0.0 else (ud90 if roll == 90.0 else -ud90)
    return UprightEstimate(roll, (e0, e90), float(ud), cue, bool(margin >= CONFIDENT_MARGIN), float(margin))
