"""Angular uncertainty of a predicted sun: cones from the sun network's distribution, calibrated.

The sun network's logits define a distribution over directions, ``p ∝ exp(logits) Omega``
(:func:`solidkit.model.losses.sun_direction_loss`). The radius around the predicted direction that holds
a fraction ``q`` of it (:func:`cone_radii`) ranks crops by how sure the network is, but its scale is
not a probability: the training target has a floor width, and the network is over- or under-confident
where it was not trained. Split conformal prediction (Vovk et al. 2005; Angelopoulos & Bates 2021, "A
gentle introduction to conformal prediction", §1) fixes the scale: on a calibration split, the factor
``s_q`` is the ``ceil((n + 1) q) / n`` empirical quantile of ``error / radius_q``, so on new crops
drawn like the calibration ones ``error <= s_q radius_q`` holds with probability at least ``q``
(:func:`calibrate_cone_scales`, :func:`cones_deg`). A sun put on an image blob
(:mod:`solidkit.model.imagesun`) gets cones of fixed width calibrated the same way on the errors of such
suns (:func:`conformal_quantile`).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from solidkit.envmap.coords import direction_grid
from solidkit.model.sunhead import log_solid_angle

__all__ = ["LEVELS", "cone_radii", "conformal_quantile", "calibrate_cone_scales", "cones_deg", "coverage"]

LEVELS = (0.68, 0.90)
"""The stated coverages of the two cones."""


def cone_radii(logits: torch.Tensor, direction: torch.Tensor, levels: tuple[float, ...] = LEVELS) -> torch.Tensor:
    """Radii (degrees) of the cones about ``direction (B, 3)`` holding each of ``levels`` of the
    distribution ``p ∝ exp(logits) Omega`` of ``logits (B, 1, H, 2H)``: ``(B, len(levels))``."""
    b, _, h, w = logits.shape
    p = torch.softmax((logits[:, 0].float() + log_solid_angle(h, logits.float())).reshape(b, -1), dim=1)
    grid = direction_grid(h, torch, dtype=torch.float32, device=logits.device).reshape(-1, 3)
    ang = torch.rad2deg(torch.arccos((direction.float() @ grid.T).clamp(-1.0, 1.0)))  # (B, HW)
    order = torch.argsort(ang, dim=1)
    cum = torch.cumsum(torch.gather(p, 1, order), dim=1)
    ang_sorted = torch.gather(ang, 1, order)
    out = []
    for q in levels:
        k = torch.searchsorted(cum.contiguous(), torch.full((b, 1), float(q), device=logits.device)).clamp(
            max=h * w - 1
        )
        out.append(torch.gather(ang_sorted, 1, k)[:, 0])
    # a cone is never narrower than one logit pixel's half-width
    return torch.stack(out, dim=1).clamp_min(90.0 / h)


def conformal_quantile(scores: np.ndarray, q: float, weights: np.ndarray | None = None) -> float:
    """The ``ceil((n + 1) q) / n`` empirical quantile of ``scores (n,)`` (split conformal prediction);
    ``inf`` when ``n`` is too small for ``q``.

    With ``weights (n,)`` (e.g. ``1 / n_d`` for a crop of domain ``d``, so that each domain counts equally), the
    weighted version (Tibshirani et al. 2019, "Conformal prediction under covariate shift", §2): the ``q``
    quantile of the scores' weighted distribution with a mass of the largest weight at ``+inf`` for the new
    crop; equal weights give the unweighted quantile.
    """
    s = np.asarray(scores, np.float64)
    if weights is None:
        s = np.sort(s)
        n = len(s)
        k = math.ceil((n + 1) * q)
        return float(s[k - 1]) if 0 < k <= n else math.inf
    w = np.asarray(weights, np.float64)
    if w.shape != s.shape or not np.all(np.isfinite(w)) or np.any(w <= 0):
        raise ValueError(f"weights must be positive and finite, one per score ({s.shape}), got {w.shape}")
    order = np.argsort(s, kind="stable")
    s, w = s[order], w[order]
    cum = np.cumsum(w) / (w.sum() + w.max())
    k = int(np.searchsorted(cum, q - 1e-12))
    return float(s[k]) if k < len(s) else math.inf


def calibrate_cone_scales(
    errors_deg: np.ndarray,
    radii_deg: np.ndarray,
    levels: tuple[float, ...] = LEVELS,
    weights: np.ndarray | None = None,
) -> tuple[float, ...]:
    """Factors ``s_q`` on :func:`cone_radii` so that ``error <= s_q radius_q`` covers ``q`` of calibration
    crops (``errors_deg (n,)``, ``radii_deg (n, len(levels))``, optional ``weights (n,)`` of
    :func:`conformal_quantile`), made non-decreasing across levels."""
    e, r = np.asarray(errors_deg, np.float64), np.asarray(radii_deg, np.float64)
    s = [conformal_quantile(e / r[:, k], q, weights) for k, q in enumerate(levels)]
    return tuple(float(v) for v in np.maximum.accumulate(s))


def cones_deg(radii_deg: torch.Tensor, scales: tuple[float, ...]) -> torch.Tensor:
    """Calibrated cones (degrees) ``(B, len(scales))`` from ``radii_deg (B, len(scales))``, capped at 180°."""
    return (radii_deg * torch.as_tensor(scales, dtype=radii_deg.dtype, device=radii_deg.device)).clamp(max=180.0)


def coverage(errors_deg: np.ndarray, cones: np.ndarray) -> list[float]:
    """Fraction of ``errors_deg (n,)`` inside each column of ``cones (n, k)`` (degrees)."""
    e, c = np.asarray(errors_deg, np.float64), np.asarray(cones, np.float64)
    return [float(np.mean(e <= c[:, k])) if len(e) else float("nan") for k in range(c.shape[1])]
