"""Colour-histogram filtering of renderings against real photographs (paper §3.2).

The paper keeps a rendering when the largest *histogram intersection* (sum over bins of the
minimum of two normalised colour histograms) with any of 1100 real street-view images exceeds
0.7. Here the histogram is a joint RGB histogram of the 8-bit sRGB image with ``bins`` levels
per channel (default 8, i.e. 512 bins), normalised to sum 1; the reference set is whatever
real LDR photographs are at hand (``--reference DIR``), and the threshold is configurable.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from solidkit.envmap.io import LDR_SUFFIXES, read_ldr
from solidkit.errors import InputError

__all__ = ["colour_histogram", "histogram_intersection", "ReferenceSet"]


def colour_histogram(image: np.ndarray, bins: int = 8) -> np.ndarray:
    """Normalised joint RGB histogram ``(bins**3,)`` of an sRGB image in [0, 1] ``(H, W, 3)`` (or uint8)."""
    img = np.asarray(image)
    if img.ndim != 3 or img.shape[2] < 3:
        raise InputError(f"colour_histogram: expected an (H, W, 3) image, got {img.shape}")
    q = img[..., :3].astype(np.float64) / (255.0 if img.dtype == np.uint8 else 1.0)
    idx = np.clip((q * bins).astype(np.int64), 0, bins - 1)
    flat = (idx[..., 0] * bins + idx[..., 1]) * bins + idx[..., 2]
    h = np.bincount(flat.ravel(), minlength=bins**3).astype(np.float64)
    return h / max(h.sum(), 1.0)


def histogram_intersection(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``sum_k min(a_k, b_k)`` over the last axis (broadcasting); 1 for identical normalised histograms."""
    return np.minimum(a, b).sum(axis=-1)


class ReferenceSet:
    """Histograms of real LDR photographs; :meth:`score` is the paper's colour similarity score."""

    def __init__(self, histograms: np.ndarray, names: list[str], bins: int = 8) -> None:
        self.histograms = np.asarray(histograms, dtype=np.float64)
        self.names = names
        self.bins = bins

    @classmethod
    def from_dir(cls, folder: str | os.PathLike, bins: int = 8, max_side: int = 640) -> ReferenceSet:
        """All LDR images under ``folder`` (recursively), downscaled to at most ``max_side`` pixels."""
        import cv2

        folder = Path(folder)
        files = sorted(p for p in folder.rglob("*") if p.suffix.lower() in LDR_SUFFIXES)
        if not files:
            raise InputError(f"{folder}: no LDR reference images found")
        hists = []
        for p in files:
            img = read_ldr(p)
            s = max_side / max(img.shape[:2])
            if s < 1:
                img = cv2.resize(img, (int(img.shape[1] * s), int(img.shape[0] * s)), interpolation=cv2.INTER_AREA)
            hists.append(colour_histogram(img, bins))
        return cls(np.stack(hists), [str(p.relative_to(folder)) for p in files], bins)

    def score(self, image: np.ndarray) -> float:
        """Largest histogram intersection of ``image`` (sRGB, [0, 1]) with the reference images."""
        return float(histogram_intersection(colour_histogram(image, self.bins)[None, :], self.histograms).max())
