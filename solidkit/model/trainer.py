"""``solidkit train``: SOLID-Net training from a TOML configuration, I-Net then P-Net (paper §4.3).

Stages (paper supplementary §1: I-Net first, then P-Net; Adam, lr 5e-4 halved every 5 epochs):

- ``sun`` (models with ``sun_net``, before I-Net): the low-resolution sun network
  (:mod:`solidkit.model.sunnet`) alone on its own terms (:func:`solidkit.model.losses.sun_terms`), from
  crops of the same panoramas held in memory with their sun measured once (:mod:`solidkit.model.suncrops`);
  the ``inet`` stage then leaves it frozen.
- ``inet``: I-Net alone on ``L_I`` (intrinsics, SH, sky and, with the sun head, the sun terms).
  A batch is either panorama crops (:mod:`solidkit.synth.panocrops`, sky targets only, the lighting
  decoders alone run) or full synthetic samples (:class:`solidkit.synth.dataset.SynthDataset`),
  drawn with probability ``crop_fraction``.
- ``pnet``: P-Net on ``L_P`` with I-Net frozen, warping with I-Net's *predicted* geometry (as at
  test time) unless ``teacher_geometry``; needs full samples (local probes).

Reproducibility and resuming: the content of batch ``step`` of a stage is a pure function of
``(seed, stage, step)`` (and of the list of crop sources, which is refreshed only every
``refresh_sources_every`` steps and stored in the checkpoint), the model has no stochastic layers,
and ``RUN/last.pt`` holds the weights, the optimiser and scheduler states and the step. So a run
stopped and resumed takes exactly the step it would have taken (``tests/model/test_trainer.py``).

Outputs in the run folder: ``last.pt`` (training state, every ``checkpoint_every`` steps and at
the end), ``best.pt`` and ``model.pt`` (model checkpoints of :func:`solidkit.model.save_checkpoint`
with their card: best validation score, and the final model), ``metrics.csv`` (one row per logged
step and per validation), TensorBoard events in ``tb/`` when ``tensorboard`` is installed, and
``config.toml`` (the configuration used).

Multi-GPU / multi-process: launch with ``torchrun --nproc_per_node N -m solidkit.cli train CONFIG``;
each process reads ``RANK``/``WORLD_SIZE``/``LOCAL_RANK``, joins the process group (NCCL on GPUs,
Gloo on CPU), wraps the trained module in ``DistributedDataParallel`` and takes its share of every
batch (the same global batch as one process: identical indices, split by rank). Rank 0 validates,
logs and writes checkpoints.
"""

from __future__ import annotations

import csv
import json
import math
import os
import platform
import sys
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any, cast

import numpy as np
import tomllib
import torch

from solidkit.envmap.coords import CONVENTIONS_VERSION
from solidkit.envmap.io import decode_ldr, tonemap
from solidkit.envmap.sun import detect_sun
from solidkit.errors import InputError
from solidkit.fsutil import atomic_write_bytes, atomic_write_text, sha256_file
from solidkit.metrics.sun import direction_errors, sun_error
from solidkit.model.config import SolidNetConfig, preset
from solidkit.model.fit import batch_from_synth
from solidkit.model.losses import solidnet_losses, sun_energy, sun_terms
from solidkit.model.solidnet import CHECKPOINT_VERSION, SolidNet, load_checkpoint, save_checkpoint
from solidkit.model.suncrops import SunCropBank
from solidkit.model.warp import camera_rotation
from solidkit.synth.dataset import SynthDataset
from solidkit.synth.panocrops import CropConfig, CropSampler, load_sources, metered_gain
from solidkit.synth.sample import derive_seed

__all__ = [
    "StageConfig",
    "TrainConfig",
    "load_train_config",
    "Trainer",
    "crop_batch",
    "synth_batch",
    "evaluate_lighting",
    "evaluate_sun",
    "best_visibility_threshold",
    "tune_visibility_threshold",
    "set_visibility_threshold",
    "export_checkpoint",
    "model_from_state",
]

STAGES = ("sun", "inet", "pnet")
_STAGE_SEED = {"inet": 0, "pnet": 1, "sun": 2}  # batch seeds of a stage (fixed when the sun stage came)


@dataclass
class StageConfig:
    """One training stage.

    Attributes
    ----------
    steps : int
        Optimiser steps (0 skips the stage).
    batch_size : int
        Images per step (paper: 8 for I-Net, 4 for P-Net).
    lr : float
        Adam learning rate (paper: 5e-4).
    lr_halve_every : int
        Steps between halvings of the learning rate (paper: 5 epochs); 0 = constant.
    crop_fraction : float
        I-Net: probability that a batch is panorama crops rather than full samples.
    probes : int
        P-Net: probes per image per step.
    teacher_geometry : bool
        P-Net: warp with the ground-truth geometry instead of I-Net's prediction.
    frozen : list of str
        Children of the stage's network kept fixed (e.g. ``["encoder", "decoders"]`` for I-Net: the
        lighting decoders alone learn, so crops without geometry cannot move the intrinsics). With a
        ``sun`` stage, I-Net's ``sun`` is frozen in the ``inet`` stage anyway.
    """

    steps: int = 0
    batch_size: int = 8
    lr: float = 5e-4
    lr_halve_every: int = 0
    crop_fraction: float = 1.0
    probes: int = 2
    teacher_geometry: bool = False
    frozen: list[str] = field(default_factory=list)


@dataclass
class TrainConfig:
    """A training run (the TOML file's keys; stages are ``[inet]`` and ``[pnet]`` tables).

    ``crops`` take the ``train`` split of a folder of real panoramas and ``val_crops`` its ``val`` split
    (:func:`solidkit.synth.panocrops.load_sources`: split by whole panorama, so no crop of a validation or
    test panorama is trained on). ``crop_weights``: one weight per ``crops`` folder, the share of the sun stage's crops
    drawn from it (a folder of 16 real panoramas beside 2400 rendered ones would otherwise give ~1 % of the
    crops); empty: every source equally likely.
    ``init``: a model checkpoint or training state to start from; tensors whose name and shape match
    the configured model are copied, the others keep their fresh initialisation (logged).
    ``sun_target_deg``: width (degrees) of the sun-direction target (:func:`solidkit.model.losses.
    sun_direction_loss`); two values ``[start, end]`` anneal it geometrically over
    ``sun_target_anneal_steps`` I-Net steps (0: the whole stage), coarse to fine.
    ``meter_samples``: full samples are metered as crops are and as ``predict`` meters a photo (the gain of
    :func:`solidkit.synth.panocrops.metered_gain` on the linear values behind the LDR photo, applied to photo,
    global map and probes before the jitter; needs the model's ``exposure_key``); off: their stored exposure.
    """

    out: str = "runs/solidnet"
    model: str = "small"
    model_overrides: dict[str, Any] = field(default_factory=dict)
    init: str | None = None
    seed: int = 0
    crops: list[str] = field(default_factory=list)
    crops_exclude: list[str] = field(default_factory=list)
    crop_weights: list[float] = field(default_factory=list)
    synth: list[str] = field(default_factory=list)
    val_crops: list[str] = field(default_factory=list)
    val_synth: list[str] = field(default_factory=list)
    val_samples: int = 32
    val_every: int = 500
    log_every: int = 10
    checkpoint_every: int = 100
    refresh_sources_every: int = 500
    threads: int = 1
    device: str = "cpu"
    max_minutes: float = 0.0
    sun_target_deg: list[float] = field(default_factory=lambda: [2.0])
    sun_target_anneal_steps: int = 0
    meter_samples: bool = False
    sun: StageConfig = field(default_factory=lambda: StageConfig(steps=0, batch_size=32))
    inet: StageConfig = field(default_factory=lambda: StageConfig(steps=1000, batch_size=8))
    pnet: StageConfig = field(default_factory=lambda: StageConfig(steps=0, batch_size=4))

    def model_config(self) -> SolidNetConfig:
        return preset(self.model, **self.model_overrides)

    def to_toml(self) -> str:
        """The configuration as TOML (written into the run folder)."""

        def val(v: Any) -> str:
            if isinstance(v, bool):
                return "true" if v else "false"
            if isinstance(v, (int, float)):
                return repr(v)
            if isinstance(v, (list, tuple)):
                return "[" + ", ".join(val(x) for x in v) + "]"
            return json.dumps(str(v))

        lines, tables = [], []
        for k, v in asdict(self).items():
            if v is None:
                continue
            if isinstance(v, dict):
                tables.append((k, v))
            else:
                lines.append(f"{k} = {val(v)}")
        for k, v in tables:
            lines.append(f"\n[{k}]")
            lines += [f"{kk} = {val(vv)}" for kk, vv in v.items() if vv is not None]
        return "\n".join(lines) + "\n"


def load_train_config(path: str | os.PathLike, **overrides: Any) -> TrainConfig:
    """Read a TOML training configuration; unknown keys and bad values are one-line :class:`InputError`."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: no such training configuration")
    try:
        data = tomllib.loads(path.read_text())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: not valid TOML ({exc})") from None
    except RecursionError:  # arrays or tables nested past the parser's stack
        raise InputError(f"{path}: not valid TOML (nested too deep)") from None
    data.update({k: v for k, v in overrides.items() if v is not None})
    known = {f.name for f in fields(TrainConfig)}
    unknown = sorted(set(data) - known)
    if unknown:
        raise InputError(f"{path}: unknown keys {unknown} (known: {sorted(known)})")
    stages: dict[str, Any] = {}
    for name in STAGES:
        table = data.pop(name, {})
        bad = sorted(set(table) - {f.name for f in fields(StageConfig)})
        if bad:
            raise InputError(f"{path}: unknown keys {bad} in [{name}]")
        stages[name] = StageConfig(**{**asdict(getattr(TrainConfig(), name)), **table})
    try:
        cfg = TrainConfig(**data, **stages)
        cfg.model_config()
    except Exception as exc:  # TypeError/ValueError from the dataclasses, ConfigError from the model config
        raise InputError(f"{path}: {exc}") from None
    for name in STAGES:
        st = getattr(cfg, name)
        if st.steps < 0 or st.batch_size < 1 or not st.lr > 0 or not 0.0 <= st.crop_fraction <= 1.0:
            raise InputError(f"{path}: [{name}] needs steps >= 0, batch_size >= 1, lr > 0, 0 <= crop_fraction <= 1")
    net = SolidNet(cfg.model_config())
    for name in ("inet", "pnet"):
        children = {n for n, _ in getattr(net, name).named_children()}
        bad = sorted(set(getattr(cfg, name).frozen) - children)
        if bad:
            raise InputError(f"{path}: [{name}] frozen names {bad} that are not parts of it ({sorted(children)})")
    if cfg.sun.frozen:
        raise InputError(f"{path}: [sun] has no frozen parts (it trains the sun network alone)")
    if not 1 <= len(cfg.sun_target_deg) <= 2 or not all(0.0 < float(v) <= 90.0 for v in cfg.sun_target_deg):
        raise InputError(
            f"{path}: sun_target_deg must be one or two widths in (0, 90] degrees, got {cfg.sun_target_deg}"
        )
    if cfg.crop_weights and (
        len(cfg.crop_weights) != len(cfg.crops)
        or not all(float(w) >= 0 for w in cfg.crop_weights)
        or not sum(cfg.crop_weights) > 0
    ):
        raise InputError(
            f"{path}: crop_weights needs one weight >= 0 per crops folder (not all 0), got {cfg.crop_weights}"
        )
    if cfg.sun.steps and not (cfg.crops and cfg.model_config().sun_net):
        raise InputError(f"{path}: [sun] steps need a model with a sun_net and crops = [folders of panoramas]")
    if cfg.inet.steps and cfg.inet.crop_fraction > 0 and not cfg.crops:
        raise InputError(f"{path}: [inet] crop_fraction > 0 needs crops = [folders of panoramas]")
    if (cfg.inet.steps and cfg.inet.crop_fraction < 1 or cfg.pnet.steps) and not cfg.synth:
        raise InputError(
            f"{path}: full-sample batches (crop_fraction < 1, or a pnet stage) need synth = [dataset folders]"
        )
    return cfg


# ----------------------------------------------------------------------------------------- data


def _t(a: Any) -> torch.Tensor:
    return torch.as_tensor(np.asarray(a), dtype=torch.float32)


def crop_batch(items: list[dict[str, Any]]) -> dict[str, torch.Tensor]:
    """Collate :class:`solidkit.synth.panocrops.CropSampler` items into the model's batch format (sky only)."""
    return {
        "image": torch.stack([_t(it["image"]).permute(2, 0, 1) for it in items]),
        "K": torch.stack([_t(it["K"]) for it in items]),
        "pitch": _t([it["pitch"] for it in items]),
        "roll": _t([it["roll"] for it in items]),
        "sky": torch.stack([_t(it["sky"]).permute(2, 0, 1) for it in items]),
        "sun_dir": torch.stack([_t(it["sun_dir"]) for it in items]),
        "sun_visible": _t([it["sun_visible"] for it in items]),
    }


def synth_batch(items: list[dict[str, Any]]) -> dict[str, torch.Tensor]:
    """Collate :class:`SynthDataset` items (:func:`solidkit.model.fit.batch_from_synth`)."""
    return batch_from_synth(items)


class _Data:
    """The crop sources and synthetic datasets of a run, with deterministic batch drawing."""

    def __init__(
        self,
        crops: list[str],
        exclude: list[str],
        synth: list[str],
        seed: int,
        exposure_key: float = 0.0,
        *,
        split: str = "train",
        weights: list[float] | None = None,
        meter_samples: bool = False,
    ) -> None:
        self.crop_dirs, self.exclude, self.seed = list(crops), tuple(exclude), seed
        self.meter_samples = bool(meter_samples and exposure_key)
        self.split, self.folder_weights = split, list(weights or [])
        self.source_folders: list[int] = []
        self.exposure_key = exposure_key or None  # the model's input exposure (SolidNetConfig.exposure_key)
        self.sources: list[Any] = []
        self.source_names: list[str] = []
        self.bank: Any = None  # the sun stage's SunCropBank, filled on its first batch
        self.synth = [SynthDataset(d) for d in synth]
        self.synth_index = [(k, i) for k, ds in enumerate(self.synth) for i in range(len(ds))]
        if synth and not self.synth_index:
            raise InputError(f"no samples in {synth}")

    def refresh(self, names: list[str] | None = None) -> None:
        """Rescan the crop folders (or restore the list ``names`` saved in a checkpoint)."""
        # keyed by folder too: two source folders both hold a 000000
        found = [
            (f"{Path(d).name}/{s.name}", (k, s))
            for k, d in enumerate(self.crop_dirs)
            for s in load_sources(d, self.exclude, self.split)
        ]
        if names is not None:
            by = dict(found)
            missing = [n for n in names if n not in by]
            if missing:
                raise InputError(f"crop sources of the checkpoint are gone: {missing[:3]}...")
            found = [(n, by[n]) for n in names]
        self.sources, self.source_names = [s for _, (_, s) in found], [n for n, _ in found]
        self.source_folders = [k for _, (k, _) in found]

    def source_weights(self) -> np.ndarray | None:
        """Probability of each source (``folder_weights`` shared evenly within a folder); ``None``: uniform."""
        if not self.folder_weights:
            return None
        folders = np.asarray(self.source_folders)
        counts = np.bincount(folders, minlength=len(self.crop_dirs))
        w = np.asarray(self.folder_weights, np.float64)[folders] / counts[folders]
        return w / w.sum()

    def batch(
        self, stage: str, step: int, size: int, crop_fraction: float, rank: int = 0, world: int = 1
    ) -> tuple[str, dict[str, torch.Tensor]]:
        if stage == "sun":
            if self.bank is None:
                self.bank = SunCropBank()
            if self.bank.names != self.source_names:
                self.bank.sync(self.source_names, self.sources)
                self.bank.weights = self.source_weights()
            return "suncrops", self.bank.batch(
                derive_seed(self.seed, 7), step, size, CropConfig(exposure_key=self.exposure_key), rank, world
            )
        rng = np.random.default_rng(derive_seed(self.seed, _STAGE_SEED[stage], step))
        use_crops = bool(self.sources) and (not self.synth_index or rng.random() < crop_fraction)
        if use_crops:
            idx = rng.integers(0, 2**31 - 1, size)[rank::world]
            sampler = CropSampler(self.sources, derive_seed(self.seed, 7), CropConfig(exposure_key=self.exposure_key))
            return "crops", crop_batch([sampler(int(i)) for i in idx])
        pick = rng.integers(0, len(self.synth_index), size)[rank::world]
        items = [self.synth[k][i] for k, i in (self.synth_index[int(j)] for j in pick)]
        flip = rng.random(size)[rank::world] < 0.5
        gains = (2.0 ** rng.uniform(-0.5, 0.5, (size, 1)) * np.exp(rng.uniform(-0.08, 0.08, (size, 3))))[rank::world]
        if self.meter_samples:
            assert self.exposure_key is not None
            gains = gains * np.asarray([[sample_meter_gain(it, self.exposure_key)] for it in items])
        items = [_relight_item(it, g) for it, g in zip(items, gains)]
        return "synth", synth_batch([_flip_item(it) if f else it for it, f in zip(items, flip)])


def sample_meter_gain(it: dict[str, Any], key: float) -> float:
    """The gain that meters a SynthDataset item's photo as ``predict`` meters a photo: ``metered_gain`` of the
    linear values behind its LDR photo (the paper's tonemap of the HDR photo, clipped, decoded again), so clipped
    pixels count at the clip level; 1 for an item without its HDR photo."""
    if "hdr" not in it:
        return 1.0
    ldr = np.clip(np.asarray(tonemap(it["hdr"][:3])), 0.0, 1.0).transpose(1, 2, 0)
    return metered_gain(decode_ldr(ldr, "paper"), key)


def _relight_item(it: dict[str, Any], gain: np.ndarray) -> dict[str, Any]:
    """Exposure / white balance of a SynthDataset item: the HDR photo, global map and probes scaled by
    ``gain (3,)`` (the light, not the albedo), the LDR input re-tonemapped from the scaled HDR photo."""
    if "hdr" not in it:
        return it

    g = torch.as_tensor(gain, dtype=torch.float32)[:, None, None]
    out = dict(it)
    out["hdr"] = it["hdr"][:3] * g
    out["image"] = tonemap(out["hdr"]).clamp(0.0, 1.0)
    for k in ("global", "probes"):
        if k in it:
            out[k] = it[k][..., :3, :, :] * g
    return out


def _flip_item(it: dict[str, Any]) -> dict[str, Any]:
    """Mirror a SynthDataset item left-right: image buffers, normals' x, panoramas in azimuth, K, pixels, roll."""
    out = dict(it)
    for k in ("image", "hdr", "albedo", "normal", "plane_distance", "depth", "shadow"):
        if k in it:
            out[k] = it[k].flip(-1)
    if "normal" in it:
        out["normal"] = out["normal"].clone()
        out["normal"][0] = -out["normal"][0]
    for k in ("global", "probes"):
        if k in it:
            out[k] = it[k].flip(-1)
    w = it["image"].shape[-1]
    K = it["K"].clone()
    K[0, 2] = w - 1 - K[0, 2]
    out["K"] = K
    pix = it["probe_pixels"].clone()
    pix[:, 0] = w - 1 - pix[:, 0]
    out["probe_pixels"] = pix
    out["roll"] = -it["roll"]
    if "sun" in it:
        s = it["sun"].clone()
        s[0] = -s[0]
        out["sun"] = s
    return out


# ----------------------------------------------------------------------------------------- metrics


@torch.no_grad()
def evaluate_lighting(model: SolidNet, batches: list[dict[str, torch.Tensor]]) -> dict[str, float]:
    """Global-lighting metrics over ``batches``: sky L1 (log1p); for skies whose truth has a visible
    sun: found rate of the default detector in the prediction, median angular error (degrees, found
    ones), median azimuth / elevation errors, median predicted / true sun energy, and the sun head's
    own direction error (``head_err_deg``, every such sky); for skies without one: their count
    (``sunless``) and the fraction where the detector finds a sun in the prediction (``false_suns``)."""
    model.eval()
    dev = next(model.parameters()).device
    l1, found, ang, daz, del_, ratio, n_sun, head, n_none, false = [], 0, [], [], [], [], 0, [], 0, 0
    for b in batches:
        b = {k: v.cpu() for k, v in b.items()}
        out = {
            k: v.cpu()
            for k, v in model.inet(
                b["image"].to(dev), intrinsics=False, K=b["K"].to(dev), pitch=b["pitch"].to(dev), roll=b["roll"].to(dev)
            ).items()
        }
        l1.append(float((out["sky_log"] - torch.log1p(b["sky"].clamp_min(0))).abs().mean()))
        for i in range(b["image"].shape[0]):
            det = detect_sun(out["sky"][i].permute(1, 2, 0).numpy())
            if b["sun_visible"][i] < 0.5:
                n_none += 1
                false += int(det.found)
                continue
            n_sun += 1
            t = b["sun_dir"][i].numpy().astype(np.float64)
            if "sun_dir" in out:
                head.append(math.degrees(float(direction_errors(out["sun_dir"][i].double().numpy(), t)[0])))
            if not det.found:
                continue
            found += 1
            e = sun_error(det.direction, t)
            ang.append(e.angle_deg)
            daz.append(e.azimuth_deg)
            del_.append(e.elevation_deg)
            pd = torch.as_tensor(det.direction, dtype=torch.float32)[None]
            e_p = sun_energy(out["sky"][i : i + 1], pd).sum()
            e_t = sun_energy(b["sky"][i : i + 1], b["sun_dir"][i : i + 1]).sum()
            ratio.append(float(e_p / e_t.clamp_min(1e-9)))
    med = lambda v: float(np.median(v)) if v else float("nan")  # noqa: E731
    return {
        "sky_l1": float(np.mean(l1)) if l1 else float("nan"),
        "suns": n_sun,
        "sun_found_rate": found / n_sun if n_sun else float("nan"),
        "sun_err_deg": med(ang),
        "sun_az_err_deg": med(daz),
        "sun_el_err_deg": med(del_),
        "sun_energy_ratio": med(ratio),
        "head_err_deg": med(head),
        "sunless": n_none,
        "false_suns": false / n_none if n_none else float("nan"),
    }


# ----------------------------------------------------------------------------------------- trainer


RESUME_FIXED = (
    "model",
    "model_overrides",
    "init",
    "seed",
    "batch_size",
    "lr",
    "lr_halve_every",
    "probes",
    "teacher_geometry",
)
"""Settings a resumed run must share with the stored one; the others (data folders, stage lengths, the
crop fraction, logging) may change, and the batches after the resumption follow the new values."""


@torch.no_grad()
def evaluate_sun(net: torch.nn.Module, batches: list[dict[str, torch.Tensor]]) -> dict[str, float]:
    """The sun network's figures on sun-stage batches (:meth:`solidkit.model.suncrops.SunCropBank.batch`):
    median angular / azimuth / elevation error (degrees) of its direction over crops with a sun, the
    balanced accuracy of its visibility at 0.5, and ``score = err / 90 + (1 - balanced accuracy)``."""
    dirs, true, vis, prob = [], [], [], []
    for b in batches:
        out = net(b["image"], b["K"], b["pitch"], b["roll"])
        dirs.append(out["sun_dir"].cpu())
        prob.append(out["sun_visible"].cpu())
        true.append(b["sun_dir"].cpu())
        vis.append(b["sun_visible"].cpu() > 0.5)
    d, t, v, p = torch.cat(dirs), torch.cat(true), torch.cat(vis), torch.cat(prob)
    m: dict[str, float] = {"suns": float(v.sum()), "sunless": float((~v).sum())}
    if v.any():
        err, daz, delv = (torch.rad2deg(e) for e in direction_errors(d[v].double(), t[v].double()))
        m.update(
            head_err_deg=float(err.median()), sun_az_err_deg=float(daz.median()), sun_el_err_deg=float(delv.median())
        )
    rates = [float((p[v] >= 0.5).float().mean())] if v.any() else []
    rates += [float((p[~v] < 0.5).float().mean())] if (~v).any() else []
    m["vis_balanced_accuracy"] = float(np.mean(rates))
    m["score"] = m.get("head_err_deg", 90.0) / 90.0 + (1.0 - m["vis_balanced_accuracy"])
    return m


def _changed_settings(old: dict[str, Any], new: dict[str, Any]) -> list[str]:
    out = []
    for k in sorted(set(old) | set(new)):
        a, b = old.get(k), new.get(k)
        if isinstance(a, dict) and isinstance(b, dict) and k in STAGES:
            out += [f"{k}.{kk}" for kk in sorted(set(a) | set(b)) if a.get(kk) != b.get(kk)]
        elif a != b:
            out.append(k)
    return out


def _dist_info() -> tuple[int, int, int]:
    return int(os.environ.get("RANK", 0)), int(os.environ.get("WORLD_SIZE", 1)), int(os.environ.get("LOCAL_RANK", 0))


class Trainer:
    """Runs (or resumes) the stages of a :class:`TrainConfig` (see module docstring)."""

    def __init__(self, cfg: TrainConfig, *, log: Callable[[str], None] | None = None, progress: bool = True) -> None:
        self.cfg = cfg
        self.out = Path(cfg.out)
        self.log = log or (lambda m: print(m, file=sys.stderr, flush=True))
        self.progress = progress
        self.rank, self.world, local = _dist_info()
        if self.world > 1 and not torch.distributed.is_initialized():
            backend = "nccl" if cfg.device.startswith("cuda") else "gloo"
            torch.distributed.init_process_group(backend)
        if cfg.device.startswith("cuda"):
            if not torch.cuda.is_available():
                raise InputError("--device cuda: no CUDA device is available to torch")
            self.device = torch.device("cuda", local if self.world > 1 else 0)
            torch.cuda.set_device(self.device)
        else:
            self.device = torch.device(cfg.device)
        torch.set_num_threads(max(1, int(cfg.threads)))
        torch.manual_seed(cfg.seed)
        self.model = SolidNet(cfg.model_config())
        if cfg.init:
            init = Path(cfg.init)
            try:  # a training state (RUN/last.pt) or a model checkpoint
                payload = torch.load(init, map_location="cpu", weights_only=True)
            except Exception:
                payload = None
            if isinstance(payload, dict) and payload.get("format") == "solidkit.train_state":
                state = payload["model"]
            else:
                state = load_checkpoint(init)["state_dict"]
            own = self.model.state_dict()
            fit = {k: v for k, v in state.items() if k in own and own[k].shape == v.shape}
            self.model.load_state_dict(fit, strict=False)
            fresh = sorted(set(own) - set(fit))
            if fresh:
                self.log(
                    f"init {init.name}: {len(fit)} tensors copied, {len(fresh)} fresh ({', '.join(fresh[:6])}"
                    f"{', ...' if len(fresh) > 6 else ''})"
                )
        self.model.to(self.device)
        key = self.model.config.exposure_key
        self.data = _Data(
            cfg.crops,
            cfg.crops_exclude,
            cfg.synth,
            cfg.seed,
            key,
            weights=cfg.crop_weights,
            meter_samples=cfg.meter_samples,
        )
        if cfg.crops:
            self.data.refresh()  # bad data folders fail here, before the run folder is created
        self.val = (
            _Data(cfg.val_crops, [], cfg.val_synth, cfg.seed + 1, key, split="val", meter_samples=cfg.meter_samples)
            if (cfg.val_crops or cfg.val_synth)
            else None
        )
        self.state: dict[str, Any] = {
            "stage": STAGES[0],
            "step": 0,
            "best": None,
            "seconds": 0.0,
            "samples": 0,
            "sources": None,
        }
        self._tb: Any = None  # a SummaryWriter once opened (tensorboard is optional)

    # -------------------------------------------------------------- state

    @property
    def is_main(self) -> bool:
        return self.rank == 0

    def _stage_modules(self, stage: str) -> torch.nn.Module:
        # the "sun" stage runs only on a model with a sun network
        sun = cast(torch.nn.Module, self.model.inet.sun)
        return {"sun": sun, "inet": self.model.inet, "pnet": self.model.pnet}[stage]

    def _make_opt(self, stage: str) -> tuple[torch.optim.Optimizer, Any]:
        st = getattr(self.cfg, stage)
        for p in self.model.parameters():
            p.requires_grad_(False)
        for p in self._stage_modules(stage).parameters():
            p.requires_grad_(True)
        if stage == "inet" and self.cfg.sun.steps and self.model.config.sun_net:
            assert self.model.inet.sun is not None
            for p in self.model.inet.sun.parameters():  # trained in its own stage
                p.requires_grad_(False)
        children = dict(self._stage_modules(stage).named_children())
        for name in st.frozen:
            for p in children[name].parameters():
                p.requires_grad_(False)
        opt = torch.optim.Adam([p for p in self._stage_modules(stage).parameters() if p.requires_grad], lr=st.lr)
        sched = torch.optim.lr_scheduler.StepLR(opt, st.lr_halve_every or 10**12, gamma=0.5)
        return opt, sched

    def save_state(self, opt: Any, sched: Any) -> None:
        if not self.is_main:
            return
        import io

        payload = {
            "format": "solidkit.train_state",
            "config": self.cfg.to_toml(),
            "state": json.dumps(self.state),
            "model_config": json.dumps(self.model.config.to_dict()),
            "model": {k: v.detach().cpu() for k, v in self.model.state_dict().items()},
            "optimizer": opt.state_dict(),
            "scheduler": sched.state_dict(),
        }
        buf = io.BytesIO()
        torch.save(payload, buf)
        atomic_write_bytes(self.out / "last.pt", buf.getvalue())

    def load_state(self) -> dict[str, Any] | None:
        path = self.out / "last.pt"
        if not path.is_file():
            return None
        try:
            payload = torch.load(path, map_location="cpu", weights_only=True)
        except Exception as exc:
            raise InputError(
                f"{path}: unreadable training state ({type(exc).__name__}); delete it to start over"
            ) from None
        if payload.get("format") != "solidkit.train_state":
            raise InputError(f"{path}: not a solidkit training state")
        old = tomllib.loads(payload["config"])
        new = tomllib.loads(self.cfg.to_toml())
        changed = _changed_settings(old, new)
        state = json.loads(payload["state"])
        begun = STAGES[: STAGES.index(state["stage"]) + 1]  # a stage not begun yet may still be configured freely
        fixed = [
            k for k in changed if k in RESUME_FIXED or (k.split(".")[0] in begun and k.split(".")[-1] in RESUME_FIXED)
        ]
        if fixed:
            raise InputError(
                f"{self.out}: holds a run with other settings ({', '.join(fixed)}); use another out folder"
            )
        if changed:
            self.log(f"resuming with changed settings: {', '.join(changed)} (later batches follow the new ones)")
        mine = self.model.config.to_dict()
        if "model_config" in payload:
            stored = json.loads(payload["model_config"])
            differ = sorted(k for k in set(stored) | set(mine) if stored.get(k) != mine.get(k))
            if differ:
                raise InputError(
                    f"{self.out}: holds a run of another model configuration ({', '.join(differ)}: "
                    f"the preset changed?); start a new run with init = its last.pt"
                )
        else:
            self.log(
                f"{path}: a training state without its model configuration (an older trainer's); resuming with "
                f"the current preset's: exposure_key {mine['exposure_key']}, sky_footprint {mine['sky_footprint']}"
            )
        self.model.load_state_dict(payload["model"])
        self.state = state
        return payload

    # -------------------------------------------------------------- logging

    def _write_row(self, row: dict[str, Any]) -> None:
        if not self.is_main:
            return
        path = self.out / "metrics.csv"
        cols = [
            "time",
            "stage",
            "step",
            "kind",
            "lr",
            "samples_per_s",
            "total",
            "inet",
            "pnet",
            "albedo",
            "normal",
            "distance",
            "shadow",
            "sky",
            "sun_dir",
            "sun_energy",
            "sun_peak",
            "sun_size",
            "dif",
            "rec",
            "local",
            "tom",
            "sky_l1",
            "suns",
            "sun_found_rate",
            "sun_err_deg",
            "sun_az_err_deg",
            "sun_el_err_deg",
            "sun_energy_ratio",
            "local_l1",
            "score",
            "sun_cos",
            "sun_vis",
            "sun_target_deg",
            "head_err_deg",
            "sunless",
            "false_suns",
            "vis_balanced_accuracy",
        ]
        new = not path.is_file()
        with path.open("a", newline="") as f:
            w = csv.DictWriter(f, fieldnames=cols, extrasaction="ignore")
            if new:
                w.writeheader()
            w.writerow({k: (round(v, 6) if isinstance(v, float) else v) for k, v in row.items()})
        if self._tb is not None:
            tag = "val" if row.get("kind") == "val" else "train"
            gstep = row["step"] + sum(getattr(self.cfg, s).steps for s in STAGES[: STAGES.index(row["stage"])])
            for k, v in row.items():
                if isinstance(v, (int, float)) and k not in ("step",) and math.isfinite(v):
                    self._tb.add_scalar(f"{tag}/{k}", v, gstep)

    def _open_tb(self) -> None:
        if not self.is_main:
            return
        try:
            from torch.utils.tensorboard import SummaryWriter
        except ImportError:  # tensorboard is optional (pip install solidkit[train])
            self.log("tensorboard not installed: logging to metrics.csv only")
            return
        self._tb = SummaryWriter(str(self.out / "tb"))

    # -------------------------------------------------------------- validation

    def _val_batches(self, stage: str) -> list[dict[str, torch.Tensor]]:
        assert self.val is not None
        if not self.val.sources and self.val.crop_dirs:
            self.val.refresh()
        n, bs = self.cfg.val_samples, 4
        if stage == "sun":
            return [self.val.batch("sun", k, min(32, n - k), 0.0)[1] for k in range(0, n, 32)]
        out = []
        for k in range(math.ceil(n / bs)):
            if stage == "inet" or not self.val.synth_index:
                frac = 1.0 if self.val.sources and (k % 2 == 0 or not self.val.synth_index) else 0.0
            else:
                frac = 0.0
            _, b = self.val.batch(stage, k, min(bs, n - k * bs), frac)
            out.append(b)
        return out

    @torch.no_grad()
    def validate(self, stage: str) -> dict[str, Any]:
        """Validation metrics on the held-out split; ``score`` (lower is better) picks ``best.pt``."""
        batches = [{k: v.to(self.device) for k, v in b.items()} for b in self._val_batches(stage)]
        self.model.eval()
        if stage == "sun":
            assert self.model.inet.sun is not None
            m = evaluate_sun(self.model.inet.sun, batches)
            self.model.train()
            return m
        m = evaluate_lighting(self.model, batches)
        if stage == "pnet":
            l1 = []
            for b in batches:
                if "local" not in b:
                    continue
                out = self.model(b["image"], b["K"], b["pixels"], b["pitch"], b["roll"])
                l1.append(float((out["local_log"] - torch.log1p(b["local"].clamp_min(0))).abs().mean()))
            m["local_l1"] = float(np.mean(l1)) if l1 else float("nan")
            m["score"] = m["local_l1"]
        else:
            err = m.get("sun_err_deg", float("nan"))
            rate = m.get("sun_found_rate", float("nan"))
            false = m.get("false_suns", float("nan"))
            m["score"] = (
                m.get("sky_l1", 0.0)
                + (1.0 - (rate if math.isfinite(rate) else 0.0))
                + ((err if math.isfinite(err) else 90.0) / 90.0)
                + (false if math.isfinite(false) else 0.0)
            )
        self.model.train()
        return m

    # -------------------------------------------------------------- the loop

    def _card(self, stage: str, metrics: dict[str, Any] | None) -> dict[str, Any]:
        c = self.cfg
        return {
            "what": "SOLID-Net trained by solidkit train",
            "config_file": c.to_toml(),
            "model": c.model,
            "stage": stage,
            "step": self.state["step"],
            "inet_steps": c.inet.steps,
            "pnet_steps": c.pnet.steps,
            "data": {
                "crops": c.crops,
                "crops_exclude": c.crops_exclude,
                "crop_weights": c.crop_weights,
                "crop_split": self.data.split,
                "crop_sources": len(self.data.sources),
                "synth": c.synth,
                "synth_samples": len(self.data.synth_index),
            },
            "samples_seen": self.state["samples"],
            "seconds": round(self.state["seconds"], 1),
            "hardware": f"{platform.machine()}, {os.cpu_count()} CPU cores, {c.threads} torch thread(s), "
            f"device {self.device}, world size {self.world}",
            "torch": str(torch.__version__),
            "seed": c.seed,
            "validation": metrics or {},
        }

    def run(self, max_minutes: float | None = None) -> dict[str, Any]:
        """Train (resuming from ``RUN/last.pt`` if present); returns the final state."""
        cfg = self.cfg
        if self.is_main:
            self.out.mkdir(parents=True, exist_ok=True)
            atomic_write_text(self.out / "config.toml", cfg.to_toml())
        self._open_tb()
        payload = self.load_state()
        limit = (max_minutes if max_minutes is not None else cfg.max_minutes) * 60.0
        t_start = time.monotonic()
        for stage in STAGES[STAGES.index(self.state["stage"]) :]:
            st = getattr(cfg, stage)
            if self.state["stage"] != stage:
                self.state.update(stage=stage, step=0, best=None)
                payload = None
            opt, sched = self._make_opt(stage)
            if payload is not None:
                opt.load_state_dict(payload["optimizer"])
                sched.load_state_dict(payload["scheduler"])
                payload = None
            module = self._stage_modules(stage)
            ddp = None
            if self.world > 1:
                # crop batches leave the intrinsic decoders unused: DDP must not wait for their gradients
                ddp = torch.nn.parallel.DistributedDataParallel(
                    module,
                    device_ids=[self.device.index] if self.device.type == "cuda" else None,
                    find_unused_parameters=True,
                )
            if self.data.crop_dirs and stage in ("sun", "inet"):
                self.data.refresh(self.state.get("sources"))
                self.state["sources"] = self.data.source_names
            self.model.train()
            bar = _Bar(st.steps, self.state["step"], stage, enabled=self.progress and self.is_main)
            window: list[dict[str, float]] = []
            t_win, n_win = time.monotonic(), 0
            while self.state["step"] < st.steps:
                if limit and time.monotonic() - t_start > limit:
                    self.save_state(opt, sched)
                    bar.close()
                    self.log(
                        f"stopped after {limit / 60:.1f} min at {stage} step {self.state['step']} (resume: run again)"
                    )
                    return self.state
                step = self.state["step"]
                if stage in ("sun", "inet") and self.data.crop_dirs and step and step % cfg.refresh_sources_every == 0:
                    self.data.refresh()
                    self.state["sources"] = self.data.source_names
                t0 = time.monotonic()
                kind, batch = self.data.batch(
                    stage, step, st.batch_size, st.crop_fraction if stage == "inet" else 0.0, self.rank, self.world
                )
                batch = {k: v.to(self.device) for k, v in batch.items()}
                losses = self._step(stage, kind, batch, ddp, st)
                opt.zero_grad(set_to_none=True)
                losses["total"].backward()
                opt.step()
                sched.step()
                n = batch["image"].shape[0] * self.world
                self.state["step"] = step + 1
                self.state["samples"] += n
                self.state["seconds"] += time.monotonic() - t0
                rec = {k: float(v.detach()) for k, v in losses.items()}
                window.append(rec)
                n_win += n
                bar.update(self.state["step"], rec["total"])
                if self.state["step"] % cfg.log_every == 0 or self.state["step"] == st.steps:
                    mean = {k: float(np.mean([r[k] for r in window if k in r])) for k in set().union(*window)}
                    rate = n_win / max(time.monotonic() - t_win, 1e-9)
                    self._write_row(
                        {
                            "time": round(time.time(), 1),
                            "stage": stage,
                            "step": self.state["step"],
                            "kind": kind,
                            "lr": sched.get_last_lr()[0],
                            "samples_per_s": rate,
                            "sun_target_deg": self.sun_target_deg(),
                            **mean,
                        }
                    )
                    if not bar.enabled and self.is_main:
                        self.log(
                            f"{stage} {self.state['step']}/{st.steps} total {mean['total']:.4f} {rate:.2f} samples/s"
                        )
                    window, t_win, n_win = [], time.monotonic(), 0
                last = self.state["step"] == st.steps
                if self.val is not None and self.is_main and (self.state["step"] % cfg.val_every == 0 or last):
                    m = self.validate(stage)
                    self._write_row(
                        {"time": round(time.time(), 1), "stage": stage, "step": self.state["step"], "kind": "val", **m}
                    )
                    self.log(
                        f"validation {stage} {self.state['step']}: "
                        + ", ".join(f"{k} {v:.3g}" for k, v in m.items() if isinstance(v, float))
                    )
                    best = self.state.get("best")
                    if best is None or m["score"] < best:
                        self.state["best"] = m["score"]
                        save_checkpoint(self.model, self.out / f"best_{stage}.pt", self._card(stage, m), half=True)
                if self.state["step"] % cfg.checkpoint_every == 0 or last:
                    self.save_state(opt, sched)
                if self.world > 1:
                    torch.distributed.barrier()
            bar.close()
            if (
                stage == STAGES[-1]
                or (stage == "inet" and cfg.pnet.steps == 0)
                or (stage == "sun" and not (cfg.inet.steps or cfg.pnet.steps))
            ):
                break
            self.state.update(stage=STAGES[STAGES.index(stage) + 1], step=0, best=None)
            self.save_state(*self._make_opt(self.state["stage"]))
        if self.is_main:
            save_checkpoint(self.model, self.out / "model.pt", self._card(self.state["stage"], None), half=True)
        if self._tb is not None:
            self._tb.close()
        self.state["done"] = True
        return self.state

    def sun_target_deg(self) -> float:
        """Width of the sun-direction target at the current I-Net step (``TrainConfig.sun_target_deg``)."""
        widths = [float(v) for v in self.cfg.sun_target_deg]
        if len(widths) == 1:
            return widths[0]
        span = self.cfg.sun_target_anneal_steps or self.cfg.inet.steps
        if self.state["stage"] == "sun":
            span = self.cfg.sun_target_anneal_steps or self.cfg.sun.steps
        t = min(1.0, self.state["step"] / max(1, span)) if self.state["stage"] in ("sun", "inet") else 1.0
        return widths[0] * (widths[1] / widths[0]) ** t

    def _step(
        self, stage: str, kind: str, batch: dict[str, torch.Tensor], ddp: Any, st: StageConfig
    ) -> dict[str, torch.Tensor]:
        cfg = self.model.config
        if stage == "sun":
            net = ddp if ddp is not None else self.model.inet.sun
            assert net is not None
            out = net(batch["image"], batch["K"], batch["pitch"], batch["roll"])
            terms = sun_terms(
                out,
                batch["sun_dir"],
                batch["sun_visible"],
                batch["sun_energy"],
                batch["sun_size"],
                math.radians(self.sun_target_deg()),
            )
            weighted = {k: v * cfg.loss_weights.get(k, 1.0) for k, v in terms.items()}
            return {**weighted, "total": cast(torch.Tensor, sum(weighted.values()))}
        if stage == "inet":
            inet = ddp if ddp is not None else self.model.inet
            out = inet(
                batch["image"], intrinsics=kind != "crops", K=batch["K"], pitch=batch["pitch"], roll=batch["roll"]
            )
            out["rotation"] = camera_rotation(batch["pitch"], batch["roll"])
            losses = solidnet_losses(
                out,
                {k: v for k, v in batch.items() if k not in ("local",)},
                cfg.loss_weights,
                cfg.loss_variant,
                math.radians(self.sun_target_deg()),
            )
            return {**losses, "total": losses["inet"]}
        # pnet: I-Net frozen; P-Net through the model's forward (its warping), DDP on P-Net only
        g = torch.Generator().manual_seed(self.state["step"])
        pick = torch.randperm(batch["pixels"].shape[1], generator=g)[: st.probes].to(self.device)
        batch["pixels"], batch["local"] = batch["pixels"][:, pick], batch["local"][:, pick]
        geometry = {k: batch[k] for k in ("normal", "distance", "shadow")} if st.teacher_geometry else None
        if ddp is not None:
            self.model.pnet = ddp  # the forward calls self.pnet(x)
        try:
            out = self.model(batch["image"], batch["K"], batch["pixels"], batch["pitch"], batch["roll"], geometry)
        finally:
            if ddp is not None:
                self.model.pnet = ddp.module
        losses = solidnet_losses({k: out[k] for k in ("local_log", "local")}, batch, cfg.loss_weights, cfg.loss_variant)
        return {**losses, "total": losses["pnet"]}


class _Bar:
    """A rich progress bar on stderr (only on a terminal; otherwise the trainer logs lines)."""

    def __init__(self, total: int, start: int, stage: str, enabled: bool = True) -> None:
        self.enabled = enabled and sys.stderr.isatty()
        if not self.enabled:
            return
        from rich.console import Console
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

        self.p = Progress(
            TextColumn(f"{stage}"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("loss {task.fields[loss]}"),
            TimeRemainingColumn(),
            console=Console(stderr=True),
        )
        self.task = self.p.add_task(stage, total=total, completed=start, loss="-")
        self.p.start()

    def update(self, step: int, loss: float) -> None:
        if self.enabled:
            self.p.update(self.task, completed=step, loss=f"{loss:.4f}")

    def close(self) -> None:
        if self.enabled:
            self.p.stop()


def best_visibility_threshold(probs: np.ndarray, truth: np.ndarray, grid: np.ndarray | None = None) -> dict[str, Any]:
    """The threshold on sun-visibility probabilities ``probs (N,)`` that best matches ``truth (N,)`` (bool).

    Over ``grid`` (default 0.05, 0.10, ..., 0.95, 0.97, 0.99) the threshold with the highest balanced accuracy (the
    mean of the rate of suns kept in skies that have one and of skies left sunless that have none) wins;
    ties go to the one closest to 0.5. Returns ``threshold``, ``balanced_accuracy``, the same at 0.5 and
    the counts of skies with / without a sun.
    """
    p, t = np.asarray(probs, dtype=np.float64), np.asarray(truth, dtype=bool)
    if t.all() or not t.any():
        raise InputError("tuning the visibility threshold needs skies with and without a sun")
    grid = (
        np.r_[np.round(np.arange(0.05, 0.951, 0.05), 2), 0.97, 0.99]
        if grid is None
        else np.asarray(grid, dtype=np.float64)
    )
    balanced = lambda th: 0.5 * (float(np.mean(p[t] >= th)) + float(np.mean(p[~t] < th)))  # noqa: E731
    scores = np.array([balanced(th) for th in grid])
    best = np.flatnonzero(scores >= scores.max() - 1e-12)
    th = float(grid[best[np.argmin(np.abs(grid[best] - 0.5))]])
    return {
        "threshold": th,
        "balanced_accuracy": round(balanced(th), 4),
        "balanced_accuracy_at_0.5": round(balanced(0.5), 4),
        "with_sun": int(t.sum()),
        "without_sun": int((~t).sum()),
    }


@torch.no_grad()
def tune_visibility_threshold(
    model: SolidNet, batches: list[dict[str, torch.Tensor]], grid: np.ndarray | None = None
) -> dict[str, Any]:
    """:func:`best_visibility_threshold` of ``model``'s sun-visibility output on crop ``batches``
    (:func:`crop_batch`) of a *validation* split (never the test split)."""
    if not model.config.sun_visibility:
        raise InputError("the model has no sun-visibility output to tune")
    model.eval()
    dev = next(model.parameters()).device
    probs, truth = [], []
    for b in batches:
        out = model.inet(
            b["image"].to(dev), intrinsics=False, K=b["K"].to(dev), pitch=b["pitch"].to(dev), roll=b["roll"].to(dev)
        )
        probs.append(out["sun_visible"].cpu().numpy())
        truth.append(b["sun_visible"].cpu().numpy() > 0.5)
    return best_visibility_threshold(np.concatenate(probs), np.concatenate(truth), grid)


def set_visibility_threshold(model: SolidNet, threshold: float) -> None:
    """Use ``threshold`` for the sun-visibility decision in evaluation (stored in the config, hence in checkpoints)."""
    model.reconfigure(sun_visibility_threshold=float(threshold))


def model_from_state(path: str | os.PathLike) -> SolidNet:
    """The model of a training state (``RUN/last.pt``, resumable) or of a model checkpoint, in eval mode."""
    path = Path(path)
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:
        raise InputError(f"{path}: unreadable checkpoint ({type(exc).__name__})") from None
    if not isinstance(payload, dict) or payload.get("format") != "solidkit.train_state":
        return SolidNet.from_checkpoint(path)
    model = SolidNet(SolidNetConfig.from_dict(json.loads(payload["model_config"])))
    model.load_state_dict(payload["model"])
    model.card = {
        "what": "SOLID-Net trained by solidkit train",
        "state": json.loads(payload["state"]),
        "config_file": payload["config"],
    }
    return model.eval()


def export_checkpoint(
    src: str | os.PathLike,
    dst: str | os.PathLike,
    extra: dict[str, Any] | None = None,
    visibility_threshold: float | None = None,
) -> dict[str, Any]:
    """Write the model checkpoint or training state ``src`` to ``dst`` (float16 weights) with ``extra`` merged
    into its card, and ``dst``'s ``.card.json`` beside it (sha256, bytes, config, parameters, card); returns that
    JSON. ``visibility_threshold`` (e.g. from :func:`tune_visibility_threshold`) replaces the configured one."""
    model = model_from_state(src)
    if visibility_threshold is not None:
        set_visibility_threshold(model, visibility_threshold)
    card = {**getattr(model, "card", {}), **(extra or {})}
    dst = Path(dst)
    save_checkpoint(model, dst, card, half=True)
    doc = {
        "file": dst.name,
        "sha256": sha256_file(dst),
        "bytes": dst.stat().st_size,
        "conventions_version": CONVENTIONS_VERSION,
        "format_version": CHECKPOINT_VERSION,
        "config": model.config.to_dict(),
        "parameters": model.num_parameters,
        "card": card,
    }
    atomic_write_text(dst.with_suffix(".card.json"), json.dumps(doc, indent=1, default=str))
    return doc
