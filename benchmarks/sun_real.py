"""The sun of a checkpoint on the crop protocol (:mod:`solidkit.model.suneval`), real and synthetic, with baselines.

1. Calibration on validation crops (the ``val`` split of the real outdoor panoramas plus rendered validation
   sources): the visibility threshold, the conformal 68 % / 90 % cone scales, the in-image cones
   (:func:`solidkit.model.suneval.calibrate_sun`), with the in-image sun on.
2. Figures on test crops no training step saw: the ``test`` split of ``../shared/data/real/hdr_outdoor``,
   the held-out real ``city.exr`` and rendered test sources, for the calibrated model, the network alone,
   the constant and brightest-column baselines, and the ``--before`` checkpoint as it shipped.

    .venv/bin/python benchmarks/sun_real.py --checkpoint RUN/best_sun.pt --val-sources DIR --test-sources DIR
        [--before solidkit/model/checkpoints/solidnet_small.pt] [--export OUT.pt] [--out benchmarks/results/sun_real]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
REAL = REPO.parent / "shared" / "data" / "real"


def _fmt(v, nd: int = 1) -> str:
    if v is None:
        return "–"
    if isinstance(v, list):
        return " / ".join(_fmt(x, nd) for x in v)
    if isinstance(v, float):
        return f"{v:.{nd}f}"
    return str(v)


def table(name: str, figures: dict) -> str:
    head = [
        "method",
        "found",
        "median angular ° (found)",
        "az / el °",
        "in view ° (n; max)",
        "beside °",
        "behind °",
        "false suns",
        "68 / 90 % cone coverage",
        "cone median °",
    ]
    lines = [f"**{name}**", "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for m, f in figures.items():
        cov = [round(100 * c) for c in f["cone_coverage"]] if "cone_coverage" in f else None
        lines.append(
            "| "
            + " | ".join(
                [
                    m,
                    f"{f['found']}/{f['suns']}",
                    _fmt(f["angular_deg"]),
                    f"{_fmt(f['azimuth_deg'])} / {_fmt(f['elevation_deg'])}",
                    f"{_fmt(f['in_view_deg'])} ({f['in_view_n']}; {_fmt(f['in_view_max_deg'])})",
                    _fmt(f["beside_deg"]),
                    _fmt(f["behind_deg"]),
                    f"{f['false_suns']}/{f['sunless']}",
                    (" / ".join(f"{c} %" for c in cov) if cov else "–"),
                    _fmt(f.get("cone_median_deg")),
                ]
            )
            + " |"
        )
    return "\n".join(lines) + "\n"


def contact_sheet(crops, pred, path: Path, title: str) -> Path:
    """The sunny crops with the true sun (green circle) and the model's (red cross; its 68 % cone dashed) where
    they fall in the image, and the angular error; negatives with the model's answer."""
    import math

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from solidkit.envmap.coords import angular_distance, rotation_from_ypr
    from solidkit.envmap.perspective import project_to_pixels

    n = len(crops)
    cols = 6
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(2.2 * cols, 1.75 * rows + 0.4))
    for ax in axes.ravel():
        ax.axis("off")
    for k, (c, ax) in enumerate(zip(crops, axes.ravel())):
        ax.imshow(c.image)
        R = np.asarray(rotation_from_ypr(0.0, c.pitch, c.roll))
        h, w = c.image.shape[:2]
        for d, style in (
            (c.sun, dict(marker="o", mfc="none", mec="lime", ms=9, mew=1.5)) if c.visible else (None, None),
            (pred["direction"][k], dict(marker="x", color="red", ms=8, mew=1.5))
            if pred["says_sun"][k]
            else (None, None),
        ):
            if d is None:
                continue
            x, y, front = project_to_pixels(c.K.astype(np.float64), R.T @ np.asarray(d, np.float64))
            if front and 0 <= x < w and 0 <= y < h:
                ax.plot([x], [y], **style)
        if c.visible:
            err = math.degrees(
                float(angular_distance(np.asarray(pred["direction"][k], np.float64), c.sun.astype(np.float64)))
            )
            label = f"{c.relative_azimuth_deg:+.0f}°: " + (f"{err:.0f}° off" if pred["says_sun"][k] else "missed")
        else:
            label = "no sun: " + ("sun put" if pred["says_sun"][k] else "none put")
        ax.set_title(f"{c.name[:16]}\n{label}", fontsize=6.5)
    fig.suptitle(title, fontsize=9)
    fig.tight_layout(rect=(0, 0, 1, 0.985))
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--checkpoint", required=True)
    ap.add_argument("--before", default=str(REPO / "solidkit" / "model" / "checkpoints" / "solidnet_small.pt"))
    ap.add_argument("--val-sources", required=True, help="rendered validation sources (solidkit synth sources)")
    ap.add_argument("--test-sources", required=True, help="rendered test sources of a seed no training used")
    ap.add_argument("--export", help="write the calibrated checkpoint here")
    ap.add_argument("--out", default=str(REPO / "benchmarks" / "results" / "sun_real"))
    a = ap.parse_args()

    import torch

    from solidkit.model.solidnet import SolidNet
    from solidkit.model.suneval import calibrate_sun, evaluate_sun_crops, protocol_crops
    from solidkit.model.trainer import model_from_state
    from solidkit.synth.panocrops import load_sources

    torch.set_num_threads(1)
    t0 = time.time()
    outdoor = REAL / "hdr_outdoor"
    val = {
        "real": protocol_crops(load_sources(outdoor, split="val")),
        "synthetic": protocol_crops(load_sources(a.val_sources)),
    }
    tests = {
        "real: test split of hdr_outdoor": protocol_crops(load_sources(outdoor, split="test")),
        "real: city.exr (held out)": protocol_crops(
            [s for s in load_sources(REAL / "hdr_panoramas") if s.name == "city"]
        ),
        "synthetic: rendered test sources": protocol_crops(load_sources(a.test_sources)),
    }
    model = model_from_state(a.checkpoint)
    cal = calibrate_sun(model, val)
    model.reconfigure(
        sun_visibility_threshold=cal["threshold"],
        sun_cone_scale=cal["cone_scale"],
        sun_in_image=cal["sun_in_image"],
        sun_blob_gate_deg=cal["gate_deg"],
        sun_blob_visibility=cal["blob_visibility"],
    )
    before = SolidNet.from_checkpoint(a.before)
    res = {"checkpoint": a.checkpoint, "calibration": cal, "tests": {}}
    n = ", ".join(f"{d}: {v['crops']} crops, {v['suns']} with a sun" for d, v in cal["n"].items() if d != "found_suns")
    md = [
        "# The sun on crops with a known sun (protocol: solidkit.model.suneval)",
        "",
        f"Checkpoint `{Path(a.checkpoint).name}`; calibrated on validation crops ({n}): visibility threshold "
        f"{cal['threshold']:.2f} (balanced accuracy {cal['balanced_accuracy']:.3f}, mean over the two), in-image sun "
        f"{'on, gate ' + str(cal['gate_deg']) + '°' if cal['sun_in_image'] else 'off'}, a blob alone makes a sun "
        f"visible from p = {cal['blob_visibility']:.2f} (0: off; balanced accuracy "
        f"{cal['balanced_accuracy_with_blob']:.3f}), cone scales "
        f"{_fmt(list(cal['cone_scale']), 2)} ({cal['n']['found_suns']} found suns). Crops: pitch +5°, 60° hfov, the "
        "sun at relative azimuths 0, ±30, ±90, 150° (panoramas without a sun at the same yaws), metered exposure.",
        "",
    ]
    for name, crops in tests.items():
        figs = evaluate_sun_crops(model, crops)
        figs["before (shipped checkpoint)"] = evaluate_sun_crops(before, crops)["model"]
        res["tests"][name] = {"crops": len(crops), "figures": figs}
        if name.startswith("real: test"):
            from solidkit.model.suneval import predict_model

            sheet = contact_sheet(
                crops,
                predict_model(model, crops),
                Path(a.out + "_test_crops.png"),
                "real test crops: true sun (green), the model's (red), its error",
            )
            md.append(f"Contact sheet: `{sheet.name}`.\n")
        md.append(table(f"{name}: {len(crops)} crops", figs))
    res["seconds"] = round(time.time() - t0, 1)
    out = Path(a.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(".json").write_text(json.dumps(res, indent=1, default=float))
    out.with_suffix(".md").write_text("\n".join(md))
    print("\n".join(md))
    if a.export:
        from solidkit.model.solidnet import save_checkpoint

        save_checkpoint(model, a.export, {**getattr(model, "card", {}), "sun_calibration": cal}, half=True)
        print(f"wrote {a.export}")


if __name__ == "__main__":
    main()
