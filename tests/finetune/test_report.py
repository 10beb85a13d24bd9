"""The evaluation figures (solidkit.finetune.report), checked on the drawn figure: what is drawn, what it says."""

from __future__ import annotations

import numpy as np
import pytest

from solidkit.finetune.report import MIN_VIOLIN_POINTS, RECIPE_NAMES, cumulative_figure, violin_figure


def _result(n: int) -> dict:
    rng = np.random.default_rng(0)
    records = []
    for m in ("solidnet", "a rather long baseline name"):
        for _ in range(n):
            sun = {k: float(rng.uniform(0, 40)) for k in ("angle_deg", "azimuth_deg", "elevation_deg")}
            records.append({"method": m, "truth_sun": True, "sun_paper": sun, "sun_core": dict(sun)})
    return {"methods": [{"name": "solidnet"}, {"name": "a rather long baseline name"}], "records": records}


def _kinds(fig) -> list[str]:
    return [type(c).__name__ for ax in fig.axes for c in ax.collections]


@pytest.mark.parametrize("n", [4, MIN_VIOLIN_POINTS])
def test_violins_only_from_enough_values_and_the_caption_fits(n: int) -> None:
    """From 4 values the figure shows the values (points), not a violin; from MIN_VIOLIN_POINTS on, violins. The
    caption stays inside the figure and names the recipes as the legend of the cumulative curve does."""
    import matplotlib.pyplot as plt

    res = _result(n)
    methods = [m["name"] for m in res["methods"]]
    fig = violin_figure(res, methods, "real")
    kinds = _kinds(fig)
    if n < MIN_VIOLIN_POINTS:
        assert not any("Poly" in k for k in kinds) and kinds.count("PathCollection") == 8  # 2 axes, methods, recipes
    else:
        assert sum("Poly" in k for k in kinds) == 8 and "PathCollection" not in kinds
    fig.canvas.draw()
    box, frame = fig._suptitle.get_window_extent(), fig.bbox
    assert frame.x0 <= box.x0 and box.x1 <= frame.x1 and box.y1 <= frame.y1
    caption = fig._suptitle.get_text()
    plt.close(fig)
    fig = cumulative_figure(res, methods, "real")
    labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    plt.close(fig)
    for name in RECIPE_NAMES.values():
        assert name in caption and any(name in lab for lab in labels)
    assert not any("(core)" in lab or "(paper)" in lab for lab in labels)
