"""The paper's "best view per 60° sector" (paper §3.1 and supplementary §2).

The candidate cameras and the rejection rules are described in :mod:`solidkit.synth.cameras`;
each candidate is judged on an item buffer rendered at low resolution (:func:`solidkit.synth.render.render_buffers`).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from solidkit.synth.cameras import Camera, sample_candidate
from solidkit.synth.render import render_buffers
from solidkit.synth.scene import CityBlock

__all__ = ["best_views"]


def best_views(
    block: CityBlock,
    scene: Any,
    rng: np.random.Generator,
    K: np.ndarray,
    width: int,
    height: int,
    *,
    candidates: int = 16,
    min_categories: int = 3,
    max_object_share: float = 0.35,
    min_sky: float = 0.05,
    item_size: tuple[int, int] = (64, 48),
    sectors: tuple[int, ...] = (0, 1, 2, 3, 4, 5),
) -> list[tuple[Camera, dict[str, Any]]]:
    """The best camera of each sector and its selection stats (coverage, categories, tries).

    When no candidate of a sector qualifies, the one with the most categories (less its largest
    object share) is kept and ``stats["accepted"]`` is False.
    """
    out = []
    for s in sectors:
        best: tuple[tuple[bool, float, int], Camera, dict[str, Any]] | None = None
        for _ in range(candidates):
            cam = sample_candidate(block, rng, s, K, width, height)
            buf = render_buffers(scene, cam.scaled(*item_size), spp=1, shadows=False)
            cats = block.category_of(buf["label"])
            hit = cats >= 0
            counts = np.bincount(cats[hit].ravel(), minlength=1)
            ncat = int(np.sum(counts >= 0.01 * cats.size))
            cov = float(hit.mean())
            groups = block.group_of(buf["label"])
            largest = float(np.bincount(groups[hit].ravel()).max() / cats.size) if hit.any() else 0.0
            ok = ncat >= min_categories and largest <= max_object_share and 1.0 - cov >= min_sky
            key = (ok, cov if ok else float(ncat) - largest, ncat)
            if best is None or key > best[0]:
                best = (
                    key,
                    cam,
                    {"coverage": cov, "categories": ncat, "largest_object_share": largest, "accepted": ok},
                )
        assert best is not None
        best[2]["candidates"] = candidates
        out.append((best[1], best[2]))
    return out
