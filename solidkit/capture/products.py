"""Derived products of a campaign: merged HDR panoramas and sun frames, each reproducible from its recipe.

Products (``CAMPAIGN_DIR/products/<scene>/<probe>/``):

- ``hdr``: each bracket merged to linear HDR EXR (:func:`solidkit.capture.frame_merge.merge_frames`,
  response curve from ``--response`` or the sRGB inverse) in the capture's layout, then made a
  panorama in the panorama frame (:func:`to_panorama`: dual-fisheye unwarped through the shipped
  lens profile of the camera model, or the per-unit profile given with ``--profile``, each lens
  first divided by its falloff when a ``--vignetting`` profile is given, to a panorama as wide as
  the capture like ``solidkit capture unwarp``; stitched input levelled from its gravity when the
  camera did not; untouched otherwise). Without a fitting profile the EXR keeps the capture
  layout (``layout``) and says why in ``stats["panorama"]``.
- ``sun_frame``: the probe's shortest exposure at or below ``low_exposure_max_s`` (a low-exposure
  shot, else the shortest bracket member), kept as an LDR panorama plus its exposure (time,
  f-number, ISO): the original JPEG itself when it is a level equirect image (no resampling; the
  sun disk saturates anyway: it gives a position, not an intensity), else an 8-bit sRGB PNG of
  :func:`to_panorama`.

Each product records its inputs (sha256), a recipe (tool, parameters, response-curve sha256;
for dual-fisheye products also the lens and vignetting profiles and the panorama size), the
solidkit version and the output's sha256: it is reproducible from originals + profiles + that
version; a product whose recipe changed (other parameters, profiles or solidkit version) is
rebuilt on the next run.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from solidkit import __version__
from solidkit.camera.lens import load_profile, profile_for_metadata
from solidkit.camera.metadata import CaptureMetadata, level_rotation
from solidkit.capture.bracket_merge import merge_bracket
from solidkit.capture.frame_merge import effective_exposure, load_frame, load_response
from solidkit.capture.manifest import Manifest, Product
from solidkit.capture.unwarp import check_image_circles, default_out_height, load_vignetting, unwarp
from solidkit.envmap.io import imread, write_exr, write_ldr
from solidkit.envmap.resample import rotate
from solidkit.envmap.tilt import TILT_FLAG_DEG, TiltEstimate, residual_tilt
from solidkit.errors import InputError, SolidkitError
from solidkit.fsutil import atomic_path, is_environmental, sha256_file
from solidkit.threads import deterministic

__all__ = ["planned_products", "to_panorama", "make_product", "record_profile", "tilt_warning", "stored_tilt"]


def tilt_warning(product: Product) -> str | None:
    """``residual_tilt: ...`` when a product's panorama is reliably more than TILT_FLAG_DEG off level."""
    t = product.stats.get("residual_tilt")
    if not t or not t.get("reliable") or t["tilt_deg"] <= TILT_FLAG_DEG:
        return None
    return (
        f"residual_tilt: the levelled panorama is {t['tilt_deg']:.2f}° ± {t['uncertainty_deg']:.2f}° off level "
        f"(correction pitch {t['pitch_deg']:.2f}°, roll {t['roll_deg']:.2f}°; {t['segments']} vertical edges)"
    )


def stored_tilt(path: str | os.PathLike, meta: CaptureMetadata) -> TiltEstimate | None:
    """The residual tilt (:func:`~solidkit.envmap.tilt.residual_tilt`) of a stitched capture as its
    file stores it, read at half size; ``None`` unless ``meta`` says equirectangular with ``W = 2 H``,
    or when the file cannot be decoded."""
    if meta.image_type != "equirect" or meta.width != 2 * meta.height:
        return None
    import cv2

    try:
        img = imread(path, cv2.IMREAD_REDUCED_COLOR_2)  # what libjpeg prints: in the error or a warning
    except InputError:
        return None
    return residual_tilt(img)


def _recipe_hash(recipe: dict[str, Any], inputs: list[str]) -> str:
    blob = json.dumps({"recipe": recipe, "inputs": inputs}, sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:16]


def planned_products(manifest: Manifest) -> list[Product]:
    """The products the grouping calls for (without their outputs)."""
    out: list[Product] = []
    for sc in manifest.scenes:
        for pr in sc.probes:
            for b in pr.brackets:
                first = manifest.shot(b.shots[0]).metadata
                # "tool" is the name manifests record (not a module path to follow): a changed recipe remakes every
                # product
                recipe = {
                    "tool": "solidkit.capture.bracket_hdr.merge_bracket",
                    "response": manifest.response,
                    "ghost_k": 6.0,
                    "deghost": False,
                    "wb": "camera",
                    "align": True,
                    "solidkit_version": __version__,
                    **_unwarp_recipe(manifest, first),
                }
                out.append(
                    Product(
                        id=f"{sc.id}/{pr.id}/hdr-{b.id}",
                        kind="hdr",
                        scene=sc.id,
                        probe=pr.id,
                        inputs=list(b.shots),
                        layout=first.get("image_type") or "unknown",
                        exposure_time=first.get("exposure_time"),
                        f_number=first.get("f_number"),
                        iso=first.get("iso"),
                        recipe=recipe,
                        recipe_hash=_recipe_hash(recipe, list(b.shots)),
                        solidkit_version=__version__,
                    )
                )
            if pr.sun_frame:
                md = manifest.shot(pr.sun_frame).metadata
                recipe = {
                    "tool": "solidkit.capture.campaign.sun_frame",
                    "solidkit_version": __version__,
                    **_unwarp_recipe(manifest, md),
                }
                out.append(
                    Product(
                        id=f"{sc.id}/{pr.id}/sun",
                        kind="sun_frame",
                        scene=sc.id,
                        probe=pr.id,
                        inputs=[pr.sun_frame],
                        layout=md.get("image_type") or "unknown",
                        exposure_time=md.get("exposure_time"),
                        f_number=md.get("f_number"),
                        iso=md.get("iso"),
                        recipe=recipe,
                        recipe_hash=_recipe_hash(recipe, [pr.sun_frame]),
                        solidkit_version=__version__,
                    )
                )
    return out


def _unwarp_recipe(manifest: Manifest, md: dict[str, Any]) -> dict[str, Any]:
    """Recipe entries of a dual-fisheye product's unwarp: panorama height, lens/vignetting profiles
    (only those given; none for stitched captures, which they do not affect)."""
    if md.get("image_type") not in ("dual_fisheye", "dual_fisheye_upright"):
        return {}

    out: dict[str, Any] = {"pano_height": default_out_height(int(md.get("width") or 0))}
    if manifest.lens_profile is not None:
        out["lens_profile"] = manifest.lens_profile
    if manifest.vignetting is not None:
        out["vignetting"] = manifest.vignetting
    return out


def record_profile(campaign: Path, path: str | os.PathLike, prefix: str) -> dict[str, Any]:
    """Copy a profile file into ``CAMPAIGN_DIR/profiles/<prefix>-<sha16><suffix>`` (once); its record."""
    src = Path(path)
    sha = sha256_file(src)
    rel = Path("profiles") / f"{prefix}-{sha[:16]}{src.suffix.lower()}"
    if not (campaign / rel).is_file() or sha256_file(campaign / rel) != sha:  # absent, or damaged: copied again
        with atomic_path(campaign / rel) as tmp:
            shutil.copyfile(src, tmp)
    return {"kind": "file", "path": rel.as_posix(), "sha256": sha}


class _DamagedProfile(InputError):
    """The campaign's copy of a profile is missing or modified: the product is built again once it is
    given again (``ingest --response/--profile/--vignetting``), not failed for good."""


def _recorded_file(campaign: Path, record: dict[str, Any], what: str) -> Path:
    """The campaign's copy of a recorded profile, checked against its recorded sha256."""
    path = campaign / record["path"]
    if not path.is_file():
        raise _DamagedProfile(f"{what} {record['path']} is missing from the campaign")
    if sha256_file(path) != record["sha256"]:
        raise _DamagedProfile(f"{what} {record['path']} was modified (sha256 differs from the manifest)")
    return path


def _load_optics(campaign: Path, recipe: dict[str, Any]) -> tuple[Any, Any]:
    """``(lens profile or None, vignetting profile or None)`` of a product's recipe."""
    lens = vig = None
    rec = recipe.get("lens_profile")
    if rec is not None:
        lens = load_profile(rec["name"] if rec["kind"] == "shipped" else _recorded_file(campaign, rec, "lens profile"))
    rec = recipe.get("vignetting")
    if rec is not None:
        vig = load_vignetting(_recorded_file(campaign, rec, "vignetting profile"))
    return lens, vig


def _product_path(p: Product, suffix: str) -> Path:
    return Path("products") / p.scene / p.probe / f"{p.id.rsplit('/', 1)[-1]}{suffix}"


def _level_rotation(md: dict[str, Any]):
    """The metadata's levelling rotation (identity for upright dual-fisheye / corrected equirect)."""
    meta = CaptureMetadata.model_validate(md)

    if meta.image_type == "dual_fisheye_upright":
        return np.eye(3)
    return np.asarray(level_rotation(meta))


def to_panorama(
    image, md: dict[str, Any], lens_profile: Any = None, vignetting: Any = None, *, circle_frame: Any = None
) -> tuple[Any, dict[str, Any]]:
    """A linear capture-layout image -> an equirect panorama in the panorama frame (conventions §2).

    Equirect: levelled by the metadata's gravity when the camera did not correct it (returned
    unchanged otherwise). Dual-fisheye: unwarped (:func:`solidkit.capture.unwarp.unwarp`) through
    ``lens_profile`` (a :class:`~solidkit.camera.lens.LensProfile`, e.g. a per-unit one) or else
    the shipped profile of the camera model, each lens divided by its falloff first when a
    ``vignetting`` profile is given, to the same size as ``solidkit capture unwarp`` makes by
    default (:func:`solidkit.capture.unwarp.default_out_height`: as wide as the input).
    The lens circles are checked against the profile (:func:`~solidkit.capture.unwarp.check_image_circles`,
    ``info["profile_warnings"]``) on ``circle_frame`` when given (one frame of ``image``'s bracket, same
    layout and size), else on ``image``.
    Returns ``(panorama, info)``; raises :class:`InputError` when no profile fits or the layout
    is unknown.
    """

    layout = md.get("image_type")
    R = _level_rotation(md)
    identity = bool(np.allclose(R, np.eye(3), atol=1e-12))
    if layout == "equirect":
        if identity:
            return image, {"resampled": False}

        return rotate(image, R, "linear"), {"resampled": True, "levelled": True}
    if layout in ("dual_fisheye", "dual_fisheye_upright"):
        h, w = image.shape[:2]
        prof = lens_profile if lens_profile is not None else profile_for_metadata(md.get("model"), w, h)
        stats: dict[str, Any] = {}
        pano = unwarp(image, prof, default_out_height(w), R, stats=stats, vignetting=vignetting)
        _, circle_warnings = check_image_circles(image if circle_frame is None else circle_frame, prof)
        return pano, {
            "resampled": True,
            "levelled": not identity,
            "profile": prof.model,
            "profile_key": prof.key(),
            "vignetting": vignetting is not None,
            "seam_mad": stats.get("seam_mad"),
            "profile_warnings": circle_warnings,
        }
    raise InputError(f"image type {layout!r} is not a panorama layout (equirect or dual-fisheye)")


def _lit_frame(camp: Path, shots: list[dict[str, Any]], exposures: list[float], md: dict[str, Any]) -> Any:
    """A dual-fisheye bracket's longest exposure (linear, sRGB assumed), where its lens circles are checked; ``None``
    for other layouts.

    Its circles' content is the most lit of the bracket against the same black surround. The merged HDR is no
    place for the check: outside the circles it holds what the bracket's estimated curve makes of the frames' dark
    noise codes (on a virtual glass card a median 0.3-0.56 x the level just inside the circles, against 0.03-0.11 x
    in the longest frame), which pulled the fit 19-26 px / +4-7 % off where the longest frame fits within 0.5 px.
    """
    if md.get("image_type") not in ("dual_fisheye", "dual_fisheye_upright"):
        return None
    i = int(np.argmax(exposures))
    return load_frame(camp / shots[i]["original"], exposures[i]).linear


def make_product(
    product: dict[str, Any], shots: list[dict[str, Any]], campaign: str, response: dict[str, Any]
) -> dict[str, Any]:
    """Worker: build one product; returns the updated product dict (``error`` set on failure).

    Built with the BLAS libraries on one thread (:func:`solidkit.threads.deterministic`): a product's
    bytes do not depend on the machine's thread count.
    """
    with deterministic():
        return _build_product(product, shots, campaign, response)


def _build_product(
    product: dict[str, Any], shots: list[dict[str, Any]], campaign: str, response: dict[str, Any]
) -> dict[str, Any]:
    p = Product.model_validate(product)
    camp = Path(campaign)
    try:
        if p.kind == "hdr":
            given = given_record = None
            if response.get("kind") == "file":
                given, given_record = load_response(_recorded_file(camp, response, "response curve")), response
            ref = shots[0]["metadata"]
            effs, inputs = [], []
            for s in shots:
                md = s["metadata"]
                t = md.get("exposure_time")
                if not t:
                    raise InputError(f"{s['original']}: no exposure time in the metadata")
                eff = effective_exposure(t, md.get("iso"), md.get("f_number"), ref.get("iso"), ref.get("f_number"))
                effs.append(eff)
                inputs.append(
                    {"original": s["original"], "sha256": s["sha256"], "exposure_time": t, "effective_exposure": eff}
                )
            result, prov = merge_bracket(
                [camp / s["original"] for s in shots],
                effs,
                response=given,
                response_record=given_record,
                align=p.recipe.get("align", True),
                ghost_k=p.recipe["ghost_k"],
                deghost=p.recipe["deghost"],
            )
            stats = dict(
                prov["stats"],
                response=prov["response"]["kind"],
                registration=prov["registration"],
                warnings=prov["warnings"],
            )
            hdr, layout = result.hdr, p.layout
            lens, vig = _load_optics(camp, p.recipe)
            try:
                hdr, pano_info = to_panorama(hdr, ref, lens, vig, circle_frame=_lit_frame(camp, shots, effs, ref))
                layout = "equirect"
                # is the level frame level? vertical edges say (envmap.tilt); flagged above TILT_FLAG_DEG
                pano_info["residual_tilt"] = residual_tilt(hdr).to_json()
            except SolidkitError as exc:  # no lens profile for this camera: keep the capture layout
                pano_info = {"panorama": f"not made: {exc}"}
            stats["warnings"] = stats.get("warnings", []) + pano_info.pop("profile_warnings", [])
            stats.update(pano_info)
            p.layout = layout
            rel = _product_path(p, ".exr")
            write_exr(
                camp / rel,
                hdr,
                {
                    "exposure_time": ref.get("exposure_time"),
                    "layout": p.layout,
                    "units": "relative radiance: linear code per second at the first frame's ISO and f-number",
                    "provenance": {
                        "tool": p.recipe["tool"],
                        "solidkit_version": p.solidkit_version,
                        "inputs": inputs,
                        "response": prov["response"],
                        "registration": prov["registration"],
                        "warnings": prov["warnings"],
                        "recipe": p.recipe,
                        "stats": stats,
                    },
                },
            )
            p.path, p.sha256, p.stats = (
                rel.as_posix(),
                sha256_file(camp / rel),
                {k: (round(v, 6) if isinstance(v, float) else v) for k, v in stats.items() if k != "noise_sigma"},
            )
        else:
            s = shots[0]
            md = s["metadata"]
            if (
                md.get("image_type") == "equirect"
                and s["original"].endswith(".jpg")
                and np.allclose(_level_rotation(md), np.eye(3), atol=1e-12)
            ):
                # the stitched, level JPEG is already the LDR panorama: referenced, not re-encoded
                p.path, p.sha256 = s["original"], s["sha256"]
                p.stats = {"resampled": False}
            else:
                frame = load_frame(camp / s["original"], float(md.get("exposure_time") or 1.0))
                pano, info = to_panorama(frame.linear, md, *_load_optics(camp, p.recipe))
                rel = _product_path(p, ".png")
                write_ldr(camp / rel, np.clip(pano, 0.0, 1.0), encode_srgb=True)  # lossless 8-bit sRGB
                p.path, p.sha256, p.stats, p.layout = rel.as_posix(), sha256_file(camp / rel), info, "equirect"
    except SolidkitError as exc:
        p.error = str(exc)
        p.error_transient = isinstance(exc, _DamagedProfile)
        p.path = p.sha256 = None
    except OSError as exc:
        # disk full, permissions, I/O: a per-product error naming the final file (not a temporary),
        # retried on the next run when environmental
        final = _product_path(p, ".exr" if p.kind == "hdr" else ".png").as_posix()
        p.error = f"{final}: could not be built: {exc.strerror or exc}"
        p.error_transient = is_environmental(exc)
        p.path = p.sha256 = None
    return p.model_dump(mode="json")
