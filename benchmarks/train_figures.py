"""Accuracy figures of a SOLID-Net checkpoint against ground truth (the shipped one by default).

- Synthetic test split: crops (:mod:`solidkit.synth.panocrops`) of panoramas rendered with a seed the
  training never used (``--test-sources``, e.g. ``solidkit`` sources of seed 3000), ``--crops`` of them.
- Real: crops of the real HDR panoramas in ``../shared/data/real/hdr_panoramas`` (Hold-Geoffroy et al.'s
  protocol); each panorama is reported on its own and flagged ``held_out`` when the training excluded it
  (the shipped run excludes ``city`` everywhere, as lighting and as crops).
- Local probes: ``solidkit.finetune.evaluate`` (the evaluation's metrics) on a synthetic dataset with probes
  (``--synth``), the model against its own global map used as every probe.

Crops are exposed as the checkpoint's inputs were while training (``SolidNetConfig.exposure_key``: metered
to a log-average luminance key, or the fixed gain 1 of the first checkpoints); ``--exposure fixed|KEY`` overrides
that, to compare checkpoints on the same images.

For each crop: the default detector (:func:`solidkit.envmap.detect_sun`, ``core``) on the predicted sky;
found rate over skies whose truth has a visible sun (the same detector on the target), median angular,
azimuth and elevation errors of the found ones, median predicted/true sun energy; plus the sun head's
own direction (always answers) for every sky with a true sun; suns found where the truth has none; and, for a
model with a visibility output, how often it says "sun" (probability >= its threshold) in skies with / without one;
and the sun head's median azimuth error split by where the true sun is: in the image, beside it (within 100°
of the view's azimuth) or behind the camera.

    .venv/bin/python benchmarks/train_figures.py --test-sources DIR [--checkpoint PT] [--crops 96]
        [--synth DIR] [--exposure model|fixed|KEY] [--out benchmarks/results/train_figures.json]
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
REAL = REPO.parent / "shared" / "data" / "real" / "hdr_panoramas"


def crop_metrics(model, sampler, indices, batch_size: int = 8) -> dict:
    import torch

    from solidkit.envmap import angles_from_direction, angular_distance, detect_sun
    from solidkit.envmap.perspective import project_to_pixels
    from solidkit.model.losses import sun_energy
    from solidkit.model.trainer import crop_batch
    from solidkit.model.warp import camera_rotation

    found, errs, daz, delv, ratios, head, n_sun, l1 = 0, [], [], [], [], [], 0, []
    head_az: dict[str, list[float]] = {"in_view": [], "beside": [], "behind": []}
    paper_az, paper_el, paper_found = [], [], 0
    true_el, true_az_from_forward = [], []  # for the constant-guess reference
    no_sun, false_found, vis_sun, vis_none = 0, 0, 0, 0
    for s in range(0, len(indices), batch_size):
        b = crop_batch([sampler(int(i)) for i in indices[s : s + batch_size]])
        with torch.no_grad():
            out = model.inet(b["image"], intrinsics=False, K=b["K"], pitch=b["pitch"], roll=b["roll"])
        rot = camera_rotation(b["pitch"].double(), b["roll"].double())
        l1.append(float((out["sky_log"] - torch.log1p(b["sky"])).abs().mean()))
        for i in range(b["image"].shape[0]):
            says_sun = (
                bool(out["sun_visible"][i] >= model.config.sun_visibility_threshold) if "sun_visible" in out else None
            )
            if b["sun_visible"][i] < 0.5:
                no_sun += 1
                vis_none += int(bool(says_sun))
                false_found += int(detect_sun(out["sky"][i].permute(1, 2, 0).numpy()).found)
                continue
            n_sun += 1
            vis_sun += int(bool(says_sun))
            t = b["sun_dir"][i].double().numpy()
            if "sun_dir" in out:
                head.append(math.degrees(float(angular_distance(out["sun_dir"][i].double().numpy(), t))))
                c = rot[i].numpy().T @ t  # the true sun in the camera frame
                u, v, front = project_to_pixels(b["K"][i].double().numpy(), c[None])
                w_img, h_img = b["image"].shape[-1], b["image"].shape[-2]
                hz, _ = angles_from_direction(out["sun_dir"][i].double().numpy())
                tz, _ = angles_from_direction(t)
                e = abs(float(hz) - float(tz)) % (2 * math.pi)
                where = (
                    "in_view"
                    if bool(front[0]) and 0 <= u[0] < w_img and 0 <= v[0] < h_img
                    else "beside"
                    if abs(math.degrees(float(tz))) <= 100
                    else "behind"
                )
                head_az[where].append(math.degrees(min(e, 2 * math.pi - e)))
            sky = out["sky"][i].permute(1, 2, 0).numpy()
            taz, tel = (float(a) for a in angles_from_direction(t))
            true_el.append(math.degrees(tel))
            true_az_from_forward.append(math.degrees(abs((taz + math.pi) % (2 * math.pi) - math.pi)))
            pap = detect_sun(sky, method="paper")  # the paper's recipe, for its azimuth / elevation metric
            if pap.found:
                paper_found += 1
                d = abs(pap.azimuth - taz) % (2 * math.pi)
                paper_az.append(math.degrees(min(d, 2 * math.pi - d)))
                paper_el.append(math.degrees(abs(pap.elevation - tel)))
            det = detect_sun(sky)
            if not det.found:
                continue
            found += 1
            errs.append(math.degrees(float(angular_distance(np.asarray(det.direction, dtype=np.float64), t))))
            d = abs(det.azimuth - taz) % (2 * math.pi)
            daz.append(math.degrees(min(d, 2 * math.pi - d)))
            delv.append(math.degrees(abs(det.elevation - tel)))
            pd = torch.as_tensor(det.direction, dtype=torch.float32)[None]
            ratios.append(
                float(
                    sun_energy(out["sky"][i : i + 1], pd).sum()
                    / sun_energy(b["sky"][i : i + 1], b["sun_dir"][i : i + 1]).sum().clamp_min(1e-9)
                )
            )
    med = lambda v: round(float(np.median(v)), 2) if v else None  # noqa: E731
    has_vis = "sun_visible" in out
    within2 = sum(0.5 <= r <= 2.0 for r in ratios)
    return {
        "crops": len(indices),
        "with_sun": n_sun,
        "found": found,
        "found_rate": round(found / n_sun, 3) if n_sun else None,
        "without_sun": no_sun,
        "sun_found_where_truth_has_none": false_found,
        "visibility_says_sun_with_sun": vis_sun if has_vis else None,
        "visibility_says_sun_without_sun": vis_none if has_vis else None,
        "median_angular_err_deg": med(errs),
        "median_azimuth_err_deg": med(daz),
        "median_elevation_err_deg": med(delv),
        "median_energy_ratio": med(ratios),
        "energy_within_2x": within2,
        "sun_head_median_err_deg": med(head),
        "paper_recipe_found": paper_found,
        "paper_recipe_median_azimuth_err_deg": med(paper_az),
        "paper_recipe_median_elevation_err_deg": med(paper_el),
        "sky_l1_log1p": round(float(np.mean(l1)), 4),
        "sun_head_median_azimuth_err_deg_by_where": {k: [med(v), len(v)] for k, v in head_az.items()},
        # reference: one constant answer for every crop (straight ahead, at the set's median true elevation)
        "constant_guess_median_azimuth_err_deg": med(true_az_from_forward),
        "constant_guess_median_elevation_err_deg": med([abs(e - np.median(true_el)) for e in true_el]),
    }


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--checkpoint", default=None)
    ap.add_argument("--test-sources", required=True, help="rendered test sources (solidkit synth sources)")
    ap.add_argument("--crops", type=int, default=96)
    ap.add_argument("--real-crops", type=int, default=48)
    ap.add_argument("--synth", default=None, help="synthetic dataset with probes for the local metrics")
    ap.add_argument("--held-out", nargs="*", default=["city"])
    ap.add_argument(
        "--exposure",
        default="model",
        help="crop exposure: 'model' (the checkpoint's exposure_key), 'fixed' (gain 1) or a key such as 0.18",
    )
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "results" / "train_figures.json"))
    a = ap.parse_args(argv)

    import torch

    from solidkit.model import SolidNet
    from solidkit.synth.panocrops import CropConfig, CropSampler, load_sources, real_source

    torch.set_num_threads(1)
    model = SolidNet.from_checkpoint(a.checkpoint)
    key = model.config.exposure_key if a.exposure == "model" else 0.0 if a.exposure == "fixed" else float(a.exposure)
    crop_cfg = CropConfig(exposure_stops=(0.0, 0.0), white_balance=0.0, exposure_key=key or None)
    res: dict = {
        "checkpoint": a.checkpoint or "shipped",
        "card_step": model.card.get("step"),
        "config": model.config.name,
        "exposure_key": key or None,
        "sun_visibility_threshold": model.config.sun_visibility_threshold,
    }
    t0 = time.time()
    if a.crops and a.test_sources and Path(a.test_sources).is_dir():
        srcs = load_sources(a.test_sources)
        sampler = CropSampler(srcs, seed=99, config=crop_cfg)
        res["synthetic_crops"] = {
            "sources": len(srcs),
            "dir": a.test_sources,
            **crop_metrics(model, sampler, list(range(a.crops))),
        }
        print("synthetic", res["synthetic_crops"], file=sys.stderr)
    if a.real_crops and REAL.is_dir():
        res["real_crops"] = {}
        for p in sorted(REAL.glob("*.exr")):
            sampler = CropSampler([real_source(p)], seed=98, config=crop_cfg)
            m = crop_metrics(model, sampler, list(range(a.real_crops)))
            res["real_crops"][p.stem] = {"held_out": p.stem in a.held_out, **m}
            print("real", p.stem, m, file=sys.stderr)
    if a.synth:
        from solidkit.finetune.evaluate import GlobalAsLocal, ModelMethod, evaluate, items_from_synth

        items = items_from_synth(a.synth)
        base = ModelMethod("solidnet", model)
        r = evaluate(items, [base, GlobalAsLocal(base)])
        keep = (
            "local_ssim",
            "local_ssim_tonemap",
            "local_mae_log1p",
            "local_mae",
            "global_mae",
            "angle_deg/core",
            "azimuth_deg/core",
            "elevation_deg/core",
            "no_sun_rate/core",
        )
        res["synthetic_local"] = {
            "dataset": a.synth,
            "items": len(items),
            "summary": {m: {k: v for k, v in s.items() if k in keep} for m, s in r["summary"].items()},
        }
        print("local", json.dumps(res["synthetic_local"])[:2000], file=sys.stderr)
    res["seconds"] = round(time.time() - t0, 1)
    Path(a.out).write_text(json.dumps(res, indent=1))
    print(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
