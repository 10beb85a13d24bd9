"""The global map of a checkpoint against the mean sky, and its sun under both recipes, with the aureole tuned.

"One sky": the sun a detector reads from the predicted global map must be the sun the model predicts, whichever
recipe reads it (the paper's largest top-2 % component or the default detector), and the map must beat the
mean sky of the other scenes on the paper's global MAE. This script

1. tunes ``sun_aureole`` (:func:`solidkit.model.sunhead.render_sun_with_aureole`) on validation crops (the
   ``val`` split of the real outdoor panoramas and rendered validation sources, each domain weighted equally):
   the fraction with the lowest mean of the two domains' median global MAE;
2. reports, on test crops no training step saw (the ``test`` split and rendered test sources) and on a real
   test set when given (e.g. the demo campaign's), the model before and after against the ``mean-sky`` and
   ``mean-probe`` baselines of :mod:`solidkit.finetune.evaluate`: global MAE, the angle between the two
   recipes' suns where both find one, the sun error under each recipe, and local SSIM / MAE.

    .venv/bin/python benchmarks/sky_maps.py --checkpoint CKPT --val-sources DIR --test-sources DIR
        [--before solidkit/model/checkpoints/solidnet_small.pt] [--testset demo_out/testset]
        [--export OUT.pt] [--out benchmarks/results/sky_maps]
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
REAL = REPO.parent / "shared" / "data" / "real" / "hdr_outdoor"
FRACTIONS = (0.0, 0.5, 0.8, 0.9)


def _split_paths(split: str) -> list[Path]:
    from solidkit.synth.panocrops import real_split

    names = {n for n, s in real_split().items() if s == split}
    return [p for p in sorted(REAL.iterdir()) if p.stem in names and p.suffix in (".hdr", ".exr")]


def _sources(folder: Path, limit: int | None) -> list[Path]:
    return sorted(folder.glob("*/scene.exr"))[:limit]


def datasets(args: argparse.Namespace, split: str) -> dict[str, list[Any]]:
    from solidkit.finetune.evaluate import items_from_panoramas, items_from_testset

    folder = args.val_sources if split == "val" else args.test_sources
    out = {
        f"real {split} split ({len(_split_paths(split))} panoramas x {args.yaws})": items_from_panoramas(
            _split_paths(split), yaws=args.yaws
        ),
        f"rendered {split} sources ({len(_sources(folder, args.limit))} x {args.yaws})": items_from_panoramas(
            _sources(folder, args.limit), yaws=args.yaws
        ),
    }
    if split == "test" and args.testset:
        out[f"real test set {args.testset}"] = items_from_testset(args.testset)
    return out


def _angle(a: dict[str, Any], b: dict[str, Any]) -> float | None:
    from solidkit.envmap.coords import angular_distance, direction_from_angles

    if not (a.get("found") and b.get("found")):
        return None
    da = direction_from_angles(math.radians(a["azimuth_deg"]), math.radians(a["elevation_deg"]))
    db = direction_from_angles(math.radians(b["azimuth_deg"]), math.radians(b["elevation_deg"]))
    return math.degrees(float(angular_distance(da, db)))


def figures(items: list[Any], model: Any) -> dict[str, dict[str, Any]]:
    from solidkit.finetune.evaluate import MeanBaseline, ModelMethod, evaluate

    res = evaluate(items, [ModelMethod("solidnet", model), MeanBaseline("sky"), MeanBaseline("probe")])
    out: dict[str, dict[str, Any]] = {}
    for method in ("solidnet", "mean-sky", "mean-probe"):
        recs = [r for r in res["records"] if r["method"] == method]
        if not recs:
            continue
        s = res["summary"].get(method, {})
        med = lambda k: (s.get(k) or {}).get("median")  # noqa: E731
        agree = [a for a in (_angle(r.get("sun_paper", {}), r.get("sun_core", {})) for r in recs) if a is not None]
        out[method] = {
            "global_mae": med("global_mae"),
            "global_mae_ci95": (s.get("global_mae") or {}).get("ci95"),
            "recipes_agree_deg": float(np.median(agree)) if agree else None,
            "recipes_within_10_deg": f"{sum(a <= 10 for a in agree)}/{len(agree)}",
            "angle_paper_deg": med("angle_deg/paper"),
            "angle_core_deg": med("angle_deg/core"),
            "local_ssim": med("local_ssim"),
            "local_mae": med("local_mae"),
            "n": len(recs),
        }
    return out


def tune(model: Any, val: dict[str, list[Any]]) -> tuple[float, dict[str, Any]]:
    scores: dict[str, Any] = {}
    for f in FRACTIONS:
        model.reconfigure(sun_aureole=f)
        per = {name: figures(items, model)["solidnet"] for name, items in val.items()}
        scores[str(f)] = {
            "score": float(np.mean([p["global_mae"] for p in per.values()])),
            **{n: {k: p[k] for k in ("global_mae", "recipes_agree_deg")} for n, p in per.items()},
        }
    best = min(FRACTIONS, key=lambda f: scores[str(f)]["score"])
    return best, scores


def markdown(doc: dict[str, Any]) -> str:
    head = [
        "method",
        "global MAE (median)",
        "recipes agree ° (within 10°)",
        "sun ° paper / default",
        "local SSIM / MAE",
    ]
    lines = [
        "# Global maps against the mean sky (`benchmarks/sky_maps.py`)",
        "",
        f"{doc['date']}; checkpoint `{doc['checkpoint']}`; aureole tuned on validation: **{doc['aureole']}**.",
        "",
    ]
    for name, per in doc["test"].items():
        lines += [f"**{name}**", "", "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
        for label, f in per.items():
            lines.append(
                f"| {label} | {_fmt(f['global_mae'], 3)} "
                f"| {_fmt(f['recipes_agree_deg'])} ({f['recipes_within_10_deg']}) "
                f"| {_fmt(f['angle_paper_deg'])} / {_fmt(f['angle_core_deg'])} "
                f"| {_fmt(f['local_ssim'], 3)} / {_fmt(f['local_mae'], 4)} |"
            )
        lines.append("")
    lines += ["Validation (aureole fraction: mean of the domains' median global MAE):", ""]
    for f, s in doc["tuning"].items():
        lines.append(f"- {f}: {s['score']:.3f}")
    return "\n".join(lines) + "\n"


def _fmt(v: Any, nd: int = 1) -> str:
    return "–" if v is None else f"{v:.{nd}f}" if isinstance(v, float) else str(v)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--checkpoint", type=Path, required=True)
    ap.add_argument("--before", type=Path, default=REPO / "solidkit" / "model" / "checkpoints" / "solidnet_small.pt")
    ap.add_argument("--val-sources", type=Path, required=True)
    ap.add_argument("--test-sources", type=Path, required=True)
    ap.add_argument("--testset", type=Path, default=None)
    ap.add_argument("--yaws", type=int, default=4)
    ap.add_argument("--limit", type=int, default=None, help="Rendered sources per folder (default: all).")
    ap.add_argument("--export", type=Path, default=None, help="Write the checkpoint with the tuned aureole here.")
    ap.add_argument("--what", default="", help="The exported checkpoint card's one-line description.")
    ap.add_argument("--out", type=Path, default=REPO / "benchmarks" / "results" / "sky_maps")
    args = ap.parse_args()

    import torch

    from solidkit.model import SolidNet

    torch.set_num_threads(1)
    t0 = time.time()
    model = SolidNet.from_checkpoint(args.checkpoint).eval()
    aureole, tuning = tune(model, datasets(args, "val"))
    model.reconfigure(sun_aureole=aureole)
    before = SolidNet.from_checkpoint(args.before).eval()
    test: dict[str, Any] = {}
    for name, items in datasets(args, "test").items():
        after = figures(items, model)
        prior = figures(items, before)
        test[name] = {
            "model (after)": after["solidnet"],
            "model (before)": prior["solidnet"],
            **{k: v for k, v in after.items() if k != "solidnet"},
        }
    doc = {
        "date": time.strftime("%Y-%m-%d"),
        "checkpoint": str(args.checkpoint),
        "before": str(args.before),
        "aureole": aureole,
        "tuning": tuning,
        "test": test,
        "seconds": round(time.time() - t0, 1),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(json.dumps(doc, indent=1) + "\n")
    args.out.with_suffix(".md").write_text(markdown(doc))
    if args.export:
        import tempfile

        from solidkit.model.solidnet import save_checkpoint
        from solidkit.model.trainer import export_checkpoint

        with tempfile.TemporaryDirectory() as tmp:
            save_checkpoint(model, Path(tmp) / "m.pt", getattr(model, "card", {}), half=True)
            summary = {k: v for k, v in doc.items() if k in ("date", "aureole", "tuning", "test")}
            export_checkpoint(Path(tmp) / "m.pt", args.export, {"what": args.what, "sky_maps": summary})
        print(f"wrote {args.export}")
    print(markdown(doc))


if __name__ == "__main__":
    main()
