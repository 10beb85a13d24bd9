"""Evaluate SOLID-Net and baselines on a real test set or a synthetic split, with the paper's metrics.

An evaluation set is a list of :class:`EvalItem` (one photo, its probe pixels and the truth), made
from a real test set (:func:`items_from_testset`, ``testset.json`` of :mod:`solidkit.testset`) or
from a synthetic dataset (:func:`items_from_synth`, :class:`solidkit.synth.dataset.SynthDataset`).
Both give the same metrics (:mod:`solidkit.metrics`): synthetic probes are turned into
LDR probes by :func:`~solidkit.metrics.simulate_ldr_probe`, so one table holds the
sim-to-real gap.

Methods (:class:`Method`), each predicting a global map and/or local probes per item:

- ``solidnet`` (and any checkpoint given with a name): :meth:`SolidNet.predict`;
- ``global-as-local``: the model's own global map used as every local probe (what ignoring
  spatial variation gives);
- ``mean-sky`` / ``mean-probe``: the mean truth global map / local probe of the *other* scenes
  of the evaluation set (leave-one-scene-out), the same for every item; real LDR probes are
  linearised (sRGB decoding) before averaging;
- the model's ablations (paper Table 2 P-Net inputs, LENet_reg) when their checkpoints are given.

:func:`evaluate` returns a JSON-able result: one record per (method, item) with the sun errors
under both recipes, the global MAE and one record per probe, plus summaries (median and mean with
scene-bootstrap 95 % intervals, no-sun rates) and timings.
"""

from __future__ import annotations

import json
import math
import os
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, cast

import numpy as np

from solidkit import metrics as M
from solidkit.envmap.coords import direction_from_angles, rotation_from_ypr
from solidkit.envmap.io import read_exr, read_image, read_ldr, srgb_decode, tonemap, validate_panorama
from solidkit.envmap.perspective import intrinsics_from_fov, perspective_crop
from solidkit.envmap.resample import resize, rotate
from solidkit.envmap.sun import detect_sun, luminance
from solidkit.errors import InputError
from solidkit.fsutil import atomic_write_text
from solidkit.model import SolidNet
from solidkit.synth.relight import OBJECTS as RELIGHT_OBJECTS
from solidkit.testset.build import load_testset

__all__ = [
    "EvalItem",
    "ItemPrediction",
    "Method",
    "ModelMethod",
    "GlobalAsLocal",
    "MeanBaseline",
    "local_truth_linear",
    "items_from_synth",
    "items_from_testset",
    "checked_testset",
    "items_from_panoramas",
    "SHIPPED_PANORAMAS",
    "default_methods",
    "load_model",
    "shipped_ablations",
    "save_json",
    "evaluate",
    "evaluate_item",
    "summarise_records",
    "METRICS",
    "Evaluation",
    "evaluate_testset",
]


def checked_testset(
    root: str | os.PathLike, *, allow_invalid: bool = False, log: Callable[[str], Any] | None = None
) -> dict[str, Any]:
    """The record of a test set that results are computed on: its path, ``dataset_version``, whether it passed
    :func:`solidkit.testset.validate.validate_testset` (flags still open for review are counted, not problems)
    and its problems. A test set that fails is refused (:class:`InputError` naming the first problems) unless
    ``allow_invalid``, then used with a warning through ``log``."""
    from solidkit.testset.validate import validate_testset

    found = validate_testset(root)
    problems = [p for p in found if p.check != "flags"]
    flagged = len(found) - len(problems)
    ts = load_testset(root) if not any(p.check == "schema" for p in problems) else None
    record = {
        "path": str(root),
        "dataset_version": None if ts is None else ts.dataset_version,
        "valid": not problems,
        "problems": [str(p) for p in problems[:20]],
        "flagged": flagged,
    }
    if problems:
        more = f" (and {len(problems) - 3} more)" if len(problems) > 3 else ""
        head = "; ".join(str(p) for p in problems[:3]) + more
        if not allow_invalid:
            raise InputError(
                f"{root}: the test set fails validation ({len(problems)} problem(s): {head}); "
                "fix it (solidkit testset validate) or pass --allow-invalid"
            )
        if log:
            log(f"warning: {root} fails validation ({len(problems)} problem(s): {head}); used anyway (--allow-invalid)")
    return record


@dataclass
class EvalItem:
    """One photo with its truth (numpy, channels last; frames as in docs/conventions.md).

    Attributes
    ----------
    scene, id : str
        Scene id and item id (equal for a real test set; ``"<index>"`` for synthetic samples).
    image : (H, W, 3) float32
        LDR photo in [0, 1], the model's input, encoded as ``encoding`` says
        (:func:`solidkit.envmap.io.decode_ldr`: ``"srgb"`` for camera photos, ``"paper"`` for photos made
        by the paper's tonemap: synthetic samples and panorama crops).
    K : (3, 3)
        Intrinsics of ``image`` (pixels, OpenCV).
    pitch, roll : float
        Camera pitch and roll, radians.
    pixels : (N, 2)
        Probe pixels ``(x, y)`` in ``image``.
    probe_ids : list of str
    sun : (3,) or None
        True sun direction in the photo's panorama frame; ``None`` when the truth has no sun.
    global_hdr : (Hp, 2Hp, 3) or None
        True global HDR map (synthetic; the camera position's bracket for a real set), with
        ``global_valid (Hp, 2Hp)`` (unsaturated pixels) or None (all valid).
    probes_ldr : list of (Hp, 2Hp, 3)
        LDR probes, sRGB-encoded in [0, 1]; ``probes_saturated`` their clipped pixels ``(Hp, 2Hp)``.
    probes_hdr : list of (Hp, 2Hp, 3) or None
        HDR probes where they exist (synthetic; a real bracket).
    source : str
        ``"real"`` or ``"synthetic"``.
    encoding : str or (256, 3)
        How ``image`` encodes linear light (above).
    """

    scene: str
    id: str
    image: np.ndarray
    K: np.ndarray
    pitch: float
    roll: float
    pixels: np.ndarray
    probe_ids: list[str]
    sun: np.ndarray | None
    global_hdr: np.ndarray | None
    probes_ldr: list[np.ndarray]
    probes_saturated: list[np.ndarray]
    probes_hdr: list[np.ndarray | None]
    source: str
    global_valid: np.ndarray | None = None
    photo_path: str | None = None
    encoding: str | np.ndarray = "srgb"


@dataclass
class ItemPrediction:
    """What a method predicts for one item: global map and local probes (linear radiance), or None."""

    sky: np.ndarray | None
    local: list[np.ndarray] | None
    seconds: float = 0.0
    extra: dict[str, Any] = field(default_factory=dict)


class Method:
    """A predictor evaluated side by side with the others. Subclasses set ``name``, ``kind``, ``predict``."""

    name: str = "method"
    kind: str = "model"  # "model" | "baseline"
    description: str = ""

    def prepare(self, items: Sequence[EvalItem]) -> None:  # noqa: D401 - hook
        """Called once with the whole evaluation set before any :meth:`predict`."""

    def predict(self, item: EvalItem) -> ItemPrediction:
        raise NotImplementedError


class ModelMethod(Method):
    """A SOLID-Net (or ablation) checkpoint, through :meth:`SolidNet.predict`; caches its predictions.

    A model whose output has no local probes (e.g. ``LENet_reg``) is evaluated on the global map only.
    """

    def __init__(self, name: str, model: Any, description: str = "") -> None:
        self.name, self.model, self.kind = name, model, "model"
        self.description = description or f"{name} ({getattr(model, 'config', None) and model.config.name})"
        self._cache: dict[str, ItemPrediction] = {}

    def predict(self, item: EvalItem) -> ItemPrediction:
        key = f"{item.scene}/{item.id}"
        if key not in self._cache:
            t0 = time.perf_counter()
            h, w = item.image.shape[:2]
            pixels = item.pixels if len(item.pixels) else np.array([[(w - 1) / 2, 0.9 * (h - 1)]])  # global map only
            pred = self.model.predict(
                item.image, pixels, K=item.K, pitch=item.pitch, roll=item.roll, encoding=item.encoding
            )
            local = list(pred.local)[: len(item.probe_ids)] if getattr(pred, "local", None) else None
            self._cache[key] = ItemPrediction(
                pred.sky, local, time.perf_counter() - t0, {"probe_valid": (pred.extra or {}).get("probe_valid")}
            )
        return self._cache[key]


class GlobalAsLocal(Method):
    """The model's global map used as every local probe (ignores spatial variation)."""

    kind = "baseline"

    def __init__(self, base: ModelMethod) -> None:
        self.base = base
        self.name = f"global-as-local ({base.name})" if base.name != "solidnet" else "global-as-local"
        self.description = f"{base.name}'s predicted global map used as every local probe"

    def predict(self, item: EvalItem) -> ItemPrediction:
        p = self.base.predict(item)
        return ItemPrediction(None, [p.sky] * len(item.pixels) if p.sky is not None else None, 0.0)


def local_truth_linear(item: EvalItem, k: int) -> np.ndarray:
    """The true local probe ``k`` of ``item`` in linear units: its HDR probe where one exists, else the LDR
    probe linearised by the sRGB decoding (clipped pixels stay at the clip level)."""
    hdr = item.probes_hdr[k]
    if hdr is not None:
        return hdr
    return srgb_decode(item.probes_ldr[k])


class MeanBaseline(Method):
    """Leave-one-scene-out mean of the truth: ``"sky"`` (global maps) or ``"probe"`` (local probes).

    Every map is first divided by its mean luminance, so that no capture's exposure dominates; the
    metrics are invariant to the overall scale anyway.
    """

    kind = "baseline"

    def __init__(self, what: str) -> None:
        self.what = what
        self.name = f"mean-{what}"
        self.description = (
            f"mean truth {'global map' if what == 'sky' else 'local probe'} of the other scenes (leave-one-scene-out)"
        )
        self._sums: dict[str, tuple[np.ndarray, int]] = {}

    def prepare(self, items: Sequence[EvalItem]) -> None:
        self._sums = {}
        for it in items:
            maps = (
                ([it.global_hdr] if it.global_hdr is not None else [])
                if self.what == "sky"
                else [local_truth_linear(it, k) for k in range(len(it.probes_ldr))]
            )
            for m in maps:
                y = float(luminance(m).mean())
                if y <= 0:
                    continue
                s, n = self._sums.get(it.scene, (np.zeros_like(m, dtype=np.float64), 0))
                self._sums[it.scene] = (s + m / y, n + 1)

    def _mean_without(self, scene: str) -> np.ndarray | None:
        parts = [(s, n) for k, (s, n) in self._sums.items() if k != scene]
        n = sum(p[1] for p in parts)
        return (
            cast(np.ndarray, sum(p[0] for p in parts) / n).astype(np.float32) if n else None
        )  # n > 0: a sum of arrays

    def predict(self, item: EvalItem) -> ItemPrediction:
        mean = self._mean_without(item.scene)
        if mean is None:
            return ItemPrediction(None, None)
        if self.what == "sky":
            return ItemPrediction(mean, None)
        return ItemPrediction(None, [mean] * len(item.pixels))


# ------------------------------------------------------------------------------------- data sources


def items_from_synth(
    root: str | os.PathLike, indices: Iterable[int] | None = None, limit: int | None = None
) -> list[EvalItem]:
    """Evaluation items from a synthetic dataset folder (``solidkit synth dataset``).

    Each sample is its own scene (samples of one city block share no lighting).
    """
    from solidkit.synth.dataset import SynthDataset  # lazy: pulls in torch

    ds = SynthDataset(root, fields=("image", "global", "probes"), indices=indices)
    n = len(ds) if limit is None else min(limit, len(ds))
    if n == 0:
        raise InputError(f"{root}: the synthetic dataset has no samples")
    items = []
    for i in range(n):
        it = ds[i]
        valid = it["probe_valid"].numpy() > 0
        hdr = [p.permute(1, 2, 0).numpy() for p, v in zip(it["probes"], valid) if v]
        sims = [M.simulate_ldr_probe(h) for h in hdr]
        idx = str(int(it["index"]))
        items.append(
            EvalItem(
                scene=f"synth-{idx}",
                id=idx,
                image=it["image"].permute(1, 2, 0).numpy(),
                K=it["K"].numpy().astype(np.float64),
                pitch=float(it["pitch"]),
                roll=float(it["roll"]),
                pixels=it["probe_pixels"].numpy()[valid].astype(np.float64),
                probe_ids=[str(k) for k in np.nonzero(valid)[0]],
                sun=it["sun"].numpy().astype(np.float64) if float(it["sun_found"]) > 0 else None,
                global_hdr=it["global"].permute(1, 2, 0).numpy()[..., :3],
                probes_ldr=[s[0] for s in sims],
                probes_saturated=[s[1] for s in sims],
                probes_hdr=hdr,
                source="synthetic",
                encoding="paper",
                photo_path=str(Path(root) / ds.entries[i]["dir"]),
            )
        )
    return items


SHIPPED_PANORAMAS = Path(__file__).resolve().parents[1] / "assets" / "hdr_panoramas"
"""Real outdoor HDR panoramas shipped with the package (Poly Haven, CC0)."""


PHOTO_MEAN_LDR = 0.21
"""Mean LDR value of the synthetic training photos (median over 12 ``solidkit synth dataset`` samples:
0.11-0.49): a photo cropped from a panorama in other units is exposed to it before the paper's tonemap."""


def _expose_like_training(photo_hdr: np.ndarray, tonemap: Any, target: float = PHOTO_MEAN_LDR) -> np.ndarray:
    """The paper's tonemap of ``s * photo_hdr`` with ``s`` chosen (bisection on ``log s``) so that the
    LDR photo's mean is ``target``; float32 in [0, 1]."""
    lo, hi = -30.0, 30.0
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        if float(np.mean(tonemap(photo_hdr * math.exp(mid)))) < target:
            lo = mid
        else:
            hi = mid
    return np.clip(tonemap(photo_hdr * math.exp(0.5 * (lo + hi))), 0, 1).astype(np.float32)


def items_from_panoramas(
    paths: Sequence[str | os.PathLike],
    yaws: int = 8,
    pitch_deg: float = 5.0,
    hfov_deg: float = 60.0,
    size: tuple[int, int] = (320, 240),
    height: int = 128,
) -> list[EvalItem]:
    """Virtual photos cropped from real HDR panoramas (as Hold-Geoffroy et al. evaluate), global map only.

    Per panorama, ``yaws`` photos at equally spaced headings (``pitch_deg`` up, ``hfov_deg`` wide,
    ``size`` pixels, LDR by the paper's tonemap as the synthetic photos are, after an exposure that
    gives them the training photos' mean brightness, :data:`PHOTO_MEAN_LDR`). Truth: the panorama
    turned into each photo's panorama frame and resized to ``height`` (energy-preserving), and its
    sun from the default detector (``None`` when it finds none: an occluded or overcast sky). No
    local probes. Each panorama is one scene, named by its file's stem (``FOLDER/STEM`` where stems repeat, as
    in the ``NNNNNN/scene.exr`` of rendered sources).
    """
    K = intrinsics_from_fov(math.radians(hfov_deg), *size)
    items = []
    stems = [Path(p).stem for p in paths]
    for path in paths:
        pano, _ = read_image(path)
        validate_panorama(pano, str(path))
        pano = pano[..., :3]
        sun = detect_sun(pano, "core")
        small = resize(pano, height)
        p = Path(path)
        name = p.stem if stems.count(p.stem) == 1 else f"{p.parent.name}/{p.stem}"
        for k in range(yaws):
            yaw = 2 * math.pi * k / yaws
            R = np.asarray(rotation_from_ypr(yaw, math.radians(pitch_deg), 0.0))
            photo = _expose_like_training(perspective_crop(pano, R, size, K=K), tonemap)
            Ry = np.asarray(rotation_from_ypr(yaw))
            items.append(
                EvalItem(
                    scene=name,
                    id=f"{name}@{round(math.degrees(yaw)):03d}",
                    image=photo,
                    K=K,
                    pitch=math.radians(pitch_deg),
                    roll=0.0,
                    pixels=np.zeros((0, 2)),
                    probe_ids=[],
                    sun=(Ry.T @ sun.direction) if sun.found else None,
                    global_hdr=rotate(small, Ry.T),
                    probes_ldr=[],
                    probes_saturated=[],
                    probes_hdr=[],
                    source="real-hdr-crops",
                    encoding="paper",
                    photo_path=str(path),
                )
            )
    return items


def _mask(path: Path) -> np.ndarray:
    m = read_ldr(path)
    return (m[..., 0] if m.ndim == 3 else m) > 0.5


def items_from_testset(root: str | os.PathLike) -> list[EvalItem]:
    """Evaluation items from a real test set folder (``testset.json``, :mod:`solidkit.testset.schema`).

    The truth global map is the HDR bracket at the photo camera's position when the test set has
    one (its saturated pixels excluded from the global MAE); probes are the 256x128 LDR probes with
    their saturation masks.
    """
    root = Path(root)
    ts = load_testset(root)  # format, schema and conventions versions checked, one-line errors
    items = []
    for sc in ts.scenes:
        if not sc.probes:
            continue
        image = read_ldr(root / sc.photo)[..., :3]
        sun = None
        if sc.sun.found and sc.sun.azimuth_deg is not None and sc.sun.elevation_deg is not None:
            sun = np.asarray(
                direction_from_angles(math.radians(sc.sun.azimuth_deg), math.radians(sc.sun.elevation_deg))
            )
        glob, gvalid = None, None
        if sc.camera is not None and sc.camera.images.hdr:
            glob = read_exr(root / sc.camera.images.hdr)[0][..., :3]
            gvalid = ~_mask(root / sc.camera.images.saturation)
        items.append(
            EvalItem(
                scene=sc.id,
                id=sc.id,
                image=image,
                K=np.asarray(sc.K, dtype=np.float64),
                pitch=math.radians(sc.pitch_deg),
                roll=math.radians(sc.roll_deg),
                pixels=np.asarray([p.pixel for p in sc.probes], dtype=np.float64),
                probe_ids=[p.id for p in sc.probes],
                sun=sun,
                global_hdr=glob,
                global_valid=gvalid,
                probes_ldr=[read_ldr(root / p.ldr)[..., :3] for p in sc.probes],
                probes_saturated=[_mask(root / p.images.saturation) for p in sc.probes],
                probes_hdr=[read_exr(root / p.hdr)[0][..., :3] if p.hdr else None for p in sc.probes],
                source="real",
                photo_path=str(root / sc.photo),
            )
        )
    if not items:
        raise InputError(f"{root}: the test set has no scene with probes")
    return items


# ------------------------------------------------------------------------------------------ methods


def load_model(path: str | os.PathLike | None) -> Any:
    """A SOLID-Net checkpoint (``None``: the shipped one), 1 torch thread on CPU."""
    return SolidNet.from_checkpoint(path)


def shipped_ablations() -> dict[str, Path]:
    """Checkpoints shipped beside the default one (``solidkit/model/checkpoints/*.pt``), by file stem:
    the model's ablations (e.g. the paper's sky decoder without the sun head), evaluated side by side."""
    from solidkit.model.solidnet import DEFAULT_CHECKPOINT  # lazy: pulls in torch

    return {
        p.stem: p for p in sorted(DEFAULT_CHECKPOINT.parent.glob("*.pt")) if p.resolve() != DEFAULT_CHECKPOINT.resolve()
    }


def default_methods(
    model: Any, name: str = "solidnet", extra: dict[str, Any] | None = None, baselines: bool = True
) -> list[Method]:
    """The model, the named extra checkpoints (ablations), and the non-learned baselines."""
    main = ModelMethod(name, model, f"{name}: {getattr(model, 'card', {}).get('what', 'SOLID-Net checkpoint')}")
    methods: list[Method] = [main]
    methods += [ModelMethod(k, v) for k, v in (extra or {}).items()]
    if baselines:
        methods += [GlobalAsLocal(main), MeanBaseline("sky"), MeanBaseline("probe")]
    return methods


# ------------------------------------------------------------------------------------------ metrics

METRICS: dict[str, tuple[str, str, bool]] = {
    # key: (label, unit, higher is better)
    "azimuth_deg/paper": ("sun azimuth error (paper recipe)", "°", False),
    "elevation_deg/paper": ("sun elevation error (paper recipe)", "°", False),
    "angle_deg/paper": ("sun angular error (paper recipe)", "°", False),
    "azimuth_deg/core": ("sun azimuth error (default detector)", "°", False),
    "elevation_deg/core": ("sun elevation error (default detector)", "°", False),
    "angle_deg/core": ("sun angular error (default detector)", "°", False),
    "global_mae": ("global map MAE (normalised HDR)", "", False),
    "local_ssim": ("local SSIM (LDR probes)", "", True),
    "local_mae": ("local MAE (LDR probes)", "", False),
    "local_ssim_tonemap": ("local SSIM (HDR, paper tonemap)", "", True),
    "local_mae_log1p": ("local MAE (HDR, log1p)", "", False),
    # with --relight (solidkit.finetune.relight): objects rendered under the method's probe and the truth's
    "relight_angle_deg": ("relit objects: shading direction error", "°", False),
    **{
        f"relight_{what}/{obj}": (f"relit {obj.replace('_', ' ')}: {label}", "", higher)
        for obj in RELIGHT_OBJECTS
        for what, label, higher in (("si_rmse", "si-RMSE", False), ("ssim", "SSIM", True))
    },
}


def evaluate_item(method: Method, item: EvalItem) -> dict[str, Any]:
    """All metrics of ``method`` on ``item``: a JSON-able record (see the module docstring)."""
    t0 = time.perf_counter()
    pred = method.predict(item)
    rec: dict[str, Any] = {
        "method": method.name,
        "scene": item.scene,
        "item": item.id,
        "source": item.source,
        "truth_sun": item.sun is not None,
    }
    if pred.sky is not None:
        for recipe in M.SUN_METHODS:
            det = M.find_sun(pred.sky, recipe)
            rec[f"sun_{recipe}"] = {
                "azimuth_deg": det.azimuth_deg,
                "elevation_deg": det.elevation_deg,
                "found": bool(det.found),
            }
            if item.sun is not None:
                rec[f"sun_{recipe}"].update(M.sun_error(det.direction if det.found else None, item.sun).to_json())
        if item.global_hdr is not None:
            rec["global_mae"] = M.global_mae(pred.sky, item.global_hdr, item.global_valid)
    if pred.local is not None:
        probes = []
        for k, pid in enumerate(item.probe_ids):
            r: dict[str, Any] = {"probe": pid}
            r.update(M.local_ldr_metrics(pred.local[k], item.probes_ldr[k], item.probes_saturated[k]))
            if item.probes_hdr[k] is not None and item.source == "synthetic":
                r.update(M.local_hdr_metrics(pred.local[k], item.probes_hdr[k]))
            probes.append(r)
        rec["probes"] = probes
    rec["seconds_predict"] = pred.seconds
    rec["seconds"] = time.perf_counter() - t0
    return rec


def _metric_values(records: Sequence[dict[str, Any]], key: str) -> tuple[list[float], list[str]]:
    vals, groups = [], []
    if key.startswith("local_"):
        sub = {
            "local_ssim": "ssim",
            "local_mae": "mae",
            "local_ssim_tonemap": "ssim_tonemap",
            "local_mae_log1p": "mae_log1p",
        }[key]
        for r in records:
            for p in r.get("probes", []):
                if sub in p:
                    vals.append(p[sub])
                    groups.append(r["scene"])
    elif key.startswith("relight_"):
        what, _, obj = key[len("relight_") :].partition("/")
        for r in records:
            for e in r.get("relight", []):
                v = e.get("shading_angle_deg") if what == "angle_deg" else e["objects"].get(obj, {}).get(what)
                if v is not None:
                    vals.append(v)
                    groups.append(r["scene"])
    elif "/" in key:
        err, recipe = key.split("/")
        for r in records:
            s = r.get(f"sun_{recipe}")
            if s is not None and r["truth_sun"] and s.get(err) is not None:
                vals.append(s[err])
                groups.append(r["scene"])
    else:
        for r in records:
            if r.get(key) is not None:
                vals.append(r[key])
                groups.append(r["scene"])
    return vals, groups


def summarise_records(records: Sequence[dict[str, Any]], seed: int = 0) -> dict[str, Any]:
    """Per metric: median and mean with scene-bootstrap 95 % intervals; per recipe: the no-sun rate."""
    out: dict[str, Any] = {}
    for key in METRICS:
        vals, groups = _metric_values(records, key)
        if vals:
            out[key] = M.summarise(vals, groups, seed=seed)
    for recipe in M.SUN_METHODS:
        with_truth = [r for r in records if r["truth_sun"] and f"sun_{recipe}" in r]
        if with_truth:
            found = sum(bool(r[f"sun_{recipe}"]["found"]) for r in with_truth)
            out[f"no_sun_rate/{recipe}"] = {
                "n": len(with_truth),
                "no_sun": len(with_truth) - found,
                "rate": 1 - found / len(with_truth),
            }
    return out


def evaluate(
    items: Sequence[EvalItem],
    methods: Sequence[Method],
    log: Callable[[str], Any] | None = None,
    seed: int = 0,
) -> dict[str, Any]:
    """Run every method on every item; returns ``{"records", "summary", "methods", "timing", "items"}``."""
    for m in methods:
        m.prepare(items)
    records: list[dict[str, Any]] = []
    per_scene: dict[str, float] = {}
    t_all = time.perf_counter()
    for i, item in enumerate(items):
        t0 = time.perf_counter()
        for m in methods:
            records.append(evaluate_item(m, item))
        per_scene[item.scene] = per_scene.get(item.scene, 0.0) + time.perf_counter() - t0
        if log is not None:
            log(
                f"  [{i + 1}/{len(items)}] {item.scene}: {len(item.probe_ids)} probes, {time.perf_counter() - t0:.1f} s"
            )
    summary = {m.name: summarise_records([r for r in records if r["method"] == m.name], seed) for m in methods}
    secs = np.array(list(per_scene.values()))
    return {
        "methods": [{"name": m.name, "kind": m.kind, "description": m.description} for m in methods],
        "items": [
            {
                "scene": it.scene,
                "item": it.id,
                "source": it.source,
                "probes": it.probe_ids,
                "truth_sun": it.sun is not None,
                "truth_global": it.global_hdr is not None,
            }
            for it in items
        ],
        "records": records,
        "summary": summary,
        "timing": {
            "seconds_total": time.perf_counter() - t_all,
            "scenes": len(per_scene),
            "seconds_per_scene_median": float(np.median(secs)) if secs.size else None,
            "seconds_per_scene_mean": float(secs.mean()) if secs.size else None,
            "methods": len(methods),
        },
    }


def save_json(path: str | os.PathLike, result: dict[str, Any]) -> None:
    """Write an evaluation result as JSON (atomic)."""
    atomic_write_text(path, json.dumps(result, indent=1, default=float, allow_nan=True))


# ------------------------------------------------------------------------------------ from Python


@dataclass(frozen=True)
class Evaluation:
    """The numbers of one evaluation, as ``solidkit eval`` reports them (:func:`evaluate_testset`).

    Attributes
    ----------
    result : dict
        :func:`evaluate`'s JSON-able result (``methods``, ``items``, ``records``, ``summary``,
        ``timing``): what ``results.json`` holds for one dataset.
    """

    result: dict[str, Any]

    @property
    def methods(self) -> list[str]:
        """The methods' names, the model first (then e.g. ``global-as-local``, ``mean-sky``, ``mean-probe``)."""
        return [m["name"] for m in self.result["methods"]]

    @property
    def records(self) -> list[dict[str, Any]]:
        """One record per (method, item): the sun errors under both recipes, the global MAE, one record per probe."""
        return self.result["records"]

    @property
    def summary(self) -> dict[str, dict[str, Any]]:
        """Per method, per metric (a key of :data:`METRICS`): ``n``, ``median``, ``mean``, ``median_ci``,
        ``mean_ci``; per recipe ``no_sun_rate/<recipe>``: ``n``, ``no_sun``, ``rate``."""
        return self.result["summary"]

    def _metric(self, metric: str, method: str | None) -> dict[str, Any] | None:
        if metric not in METRICS:
            raise KeyError(f"unknown metric {metric!r}; one of {', '.join(METRICS)}")
        name = self.methods[0] if method is None else method
        if name not in self.summary:
            raise KeyError(f"no method {name!r} in this evaluation; one of {', '.join(self.methods)}")
        return self.summary[name].get(metric)

    def median(self, metric: str, method: str | None = None) -> float | None:
        """The median of ``metric`` (a key of :data:`METRICS`; sun errors in degrees) for ``method``
        (default: the model), as in the report's headline table; ``None`` where it was not measured
        (e.g. the local SSIM of ``mean-sky``)."""
        s = self._metric(metric, method)
        return None if s is None else s["median"]

    def interval(self, metric: str, method: str | None = None) -> tuple[float | None, float | None]:
        """The scene-bootstrap 95 % interval of :meth:`median`; ``(None, None)`` where it was not measured."""
        s = self._metric(metric, method)
        return (None, None) if s is None else tuple(s["median_ci"])

    def no_sun_rate(self, method: str | None = None, recipe: str = "core") -> float | None:
        """The fraction of photos with a true sun where ``method`` (default: the model) predicts none,
        under ``recipe`` (``"paper"`` or ``"core"``, the default detector); ``None`` without a true sun."""
        s = self.summary[self.methods[0] if method is None else method].get(f"no_sun_rate/{recipe}")
        return None if s is None else s["rate"]


def evaluate_testset(
    testset: str | os.PathLike,
    checkpoint: str | os.PathLike | None = None,
    *,
    baselines: bool = True,
    ablations: bool = False,
    limit: int | None = None,
    log: Callable[[str], Any] | None = None,
    seed: int = 0,
) -> Evaluation:
    """Evaluate a SOLID-Net checkpoint on a real test set: the numbers ``solidkit eval --testset TESTSET
    --model CHECKPOINT`` reports for it, without writing a report.

    Parameters
    ----------
    testset : path
        A test set folder (``testset.json``, ``solidkit testset build``).
    checkpoint : path, optional
        A SOLID-Net checkpoint (``.pt``); ``None``: the shipped one.
    baselines : bool
        Also the non-learned baselines (``global-as-local``, ``mean-sky``, ``mean-probe``).
    ablations : bool
        Also every checkpoint shipped beside the default one (as ``solidkit eval`` does), named ``ablation: <stem>``.
    limit : int, optional
        Only the first ``limit`` scenes with probes.
    log : callable, optional
        Called with one progress line per photo.
    seed : int
        Seed of the bootstrap intervals.
    """
    items = items_from_testset(testset)[:limit]
    extra = {f"ablation: {k}": load_model(p) for k, p in shipped_ablations().items()} if ablations else None
    methods = default_methods(load_model(checkpoint), extra=extra, baselines=baselines)
    return Evaluation(evaluate(items, methods, log=log, seed=seed))
