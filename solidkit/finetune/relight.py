"""Relighting in ``solidkit eval --relight``: virtual objects lit by each method's probe and by the truth.

At every probe of every photo, the objects of :data:`solidkit.synth.relight.OBJECTS` (a diffuse sphere, a
glossy sphere, a procedural bunny) are path-traced on a shadow-catching ground plane
(:func:`solidkit.synth.relight.render_objects`, seen from the direction the photo's camera sees the probe's
pixel from) under

- each method's probe: its local probe, or its global map where it predicts no local probe (``mean-sky``,
  a global-only ablation; ``lit_by`` says which);
- the truth: the test set's HDR probe where a bracket exists, otherwise its LDR probe linearised (sRGB
  decoding; clipped pixels, the sun among them, stay at their clip level, so the truth is too dim there:
  ``truth`` says which). ``truth_saturated_fraction``: for an LDR truth, the share of its pixels clipped
  (the test set's saturation mask); 0 for an HDR truth (whose own clipping the test set does not record).

The renders of a method and of the truth are compared by :mod:`solidkit.metrics.relight` (scale-invariant
RMSE and SSIM over the pixels that see the object or the plane, so the shadow counts; the angle between the
probes' shading directions) and stored per probe in the evaluation record (``record["relight"]``), so that
:func:`solidkit.finetune.evaluate.summarise_records` gives them the same scene-bootstrap intervals as every
other metric. For the figures, the renders of the model, of its global map (``global-as-local``) and of the
truth are composited into the photo (differential rendering, :func:`solidkit.synth.relight.composite`),
each exposed so that its virtual ground matches the photo's ground at the probe's pixel.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from solidkit import metrics as M
from solidkit.envmap.io import srgb_decode, srgb_encode
from solidkit.finetune.evaluate import EvalItem, GlobalAsLocal, Method, local_truth_linear, summarise_records
from solidkit.synth.relight import (
    OBJECTS,
    ObjectRender,
    composite,
    relight_view,
    render_objects,
    renderer_name,
    square_spp,
)

__all__ = ["TRUTH_KINDS", "RelightSettings", "RelitScene", "relight_evaluation"]

TRUTH_KINDS = {
    "hdr": "HDR probe",
    "ldr": "LDR probe linearised (no bracket: clipped pixels stay clipped)",
}


@dataclass(frozen=True)
class RelightSettings:
    """spp: samples per pixel (rounded up to a square, :func:`~solidkit.synth.relight.square_spp`); size: the
    object renders' side (pixels); objects: names of :data:`~solidkit.synth.relight.OBJECTS`; seed: of every
    render (the truth is rendered once more with ``seed + 1``: the Monte Carlo noise floor of the scores)."""

    spp: int = 64
    size: int = 64
    objects: tuple[str, ...] = OBJECTS
    seed: int = 0


@dataclass
class RelitScene:
    """One photo relit for the figure: ``panels[column][object]`` are sRGB composites ``(H, W, 3)`` in [0, 1].

    Columns: ``"prediction"`` (the model's local probes), ``"truth"``, ``"global"`` (the model's global map
    as the probe); ``names[column]``: what lit it; ``angles[column]``: shading-direction error per probe
    (degrees; 0 for the truth); ``si_rmse[column]``: per probe, per object; ``truth``: per probe, a key of
    :data:`TRUTH_KINDS`; ``objects``: the rows' object names; ``renders[column]``: per probe, the object
    renders (:class:`~solidkit.synth.relight.ObjectRender`, one per object).
    """

    item: EvalItem
    panels: dict[str, list[np.ndarray]] = field(default_factory=dict)
    names: dict[str, str] = field(default_factory=dict)
    angles: dict[str, list[float]] = field(default_factory=dict)
    si_rmse: dict[str, list[dict[str, float]]] = field(default_factory=dict)
    truth: list[str] = field(default_factory=list)
    objects: tuple[str, ...] = OBJECTS
    renders: dict[str, list[list[ObjectRender]]] = field(default_factory=dict)


def _lighting(method: Method, item: EvalItem, k: int) -> tuple[np.ndarray | None, str]:
    pred = method.predict(item)
    if isinstance(method, GlobalAsLocal):
        return (pred.local[k] if pred.local is not None else None), "global map"
    if pred.local is not None and k < len(pred.local) and pred.local[k] is not None:
        return pred.local[k], "local probe"
    return pred.sky, "global map"


def _scores(renders: Sequence[ObjectRender], truth: Sequence[ObjectRender]) -> dict[str, dict[str, float]]:
    out = {}
    for r, t in zip(renders, truth):
        mask = t.hit_mask
        out[r.name] = {
            "si_rmse": M.si_rmse(r.with_object, t.with_object, mask),
            "ssim": M.render_ssim(r.with_object, t.with_object, mask),
            "seconds": r.seconds,
        }
    return out


def _composite_all(photo_linear: np.ndarray, per_probe: Sequence[Sequence[ObjectRender]], pixels: np.ndarray) -> list:
    """One sRGB composite per object, with that object placed at every probe."""
    out = []
    for j in range(len(per_probe[0]) if per_probe else 0):
        img = photo_linear
        for k, renders in enumerate(per_probe):
            img, _ = composite(img, renders[j], pixels[k])
        out.append(srgb_encode(np.clip(img, 0.0, 1.0)).astype(np.float32))
    return out


def relight_evaluation(
    result: dict[str, Any],
    items: Sequence[EvalItem],
    methods: Sequence[Method],
    settings: RelightSettings | None = None,
    *,
    figures: int | None = None,
    log: Callable[[str], Any] | None = None,
    seed: int = 0,
) -> list[RelitScene]:
    """Relight every probe of ``items`` under every method of ``methods`` and the truth; add the scores to
    ``result`` (:func:`solidkit.finetune.evaluate.evaluate`'s, of the same items and methods) in place:
    ``record["relight"]`` (one entry per probe), the summaries recomputed (``seed``: of their bootstrap) and
    ``result["relight"]`` (settings, renderer, timing, and ``noise_floor``: the truth's renders against the
    truth's with another seed, summarised like the methods). Returns the :class:`RelitScene` of the first
    ``figures`` photos with probes (default: all)."""
    cfg = settings or RelightSettings()
    by_key = {(r["method"], r["scene"], r["item"]): r for r in result["records"]}
    model = methods[0]
    global_method = next((m for m in methods if isinstance(m, GlobalAsLocal) and m.base is model), None)
    seconds: list[float] = []
    floor: dict[str, tuple[list[float], list[str]]] = {}
    kinds = {"hdr": 0, "ldr": 0}
    n_clipped = 0
    scenes: list[RelitScene] = []
    t_all = time.perf_counter()
    with_probes = [it for it in items if len(it.probe_ids)]
    if log is not None and renderer_name().startswith("scalar"):
        n = sum(len(it.probe_ids) for it in with_probes) * (len(methods) + 2) * (len(cfg.objects) + 1)
        log(
            f"  warning: Mitsuba's {renderer_name()} renders >100x slower than llvm_ad_rgb (about 0.37 s per sample "
            f"per pixel of a 64x64 object): {n} renders at {square_spp(cfg.spp)} spp; install libLLVM 19 "
            "(make system-deps) or lower --relight-spp"
        )
    for i, item in enumerate(with_probes):
        t0 = time.perf_counter()
        keep = figures is None or len(scenes) < figures
        shown: dict[str, list[list[ObjectRender]]] = {"prediction": [], "truth": [], "global": []}
        relit = RelitScene(item, objects=cfg.objects)
        for k, pid in enumerate(item.probe_ids):
            view = relight_view(item.pixels[k], item.K, item.pitch, item.roll, size=cfg.size)
            kind = "hdr" if item.probes_hdr[k] is not None else "ldr"
            kinds[kind] += 1
            clipped = float(np.mean(item.probes_saturated[k])) if kind == "ldr" else 0.0
            n_clipped += clipped > 0
            relit.truth.append(kind)
            truth_probe = local_truth_linear(item, k)
            truth = render_objects(truth_probe, view, cfg.objects, spp=cfg.spp, seed=cfg.seed)
            again = render_objects(truth_probe, view, cfg.objects, spp=cfg.spp, seed=cfg.seed + 1)
            seconds += [r.seconds for r in truth + again]
            shown["truth"].append(truth)
            for name, v in _scores(again, truth).items():
                for metric in ("si_rmse", "ssim"):
                    floor.setdefault(f"{metric}/{name}", ([], []))
                    floor[f"{metric}/{name}"][0].append(v[metric])
                    floor[f"{metric}/{name}"][1].append(item.scene)
            for m in methods:
                probe, lit_by = _lighting(m, item, k)
                if probe is None:
                    continue
                renders = render_objects(probe, view, cfg.objects, spp=cfg.spp, seed=cfg.seed)
                seconds += [r.seconds for r in renders]
                entry = {
                    "probe": pid,
                    "lit_by": lit_by,
                    "truth": kind,
                    "truth_saturated_fraction": clipped,
                    "shading_angle_deg": M.shading_angle_deg(probe, truth_probe),
                    "objects": _scores(renders, truth),
                }
                by_key[(m.name, item.scene, item.id)].setdefault("relight", []).append(entry)
                for column, who in (("prediction", model), ("global", global_method)):
                    if m is who:
                        shown[column].append(renders)
                        relit.angles.setdefault(column, []).append(entry["shading_angle_deg"])
                        relit.si_rmse.setdefault(column, []).append(
                            {o: v["si_rmse"] for o, v in entry["objects"].items()}
                        )
                        relit.names[column] = f"{m.name} ({lit_by})"
        if keep:
            photo = srgb_decode(np.clip(item.image, 0.0, 1.0)).astype(np.float32)
            relit.names["truth"] = "truth (" + ", ".join(sorted({TRUTH_KINDS[t] for t in relit.truth})) + ")"
            relit.angles["truth"] = [0.0] * len(item.probe_ids)
            for column, per_probe in shown.items():
                if len(per_probe) == len(item.probe_ids):
                    relit.panels[column] = _composite_all(photo, per_probe, item.pixels)
                    relit.renders[column] = per_probe
            scenes.append(relit)
        if log is not None:
            log(f"  relit [{i + 1}/{len(with_probes)}] {item.scene}: {time.perf_counter() - t0:.1f} s")
    names = [m.name for m in methods]
    result["summary"] = {n: summarise_records([r for r in result["records"] if r["method"] == n], seed) for n in names}
    secs = np.asarray(seconds)
    result["relight"] = {
        "objects": list(cfg.objects),
        "spp": square_spp(cfg.spp),
        "size": [cfg.size, cfg.size],
        "renderer": renderer_name(),
        "truth": kinds,
        "truth_with_saturated_pixels": int(n_clipped),
        "renders": int(secs.size),
        "seconds_per_object_median": float(np.median(secs)) if secs.size else None,
        "seconds_per_object_max": float(secs.max()) if secs.size else None,
        "seconds_total": time.perf_counter() - t_all,
        "noise_floor": {k: M.summarise(v, g, seed=seed) for k, (v, g) in floor.items()},
    }
    return scenes
