"""Measure an alignment against a virtual campaign's truth (tests and benchmarks only).

The truth (:class:`solidkit.synth.campaign.CampaignTruth`) is read here and nowhere in the
processing. Figures:

- **sun per capture**: angle between the chosen direction (level frame of the sun-frame product)
  and the truth sun in that frame (``R(0, recorded pitch, recorded roll) · sun_body``: the
  product was levelled with the recorded gravity); captures where the truth says the sun is
  visible but none was chosen are *misses*; a chosen direction more than 2° off is a *false sun*
  (a glint or surface accepted);
- **scene sun** in the photo's panorama frame against ``SceneTruth.sun_azimuth/elevation_deg``;
- **yaw** of every capture against ``yaw_true = yaw_c - photo yaw`` (truth ``R_pano_from_body``);
- **PSNR** of the aligned 256x128 LDR probe against the truth probe (HDR, photo panorama frame)
  in the paper's tonemap (conventions §5), the LDR converted to radiance with the campaign's
  sensor constant and the shot's exposure; beside it the same probe aligned with the true yaw
  (on the metadata's levelling), with the true rotation (yaw and levelling: the chain's upper
  bound) and with the compass yaw (the peers: perfect and naive alignment); and the truth
  probe's own noise: measured when it was rendered (``truth_noise_db``: two independent halves
  of its samples, :mod:`solidkit.synth.truth_probes`; truths of recipe 2 and later) and the rough
  ceiling :func:`noise_floor_db` (its own 3x3 median: counts edges too);
- **probe pixels**: the geometry's pixel (relative pose) against the truth's pixel (degrees,
  pixels, fraction of the photo width).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import cv2
import numpy as np

from solidkit.align.captures import captures_of, levelling_of, load_normal_panorama
from solidkit.align.schema import level_to_pano, load_alignment, wrap_deg
from solidkit.capture.manifest import load_manifest
from solidkit.envmap.coords import angles_from_direction, angular_distance, direction_from_angles, rotation_from_ypr
from solidkit.envmap.io import read_exr, read_ldr, srgb_decode, srgb_encode, tonemap
from solidkit.envmap.perspective import rays_through_pixels
from solidkit.envmap.resample import resize
from solidkit.synth.truth_probes import psnr  # one home: the truth probes' noise is measured with it too

__all__ = ["evaluate", "summary", "psnr", "noise_floor_db"]


def noise_floor_db(image: np.ndarray) -> float:
    """PSNR (dB) of a tonemapped image against its own 3x3 median: a bound set by its pixel noise.

    A rendered truth probe carries Monte Carlo noise (speckles from glossy and glass paths); an
    aligned probe averaged down from a larger panorama carries far less, so its PSNR against the
    truth cannot exceed what the truth's own noise allows (measured on virtual campaigns: glass
    scenes 26-27 dB, others 31-35 dB). Edges count as "noise" too, so this is a rough ceiling.
    """
    img = np.asarray(image, np.float32)
    return psnr(img, cv2.medianBlur(img, 3))


def _angle(az1, el1, az2, el2) -> float:
    a = direction_from_angles(math.radians(az1), math.radians(el1))
    b = direction_from_angles(math.radians(az2), math.radians(el2))
    return math.degrees(float(angular_distance(a, b)))


def _radiance(ldr8: np.ndarray, md: dict[str, Any], k_sensor: float) -> np.ndarray:
    lin = np.asarray(srgb_decode(ldr8.astype(np.float32) / 255.0), np.float32)
    gain = (
        k_sensor
        * float(md["exposure_time"])
        * float(md.get("iso") or 100.0)
        / 100.0
        / float(md.get("f_number") or 2.0) ** 2
    )
    return lin / gain


def evaluate(campaign_dir: str | Path, truth_path: str | Path, *, peers: bool = True) -> dict[str, Any]:
    """Per-capture and per-scene errors of ``CAMPAIGN/align/alignment.json`` against the truth (module doc)."""
    campaign = Path(campaign_dir)
    truth = _load_truth(truth_path)
    root = Path(truth_path).parent.parent
    al = load_alignment(campaign)
    manifest = load_manifest(campaign)
    k_sensor = float(truth.radiometry["K_SENSOR"])
    rows: list[dict[str, Any]] = []
    scenes: list[dict[str, Any]] = []
    for st in truth.scenes:
        try:
            sa = al.scene(st.id)
        except KeyError:
            continue
        photo_yaw = st.heading_deg
        srow = {"scene": st.id, "sun_truth": st.sun_found, "sun_found": sa.sun.found, "flags": sa.flags + sa.sun.flags}
        if st.sun_found and sa.sun.found and sa.sun.azimuth_deg is not None:
            srow["sun_error_deg"] = _angle(
                sa.sun.azimuth_deg, sa.sun.elevation_deg, st.sun_azimuth_deg, st.sun_elevation_deg
            )
        scenes.append(srow)
        caps = {c.id: c for c in captures_of(manifest, manifest.scene(st.id))}
        for ct in st.captures:
            try:
                pa = sa.probe(ct.id)
            except KeyError:
                continue
            cs = next((c for c in sa.sun.captures if c.probe == ct.id), None)
            row: dict[str, Any] = {"scene": st.id, "probe": ct.id, "role": pa.role, "flags": list(pa.flags)}
            true_yaw = wrap_deg(ct.yaw_deg - photo_yaw)
            row["yaw_true"] = true_yaw
            row["yaw"] = pa.yaw_deg
            if pa.yaw_deg is not None:
                row["yaw_error_deg"] = abs(wrap_deg(pa.yaw_deg - true_yaw))
            row["compass_error_deg"] = abs(wrap_deg(ct.recorded_heading_deg - photo_yaw - true_yaw))
            row["cues"] = {
                k: (None if c.yaw_deg is None else round(wrap_deg(c.yaw_deg - true_yaw), 3)) for k, c in pa.cues.items()
            }
            # sun in the level frame of the product
            row["sun_visible"] = ct.sun_visible
            if cs is not None:
                row["sun_found"] = cs.found
                if cs.found and ct.sun_body is not None:
                    R = np.asarray(
                        rotation_from_ypr(0.0, math.radians(ct.recorded_pitch_deg), math.radians(ct.recorded_roll_deg))
                    )
                    az, el = (math.degrees(float(v)) for v in angles_from_direction(R @ np.asarray(ct.sun_body)))
                    row["sun_error_deg"] = _angle(cs.azimuth_deg, cs.elevation_deg, az, el)
                    row["false_sun"] = row["sun_error_deg"] > 2.0
                row["miss"] = bool(ct.sun_visible and not cs.found)
                glint = getattr(ct, "glint_body", None)
                if glint is not None:  # a glint of the sun on glass that this capture sees
                    R = np.asarray(
                        rotation_from_ypr(0.0, math.radians(ct.recorded_pitch_deg), math.radians(ct.recorded_roll_deg))
                    )
                    gaz, gel = (math.degrees(float(v)) for v in angles_from_direction(R @ np.asarray(glint)))
                    near = [c for c in cs.candidates if _angle(c.azimuth_deg, c.elevation_deg, gaz, gel) < 2.0]
                    row["glint_candidate"] = bool(near)
                    row["glint_accepted"] = any(c.chosen for c in near)
                    row["glint_reasons"] = [r for c in near for r in c.reasons]
            # the probe's pixel: the geometry's direction (relative pose) against the truth's pixel
            if ct.probe is not None and sa.photo is not None:
                K = np.asarray(sa.photo.K_full)
                true_px = np.asarray(ct.probe.pixel, np.float64)
                if pa.pixel_geometry is not None:
                    r = rays_through_pixels(
                        K, np.array([true_px[0], pa.pixel_geometry[0]]), np.array([true_px[1], pa.pixel_geometry[1]])
                    )
                    row["pixel_geometry_error_deg"] = math.degrees(float(angular_distance(r[0], r[1])))
                    row["pixel_geometry_error_px"] = float(np.hypot(*(np.asarray(pa.pixel_geometry) - true_px)))
                    row["pixel_geometry_error_frac_width"] = row["pixel_geometry_error_px"] / float(sa.photo.size[0])
                if pa.pixel_full is not None:
                    row["pixel_error_px"] = float(np.hypot(*(np.asarray(pa.pixel_full) - true_px)))
            # probes: PSNR in the paper's tonemap
            if ct.probe is not None and pa.products.ldr_256:
                ref, _ = read_exr(root / ct.probe.hdr_file)
                ref_t = np.asarray(tonemap(ref))
                cap = caps[ct.id]
                assert cap.normal is not None  # the LDR product is made from it
                md = cap.normal.metadata
                ours = read_ldr(campaign / pa.products.ldr_256)
                ours8 = np.round(ours * 255).astype(np.uint8)
                row["psnr_db"] = psnr(np.asarray(tonemap(_radiance(ours8, md, k_sensor))), ref_t)
                row["truth_noise_floor_db"] = noise_floor_db(ref_t)
                render = getattr(ct.probe, "render", None)  # None: a truth of recipe 1 (no render record)
                row["truth_spp"] = getattr(render, "spp", None)
                row["truth_noise_db"] = getattr(render, "noise_psnr_db", None)  # measured (split halves)
                if peers:
                    # R_extra maps the shot's metadata-levelled frame: the true rotation is R_true R_levelᵀ
                    R_true_extra = np.asarray(ct.R_pano_from_body) @ levelling_of(cap.normal)[2].T
                    for name, R_extra in (
                        ("psnr_true_yaw_db", level_to_pano(true_yaw)),
                        ("psnr_true_rotation_db", R_true_extra),
                        ("psnr_compass_db", level_to_pano(wrap_deg(ct.recorded_heading_deg - photo_yaw))),
                    ):
                        pano = load_normal_panorama(campaign, manifest, cap.normal, R_extra)
                        lin = np.asarray(srgb_decode(pano.astype(np.float32) / 255.0), np.float32)
                        s8 = np.round(
                            np.asarray(srgb_encode(np.clip(np.asarray(resize(lin, ref.shape[0])), 0, 1))) * 255
                        ).astype(np.uint8)
                        row[name] = psnr(np.asarray(tonemap(_radiance(s8, md, k_sensor))), ref_t)
            rows.append(row)
    return {"captures": rows, "scenes": scenes, "seed": truth.seed, "n_scenes": len(scenes), "n_captures": len(rows)}


def _load_truth(path: str | Path) -> Any:
    """The truth JSON as attribute-access objects (tolerant of older and newer truth schemas)."""

    def ns(x: Any) -> Any:
        if isinstance(x, dict):
            return SimpleNamespace(**{k: ns(v) for k, v in x.items()})
        if isinstance(x, list):
            return [ns(v) for v in x]
        return x

    data = json.loads(Path(path).read_text())
    t = ns(data)
    t.radiometry = data["radiometry"]
    for st in t.scenes:
        for c in st.captures:
            c.probe = getattr(c, "probe", None)
    return t


def _q(values: list[float], q: float) -> float | None:
    return None if not values else float(np.percentile(values, q))


def summary(result: dict[str, Any]) -> dict[str, Any]:
    """Medians, 95th percentiles and counts of :func:`evaluate`'s figures."""
    rows = result["captures"]
    sun = [r["sun_error_deg"] for r in rows if "sun_error_deg" in r and not r.get("false_sun")]
    yaw = [r["yaw_error_deg"] for r in rows if "yaw_error_deg" in r and r["role"] == "probe"]
    yaw_all = [r["yaw_error_deg"] for r in rows if "yaw_error_deg" in r]
    comp = [r["compass_error_deg"] for r in rows if r["role"] == "probe"]
    ps = [r["psnr_db"] for r in rows if "psnr_db" in r]
    out = {
        "seed": result["seed"],
        "scenes": result["n_scenes"],
        "captures": result["n_captures"],
        "sun_median_deg": _q(sun, 50),
        "sun_p95_deg": _q(sun, 95),
        "sun_n": len(sun),
        "sun_false": sum(1 for r in rows if r.get("false_sun")),
        "sun_missed": sum(1 for r in rows if r.get("miss")),
        "sun_found_not_visible": sum(1 for r in rows if r.get("sun_found") and not r.get("sun_visible")),
        "glints_in_truth": sum(1 for r in rows if "glint_candidate" in r),
        "glints_as_candidates": sum(1 for r in rows if r.get("glint_candidate")),
        "glints_accepted": sum(1 for r in rows if r.get("glint_accepted")),
        "scene_sun_median_deg": _q([s["sun_error_deg"] for s in result["scenes"] if "sun_error_deg" in s], 50),
        "yaw_probe_median_deg": _q(yaw, 50),
        "yaw_probe_p95_deg": _q(yaw, 95),
        "yaw_probe_n": len(yaw),
        "yaw_all_median_deg": _q(yaw_all, 50),
        "yaw_all_p95_deg": _q(yaw_all, 95),
        "compass_probe_median_deg": _q(comp, 50),
        "compass_probe_p95_deg": _q(comp, 95),
        "psnr_median_db": _q(ps, 50),
        "psnr_min_db": min(ps) if ps else None,
        "psnr_n": len(ps),
        "truth_noise_floor_median_db": _q([r["truth_noise_floor_db"] for r in rows if "truth_noise_floor_db" in r], 50),
        "truth_noise_floor_min_db": min(
            [r["truth_noise_floor_db"] for r in rows if "truth_noise_floor_db" in r], default=None
        ),
        "truth_noise_median_db": _q([r["truth_noise_db"] for r in rows if r.get("truth_noise_db") is not None], 50),
        "truth_noise_min_db": min(
            [r["truth_noise_db"] for r in rows if r.get("truth_noise_db") is not None], default=None
        ),
        "pixel_geometry_median_deg": _q(
            [r["pixel_geometry_error_deg"] for r in rows if "pixel_geometry_error_deg" in r], 50
        ),
        "pixel_geometry_p95_deg": _q(
            [r["pixel_geometry_error_deg"] for r in rows if "pixel_geometry_error_deg" in r], 95
        ),
        "pixel_geometry_median_frac_width": _q(
            [r["pixel_geometry_error_frac_width"] for r in rows if "pixel_geometry_error_frac_width" in r], 50
        ),
        "pixel_geometry_n": sum(1 for r in rows if "pixel_geometry_error_deg" in r),
        "psnr_true_yaw_median_db": _q([r["psnr_true_yaw_db"] for r in rows if "psnr_true_yaw_db" in r], 50),
        "psnr_true_rotation_median_db": _q(
            [r["psnr_true_rotation_db"] for r in rows if "psnr_true_rotation_db" in r], 50
        ),
        "psnr_compass_median_db": _q([r["psnr_compass_db"] for r in rows if "psnr_compass_db" in r], 50),
        # review: what a reviewer is told (flags at the probe) against what is wrong
        "scene_sun_found": sum(1 for s in result["scenes"] if s.get("sun_found")),
        "scene_sun_truth": sum(1 for s in result["scenes"] if s.get("sun_truth")),
        "probes_flagged": sum(1 for r in rows if r["role"] == "probe" and r["flags"]),
        "yaw_over_2deg": sum(1 for r in rows if (r.get("yaw_error_deg") or 0.0) > 2.0),
        "yaw_over_2deg_unflagged": sum(1 for r in rows if (r.get("yaw_error_deg") or 0.0) > 2.0 and not r["flags"]),
    }
    return out
