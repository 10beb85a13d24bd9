r"""Where the sun-direction error of a SOLID-Net checkpoint comes from: crops split by where the true sun is.

For crops (:mod:`solidkit.synth.panocrops`, exposed as the checkpoint's inputs were, as in
``train_figures.py``) of rendered sources with a visible sun, the sun head's azimuth / elevation errors
are split by

- ``where``: the true sun is in the image, beside it (within 100° of the view's azimuth) or behind the camera;
- ``occluded``: the sun is hidden at the camera position (the rendered scene's radiance within 2 pixels of the
  sun's direction is below 100, against ~10^4 for a visible sun; a measurement on the source, never a model input);
- ``saturated``: at least 1 % of the crop's pixels are clipped in some channel.

It also reports how often the predicted sun is on the correct side left / right and front / back (chance: 50 %),
and the coarse global logit map's own azimuth error (the pathway that can place a sun behind the camera).

    .venv/bin/python benchmarks/train_figures_where.py --checkpoint PT --sources DIR \
        [--crops 96] [--seed 99] [--out JSON]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np


def _az_err(a: float, b: float) -> float:
    d = abs(a - b) % (2 * math.pi)
    return math.degrees(min(d, 2 * math.pi - d))


def _pixel(d: np.ndarray, height: int) -> tuple[int, int]:
    from solidkit.envmap import coords_from_direction

    x, y = coords_from_direction(d, height)
    return int(np.clip(y, 0, height - 1)), int(x) % (2 * height)


def rows_for(model, sampler, indices, batch_size: int = 8) -> list[dict]:
    import torch

    from solidkit.envmap import angles_from_direction, rotate, rotation_y
    from solidkit.envmap.perspective import project_to_pixels
    from solidkit.model.sunhead import local_soft_argmax
    from solidkit.model.trainer import crop_batch
    from solidkit.model.warp import camera_rotation

    inet, rows = model.inet, []
    for s in range(0, len(indices), batch_size):
        items = [sampler(int(i)) for i in indices[s : s + batch_size]]
        b = crop_batch(items)
        with torch.no_grad():
            out = inet(b["image"], intrinsics=False, K=b["K"], pitch=b["pitch"], roll=b["roll"])
            pooled = torch.flatten(inet.light_pool(inet.light(inet.encoder(b["image"] * 2.0 - 1.0)[-1])), 1)
            h = inet.sun.coarse_height
            coarse = local_soft_argmax(inet.sun.coarse(inet.sun.mlp(pooled)).view(-1, 1, h, 2 * h))
        rot = camera_rotation(b["pitch"].double(), b["roll"].double()).numpy()
        for k, it in enumerate(items):
            if it["sun_visible"] < 0.5:
                continue
            t = it["sun_dir"].astype(np.float64)
            taz, tel = (float(v) for v in angles_from_direction(t))
            paz, pel = (float(v) for v in angles_from_direction(out["sun_dir"][k].double().numpy()))
            caz, _ = angles_from_direction(coarse[k].double().numpy())
            u, v, front = project_to_pixels(it["K"].astype(np.float64), (rot[k].T @ t)[None])
            inview = bool(front[0]) and 0 <= u[0] < it["image"].shape[1] and 0 <= v[0] < it["image"].shape[0]
            src = next(x for x in sampler.sources if x.name == it["source"])
            scene, light = src.load()
            turn = np.asarray(rotation_y(float(it["yaw"]))).T
            # the sampler's target is the light turned by -yaw, mirrored when the crop was flipped
            flipped = not np.allclose(np.asarray(rotate(light, turn)) * it["gain"], it["sky"], rtol=0.02, atol=1e-3)
            sc = np.asarray(rotate(scene, turn), dtype=np.float32)
            if flipped:
                sc = sc[:, ::-1]
            y, x = _pixel(t, sc.shape[0])
            near = sc[max(0, y - 2) : y + 3, np.arange(x - 2, x + 3) % sc.shape[1]].max()
            rows.append(
                {
                    "i": int(indices[s + k]),
                    "source": it["source"],
                    "where": "in_view" if inview else "beside" if abs(math.degrees(taz)) <= 100 else "behind",
                    "occluded": bool(near < 100.0),
                    "saturated": bool((it["image"].max(-1) >= 0.999).mean() >= 0.01),
                    "true_az": math.degrees(taz),
                    "pred_az": math.degrees(paz),
                    "az_err": _az_err(paz, taz),
                    "el_err": abs(math.degrees(pel - tel)),
                    "coarse_az_err": _az_err(float(caz), taz),
                }
            )
    return rows


def summarise(rows: list[dict]) -> dict:
    med = lambda v: [round(float(np.median(v)), 1), len(v)] if v else [None, 0]  # noqa: E731
    out = {
        "with_sun": len(rows),
        "azimuth_err_deg": med([r["az_err"] for r in rows]),
        "elevation_err_deg": med([r["el_err"] for r in rows]),
        "coarse_map_azimuth_err_deg": med([r["coarse_az_err"] for r in rows]),
        "same_left_right": sum((r["pred_az"] >= 0) == (r["true_az"] >= 0) for r in rows),
        "same_front_back": sum((abs(r["pred_az"]) < 90) == (abs(r["true_az"]) < 90) for r in rows),
    }
    for key, groups in (
        ("where", ("in_view", "beside", "behind")),
        ("occluded", (False, True)),
        ("saturated", (False, True)),
    ):
        out[f"azimuth_err_deg_by_{key}"] = {str(g): med([r["az_err"] for r in rows if r[key] == g]) for g in groups}
    out["azimuth_err_deg_by_where_visible"] = {
        w: med([r["az_err"] for r in rows if r["where"] == w and not r["occluded"]])
        for w in ("in_view", "beside", "behind")
    }
    return out


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--checkpoint", default=None)
    ap.add_argument("--sources", required=True, help="rendered sources with a known sun (solidkit synth sources)")
    ap.add_argument("--crops", type=int, default=96)
    ap.add_argument("--seed", type=int, default=99)
    ap.add_argument("--exposure", default="model", help="'model', 'fixed' or a key (as train_figures.py)")
    ap.add_argument("--out", default=None)
    a = ap.parse_args(argv)

    import torch

    from solidkit.model import SolidNet
    from solidkit.synth.panocrops import CropConfig, CropSampler, load_sources

    torch.set_num_threads(1)
    model = SolidNet.from_checkpoint(a.checkpoint).eval()
    key = model.config.exposure_key if a.exposure == "model" else 0.0 if a.exposure == "fixed" else float(a.exposure)
    sampler = CropSampler(
        load_sources(a.sources),
        seed=a.seed,
        config=CropConfig(exposure_stops=(0.0, 0.0), white_balance=0.0, exposure_key=key or None),
    )
    rows = rows_for(model, sampler, list(range(a.crops)))
    res = {
        "checkpoint": a.checkpoint or "shipped",
        "card_step": model.card.get("step"),
        "sources": a.sources,
        "crops": a.crops,
        "seed": a.seed,
        "exposure_key": key or None,
        **summarise(rows),
    }
    print(json.dumps(res, indent=1))
    if a.out:
        Path(a.out).write_text(json.dumps({**res, "rows": rows}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
