"""Where a photo shows open sky: a geometric + appearance mask for sanity checks of probe pixels.

A local probe is a Theta put on a surface seen in the photo, so its pixel never shows the sky.
The mask marks pixels that are (1) above the horizon, from K and the camera's pitch/roll
(conventions §1, §2, §4); (2) smooth (sky has no texture: the standard deviation of the luminance
in a 5x5 window below ``max_std``, measured at the photo's full resolution, where facades show
their bricks and joints); (3) not darker than ``min_brightness`` of the bright end of the
above-horizon pixels and not more red than blue by more than ``max_red_excess`` (clear sky is
blue, overcast sky grey; sunlit stone and brick are warm); and (4) connected to the top edge of the image through
such pixels (OpenCV connected components). It is conservative: facades that are smooth and bright but do not touch
the top through smooth bright pixels are not sky; a probe pixel is reported only when most of its
neighbourhood is sky (:func:`on_sky`).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from solidkit.envmap.coords import rotation_from_ypr
from solidkit.envmap.perspective import pixel_rays
from solidkit.envmap.sun import luminance

__all__ = ["sky_mask", "on_sky"]


def sky_mask(
    photo: np.ndarray,
    K: np.ndarray,
    pitch_deg: float = 0.0,
    roll_deg: float = 0.0,
    *,
    max_std: float = 0.025,
    min_brightness: float = 0.45,
    max_red_excess: float = 0.02,
) -> np.ndarray:
    """Boolean sky mask ``(H, W)`` of an sRGB photo ``(H, W, 3)`` (RGB, float in [0, 1] or uint8).

    Parameters
    ----------
    photo : ndarray (H, W, 3)
        The photo, RGB.
    K : array (3, 3)
        Its intrinsics (OpenCV pixel centres).
    pitch_deg, roll_deg : float
        The camera's orientation in its panorama frame, degrees (conventions §4).
    max_std : float
        Largest standard deviation of the luminance (sRGB-encoded, in [0, 1]) in the 5x5 window
        around a sky pixel.
    min_brightness : float
        A sky pixel's luminance is at least this fraction of the 95th percentile of the
        above-horizon luminance.
    max_red_excess : float
        A sky pixel has ``R - B <= max_red_excess`` (sRGB values in [0, 1]).
    """
    img = np.asarray(photo)
    img = img.astype(np.float32) / 255.0 if img.dtype == np.uint8 else img.astype(np.float32)
    h, w = img.shape[:2]
    R = np.asarray(rotation_from_ypr(0.0, math.radians(pitch_deg), math.radians(roll_deg)), dtype=np.float64)
    d = pixel_rays(K, w, h) @ R.T
    above = -d[..., 1] > 1e-9
    if not above.any():
        return np.zeros((h, w), bool)
    lum = luminance(img)
    mean = cv2.blur(lum, (5, 5))
    smooth = np.sqrt(np.maximum(cv2.blur(lum * lum, (5, 5)) - mean * mean, 0.0)) < max_std
    bright = lum >= min_brightness * float(np.percentile(lum[above], 95))
    colour = (img[..., 0] - img[..., 2]) <= max_red_excess
    cand = (above & smooth & bright & colour).astype(np.uint8)
    n, labels = cv2.connectedComponents(cand, connectivity=4)
    top = np.unique(labels[0][cand[0] > 0])
    mask = np.isin(labels, top[top > 0])
    # close pinholes (noise, a stray pixel over the gradient threshold) inside the sky
    mask = cv2.morphologyEx(mask.astype(np.uint8), cv2.MORPH_CLOSE, np.ones((5, 5), np.uint8)).astype(bool)
    return mask & above


def on_sky(mask: np.ndarray, x: float, y: float, radius: int = 2, share: float = 0.8) -> bool:
    """True when at least ``share`` of the ``(2 radius + 1)²`` pixels around ``(x, y)`` are sky."""
    h, w = mask.shape
    xi, yi = int(round(x)), int(round(y))
    win = mask[max(0, yi - radius) : min(h, yi + radius + 1), max(0, xi - radius) : min(w, xi + radius + 1)]
    return bool(win.size) and float(win.mean()) >= share
