"""Sun-position metrics: the sun of a predicted map and its errors against the truth.

Zhu et al., "Spatially-Varying Outdoor Lighting Estimation from Intrinsics", CVPR 2021, §5: sun
azimuth / elevation error from the predicted global map.

The sun of a predicted map is found with :func:`solidkit.envmap.sun.detect_sun`, never with a second
finder: ``"paper"`` is the paper's recipe taken literally (brightest 2 %, largest component, its
centroid) and, as in the paper, it always answers (``min_contrast=0``: only a black or constant map has
no sun); ``"core"`` is the package's default detector, which may say "no sun". A prediction without a
sun is never dropped silently: :func:`sun_statistics` reports the no-sun rate next to every error
statistic. Errors (:func:`direction_errors`): azimuth ``|wrap(phi_p - phi_t)|`` in [0°, 180°], elevation
``|theta_p - theta_t|``, and the angle between the two directions (conventions §3, §6).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from solidkit.envmap.coords import angles_from_direction, angular_distance, wrap_angle
from solidkit.envmap.sun import SunDetection, detect_sun

__all__ = ["SUN_METHODS", "SunError", "direction_errors", "find_sun", "sun_error", "sun_statistics"]

SUN_METHODS = ("paper", "core")
"""The sun recipes evaluated: the paper's (always answers) and the package's default detector."""


def find_sun(sky: np.ndarray, method: Literal["paper", "core"]) -> SunDetection:
    """The sun of a predicted global map ``(H, 2H, 3)`` linear radiance, by ``method``.

    ``"paper"`` runs :func:`~solidkit.envmap.sun.sun_paper` as the paper computes it: every map
    gets an answer (``min_contrast=0``). ``"core"`` runs the default detector unchanged.
    """
    if method == "paper":
        return detect_sun(sky, "paper", min_contrast=0.0)
    return detect_sun(sky, method)


def direction_errors(predicted: Any, truth: Any) -> tuple[Any, Any, Any]:
    """Angle, azimuth error and elevation error (radians) between directions ``(..., 3)``: NumPy or torch.

    ``angle`` is the great-circle distance (:func:`~solidkit.envmap.coords.angular_distance`), ``azimuth``
    ``|wrap(phi_p - phi_t)|`` in ``[0, pi]`` and ``elevation`` ``|theta_p - theta_t|`` (conventions §3); the
    directions need not be unit vectors. Every sun error of the package (training validation, the crop
    protocol, ``solidkit eval``) is this function.

    Examples
    --------
    >>> a, b = np.array([0.0, -1.0, 1.0]), np.array([-1.0, 0.0, 0.0])  # 45 deg up ahead; level, left
    >>> [round(math.degrees(float(e)), 6) for e in direction_errors(a, b)]
    [90.0, 90.0, 45.0]
    """
    (phi_p, theta_p), (phi_t, theta_t) = angles_from_direction(predicted), angles_from_direction(truth)
    return angular_distance(predicted, truth), abs(wrap_angle(phi_p - phi_t)), abs(theta_p - theta_t)


@dataclass(frozen=True)
class SunError:
    """Sun-position errors of one prediction, degrees (``None`` when the prediction has no sun)."""

    found: bool
    azimuth_deg: float | None = None
    elevation_deg: float | None = None
    angle_deg: float | None = None

    def to_json(self) -> dict[str, Any]:
        return {
            "found": self.found,
            "azimuth_deg": self.azimuth_deg,
            "elevation_deg": self.elevation_deg,
            "angle_deg": self.angle_deg,
        }


def sun_error(predicted: np.ndarray | None, truth: np.ndarray) -> SunError:
    """Errors between a predicted sun direction ``(3,)`` (or ``None``: no sun) and the true one ``(3,)``.

    Azimuth error: ``|phi_p - phi_t|`` wrapped to [0°, 180°]; elevation error: ``|theta_p - theta_t|``;
    angle: the great-circle distance. Directions are in the panorama frame (conventions §3).
    """
    if predicted is None:
        return SunError(found=False)
    p = np.asarray(predicted, dtype=np.float64)
    t = np.asarray(truth, dtype=np.float64)
    angle, azimuth, elevation = direction_errors(p / np.linalg.norm(p), t / np.linalg.norm(t))
    return SunError(True, math.degrees(float(azimuth)), math.degrees(float(elevation)), math.degrees(float(angle)))


def sun_statistics(errors: Sequence[SunError]) -> dict[str, Any]:
    """Counts, the no-sun rate and the median / mean of each error over the predictions with a sun."""
    n = len(errors)
    found = [e for e in errors if e.found]
    out: dict[str, Any] = {"n": n, "found": len(found), "no_sun_rate": (1 - len(found) / n) if n else None}
    for key in ("azimuth_deg", "elevation_deg", "angle_deg"):
        v = np.array([getattr(e, key) for e in found], dtype=np.float64)
        out[key] = {"median": float(np.median(v)) if v.size else None, "mean": float(v.mean()) if v.size else None}
    return out
