"""Image circles of a dual-fisheye frame: where the two lenses image, found without a lens profile.

A fisheye whose field exceeds its sensor's short side images a bright disc on a black surround.
:func:`find_image_circles` finds both discs of a dual-fisheye frame from the frame alone:

1. the arrangement: side by side when the frame is wider than high, stacked otherwise (every
   dual-fisheye layout puts one circle in each half of the long side);
2. per half, a first guess: the frame is reduced to ~512 px on its long side, the black level is
   the 2nd percentile of luminance and a pixel is *image* above ``black + 0.03 (p99 - black)``;
   the convex hull of the connected components larger than 0.2 % of the half (dark content inside
   the circle is a hole, not an edge; specks of noise are left out) gives the minimum enclosing circle;
3. :func:`fit_image_circle` refines it at full resolution: sub-pixel edge points along rays where
   the luminance falls below a fraction of the ray's inner level, and a circle fitted to them by
   least squares with outlier trimming.

A frame without two such discs (an equirect panorama, a photo, a black frame) raises
:class:`CircleError` with what was seen.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import asdict, dataclass

import cv2
import numpy as np

from solidkit.envmap.perspective import scale_pixel_coordinates
from solidkit.envmap.resample import sample_image
from solidkit.errors import InputError

__all__ = ["Circle", "CircleError", "fit_image_circle", "find_image_circles", "arrangement_of_centres"]


class CircleError(InputError):
    """The frame does not show two fisheye image circles."""


@dataclass(frozen=True)
class Circle:
    """One image circle: centre ``(cx, cy)`` and radius ``r`` (px, pixel centres at integers,
    conventions §1) and the fraction of rays whose edge point was kept (``inliers``)."""

    cx: float
    cy: float
    r: float
    inliers: float

    def to_json(self) -> dict[str, float]:
        return {k: round(v, 3) for k, v in asdict(self).items()}


def fit_image_circle(
    lum: np.ndarray,
    center: tuple[float, float],
    radius: float,
    *,
    n_rays: int = 720,
    search: float = 0.12,
    rel_threshold: float = 0.1,
) -> tuple[float, float, float, float]:
    """Centre and radius of a fisheye's image circle (the edge between image and the dark outside).

    Along ``n_rays`` rays from ``center``, the outermost radius within ``radius (1 ± search)``
    where the luminance exceeds ``rel_threshold`` times the ray's median just inside is an edge
    point; a circle is fitted to the edge points by linear least squares (Kasa), trimming points
    beyond 3 MADs (rays where dark content reaches the edge, the frame border, lens glints) for
    10 rounds. Returns ``(cx, cy, r, inlier_fraction)``; NaNs when fewer than 20 rays found an edge.
    """
    h, w = lum.shape[:2]
    ang = np.linspace(0, 2 * np.pi, n_rays, endpoint=False)
    rs = np.arange(radius * (1 - search), radius * (1 + search), 0.25)
    X = center[0] + np.cos(ang)[:, None] * rs
    Y = center[1] + np.sin(ang)[:, None] * rs
    prof = sample_image(np.nan_to_num(lum.astype(np.float32)), X.ravel(), Y.ravel(), border_value=np.nan).reshape(
        X.shape
    )
    with warnings.catch_warnings():  # rays that leave the frame at once are all-NaN: skipped below
        warnings.simplefilter("ignore", RuntimeWarning)
        inner = np.nanmedian(prof[:, : max(2, len(rs) // 6)], axis=1)
    pts = []
    for i in range(n_rays):
        row = prof[i]
        above = np.nonzero(np.isfinite(row) & (row > rel_threshold * inner[i]))[0]
        if inner[i] <= 0 or not above.size or above[-1] >= len(rs) - 1:
            continue
        j = above[-1]  # sub-pixel: linear crossing between j and j + 1
        t = rel_threshold * inner[i]
        frac = (row[j] - t) / max(row[j] - row[j + 1], 1e-12) if np.isfinite(row[j + 1]) else 0.0
        x, y = X[i, j] + frac * (X[i, j + 1] - X[i, j]), Y[i, j] + frac * (Y[i, j + 1] - Y[i, j])
        if 1 <= x <= w - 2 and 1 <= y <= h - 2:
            pts.append((x, y))
    if len(pts) < 20:
        return math.nan, math.nan, math.nan, 0.0
    c = np.asarray(pts)
    keep = np.ones(len(c), bool)
    for _ in range(10):
        A = np.column_stack([2 * c[keep, 0], 2 * c[keep, 1], np.ones(keep.sum())])
        sol = np.linalg.lstsq(A, (c[keep] ** 2).sum(1), rcond=None)[0]
        r = math.sqrt(max(sol[2] + sol[0] ** 2 + sol[1] ** 2, 0.0))
        res = np.hypot(c[:, 0] - sol[0], c[:, 1] - sol[1]) - r
        mad = float(np.median(np.abs(res[keep]))) if keep.any() else 0.0
        new = np.abs(res) <= max(0.5, 3 * 1.4826 * mad)
        if new.sum() < 20 or np.array_equal(new, keep):
            break
        keep = new
    return float(sol[0]), float(sol[1]), r, float(keep.mean() * len(c) / n_rays)


def arrangement_of_centres(centres: list[tuple[float, float]]) -> str:
    """``"side_by_side"`` when two centres differ more in x than in y, else ``"stacked"``."""
    (x0, y0), (x1, y1) = centres[:2]
    return "side_by_side" if abs(x1 - x0) >= abs(y1 - y0) else "stacked"


def _first_guess(lum_small: np.ndarray, scale: float, offset: tuple[int, int]) -> tuple[float, float, float] | None:
    lo = float(np.percentile(lum_small, 2))
    hi = float(np.percentile(lum_small, 99))
    if not hi > lo + 1e-4:
        return None
    mask: np.ndarray = (lum_small > lo + 0.03 * (hi - lo)).astype(np.uint8)
    mask = cv2.morphologyEx(mask, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    n, labels, stats, _ = cv2.connectedComponentsWithStats(mask, connectivity=8)
    if n < 2:
        return None
    big = 1 + np.nonzero(stats[1:, cv2.CC_STAT_AREA] >= 0.002 * mask.size)[0]  # the disc's pieces, not specks
    if not big.size:
        return None
    ys, xs = np.nonzero(np.isin(labels, big))
    pts = np.stack([xs, ys], axis=1).astype(np.float32)
    hull = cv2.convexHull(pts)
    (cx, cy), r = cv2.minEnclosingCircle(hull)
    fill = float(stats[big, cv2.CC_STAT_AREA].sum()) / max(math.pi * r * r, 1.0)
    if r < 8 or fill < 0.3:  # a scatter of bright bits, not a disc
        return None
    return scale_pixel_coordinates(cx, scale) + offset[0], scale_pixel_coordinates(cy, scale) + offset[1], r * scale


def find_image_circles(lum: np.ndarray, *, min_radius_frac: float = 0.25) -> tuple[list[Circle], str]:
    """Both image circles of a dual-fisheye frame, and the arrangement (module docstring).

    Parameters
    ----------
    lum : (H, W) float array
        Linear luminance of the frame (NaN allowed: treated as black).
    min_radius_frac : float
        A circle smaller than this fraction of the frame's short side is not a fisheye's.

    Returns
    -------
    circles : list of two :class:`Circle`
        Left then right (side by side), top then bottom (stacked), at full resolution.
    arrangement : str
        ``"side_by_side"`` or ``"stacked"``.

    Raises
    ------
    CircleError
        When either half shows no disc with a clean edge.
    """
    lum = np.nan_to_num(np.asarray(lum, np.float32))
    H, W = lum.shape[:2]
    arrangement = "side_by_side" if W >= H else "stacked"
    s = max(1.0, max(H, W) / 512.0)
    small = cv2.resize(lum, (max(8, round(W / s)), max(8, round(H / s))), interpolation=cv2.INTER_AREA)
    sh, sw = small.shape
    sx, sy = W / sw, H / sh
    halves = (
        [(slice(None), slice(0, sw // 2)), (slice(None), slice(sw // 2, sw))]
        if arrangement == "side_by_side"
        else [(slice(0, sh // 2), slice(None)), (slice(sh // 2, sh), slice(None))]
    )
    circles = []
    for k, (rows, cols) in enumerate(halves):
        part = small[rows, cols]
        off = ((cols.start or 0) * sx, (rows.start or 0) * sy)
        guess = _first_guess(part, sx, (int(round(off[0])), int(round(off[1]))))
        which = ("left", "right") if arrangement == "side_by_side" else ("top", "bottom")
        if guess is None:
            raise CircleError(
                f"no fisheye image circle in the {which[k]} half of the {W}x{H} frame "
                "(expected a bright disc on a black surround: is this a dual-fisheye frame?)"
            )
        cx, cy, r = guess
        if r < min_radius_frac * min(H, W):
            raise CircleError(
                f"the {which[k]} half of the {W}x{H} frame shows no fisheye image circle "
                f"(largest bright region {2 * r:.0f} px across): not a dual-fisheye frame?"
            )
        fx, fy, fr, inl = fit_image_circle(lum, (cx, cy), r, search=0.15, rel_threshold=0.25)
        if not (math.isfinite(fr) and inl >= 0.3):
            raise CircleError(
                f"the {which[k]} half of the {W}x{H} frame has no circular image edge "
                f"(edge found on {100 * inl:.0f} % of the rays): not a dual-fisheye frame?"
            )
        circles.append(Circle(fx, fy, fr, inl))
    return circles, arrangement
