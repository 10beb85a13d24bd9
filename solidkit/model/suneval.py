"""The sun on limited-field-of-view crops with a known sun: a fixed protocol, the model and its baselines.

Protocol (after Hold-Geoffroy et al. 2017, who crop SUN360 panoramas): every panorama is seen by a
camera at ``PITCH_DEG`` up with a ``HFOV_DEG`` horizontal field of view, turned so that the true sun sits
at each of ``RELATIVE_AZIMUTHS_DEG`` from the view's forward direction (in view, beside, behind); a
panorama without a sun is seen at the same yaws from its own forward direction. Crops are metered as a
camera's auto-exposure would (:func:`solidkit.synth.panocrops.metered_gain`), with no jitter or flip, so
the figures are a pure function of the panoramas.

Predictors (each returns a direction in the camera's level panorama frame and whether it says "sun"):
the model's sun (network, moved onto an image blob where its config says so, with its cones), and two
baselines that need no training: ``constant`` (straight ahead at a fixed elevation, always "sun") and
``brightest_column`` (the azimuth of the image column of highest mean luminance at a fixed elevation,
always "sun").
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from solidkit.envmap.coords import angles_from_direction, direction_from_angles, rotation_from_ypr
from solidkit.envmap.perspective import project_to_pixels, rays_through_pixels
from solidkit.envmap.sun import luminance
from solidkit.metrics.sun import direction_errors
from solidkit.model.suncrops import source_sun
from solidkit.model.sununcertainty import calibrate_cone_scales
from solidkit.synth.panocrops import CropConfig, View, render_view, view_direction

__all__ = [
    "RELATIVE_AZIMUTHS_DEG",
    "PITCH_DEG",
    "HFOV_DEG",
    "BASELINE_ELEVATION_DEG",
    "ProtocolCrop",
    "protocol_crops",
    "predict_model",
    "predict_constant",
    "predict_brightest_column",
    "sun_figures",
    "evaluate_sun_crops",
    "calibrate_sun",
]

RELATIVE_AZIMUTHS_DEG = (0.0, 30.0, -30.0, 90.0, -90.0, 150.0)
PITCH_DEG = 5.0
HFOV_DEG = 60.0
BASELINE_ELEVATION_DEG = 20.0
"""Elevation of the constant and brightest-column baselines (about the median sun of the training panoramas)."""


@dataclass(frozen=True)
class ProtocolCrop:
    """A crop of the protocol: ``image (H, W, 3)`` tonemapped, ``K``, ``pitch``, ``roll`` (radians), the source
    ``name``, the relative azimuth asked for, and the truth: ``sun (3,)`` (camera's level panorama frame;
    zero without a sun), ``visible`` and ``in_view`` (the sun projects inside the image)."""

    image: np.ndarray
    K: np.ndarray
    pitch: float
    roll: float
    name: str
    relative_azimuth_deg: float
    sun: np.ndarray
    visible: bool
    in_view: bool


def protocol_crops(
    sources: list[Any],
    size: tuple[int, int] = (240, 320),
    *,
    exposure_key: float = 0.18,
    relative_azimuths_deg: tuple[float, ...] = RELATIVE_AZIMUTHS_DEG,
    pitch_deg: float = PITCH_DEG,
    hfov_deg: float = HFOV_DEG,
) -> list[ProtocolCrop]:
    """The protocol's crops of ``sources`` (:class:`solidkit.synth.panocrops.Source`; the sun is the
    catalogue's where the source has one, else the crop path's detector on its lighting)."""
    cfg = CropConfig(width=size[1], height=size[0], exposure_key=exposure_key)
    out = []
    for src in sources:
        scene, light = src.load()
        sun = source_sun(light, getattr(src, "sun", None))
        base = math.degrees(float(angles_from_direction(sun.direction)[0])) if sun.visible else 0.0
        for rel in relative_azimuths_deg:
            yaw = math.radians(base - rel)
            view = View(yaw, math.radians(pitch_deg), 0.0, math.radians(hfov_deg), np.ones(3), False)
            image, K, roll, _ = render_view(scene, view, cfg)
            d = view_direction(sun.direction, view) if sun.visible else np.zeros(3)
            in_view = False
            if sun.visible:
                cam = np.asarray(rotation_from_ypr(0.0, view.pitch, 0.0)).T @ d
                x, y, front = project_to_pixels(K.astype(np.float64), cam)
                in_view = bool(front) and 0 <= float(x) < size[1] and 0 <= float(y) < size[0]
            out.append(
                ProtocolCrop(
                    image, K, view.pitch, roll, src.name, rel, d.astype(np.float32), bool(sun.visible), in_view
                )
            )
    return out


def _batch(crops: list[ProtocolCrop]) -> tuple[torch.Tensor, ...]:
    image = torch.as_tensor(np.stack([c.image for c in crops]), dtype=torch.float32).permute(0, 3, 1, 2)
    K = torch.as_tensor(np.stack([c.K for c in crops]), dtype=torch.float32)
    pitch = torch.as_tensor([c.pitch for c in crops], dtype=torch.float32)
    roll = torch.as_tensor([c.roll for c in crops], dtype=torch.float32)
    return image, K, pitch, roll


@torch.no_grad()
def predict_model(model: Any, crops: list[ProtocolCrop], batch_size: int = 16) -> dict[str, np.ndarray]:
    """The model's sun on ``crops``: ``direction (N, 3)``, ``says_sun (N,)``, ``visible_prob``, ``on_blob`` and
    ``cone_deg (N, 2)`` (68 % / 90 %); only the sun branch runs (a model with ``config.sun_net``)."""
    inet = model.inet
    inet.eval()
    keys = ("sun_dir", "sun_visible", "sun_on_blob", "sun_cone_deg")
    acc: dict[str, list[np.ndarray]] = {k: [] for k in keys}
    for s in range(0, len(crops), batch_size):
        image, K, pitch, roll = _batch(crops[s : s + batch_size])
        out = dict(inet.sun(image, K, pitch, roll))
        inet.finish_sun(out, image, (K, pitch, roll))
        for k in keys:
            acc[k].append(out[k].float().numpy() if k != "sun_on_blob" else out[k].numpy())
    prob = np.concatenate(acc["sun_visible"])
    return {
        "direction": np.concatenate(acc["sun_dir"]),
        "visible_prob": prob,
        "says_sun": prob >= model.config.sun_visibility_threshold,
        "on_blob": np.concatenate(acc["sun_on_blob"]),
        "cone_deg": np.concatenate(acc["sun_cone_deg"]),
    }


def predict_constant(crops: list[ProtocolCrop], elevation_deg: float = BASELINE_ELEVATION_DEG) -> dict[str, np.ndarray]:
    """Straight ahead at ``elevation_deg``, always "sun"."""
    d = np.asarray(direction_from_angles(0.0, math.radians(elevation_deg)), np.float32)
    return {"direction": np.tile(d, (len(crops), 1)), "says_sun": np.ones(len(crops), bool)}


def predict_brightest_column(
    crops: list[ProtocolCrop], elevation_deg: float = BASELINE_ELEVATION_DEG
) -> dict[str, np.ndarray]:
    """The azimuth of the image column of highest mean luminance (its ray at the principal point's row,
    turned by the camera's pitch and roll) at ``elevation_deg``, always "sun"."""
    dirs = []
    for c in crops:
        col = int(np.argmax(luminance(c.image).mean(axis=0)))
        ray = np.asarray(
            rays_through_pixels(c.K.astype(np.float64), np.array([col + 0.0]), np.array([float(c.K[1, 2])]))
        )[0]
        az, _ = angles_from_direction(np.asarray(rotation_from_ypr(0.0, c.pitch, c.roll)) @ ray)
        dirs.append(direction_from_angles(float(az), math.radians(elevation_deg)))
    return {"direction": np.asarray(dirs, np.float32), "says_sun": np.ones(len(crops), bool)}


def sun_figures(crops: list[ProtocolCrop], pred: dict[str, np.ndarray]) -> dict[str, Any]:
    """Figures of a predictor on ``crops``: crops with a sun (``suns``) and without (``sunless``); ``found``
    (says "sun" where there is one); the median angular / azimuth / elevation error (degrees) over the
    found suns and over all suns (``angular_all_deg``: the direction is read even where it says no sun),
    the median angular error by where the sun is (in the image, beside: within 100° of the view, behind);
    ``false_suns`` over sunless crops; with cones, their coverage of the found suns' errors."""
    vis = np.array([c.visible for c in crops])
    in_view = np.array([c.in_view for c in crops])
    rel = np.abs(np.array([c.relative_azimuth_deg for c in crops]))
    true = np.stack([c.sun for c in crops]).astype(np.float64)
    d = np.asarray(pred["direction"], np.float64)
    says = np.asarray(pred["says_sun"], bool)
    err, daz, delv = (np.degrees(e) for e in direction_errors(d, np.where(vis[:, None], true, d)))
    found = vis & says
    med = lambda x: float(np.median(x)) if len(x) else None  # noqa: E731
    f: dict[str, Any] = {
        "suns": int(vis.sum()),
        "sunless": int((~vis).sum()),
        "found": int(found.sum()),
        "found_rate": float(found.sum() / vis.sum()) if vis.any() else None,
        "angular_deg": med(err[found]),
        "azimuth_deg": med(daz[found]),
        "elevation_deg": med(delv[found]),
        "angular_all_deg": med(err[vis]),
        "in_view_deg": med(err[vis & in_view]),
        "in_view_n": int((vis & in_view).sum()),
        "in_view_max_deg": float(err[vis & in_view].max()) if (vis & in_view).any() else None,
        "beside_deg": med(err[vis & ~in_view & (rel <= 100)]),
        "behind_deg": med(err[vis & ~in_view & (rel > 100)]),
        "false_suns": int((~vis & says).sum()),
        "false_sun_rate": float((~vis & says).sum() / (~vis).sum()) if (~vis).any() else None,
    }
    if "cone_deg" in pred and found.any():
        cones = np.asarray(pred["cone_deg"], np.float64)[found]
        f["cone_coverage"] = [float(np.mean(err[found] <= cones[:, k])) for k in range(cones.shape[1])]
        f["cone_median_deg"] = [float(np.median(cones[:, k])) for k in range(cones.shape[1])]
    if "on_blob" in pred:
        f["on_blob"] = int(np.asarray(pred["on_blob"])[found].sum())
    return f


def evaluate_sun_crops(model: Any, crops: list[ProtocolCrop]) -> dict[str, dict[str, Any]]:
    """:func:`sun_figures` of the model (as configured; with ``sun_in_image`` also the network alone) and of
    the two baselines on ``crops``: ``{method: figures}``."""
    out = {"model": sun_figures(crops, predict_model(model, crops))}
    if model.config.sun_in_image:
        saved = model.reconfigure(sun_in_image=False)
        try:
            out["model, network only"] = sun_figures(crops, predict_model(model, crops))
        finally:
            model.reconfigure(**saved.to_dict())
    out["constant"] = sun_figures(crops, predict_constant(crops))
    out["brightest column"] = sun_figures(crops, predict_brightest_column(crops))
    return out


GATE_GRID_DEG = (15.0, 30.0, 60.0)
"""Blob gates tried by :func:`calibrate_sun` (besides no in-image sun at all)."""
PROMOTE_GRID = (1e-6, 1e-4, 0.01, 0.02, 0.05, 0.1, 0.15, 0.2, 0.3, 0.4, 0.5)
"""Probabilities from which a sun-like blob alone may make the sun visible, tried by :func:`calibrate_sun`."""


def _balanced_accuracy(prob: np.ndarray, vis: np.ndarray, t: float) -> float:
    rates = ([float(np.mean(prob[vis] >= t))] if vis.any() else []) + (
        [float(np.mean(prob[~vis] < t))] if (~vis).any() else []
    )
    return float(np.mean(rates))


def calibrate_sun(
    model: Any, domains: dict[str, list[ProtocolCrop]], levels: tuple[float, ...] = (0.68, 0.90)
) -> dict[str, Any]:
    """The sun settings of a checkpoint from validation crops of one or more ``domains`` (e.g. real and rendered
    panoramas; each counts equally, whatever its number of crops):

    1. the visibility threshold of the highest balanced accuracy (mean over domains) on a 0.05-0.99 grid;
    2. the in-image sun (:mod:`solidkit.model.imagesun`): off, or the gate of :data:`GATE_GRID_DEG` with the
       lowest median angular error of the found suns (mean over domains);
    3. with the in-image sun on, the probability from which a sun-like blob alone makes the sun visible
       (``sun_blob_visibility``, :data:`PROMOTE_GRID` or off): the highest balanced accuracy of the decisions,
       kept only where it beats the network alone;
    4. at those settings, the conformal 68 % / 90 % cone scales (:mod:`solidkit.model.sununcertainty`) on
       the found suns of all domains, each domain weighing equally (weighted conformal quantile): a few real
       crops are not drowned by many rendered ones.

    Returns ``{"threshold", "balanced_accuracy", "sun_in_image", "gate_deg", "blob_visibility",
    "balanced_accuracy_with_blob", "cone_scale", "n", "trials", "blob_trials"}``;
    the model is left as it was.
    """
    saved = model.reconfigure(sun_cone_scale=(), sun_in_image=False, sun_blob_visibility=0.0)
    try:
        probs = {d: predict_model(model, c)["visible_prob"] for d, c in domains.items()}
        vis = {d: np.array([x.visible for x in c]) for d, c in domains.items()}
        grid = np.round(np.arange(0.05, 0.991, 0.01), 2)
        acc = [np.mean([_balanced_accuracy(probs[d], vis[d], t) for d in domains]) for t in grid]
        threshold = float(grid[int(np.argmax(acc))])
        model.reconfigure(sun_visibility_threshold=threshold)
        trials = []
        for on, gate in [(False, saved.sun_blob_gate_deg)] + [(True, g) for g in GATE_GRID_DEG]:
            model.reconfigure(sun_in_image=on, sun_blob_gate_deg=gate)
            errs = [sun_figures(c, predict_model(model, c))["angular_deg"] for c in domains.values()]
            trials.append(
                {
                    "sun_in_image": on,
                    "gate_deg": gate,
                    "angular_deg": [e for e in errs],
                    "score": float(np.mean([90.0 if e is None else e for e in errs])),
                }
            )
        best = min(trials, key=lambda t: t["score"])
        model.reconfigure(sun_in_image=best["sun_in_image"], sun_blob_gate_deg=best["gate_deg"])
        promote, promote_acc = 0.0, float(max(acc))
        promote_trials = []
        if best["sun_in_image"]:
            for p in [g for g in PROMOTE_GRID if g < threshold]:
                model.reconfigure(sun_blob_visibility=p)
                says = {d: predict_model(model, c)["says_sun"] for d, c in domains.items()}
                a = float(np.mean([_balanced_accuracy(says[d].astype(float), vis[d], 0.5) for d in domains]))
                promote_trials.append({"sun_blob_visibility": p, "balanced_accuracy": a})
                if a > promote_acc + 1e-9:
                    promote, promote_acc = p, a
            model.reconfigure(sun_blob_visibility=promote)
        errs, radii = [], []
        for c in domains.values():
            pred = predict_model(model, c)
            found = np.array([x.visible for x in c]) & pred["says_sun"]
            true = np.stack([x.sun for x in c]).astype(np.float64)
            e = np.degrees(direction_errors(np.asarray(pred["direction"], np.float64), true)[0])
            errs.append(e[found])
            radii.append(pred["cone_deg"][found])  # uncalibrated: the radii themselves
        err, rad = np.concatenate(errs), np.concatenate(radii)
        weights = np.concatenate([np.full(len(e), 1.0 / len(e)) for e in errs if len(e)])
        scale = calibrate_cone_scales(err, rad, levels, weights) if len(err) >= 10 else ()
    finally:
        model.reconfigure(**saved.to_dict())
    return {
        "threshold": threshold,
        "balanced_accuracy": float(max(acc)),
        "sun_in_image": best["sun_in_image"],
        "gate_deg": best["gate_deg"],
        "blob_visibility": promote,
        "balanced_accuracy_with_blob": promote_acc,
        "blob_trials": promote_trials,
        "cone_scale": tuple(float(s) for s in scale),
        "trials": trials,
        "n": {d: {"crops": len(c), "suns": int(vis[d].sum())} for d, c in domains.items()}
        | {"found_suns": int(len(err))},
    }
