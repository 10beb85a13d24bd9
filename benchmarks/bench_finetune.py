"""Benchmark of the evaluation (time per scene) and the k-fold fine-tuning (time per fold).

Input: the analytic campaign of ``tests/support/testset_campaign.py`` with 6 scenes (camera position + 2
probes each), built into a test set; the shipped checkpoint; 1 torch thread. Peers, in the same run:

* evaluation per scene (the model, global-as-local, mean sky, mean probe; every metric with both
  sun recipes; bootstrap summaries) vs ``SolidNet.predict`` alone on the same photos: what the
  metrics and baselines cost beyond inference;
* fine-tuning per fold (3 folds, 2 epochs, early-stopping evaluations included) vs the inference of
  the same number of photo passes: what a training pass costs against a forward pass.

Writes benchmarks/results/finetune.json and finetune.md. Run: ``.venv/bin/python benchmarks/bench_finetune.py``.
"""

from __future__ import annotations

import json
import platform
import sys
import tempfile
import time
from pathlib import Path

import torch

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from solidkit.finetune.evaluate import default_methods, evaluate, items_from_testset, load_model  # noqa: E402
from solidkit.finetune.finetune import FineTuneConfig, run_finetune  # noqa: E402
from solidkit.testset.build import build_testset  # noqa: E402
from tests.support.testset_campaign import SCENES, make_campaign  # noqa: E402

OUT = HERE / "results"
N_SCENES = 6


def main() -> None:
    torch.set_num_threads(1)
    base = SCENES["sA"]
    scenes = {
        f"s{k:02d}": (base[0] + 50 * k - 150, base[1] + 3 * k, base[2], base[3], base[4], base[5])
        for k in range(N_SCENES)
    }
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        make_campaign(tmp / "camp", scenes)
        build_testset(tmp / "camp", tmp / "ts")
        items = items_from_testset(tmp / "ts")
    net = load_model(None)
    n_probes = sum(len(i.probe_ids) for i in items)

    t0 = time.perf_counter()
    for it in items:
        net.predict(it.image, it.pixels, K=it.K, pitch=it.pitch, roll=it.roll)
    t_predict = (time.perf_counter() - t0) / len(items)
    res_eval = evaluate(items, default_methods(net))
    t_eval = res_eval["timing"]["seconds_total"] / len(items)

    cfg = FineTuneConfig(folds=3, epochs=2, patience=5, seed=0)
    t0 = time.perf_counter()
    res_ft = run_finetune(net, items, cfg)
    t_ft_total = time.perf_counter() - t0
    per_fold = res_ft["seconds_per_fold"]
    passes = [
        sum(len(f["split"][k]) for k in ("train",)) * f["epochs_run"] + len(f["split"]["val"]) * (f["epochs_run"] + 1)
        for f in res_ft["folds"]
    ]  # training steps + validation passes (before fine-tuning and after each epoch)
    t_fold = sum(per_fold) / len(per_fold)
    t_fold_peer = t_predict * sum(passes) / len(passes)
    res = {
        "machine": platform.platform(),
        "python": platform.python_version(),
        "torch": torch.__version__,
        "threads": 1,
        "load_average_1min": round(__import__("os").getloadavg()[0], 1),
        "scenes": N_SCENES,
        "probes": n_probes,
        "model": net.config.name,
        "parameters": net.num_parameters,
        "eval_s_per_scene": round(t_eval, 3),
        "predict_peer_s_per_scene": round(t_predict, 3),
        "eval_over_predict": round(t_eval / t_predict, 2),
        "finetune_folds": len(per_fold),
        "finetune_epochs": cfg.epochs,
        "finetune_s_per_fold": round(t_fold, 2),
        "finetune_s_total": round(t_ft_total, 2),
        "photo_passes_per_fold": round(sum(passes) / len(passes), 1),
        "inference_of_as_many_passes_s": round(t_fold_peer, 2),
        "finetune_over_inference": round(t_fold / t_fold_peer, 2),
        "trainable_parameters": res_ft["folds"][0]["trainable_parameters"],
    }
    OUT.mkdir(exist_ok=True)
    (OUT / "finetune.json").write_text(json.dumps(res, indent=1) + "\n")
    (OUT / "finetune.md").write_text(
        "# evaluation and k-fold fine-tuning\n\n"
        f"{N_SCENES} analytic scenes, {n_probes} probes; model `{net.config.name}` ({net.num_parameters / 1e6:.2f} M "
        f"parameters, {res['trainable_parameters'] / 1e3:.0f} k trainable), 1 torch thread; {res['machine']}, load "
        f"average {res['load_average_1min']} when measured (shared machine: the ratios hold, absolute times do not)\n\n"
        "| step | seconds | peer | peer seconds | ratio |\n|---|---|---|---|---|\n"
        f"| evaluation per scene (4 methods, all metrics) | {t_eval:.2f} | SolidNet.predict per scene | "
        f"{t_predict:.2f} | {t_eval / t_predict:.1f}x |\n"
        f"| fine-tuning per fold ({cfg.folds} folds, {cfg.epochs} epochs) | {t_fold:.1f} | inference of as many photo "
        f"passes ({res['photo_passes_per_fold']}) | {t_fold_peer:.1f} | {t_fold / t_fold_peer:.1f}x |\n"
    )
    print(json.dumps(res, indent=1))


if __name__ == "__main__":
    main()
