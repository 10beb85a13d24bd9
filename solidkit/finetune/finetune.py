"""Sim-to-real fine-tuning of SOLID-Net with scene-level k-fold cross-validation.

The paper (supplementary §2) found that end-to-end fine-tuning did not help; this module measures
whether fine-tuning on a real test set helps *here*, without ever testing on a scene it trained on.

Protocol
    - **Folds** (:func:`scene_folds`): the scenes are shuffled with the seed and dealt into ``k``
      parts; fold ``i`` tests on part ``i`` and trains on the rest. A scene is never on both sides.
      Inside the training part one scene (more for large sets: 20 %) is held out for early stopping
      (*validation*), so the fold's test scenes never choose the epoch. The split is recorded.
    - **Loss: only what real labels support** (:func:`real_losses`):

      * local probes, LDR: the prediction is exposed by the median log-luminance ratio to the probe
        (the L1-optimal exposure, so the loss is exposure-invariant; the scale is not
        back-propagated) and compared on the unsaturated, not-too-dark pixels by an L1 of
        ``log`` radiance plus ``1 - SSIM`` of the camera tonemap (the evaluation's own comparison,
        :func:`solidkit.metrics.local_ldr_metrics`, made differentiable);
      * the sun direction, on photos whose label has a sun: the cross-entropy of the sun
        distribution against a 2° Gaussian at the labelled sun
        (:func:`solidkit.model.losses.sun_direction_loss`), on the sun head's logits when the model
        has one, else on the predicted sky's ``log1p`` luminance (times :data:`SKY_LOGIT_GAIN`).

      No HDR, intrinsic-image or global-map term: real labels have none of them.
    - **Few trainable parameters** by default: P-Net and I-Net's sky decoder (and sun head);
      everything else is frozen and the whole network stays in eval mode (GroupNorm only, so
      batch-1 steps are safe). ``trainable="all"`` unfreezes everything.
    - **Synthetic mixing** (optional, ``synthetic=DIR``): one synthetic batch with the full
      training loss after each real step, against forgetting. Default: off. With a few hundred
      thousand trainable parameters, a small learning rate and early stopping on held-out real
      scenes the drift is bounded, and a fresh clone has no synthetic training set; the
      synthetic evaluation after fine-tuning (when given) measures the forgetting either way.
    - **Seeded**: the fold split, the order of the training items and torch's RNG.

:func:`run_finetune` evaluates every fold's test scenes before (the synthetic-only model) and after
fine-tuning with :func:`solidkit.finetune.evaluate.evaluate`, pools the folds, and tests the paired
per-probe / per-photo differences with a scene-bootstrap interval to say whether it helps.
"""

from __future__ import annotations

import copy
import math
import random
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, cast

import numpy as np
import torch
from kornia.metrics import ssim as kornia_ssim

from solidkit import metrics as M
from solidkit.envmap.io import srgb_decode, srgb_encode
from solidkit.envmap.sun import LUMINANCE_WEIGHTS
from solidkit.errors import InputError
from solidkit.finetune.evaluate import (
    EvalItem,
    ModelMethod,
    checked_testset,
    evaluate,
    items_from_synth,
    items_from_testset,
    load_model,
    summarise_records,
)
from solidkit.finetune.report import finetune_sections, testset_line, write_report
from solidkit.fsutil import atomic_write_text
from solidkit.model.config import SolidNetConfig
from solidkit.model.fit import batch_from_synth
from solidkit.model.losses import solidnet_losses, sun_direction_loss
from solidkit.synth.dataset import SynthDataset
from solidkit.threads import ensure_threads

__all__ = [
    "TRAINABLE",
    "SKY_LOGIT_GAIN",
    "FineTuneConfig",
    "scene_folds",
    "set_trainable",
    "real_losses",
    "finetune_fold",
    "paired_difference",
    "run_finetune",
    "finetune_report",
]

TRAINABLE: dict[str, tuple[str, ...]] = {
    "pnet+sky": ("pnet.", "inet.sky_", "inet.sun."),
    "pnet": ("pnet.",),
    "sky": ("inet.sky_", "inet.sun."),
    "all": ("",),
}
"""Parameter-name prefixes unfrozen by each ``trainable`` choice."""

SKY_LOGIT_GAIN = 4.0
"""Logits = gain x mean-channel ``log1p`` of the predicted sky, for models without a sun head."""

EPS = 1e-4

MIN_SCENES_FOR_VERDICT = 5
"""Fewer test scenes than this and the scene bootstrap cannot support a verdict (it says so)."""


@dataclass(frozen=True)
class FineTuneConfig:
    """Settings of one fine-tuning run (recorded in the report)."""

    folds: int = 3
    epochs: int = 8
    patience: int = 2
    lr: float = 1e-4
    trainable: str = "pnet+sky"
    sun_weight: float = 1.0
    seed: int = 0
    synthetic_every: int = 0  # 0 = no synthetic mixing; n = one synthetic batch after every n real steps
    max_seconds_per_fold: float | None = None

    def to_json(self) -> dict[str, Any]:
        return dict(self.__dict__)


# ----------------------------------------------------------------------------------------- folds


def scene_folds(scenes: Sequence[str], k: int, seed: int = 0) -> list[dict[str, list[str]]]:
    """Scene-level k-fold split: ``[{"train": [...], "val": [...], "test": [...]}, ...]``.

    The unique scenes (order of first appearance) are shuffled with ``seed`` and dealt round-robin
    into ``min(k, n)`` test parts; every scene is tested exactly once and never trained on in the
    same fold. ``val`` is taken from the training part (``max(1, round(0.2 n_train))`` scenes, none
    when only one training scene is left) for early stopping; ``train`` is the rest.
    """
    names = list(dict.fromkeys(scenes))
    if len(names) < 2:
        raise InputError(f"k-fold fine-tuning needs at least 2 scenes, got {len(names)}")
    if k < 2:
        raise InputError(f"--folds must be at least 2, got {k}")
    order = names[:]
    random.Random(seed).shuffle(order)
    k = min(k, len(order))
    parts = [order[i::k] for i in range(k)]
    folds = []
    for i, test in enumerate(parts):
        rest = [s for j, p in enumerate(parts) if j != i for s in p]
        n_val = 0 if len(rest) < 2 else max(1, round(0.2 * len(rest)))
        folds.append({"train": sorted(rest[n_val:]), "val": sorted(rest[:n_val]), "test": sorted(test)})
    return folds


def set_trainable(model: torch.nn.Module, which: str) -> int:
    """Freeze every parameter but those named by ``TRAINABLE[which]``; returns the trainable count."""
    if which not in TRAINABLE:
        raise InputError(f"unknown --trainable {which!r}; choose one of {sorted(TRAINABLE)}")
    prefixes = TRAINABLE[which]
    n = 0
    for name, p in model.named_parameters():
        p.requires_grad_(any(name.startswith(q) for q in prefixes))
        n += p.numel() if p.requires_grad else 0
    if n == 0:
        raise InputError(f"--trainable {which}: the model has no such parameters")
    return n


# ------------------------------------------------------------------------------------------ loss


def _tensor(a: Any) -> torch.Tensor:
    return torch.as_tensor(np.asarray(a), dtype=torch.float32)


def _item_inputs(item: EvalItem, model: Any) -> tuple[torch.Tensor, ...]:
    """The model's inputs for ``item``: its photo made as the training photos were
    (:meth:`~solidkit.model.solidnet.SolidNet.photo_input`, as ``predict`` does), K, pixels, pitch, roll."""
    size = cast(SolidNetConfig, model.config).image_size
    h, w = item.image.shape[:2]
    if (h, w) != tuple(size):
        raise InputError(
            f"{item.scene}: photo is {w}x{h}, the model takes {size[1]}x{size[0]} (build the test set for it)"
        )
    photo = model.photo_input(item.image[..., :3], item.encoding)[0] if hasattr(model, "photo_input") else item.image
    return (
        _tensor(photo[..., :3]).permute(2, 0, 1)[None],
        _tensor(item.K)[None],
        _tensor(item.pixels)[None],
        _tensor([item.pitch]),
        _tensor([item.roll]),
    )


def _luma(x: torch.Tensor) -> torch.Tensor:
    return torch.einsum("nchw,c->nhw", x, torch.as_tensor(LUMINANCE_WEIGHTS, dtype=x.dtype))


def local_ldr_loss(pred: torch.Tensor, probe_ldr: torch.Tensor, saturated: torch.Tensor) -> torch.Tensor:
    """Exposure-invariant loss of HDR predictions ``(N, 3, H, W)`` against LDR probes (sRGB, [0, 1]).

    ``log s = median(log Y_probe - log Y_pred)`` (no gradient) over usable pixels (not
    ``saturated (N, H, W)``, probe luminance above :data:`~solidkit.metrics.DARK_FLOOR`);
    loss = mean over them of ``|log(s pred + eps) - log(probe_lin + eps)|`` plus
    ``1 - SSIM(srgb_encode(clip(s pred)), probe)`` averaged over the unsaturated pixels, with the
    prediction replaced by the probe on saturated pixels (as the metric does).
    """
    lin = srgb_decode(probe_ldr)
    y_probe, y_pred = _luma(lin), _luma(pred)
    usable = (~saturated) & (y_probe > M.DARK_FLOOR)
    total = pred.new_zeros(())
    for i in range(pred.shape[0]):
        u = usable[i]
        if not u.any():
            continue
        with torch.no_grad():
            log_s = torch.median(torch.log(y_probe[i][u]) - torch.log(y_pred[i][u].clamp_min(EPS)))
        exposed = pred[i] * torch.exp(log_s)
        l1 = (torch.log(exposed + EPS) - torch.log(lin[i] + EPS)).abs()[:, u].mean()
        ldr = srgb_encode(exposed.clamp(0.0, 1.0))
        ldr = torch.where(saturated[i][None], probe_ldr[i], ldr)
        smap = kornia_ssim(ldr[None], probe_ldr[i][None], M.SSIM_WINDOW, max_val=1.0)[0].mean(dim=0)
        total = total + l1 + (1.0 - smap[~saturated[i]].mean())
    return total / pred.shape[0]


def _sun_logits(out: dict[str, torch.Tensor]) -> torch.Tensor:
    if "sun_logits" in out:
        return out["sun_logits"]
    return SKY_LOGIT_GAIN * out["sky_log"].mean(dim=1, keepdim=True)


def real_losses(model: torch.nn.Module, item: EvalItem, sun_weight: float = 1.0) -> dict[str, torch.Tensor]:
    """The fine-tuning loss of one real photo: ``local`` (LDR probes) + ``sun_weight x sun``."""
    image, K, pixels, pitch, roll = _item_inputs(item, model)
    out = model(image, K, pixels, pitch, roll)
    probes = _tensor(np.stack(item.probes_ldr)).permute(0, 3, 1, 2)
    sat = torch.as_tensor(np.stack([M.saturation_mask(p, s) for p, s in zip(item.probes_ldr, item.probes_saturated)]))
    terms = {"local": local_ldr_loss(out["local"][0], probes, sat)}
    if item.sun is not None:
        terms["sun"] = sun_direction_loss(_sun_logits(out), _tensor(item.sun)[None], torch.ones(1))
    else:
        terms["sun"] = out["sky_log"].sum() * 0.0
    terms["total"] = terms["local"] + sun_weight * terms["sun"]
    return terms


# --------------------------------------------------------------------------------------- one fold


def _mean_loss(model: torch.nn.Module, items: Sequence[EvalItem], sun_weight: float) -> float:
    with torch.no_grad():
        return (
            float(np.mean([float(real_losses(model, it, sun_weight)["total"]) for it in items])) if items else math.nan
        )


def _synthetic_batches(dataset: Any, seed: int) -> Any:
    """Endless seeded shuffled batches of one synthetic sample (the model's batch format)."""
    g = torch.Generator().manual_seed(seed)
    while True:
        yield from torch.utils.data.DataLoader(
            dataset, batch_size=1, shuffle=True, collate_fn=batch_from_synth, generator=g
        )


def finetune_fold(
    model: torch.nn.Module,
    train: Sequence[EvalItem],
    val: Sequence[EvalItem],
    cfg: FineTuneConfig,
    synthetic: Any = None,
    log: Callable[[str], Any] | None = None,
) -> tuple[torch.nn.Module, dict[str, Any]]:
    """Fine-tune a copy of ``model`` on ``train``; early stopping on ``val`` (when not empty).

    Returns the best model (lowest validation loss; the last one without validation) and a record
    with the loss history, the best epoch, the trainable parameter count and the time.
    """
    torch.manual_seed(cfg.seed)
    rng = random.Random(cfg.seed)
    net = copy.deepcopy(model).eval()  # GroupNorm only: eval mode changes nothing but keeps it explicit
    n_train = set_trainable(net, cfg.trainable)
    opt = torch.optim.Adam([p for p in net.parameters() if p.requires_grad], lr=cfg.lr)
    t0 = time.perf_counter()
    # epoch 0 is the starting point for early stopping; its training loss would cost a pass over the training
    # photos that no decision uses, so it is not computed (``None``)
    history: list[dict[str, Any]] = [{"epoch": 0, "train": None, "val": _mean_loss(net, val, cfg.sun_weight)}]
    best, best_epoch, bad = copy.deepcopy(net.state_dict()), 0, 0
    best_val = history[0]["val"]
    order = list(range(len(train)))
    mixing = synthetic is not None and cfg.synthetic_every > 0
    syn = _synthetic_batches(synthetic, cfg.seed) if mixing else None
    steps = 0
    for epoch in range(1, cfg.epochs + 1):
        rng.shuffle(order)
        losses = []
        for i in order:
            terms = real_losses(net, train[i], cfg.sun_weight)
            opt.zero_grad(set_to_none=True)
            terms["total"].backward()
            opt.step()
            losses.append(float(terms["total"].detach()))
            steps += 1
            if mixing and steps % cfg.synthetic_every == 0:
                assert syn is not None  # mixing
                batch = next(syn)
                o = net(batch["image"], batch["K"], batch["pixels"], batch["pitch"], batch["roll"])
                loss = solidnet_losses(
                    o,
                    batch,
                    cast(SolidNetConfig, net.config).loss_weights,
                    getattr(net.config, "loss_variant", "paper"),
                )["total"]
                opt.zero_grad(set_to_none=True)
                loss.backward()
                opt.step()
        rec = {"epoch": epoch, "train": float(np.mean(losses)), "val": _mean_loss(net, val, cfg.sun_weight)}
        history.append(rec)
        if log is not None:
            log(f"    epoch {epoch}: train loss {rec['train']:.4f}, validation {rec['val']:.4f}")
        if val:
            if rec["val"] < best_val - 1e-6:
                best, best_epoch, best_val, bad = copy.deepcopy(net.state_dict()), epoch, rec["val"], 0
            else:
                bad += 1
                if bad >= cfg.patience:
                    break
        else:
            best, best_epoch = copy.deepcopy(net.state_dict()), epoch
        if cfg.max_seconds_per_fold is not None and time.perf_counter() - t0 > cfg.max_seconds_per_fold:
            break
    net.load_state_dict(best)
    for p in net.parameters():
        p.requires_grad_(False)
    return net.eval(), {
        "history": history,
        "best_epoch": best_epoch,
        "epochs_run": history[-1]["epoch"],
        "trainable_parameters": n_train,
        "seconds": time.perf_counter() - t0,
        "early_stopping": bool(val),
    }


# -------------------------------------------------------------------------------------- analysis


def _paired(before: Sequence[dict], after: Sequence[dict], key: str) -> tuple[list[float], list[str]]:
    """Per-probe (local metrics) or per-photo (sun) differences after - before, matched by item."""
    b = {(r["scene"], r["item"]): r for r in before}
    diffs, groups = [], []
    for r in after:
        r0 = b.get((r["scene"], r["item"]))
        if r0 is None:
            continue
        if key in ("ssim", "mae"):
            p0 = {p["probe"]: p for p in r0.get("probes", [])}
            for p in r.get("probes", []):
                q = p0.get(p["probe"])
                if q is not None and math.isfinite(p[key]) and math.isfinite(q[key]):
                    diffs.append(p[key] - q[key])
                    groups.append(r["scene"])
        else:
            recipe = key.split("/")[1]
            e0, e1 = r0.get(f"sun_{recipe}", {}), r.get(f"sun_{recipe}", {})
            if r["truth_sun"] and e0.get("angle_deg") is not None and e1.get("angle_deg") is not None:
                diffs.append(e1["angle_deg"] - e0["angle_deg"])
                groups.append(r["scene"])
    return diffs, groups


def paired_difference(
    before: Sequence[dict], after: Sequence[dict], key: str, higher_is_better: bool
) -> dict[str, Any]:
    """Mean paired difference (after - before) with a scene-bootstrap 95 % interval and a verdict."""
    d, g = _paired(before, after, key)
    if not d:
        return {"n": 0, "verdict": "not measurable"}
    s = M.summarise(d, g)
    n_scenes = len(set(g))
    if n_scenes < MIN_SCENES_FOR_VERDICT:
        return {
            "n": s["n"],
            "mean": s["mean"],
            "mean_ci": s["mean_ci"],
            "median": s["median"],
            "verdict": f"too few scenes to tell ({n_scenes} < {MIN_SCENES_FOR_VERDICT})",
        }
    lo, hi = s["mean_ci"]
    good, bad = (lo > 0, hi < 0) if higher_is_better else (hi < 0, lo > 0)
    verdict = "helps" if good else "hurts" if bad else "no significant change"
    return {"n": s["n"], "mean": s["mean"], "mean_ci": s["mean_ci"], "median": s["median"], "verdict": verdict}


def run_finetune(
    model: torch.nn.Module,
    items: Sequence[EvalItem],
    cfg: FineTuneConfig,
    synthetic: Any = None,
    synthetic_eval: Sequence[EvalItem] | None = None,
    log: Callable[[str], Any] | None = None,
) -> dict[str, Any]:
    """k-fold fine-tuning on ``items`` (real); see the module docstring. JSON-able result, plus the
    fine-tuned models under ``"models"`` (one per fold; not JSON)."""
    log = log or (lambda s: None)
    torch.manual_seed(cfg.seed)
    folds = scene_folds([it.scene for it in items], cfg.folds, cfg.seed)
    by_scene: dict[str, list[EvalItem]] = {}
    for it in items:
        by_scene.setdefault(it.scene, []).append(it)
    base = ModelMethod("synthetic-only", model)
    out_folds, models, before_all, after_all = [], [], [], []
    for i, split in enumerate(folds):
        pick = lambda names: [it for s in names for it in by_scene[s]]  # noqa: E731
        train, val, test = pick(split["train"]), pick(split["val"]), pick(split["test"])
        log(
            f"  fold {i + 1}/{len(folds)}: train {len(split['train'])} scenes ({len(train)} photos), "
            f"validation {len(split['val'])}, test {len(split['test'])}"
        )
        tuned, rec = finetune_fold(model, train, val, cfg, synthetic, log)
        after = ModelMethod("fine-tuned", tuned)
        before_res = evaluate(test, [base])
        after_res = evaluate(test, [after])
        before_all += before_res["records"]
        after_all += after_res["records"]
        out_folds.append(
            {
                "fold": i,
                "split": split,
                **rec,
                "before": before_res["summary"]["synthetic-only"],
                "after": after_res["summary"]["fine-tuned"],
            }
        )
        models.append(tuned)
        log(f"    best epoch {rec['best_epoch']} of {rec['epochs_run']}, {rec['seconds']:.1f} s")
    pooled: dict[str, Any] = {
        "methods": [
            {
                "name": "synthetic-only",
                "kind": "model",
                "description": "the checkpoint as shipped (synthetic data only)",
            },
            {
                "name": "fine-tuned",
                "kind": "model",
                "description": f"fine-tuned per fold on the other scenes ({cfg.trainable}, lr {cfg.lr:g})",
            },
        ],
        "records": before_all + after_all,
    }

    pooled["summary"] = {
        "synthetic-only": summarise_records(before_all, cfg.seed),
        "fine-tuned": summarise_records(after_all, cfg.seed),
    }
    n_scenes = len({it.scene for it in items})
    pooled["timing"] = {
        "scenes": n_scenes,
        "methods": 2,
        "seconds_total": float(sum(f["seconds"] for f in out_folds)),
        "seconds_per_scene_median": None,
    }
    effect = {
        "local_ssim": paired_difference(before_all, after_all, "ssim", True),
        "local_mae": paired_difference(before_all, after_all, "mae", False),
        "sun_angle/paper": paired_difference(before_all, after_all, "angle/paper", False),
        "sun_angle/core": paired_difference(before_all, after_all, "angle/core", False),
    }
    result: dict[str, Any] = {
        "config": cfg.to_json(),
        "folds": out_folds,
        "pooled": pooled,
        "effect": effect,
        "seconds_per_fold": [f["seconds"] for f in out_folds],
        "models": models,
    }
    if synthetic_eval:
        log("  forgetting check on the synthetic split")
        result["synthetic"] = evaluate(
            synthetic_eval, [base] + [ModelMethod(f"fine-tuned fold {i + 1}", m) for i, m in enumerate(models)]
        )
    return result


def finetune_report(
    out: Any,
    model: Any = None,
    testset: Any = None,
    cfg: FineTuneConfig | None = None,
    mix_synthetic: Any = None,
    synthetic: Any = None,
    real_items: Sequence[EvalItem] | None = None,
    save_models: bool = True,
    log: Callable[[str], Any] | None = None,
    allow_invalid: bool = False,
) -> dict[str, Any]:
    """``solidkit finetune``: k-fold fine-tuning on a real test set, or several pooled (``testset`` a
    list; scene ids are then prefixed by each folder's name); writes ``finetune.json``,
    ``report.md``/``report.html``, ``figures/`` and ``fold_<i>.pt`` into ``out``. A test set that fails
    validation is refused unless ``allow_invalid``; each one's path and ``dataset_version`` go into
    ``finetune.json`` (``testsets``) and the report."""
    import json
    from pathlib import Path

    log = log or (lambda s: None)
    cfg = cfg or FineTuneConfig()
    ensure_threads()
    records: list[dict[str, Any]] = []
    if real_items is not None:
        items = list(real_items)
    else:
        sets = [testset] if isinstance(testset, (str, Path)) else list(testset)
        records = [checked_testset(ts, allow_invalid=allow_invalid, log=log) for ts in sets]
        items = []
        for ts in sets:  # several test sets pool their scenes (ids prefixed by the folder name)
            for it in items_from_testset(ts):
                if len(sets) > 1:
                    it.scene = it.id = f"{Path(ts).name}/{it.scene}"
                items.append(it)
    net = load_model(model)
    mix = None
    if mix_synthetic is not None:
        mix = SynthDataset(mix_synthetic)
        if cfg.synthetic_every == 0:
            cfg = FineTuneConfig(**{**cfg.to_json(), "synthetic_every": 1})
    syn_eval = items_from_synth(synthetic, limit=8) if synthetic is not None else None
    log(f"fine-tuning on {len({i.scene for i in items})} scenes, {sum(len(i.probe_ids) for i in items)} probes")
    res = run_finetune(net, items, cfg, mix, syn_eval, log)
    if records:
        res = {"testsets": records, **res}
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    models = res.pop("models")
    if save_models:
        for i, m in enumerate(models):
            m.save(
                out / f"fold_{i + 1}.pt",
                {
                    **getattr(net, "card", {}),
                    "what": f"fine-tuned on real scenes, fold {i + 1}",
                    "finetune": {"config": cfg.to_json(), "split": res["folds"][i]["split"]},
                },
            )
    atomic_write_text(out / "finetune.json", json.dumps(res, indent=1, default=float))
    sections = finetune_sections(res, out)
    if records:
        sections = [("Test sets", "\n\n".join(testset_line(r) for r in records)), *sections]
    md, page = write_report(out, "SOLID-Net fine-tuning on real scenes (k-fold)", sections)
    return {**res, "report": str(page), "markdown": str(md)}
